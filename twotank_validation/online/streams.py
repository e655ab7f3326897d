"""The input streams: names, message types, unit conversions and extractors (ROS-free).

Shared by the nodes and bag replay. The extractors read only field names common to rclpy
messages and rosbags' decoded messages (``header.stamp.sec/nanosec``, ``fluid_pressure``,
``temperature``, ``hot``, ``cold``), so live and replay go through the same code. Nothing here
imports a ROS message package (that is :mod:`twotank_validation.ros.messages`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from twotank_validation.defaults import NS_PER_S
from twotank_validation.online.aligner import COMMAND

_V = TypeVar("_V", float, np.ndarray)  # one value, or many at once (same float operations)

FLOW_CMD_TYPE = "twotank_validation_msgs/msg/FlowCommand"
HEIGHT_TYPE = "sensor_msgs/msg/FluidPressure"
TEMPERATURE_TYPE = "sensor_msgs/msg/Temperature"

FLOW_CMD = "flow_cmd"
"""Stream of valve commands ``(hot, cold)`` (model units); also the default topic name."""
HEIGHT = "height"
"""Stream of level measurements; also the default topic name."""
TEMPERATURE = "temperature"
"""Stream of temperature measurements; also the default topic name."""
STREAMS = (FLOW_CMD, HEIGHT, TEMPERATURE)
"""The validator's input streams."""
MEASUREMENTS = (HEIGHT, TEMPERATURE)
"""The measured streams, in the order of the outputs ``y``."""
STREAM_KINDS = {FLOW_CMD: COMMAND, **{s: channel for channel, s in enumerate(MEASUREMENTS)}}
"""Event kind of each stream (:data:`~twotank_validation.online.aligner.COMMAND` or the output
channel), as ``OnlineValidator.feed_many`` takes it."""
STREAM_TYPES = {FLOW_CMD: FLOW_CMD_TYPE, HEIGHT: HEIGHT_TYPE, TEMPERATURE: TEMPERATURE_TYPE}
"""Message type of each stream."""


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


def stamp_ns(msg: Any) -> int:
    """Header stamp of a message in integer nanoseconds."""
    st = msg.header.stamp
    return int(st.sec) * NS_PER_S + int(st.nanosec)


def set_stamp(stamp_msg: Any, ns: int) -> None:
    """Write integer nanoseconds into a builtin_interfaces/Time-like object."""
    stamp_msg.sec = int(ns // NS_PER_S)
    stamp_msg.nanosec = int(ns % NS_PER_S)


def flow_values(msg: Any) -> tuple[float, float]:
    """(hot, cold) valve commands in model units from a FlowCommand."""
    return float(msg.hot), float(msg.cold)


def height_value(msg: Any, units: RigUnits) -> float:
    """Model-unit level from a sensor_msgs/FluidPressure."""
    return units.level_from_pressure(float(msg.fluid_pressure))


def temperature_value(msg: Any, units: RigUnits) -> float:
    """Model-unit temperature from a sensor_msgs/Temperature."""
    return units.temperature_from_celsius(float(msg.temperature))


STREAM_FIELDS: dict[str, tuple[str, ...]] = {
    FLOW_CMD: ("hot", "cold"),
    HEIGHT: ("fluid_pressure",),
    TEMPERATURE: ("temperature",),
}
"""Message fields each stream's extractor reads (besides ``header.stamp``)."""


def stream_values(stream: str, fields: np.ndarray, units: RigUnits) -> np.ndarray:
    """Model-unit values of many messages of one stream: the extractors above, on arrays.

    Args:
        stream: ``flow_cmd``, ``height`` or ``temperature``.
        fields: (n, k) float, the :data:`STREAM_FIELDS` of the stream, in that order.
        units: unit conversion.

    Returns:
        (n, 2) float: ``(hot, cold)`` rows for ``flow_cmd``; the value in column 0 (column 1
        NaN) for a measurement. The same float operations as :func:`flow_values`,
        :func:`height_value` and :func:`temperature_value`, so the same values bit for bit.
    """
    out = np.full((len(fields), 2), np.nan)
    if stream == FLOW_CMD:
        out[:] = fields[:, :2]
    elif stream == HEIGHT:
        out[:, 0] = units.level_from_pressure(fields[:, 0])
    elif stream == TEMPERATURE:
        out[:, 0] = units.temperature_from_celsius(fields[:, 0])
    else:
        raise ValueError(f"unknown stream {stream!r}")
    return out
