"""formic_agent."""
