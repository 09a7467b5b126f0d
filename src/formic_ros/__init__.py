"""ForMIC as a distributed ROS 2 system, one subpackage per process: ``world``, ``drivers``
(agent host, planner, learning host, trainer), ``robots``, ``recording`` and the ROS-free
``launch`` layer that starts them; what they share lies at the top (docs/layout.md).

Everything that imports rclpy lives here, so the core, the policies and the trainer stay
importable without ROS. Topic names and message types are in :mod:`formic_topics` (no ROS),
their QoS in :mod:`formic_ros.qos`; message conversion in :mod:`formic_ros.convert`.
"""
