"""The one stop rule of every ForMIC command and node: SIGINT, SIGTERM and SIGHUP ask to stop.

Where a stop must finish what it started (a launcher stopping its children, a recorder closing
its file, a trainer saving its checkpoint) the first stop signal counts and later ones (a second
Ctrl-C, ``timeout``'s SIGTERM to the group, a closing terminal's SIGHUP) are ignored while it
stops. Every handler installed here is installed for a block (:func:`handling`) and the previous
one comes back when the block ends. Signal handlers exist only in the main thread: elsewhere the
blocks change nothing. No ROS here (the launch layer uses it)."""

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


class InterruptibleExecutor:
    """An executor whose :meth:`spin_once` holds back SIGINT or SIGTERM while it runs and then
    raises KeyboardInterrupt: raised inside a timer or subscription callback, the interrupt
    would be logged by the executor as a FATAL error of that node on every normal Ctrl-C.
    Outside ``spin_once`` the signal interrupts at once. Everything else is the wrapped
    executor's."""

    def __init__(self, executor):
        self._executor = executor
        self._depth = 0  # spin_once calls under way (a callback may spin too)
        self._held: int | None = None  # the signal that arrived during one

    def __getattr__(self, name: str):
        return getattr(self._executor, name)

    def spin_once(self, timeout_sec: float | None = None) -> None:
        self._spin(self._executor.spin_once, timeout_sec=timeout_sec)

    def spin_ready(self) -> None:
        """Run every event that is ready now and wait for none (``spin_once`` runs one event:
        a loop that spins between other waits would fall behind a busy topic)."""
        from rclpy.task import Future

        self._spin(self._executor.spin_until_future_complete, Future(), timeout_sec=0.0)

    def _spin(self, spin, *args, **kwargs) -> None:
        self._depth += 1
        try:
            spin(*args, **kwargs)
        finally:
            self._depth -= 1
        if self._held is not None and not self._depth:
            signum, self._held = self._held, None
            raise KeyboardInterrupt(f"signal {signum}")

    def interrupt(self, signum: int, frame: FrameType | None) -> None:
        """The handler of :data:`INTERRUPT_SIGNALS`."""
        if self._depth:
            self._held = signum
        else:
            raise KeyboardInterrupt(f"signal {signum}")
