"""Control the world like any ROS 2 simulator: the standard ``simulation_interfaces`` (release
1.5.1) services and action, in the world's namespace (docs/ros.md, "Control the world").

Play, pause, stop, step N steps (a service, or an action with feedback), reset to a new
episode, list the entities and read their states. The services live on their own node
(``world_control``), spun by a thread of its own, because a step is long (it waits for the
agents, as a free-running step does) and the world's events executor can neither answer a
service later nor spin inside a callback. Every change is carried out by the world's own
thread, between steps, through the same :meth:`WorldNode.step` the episode loop uses; a
service call waits for it. Reads (entities, states) take the world's core lock instead, so
they answer at once, even mid-step.

States: ``formic world`` plays at once and leaves when the episode ends, as it always did;
``--paused`` starts paused at step 0 and stays up (episode after episode, through resets)
until a client sets ``STATE_QUITTING`` or the process is interrupted. Stopped is the episode
reset and paused at step 0. A reset (or a stop) builds the next episode from the world's
``seed`` and ``scenario_file`` parameters exactly as a fresh ``formic world`` would.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import Result, SimulationState, SimulatorFeatures
from simulation_interfaces.srv import (GetEntities, GetEntitiesStates, GetEntityInfo, GetEntityState,
                                       GetSimulationState, GetSimulatorFeatures, ResetSimulation,
                                       SetSimulationState, StepSimulation)

from ..parameters import declare_settings, settings_of
from .entity_reads import EntityReads, result
from .next_episode import NextEpisode

if TYPE_CHECKING:
    from .node import WorldNode

CONTROL_NODE = "world_control"
SERVICES = {  # name in the namespace -> type
    "get_simulator_features": GetSimulatorFeatures,
    "get_simulation_state": GetSimulationState,
    "set_simulation_state": SetSimulationState,
    "step_simulation": StepSimulation,
    "reset_simulation": ResetSimulation,
    "get_entities": GetEntities,
    "get_entities_states": GetEntitiesStates,
    "get_entity_state": GetEntityState,
    "get_entity_info": GetEntityInfo,
}
SIMULATE_STEPS_ACTION = "simulate_steps"
FEATURES = (  # exactly what the services above do
    SimulatorFeatures.ENTITY_TAGS, SimulatorFeatures.ENTITY_BOUNDS_BOX, SimulatorFeatures.ENTITY_CATEGORIES,
    SimulatorFeatures.ENTITY_STATE_GETTING, SimulatorFeatures.ENTITY_INFO_GETTING,
    SimulatorFeatures.SIMULATION_RESET, SimulatorFeatures.SIMULATION_STATE_GETTING,
    SimulatorFeatures.SIMULATION_STATE_SETTING, SimulatorFeatures.SIMULATION_STATE_PAUSE,
    SimulatorFeatures.STEP_SIMULATION_SINGLE, SimulatorFeatures.STEP_SIMULATION_MULTIPLE,
    SimulatorFeatures.STEP_SIMULATION_ACTION,
)
FULL_RESET = ResetSimulation.Request.SCOPE_TIME | ResetSimulation.Request.SCOPE_STATE  # no spawned entities here
STATE_NAMES = {SimulationState.STATE_STOPPED: "stopped", SimulationState.STATE_PLAYING: "playing",
               SimulationState.STATE_PAUSED: "paused", SimulationState.STATE_QUITTING: "quitting"}
# feedback samples the action keeps for a slow client (rclpy's default 10 lost most of a fast
# 20-step goal's feedback on 2 busy cores); a client still drops feedback that trails the result
FEEDBACK_DEPTH = 100
IDLE_WAIT_S = 0.01  # paused: how long the world's thread waits for a command between spins
QUIT_LINGER_S = 0.5  # after STATE_QUITTING, so the answer goes out before the node does


@dataclass
class Command:
    """A change the world's thread carries out between steps; the caller waits for ``done``."""

    name: str
    argument: int = 0
    outcome: Result = field(default_factory=result)
    done: threading.Event = field(default_factory=threading.Event)


class SimulationControl:
    """The simulation_interfaces side of one world node; :meth:`serve` runs the world."""

    def __init__(self, world: WorldNode, executor, scenario_file: str = "", stays: bool = False):
        self.world, self.executor = world, executor
        opts = world.options
        self.config = world.scenario.config
        self.state = SimulationState.STATE_PAUSED if opts.paused else SimulationState.STATE_PLAYING
        self.stays = stays  # after an episode: stay up until told to quit (else leave)
        self.episode_ended = False
        self.summary: dict | None = None  # of the last episode played to its end
        self.commands: queue.Queue[Command] = queue.Queue()
        self.closing = threading.Event()
        declare_settings(world, {f"world.{k}": v for k, v in settings_of(self.config).items()})
        self.next_episode = NextEpisode(world, self.config, world.scenario.seed, scenario_file)

        self.node = Node(CONTROL_NODE, namespace=opts.namespace)
        group = ReentrantCallbackGroup()  # reads answer while a step waits
        handlers = {"get_simulator_features": self._features, "get_simulation_state": self._get_state,
                    "set_simulation_state": self._set_state, "step_simulation": self._step,
                    "reset_simulation": self._reset, **EntityReads(world).handlers()}
        for name, srv_type in SERVICES.items():
            self.node.create_service(srv_type, name, handlers[name], callback_group=group)
        self.action = ActionServer(self.node, SimulateSteps, SIMULATE_STEPS_ACTION, self._simulate_steps,
                                   cancel_callback=lambda _goal: CancelResponse.ACCEPT, callback_group=group,
                                   feedback_pub_qos_profile=QoSProfile(depth=FEEDBACK_DEPTH))
        self.control_executor = MultiThreadedExecutor(num_threads=3, context=self.node.context)
        self.control_executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin_control, name="world_control", daemon=True)
        self.thread.start()

    # ------------------------------------------------------------ the world's thread
    def serve(self, on_summary: Callable[[dict], None] | None = None) -> dict | None:
        """Run the world as the state says until it leaves: after the episode (unless it
        stays) or when told to quit. Returns the last episode's summary."""
        world = self.world
        world.begin_episode(self.executor)
        if self.state != SimulationState.STATE_PLAYING:
            world.pause()
        while self.state != SimulationState.STATE_QUITTING:
            if self.state == SimulationState.STATE_PLAYING and not world.world.done:
                world.step(self.executor)
                self._carry_out()
            else:
                self.executor.spin_once(timeout_sec=0)
                self._carry_out(timeout=IDLE_WAIT_S)
            if world.world.done and not self.episode_ended:
                self.episode_ended = True
                self.summary = world.end_episode(self.executor, last=not self.stays)
                if on_summary is not None:
                    on_summary(self.summary)
                self.state = SimulationState.STATE_PAUSED  # at the episode's end
                if not self.stays:
                    break
        if self.state == SimulationState.STATE_QUITTING:
            until = time.monotonic() + QUIT_LINGER_S
            while time.monotonic() < until:
                self.executor.spin_once(timeout_sec=0.05)
        return self.summary

    def _carry_out(self, timeout: float | None = None) -> None:
        """Carry out the waiting commands (``timeout``: wait this long for one)."""
        while True:
            try:
                command = self.commands.get(timeout=timeout) if timeout else self.commands.get_nowait()
            except queue.Empty:
                return
            timeout = None
            try:
                command.outcome = getattr(self, f"_do_{command.name}")(command.argument)
            except BaseException as exc:  # e.g. nobody joined step 0: the client hears why, the world ends
                command.outcome = result(Result.RESULT_OPERATION_FAILED, f"{type(exc).__name__}: {exc}")
                raise
            finally:
                command.done.set()

    def _do_set_state(self, target: int) -> Result:
        world, current = self.world, self.state
        if target == current:
            return result(SetSimulationState.Response.ALREADY_IN_TARGET_STATE, f"already {STATE_NAMES[target]}")
        if target == SimulationState.STATE_PLAYING:
            if world.world.done:
                return result(SetSimulationState.Response.STATE_TRANSITION_ERROR,
                              f"the episode ended at step {world.world.t}: reset the simulation first")
            world.restart_clock()
        elif target == SimulationState.STATE_PAUSED:
            world.pause()
        elif target == SimulationState.STATE_STOPPED:
            outcome = self._do_reset(FULL_RESET)
            if outcome.result != Result.RESULT_OK:
                return outcome
        elif target == SimulationState.STATE_QUITTING:
            if not self.episode_ended:
                world.abandon_episode()
        else:
            return result(SetSimulationState.Response.INCORRECT_TRANSITION,
                          f"state {target} cannot be set: the world is always loaded")
        self.state = target
        return result()

    def _do_step(self, steps: int) -> Result:
        world = self.world
        if self.state != SimulationState.STATE_PAUSED:  # what StepSimulation and SimulateSteps define
            return result(Result.RESULT_OPERATION_FAILED,
                          f"the simulation is {STATE_NAMES[self.state]}: stepping needs it paused")
        left = self.config.episode_steps - world.world.t
        if steps > left:
            return result(Result.RESULT_OPERATION_FAILED,
                          f"{left} steps left in this episode (at step {world.world.t} of "
                          f"{self.config.episode_steps}): reset the simulation for a new one")
        world.restart_clock()
        for _ in range(steps):
            world.step(self.executor)
        world.pause()
        return result()

    def _do_reset(self, scope: int) -> Result:
        try:
            scenario = self.next_episode.scenario()
        except (OSError, ValueError) as exc:
            return result(Result.RESULT_OPERATION_FAILED, f"cannot build the next episode: {exc}")
        world = self.world
        if not self.episode_ended:
            world.abandon_episode()
        world.load(scenario)
        world.begin_episode(self.executor)
        if self.state != SimulationState.STATE_PLAYING:
            world.pause()
        self.episode_ended = False
        return result()

    # ---------------------------------------------------------- the control thread
    def _spin_control(self) -> None:
        while not self.closing.is_set():
            self.control_executor.spin_once(timeout_sec=0.1)

    def _submit(self, name: str, argument: int = 0) -> Result:
        """Hand a change to the world's thread and wait for it (or for the world to close)."""
        command = Command(name, argument)
        self.commands.put(command)
        while not command.done.wait(0.2):
            if self.closing.is_set():
                return result(Result.RESULT_OPERATION_FAILED, "the world is shutting down")
        return command.outcome

    def _features(self, request: GetSimulatorFeatures.Request,
                  response: GetSimulatorFeatures.Response) -> GetSimulatorFeatures.Response:
        f = self.world.metric_frame
        response.features.features = list(FEATURES)
        response.features.custom_info = (
            f"ForMIC world: entities in frame 'map', x east, y north, {f.cell_size:g} m cells, grid's south-west "
            f"corner at ({f.origin_x:g}, {f.origin_y:g}); one step is {self.world.options.dt:g} s of sim time. "
            "ResetSimulation builds the next episode from the world node's 'seed' and 'scenario_file' parameters.")
        return response

    def _get_state(self, request: GetSimulationState.Request,
                   response: GetSimulationState.Response) -> GetSimulationState.Response:
        response.state.state, response.result = self.state, result()
        return response

    def _set_state(self, request: SetSimulationState.Request,
                   response: SetSimulationState.Response) -> SetSimulationState.Response:
        response.result = self._submit("set_state", request.state.state)
        return response

    def _step(self, request: StepSimulation.Request, response: StepSimulation.Response) -> StepSimulation.Response:
        response.result = self._submit("step", request.steps)
        return response

    def _reset(self, request: ResetSimulation.Request,
               response: ResetSimulation.Response) -> ResetSimulation.Response:
        scope = request.scope
        if scope != ResetSimulation.Request.SCOPE_DEFAULT and scope & FULL_RESET != FULL_RESET:
            response.result = result(Result.RESULT_FEATURE_UNSUPPORTED,
                                     "only full resets (time and state together, or SCOPE_DEFAULT/SCOPE_ALL)")
        else:
            response.result = self._submit("reset", scope)
        return response

    def _simulate_steps(self, goal) -> SimulateSteps.Result:
        """The SimulateSteps action: one step at a time, feedback after each; a cancel or a
        state change stops it between steps."""
        steps, outcome = goal.request.steps, result()
        left = self.config.episode_steps - self.world.world.t
        if self.state != SimulationState.STATE_PAUSED or steps > left:
            outcome = self._submit("step", steps)  # refused, with the step service's reason
        for done in range(steps if outcome.result == Result.RESULT_OK else 0):
            if goal.is_cancel_requested:
                goal.canceled()
                return SimulateSteps.Result(result=result(Result.RESULT_OPERATION_FAILED,
                                                          f"canceled after {done} of {steps} steps"))
            outcome = self._submit("step", 1)
            if outcome.result != Result.RESULT_OK:
                break
            goal.publish_feedback(SimulateSteps.Feedback(completed_steps=done + 1, remaining_steps=steps - done - 1))
        if outcome.result == Result.RESULT_OK:
            goal.succeed()
        else:
            goal.abort()
        return SimulateSteps.Result(result=outcome)

    def close(self) -> None:
        """Stop answering: waiting callers hear that the world is shutting down."""
        self.closing.set()
        self.control_executor.wake()  # out of its spin_once now, not at the timeout
        self.thread.join(timeout=2.0)
        self.control_executor.shutdown(timeout_sec=1.0)  # callbacks under way finish first
        self.action.destroy()
        self.node.destroy_node()
