"""Two "machines" on one Linux host, joined by a link with delay and loss (root only).

This kernel may lack netem, so the link is a userspace layer-2 forwarder: two network
namespaces (``<prefix>a``, ``<prefix>b``) each get one end of a veth pair whose other end lies
in a third namespace (``<prefix>r``), where :func:`forward` copies Ethernet frames between the
two ends with a fixed one-way delay and a seeded random loss of IPv4 packets. Veth leaves UDP
checksums unfilled (offload), so the forwarder zeroes them (valid for IPv4: "no checksum").

Test and benchmark infrastructure, not part of the package. Use only for tests and measurements::

    with Link("fx", delay_ms=20, loss=0.02, seed=1) as link:
        subprocess.run(link.exec_in("a") + ["python", "-c", "..."])   # address link.addr("a")

or from a shell: ``python benchmarks/netsim.py forward IF1 IF2 --delay-ms 20 --loss 0.02``
(inside the router namespace). ``bench`` measures lockstep across such a link,
``train`` distributed training (:func:`training_across_link`).
"""

from __future__ import annotations

import argparse
import heapq
import os
import random
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time

ETH_P_ALL = 0x0003
PACKET_OUTGOING = 4


def namespaces_available() -> bool:
    """Whether this process can create network namespaces (root, ``ip`` present)."""
    if shutil.which("ip") is None or os.geteuid() != 0:
        return False
    name = f"fxprobe{os.getpid()}"
    try:
        ok = subprocess.run(["ip", "netns", "add", name], capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False
    if ok:
        subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=10)
    return ok


def _zero_udp_checksum(frame: bytearray) -> None:
    if len(frame) < 34 or frame[12:14] != b"\x08\x00":
        return
    ihl = (frame[14] & 0x0F) * 4
    frag = struct.unpack_from("!H", frame, 20)[0] & 0x1FFF
    if frame[23] == 17 and frag == 0 and len(frame) >= 14 + ihl + 8:
        frame[14 + ihl + 6:14 + ihl + 8] = b"\x00\x00"


def forward(if1: str, if2: str, delay_ms: float = 0.0, loss: float = 0.0, seed: int = 0,
            duration_s: float | None = None) -> dict:
    """Relay frames between two interfaces of this namespace (both directions), each IPv4 frame
    dropped with probability ``loss`` and sent ``delay_ms`` after it arrived. Runs until
    SIGTERM/SIGINT or ``duration_s``; returns counts."""
    rng = random.Random(seed)
    socks = {}
    for name in (if1, if2):
        s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        s.bind((name, 0))
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        socks[name] = s
    peer = {socks[if1]: socks[if2], socks[if2]: socks[if1]}
    queue: list = []
    seq = 0
    counts = {"forwarded": 0, "dropped": 0}
    stop = []
    signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
    end = None if duration_s is None else time.monotonic() + duration_s
    delay = delay_ms / 1e3
    try:
        while not stop and (end is None or time.monotonic() < end):
            now = time.monotonic()
            while queue and queue[0][0] <= now:
                _, _, out, frame = heapq.heappop(queue)
                try:
                    out.send(frame)
                    counts["forwarded"] += 1
                except OSError:
                    pass
            timeout = 0.05 if not queue else max(0.0, queue[0][0] - time.monotonic())
            ready, _, _ = select.select(list(peer), [], [], timeout)
            for s in ready:
                try:
                    data, addr = s.recvfrom(65536)
                except OSError:
                    continue
                if addr[2] == PACKET_OUTGOING:
                    continue
                frame = bytearray(data)
                if frame[12:14] == b"\x08\x00" and loss > 0 and rng.random() < loss:
                    counts["dropped"] += 1
                    continue
                _zero_udp_checksum(frame)
                seq += 1
                heapq.heappush(queue, (time.monotonic() + delay, seq, peer[s], bytes(frame)))
    except KeyboardInterrupt:
        pass
    finally:
        for s in socks.values():
            s.close()
    return counts


def _ip(*args: str, check: bool = True) -> None:
    subprocess.run(["ip", *args], check=check, capture_output=True, timeout=10)


class Link:
    """Namespaces ``<prefix>a`` (``10.<net>.0.1``) and ``<prefix>b`` (``10.<net>.0.2``) joined
    through a forwarder in ``<prefix>r``. Everything is removed on exit."""

    def __init__(self, prefix: str, delay_ms: float = 0.0, loss: float = 0.0, seed: int = 0, net: int = 213):
        self.prefix, self.delay_ms, self.loss, self.seed, self.net = prefix, delay_ms, loss, seed, net
        self.forwarder: subprocess.Popen | None = None

    def ns(self, side: str) -> str:
        return f"{self.prefix}{side}"

    def addr(self, side: str) -> str:
        return f"10.{self.net}.0.{1 if side == 'a' else 2}"

    def exec_in(self, side: str) -> list[str]:
        return ["ip", "netns", "exec", self.ns(side)]

    def __enter__(self) -> "Link":
        try:
            self.close()
            for side in "abr":
                _ip("netns", "add", self.ns(side))
                _ip("-n", self.ns(side), "link", "set", "lo", "up")
            for side in "ab":
                host, router = f"{self.prefix}{side}0", f"{self.prefix}{side}1"
                _ip("link", "add", host, "netns", self.ns(side), "type", "veth", "peer", "name", router,
                    "netns", self.ns("r"))
                _ip("-n", self.ns(side), "addr", "add", f"{self.addr(side)}/24", "dev", host)
                _ip("-n", self.ns(side), "link", "set", host, "up")
                _ip("-n", self.ns("r"), "link", "set", router, "up")
            self.forwarder = subprocess.Popen(
                self.exec_in("r") + [sys.executable, os.path.abspath(__file__), "forward",
                                     f"{self.prefix}a1", f"{self.prefix}b1", "--delay-ms", str(self.delay_ms),
                                     "--loss", str(self.loss), "--seed", str(self.seed)],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
            time.sleep(0.3)
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        if self.forwarder is not None:
            try:
                os.killpg(self.forwarder.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.forwarder.wait(timeout=10)
            self.forwarder = None
        for side in "abr":
            _ip("netns", "del", self.ns(side), check=False)

    def __exit__(self, *exc) -> None:
        self.close()


EMPTY_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"><profiles/></dds>
"""


def _json_line(text: str) -> dict:
    import json

    for line in reversed(text.splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise ValueError(f"no JSON line in:\n{text[-3000:]}")


def _link_environments(link: Link, domain_id: int, fastdds_defaults: bool, workdir: str) -> tuple[dict, dict]:
    """The two sides' environments: multi-host DDS on UDPv4 only (no shared memory between
    namespaces of one host), each naming the other in ``ROS_STATIC_PEERS``. ``fastdds_defaults``:
    an empty user profile (Fast DDS's own settings) instead of the shipped one."""
    from formic_ros.env import ros_environment

    base = dict(os.environ, FASTDDS_BUILTIN_TRANSPORTS="UDPv4", FORMIC_DDS_NETWORK="hosts",
                ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", _FORMIC_HOSTS_WARNED="1")
    base.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    base.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
    if fastdds_defaults:
        path = os.path.join(workdir, f"{link.prefix}_empty_profile.xml")
        with open(path, "w") as fh:
            fh.write(EMPTY_PROFILE)
        base["FASTRTPS_DEFAULT_PROFILES_FILE"] = path
    return (ros_environment(domain_id, dict(base, ROS_STATIC_PEERS=link.addr("b"))),
            ros_environment(domain_id, dict(base, ROS_STATIC_PEERS=link.addr("a"))))


def _kill_all(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        p.wait(timeout=10)


FORMIC = [sys.executable, "-m", "formic_cli.main"]


def run_on_link(link: Link, envs: dict[str, dict], commands: dict[str, tuple[str, list[str]]],
                waited: tuple[str, ...], limit_s: float, workdir: str) -> tuple[dict[str, str], dict, float]:
    """Each command (``name: (side, formic arguments)``) started in namespace ``side`` of
    ``link`` with ``envs[side]``, its output in ``workdir/<prefix>_<name>.log``; waits at most
    ``limit_s`` in all for the ``waited`` ones. Returns every log's text, every exit code (None:
    still running, then killed) and the seconds waited; the processes are killed in any case."""
    procs: dict[str, subprocess.Popen] = {}
    logs = {name: open(os.path.join(workdir, f"{link.prefix}_{name}.log"), "w+") for name in commands}
    try:
        started = time.monotonic()
        for name, (side, args) in commands.items():
            procs[name] = subprocess.Popen(link.exec_in(side) + FORMIC + args, env=envs[side], stdout=logs[name],
                                           stderr=subprocess.STDOUT, start_new_session=True)
        end = started + limit_s
        for name in waited:
            try:
                procs[name].wait(timeout=max(1.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                break
        elapsed = time.monotonic() - started
        for log in logs.values():
            log.seek(0)
        return {name: log.read() for name, log in logs.items()}, {name: p.poll() for name, p in procs.items()}, elapsed
    finally:
        _kill_all(list(procs.values()))
        for log in logs.values():
            log.close()


def lockstep_across_link(agents: int = 16, steps: int = 60, size: int = 32, seed: int = 0,
                         delay_ms: float = 20.0, loss: float = 0.02, link_seed: int = 1,
                         fastdds_defaults: bool = False, domain_id: int = 147, prefix: str = "fxl",
                         limit_s: float = 120.0, workdir: str = "/tmp") -> dict:
    """``formic world`` in namespace a, ``formic agents`` (per-agent, learned ``formic``) in b,
    lockstep over a link with ``delay_ms`` each way and ``loss``; returns the world's JSON
    summary plus ``link``. ``fastdds_defaults``: an empty user profile (Fast DDS's own 3 s
    heartbeat) instead of the shipped one."""
    world_args = ["--agents", str(agents), "--size", str(size), "--steps", str(steps), "--seed", str(seed)]
    with Link(prefix, delay_ms=delay_ms, loss=loss, seed=link_seed) as link:
        env_a, env_b = _link_environments(link, domain_id, fastdds_defaults, workdir)
        procs = []
        try:
            logs = [open(os.path.join(workdir, f"{prefix}_{side}.log"), "w+") for side in "ab"]
            started = time.monotonic()
            world = subprocess.Popen(link.exec_in("a") + FORMIC + ["world", *world_args, "--json",
                                                                  "--startup-timeout", str(limit_s / 2)],
                                     env=env_a, stdout=logs[0], stderr=subprocess.STDOUT, start_new_session=True)
            procs.append(world)
            host = subprocess.Popen(link.exec_in("b") + FORMIC + ["agents", "--ids", f"0-{agents - 1}",
                                                                 "--policy", "formic", "--once"],
                                    env=env_b, stdout=logs[1], stderr=subprocess.STDOUT, start_new_session=True)
            procs.append(host)
            world.wait(timeout=limit_s)
            elapsed = time.monotonic() - started
            logs[0].seek(0)
            summary = _json_line(logs[0].read())
            summary["link"] = {"delay_ms": delay_ms, "loss": loss, "seed": link_seed,
                               "profile": "fastdds-defaults" if fastdds_defaults else "formic",
                               "wall_s": round(elapsed, 1)}
            return summary
        finally:
            _kill_all(procs)


def _json_lines(text: str) -> list[dict]:
    import json

    return [json.loads(line) for line in text.splitlines() if line.startswith("{")]


def link_training_config(agents: int = 16, size: int = 32, steps: int = 128, seed: int = 0):
    """The training configuration :func:`training_across_link` runs: the cpu preset (128-step
    rollouts), one team of ``agents`` on a ``size`` square, ``steps``-step episodes."""
    from formic_trainer.config import make_config

    return make_config("cpu", seed=seed, teams=(agents,), world_sizes=((size, size),), episode_steps=steps)


def training_across_link(episodes: int = 10, agents: int = 16, size: int = 32, steps: int = 128, seed: int = 0,
                         delay_ms: float = 20.0, loss: float = 0.02, link_seed: int = 1,
                         fastdds_defaults: bool = False, domain_id: int = 148, prefix: str = "fxt",
                         net: int = 216, limit_s: float = 300.0, workdir: str = "/tmp") -> dict:
    """``formic train-ros``'s three nodes split over a link with ``delay_ms`` each way and
    ``loss``, started by hand as docs/ros.md shows: ``formic trainer`` and ``formic world
    --train-config`` in namespace a, ``formic agents --train-config`` (the whole team, batched)
    in b, ``episodes`` episodes of :func:`link_training_config`. Returns the world's episode
    summaries, the trainer's result,
    ``episodes_per_s`` (episodes after the first over their wall time, start-up excluded) and
    ``link``; the logs stay in ``workdir``."""
    import json
    import math

    cfg = link_training_config(agents, size, steps, seed)
    config_file = os.path.join(workdir, f"{prefix}_config.json")
    with open(config_file, "w") as fh:
        json.dump(cfg.to_dict(), fh)
    rollouts = episodes * math.ceil(steps / cfg.rollout_steps)
    train = ["--train-config", config_file]
    commands = {
        "trainer": ("a", ["trainer", *train, "--run-dir", os.path.join(workdir, f"{prefix}_run"), "--fresh",
                          "--max-rollouts", str(rollouts), "--json"]),
        "world": ("a", ["world", *train, "--episodes", str(episodes), "--deadline-ms", "120000",
                        "--startup-timeout", str(limit_s / 2), "--json"]),
        "host": ("b", ["agents", "--ids", f"0-{agents - 1}", "--transport", "batched", *train,
                       "--episodes", str(episodes)]),
    }
    with Link(prefix, delay_ms=delay_ms, loss=loss, seed=link_seed, net=net) as link:
        envs = dict(zip("ab", _link_environments(link, domain_id, fastdds_defaults, workdir)))
        texts, exit_codes, elapsed = run_on_link(link, envs, commands, ("world", "trainer"), limit_s, workdir)
    summaries = _json_lines(texts["world"])
    trainer = _json_lines(texts["trainer"])
    later = [s["wall_s"] for s in summaries[1:]]
    return {
        "episodes": [{k: s.get(k) for k in ("episode", "food", "steps_per_s", "missed_actions", "wall_s")}
                     for s in summaries],
        "trainer": trainer[-1] if trainer else None,
        "episodes_per_s": len(later) / sum(later) if later else 0.0,
        "exit_codes": exit_codes,
        "link": {"delay_ms": delay_ms, "loss": loss, "seed": link_seed,
                 "profile": "fastdds-defaults" if fastdds_defaults else "formic", "wall_s": round(elapsed, 1)},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python benchmarks/netsim.py")
    sub = parser.add_subparsers(dest="command", required=True)
    f = sub.add_parser("forward", help="relay frames between two interfaces with delay and loss")
    f.add_argument("if1")
    f.add_argument("if2")
    f.add_argument("--delay-ms", type=float, default=0.0)
    f.add_argument("--loss", type=float, default=0.0)
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--duration-s", type=float)
    b = sub.add_parser("bench", help="lockstep world | agents across a lossy link (root)")
    b.add_argument("--agents", type=int, default=16)
    b.add_argument("--steps", type=int, default=60)
    b.add_argument("--delay-ms", type=float, default=20.0)
    b.add_argument("--loss", type=float, default=0.02)
    b.add_argument("--fastdds-defaults", action="store_true", help="Fast DDS's own settings (3 s heartbeat)")
    t = sub.add_parser("train", help="trainer + training world | learning host across a lossy link (root)")
    t.add_argument("--episodes", type=int, default=10)
    t.add_argument("--agents", type=int, default=16)
    t.add_argument("--steps", type=int, default=128)
    t.add_argument("--delay-ms", type=float, default=20.0)
    t.add_argument("--loss", type=float, default=0.02)
    t.add_argument("--fastdds-defaults", action="store_true", help="Fast DDS's own settings")
    t.add_argument("--workdir", default="/tmp", help="logs and the run directory go here")
    args = parser.parse_args(argv)
    if args.command == "train":
        import json

        print(json.dumps(training_across_link(args.episodes, args.agents, steps=args.steps, delay_ms=args.delay_ms,
                                              loss=args.loss, fastdds_defaults=args.fastdds_defaults,
                                              workdir=args.workdir)))
        return 0
    if args.command == "bench":
        import json

        r = lockstep_across_link(args.agents, args.steps, delay_ms=args.delay_ms, loss=args.loss,
                                 fastdds_defaults=args.fastdds_defaults)
        print(json.dumps({k: r.get(k) for k in ("steps_per_s", "missed_actions", "state_digest", "link")}))
        return 0
    counts = forward(args.if1, args.if2, args.delay_ms, args.loss, args.seed, args.duration_s)
    print(counts, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
