"""formic_cli."""
