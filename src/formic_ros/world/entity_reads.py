"""The entity services of simulation_interfaces (get_entities, get_entities_states,
get_entity_state, get_entity_info): reads of one consistent world state, taken under the world's
core lock, so they answer at once, even mid-step. Served on the control node
(:mod:`formic_ros.world.control`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from simulation_interfaces.msg import Result
from simulation_interfaces.srv import GetEntities, GetEntitiesStates, GetEntityInfo, GetEntityState

from . import viewer_msgs
from .entities import Entity, FilterError, entity_info, entity_state, select, world_entities

if TYPE_CHECKING:
    from .node import WorldNode


def result(code: int = Result.RESULT_OK, message: str = "") -> Result:
    return Result(result=code, error_message=message)


class EntityReads:
    """The entity services' handlers over one world node."""

    def __init__(self, node: WorldNode):
        self.node = node

    def handlers(self) -> dict:
        """Service name in the namespace -> handler."""
        return {"get_entities": self._entities, "get_entities_states": self._entities_states,
                "get_entity_state": self._entity_state, "get_entity_info": self._entity_info}

    def _snapshot(self) -> tuple[list[Entity], object]:
        """The entities and the sim time of one consistent world state."""
        with self.node.core_lock:
            world = self.node.world
            return world_entities(world, self.node.metric_frame), viewer_msgs.sim_time(world.t, self.node.options.dt)

    def _entities(self, request: GetEntities.Request, response: GetEntities.Response) -> GetEntities.Response:
        entities, _ = self._snapshot()
        try:
            response.entities = [e.name for e in select(entities, request.filters, self.node.metric_frame.cell_size)]
            response.result = result()
        except FilterError as exc:
            response.result = result(exc.code, str(exc))
        return response

    def _entities_states(self, request: GetEntitiesStates.Request,
                         response: GetEntitiesStates.Response) -> GetEntitiesStates.Response:
        entities, stamp = self._snapshot()
        try:
            chosen = select(entities, request.filters, self.node.metric_frame.cell_size)
        except FilterError as exc:
            response.result = result(exc.code, str(exc))
            return response
        response.entities = [e.name for e in chosen]
        response.states = [entity_state(e, stamp) for e in chosen]
        response.result = result()
        return response

    def _named(self, name: str) -> tuple[Entity | None, object]:
        entities, stamp = self._snapshot()
        return next((e for e in entities if e.name == name), None), stamp

    def _entity_state(self, request: GetEntityState.Request,
                      response: GetEntityState.Response) -> GetEntityState.Response:
        entity, stamp = self._named(request.entity)
        if entity is None:
            response.result = result(Result.RESULT_NOT_FOUND, f"no entity {request.entity!r}")
        else:
            response.state, response.result = entity_state(entity, stamp), result()
        return response

    def _entity_info(self, request: GetEntityInfo.Request, response: GetEntityInfo.Response) -> GetEntityInfo.Response:
        entity, _ = self._named(request.entity)
        if entity is None:
            response.result = result(Result.RESULT_NOT_FOUND, f"no entity {request.entity!r}")
        else:
            response.info, response.result = entity_info(entity), result()
        return response
