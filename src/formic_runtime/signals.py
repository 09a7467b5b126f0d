"""The one stop rule of every ForMIC command and node: SIGINT, SIGTERM and SIGHUP ask to stop.

Where a stop must finish what it started (a launcher stopping its children, a recorder closing
its file, a trainer saving its checkpoint) the first stop signal counts and later ones (a second
Ctrl-C, ``timeout``'s SIGTERM to the group, a closing terminal's SIGHUP) are ignored while it
stops. Every handler installed here is installed for a block (:func:`handling`) and the previous
one comes back when the block ends. Signal handlers exist only in the main thread: elsewhere the
blocks change nothing. No ROS here: the launch layer and the ROS-free commands (``formic eval``)
use it too; the ROS executor that holds a signal back until its callback ends is
:class:`formic_ros.executor.InterruptibleExecutor`."""

from __future__ import annotations

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


@contextmanager
def stop_requests() -> Iterator[list]:
    """Stop signals append to the yielded list instead of interrupting, until the block ends: a
    node that must close a recording or save a checkpoint polls the list, and a second Ctrl-C
    (or the terminal's SIGHUP) cannot cut its closing short."""
    stop: list[bool] = []
    with handling(STOP_SIGNALS, lambda *_: stop.append(True)):
        yield stop
