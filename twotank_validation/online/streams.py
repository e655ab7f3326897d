"""The two-tank rig's interface: its topics, message types and units, as a preset map.

The rig publishes valve commands (``flow_cmd``, a FlowCommand with ``hot`` and ``cold``),
the level as a gauge pressure (``height``, sensor_msgs/FluidPressure) and the temperature in
°C (``temperature``, sensor_msgs/Temperature). :func:`two_tank_map` is that interface as an
:class:`~twotank_validation.online.interface.InterfaceMap` (the default of every command and
node): inputs ``hot``, ``cold``; outputs ``height``, ``temperature``, converted to model units
by :class:`RigUnits`. There is no other stream path: the validator reads the rig through this
map as it reads any other rig through its own. Nothing here imports a ROS message package.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from twotank_validation.defaults import NS_PER_S
from twotank_validation.online.aligner import COMMAND
from twotank_validation.online.extraction import stamp_ns
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.online.sources import InterfaceMapError, Source

_V = TypeVar("_V", float, np.ndarray)  # one value, or many at once (same float operations)

FLOW_CMD_TYPE = "twotank_validation_msgs/msg/FlowCommand"
HEIGHT_TYPE = "sensor_msgs/msg/FluidPressure"
TEMPERATURE_TYPE = "sensor_msgs/msg/Temperature"

FLOW_CMD = "flow_cmd"
"""The rig's topic of valve commands ``(hot, cold)`` (model units)."""
HEIGHT = "height"
"""The rig's topic of level measurements; also the output's name."""
TEMPERATURE = "temperature"
"""The rig's topic of temperature measurements; also the output's name."""
STREAMS = (FLOW_CMD, HEIGHT, TEMPERATURE)
"""The rig's topics (names as :func:`two_tank_map` gives them before any remapping)."""
INPUTS = ("hot", "cold")
"""The rig's input channels, in the order of the map."""
MEASUREMENTS = (HEIGHT, TEMPERATURE)
"""The rig's output channels, in the order of the map."""
STREAM_KINDS = {FLOW_CMD: COMMAND, **{s: channel for channel, s in enumerate(MEASUREMENTS)}}
"""Event kind of each of the rig's topics under :func:`two_tank_map`
(:data:`~twotank_validation.online.aligner.COMMAND` or the output channel), as
``OnlineValidator.feed_many`` takes it."""
STREAM_TYPES = {FLOW_CMD: FLOW_CMD_TYPE, HEIGHT: HEIGHT_TYPE, TEMPERATURE: TEMPERATURE_TYPE}
"""Message type of each of the rig's topics."""


@dataclass(frozen=True)
class RigUnits:
    """Per-rig conversion of the measurement messages to model units.

    Attributes:
        pascal_per_unit: gauge pressure at the tank base per model unit of level
            (9806.65 Pa: 1 model unit = 1 m of water).
        temperature_offset_c: temperature (°C) of model unit 0 (the cold supply, 15 °C).
        temperature_span_c: °C per model unit (hot supply 65 °C = 1).
    """

    pascal_per_unit: float = 9806.65
    temperature_offset_c: float = 15.0
    temperature_span_c: float = 50.0

    def __post_init__(self) -> None:
        for name in ("pascal_per_unit", "temperature_offset_c", "temperature_span_c"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, found {getattr(self, name)}")
        if self.pascal_per_unit <= 0 or self.temperature_span_c <= 0:
            raise ValueError("pascal_per_unit and temperature_span_c must be positive")

    def level_from_pressure(self, pressure_pa: _V) -> _V:
        """Model-unit level from gauge pressure (Pa)."""
        return pressure_pa / self.pascal_per_unit

    def pressure_from_level(self, level: _V) -> _V:
        """Gauge pressure (Pa) from model-unit level."""
        return level * self.pascal_per_unit

    def temperature_from_celsius(self, celsius: _V) -> _V:
        """Model-unit temperature from °C."""
        return (celsius - self.temperature_offset_c) / self.temperature_span_c

    def celsius_from_temperature(self, temperature: _V) -> _V:
        """°C from model-unit temperature."""
        return self.temperature_offset_c + self.temperature_span_c * temperature


def set_stamp(stamp_msg: Any, ns: int) -> None:
    """Write integer nanoseconds into a builtin_interfaces/Time-like object."""
    stamp_msg.sec = int(ns // NS_PER_S)
    stamp_msg.nanosec = int(ns % NS_PER_S)


TWO_TANK_LABEL = "the two-tank interface (the default map: topics flow_cmd, height, temperature)"
"""How :func:`two_tank_map` is named in messages."""


def two_tank_map(
    units: RigUnits | None = None, topics: Mapping[str, str] | None = None
) -> InterfaceMap:
    """The two-tank rig's interface as a map (the default of every command and node).

    Inputs ``hot`` and ``cold`` from the FlowCommand topic; outputs ``height`` (the
    FluidPressure's ``fluid_pressure`` over ``units.pascal_per_unit``) and ``temperature``
    (the Temperature's ``(°C - offset) / span``); stamps from the headers. The conversions
    are :class:`RigUnits`' float operations, bit for bit (``(x - 0.0) / s == x / s``).

    Args:
        units: the rig's unit conversions (default: :class:`RigUnits()`).
        topics: the rig's topic of each of :data:`STREAMS` where it is remapped (stream ->
            topic; topics not named keep their names).

    Raises:
        InterfaceMapError: ``topics`` names an unknown stream, or maps two streams to one
            topic.
    """
    u = units if units is not None else RigUnits()
    given = dict(topics or {})
    if unknown := sorted(set(given) - set(STREAMS)):
        raise InterfaceMapError(
            f"the two-tank interface has no stream {unknown}; remap one of {list(STREAMS)} "
            "(STREAM=TOPIC)"
        )
    names = {s: given.get(s, s) for s in STREAMS}
    shared = sorted({t for t in names.values() if list(names.values()).count(t) > 1})
    if shared:
        streams = [s for s in STREAMS if names[s] in shared]
        raise InterfaceMapError(
            f"the streams {streams} are all mapped to the topic(s) {shared}; each stream is "
            "read from a topic of its own type: map each to its own topic (--topic STREAM=TOPIC)"
        )
    remapped = any(names[s] != s for s in STREAMS)
    label = "the two-tank interface (remapped topics)" if remapped else TWO_TANK_LABEL
    return InterfaceMap(
        inputs=(
            Source("hot", names[FLOW_CMD], FLOW_CMD_TYPE, "hot"),
            Source("cold", names[FLOW_CMD], FLOW_CMD_TYPE, "cold"),
        ),
        outputs=(
            Source(HEIGHT, names[HEIGHT], HEIGHT_TYPE, "fluid_pressure", scale=u.pascal_per_unit),
            Source(
                TEMPERATURE,
                names[TEMPERATURE],
                TEMPERATURE_TYPE,
                "temperature",
                offset=u.temperature_offset_c,
                scale=u.temperature_span_c,
            ),
        ),
        label=label,
    )


__all__ = [
    "FLOW_CMD",
    "FLOW_CMD_TYPE",
    "HEIGHT",
    "HEIGHT_TYPE",
    "INPUTS",
    "MEASUREMENTS",
    "STREAMS",
    "STREAM_KINDS",
    "STREAM_TYPES",
    "TEMPERATURE",
    "TEMPERATURE_TYPE",
    "TWO_TANK_LABEL",
    "RigUnits",
    "set_stamp",
    "stamp_ns",
    "two_tank_map",
]
