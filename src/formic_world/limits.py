"""Upper limits on what a user's input may ask for, checked before anything is allocated.

Why: memory. A world holds several arrays of its area per step (grid, pheromones, occupancy),
the team arrays grow with the agent count, an observation with the square of the view, and a
recording with the episode's length: a scenario file asking for a 1,000,000-cell side would
otherwise be accepted and grind for minutes at gigabytes before failing. The limits sit far
above every experiment (sides 20-128, teams up to 1024, views 5-21, episodes of 1024 steps),
and an error names the field, the value and the limit. File sizes are checked before a file is
read: JSON and torch both hold a whole file (and more) in memory while parsing it.
"""

from __future__ import annotations

MAX_SIDE = 2048  # cells, a world's height and width
MAX_AGENTS = 65_536
MAX_VIEW_SIZE = 63  # cells, odd: an observation is 8 x V x V floats per agent
MAX_EPISODE_STEPS = 1_000_000
MAX_QUEUE_LEN = 64  # cells of one queue (every cache and resource owns one)

MAX_SCENARIO_BYTES = 64 * 1024**2  # a scenario file (a 2048x2048 layout stays far below)
MAX_CHECKPOINT_BYTES = 512 * 1024**2  # a model file (the paper's network is ~20 MB)
MAX_NETWORK_WIDTH = 4096  # channels or units of any layer in a checkpoint's network configuration


def check_at_most(name: str, value: int, limit: int) -> None:
    """Refuse ``value`` above ``limit`` with a message naming the field, the value and the limit."""
    if value > limit:
        raise ValueError(f"{name} {value} is over the limit of {limit}")
