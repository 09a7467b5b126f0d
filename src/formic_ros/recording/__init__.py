"""The recorder process: every topic of a run into a rosbag2 (MCAP) recording, and republishing
one."""
