"""Recordings without ROS: rosbag2 (MCAP) writing, reading and repair (:mod:`.bag`), and the
replay reader that re-simulates a recording to verify, render or view it (:mod:`.replay`).
Nothing here imports rclpy; publishing a recording again is :mod:`formic_ros.recording.recorder`'s.
"""
