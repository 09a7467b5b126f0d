"""The robot processes: the bridge from grid goals to velocity commands, the simulated robots,
and the launch specs for both."""
