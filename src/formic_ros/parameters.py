"""A node's settings as ROS parameters, so the standard parameter services (``ros2 param list``,
``ros2 param get``, rcl_interfaces ``ListParameters``/``GetParameters``) show how it runs.

The settings stay where they are (dataclasses, JSON specs); a node mirrors them as parameters
once, at start. One rule maps a value to a parameter: booleans, integers, floats and strings as
themselves, None as a parameter that is declared but not set, anything else (tuples, lists,
nested settings) as JSON text. Parameters are read-only unless named writable: a change
mid-run would not be applied, and a read-only parameter says so to whoever tries.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable, Mapping

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

ParameterScalar = bool | int | float | str


def parameter_value(value: object) -> ParameterScalar | None:
    """The value a setting is declared with (see the module's rule)."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if dataclasses.is_dataclass(value):
        value = dataclasses.asdict(value)
    return json.dumps(value, default=str, sort_keys=True)


def settings_of(obj: object, exclude: Iterable[str] = ()) -> dict[str, object]:
    """A dataclass instance's fields by name, less ``exclude``."""
    skip = set(exclude)
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.name not in skip}


def declare_settings(node: Node, settings: Mapping[str, object], writable: Iterable[str] = (),
                     descriptions: Mapping[str, str] | None = None) -> None:
    """Declare each setting as a parameter of ``node``: read-only unless in ``writable``.
    ``descriptions``: a line of help for some of them (shown by ``ros2 param describe``)."""
    writable, descriptions = set(writable), descriptions or {}
    for name, value in settings.items():
        value = parameter_value(value)
        descriptor = ParameterDescriptor(name=name, description=descriptions.get(name, ""),
                                         read_only=name not in writable, dynamic_typing=value is None)
        node.declare_parameter(name, value, descriptor)
