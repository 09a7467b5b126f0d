"""The world process: the world node (the simulation core stepped in lockstep with its agents),
what it publishes, whose actions it takes (ownership), its simulation_interfaces control, robot
steps, training mode, and :func:`formic_ros.world.serve.serve_world`, which puts them together."""
