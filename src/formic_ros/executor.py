"""A node's spin loop and the stop rule (:mod:`formic_runtime.signals`): the executor holds a
stop signal back until the callback it is running ends, then interrupts."""

from __future__ import annotations

from types import FrameType


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
