"""Records and messages as the online validator takes them.

Events in arrival order, and the two-tank rig's message values read straight from their
fields.

Used by tests and benches that feed ``OnlineValidator.feed_many`` from simulated samples, and
as the reference of the interface map's extraction on the rig's messages.
"""

from __future__ import annotations

import numpy as np

from twotank_validation.online import COMMAND
from twotank_validation.online.streams import FLOW_CMD, HEIGHT, TEMPERATURE, RigUnits


def arrival_order(
    kinds: np.ndarray, stamps_ns: np.ndarray, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Events sorted by stamp, a command before the measurements of the same stamp.

    Args:
        kinds: (n,) int, :data:`COMMAND` or the measurement channel.
        stamps_ns: (n,) int, stamps.
        values: (n, w) float, as ``feed_many`` takes them.

    Returns:
        ``(kinds int8, stamps int64, values)`` in that order (a stable sort).
    """
    kinds = np.asarray(kinds)
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    order = np.argsort(stamps + np.where(kinds == COMMAND, 0, 1), kind="stable")
    return kinds[order].astype(np.int8), stamps[order], np.asarray(values)[order]


def record_events(
    stamps_ns: np.ndarray, u: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One command and one message per output for every sample of a record.

    Args:
        stamps_ns: (n,) int, sample stamps.
        u: (n, nu) float, commands.
        y: (n, ny) float, outputs (model units).

    Returns:
        ``feed_many``'s ``(kinds, stamps, values)`` in arrival order.
    """
    n, ny = len(stamps_ns), y.shape[1]
    kinds = np.concatenate([np.full(n, COMMAND)] + [np.full(n, c) for c in range(ny)])
    stamps = np.tile(np.asarray(stamps_ns, dtype=np.int64), ny + 1)
    values = np.full(((ny + 1) * n, max(1, u.shape[1])), np.nan)
    values[:n, : u.shape[1]] = u
    for c in range(ny):
        values[(c + 1) * n : (c + 2) * n, 0] = y[:, c]
    return arrival_order(kinds, stamps, values)


def two_tank_value(stream: str, msg: object, units: RigUnits) -> float | tuple[float, float]:
    """A two-tank message's model-unit value read straight from its fields (no map).

    The reference the interface map's extraction (:func:`~twotank_validation.online.
    interface.extract` through :func:`~twotank_validation.online.streams.two_tank_map`) is
    checked against: ``(hot, cold)`` of a FlowCommand, the level of a FluidPressure, the
    temperature of a Temperature, by :class:`RigUnits`' own conversions.
    """
    if stream == FLOW_CMD:
        return float(msg.hot), float(msg.cold)  # type: ignore[attr-defined]
    if stream == HEIGHT:
        return units.level_from_pressure(float(msg.fluid_pressure))  # type: ignore[attr-defined]
    if stream == TEMPERATURE:
        return units.temperature_from_celsius(float(msg.temperature))  # type: ignore[attr-defined]
    raise ValueError(f"unknown stream {stream!r}")
