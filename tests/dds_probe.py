"""A tiny rclpy talker or listener for the DDS environment tests (run as a script, with the
environment already prepared by the test): ``talk`` publishes for ``seconds``; ``listen``
prints ``received N`` once a message arrives or ``received 0`` after ``seconds``."""

import sys
import time

from formic_ros.env import configure_this_process

configure_this_process()
import rclpy  # noqa: E402
from std_msgs.msg import String  # noqa: E402

role, seconds = sys.argv[1], float(sys.argv[2])
rclpy.init()
node = rclpy.create_node(f"dds_probe_{role}")
end = time.monotonic() + seconds
if role == "talk":
    pub = node.create_publisher(String, "dds_probe", 10)
    while time.monotonic() < end:
        pub.publish(String(data="hello"))
        rclpy.spin_once(node, timeout_sec=0.1)
    print("talked", flush=True)
else:
    got = []
    node.create_subscription(String, "dds_probe", got.append, 10)
    while time.monotonic() < end and not got:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(f"received {len(got)}", flush=True)
node.destroy_node()
rclpy.try_shutdown()
