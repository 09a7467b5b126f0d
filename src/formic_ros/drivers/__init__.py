"""The driver processes, which answer the world's observations with actions: agent host,
planner, learning host, and the trainer node the learning hosts learn from; what they share is
the claim on their agents and the world watch."""
