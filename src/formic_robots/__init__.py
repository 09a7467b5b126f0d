"""Robots in the team, without ROS: the go-to-cell controller a robot bridge drives with
(:mod:`.controller`), the unicycle model the robot simulator integrates (:mod:`.unicycle`), and
the robot-paced step that commits a world step only once the robots have reached their cells
(:mod:`.steps`). The ROS nodes around them are in :mod:`formic_ros` (docs/robots.md)."""
