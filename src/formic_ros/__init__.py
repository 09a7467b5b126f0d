"""ForMIC as a distributed ROS 2 system: world node, agent hosts, planner, launcher.

Everything that imports rclpy lives here, so the core, the policies and the trainer stay
importable without ROS. Topic names and message types are in :mod:`formic_topics` (no ROS),
their QoS in :mod:`formic_ros.qos`; message conversion in :mod:`formic_ros.convert`; the
environment child processes need in :mod:`formic_ros.env`.
"""
