"""Writing rosbag2 bags (MCAP or SQLite3) without ROS: rosbags' writer plus this package's types.

``typestore()`` is rosbags' ROS 2 Kilted type store with ``twotank_validation_msgs``'
FlowCommand and ValidationReport registered from their ``.msg`` text, so bags written here
decode with rclpy, ``ros2 bag`` and mcap-ros2-support, and the reverse. :class:`BagWriter`
wraps :class:`rosbags.rosbag2.Writer`: it never overwrites, and closing it always finalises
the bag (metadata and index), also when the block it guards raised (Ctrl-C in a recorder), so
nothing already written is lost. The message helpers build the three interface messages of
the validator (``flow_cmd``, ``height``, ``temperature``) from model-unit values.

This module imports rosbags but never rclpy.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Final

import yaml
from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from twotank_validation.bags.bag_errors import BagExistsError, BagWriteError
from twotank_validation.defaults import NS_PER_S
from twotank_validation.online.streams import (
    FLOW_CMD_TYPE,
    HEIGHT_TYPE,
    TEMPERATURE_TYPE,
    RigUnits,
)

__all__ = [
    "BAG_VERSION",
    "DEFAULT_UNITS",
    "FRAME_ID",
    "INTERFACE_PACKAGE",
    "REPORT_TYPE",
    "STORAGES",
    "BagWriter",
    "flow_command",
    "fluid_pressure",
    "interface_msg_dir",
    "temperature_msg",
    "typestore",
]

INTERFACE_PACKAGE: Final = "twotank_validation_msgs"
"""ROS package of this project's messages (built from the repository's ``msg/``)."""

REPORT_TYPE: Final = f"{INTERFACE_PACKAGE}/msg/ValidationReport"
_OWN_MESSAGES: Final = ("FlowCommand", "ValidationReport")

STORAGES: Final = ("mcap", "sqlite3")
"""Storage formats :class:`BagWriter` writes (rosbag2 storage identifiers)."""

_PLUGINS: Final = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}

BAG_VERSION: Final = 9
"""rosbag2 metadata version written (the one of ROS 2 Jazzy/Kilted)."""

FRAME_ID: Final = "tank1_base"
"""``header.frame_id`` of the measurement and command messages (as the plant node)."""

DEFAULT_UNITS: Final = RigUnits()

_MAX_LOG_TIME_NS: Final = 2**63 - 1
_MAX_STAMP_NS: Final = (2**31 - 1) * NS_PER_S + NS_PER_S - 1  # builtin_interfaces/Time, int32 sec


def _msg_dir_candidates() -> list[Path]:
    """Where the ``.msg`` files may be, in order of preference."""
    share = Path("share", INTERFACE_PACKAGE, "msg")
    places = [Path(sys.prefix) / share]
    places += [
        Path(p) / share for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p
    ]
    places.append(Path(__file__).resolve().parents[2] / "msg")  # repository (editable install)
    return places


def interface_msg_dir(search: Sequence[Path] | None = None) -> Path:
    """Directory holding ``FlowCommand.msg`` and ``ValidationReport.msg``.

    Looked up in the installed interface package (``<sys.prefix>/share/twotank_validation_msgs
    /msg``, then the same under each ``AMENT_PREFIX_PATH`` entry of a colcon workspace), then
    in the repository's top-level ``msg/`` (editable installs).

    Args:
        search: Directories to try instead, in order.

    Raises:
        BagError: If no candidate holds both files (the message lists where it looked).
    """
    candidates = _msg_dir_candidates() if search is None else [Path(p) for p in search]
    for place in candidates:
        if all((place / f"{name}.msg").is_file() for name in _OWN_MESSAGES):
            return place
    looked = "\n  ".join(str(p) for p in candidates)
    raise BagWriteError(
        f"cannot find the message definitions {', '.join(n + '.msg' for n in _OWN_MESSAGES)} "
        f"of {INTERFACE_PACKAGE}; looked in:\n  {looked}\n"
        "install the interface package (bash scripts/run exec true, or a colcon build of "
        "twotank_validation_msgs/) or run from a checkout of the repository"
    )


@functools.cache
def typestore() -> Typestore:
    """Rosbags type store: ROS 2 Kilted plus FlowCommand and ValidationReport of this package.

    Built once (cached); the package's types are registered from the ``.msg`` text found by
    :func:`interface_msg_dir` under ``twotank_validation_msgs/msg/<Name>``.

    Raises:
        BagError: If the ``.msg`` files are not found or do not parse.
    """
    store = get_typestore(Stores.ROS2_KILTED)
    msg_dir = interface_msg_dir()
    types: dict[str, Any] = {}
    for name in _OWN_MESSAGES:
        path = msg_dir / f"{name}.msg"
        try:
            types.update(get_types_from_msg(path.read_text(), f"{INTERFACE_PACKAGE}/msg/{name}"))
        except Exception as err:
            raise BagWriteError(f"{path}: cannot parse the message definition: {err}") from err
    store.register(types)
    return store


class BagWriter:
    """A rosbag2 bag being written (MCAP by default, or SQLite3); a context manager.

    The bag directory is created by the constructor. Register each topic with
    :meth:`add_topic`, then write messages with :meth:`write` (rosbags message instances) or
    :meth:`write_raw` (CDR bytes, e.g. from an rclpy raw subscription). :meth:`close` (also
    called on leaving a ``with`` block, even by an exception or KeyboardInterrupt) writes the
    index and ``metadata.yaml``; everything written before is in the bag.

    Args:
        path: Bag directory to create; must not exist.
        storage: ``"mcap"`` (default) or ``"sqlite3"``.
        store: Type store; default :func:`typestore`.

    Raises:
        BagExistsError: If ``path`` exists.
        BagError: If ``storage`` is unknown or the bag cannot be created.
    """

    def __init__(
        self, path: str | os.PathLike[str], storage: str = "mcap", *, store: Typestore | None = None
    ) -> None:
        if storage not in STORAGES:
            raise BagWriteError(
                f"storage={storage!r} is not a known bag storage; use one of {STORAGES}"
            )
        self.path = Path(path)
        self.storage = storage
        if self.path.exists() or self.path.is_symlink():
            raise BagExistsError(
                f"{self.path} exists already; bags are never overwritten: choose another path "
                "or remove it"
            )
        self._store = typestore() if store is None else store
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=_PLUGINS[storage])
        try:
            self._writer.open()
        except WriterError as err:  # created by someone else in between
            raise BagExistsError(f"{self.path}: {err}") from err
        except OSError as err:
            raise BagWriteError(f"cannot create the bag {self.path}: {err}") from err
        self._connections: dict[str, Connection] = {}
        self._closed = False

    # --- context manager ------------------------------------------------------------------

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_val: BaseException | None,
        exc_tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Finalise the bag (index, metadata.yaml); idempotent.

        If finalising fails, the storage is aborted and the error re-raised.
        """
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
        except BaseException:
            with contextlib.suppress(Exception):
                self._writer.abort()
            raise

    def flush(self) -> None:
        """Make everything written so far readable after a crash (MCAP storage).

        Closes the pending chunk (rosbags' MCAP writer otherwise holds up to 1 MiB in memory),
        flushes the file to the operating system and (re)writes ``metadata.yaml`` for what
        is in the file now (atomically: a temporary file renamed), so that a bag killed at
        any later point is a rosbag2 directory whose file holds every flushed message: its
        summary is missing, and the reader scans it (:mod:`~twotank_validation.bags.scan`).
        :meth:`close` replaces the metadata with the final one. SQLite3 storage: nothing to
        do (each write is in the database already).

        Raises:
            BagError: the bag is closed.
        """
        self._check_open()
        storage: Any = self._writer.storage
        if self.storage != "mcap" or storage is None:
            return
        # rosbags' McapWriter (pinned 0.11.9): the pending chunk and the file object
        if storage.chunk.bio.tell():
            storage.close_chunk()
        storage.bio.flush()
        self._write_metadata()

    def _write_metadata(self) -> None:
        w = self._writer
        count = sum(w.counts.values())
        start = w.min_timestamp if count else 0
        duration = max(0, w.max_timestamp - w.min_timestamp) if count else 0
        name = f"{self.path.name}.mcap"
        info = {
            "version": BAG_VERSION,
            "storage_identifier": "mcap",
            "relative_file_paths": [name],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": c.topic,
                        "type": c.msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": [],
                        "type_description_hash": c.digest,
                    },
                    "message_count": w.counts[c.id],
                }
                for c in w.connections
            ],
            "compression_format": "",
            "compression_mode": "",
            "files": [
                {
                    "path": name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": count,
                }
            ],
            "custom_data": dict(w.custom_data) or None,
            "ros_distro": "rosbags",
        }
        meta = self.path / "metadata.yaml"
        tmp = meta.with_suffix(".yaml.tmp")
        tmp.write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}), "utf8")
        tmp.replace(meta)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran."""
        return self._closed

    # --- topics and messages --------------------------------------------------------------

    @property
    def topics(self) -> dict[str, str]:
        """Registered topics: name -> message type."""
        return {name: conn.msgtype for name, conn in self._connections.items()}

    @property
    def typestore(self) -> Typestore:
        """The type store messages are serialised with."""
        return self._store

    def _check_open(self) -> None:
        if self._closed:
            raise BagWriteError(f"the bag {self.path} is closed; nothing more can be written to it")

    def add_topic(
        self, topic: str, msgtype: str, *, offered_qos_profiles: Sequence[Qos] = ()
    ) -> Connection:
        """Register a topic of message type ``msgtype`` (e.g. ``"sensor_msgs/msg/Temperature"``).

        Raises:
            BagError: If the bag is closed, the topic is registered already or the type is not
                in the type store.
        """
        self._check_open()
        if not isinstance(topic, str) or not topic:
            raise BagWriteError(f"topic={topic!r} must be a non-empty string")
        if topic in self._connections:
            raise BagWriteError(
                f"topic {topic!r} is registered already (type {self._connections[topic].msgtype})"
            )
        if msgtype not in self._store.types:
            raise BagWriteError(
                f"message type {msgtype!r} of topic {topic!r} is not in the type store "
                "(ROS 2 Kilted types and twotank_validation_msgs); write 'pkg/msg/Name'"
            )
        conn = self._writer.add_connection(
            topic, msgtype, typestore=self._store, offered_qos_profiles=list(offered_qos_profiles)
        )
        self._connections[topic] = conn
        return conn

    def _connection(self, topic: str) -> Connection:
        self._check_open()
        try:
            return self._connections[topic]
        except KeyError:
            raise BagWriteError(
                f"topic {topic!r} is not registered; call add_topic first "
                f"(registered: {sorted(self._connections)})"
            ) from None

    @staticmethod
    def _check_time(topic: str, log_time_ns: int) -> int:
        if isinstance(log_time_ns, bool) or not hasattr(log_time_ns, "__index__"):
            raise BagWriteError(
                f"log time {log_time_ns!r} on {topic!r} must be integer nanoseconds"
            )
        t = int(log_time_ns)
        if not 0 <= t <= _MAX_LOG_TIME_NS:
            raise BagWriteError(f"log time {t} ns on {topic!r} is outside 0 .. 2**63 - 1 ns")
        return t

    def write(self, topic: str, log_time_ns: int, msg: object) -> None:
        """Serialise a rosbags message instance (CDR) and write it at ``log_time_ns``.

        Raises:
            BagError: Closed bag, unknown topic, bad time, or a message of another type.
        """
        conn = self._connection(topic)
        t = self._check_time(topic, log_time_ns)
        msgtype = getattr(msg, "__msgtype__", None)
        if msgtype != conn.msgtype:
            raise BagWriteError(
                f"topic {topic!r} carries {conn.msgtype}, got a message of type "
                f"{msgtype or type(msg).__name__}; build it from this writer's typestore"
            )
        self._writer.write(conn, t, self._store.serialize_cdr(msg, conn.msgtype))

    def write_raw(self, topic: str, log_time_ns: int, data: bytes | bytearray | memoryview) -> None:
        """Write an already serialised (CDR) message at ``log_time_ns``.

        Raises:
            BagError: Closed bag, unknown topic, bad time, or data that is not CDR bytes.
        """
        conn = self._connection(topic)
        t = self._check_time(topic, log_time_ns)
        if not isinstance(data, bytes | bytearray | memoryview) or len(data) < 4:
            raise BagWriteError(
                f"data on {topic!r} must be serialised CDR bytes (>= 4 bytes), got "
                f"{type(data).__name__}"
            )
        self._writer.write(conn, t, bytes(data) if isinstance(data, bytearray) else data)

    def set_custom_data(self, key: str, value: str) -> None:
        """Store a string under ``key`` in the bag's ``custom_data`` (metadata.yaml)."""
        self._check_open()
        if not isinstance(value, str):
            raise BagWriteError(f"custom data {key!r} must be a string, got {type(value).__name__}")
        self._writer.set_custom_data(key, value)


# --- the validator's interface messages, from model-unit values ------------------------------


def _header(store: Typestore, stamp_ns: int) -> Any:
    if isinstance(stamp_ns, bool) or not hasattr(stamp_ns, "__index__"):
        raise BagWriteError(f"stamp {stamp_ns!r} must be integer nanoseconds")
    ns = int(stamp_ns)
    if not 0 <= ns <= _MAX_STAMP_NS:
        raise BagWriteError(f"stamp {ns} ns is outside builtin_interfaces/Time (0 .. 2**31 s)")
    time_cls = store.types["builtin_interfaces/msg/Time"]
    header_cls = store.types["std_msgs/msg/Header"]
    return header_cls(stamp=time_cls(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S), frame_id=FRAME_ID)


def flow_command(stamp_ns: int, hot: float, cold: float) -> Any:
    """``twotank_validation_msgs/msg/FlowCommand`` (rosbags instance), commands in model units."""
    store = typestore()
    return store.types[FLOW_CMD_TYPE](
        header=_header(store, stamp_ns), hot=float(hot), cold=float(cold)
    )


def fluid_pressure(stamp_ns: int, level: float, units: RigUnits = DEFAULT_UNITS) -> Any:
    """``sensor_msgs/msg/FluidPressure`` (Pa) of a model-unit level; variance 0 (unknown)."""
    store = typestore()
    return store.types[HEIGHT_TYPE](
        header=_header(store, stamp_ns),
        fluid_pressure=units.pressure_from_level(float(level)),
        variance=0.0,
    )


def temperature_msg(stamp_ns: int, temperature: float, units: RigUnits = DEFAULT_UNITS) -> Any:
    """``sensor_msgs/msg/Temperature`` (°C) of a model-unit temperature; variance 0 (unknown)."""
    store = typestore()
    return store.types[TEMPERATURE_TYPE](
        header=_header(store, stamp_ns),
        temperature=units.celsius_from_temperature(float(temperature)),
        variance=0.0,
    )
