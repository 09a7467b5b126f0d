"""The launch layer, without ROS: ``formic run`` and ``formic train-ros`` start every node as a
child process (launcher, node_process), watch and stop them (processes)."""
