"""The environment every ForMIC ROS process runs with (docs/ros.md, "Running nodes on several
machines", has the details and the shipped profiles).

Discovery stays on this machine unless the user says otherwise
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` is set only when the variable is absent), and the
domain id is explicit, so two runs on one network or one machine do not mix. Fast DDS gets a
shipped XML profile unless the user set one: loopback only by default, every interface with
``FORMIC_DDS_NETWORK=hosts``, and a 50 ms reliable-writer heartbeat in both, so a lost sample
is repaired within ~100 ms instead of at the 3 s default (past the world's 1 s deadline).
Set these before ``rclpy.init``: rcl reads them when the context starts.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterator, Mapping
from contextlib import ExitStack, contextmanager, suppress
from pathlib import Path

from formic_runtime.signals import INTERRUPT_SIGNALS, handling

from .executor import InterruptibleExecutor

DISCOVERY_VARIABLE = "ROS_AUTOMATIC_DISCOVERY_RANGE"
DOMAIN_VARIABLE = "ROS_DOMAIN_ID"
PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"  # the one the Fast DDS 2.14 of the PyPI wheels reads
PROFILE_VARIABLE_V3 = "FASTDDS_DEFAULT_PROFILES_FILE"  # Fast DDS 3's name
NETWORK_VARIABLE = "FORMIC_DDS_NETWORK"
WARNED_VARIABLE = "_FORMIC_HOSTS_WARNED"
PROFILE_DIR = Path(__file__).resolve().parent / "fastdds"
PROFILES = {"loopback": PROFILE_DIR / "loopback.xml", "loopback_udp": PROFILE_DIR / "loopback_udp.xml",
            "hosts": PROFILE_DIR / "hosts.xml", "hosts_udp": PROFILE_DIR / "hosts_udp.xml"}
HOSTS_WARNING = ("formic: multi-host DDS (FORMIC_DDS_NETWORK=hosts): this domain's UDP ports "
                 "(7400+250*domain and up) listen on every network interface; anyone who reaches "
                 "them can read the world and drive agents (no DDS security in the pip wheels)")


def network_mode(env: Mapping[str, str]) -> str:
    """``"hosts"`` or ``"loopback"``, from ``FORMIC_DDS_NETWORK`` (default loopback)."""
    value = env.get(NETWORK_VARIABLE, "").strip().lower()
    if value in ("", "loopback", "local", "localhost"):
        return "loopback"
    if value in ("hosts", "host", "network", "all"):
        return "hosts"
    raise ValueError(f"{NETWORK_VARIABLE}={value!r}: expected 'loopback' or 'hosts'")


def shipped_profile(env: Mapping[str, str]) -> Path:
    """The shipped Fast DDS profile for this environment (a profile names its transports, so
    ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4`` picks the one without shared memory)."""
    udp_only = env.get("FASTDDS_BUILTIN_TRANSPORTS", "").strip().upper() == "UDPV4"
    mode = network_mode(env)
    return PROFILES[f"{mode}_udp" if udp_only else mode]


def _is_shipped(path: str) -> bool:
    try:
        return Path(path).resolve().parent == PROFILE_DIR and Path(path).name in {p.name for p in PROFILES.values()}
    except OSError:
        return False


def apply_profile(env: dict[str, str]) -> None:
    """Point Fast DDS at the shipped profile unless the user set their own (a shipped one is
    re-chosen, so a child that changes ``FASTDDS_BUILTIN_TRANSPORTS`` or ``FORMIC_DDS_NETWORK``
    gets the matching file)."""
    user = env.get(PROFILE_VARIABLE) or env.get(PROFILE_VARIABLE_V3)
    if user and not _is_shipped(user):
        for variable in (PROFILE_VARIABLE, PROFILE_VARIABLE_V3):
            env.setdefault(variable, user)
    else:
        env.update(dict.fromkeys((PROFILE_VARIABLE, PROFILE_VARIABLE_V3), str(shipped_profile(env))))


def warn_if_exposed(env: Mapping[str, str] | None = None, stream=None) -> bool:
    """Print :data:`HOSTS_WARNING` to stderr when multi-host DDS is selected, once per process
    tree (a marker in this process's environment passes to children made after the call)."""
    env = os.environ if env is None else env
    if network_mode(env) != "hosts" or env.get(WARNED_VARIABLE) == "1" or os.environ.get(WARNED_VARIABLE) == "1":
        return False
    print(HOSTS_WARNING, file=stream or sys.stderr, flush=True)
    os.environ[WARNED_VARIABLE] = "1"
    return True


def ros_environment(domain_id: int | None = None, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """A copy of ``base`` (default: this process's environment) ready for a ForMIC ROS child;
    ``domain_id`` overrides ``ROS_DOMAIN_ID``. Other ROS and Fast DDS variables pass through
    (e.g. ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``, which avoids stale shared-memory ports after a
    SIGKILL: the tests use it)."""
    env = dict(os.environ if base is None else base)
    env.setdefault(DISCOVERY_VARIABLE, "LOCALHOST")
    apply_profile(env)
    if domain_id is not None:
        env[DOMAIN_VARIABLE] = str(domain_id)
    env["PYTHONUNBUFFERED"] = "1"
    env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    return env


def configure_this_process(domain_id: int | None = None) -> None:
    """Apply :func:`ros_environment` to this process (call before ``rclpy.init``); warn once
    (per process tree) when multi-host DDS is selected."""
    env = ros_environment(domain_id)
    warn_if_exposed(env)
    os.environ.update(env)


def check_domain_id(domain_id: int | None) -> None:
    """Fast DDS accepts domain ids 0-232 (ports are derived from them)."""
    if domain_id is not None and not 0 <= domain_id <= 232:
        raise ValueError(f"ROS domain id {domain_id} is outside 0-232")


LAST_MESSAGES_S = 1.0  # how long a leaving process waits, at most, for its last messages to be acknowledged


def deliver_last_messages(nodes, timeout_s: float = LAST_MESSAGES_S) -> None:
    """Before a process leaves: wait (``timeout_s`` at most, for all its publishers together)
    until every reader matched to its reliable publishers has acknowledged their last messages.
    A sample a reader has not taken yet (a recorder behind on a busy machine, a lost datagram
    waiting for its repair) is lost for good once its writer is gone: a robot bridge that left
    right after the world took its last status once cost the recording that status."""
    from rclpy.duration import Duration

    deadline = time.monotonic() + timeout_s
    with suppress(KeyboardInterrupt):  # a second stop signal: leave at once
        for node in nodes:
            for publisher in node.publishers:
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                publisher.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))


@contextmanager
def ros_session(domain_id: int | None = None, interrupt: bool = True) -> Iterator[InterruptibleExecutor]:
    """rclpy initialised for this process, with one EventsExecutor (yielded, as an
    :class:`InterruptibleExecutor`).

    rclpy's own signal handlers are off: SIGINT and SIGTERM raise KeyboardInterrupt in the
    spin loop (``spin_once`` with short timeouts, never ``spin()``: the events executor from
    the wheels ignores signals inside ``spin()``), so every node shuts down through the same
    ``finally``; with ``interrupt=False`` the signal handlers are left as they are (inside
    :func:`formic_runtime.signals.stop_requests`). Nodes added to the executor are destroyed on exit.
    """
    check_domain_id(domain_id)
    configure_this_process(domain_id)
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    executor = InterruptibleExecutor(EventsExecutor())
    with ExitStack() as signals:
        if interrupt:
            signals.enter_context(handling(INTERRUPT_SIGNALS, executor.interrupt))
        try:
            yield executor
        finally:
            nodes = list(executor.get_nodes())
            deliver_last_messages(nodes)
            executor.shutdown()
            for node in nodes:
                node.destroy_node()
            rclpy.try_shutdown()
