"""Grid geometry shared by every rule: directions, cell kinds, the nest and its pinwheel queues."""

from __future__ import annotations

import numpy as np

# Actions 0-3 are moves in these directions; 4 is JOIN (SPEC §4). Row index grows southwards.
NORTH, EAST, SOUTH, WEST, JOIN = 0, 1, 2, 3, 4
N_ACTIONS = 5
NO_ACTION = -1  # an agent whose action is missing (a late or dead agent node) does nothing
DIRECTION_DELTAS = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]], dtype=np.int64)

# Cell kinds of the static grid. Resource and cache cells are impassable.
FREE, OBSTACLE, RESOURCE, CACHE = 0, 1, 2, 3


def nest_cache_cells(height: int, width: int) -> list[tuple[int, int]]:
    """The 2x2 nest: NW, NE, SW, SE caches (rows h-1,h and cols w-1,w)."""
    h, w = height // 2, width // 2
    return [(h - 1, w - 1), (h - 1, w), (h, w - 1), (h, w)]


# Pinwheel: NW's queue runs west, NE's north, SW's south, SE's east.
NEST_QUEUE_DIRECTIONS = (WEST, NORTH, SOUTH, EAST)


def nest_centre(height: int, width: int) -> tuple[float, float]:
    """The point between the four caches, in (row, col) cell coordinates."""
    return height // 2 - 0.5, width // 2 - 0.5


def queue_cells(anchor: tuple[int, int], direction: int, length: int) -> np.ndarray:
    """Cells of a straight queue: spot 0 touches ``anchor`` and spots run in ``direction``."""
    return strip_cells(anchor, direction, length)[1:-1]


def strip_cells(anchor: tuple[int, int], direction: int, length: int) -> np.ndarray:
    """Anchor, its queue and one more cell past the queue end: the reserved strip (SPEC §1)."""
    dr, dc = DIRECTION_DELTAS[direction]
    k = np.arange(0, length + 2)
    return np.stack([anchor[0] + dr * k, anchor[1] + dc * k], axis=1).astype(np.int64)
