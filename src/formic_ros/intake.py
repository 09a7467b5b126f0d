"""Per-agent readers that a process's own loop takes from, in agent order, instead of its
executor dispatching each message.

On the per-agent transport a step is a burst of one message per agent, published in agent order.
Dispatched by the executor, every message wakes the reading thread, which then runs beside the
writer and both processes' DDS receive threads, and each wake-up costs 50-70 µs on our VMs. With
an :class:`Intake` the process's loop sleeps until a chunk of the messages it expects is there
(the reader some agents ahead has one), takes everything waiting in one loop, and so wakes a few
times a step, its takes overlapping the writer's publishes (docs/ros.md, "Speed"). Its readers
belong to nodes that no executor holds (:func:`lean_node`), so nothing else takes their
messages; the loop runs its executor between waits for everything else.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.subscription import Subscription
from rclpy.type_description_service import START_TYPE_DESCRIPTION_SERVICE_PARAM

WRITERS_REFRESH_S = 0.25  # how often the readers' matched publishers are counted afresh


def lean_node(name: str, namespace: str) -> Node:
    """A node without parameter, type-description or rosout endpoints: with a hundred agents per
    process those would be most of the DDS endpoints to discover, and such nodes neither take
    parameters nor log (their process's main node does)."""
    return Node(
        name, namespace=namespace, enable_rosout=False, start_parameter_services=False,
        parameter_overrides=[Parameter(START_TYPE_DESCRIPTION_SERVICE_PARAM, value=False)],
    )


def not_dispatched(_message) -> None:
    """The callback of an intake's reader: never called, as no executor holds its node."""


class Intake:
    """Readers of serialized messages (created with ``raw=True`` on nodes no executor holds),
    one per agent, taken by :meth:`sweep` and waited on by :meth:`wait`."""

    def __init__(self, readers: Sequence[Subscription], context):
        self.readers = list(readers)
        self.handles = [reader.handle for reader in self.readers]
        self.msg_type = self.readers[0].msg_type if self.readers else None
        self.wait_set = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, context.handle)
        self.writers = np.zeros(len(self.readers), dtype=bool)  # which readers have a matched publisher
        self.writers_at = -np.inf

    def count_writers(self, now: float, fresh: bool = False) -> np.ndarray:
        """Which readers have a publisher (re-read every ``WRITERS_REFRESH_S``, or now)."""
        if fresh or now - self.writers_at > WRITERS_REFRESH_S:
            self.writers = np.array([reader.get_publisher_count() > 0 for reader in self.readers], dtype=bool)
            self.writers_at = now
        return self.writers

    def sweep(self, indices: list[int]) -> list[tuple[int, bytes]]:
        """Every waiting message of the readers ``indices``, in that order: (index, serialized)."""
        taken = []
        handles, msg_type = self.handles, self.msg_type
        for index in indices:
            while (got := handles[index].take_message(msg_type, True)) is not None:
                taken.append((index, got[0]))
        return taken

    def wait(self, index: int, timeout_s: float) -> None:
        """Sleep until reader ``index`` has a message, or ``timeout_s``."""
        self.wait_set.clear_entities()
        self.wait_set.add_subscription(self.handles[index])
        self.wait_set.wait(max(0, int(timeout_s * 1e9)))
