"""The runtime layer above the policies (formic_agent, formic_baselines): the policy registry,
teams, the episode loop and its statistics, and the process's thread settings. ``formic sim``,
the evaluation harness and the ROS nodes all run policies through it."""
