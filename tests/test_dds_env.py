"""The Fast DDS profile every ForMIC ROS process gets (formic_ros.env): loopback-only
transports by default, an explicit multi-host opt-in, fast reliable repair."""

import os
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from formic_ros import env as ros_env
from benchmarks.netsim import Link, namespaces_available

PROBE = str(Path(__file__).with_name("dds_probe.py"))
NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"


def _clean(**extra):
    base = {k: v for k, v in os.environ.items()
            if k not in ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE", "FORMIC_DDS_NETWORK",
                         "FASTDDS_BUILTIN_TRANSPORTS", "ROS_STATIC_PEERS", ros_env.WARNED_VARIABLE)}
    base.update(extra)
    return base


def test_environment_carries_the_shipped_profile():
    env = ros_env.ros_environment(5, _clean())
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(ros_env.PROFILES["loopback"])
    assert env["FASTDDS_DEFAULT_PROFILES_FILE"] == env["FASTRTPS_DEFAULT_PROFILES_FILE"]
    udp = ros_env.ros_environment(5, _clean(FASTDDS_BUILTIN_TRANSPORTS="UDPv4"))
    assert udp["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(ros_env.PROFILES["loopback_udp"])
    # a child that changes the transports or the network mode gets the matching shipped file
    again = ros_env.ros_environment(5, dict(env, FORMIC_DDS_NETWORK="hosts"))
    assert again["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(ros_env.PROFILES["hosts"])
    hosts_udp = ros_env.ros_environment(5, dict(udp, FORMIC_DDS_NETWORK="hosts"))
    assert hosts_udp["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(ros_env.PROFILES["hosts_udp"])
    # the user's own profile wins
    mine = ros_env.ros_environment(5, _clean(FASTRTPS_DEFAULT_PROFILES_FILE="/etc/my.xml"))
    assert mine["FASTRTPS_DEFAULT_PROFILES_FILE"] == "/etc/my.xml"
    with pytest.raises(ValueError):
        ros_env.ros_environment(5, _clean(FORMIC_DDS_NETWORK="everywhere"))


def test_profiles_parse_bind_loopback_and_beat_fast():
    for name, path in ros_env.PROFILES.items():
        assert path.is_file(), path
        root = ET.parse(path).getroot()
        periods = root.findall(f".//{NS}data_writer/{NS}times/{NS}heartbeatPeriod")
        assert periods and periods[0].findtext(f"{NS}sec") == "0"
        assert int(periods[0].findtext(f"{NS}nanosec")) <= 100_000_000
        allow = [i.get("name") for i in root.iter(f"{NS}interface")]
        assert allow == (["lo"] if name.startswith("loopback") else []), name
        assert root.find(f".//{NS}useBuiltinTransports").text == "false"
        kinds = [t.findtext(f"{NS}type") for t in root.iter(f"{NS}transport_descriptor")]
        assert kinds == (["UDPv4"] if name.endswith("_udp") else ["UDPv4", "SHM"]), name
        if name.startswith("hosts"):  # across machines: one datagram fits a 1500-byte MTU, IP never fragments
            assert int(root.findtext(f".//{NS}maxMessageSize")) <= 1500 - 28


def test_hosts_mode_warns_once(capsys, monkeypatch):
    monkeypatch.delenv(ros_env.WARNED_VARIABLE, raising=False)
    assert ros_env.warn_if_exposed({"FORMIC_DDS_NETWORK": "hosts"})
    assert not ros_env.warn_if_exposed({"FORMIC_DDS_NETWORK": "hosts"})
    assert "every network interface" in capsys.readouterr().err
    assert not ros_env.warn_if_exposed({})


def _run_pair(listen_cmd, talk_cmd, listen_env, talk_env, seconds=8.0):
    py = [sys.executable, PROBE]
    listener = subprocess.Popen(listen_cmd + py + ["listen", str(seconds)], env=listen_env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    talker = subprocess.Popen(talk_cmd + py + ["talk", str(seconds)], env=talk_env, text=True,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        out = listener.communicate(timeout=seconds + 15)[0]
        return out
    finally:
        for p in (listener, talker):
            if p.poll() is None:
                p.kill()
            p.wait(timeout=10)


def test_default_profile_discovers_on_this_machine_and_binds_loopback_only():
    pytest.importorskip("rclpy")
    # domains 60-79: their well-known ports (22400-27175) lie below the kernel's ephemeral range
    # (32768 up), so none of Fast DDS's ephemeral sending sockets, bound to any interface, can
    # take one (one did, in domain 116); the other ROS tests use 120-219
    domain = 60 + os.getpid() % 20
    ephemeral_low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    assert 7400 + 250 * domain + 26 < ephemeral_low, "pick domains whose ports lie below the ephemeral range"
    env = ros_env.ros_environment(domain, _clean(FASTDDS_BUILTIN_TRANSPORTS="UDPv4"))
    out = _run_pair([], [], env, env)
    assert "received 1" in out, out
    # what a default-profile process listens on: the domain's ports only on 127.0.0.1
    py = [sys.executable, PROBE, "listen", "40"]
    p = subprocess.Popen(py, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    base = 7400 + 250 * domain
    # the well-known ports (docs/ros.md, "Network exposure"): multicast, and the unicast pairs of
    # the first participant indexes; Fast DDS's ephemeral sending ports (any interface, any port
    # number, sometimes one inside the domain's range) are not listening locators
    well_known = {base, base + 1, 7000, 7001} | {base + 10 + 2 * i + k for i in range(8) for k in (0, 1)}

    def listening() -> tuple[list[str], list[str]]:
        ss = subprocess.run(["ss", "-ulpnH"], capture_output=True, text=True, timeout=10).stdout
        mine = [line.split()[3] for line in ss.splitlines() if f"pid={p.pid}," in line]
        return mine, [a for a in mine if int(a.rsplit(":", 1)[1]) in well_known]

    deadline = time.monotonic() + 30  # until the participant is up (a loaded machine imports rclpy slowly)
    try:
        while not listening()[1] and time.monotonic() < deadline and p.poll() is None:
            time.sleep(0.25)
        time.sleep(1.0)  # the participant opens its sockets together; give the rest a moment
        mine, domain_ports = listening()
    finally:
        p.kill()
        p.wait(timeout=10)
    assert domain_ports, mine
    assert all(a.startswith("127.0.0.1:") for a in domain_ports), mine


@pytest.mark.skipif(not namespaces_available(), reason="cannot create network namespaces")
@pytest.mark.parametrize("world_network", ["loopback", "hosts"])
def test_static_peer_from_another_namespace_joins_only_in_hosts_mode(world_network):
    """A node in another namespace naming the world's address in ROS_STATIC_PEERS cannot reach
    a default-profile participant, and can once the world opts in to hosts mode."""
    pytest.importorskip("rclpy")
    domain = 140 + os.getpid() % 20
    with Link(f"fxe{world_network[0]}", net=214 if world_network == "hosts" else 215) as link:
        world_env = ros_env.ros_environment(domain, _clean(FASTDDS_BUILTIN_TRANSPORTS="UDPv4",
                                                           FORMIC_DDS_NETWORK=world_network,
                                                           **{ros_env.WARNED_VARIABLE: "1"}))
        intruder_env = ros_env.ros_environment(domain, _clean(FASTDDS_BUILTIN_TRANSPORTS="UDPv4",
                                                              FORMIC_DDS_NETWORK="hosts",
                                                              ROS_STATIC_PEERS=link.addr("a"),
                                                              **{ros_env.WARNED_VARIABLE: "1"}))
        out = _run_pair(link.exec_in("a"), link.exec_in("b"), world_env, intruder_env, seconds=6.0)
    expected = "received 1" if world_network == "hosts" else "received 0"
    assert expected in out, out
