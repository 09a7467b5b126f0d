"""formic_baselines."""
