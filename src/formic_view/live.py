"""A live view of a run: a Foxglove WebSocket server fed by the :class:`formic_world.World`.

Foxglove or Lichtblick connect to it directly (``Open connection -> Foxglove WebSocket``), so
watching needs neither ROS nor a bridge. One :class:`LiveView` owns the server and four
channels, named like the recorded topics where the same panel can show both (the JSON ones
share the recorded fields ``/formic/score.data``, ``/formic/state.step`` and ``.score``):

==========================  ==========================  =====================================
live channel                schema                      recorded counterpart
==========================  ==========================  =====================================
``/formic/world``           ``foxglove.Grid``           ``/formic/map`` (``nav_msgs/OccupancyGrid``)
``/formic/agent_markers``   ``foxglove.SceneUpdate``    ``/formic/agent_markers`` (``MarkerArray``)
``/formic/score``           JSON ``formic.Score``       ``/formic/score`` (``std_msgs/Float64``)
``/formic/state``           JSON ``formic.State``       ``/formic/state`` (``WorldState``)
==========================  ==========================  =====================================

Frames: ``map``, one unit a cell, x east along the columns, y north (row 0 of the world is the
top): the recorded map and markers' layout, which are in metres (the world's ``--cell-size``).
Message times are sim time (step x ``dt``), so the timeline and plots read the same as a
recording's ``/clock``.

The run must not wait for the viewer: :meth:`LiveView.publish` returns at once unless the
last publication is ``1 / max_hz`` seconds old (wall clock), and builds nothing for channels
nobody subscribes to. The final step is always published, and a new subscriber gets the next
step at once.
"""

from __future__ import annotations

import json
import math
import threading
import time
from typing import TYPE_CHECKING

import foxglove
import numpy as np
from foxglove.channels import GridChannel, SceneUpdateChannel
from foxglove.messages import (Color, CubePrimitive, Grid, KeyValuePair, PackedElementField,
                                PackedElementFieldNumericType, Pose, Quaternion, SceneEntity, SceneUpdate,
                                SpherePrimitive, Timestamp, Vector2, Vector3)

from . import DEFAULT_HOST, DEFAULT_MAX_HZ, DEFAULT_PORT, address

if TYPE_CHECKING:
    from formic_world import World

FRAME = "map"
WORLD_TOPIC = "/formic/world"
AGENTS_TOPIC = "/formic/agent_markers"
SCORE_TOPIC = "/formic/score"
STATE_TOPIC = "/formic/state"
CLOSE_FLUSH_S = 0.5  # how long close() lets the last messages reach connected viewers

# One grid cell: the rendered colour (as `formic render` draws it), then the raw layers.
CELL = np.dtype([("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1"),
                 ("pheromone", "<f4"), ("cell", "u1")])  # cell: 0 free, 1 obstacle, 2 resource, 3 nest cache
GRID_FIELDS = [PackedElementField(name=name, offset=CELL.fields[name][1],
                                  type=PackedElementFieldNumericType.Float32 if name == "pheromone"
                                  else PackedElementFieldNumericType.Uint8) for name in CELL.names]

EMPTY = (0.2, 0.4, 1.0)  # the recorded markers' colours: blue empty, orange full
LOADED = (1.0, 0.55, 0.0)
AGENT_SIZE = 0.8


def _json_schema(name: str, **properties: tuple[str | list[str], str]) -> foxglove.Schema:
    """The JSON schema of an object with these properties: (type, description) each."""
    fields = {key: {"type": kind, "description": text} for key, (kind, text) in properties.items()}
    return foxglove.Schema(name=name, encoding="jsonschema",
                           data=json.dumps({"type": "object", "properties": fields}).encode())


SCORE_SCHEMA = _json_schema("formic.Score",
                            data=("number", "food delivered to the nest, as std_msgs/Float64"))
STATE_SCHEMA = _json_schema(
    "formic.State",
    step=("integer", "world step, as WorldState.step"),
    score=("number", "food delivered to the nest, as WorldState.score"),
    sim_time=("number", "simulated seconds (step x dt)"),
    food_carried=("number", "food the agents carry"),
    food_left=(["number", "null"], "food left in finite resources (null: infinite)"),
    carrying=("integer", "agents carrying food"),
    queued=("integer", "agents waiting in a queue"),
    agents=("integer", "team size"),
)


class _Listener(foxglove.websocket.ServerListener):
    def __init__(self, view: LiveView):
        self.view = view

    def on_subscribe(self, client, channel) -> None:  # server thread: only flags
        self.view._fresh_subscriber = True
        self.view.subscribed.set()


class LiveView:
    """The server and its channels; call :meth:`publish` after every step of a world."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST, max_hz: float = DEFAULT_MAX_HZ,
                 dt: float = 0.1, name: str = "formic"):
        if max_hz <= 0:
            raise ValueError(f"max_hz must be positive, got {max_hz}")
        self.min_interval = 1.0 / max_hz
        self.dt = dt
        self.host = host
        self.subscribed = threading.Event()  # some client subscribed to some channel (ever)
        self._fresh_subscriber = False
        self._last = -math.inf
        self.published = 0  # steps published
        # Its own context, so several views (tests) in one process do not mix; kept, as
        # channels and server stop meeting once the context is collected.
        self._context = context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=context,
                                                server_listener=_Listener(self))
        except RuntimeError as exc:
            raise OSError(f"live view: cannot serve on {address(host, port)}: {exc}") from exc
        self.world_channel = GridChannel(WORLD_TOPIC, context=context)
        self.agents_channel = SceneUpdateChannel(AGENTS_TOPIC, context=context)
        self.score_channel = foxglove.Channel(SCORE_TOPIC, schema=SCORE_SCHEMA, message_encoding="json",
                                              context=context)
        self.state_channel = foxglove.Channel(STATE_TOPIC, schema=STATE_SCHEMA, message_encoding="json",
                                              context=context)

    @property
    def context(self) -> foxglove.Context:
        """The server's context, for channels of other layers (:mod:`formic_view.robots`)."""
        return self._context

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        return address(self.host, self.port)

    def wait_for_viewer(self, timeout_s: float | None = None) -> bool:
        """Block until a client subscribes to a channel (or ``timeout_s``); True if one did."""
        return self.subscribed.wait(timeout_s)

    def publish(self, world: World, final: bool = False) -> bool:
        """Send ``world`` as it is now, unless the last send is under ``1 / max_hz`` s old
        (``final`` and a new subscriber always go out). Returns whether anything was sent."""
        now = time.monotonic()
        if not (final or self._fresh_subscriber or now - self._last >= self.min_interval):
            return False
        self._fresh_subscriber = False
        self._last = now
        nanos = int(round(world.t * self.dt * 1e9))
        stamp = Timestamp(nanos // 1_000_000_000, nanos % 1_000_000_000)
        sent = False
        for channel, build in ((self.world_channel, lambda: world_grid(world, stamp)),
                               (self.agents_channel, lambda: agent_scene(world, stamp)),
                               (self.score_channel, lambda: {"data": world.score}),
                               (self.state_channel, lambda: state_message(world, self.dt))):
            if channel.has_sinks():  # nothing is built for a channel nobody subscribes to
                channel.log(build(), log_time=nanos)
                sent = True
        self.published += sent
        return sent

    def close(self) -> None:
        """Stop serving, after a moment for the last (final) messages to reach connected
        viewers: the server sends from its own thread, and stopping at once can drop them."""
        if self.published:
            time.sleep(CLOSE_FLUSH_S)
        self.server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_IDENTITY = Quaternion(w=1.0)


def _pose(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=_IDENTITY)


def world_grid(world: World, stamp: Timestamp) -> Grid:
    """Every cell: its colour in the project's pictures (pheromone green, resources blue, nest
    brown, obstacles grey, queues tinted), its pheromone as agents see it, and its kind."""
    from formic_world.render import cell_colours

    height, width = world.grid.shape
    cells = np.empty((height, width), dtype=CELL)
    north_up = slice(None, None, -1)  # grid rows go north: the world's last row first
    colours = cell_colours(world)[north_up]
    for channel, name in enumerate(("red", "green", "blue")):
        cells[name] = np.rint(colours[..., channel])
    cells["alpha"] = 255
    cells["pheromone"] = world.visible_pheromone()[north_up]
    cells["cell"] = world.grid[north_up]
    return Grid(timestamp=stamp, frame_id=FRAME, pose=_pose(), column_count=width,
                cell_size=Vector2(x=1.0, y=1.0), row_stride=width * CELL.itemsize, cell_stride=CELL.itemsize,
                fields=GRID_FIELDS, data=cells.tobytes())


def _colour(load: float) -> Color:
    r, g, b = (empty + (loaded - empty) * load for empty, loaded in zip(EMPTY, LOADED))
    return Color(r=r, g=g, b=b, a=1.0)


_SIZE = Vector3(x=AGENT_SIZE, y=AGENT_SIZE, z=AGENT_SIZE)


def agent_scene(world: World, stamp: Timestamp) -> SceneUpdate:
    """One entity per agent (id ``agent_K``): a sphere while free, a cube while queued,
    coloured from blue (empty) to orange (full), with its load and queue as metadata."""
    height = world.grid.shape[0]
    colours: dict[float, Color] = {}  # loads take a few values (tenths): one colour object each
    entities = []
    for a, ((row, col), load, queue) in enumerate(zip(world.pos.tolist(), world.loads.tolist(),
                                                      world.queue_of.tolist())):
        colour = colours.get(load) or colours.setdefault(load, _colour(load))
        pose = _pose(col + 0.5, height - 1 - row + 0.5, AGENT_SIZE / 2)
        shape = ({"cubes": [CubePrimitive(pose=pose, size=_SIZE, color=colour)]} if queue >= 0 else
                 {"spheres": [SpherePrimitive(pose=pose, size=_SIZE, color=colour)]})
        entities.append(SceneEntity(
            timestamp=stamp, frame_id=FRAME, id=f"agent_{a}", frame_locked=True,
            metadata=[KeyValuePair(key="load", value=f"{load:g}"), KeyValuePair(key="queue", value=str(queue))],
            **shape))
    return SceneUpdate(entities=entities)


def state_message(world: World, dt: float) -> dict:
    finite = world.resource_capacity >= 0
    left = float(world.resource_remaining[finite].sum() / world.load_full) if finite.any() else None
    return {"step": int(world.t), "score": world.score, "sim_time": world.t * dt,
            "food_carried": float(world.loads.sum()), "food_left": left,
            "carrying": int(world.carrying.sum()), "queued": int(world.queued.sum()),
            "agents": int(world.config.n_agents)}
