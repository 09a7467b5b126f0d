"""Rendering: exact colours on a hand-built 16x16 world, and animations that read back."""

from __future__ import annotations

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np
import pytest

from formic_world import World, WorldConfig
from formic_world.render import (
    AGENT_EMPTY_COLOUR,
    AGENT_LOAD_COLOUR,
    AGENT_OUTLINE_COLOUR,
    CACHE_COLOUR,
    CAPTION_HEIGHT,
    OBSTACLE_COLOUR,
    PHEROMONE_COLOUR,
    QUEUED_OUTLINE_COLOUR,
    RESOURCE_COLOUR,
    _pad_even,
    render_frame,
    render_frames_to_file,
    render_scenario,
    save_png,
)
from formic_world.scenario import AgentStart, ResourceSpec, Scenario

S = 8  # pixels per cell in most tests
CFG = WorldConfig(height=16, width=16, n_agents=4, episode_steps=64)
# Nest caches at rows 7-8, cols 7-8; resource 0 at (1, 1) with its queue running east.
SCENARIO = Scenario(
    CFG,
    seed=0,
    obstacles=((12, 2),),
    resources=(ResourceSpec(1, 1, 1, 0),),
    agents=(
        AgentStart(10, 10, False, -1),  # empty, free
        AgentStart(12, 12, True, -1),  # carrying, free
        AgentStart(7, 6, True, 0),  # carrying, queued at the NW cache (spot 0)
        AgentStart(4, 12, False, -1),
    ),
    wipeout_starts=(),
)


def block(frame: np.ndarray, row: int, col: int, scale: int = S) -> np.ndarray:
    return frame[row * scale:(row + 1) * scale, col * scale:(col + 1) * scale]


def colour(c: np.ndarray) -> np.ndarray:
    return np.rint(c).astype(np.uint8)


@pytest.fixture
def world() -> World:
    w = World(SCENARIO)
    w.pheromone[3, 3] = 0.8
    return w


def test_shape_and_dtype(world):
    frame = render_frame(world, scale=S)
    assert frame.shape == (16 * S, 16 * S, 3) and frame.dtype == np.uint8
    assert render_frame(world).shape == (64, 64, 3)
    assert render_frame(world, scale=1).shape == (16, 16, 3)
    assert render_frame(world, scale=S, caption=True).shape == (16 * S + CAPTION_HEIGHT, 16 * S, 3)


def test_static_cells(world):
    frame = render_frame(world, scale=S)
    assert (block(frame, 12, 2) == colour(OBSTACLE_COLOUR)).all()
    assert (block(frame, 1, 1) == colour(RESOURCE_COLOUR)).all()
    assert (block(frame, 7, 7) == colour(CACHE_COLOUR)).all()
    assert (block(frame, 0, 15) == 255).all()  # free


def test_pheromone_is_green(world):
    frame = render_frame(world, scale=S)
    pixel = block(frame, 3, 3)[S // 2, S // 2]
    assert (pixel == colour(0.2 * 255 + 0.8 * PHEROMONE_COLOUR)).all()  # 80% green over white
    assert pixel[1] > max(pixel[0], pixel[2]) + 50
    assert (block(frame, 3, 4) == 255).all()


def test_queue_cells_are_tinted_and_entries_outlined(world):
    frame = render_frame(world, scale=S)
    inner = block(frame, 1, 4)[S // 2, S // 2].astype(int)  # resource queue spot 2
    assert inner[2] > inner[0] and inner[0] < 255
    entry = block(frame, 1, 2)  # spot 0 is the entry of the empty queue
    assert (entry[0] == colour(RESOURCE_COLOUR)).all() and (entry[:, -1] == colour(RESOURCE_COLOUR)).all()
    assert (entry[S // 2, S // 2] != colour(RESOURCE_COLOUR)).any()


def test_agents_show_load_and_queueing(world):
    frame = render_frame(world, scale=S)
    empty, carrying, queued = block(frame, 10, 10), block(frame, 12, 12), block(frame, 7, 6)
    centre = S // 2
    assert (empty[centre, centre] == colour(AGENT_EMPTY_COLOUR)).all()
    assert (carrying[centre, centre] == colour(AGENT_LOAD_COLOUR)).all()
    assert (empty[0, centre] == colour(AGENT_OUTLINE_COLOUR)).all()
    assert (queued[0, centre] == colour(QUEUED_OUTLINE_COLOUR)).all()
    assert not np.array_equal(empty, carrying)


def test_partial_load_fills_from_the_bottom(world):
    world.step(np.array([0, 0, 0, 0]))  # the queued agent unloads half its unit
    assert world.loads[2] == 0.5
    agent = block(render_frame(world, scale=S), 7, 6)
    centre = S // 2
    assert (agent[centre + 1, centre] == colour(AGENT_LOAD_COLOUR)).all()
    assert (agent[centre - 2, centre] == colour(AGENT_EMPTY_COLOUR)).all()


def test_load_shows_at_the_smallest_scale(world):
    frame = render_frame(world, scale=1)
    assert not np.array_equal(frame[10, 10], frame[12, 12])


def test_save_png_and_render_scenario(world, tmp_path):
    frame = render_frame(world, scale=2)
    save_png(frame, tmp_path / "a.png")
    assert np.array_equal(iio.imread(tmp_path / "a.png"), frame)
    drawn = render_scenario(SCENARIO, tmp_path / "sub" / "s.png", scale=3)
    assert np.array_equal(iio.imread(tmp_path / "sub" / "s.png"), drawn)
    assert np.array_equal(drawn, render_frame(World(SCENARIO), scale=3))


def _episode_frames(count: int) -> list[np.ndarray]:
    world = World(SCENARIO)
    frames = []
    for _ in range(count):
        world.step(np.array([2, 0, 0, 3]))
        frames.append(render_frame(world, scale=3, caption=True))  # the caption's step differs
    return frames


def test_gif_round_trip(tmp_path):
    frames = _episode_frames(6)
    assert render_frames_to_file(iter(frames), tmp_path / "ep.gif", fps=10) == 6
    back = iio.imread(tmp_path / "ep.gif", index=None)
    assert back.shape[:3] == (6,) + frames[0].shape[:2]


def test_mp4_round_trip_pads_odd_sides(tmp_path):
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, size=(39, 45, 3), dtype=np.uint8) for _ in range(7)]
    assert render_frames_to_file(frames, tmp_path / "ep.mp4", fps=20) == 7
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "ep.mp4"))[0] == 7
    padded = _pad_even(frames[0])  # H.264 needs even sides
    assert padded.shape == (40, 46, 3) and np.array_equal(padded[:39, :45], frames[0])
    assert (padded[39] == 255).all() and (padded[:, 45] == 255).all()


def test_bad_animation_requests(tmp_path):
    with pytest.raises(ValueError, match="gif or .mp4"):
        render_frames_to_file([np.zeros((4, 4, 3), np.uint8)], tmp_path / "x.avi")
    with pytest.raises(ValueError, match="no frames"):
        render_frames_to_file([], tmp_path / "x.gif")
    assert not (tmp_path / "x.gif").exists()
