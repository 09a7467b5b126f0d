#!/usr/bin/env python3
"""The cost of one rclpy ``publish`` of a small message to a subscriber in another process:
the floor under the per-agent transport, which publishes one observation and one action per
agent and step (docs/ros.md, "Speed").

N publishers (one topic each, as the per-agent transport has) send ``AgentAction`` messages
with the transport's QoS (reliable, keep last); a subscriber process takes them with an events
executor and reports how many arrived and its CPU time per message taken (the executor's take and
dispatch and a Python callback that counts: the receiving side of a message). With ``--message observation`` they send what the world
sends each agent instead: a serialized ``AgentObservation`` of an 8-channel 11x11 view (3.9 kB),
as bytes, taken as bytes. Printed: microseconds per publish, over ``--rounds`` rounds of one
message per topic (a short sleep between rounds, not counted):

    .venv/bin/python benchmarks/rclpy_publish.py --topics 128 --rounds 100
    .venv/bin/python benchmarks/rclpy_publish.py --topics 128 --rounds 100 --message observation
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

SUBSCRIBER = """
import sys, time
import rclpy
from rclpy.experimental import EventsExecutor
from formic_interfaces.msg import AgentAction, AgentObservation
from formic_ros import qos
topics, seconds, observation = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3] == "observation"
rclpy.init()
node = rclpy.create_node("publish_bench_reader")
count, cpu = [0], [0.0, 0.0]  # messages; the reader's CPU clock at the first and the last
def taken(_message):
    cpu[count[0] > 0] = time.process_time()
    count[0] += 1
for i in range(topics):
    node.create_subscription(AgentObservation if observation else AgentAction, f"publish_bench/a{i}", taken,
                             qos.STREAM, raw=observation)
executor = EventsExecutor()
executor.add_node(node)
end = time.monotonic() + seconds
while time.monotonic() < end:
    executor.spin_once(timeout_sec=0.05)
print(count[0], (cpu[1] - cpu[0]) / max(count[0] - 1, 1), flush=True)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--topics", type=int, default=128)
    parser.add_argument("--rounds", type=int, default=100)
    parser.add_argument("--message", choices=("action", "observation"), default="action",
                        help="AgentAction messages, or serialized AgentObservation bytes (what the world sends).")
    parser.add_argument("--domain-id", type=int, default=77, help="A ROS domain no other run uses.")
    parser.add_argument("--json", action="store_true", help="Print one JSON object.")
    args = parser.parse_args()

    from formic_ros.env import ros_environment

    os.environ.update(ros_environment(args.domain_id))
    import rclpy
    from formic_interfaces.msg import AgentAction, AgentObservation
    from rclpy.serialization import serialize_message

    from formic_ros import qos

    rclpy.init()
    node = rclpy.create_node("publish_bench_writer")
    kind = AgentObservation if args.message == "observation" else AgentAction
    publishers = [node.create_publisher(kind, f"publish_bench/a{i}", qos.STREAM_WRITER) for i in range(args.topics)]
    reader_s = 15.0 + args.rounds * args.topics * 1e-4
    reader = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(args.topics), str(reader_s), args.message],
                              stdout=subprocess.PIPE, text=True, env=os.environ.copy())
    try:
        deadline = time.monotonic() + 10.0
        while any(p.get_subscription_count() == 0 for p in publishers):
            if time.monotonic() > deadline:
                raise SystemExit("the reader did not match every topic within 10 s")
            time.sleep(0.05)
        time.sleep(0.5)
        if args.message == "observation":  # the world's: serialized bytes, an 8 x 11 x 11 view
            messages = [serialize_message(AgentObservation(step=1, agent_id=i, channels=8, size=11,
                                                           data=[0.5] * (8 * 11 * 11), action_mask=[1] * 5))
                        for i in range(args.topics)]
        else:
            messages = [AgentAction(step=1, agent_id=i, action=2) for i in range(args.topics)]
        pause, spent = 0.002, 0.0
        for _ in range(args.rounds):
            started = time.perf_counter()
            for publisher, message in zip(publishers, messages):
                publisher.publish(message)
            spent += time.perf_counter() - started
            time.sleep(pause)
        received, take_s = reader.communicate(timeout=reader_s + 10)[0].split()
    finally:
        if reader.poll() is None:
            reader.kill()
        rclpy.shutdown()
    sent = args.rounds * args.topics
    result = {"topics": args.topics, "message": args.message, "bytes": len(serialize_message(messages[0]))
              if args.message == "action" else len(messages[0]), "sent": sent, "received": int(received),
              "us_per_publish": spent / sent * 1e6, "us_per_take": float(take_s) * 1e6}
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['us_per_publish']:.1f} us per publish of {result['bytes']} bytes ({sent} sent to "
              f"{args.topics} topics, {received} received); the reader's CPU {result['us_per_take']:.1f} us a message")


if __name__ == "__main__":
    main()
