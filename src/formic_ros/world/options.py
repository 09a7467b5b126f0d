"""The world node's settings (:class:`WorldNodeOptions`), in a module of their own: the
launcher builds them for a child process and must not import rclpy, numba and the core on the
way (about 0.25 s before the first child could start)."""

from __future__ import annotations

from dataclasses import dataclass

import formic_topics as topics


@dataclass(frozen=True)
class WorldNodeOptions:
    namespace: str = topics.DEFAULT_NAMESPACE
    deadline_s: float = 1.0  # lockstep: how long a step waits for the last action
    startup_timeout_s: float = 60.0  # how long step 0 waits for every agent
    rate_hz: float | None = None  # free-running: steps per second (no waiting for agents)
    viewer_every: int = 10  # map, markers and score every k steps (0: never)
    dt: float = 0.1  # simulated seconds per step (/clock)
    policy_label: str = ""  # which policies drive the team, for the scenario message and summary
    training_masks: bool = False  # fill ObservationBatch.train_masks (SPEC 4 filter)
    observation_encoding: str = "compact"  # ObservationBatch: "compact" (lossless, ~10x smaller) or "float32"
    require_subscribers: tuple[str, ...] = ()  # topics (e.g. "applied_actions") needing a subscriber before step 0
    recorders: int = 0  # recorders that must match every topic before step 0 (more if present at start)
    progress: bool = False
    allow_empty: bool = False  # step on when agents did not answer step 0 (else NobodyJoined, naming them)
    view_port: int | None = None  # live view (formic_view, Foxglove WebSocket) on this port; None: none
    view_wait: bool = False  # with view_port: step 0 waits for a viewer to subscribe
    external: tuple[int, ...] | None = None  # agents other nodes may drive (None: any; formic_ros.world.ownership)
    drivers: tuple[str, ...] | None = None  # the run's own driver nodes, the only claimants of the rest (None: anyone)
    paused: bool = False  # start paused at step 0 and stay up for simulation_interfaces clients (sim_control)
    cell_size: float = 1.0  # metres per cell in the map frame (formic_world.metric_frame): entity poses
    origin_x: float = 0.0  # map coordinates of the grid's south-west corner
    origin_y: float = 0.0
    robots: tuple[int, ...] = ()  # robot agents: each step waits for them to reach their cells (world/robot_steps.py)
    robot_tolerance: float = 0.1  # metres from its cell's centre that count as a robot being in the cell
    robot_cell_s: float = 10.0  # seconds a robot gets per cell of a move before the move counts as failed
