"""The 8-channel local observation (SPEC §3), built for all agents in one gather.

Channel maps are kept padded by the view radius; out-of-bounds cells read 1 in the blocked
channel and 0 elsewhere. Each step the dynamic channels are redrawn and every agent's window
is cut out with a single fancy-indexing gather.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .geometry import DIRECTION_DELTAS, FREE
from .kernels import queue_entry_spots

if TYPE_CHECKING:
    from .world import World

N_CHANNELS = 8
(
    CH_EMPTY_AGENTS,
    CH_CARRYING_AGENTS,
    CH_BLOCKED,
    CH_RESOURCE_ENTRY,
    CH_CACHE_ENTRY,
    CH_RESOURCE_QUEUED,
    CH_CACHE_QUEUED,
    CH_PHEROMONE,
) = range(N_CHANNELS)
CHANNEL_NAMES = (
    "empty agents",
    "carrying agents",
    "blocked",
    "resource queue entries",
    "cache queue entries",
    "agents in resource queues",
    "agents in cache queues",
    "pheromone",
)


class ObservationBuilder:
    def __init__(self, world: "World"):
        self.world = world
        self.radius = world.config.view_size // 2
        height, width = world.grid.shape
        r = self.radius
        self.maps = np.zeros((N_CHANNELS, height + 2 * r, width + 2 * r), dtype=np.float32)
        self.interior = (slice(r, r + height), slice(r, r + width))
        self.windows = sliding_window_view(self.maps, (2 * r + 1, 2 * r + 1), axis=(1, 2))
        self.grid_changed()

    def grid_changed(self) -> None:
        """Redraw the static blocked channel (after reset or a resource respawn)."""
        blocked = self.maps[CH_BLOCKED]
        blocked[:] = 1.0
        blocked[self.interior] = self.world.grid != FREE

    def observe(self) -> np.ndarray:
        """Observations of every agent, shape (N, 8, V, V) float32."""
        w = self.world
        r = self.radius
        rows, cols = w.pos[:, 0] + r, w.pos[:, 1] + r
        maps = self.maps
        for ch in (CH_EMPTY_AGENTS, CH_CARRYING_AGENTS, CH_RESOURCE_ENTRY, CH_CACHE_ENTRY,
                   CH_RESOURCE_QUEUED, CH_CACHE_QUEUED):
            maps[ch][self.interior] = 0.0
        carrying = w.carrying
        maps[CH_CARRYING_AGENTS, rows[carrying], cols[carrying]] = 1.0
        maps[CH_EMPTY_AGENTS, rows[~carrying], cols[~carrying]] = 1.0
        queued = w.queue_of >= 0
        in_cache = queued & w.queue_is_cache[np.maximum(w.queue_of, 0)]
        in_resource = queued & ~in_cache
        maps[CH_CACHE_QUEUED, rows[in_cache], cols[in_cache]] = 1.0
        maps[CH_RESOURCE_QUEUED, rows[in_resource], cols[in_resource]] = 1.0
        self._draw_entries()
        maps[CH_PHEROMONE][self.interior] = w.visible_pheromone()
        return np.ascontiguousarray(self.windows[:, w.pos[:, 0], w.pos[:, 1]].transpose(1, 0, 2, 3))

    def _draw_entries(self) -> None:
        """Joinable queues: the entry cell holds the resource's remaining fraction (1 for
        infinite resources and caches); each free in-bounds neighbour of the entry holds 1."""
        w = self.world
        qlen = w.config.queue_len
        count, head = w.queue_count, w.queue_head
        spot = queue_entry_spots(count, head, qlen)
        # Queues 0-3 (the caches) read -1, infinite; queue 4+i reads resource i (there may be none).
        remaining = np.concatenate([[-1] * 4, w.resource_remaining])
        capacity = np.concatenate([[-1] * 4, w.resource_capacity])
        accepts = (spot >= 0) & ((remaining < 0) | (remaining > count * w.load_full))
        q = np.flatnonzero(accepts)
        entry = w.queue_cells[q, spot[q]]
        value = np.where(remaining[q] < 0, 1.0, remaining[q] / np.maximum(capacity[q], 1)).astype(np.float32)
        channel = np.where(w.queue_is_cache[q], CH_CACHE_ENTRY, CH_RESOURCE_ENTRY)
        r = self.radius
        # Neighbours in padded coordinates (the padding is at least 1 wide): the blocked
        # channel reads 0 exactly on free in-bounds cells.
        neighbours = entry[:, None, :] + DIRECTION_DELTAS[None, :, :] + r  # (k, 4, 2)
        nr, nc = neighbours[..., 0], neighbours[..., 1]
        free = self.maps[CH_BLOCKED, nr, nc] == 0
        k_idx, _ = np.nonzero(free)
        # Where cells coincide the larger value wins: entry cells are distinct within a channel
        # (queue strips never overlap), and the neighbours' 1.0, drawn last, is the maximum.
        self.maps[channel, entry[:, 0] + r, entry[:, 1] + r] = value
        self.maps[channel[k_idx], nr[free], nc[free]] = 1.0
