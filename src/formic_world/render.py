"""Pictures of a world in the style of the paper's Fig. 3, and animations of episodes.

Each cell becomes a ``scale``×``scale`` block: free cells white, pheromone as green over free
cells (more intense, more opaque), obstacles dark grey, resources blue (finite ones fade as
they deplete), the four nest caches brown. Queue cells are lightly tinted with their owner's
colour and each queue's current entry cell is outlined in it (the paper's "square outlined in
the corresponding color"). Agents are discs filled from the bottom in proportion to their load
(an empty agent is a light disc, a full one solid dark blue) with a black outline, or an
orange one while they wait in a queue. Below ``scale`` 3 there is no room for outlines: agents
are then plain blocks coloured by load.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from .geometry import CACHE, FREE, OBSTACLE

if TYPE_CHECKING:
    from .scenario import Scenario
    from .world import World

MAX_FRAME_SIDE = 16384  # pixels: a frame is drawn as H x W x 3 float32 blocks first (3 GiB at this side)
FREE_COLOUR = np.array([255, 255, 255], dtype=np.float32)
OBSTACLE_COLOUR = np.array([64, 64, 64], dtype=np.float32)
RESOURCE_COLOUR = np.array([30, 90, 220], dtype=np.float32)
CACHE_COLOUR = np.array([150, 75, 0], dtype=np.float32)
PHEROMONE_COLOUR = np.array([0, 170, 60], dtype=np.float32)
AGENT_EMPTY_COLOUR = np.array([215, 215, 215], dtype=np.float32)
AGENT_LOAD_COLOUR = np.array([10, 30, 130], dtype=np.float32)
AGENT_OUTLINE_COLOUR = np.array([0, 0, 0], dtype=np.float32)
QUEUED_OUTLINE_COLOUR = np.array([255, 140, 0], dtype=np.float32)
QUEUE_TINT = 0.2  # share of the owner's colour in a queue cell
DEPLETED_RESOURCE_SHADE = 0.35  # a finite resource's colour share when (almost) empty
CAPTION_HEIGHT = 14  # pixels of the optional caption strip


def render_frame(world: "World", scale: int = 4, caption: bool = False) -> np.ndarray:
    """The world as an RGB image, shape (H*scale, W*scale, 3) uint8 (plus a caption strip
    of ``CAPTION_HEIGHT`` rows with the step and score on top when ``caption``)."""
    height, width = world.grid.shape
    if not 1 <= scale <= MAX_FRAME_SIDE // max(height, width):
        raise ValueError(f"a {height}x{width} world at scale {scale} is no frame: the scale goes from 1 to "
                         f"{MAX_FRAME_SIDE // max(height, width)} ({MAX_FRAME_SIDE} pixels a side at most)")
    blocks = np.empty((height, scale, width, scale, 3), dtype=np.float32)
    blocks[:] = cell_colours(world)[:, None, :, None, :]
    if scale >= 3:
        _outline_entries(world, blocks)
    _draw_agents(world, blocks)
    frame = np.rint(blocks).astype(np.uint8).reshape(height * scale, width * scale, 3)
    if caption:
        frame = add_caption(frame, f"t={world.t}  food={world.score:g}")
    return frame


def cell_colours(world: "World") -> np.ndarray:
    """One colour per cell, (H, W, 3) float32 (also the live view's world layer)."""
    grid = world.grid
    colours = np.empty(grid.shape + (3,), dtype=np.float32)
    colours[:] = FREE_COLOUR
    owner = _queue_colours(world)  # (Q, 3)
    cells = world.queue_cells  # (Q, L, 2)
    colours[cells[..., 0], cells[..., 1]] = ((1 - QUEUE_TINT) * FREE_COLOUR + QUEUE_TINT * owner)[:, None, :]
    pheromone = np.clip(world.visible_pheromone(), 0.0, 1.0).astype(np.float32)
    pheromone = np.where(grid == FREE, pheromone, 0.0)[..., None]
    colours = (1 - pheromone) * colours + pheromone * PHEROMONE_COLOUR
    colours[grid == OBSTACLE] = OBSTACLE_COLOUR
    colours[grid == CACHE] = CACHE_COLOUR
    capacity = world.resource_capacity
    fraction = np.where(capacity > 0, world.resource_remaining / np.maximum(capacity, 1), 1.0)
    share = DEPLETED_RESOURCE_SHADE + (1 - DEPLETED_RESOURCE_SHADE) * fraction
    colours[world.resource_pos[:, 0], world.resource_pos[:, 1]] = (
        (1 - share)[:, None] * FREE_COLOUR + share[:, None] * RESOURCE_COLOUR
    )
    return colours


def _queue_colours(world: "World") -> np.ndarray:
    return np.where(world.queue_is_cache[:, None], CACHE_COLOUR, RESOURCE_COLOUR)


def _outline_entries(world: "World", blocks: np.ndarray) -> None:
    """Outline each queue's entry cell (where the next agent would join) in its owner's colour."""
    rows, cols = np.nonzero(world.entry_owner >= 0)
    colours = _queue_colours(world)[world.entry_owner[rows, cols]]
    scale = blocks.shape[1]
    border = np.ones((scale, scale), dtype=bool)
    border[1:-1, 1:-1] = False
    cells = blocks[rows, :, cols, :]  # (k, s, s, 3)
    blocks[rows, :, cols, :] = np.where(border[None, :, :, None], colours[:, None, None, :], cells)


def _agent_masks(scale: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Outline and interior pixel masks of an agent's disc, and each pixel row's height above
    the interior's bottom as a fraction of the interior's height (a row fills when its
    fraction is below the load, so any load shows and a full load fills everything)."""
    centre = np.arange(scale) + 0.5
    dist = np.hypot(centre[:, None] - scale / 2, centre[None, :] - scale / 2)
    disc = dist <= scale / 2
    interior = dist <= scale / 2 - max(1, scale // 8)
    if not interior.any():  # too small for an outline: the whole disc shows the load
        interior = disc
    rows = np.flatnonzero(interior.any(axis=1))
    top, bottom = rows[0], rows[-1]
    level = (bottom - np.arange(scale)) / (bottom - top + 1)
    return disc & ~interior, interior, level


def _draw_agents(world: "World", blocks: np.ndarray) -> None:
    outline, interior, level = _agent_masks(blocks.shape[1])
    rows, cols = world.pos[:, 0], world.pos[:, 1]
    filled = interior[None] & (level[None, :, None] < world.loads[:, None, None])  # (N, s, s)
    edge = np.where(world.queued[:, None], QUEUED_OUTLINE_COLOUR, AGENT_OUTLINE_COLOUR)  # (N, 3)
    cells = blocks[rows, :, cols, :]  # (N, s, s, 3)
    cells = np.where(interior[None, :, :, None], AGENT_EMPTY_COLOUR, cells)
    cells = np.where(filled[..., None], AGENT_LOAD_COLOUR, cells)
    cells = np.where(outline[None, :, :, None], edge[:, None, None, :], cells)
    blocks[rows, :, cols, :] = cells


def add_caption(frame: np.ndarray, text: str) -> np.ndarray:
    """The frame with a white strip of ``CAPTION_HEIGHT`` rows on top holding ``text``."""
    strip = Image.new("RGB", (frame.shape[1], CAPTION_HEIGHT), (255, 255, 255))
    ImageDraw.Draw(strip).text((2, 1), text, fill=(0, 0, 0), font=ImageFont.load_default())
    return np.concatenate([np.asarray(strip), frame], axis=0)


def save_png(frame: np.ndarray, path: str | os.PathLike) -> None:
    """Write one frame as an image (PNG, or whatever format Pillow reads from the suffix)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.asarray(frame, dtype=np.uint8)).save(path)


def render_frames_to_file(frames: Iterable[np.ndarray], path: str | os.PathLike, fps: float = 20) -> int:
    """Write frames (all the same shape) as an animated ``.gif`` or an ``.mp4`` (H.264);
    frames may be a generator. Returns the number of frames written.

    Pillow merges identical consecutive GIF frames into one longer frame; MP4 frames are
    padded with white to even sides, as H.264 requires.
    """
    import imageio.v2 as imageio_v2
    import imageio.v3 as iio

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"animation must be .gif or .mp4, got {path.name!r}")
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    path.parent.mkdir(parents=True, exist_ok=True)
    count = 0
    if suffix == ".gif":
        with iio.imopen(path, "w", plugin="pillow") as file:
            for frame in frames:
                file.write(np.asarray(frame, dtype=np.uint8), is_batch=False, duration=1000 / fps, loop=0)
                count += 1
    else:
        with imageio_v2.get_writer(
            path, format="FFMPEG", mode="I", fps=fps, codec="libx264", pixelformat="yuv420p",
            macro_block_size=2,
        ) as writer:
            for frame in frames:
                writer.append_data(_pad_even(np.asarray(frame, dtype=np.uint8)))
                count += 1
    if count == 0:
        path.unlink(missing_ok=True)
        raise ValueError("no frames to write")
    return count


def _pad_even(frame: np.ndarray) -> np.ndarray:
    return np.pad(frame, ((0, frame.shape[0] % 2), (0, frame.shape[1] % 2), (0, 0)), constant_values=255)


def render_scenario(
    scenario: "Scenario", path: str | os.PathLike, scale: int = 4, caption: bool = False
) -> np.ndarray:
    """Save a picture of a scenario's initial state (before any step); returns the frame."""
    from .world import World

    frame = render_frame(World(scenario), scale=scale, caption=caption)
    save_png(frame, path)
    return frame
