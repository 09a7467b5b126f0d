"""formic_trainer."""
