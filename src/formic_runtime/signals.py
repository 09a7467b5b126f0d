"""The one stop rule of every ForMIC command and node: SIGINT, SIGTERM and SIGHUP ask to stop.

Where a stop must finish what it started (a launcher stopping its children, a recorder closing
its file, a trainer saving its checkpoint) the first stop signal counts and later ones (a second
Ctrl-C, ``timeout``'s SIGTERM to the group, a closing terminal's SIGHUP) are ignored while it
stops. A loop whose steps take minutes to end whole (an in-process training's episode set) is the
exception (:class:`StopBetweenSteps`): a second stop there interrupts at once, as the user asked
twice. Every handler installed here is installed for a block (:func:`handling`) and the previous
one comes back when the block ends. Signal handlers exist only in the main thread: elsewhere the
blocks change nothing. No ROS here: the launch layer and the ROS-free commands (``formic eval``)
use it too; the ROS executor that holds a signal back until its callback ends is
:class:`formic_ros.executor.InterruptibleExecutor`."""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
INTERRUPT_SIGNALS = (signal.SIGINT, signal.SIGTERM)  # what interrupts a node's spin loop

Handler = Callable[[int, FrameType | None], None]


@contextmanager
def handling(signals: tuple[int, ...], handler: Handler) -> Iterator[None]:
    """``handler`` for ``signals`` inside the block (main thread only), the previous handlers
    back on exit (the default where Python had none)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, handler) for s in signals}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old if old is not None else signal.SIG_DFL)


class FirstStopInterrupts:
    """A handler: the first stop signal raises KeyboardInterrupt, every later one is ignored
    (as is any after :meth:`stop` was called: the stop is already under way)."""

    def __init__(self):
        self.stopping = False

    def stop(self) -> None:
        self.stopping = True

    def __call__(self, signum: int, _frame: FrameType | None) -> None:
        if not self.stopping:
            self.stopping = True
            raise KeyboardInterrupt(f"signal {signum}")


class StopBetweenSteps:
    """A handler for a loop of long steps: the first stop signal asks it to stop after the step in
    progress (:attr:`requested`; ``notice`` goes to stderr at once, so that the user knows the
    signal was heard), a second one raises KeyboardInterrupt, losing that step."""

    def __init__(self, notice: str):
        self.notice, self.requested = notice, False

    def __call__(self, signum: int, _frame: FrameType | None) -> None:
        if self.requested:
            raise KeyboardInterrupt(f"signal {signum}")
        self.requested = True
        try:  # unbuffered: the handler may run inside a print to the same stream
            os.write(2, f"{self.notice}\n".encode())
        except OSError:
            pass


@contextmanager
def stop_requests() -> Iterator[list]:
    """Stop signals append to the yielded list instead of interrupting, until the block ends: a
    node that must close a recording or save a checkpoint polls the list, and a second Ctrl-C
    (or the terminal's SIGHUP) cannot cut its closing short."""
    stop: list[bool] = []
    with handling(STOP_SIGNALS, lambda *_: stop.append(True)):
        yield stop
