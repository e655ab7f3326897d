"""What the bag reader hands out, and the small helpers all of its parts share.

:class:`BagInfo` (what a bag holds, ``storage`` one of the ``STORAGE_*`` values),
:class:`BagMessage` (one decoded message) and :class:`FieldBatch` (consecutive messages
reduced to their stamps and float fields); ``_norm_type`` (ROS 1 style type names),
``_fmt_ns`` and ``_short`` (times and library errors in messages). No I/O, no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from twotank_validation.defaults import NS_PER_S

__all__ = [
    "STORAGE_MCAP",
    "STORAGE_MCAP_PLAIN",
    "STORAGE_SQLITE3",
    "BagInfo",
    "BagMessage",
    "FieldBatch",
]


STORAGE_MCAP: Final = "mcap"
"""``BagInfo.storage`` of a rosbag2 bag in MCAP storage."""
STORAGE_SQLITE3: Final = "sqlite3"
"""``BagInfo.storage`` of a rosbag2 bag in SQLite3 storage (or a lone ``.db3`` file)."""
STORAGE_MCAP_PLAIN: Final = "mcap-plain"
"""``BagInfo.storage`` of an MCAP file outside a rosbag2 directory."""


@dataclass(frozen=True)
class BagMessage:
    """One decoded message.

    Attributes:
        topic: the topic name as requested from
            :meth:`~twotank_validation.bags.reader.BagReader.messages`.
        msgtype: its type, e.g. ``sensor_msgs/msg/FluidPressure``.
        log_time_ns: time the recorder logged it (ns since the epoch, or of the simulated
            clock when recorded on sim time).
        msg: the decoded message (rosbags or mcap_ros2 object; attribute access as rclpy).
    """

    topic: str
    msgtype: str
    log_time_ns: int
    msg: Any


@dataclass(frozen=True)
class FieldBatch:
    """Consecutive messages (log-time order) reduced to their stamps and float fields.

    Attributes:
        topics: the requested topic names; ``topic`` indexes into it.
        topic: (n,) int, topic of each message.
        log_time_ns: (n,) int64, log times.
        stamp_ns: (n,) int64, ``header.stamp`` in nanoseconds.
        values: (n, w) float64, the requested fields of each message's topic in the order
            asked for (NaN in the columns its topic did not ask for).
        bulk_decoded: messages decoded by the fixed-layout path (the rest generically).
    """

    topics: tuple[str, ...]
    topic: np.ndarray
    log_time_ns: np.ndarray
    stamp_ns: np.ndarray
    values: np.ndarray
    bulk_decoded: int

    def __len__(self) -> int:
        """Number of messages."""
        return len(self.topic)


@dataclass(frozen=True)
class BagInfo:
    """What a bag holds.

    Attributes:
        path: the bag (directory of a rosbag2 bag, else the file).
        storage: ``"mcap"``, ``"sqlite3"`` (rosbag2) or ``"mcap-plain"``.
        topics: topic -> message type (``" | "``-joined if a topic carries several).
        message_counts: topic -> messages (from the index; after damage, the readable ones).
        start_ns: log time of the first message (ns), None if there is none.
        end_ns: log time of the last message (ns), None if there is none.
        damage: None for a healthy bag; else what was found at open (the index could not be
            read, the file is truncated at byte N, ...) and how the bag is read instead.
        custom_data: the ``custom_data`` strings of a rosbag2 bag's metadata.yaml (empty for
            a plain MCAP file or an unreadable metadata.yaml).
    """

    path: Path
    storage: str
    topics: dict[str, str]
    message_counts: dict[str, int]
    start_ns: int | None
    end_ns: int | None
    damage: str | None = None
    custom_data: dict[str, str] = field(default_factory=dict)


def _norm_type(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (ROS 1 style names some tools write)."""
    parts = name.split("/")
    if len(parts) == 2 and all(parts):
        return f"{parts[0]}/msg/{parts[1]}"
    return name


def _fmt_ns(ns: int) -> str:
    sign = "-" if ns < 0 else ""
    sec, frac = divmod(abs(ns), NS_PER_S)
    return f"{sign}{sec}.{frac:09d} s"


def _short(err: BaseException) -> str:
    text = str(err).strip() or "no details"
    if len(text) > 300:
        text = text[:300] + "..."
    return f"{type(err).__name__}: {text}"
