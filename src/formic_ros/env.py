"""The environment every ForMIC ROS process runs with.

Discovery stays on this machine unless the user says otherwise
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` is set only when the variable is absent), and the
domain id is explicit, so two runs on one network or one machine do not mix. Set these before
``rclpy.init``: rcl reads them when the context starts.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

DISCOVERY_VARIABLE = "ROS_AUTOMATIC_DISCOVERY_RANGE"
DOMAIN_VARIABLE = "ROS_DOMAIN_ID"


def ros_environment(domain_id: int | None = None, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """A copy of ``base`` (default: this process's environment) ready for a ForMIC ROS child;
    ``domain_id`` overrides ``ROS_DOMAIN_ID``. Other ROS and Fast DDS variables pass through
    (e.g. ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``, which avoids stale shared-memory ports after a
    SIGKILL: the tests use it)."""
    env = dict(os.environ if base is None else base)
    env.setdefault(DISCOVERY_VARIABLE, "LOCALHOST")
    if domain_id is not None:
        env[DOMAIN_VARIABLE] = str(domain_id)
    env["PYTHONUNBUFFERED"] = "1"
    env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    return env


def configure_this_process(domain_id: int | None = None) -> None:
    """Apply :func:`ros_environment` to this process (call before ``rclpy.init``)."""
    os.environ.update(ros_environment(domain_id))


def check_domain_id(domain_id: int | None) -> None:
    """Fast DDS accepts domain ids 0-232 (ports are derived from them)."""
    if domain_id is not None and not 0 <= domain_id <= 232:
        raise ValueError(f"ROS domain id {domain_id} is outside 0-232")


@contextmanager
def stop_requests() -> Iterator[list]:
    """SIGINT and SIGTERM append to the yielded list instead of interrupting (a node that must
    close files or save a checkpoint polls it); the previous handlers come back on exit."""
    stop: list[bool] = []
    handlers = {s: signal.signal(s, lambda *_: stop.append(True)) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@contextmanager
def ros_session(domain_id: int | None = None) -> Iterator:
    """rclpy initialised for this process, with one EventsExecutor (yielded).

    rclpy's own signal handlers are off: SIGINT and SIGTERM raise KeyboardInterrupt in the
    spin loop (``spin_once`` with short timeouts, never ``spin()``: the events executor from
    the wheels ignores signals inside ``spin()``), so every node shuts down through the same
    ``finally``. Nodes added to the executor are destroyed on exit.
    """
    check_domain_id(domain_id)
    configure_this_process(domain_id)
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    previous = signal.signal(signal.SIGTERM, _interrupt)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    executor = EventsExecutor()
    try:
        yield executor
    finally:
        nodes = list(executor.get_nodes())
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGTERM, previous)
