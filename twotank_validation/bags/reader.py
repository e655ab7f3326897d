"""One streaming iterator over recorded data, whatever the storage.

Reads rosbag2 bags in MCAP and SQLite3 storage (a bag directory with ``metadata.yaml``, or
the ``.mcap``/``.db3`` file inside one) through :class:`rosbags.highlevel.AnyReader`, and
plain MCAP files written by other ROS 2 tools (no ``metadata.yaml``) through
:func:`mcap.reader.make_reader`'s seeking reader with :class:`mcap_ros2.decoder.DecoderFactory`.
Messages come out decoded, in log-time order, one at a time (memory stays bounded by about
one MCAP chunk, whatever the length of the bag), with the attribute access of rclpy messages
(``msg.header.stamp.sec``, ``msg.fluid_pressure``, ``msg.hot``, ...).

Custom types are rebuilt from the definitions stored in the bag. Where a bag carries none
(SQLite3 bags of ROS 2 Humble and older), the ROS 2 Kilted types and this package's
``twotank_validation_msgs`` (from ``<sys.prefix>/share/twotank_validation_msgs/msg``, a colcon
prefix in ``AMENT_PREFIX_PATH``, or the repository's ``msg/``) are used instead.

Damage. When the index of a bag cannot be used (an MCAP file cut short by a killed recorder
has no summary and no footer; a truncated SQLite3 file fails the index queries; counts or
time ranges contradict each other), the reader falls back to a scan that recovers everything
before the damage. MCAP: every complete record up to the first bad one, including the
complete messages at the head of an uncompressed chunk the file cuts short; the scan at open
notes each chunk's byte and time range (an index rebuilt from the data) and the messages are
then merged in log-time order, chunk by chunk. SQLite3: every row SQLite still returns, in
time order through the timestamp index, or in insertion order through the table if that
reaches further (``writable_schema`` lets SQLite use the pages a truncated file has).
``info.damage`` says what was found. :meth:`BagReader.messages` yields the readable messages
first and raises :class:`BagCorruptError` (``messages_read``, ``last_good_ns``) where the
damage starts; through an index, reading fewer messages than it lists or going back in time
is damage too. Every error of this module is a :class:`BagError`; errors of the underlying
libraries (rosbags, mcap, sqlite3, yaml, struct, decompressors) are wrapped ``from`` the
original. The reader never loops on garbage: every loop advances through a file of known
size, record lengths are checked against it, and decompression stops at the declared size.

This module imports rosbags, mcap and mcap-ros2-support, never rclpy.
"""

from __future__ import annotations

import contextlib
import functools
import heapq
import io
import os
import sqlite3
import struct
import sys
import time
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePath
from types import TracebackType
from typing import Any, Final, Self
from urllib.parse import quote

import lz4.frame
import numpy as np
import yaml
import zstandard
from mcap.reader import SeekingReader
from mcap.records import Schema as McapSchema
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.interfaces import ConnectionExtRosbag2, Nodetype
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from twotank_validation.defaults import NS_PER_S
from twotank_validation.errors import TwotankError

__all__ = [
    "STORAGE_MCAP",
    "STORAGE_MCAP_PLAIN",
    "STORAGE_SQLITE3",
    "BagCorruptError",
    "BagEmptyError",
    "BagError",
    "BagFormatError",
    "BagInfo",
    "BagMessage",
    "BagNotFoundError",
    "BagReader",
    "FieldBatch",
    "TopicMissingError",
    "TopicTypeError",
    "expected_types",
    "open_bag",
]

STORAGE_MCAP: Final = "mcap"
"""``BagInfo.storage`` of a rosbag2 bag in MCAP storage."""
STORAGE_SQLITE3: Final = "sqlite3"
"""``BagInfo.storage`` of a rosbag2 bag in SQLite3 storage (or a lone ``.db3`` file)."""
STORAGE_MCAP_PLAIN: Final = "mcap-plain"
"""``BagInfo.storage`` of an MCAP file outside a rosbag2 directory."""

_MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
_SQLITE_MAGIC: Final = b"SQLite format 3\x00"
_MSG_PACKAGE: Final = "twotank_validation_msgs"
_OWN_TYPES: Final = ("FlowCommand", "ValidationReport")
_MAX_CHUNK_BYTES: Final = 1 << 31  # a chunk header claiming more is corrupt
_SQLITE_STALL_S: Final = 60.0  # a query producing no row for this long is aborted
_REPAIR_HINT: Final = (
    "re-copy the recording, or repair it (`mcap recover` for MCAP, the sqlite3 shell's "
    "`.recover` for SQLite3)"
)


# --------------------------------------------------------------------------- errors


class BagError(TwotankError):
    """Root of every error of the bag reader (each subclass also inherits a builtin)."""


class BagNotFoundError(BagError, FileNotFoundError):
    """The path does not exist."""


class BagFormatError(BagError, ValueError):
    """The path is not a bag, its metadata is unreadable, or a topic cannot be decoded."""


class BagEmptyError(BagError, ValueError):
    """The bag holds no message at all."""


class BagCorruptError(BagError, ValueError):
    """The bag's data is truncated or corrupt from some point on.

    Attributes:
        messages_read: messages of the requested topics delivered before the damage.
        last_good_ns: log time (ns) of the last of them, None if none was read.
        offset: byte offset of the damage in its file, None where unknown (SQLite3).
    """

    def __init__(
        self,
        message: str,
        *,
        messages_read: int = 0,
        last_good_ns: int | None = None,
        offset: int | None = None,
    ) -> None:
        super().__init__(message)
        self.messages_read = messages_read
        self.last_good_ns = last_good_ns
        self.offset = offset


class TopicMissingError(BagError, KeyError):
    """Topics asked for are not in the bag (or hold no message).

    Attributes:
        missing: the requested names that were not found or are empty.
        available: topic -> message type of everything the bag has.
    """

    def __init__(self, message: str, missing: Sequence[str], available: Mapping[str, str]) -> None:
        super().__init__(message)
        self.missing = tuple(missing)
        self.available = dict(available)

    def __str__(self) -> str:
        """The message itself (KeyError would show its repr)."""
        return str(self.args[0])


class TopicTypeError(BagError, TypeError):
    """A topic carries another message type than the one expected.

    Attributes:
        topic: the topic as requested.
        found: its type(s) in the bag (``" | "``-joined if several).
        expected: the accepted types.
    """

    def __init__(self, message: str, topic: str, found: str, expected: Sequence[str]) -> None:
        super().__init__(message)
        self.topic = topic
        self.found = found
        self.expected = tuple(expected)


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class BagMessage:
    """One decoded message.

    Attributes:
        topic: the topic name as requested from :meth:`BagReader.messages`.
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
    """

    path: Path
    storage: str
    topics: dict[str, str]
    message_counts: dict[str, int]
    start_ns: int | None
    end_ns: int | None
    damage: str | None = None


def expected_types() -> dict[str, tuple[str, ...]]:
    """Accepted message types of the validator's default topics (names may be remapped)."""
    from twotank_validation.online.streams import (  # noqa: PLC0415 - keeps the reader light
        FLOW_CMD_TYPE,
        HEIGHT_TYPE,
        TEMPERATURE_TYPE,
    )

    return {
        "flow_cmd": (FLOW_CMD_TYPE,),
        "height": (HEIGHT_TYPE,),
        "temperature": (TEMPERATURE_TYPE,),
    }


def open_bag(path: str | Path) -> BagReader:
    """Open a bag for reading; use it as a context manager.

    Args:
        path: a rosbag2 directory (MCAP or SQLite3 storage), its ``metadata.yaml``, the
            ``.mcap``/``.db3`` file inside one, or a plain MCAP file.

    Raises:
        BagNotFoundError: The path does not exist.
        BagFormatError: The path is not a bag, or its metadata cannot be read.
    """
    return BagReader(path)


# --------------------------------------------------------------------------- helpers


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


def _msg_dirs() -> list[Path]:
    share = Path("share", _MSG_PACKAGE, "msg")
    places = [Path(sys.prefix) / share]
    ament = os.environ.get("AMENT_PREFIX_PATH", "")
    places += [Path(p) / share for p in ament.split(os.pathsep) if p]
    places.append(Path(__file__).resolve().parents[2] / "msg")
    return places


@functools.cache
def _default_fielddefs() -> dict[str, Any]:
    """Field definitions of ROS 2 Kilted plus this package's messages (if found)."""
    store = get_typestore(Stores.ROS2_KILTED)
    for place in _msg_dirs():
        if all((place / f"{n}.msg").is_file() for n in _OWN_TYPES):
            types: dict[str, Any] = {}
            for n in _OWN_TYPES:
                text = (place / f"{n}.msg").read_text(encoding="utf-8")
                types.update(get_types_from_msg(text, f"{_MSG_PACKAGE}/msg/{n}"))
            store.register(types)
            break
    return dict(store.fielddefs)


@functools.cache
def _default_typestore() -> Typestore:
    """Shared read-only default store (AnyReader only reads its ``fielddefs``)."""
    store = get_typestore(Stores.EMPTY)
    store.register(_default_fielddefs())
    return store


def _names_in(tree: Any, known: Mapping[str, Any], out: set[str]) -> None:
    if isinstance(tree, str):
        if tree in known:
            out.add(tree)
    elif isinstance(tree, tuple | list):
        for item in tree:
            _names_in(item, known, out)


def _fill_defaults(store: Typestore, wanted: Iterable[str]) -> None:
    """Register in ``store`` the default types ``wanted`` needs and the store lacks."""
    defaults = _default_fielddefs()
    todo = [t for t in wanted if t not in store.fielddefs and t in defaults]
    add: dict[str, Any] = {}
    while todo:
        name = todo.pop()
        if name in add or name in store.fielddefs:
            continue
        add[name] = defaults[name]
        deps: set[str] = set()
        _names_in(defaults[name], defaults, deps)
        todo.extend(deps - add.keys())
    if add:
        store.register(add)


def _types_from_definition(msgtype: str, encoding: str, text: str) -> dict[str, Any]:
    """Parse a stored definition (``ros2msg`` or ``ros2idl``); {} if it cannot be parsed."""
    try:
        if encoding == "ros2msg":
            return dict(get_types_from_msg(text, msgtype))
        if encoding == "ros2idl":
            sep = "=" * 80 + "\n"
            out: dict[str, Any] = {}
            if text.startswith(f"{sep}IDL: "):
                for part in text.split(sep)[1:]:
                    out.update(get_types_from_idl(part.split("\n", 1)[1]))
            else:
                out.update(get_types_from_idl(text))
            return out
    except Exception:  # an unparsable definition falls back to known types
        return {}
    return {}


def _typestore_from(
    definitions: Iterable[tuple[str, str, str]], wanted: Iterable[str]
) -> Typestore:
    """Type store from the bag's (msgtype, encoding, text) definitions, then the defaults."""
    types: dict[str, Any] = {}
    for msgtype, encoding, text in definitions:
        types.update(_types_from_definition(msgtype, encoding, text))
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(types)
    except Exception:  # inconsistent stored definitions: use the known types
        store = get_typestore(Stores.EMPTY)
    _fill_defaults(store, wanted)
    return store


def _unknown_type(msgtype: str) -> str:
    return (
        f"its type {msgtype} is neither defined in the bag nor one this reader knows (ROS 2 "
        f"Kilted and {_MSG_PACKAGE}, looked for in {', '.join(str(p) for p in _msg_dirs())})"
    )


class _Damage(Exception):  # noqa: N818 - internal signal, never leaves the module
    """Where a linear scan stopped: file, byte offset (None if unknown), what was wrong."""

    def __init__(self, path: Path, offset: int | None, detail: str, *, truncated: bool) -> None:
        super().__init__(detail)
        self.path = path
        self.offset = offset
        self.detail = detail
        self.truncated = truncated

    def where(self) -> str:
        at = f" at byte {self.offset}" if self.offset is not None else ""
        what = "truncated" if self.truncated else "corrupt"
        return f"{self.path.name} is {what}{at} ({self.detail})"


class _Codec:
    """How one channel's messages are decoded.

    ``decode`` is the generic deserialiser (rosbags, or mcap_ros2 for plain MCAP files):
    every message goes through it unless :meth:`layout` applies. ``layout`` reads the type's
    definition as the generic deserialiser sees it (``fielddefs``, rosbags' form) and
    returns the names of its float64 fields when the type is ``std_msgs/Header header``
    followed by float64 fields only, the fixed layout :func:`_fixed_layout_rows` reads.
    """

    __slots__ = ("_defs", "_layout", "_looked", "decode", "msgtype")

    def __init__(
        self,
        decode: Callable[[Any], Any],
        msgtype: str,
        fielddefs: Callable[[], Mapping[str, Any] | None],
    ) -> None:
        self.decode = decode
        self.msgtype = msgtype
        self._defs = fielddefs
        self._layout: tuple[str, ...] | None = None
        self._looked = False

    def layout(self) -> tuple[str, ...] | None:
        if not self._looked:
            self._looked = True
            try:
                defs = self._defs()
                self._layout = None if defs is None else _header_float_layout(defs, self.msgtype)
            except Exception:  # no usable definition: the generic path only
                self._layout = None
        return self._layout


_BASE, _NAME = int(Nodetype.BASE), int(Nodetype.NAME)
_HEADER_FIELDS: Final = [
    ("stamp", (_NAME, "builtin_interfaces/msg/Time")),
    ("frame_id", (_BASE, ("string", 0))),
]
_TIME_FIELDS: Final = [("sec", (_BASE, ("int32", 0))), ("nanosec", (_BASE, ("uint32", 0)))]


def _plain(fields: Sequence[Any]) -> list[tuple[str, tuple[int, Any]]]:
    return [(str(name), (int(desc[0]), desc[1])) for name, desc in fields]


def _header_float_layout(fielddefs: Mapping[str, Any], msgtype: str) -> tuple[str, ...] | None:
    """Float64 field names of ``msgtype`` if it is ``Header header`` + float64 fields, else None."""
    fields = _plain(fielddefs[msgtype][1])
    if not fields or fields[0] != ("header", (_NAME, "std_msgs/msg/Header")):
        return None
    if _plain(fielddefs["std_msgs/msg/Header"][1]) != _HEADER_FIELDS:
        return None
    if _plain(fielddefs["builtin_interfaces/msg/Time"][1]) != _TIME_FIELDS:
        return None
    if any(desc != (_BASE, ("float64", 0)) for _, desc in fields[1:]):
        return None
    return tuple(name for name, _ in fields[1:])


def _fixed_layout_rows(
    datas: Sequence[bytes | memoryview], n_floats: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Vectorised CDR decoding of equal-length ``Header header`` + float64 messages.

    Why: rosbags' (and mcap_ros2's) deserialisers are generic, a few microseconds of Python
    per message; for the three fixed layouts of the validator's inputs this reads a whole
    batch with a handful of numpy operations. It only reads what the generic deserialiser
    would give: little-endian CDR, the float64 fields right after the aligned frame_id,
    nothing after them. Every message must repeat the first one's bytes except the stamp and
    the float64 fields (same encapsulation, frame_id and padding); the caller checks the first
    one against the generic deserialiser, which then accepts all of them alike. Rows that
    differ come back flagged in ``ok``; the caller decodes those generically.

    Returns:
        ``(stamp_ns (n,) int64, values (n, n_floats) float64, ok (n,) bool)``, or None if
        the first message does not have this layout.
    """
    n = len(datas)
    size = len(datas[0])
    if size < 16:
        return None
    first = bytes(datas[0][:16])
    if first[:2] != b"\x00\x01":  # CDR little endian (big endian: generic path)
        return None
    strlen = int.from_bytes(first[12:16], "little")
    at = 4 + ((12 + strlen + 7) & ~7)  # first float64, 8-aligned after the frame_id
    if strlen < 1 or at + 8 * n_floats != size:
        return None
    buf = b"".join(datas)
    rows = np.frombuffer(buf, dtype=np.uint8).reshape(n, size)
    fixed = np.r_[0:4, 12:at]  # all but the stamp and the float64 fields
    ok = (rows[:, fixed] == rows[0, fixed]).all(axis=1)
    sec = np.ndarray((n,), dtype="<i4", buffer=buf, offset=4, strides=(size,))
    nanosec = np.ndarray((n,), dtype="<u4", buffer=buf, offset=8, strides=(size,))
    stamps = sec.astype(np.int64) * NS_PER_S + nanosec.astype(np.int64)
    values = np.ndarray((n, n_floats), dtype="<f8", buffer=buf, offset=at, strides=(size, 8))
    return stamps, values.astype(np.float64), ok


def _header_stamp_ns(msg: Any) -> int:
    st = msg.header.stamp
    return int(st.sec) * NS_PER_S + int(st.nanosec)


_Raw = tuple[str, str, int, Any, _Codec]
"""What a backend yields: bag topic, message type, log time (ns), CDR bytes, codec."""


@dataclass
class _RawBatch:
    """Consecutive undecoded messages, column by column."""

    topic: list[str]
    msgtype: list[str]
    log_time_ns: list[int]
    data: list[Any]
    codec: list[_Codec]

    def __len__(self) -> int:
        return len(self.topic)


# --------------------------------------------------------------------------- backends


class _Backend:
    """What every storage reader provides to :class:`BagReader`."""

    storage: str
    shown: Path
    indexed: bool  # the counts are promised by an index: reading fewer is damage
    ordered = True  # messages come in log-time order: going back is damage
    damage: str | None = None

    def __init__(self) -> None:
        self.topics: dict[str, tuple[str, ...]] = {}
        self.counts: dict[str, int] = {}
        self.start_ns: int | None = None
        self.end_ns: int | None = None

    def problem(self, topic: str) -> str | None:  # pragma: no cover - overridden
        """Why ``topic`` cannot be decoded, or None."""
        raise NotImplementedError

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:  # pragma: no cover - overridden
        """Decoded messages of ``topics``; may raise anything, or _Damage."""
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - overridden
        """Release files."""
        raise NotImplementedError


class _RosbagsBackend(_Backend):
    """rosbag2 (directory or lone storage file) through rosbags' AnyReader and its index."""

    indexed = True

    def __init__(self, path: Path, storage: str, shown: Path) -> None:
        super().__init__()
        self.storage = storage
        self.shown = shown
        self._reader = AnyReader([path], default_typestore=_default_typestore())
        self._reader.open()
        try:
            conns = self._reader.connections
            _fill_defaults(self._reader.typestore, {c.msgtype for c in conns})
            types: dict[str, set[str]] = {}
            for c in conns:
                types.setdefault(c.topic, set()).add(_norm_type(c.msgtype))
                self.counts[c.topic] = self.counts.get(c.topic, 0) + int(c.msgcount)
            self.topics = {t: tuple(sorted(v)) for t, v in types.items()}
            total = int(self._reader.message_count)
            if total:
                self.start_ns = int(self._reader.start_time)
                self.end_ns = int(self._reader.end_time) - 1  # rosbags: one past the last
            _check_index(self.counts, total, self.start_ns, self.end_ns)
            if not total and next(self._reader.messages(), None) is not None:
                raise _NeedScan("its metadata counts no message but the storage holds some")
        except BaseException:
            self._reader.close()
            raise

    def problem(self, topic: str) -> str | None:
        for c in self._reader.connections:
            if c.topic != topic:
                continue
            ext = c.ext
            if isinstance(ext, ConnectionExtRosbag2) and ext.serialization_format != "cdr":
                return f"it is serialised as {ext.serialization_format!r}, not ROS 2 CDR"
            if c.msgtype not in self._reader.typestore.fielddefs:
                return _unknown_type(c.msgtype)
        return None

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:
        conns = [c for c in self._reader.connections if c.topic in topics]
        if not conns:
            return
        reader = self._reader
        store = reader.typestore
        codecs: dict[int, tuple[str, str, _Codec]] = {}
        for c in conns:
            dec = functools.partial(_rosbags_decode, reader, c.msgtype)
            codecs[id(c)] = (
                c.topic,
                _norm_type(c.msgtype),
                _Codec(dec, c.msgtype, lambda: store.fielddefs),
            )
        for conn, log_ns, raw in reader.messages(connections=conns):
            topic, msgtype, codec = codecs[id(conn)]
            yield topic, msgtype, int(log_ns), raw, codec

    def close(self) -> None:
        self._reader.close()


def _rosbags_decode(reader: AnyReader, msgtype: str, data: Any) -> Any:
    return reader.deserialize(data, msgtype)


def _schema_fielddefs(name: str, encoding: str, text: str) -> Mapping[str, Any] | None:
    """Field definitions parsed from one stored schema alone (None if it cannot be parsed)."""
    types = _types_from_definition(name, encoding, text)
    if not types:
        return None
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return store.fielddefs


class _Decoders:
    """Per-channel CDR decoders: mcap_ros2's DecoderFactory or a rosbags type store."""

    def __init__(self, prefer_rosbags: bool) -> None:
        self._prefer_rosbags = prefer_rosbags
        self._factories: dict[int, DecoderFactory] = {}
        self._decoders: dict[tuple[int, int], _Codec] = {}
        self._store: Typestore | None = None
        self._definitions: dict[str, tuple[str, str, str]] = {}

    def add_schema(self, schema: McapSchema) -> None:
        enc = "ros2idl" if schema.encoding in ("ros2idl", "omgidl") else schema.encoding
        if schema.name not in self._definitions and schema.data:
            text = bytes(schema.data).decode("utf-8", errors="replace")
            self._definitions[schema.name] = (schema.name, enc, text)

    def _rosbags(self, msgtype: str) -> _Codec | None:
        if self._store is None or msgtype not in self._store.fielddefs:
            self._store = _typestore_from(self._definitions.values(), [msgtype])
        store = self._store
        if msgtype not in store.fielddefs:
            return None
        return _Codec(
            lambda data: store.deserialize_cdr(data, msgtype), msgtype, lambda: store.fielddefs
        )

    def get(
        self, key: tuple[int, int], encoding: str, schema: McapSchema | None, msgtype: str
    ) -> _Codec | str:
        """The decoder of channel ``key`` = (file index, channel id), or why there is none."""
        if (dec := self._decoders.get(key)) is not None:
            return dec
        if encoding != "cdr":
            return f"it is encoded as {encoding!r}, not ROS 2 CDR"
        found: _Codec | None = None
        if self._prefer_rosbags:
            found = self._rosbags(msgtype)
        if found is None and schema is not None:
            factory = self._factories.setdefault(key[0], DecoderFactory())
            try:
                # mcap_ros2's vendored parser prints the lines it rejects to stderr
                with contextlib.redirect_stderr(io.StringIO()):
                    mcap_dec = factory.decoder_for(encoding, schema)
            except Exception:  # unparsable stored schema: try rosbags below
                mcap_dec = None
            if mcap_dec is not None:
                # the layout as this schema alone defines it (what mcap_ros2 decodes by)
                enc = "ros2idl" if schema.encoding in ("ros2idl", "omgidl") else schema.encoding
                text = bytes(schema.data).decode("utf-8", errors="replace")
                found = _Codec(
                    mcap_dec,
                    msgtype,
                    functools.partial(_schema_fielddefs, schema.name, enc, text),
                )
        if found is None and not self._prefer_rosbags:
            found = self._rosbags(msgtype)
        if found is None:
            return _unknown_type(msgtype)
        self._decoders[key] = found
        return found


class _PlainMcapBackend(_Backend):
    """A healthy plain MCAP file with a summary: mcap's seeking reader, log-time order."""

    indexed = True
    storage = STORAGE_MCAP_PLAIN

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.shown = path
        self._file = path.open("rb")
        try:
            self._setup(path)
        except BaseException:
            self._file.close()
            raise

    def _setup(self, path: Path) -> None:
        size = path.stat().st_size
        self._reader = SeekingReader(self._file, validate_crcs=True, record_size_limit=size)
        summary = self._reader.get_summary()
        if summary is None or summary.statistics is None:
            raise _NeedScan("the file has no summary section (index)", benign=True)
        stats = summary.statistics
        if not summary.chunk_indexes and stats.message_count:
            raise _NeedScan("the file has no chunk index", benign=True)
        for ci in summary.chunk_indexes:
            if (
                ci.chunk_start_offset + ci.chunk_length > size
                or ci.compressed_size > ci.chunk_length
                or ci.uncompressed_size > _MAX_CHUNK_BYTES
                or ci.compression not in ("", "zstd", "lz4")
                or any(cid not in summary.channels for cid in ci.message_index_offsets)
            ):
                raise _NeedScan(
                    f"its chunk index is inconsistent (chunk at byte {ci.chunk_start_offset})"
                )
        self._channels = summary.channels
        self._schemas = summary.schemas
        self._decoders = _Decoders(prefer_rosbags=False)
        for schema in summary.schemas.values():
            self._decoders.add_schema(schema)
        types: dict[str, set[str]] = {}
        for ch in summary.channels.values():
            if ch.schema_id and ch.schema_id not in summary.schemas:
                raise _NeedScan(f"channel {ch.id} refers to a missing schema {ch.schema_id}")
            types.setdefault(ch.topic, set()).add(self._msgtype(ch.schema_id))
            n = stats.channel_message_counts.get(ch.id, 0)
            self.counts[ch.topic] = self.counts.get(ch.topic, 0) + n
        self.topics = {t: tuple(sorted(v)) for t, v in types.items()}
        if stats.message_count:
            self.start_ns = int(stats.message_start_time)
            self.end_ns = int(stats.message_end_time)
        _check_index(self.counts, int(stats.message_count), self.start_ns, self.end_ns)
        if not stats.message_count and summary.chunk_indexes:
            raise _NeedScan("its statistics count no message but it has chunks")

    def _msgtype(self, schema_id: int) -> str:
        schema = self._schemas.get(schema_id)
        return _norm_type(schema.name) if schema is not None else "(no schema)"

    def _decoder(self, channel_id: int) -> _Codec | str:
        ch = self._channels[channel_id]
        schema = self._schemas.get(ch.schema_id)
        return self._decoders.get(
            (0, ch.id), ch.message_encoding, schema, self._msgtype(ch.schema_id)
        )

    def problem(self, topic: str) -> str | None:
        for ch in self._channels.values():
            if ch.topic == topic and isinstance(found := self._decoder(ch.id), str):
                return found
        return None

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:
        for _, channel, message in self._reader.iter_messages(topics=sorted(topics)):
            dec = self._decoder(channel.id)
            if isinstance(dec, str):  # pragma: no cover - problem() ran before
                raise BagFormatError(dec)
            msgtype = self._msgtype(channel.schema_id)
            yield channel.topic, msgtype, int(message.log_time), message.data, dec

    def close(self) -> None:
        self._file.close()


class _NeedScan(Exception):  # noqa: N818 - internal signal
    """The index cannot be used; read the file by a linear scan.

    ``benign``: the file simply has no index (valid MCAP), as opposed to an inconsistent one.
    """

    def __init__(self, reason: str, *, benign: bool = False) -> None:
        super().__init__(reason)
        self.benign = benign


def _check_index(
    counts: Mapping[str, int], total: int, start_ns: int | None, end_ns: int | None
) -> None:
    """Raise _NeedScan if an index's counts and time range contradict each other."""
    if sum(counts.values()) != total or any(n < 0 for n in counts.values()):
        raise _NeedScan(
            f"its index is inconsistent: {total} messages in all, "
            f"{sum(counts.values())} counted per topic"
        )
    if start_ns is not None and end_ns is not None and start_ns > end_ns:
        raise _NeedScan("its index is inconsistent: its time range ends before it starts")


class _Cursor:
    """Bounds-checked little-endian reads from a record body."""

    __slots__ = ("buf", "pos")

    def __init__(self, buf: bytes | memoryview, pos: int = 0) -> None:
        self.buf = memoryview(buf)
        self.pos = pos

    def take(self, n: int) -> memoryview:
        if n < 0 or n > len(self.buf) - self.pos:
            raise ValueError(f"needs {n} bytes, {len(self.buf) - self.pos} left in the record")
        out = self.buf[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return int(struct.unpack("<H", self.take(2))[0])

    def u32(self) -> int:
        return int(struct.unpack("<I", self.take(4))[0])

    def u64(self) -> int:
        return int(struct.unpack("<Q", self.take(8))[0])

    def string(self) -> str:
        return bytes(self.take(self.u32())).decode("utf-8")


_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_DATA_END: Final = 0x0F


def _decompress(compression: str, data: bytes | memoryview, size: int) -> bytes:
    """Decompress a chunk, never producing more than its declared ``size`` (+1) bytes."""
    if size > _MAX_CHUNK_BYTES:
        raise ValueError(f"declares {size} uncompressed bytes")
    if compression == "":
        out = bytes(data)
    elif compression == "zstd":
        parts: list[bytes] = []
        total = 0
        with zstandard.ZstdDecompressor().stream_reader(bytes(data)) as src:
            while total <= size:
                piece = src.read(min(1 << 20, size + 1 - total))
                if not piece:
                    break
                parts.append(piece)
                total += len(piece)
        out = b"".join(parts)
    elif compression == "lz4":
        out = lz4.frame.LZ4FrameDecompressor().decompress(bytes(data), max_length=size + 1)
    else:
        raise ValueError(f"unsupported compression {compression!r}")
    if len(out) != size:
        raise ValueError(f"decompresses to {len(out)} bytes, its header says {size}")
    return out


_Msg = tuple[int, int, tuple[int, int], memoryview]  # log time, file order, channel key, data

_RUN_MAX_MESSAGES: Final = 10_000
_RUN_MAX_BYTES: Final = 4 << 20


@dataclass
class _Segment:
    """A piece of an MCAP file the scan can reload: a chunk, or a run of loose records.

    ``kind`` is "run" (top-level records in ``[offset, stop)``), "chunk" (the chunk record at
    ``offset``, its first ``limit`` messages if set) or "partial" (an uncompressed chunk the
    file cuts short, from ``offset`` to the end of the file).
    """

    file_idx: int
    kind: str
    offset: int
    stop: int
    start_ns: int
    end_ns: int
    topics: set[str]
    limit: int | None = None


class _McapScanBackend(_Backend):
    """An MCAP read without its index: scanned once at open into segments, then merged.

    The scan at open walks every record from the start, up to the data-end record or the
    first damage, and notes for each chunk (or run of loose messages, bounded in size) its
    byte range, its time range and its topics: an index rebuilt from the data, as
    ``mcap recover`` does. :meth:`iter` then merges the segments by log time, loading each
    one only when its first message is due, so memory stays bounded by a few segments.
    """

    indexed = False

    def __init__(
        self,
        files: Sequence[Path],
        storage: str,
        shown: Path,
        *,
        reason: str,
        message_compression: bool = False,
        benign: bool = False,
    ) -> None:
        super().__init__()
        self.storage = storage
        self.shown = shown
        self._files = list(files)
        self._message_compression = message_compression
        self._decoders = _Decoders(prefer_rosbags=storage != STORAGE_MCAP_PLAIN)
        self._schemas: dict[tuple[int, int], McapSchema] = {}
        self._channels: dict[tuple[int, int], tuple[str, str, int]] = {}  # topic, enc, schema
        self._segments: list[_Segment] = []
        self._counts: Counter[str] = Counter()
        self._damage: _Damage | None = None
        try:
            for idx, path in enumerate(self._files):
                self._index_file(idx, path)
        except _Damage as err:
            self._damage = err
        types: dict[str, set[str]] = {}
        for key, (topic, _, _) in self._channels.items():
            types.setdefault(topic, set()).add(self._msgtype(key))
        self.topics = {t: tuple(sorted(v)) for t, v in types.items()}
        self.counts = {t: self._counts.get(t, 0) for t in self.topics}
        if self._segments:
            self.start_ns = min(s.start_ns for s in self._segments)
            self.end_ns = max(s.end_ns for s in self._segments)
        how = (
            "read by a linear scan: all of it was readable"
            if self._damage is None
            else f"{self._damage.where()}; read by a linear scan up to there"
        )
        # A valid file written without a summary (streaming writers) is not damaged.
        self.damage = None if benign and self._damage is None else f"{reason}; {how}"

    def _msgtype(self, key: tuple[int, int]) -> str:
        schema = self._schemas.get((key[0], self._channels[key][2]))
        return _norm_type(schema.name) if schema is not None else "(no schema)"

    def _decoder(self, key: tuple[int, int]) -> _Codec | str:
        _, enc, schema_id = self._channels[key]
        schema = self._schemas.get((key[0], schema_id))
        return self._decoders.get(key, enc, schema, self._msgtype(key))

    def problem(self, topic: str) -> str | None:
        for key, (t, _, _) in self._channels.items():
            if t == topic and isinstance(found := self._decoder(key), str):
                return found
        return None

    def close(self) -> None:
        """Files are opened per read."""

    # -- the scan at open
    def _add(self, seg: _Segment, msgs: Sequence[_Msg]) -> None:
        if not msgs:
            return
        times = [m[0] for m in msgs]
        seg.start_ns, seg.end_ns = min(times), max(times)
        for m in msgs:
            topic = self._channels[m[2]][0]
            seg.topics.add(topic)
            self._counts[topic] += 1
        self._segments.append(seg)

    def _index_file(self, idx: int, path: Path) -> None:
        run: list[_Msg] = []
        span = [0, 0]  # byte range of the current run of loose messages

        def flush() -> None:
            if run:
                self._add(_Segment(idx, "run", span[0], span[1], 0, 0, set()), run)
                run.clear()

        try:
            for pos, op, length, body in self._records(path):
                if op == _OP_CHUNK:
                    flush()
                    if body is None:  # cut short: keep its complete messages (then _Damage)
                        seg = _Segment(idx, "partial", pos, pos, 0, 0, set())
                        self._add(seg, self._partial_chunk(idx, path, pos, self._tail(path, pos)))
                        continue
                    msgs, problem = self._chunk(idx, path, pos, body)
                    limit = len(msgs) if problem is not None else None
                    self._add(
                        _Segment(idx, "chunk", pos, pos + 9 + length, 0, 0, set(), limit), msgs
                    )
                    if problem is not None:
                        raise _Damage(path, pos, f"bad chunk: {problem}", truncated=False)
                elif body is not None:
                    msg = self._record(idx, path, pos, op, body)
                    if msg is not None:
                        if not run:
                            span[0] = pos
                        span[1] = pos + 9 + length
                        run.append((msg[1], len(run), msg[0], msg[2]))
                        if len(run) >= _RUN_MAX_MESSAGES or span[1] - span[0] >= _RUN_MAX_BYTES:
                            flush()
        finally:
            flush()

    @staticmethod
    def _tail(path: Path, pos: int) -> bytes:
        with path.open("rb") as f:
            f.seek(pos + 9)
            return f.read()

    @staticmethod
    def _records(path: Path) -> Iterator[tuple[int, int, int, bytes | None]]:
        """Top-level records (byte offset, opcode, length, body) up to the data end.

        A chunk record the file cuts short comes with body None (and then _Damage follows);
        any other damage raises _Damage.
        """
        try:
            size = path.stat().st_size
            f = path.open("rb")
        except OSError as err:
            raise _Damage(path, None, f"cannot be read: {err}", truncated=False) from err
        with f:
            head = f.read(8)
            if head != _MCAP_MAGIC:
                if len(head) < 8 and _MCAP_MAGIC.startswith(head):
                    raise _Damage(
                        path, len(head), "the file ends inside the MCAP magic", truncated=True
                    )
                raise _Damage(path, 0, "it does not start with the MCAP magic", truncated=False)
            pos = 8
            while True:
                hdr = f.read(9)
                if len(hdr) < 9:
                    detail = (
                        "the file ends without the data-end record and footer"
                        if not hdr
                        else "the file ends inside a record header"
                    )
                    raise _Damage(path, pos, detail, truncated=True)
                op, length = struct.unpack("<BQ", hdr)
                if op == 0 or 0x10 <= op < 0x80:
                    raise _Damage(path, pos, f"unknown record opcode 0x{op:02x}", truncated=False)
                avail = max(size - pos - 9, 0)
                if length > avail:
                    if op == _OP_CHUNK:
                        yield pos, op, length, None
                    raise _Damage(
                        path,
                        pos,
                        f"the record at byte {pos} (opcode 0x{op:02x}) needs {length} bytes, "
                        f"the file ends after {avail}",
                        truncated=True,
                    )
                if op in (_OP_DATA_END, _OP_FOOTER):
                    return
                if op in (_OP_CHUNK, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE):
                    body = f.read(length)
                    if len(body) != length:  # the file shrank while being read
                        raise _Damage(path, pos, "the file ends early", truncated=True)
                    yield pos, op, length, body
                else:
                    f.seek(length, os.SEEK_CUR)
                pos += 9 + length

    def _record(
        self, idx: int, path: Path, pos: int, op: int, body: bytes | memoryview
    ) -> tuple[tuple[int, int], int, memoryview] | None:
        """Parse a schema, channel or message record; return a message as (key, t, data)."""
        try:
            cur = _Cursor(body)
            if op == _OP_SCHEMA:
                sid = cur.u16()
                name, encoding = cur.string(), cur.string()
                data = bytes(cur.take(cur.u32()))
                schema = McapSchema(id=sid, name=name, encoding=encoding, data=data)
                self._schemas.setdefault((idx, sid), schema)
                self._decoders.add_schema(schema)
            elif op == _OP_CHANNEL:
                cid, sid = cur.u16(), cur.u16()
                topic, encoding = cur.string(), cur.string()
                self._channels.setdefault((idx, cid), (topic, encoding, sid))
            elif op == _OP_MESSAGE:
                cid = cur.u16()
                cur.take(4)  # sequence
                log_ns = cur.u64()
                cur.take(8)  # publish time
                if (idx, cid) not in self._channels:
                    raise ValueError(f"a message refers to channel {cid}, never defined")
                return (idx, cid), log_ns, cur.take(len(cur.buf) - cur.pos)
        except (ValueError, struct.error) as err:  # UnicodeDecodeError is a ValueError
            raise _Damage(
                path, pos, f"bad record (opcode 0x{op:02x}): {err}", truncated=False
            ) from err
        return None

    def _inner(
        self, idx: int, path: Path, pos: int, data: bytes | memoryview, *, partial: bool
    ) -> tuple[list[_Msg], str | None]:
        """Records of a chunk's payload: (messages in file order, problem or None)."""
        view = memoryview(data)
        msgs: list[_Msg] = []
        at = 0
        while at < len(view):
            if len(view) - at < 9:
                return msgs, "the chunk ends inside a record header"
            op, length = struct.unpack_from("<BQ", view, at)
            if length > len(view) - at - 9:
                return (
                    msgs,
                    f"a record in the chunk needs {length} bytes, {len(view) - at - 9} left",
                )
            if not partial and (op == 0 or 0x10 <= op < 0x80):
                return msgs, f"unknown record opcode 0x{op:02x} in the chunk"
            if op in (_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE):
                try:
                    msg = self._record(idx, path, pos, op, view[at + 9 : at + 9 + length])
                except _Damage as err:
                    return msgs, err.detail
                if msg is not None:
                    msgs.append((msg[1], len(msgs), msg[0], msg[2]))
            at += 9 + length
        return msgs, None

    def _chunk(self, idx: int, path: Path, pos: int, body: bytes) -> tuple[list[_Msg], str | None]:
        """Messages of a complete chunk record (file order), and a problem found after them.

        Raises:
            _Damage: The chunk cannot be decompressed or fails its CRC (nothing usable).
        """
        try:
            cur = _Cursor(body)
            cur.take(16)  # message start and end time
            usize, crc = cur.u64(), cur.u32()
            compression = cur.string()
            payload = cur.take(cur.u64())
            data = _decompress(compression, payload, usize)
        except Exception as err:  # any decoder failure is damage here
            raise _Damage(path, pos, f"bad chunk: {_short(err)}", truncated=False) from err
        if crc and zlib.crc32(data) != crc:
            raise _Damage(path, pos, "the chunk's CRC does not match its content", truncated=False)
        return self._inner(idx, path, pos, data, partial=False)

    def _partial_chunk(self, idx: int, path: Path, pos: int, body: bytes) -> list[_Msg]:
        """Complete messages at the start of an uncompressed chunk the file cuts short."""
        try:
            cur = _Cursor(body)
            cur.take(28)  # times, uncompressed size and CRC
            if cur.string() != "":
                return []  # a compressed chunk cut short cannot be decoded
            cur.take(8)
        except ValueError:
            return []
        msgs, _ = self._inner(idx, path, pos, memoryview(body)[cur.pos :], partial=True)
        return msgs

    # -- reading
    def _load(self, seg: _Segment) -> list[_Msg]:
        """The messages of a segment, sorted by log time (ties in file order)."""
        path = self._files[seg.file_idx]
        with path.open("rb") as f:
            f.seek(seg.offset)
            data = f.read(seg.stop - seg.offset if seg.kind != "partial" else -1)
        if seg.kind == "partial":
            msgs = self._partial_chunk(seg.file_idx, path, seg.offset, data[9:])
        elif seg.kind == "chunk":
            msgs, _ = self._chunk(seg.file_idx, path, seg.offset, data[9:])
            msgs = msgs[: seg.limit] if seg.limit is not None else msgs
        else:
            msgs = []
            view = memoryview(data)
            at = 0
            while at < len(view):
                op, length = struct.unpack_from("<BQ", view, at)
                if op == _OP_MESSAGE:
                    msg = self._record(
                        seg.file_idx, path, seg.offset + at, op, view[at + 9 : at + 9 + length]
                    )
                    if msg is not None:
                        msgs.append((msg[1], len(msgs), msg[0], msg[2]))
                at += 9 + length
        msgs.sort(key=lambda m: (m[0], m[1]))
        return msgs

    def _source(
        self, seg: _Segment, order: int, topics: frozenset[str]
    ) -> Iterator[tuple[int, int, int, Any, Any]]:
        yield seg.start_ns, order, -1, None, None  # placeholder: loads nothing until due
        for i, (log_ns, _, key, data) in enumerate(self._load(seg)):
            if self._channels[key][0] in topics:
                yield log_ns, order, i, key, data

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:
        segs = sorted((s for s in self._segments if s.topics & topics), key=lambda s: s.start_ns)
        sources = [self._source(s, i, topics) for i, s in enumerate(segs)]
        for log_ns, _, _, key, data in heapq.merge(*sources):
            if key is None:
                continue
            dec = self._decoder(key)
            if isinstance(dec, str):  # pragma: no cover - problem() ran before
                raise BagFormatError(dec)
            raw = _unzstd(data) if self._message_compression else bytes(data)
            yield self._channels[key][0], self._msgtype(key), log_ns, raw, dec
        if self._damage is not None:
            raise self._damage


def _unzstd(data: bytes | memoryview) -> bytes:
    parts: list[bytes] = []
    total = 0
    with zstandard.ZstdDecompressor().stream_reader(bytes(data)) as src:
        while piece := src.read(1 << 20):
            parts.append(piece)
            total += len(piece)
            if total > _MAX_CHUNK_BYTES:
                raise ValueError("a compressed message expands beyond 2 GiB")
    return b"".join(parts)


class _SqliteScanBackend(_Backend):
    """rosbag2 SQLite3 files read with the sqlite3 module row by row, up to the damage.

    The connection is read-only and immutable, with ``writable_schema`` on so that SQLite
    takes the pages the file really has instead of refusing a file shorter than its header
    says. Rows come in log-time order through the timestamp index; if the index is damaged
    and the table scan reaches further, rows come in insertion (rowid) order instead, which
    is the recorder's write order.
    """

    indexed = False
    storage = STORAGE_SQLITE3

    def __init__(
        self, files: Sequence[Path], shown: Path, *, reason: str, message_compression: bool
    ) -> None:
        super().__init__()
        self.shown = shown
        self._files = list(files)
        self._message_compression = message_compression
        self._topic_of: dict[tuple[int, int], tuple[str, str]] = {}
        self._definitions: list[tuple[str, str, str]] = []
        self._store: Typestore | None = None
        self._tick = [time.monotonic()]
        self._order = "timestamp"
        counts, damage, n, span = self._prescan()
        if damage is not None:
            self._order = "rowid"  # the table scan may reach rows the time index cannot
            counts2, damage2, n2, span2 = self._prescan()
            if n2 > n:
                counts, damage, span = counts2, damage2, span2
                self.ordered = False
            else:
                self._order = "timestamp"
        self.start_ns, self.end_ns = span
        self._damage = damage
        types: dict[str, set[str]] = {}
        for topic, msgtype in self._topic_of.values():
            types.setdefault(topic, set()).add(_norm_type(msgtype))
        self.topics = {t: tuple(sorted(v)) for t, v in types.items()}
        self.counts = {t: counts.get(t, 0) for t in self.topics}
        how = (
            "read row by row: all of it was readable"
            if damage is None
            else f"{damage.where()}; read row by row up to there"
            + (" (in insertion order: the time index is damaged)" if self._order == "rowid" else "")
        )
        self.damage = f"{reason}; {how}"

    def _prescan(self) -> tuple[Counter[str], _Damage | None, int, tuple[int | None, int | None]]:
        counts: Counter[str] = Counter()
        start: int | None = None
        end: int | None = None
        try:
            for key, log_ns, _ in self._rows(None):
                counts[self._topic_of[key][0]] += 1
                start = log_ns if start is None else min(start, log_ns)
                end = log_ns if end is None else max(end, log_ns)
        except _Damage as err:
            return counts, err, sum(counts.values()), (start, end)
        return counts, None, sum(counts.values()), (start, end)

    def _connect(self, path: Path) -> sqlite3.Connection:
        uri = f"file:{quote(str(path.resolve()))}?mode=ro&immutable=1"
        conn = sqlite3.connect(uri, uri=True)
        tick = self._tick

        def stalled() -> int:
            return int(time.monotonic() - tick[0] > _SQLITE_STALL_S)

        conn.set_progress_handler(stalled, 10_000)
        conn.execute("PRAGMA writable_schema = ON")  # use the pages the file has (read-only)
        return conn

    def _rows(self, topics: frozenset[str] | None) -> Iterator[tuple[tuple[int, int], int, bytes]]:
        for idx, path in enumerate(self._files):
            yield from self._file_rows(idx, path, topics)

    def _file_rows(
        self, idx: int, path: Path, topics: frozenset[str] | None
    ) -> Iterator[tuple[tuple[int, int], int, bytes]]:
        self._tick[0] = time.monotonic()
        try:
            conn = self._connect(path)
        except sqlite3.Error as err:
            raise _Damage(path, None, f"SQLite: {err}", truncated=False) from err
        try:
            kinds = dict(
                conn.execute(
                    "SELECT name, type FROM sqlite_master WHERE name IN ('messages', 'topics')"
                ).fetchall()
            )
            if kinds.get("messages") != "table" or kinds.get("topics") != "table":
                raise _Damage(
                    path, None, "no rosbag2 'messages' and 'topics' tables", truncated=False
                )
            for tid, name, msgtype in conn.execute("SELECT id, name, type FROM topics"):
                if not (
                    isinstance(tid, int) and isinstance(name, str) and isinstance(msgtype, str)
                ):
                    raise _Damage(path, None, "the topics table is damaged", truncated=False)
                self._topic_of.setdefault((idx, tid), (name, msgtype))
            has_defs = conn.execute(
                "SELECT count(*) FROM sqlite_master "
                "WHERE type = 'table' AND name = 'message_definitions'"
            ).fetchone()[0]
            if has_defs and not self._definitions:
                for row in conn.execute(
                    "SELECT topic_type, encoding, encoded_message_definition "
                    "FROM message_definitions"
                ):
                    self._definitions.append((str(row[0]), str(row[1]), str(row[2])))
            ids = [
                k[1]
                for k, v in self._topic_of.items()
                if k[0] == idx and (topics is None or v[0] in topics)
            ]
            if not ids:
                return
            marks = ",".join("?" * len(ids))
            order = "timestamp" if self._order == "timestamp" else "rowid"
            # Only '?' marks and a fixed ORDER BY are formatted into the query.
            cursor = conn.execute(
                f"SELECT topic_id, timestamp, data FROM messages "
                f"WHERE topic_id IN ({marks}) ORDER BY {order}",
                ids,
            )
            while True:
                self._tick[0] = time.monotonic()
                row = cursor.fetchone()
                if row is None:
                    break
                tid, log_ns, data = row
                key = (idx, tid)
                if key not in self._topic_of or not isinstance(log_ns, int):
                    raise _Damage(
                        path, None, "a row does not fit the rosbag2 schema", truncated=False
                    )
                if not isinstance(data, bytes):
                    raise _Damage(path, None, "a message row holds no data blob", truncated=False)
                yield key, log_ns, data
        except sqlite3.Error as err:
            raise _Damage(path, None, f"SQLite: {err}", truncated=False) from err
        finally:
            conn.close()

    def _decode(self, msgtype: str) -> _Codec | None:
        if self._store is None or msgtype not in self._store.fielddefs:
            wanted = {t for _, t in self._topic_of.values()}
            self._store = _typestore_from(self._definitions, wanted)
        store = self._store
        if msgtype not in store.fielddefs:
            return None
        return _Codec(
            lambda data: store.deserialize_cdr(data, msgtype), msgtype, lambda: store.fielddefs
        )

    def problem(self, topic: str) -> str | None:
        for t, msgtype in self._topic_of.values():
            if t == topic and self._decode(msgtype) is None:
                return _unknown_type(msgtype)
        return None

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:
        decoders: dict[str, _Codec | None] = {}
        for key, log_ns, data in self._rows(topics):
            topic, msgtype = self._topic_of[key]
            if msgtype not in decoders:
                decoders[msgtype] = self._decode(msgtype)
            dec = decoders[msgtype]
            if dec is None:  # pragma: no cover - problem() ran before
                raise BagFormatError(_unknown_type(msgtype))
            raw = _unzstd(data) if self._message_compression else data
            yield topic, _norm_type(msgtype), log_ns, raw, dec
        if self._damage is not None:
            raise self._damage

    def close(self) -> None:
        """Connections are closed after each read."""


# --------------------------------------------------------------------------- opening


def _load_metadata(bagdir: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping of a bag's metadata.yaml, checked."""
    meta = bagdir / "metadata.yaml"
    hint = (
        f"restore {meta} (`ros2 bag reindex {bagdir}` regenerates it), or open the storage "
        "file inside the directory directly"
    )
    try:
        doc = yaml.safe_load(meta.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise BagFormatError(
            f"bag {bagdir}: cannot read {meta.name} ({_short(err)}); {hint}"
        ) from err
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    problem = None
    if not isinstance(info, dict):
        problem = "it has no 'rosbag2_bagfile_information' mapping"
    elif info.get("storage_identifier") not in (STORAGE_MCAP, STORAGE_SQLITE3):
        problem = (
            f"storage {info.get('storage_identifier')!r} is not supported "
            f"(only {STORAGE_MCAP!r} and {STORAGE_SQLITE3!r})"
        )
    elif not isinstance(files := info.get("relative_file_paths"), list) or not all(
        isinstance(x, str) and x for x in files
    ):
        problem = "'relative_file_paths' is not a list of file names"
    if problem is not None:
        raise BagFormatError(
            f"bag {bagdir}: {meta.name} is not rosbag2 metadata: {problem}; {hint}"
        )
    assert isinstance(info, dict)
    return info


def _bag_files(bagdir: Path, info: Mapping[str, Any]) -> list[Path]:
    return [bagdir / PurePath(x).name for x in info["relative_file_paths"]]


def _open_rosbag2(bagdir: Path, info: Mapping[str, Any] | None = None) -> _Backend:
    info = _load_metadata(bagdir) if info is None else info
    storage = str(info["storage_identifier"])
    files = _bag_files(bagdir, info)
    if missing := [f.name for f in files if not f.is_file()]:
        raise BagFormatError(
            f"bag {bagdir}: metadata.yaml lists {', '.join(missing)}, which "
            f"{'is' if len(missing) == 1 else 'are'} not in the directory: the bag is incomplete; "
            "copy the missing files, or open a storage file on its own"
        )
    mode = str(info.get("compression_mode") or "").lower()
    try:
        return _RosbagsBackend(bagdir, storage, bagdir)
    except Exception as err:  # any failure of the index path: scan instead
        reason = _why(err)
        if mode == "file":
            raise BagCorruptError(
                f"bag {bagdir} cannot be read: {reason}; its files are compressed whole, so "
                f"nothing can be recovered by a scan: {_REPAIR_HINT}"
            ) from err
        if storage == STORAGE_MCAP:
            if any(not _is_mcap(_head(f), f) for f in files):
                raise BagFormatError(
                    f"bag {bagdir}: metadata.yaml says MCAP storage but its files are not MCAP "
                    f"({reason})"
                ) from err
            return _McapScanBackend(
                files, STORAGE_MCAP, bagdir, reason=reason, message_compression=mode == "message"
            )
        return _SqliteScanBackend(
            files, bagdir, reason=reason, message_compression=mode == "message"
        )


def _why(err: Exception) -> str:
    """Why the index path failed, for ``info.damage``."""
    if isinstance(err, _NeedScan):
        return str(err)
    return f"its index could not be read ({_short(err)})"


def _head(path: Path) -> bytes:
    try:
        with path.open("rb") as f:
            return f.read(16)
    except OSError as err:
        raise BagFormatError(
            f"{path} cannot be read ({_short(err)}): check its permissions"
        ) from err


def _is_mcap(head: bytes, path: Path) -> bool:
    if head.startswith(_MCAP_MAGIC):
        return True
    return path.suffix == ".mcap" and _MCAP_MAGIC.startswith(head)


def _is_sqlite(head: bytes, path: Path) -> bool:
    if head.startswith(_SQLITE_MAGIC):
        return True
    return path.suffix == ".db3" and _SQLITE_MAGIC.startswith(head)


def _open_file(path: Path) -> _Backend:  # noqa: PLR0911 - one return per kind of file
    head = _head(path)
    meta = path.parent / "metadata.yaml"
    in_bag = meta.is_file()
    if in_bag:
        try:
            info = _load_metadata(path.parent)
        except BagFormatError:
            info = None  # a broken metadata.yaml: read the file on its own
        if info is not None and [f.name for f in _bag_files(path.parent, info)] == [path.name]:
            return _open_rosbag2(path.parent, info)
    if _is_mcap(head, path):
        if in_bag:
            try:
                return _RosbagsBackend(path, STORAGE_MCAP, path)
            except Exception as err:  # scan instead
                return _McapScanBackend(
                    [path],
                    STORAGE_MCAP,
                    path,
                    reason=_why(err),
                )
        try:
            return _PlainMcapBackend(path)
        except _NeedScan as err:  # no usable summary: scan instead
            return _McapScanBackend(
                [path], STORAGE_MCAP_PLAIN, path, reason=str(err), benign=err.benign
            )
        except Exception as err:  # an unreadable summary: scan instead
            why = _why(err)
            return _McapScanBackend([path], STORAGE_MCAP_PLAIN, path, reason=why)
    if _is_sqlite(head, path):
        if path.suffix == ".db3":
            try:
                return _RosbagsBackend(path, STORAGE_SQLITE3, path)
            except Exception as err:  # scan instead
                reason = _why(err)
        else:
            reason = "a SQLite3 file without the .db3 suffix"
        return _SqliteScanBackend([path], path, reason=reason, message_compression=False)
    raise BagFormatError(
        f"{path} is not a bag: it is neither MCAP nor SQLite3 (it starts with {head[:8]!r}); "
        "pass a rosbag2 directory (with metadata.yaml), an .mcap file or a .db3 file"
    )


def _open_backend(path: Path) -> _Backend:
    try:
        exists = path.exists()
        is_dir = path.is_dir()
    except OSError as err:  # e.g. a name too long
        raise BagFormatError(f"{path} cannot be accessed ({_short(err)})") from err
    if not exists:
        raise BagNotFoundError(
            f"bag {path} does not exist: pass a rosbag2 directory (with metadata.yaml), the "
            ".mcap/.db3 file inside one, or a plain .mcap file"
        )
    if is_dir:
        if not (path / "metadata.yaml").is_file():
            storage_files = sorted(
                p.name for p in path.iterdir() if p.suffix in (".mcap", ".db3") and p.is_file()
            )
            hint = (
                f"; it holds {', '.join(storage_files[:5])}: open such a file directly, or "
                f"regenerate the metadata with `ros2 bag reindex {path}`"
                if storage_files
                else ""
            )
            raise BagFormatError(
                f"{path} is a directory but not a rosbag2 bag: no metadata.yaml{hint}"
            )
        return _open_rosbag2(path)
    if path.name == "metadata.yaml":
        return _open_rosbag2(path.parent)
    return _open_file(path)


# --------------------------------------------------------------------------- the reader


class BagReader:
    """An open bag: :attr:`info`, :meth:`check_topics` and the :meth:`messages` stream.

    Topic names are matched exactly, and a relative name also matches its absolute form in
    the root namespace (``height`` finds ``/height``, as rosbag2 records it);
    :meth:`resolve_topic` tells which. Create with :func:`open_bag`.

    Attributes:
        info: what the bag holds (see :class:`BagInfo`).
    """

    def __init__(self, path: str | Path) -> None:
        """Open ``path`` (see :func:`open_bag`)."""
        self._closed = True
        bag = Path(path)
        try:
            self._backend = _open_backend(bag)
        except BagError:
            raise
        except OSError as err:
            raise BagFormatError(
                f"{bag} cannot be read ({_short(err)}): check that it is readable"
            ) from err
        except Exception as err:  # whatever a library raises on garbage
            raise BagCorruptError(
                f"bag {bag} cannot be read ({_short(err)}): {_REPAIR_HINT}"
            ) from err
        self._closed = False
        b = self._backend
        self.info = BagInfo(
            path=b.shown,
            storage=b.storage,
            topics={t: " | ".join(v) for t, v in sorted(b.topics.items())},
            message_counts={t: b.counts.get(t, 0) for t in sorted(b.topics)},
            start_ns=b.start_ns,
            end_ns=b.end_ns,
            damage=b.damage,
        )

    # -- context manager
    def __enter__(self) -> Self:
        """Return the reader itself."""
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Close the bag."""
        self.close()

    def close(self) -> None:
        """Release the bag's files (idempotent)."""
        if not self._closed:
            self._closed = True
            with contextlib.suppress(Exception):  # closing a damaged file must not raise
                self._backend.close()

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f"bag {self.info.path} is closed: use it inside `with open_bag(...)`")

    # -- topics
    def resolve_topic(self, name: str) -> str | None:
        """The bag's name for a requested topic (``x`` also finds ``/x``), or None."""
        topics = self._backend.topics
        if name in topics:
            return name
        if not name.startswith("/") and f"/{name}" in topics:
            return f"/{name}"
        return None

    def _listing(self) -> str:
        if not self.info.topics:
            return "no topics"
        return ", ".join(
            f"{t} ({ty}, {self.info.message_counts.get(t, 0)} messages)"
            for t, ty in self.info.topics.items()
        )

    def _damage_note(self) -> str:
        return f" (the bag is damaged: {self.info.damage})" if self.info.damage else ""

    def _total(self) -> int:
        return sum(self.info.message_counts.values())

    def _raise_if_empty(self) -> None:
        if self._total() == 0 and self.info.damage is None:
            raise BagEmptyError(
                f"bag {self.info.path} holds no messages ({self._listing()}): nothing to read; "
                "check that the recorder received data on the topics before it stopped"
            )

    def _missing_error(
        self, missing: Sequence[str], *, empty: Sequence[str] = ()
    ) -> TopicMissingError:
        parts = []
        for name in missing:
            if name in empty:
                parts.append(f"{name!r} (recorded, but it holds no readable message)")
            else:
                parts.append(repr(name))
        return TopicMissingError(
            f"bag {self.info.path} lacks topic(s) {', '.join(parts)}; it has: {self._listing()}"
            f"{self._damage_note()}. Map the streams to the bag's topic names, or record the "
            "missing topics",
            missing,
            self.info.topics,
        )

    def check_topics(self, expected: Mapping[str, str | tuple[str, ...]]) -> None:
        """Check that the bag has the expected topics with an accepted type.

        Args:
            expected: topic name -> accepted message type(s).

        Raises:
            BagEmptyError: The bag (undamaged) holds no message at all.
            TopicMissingError: Some topics are absent or hold no message (all are named).
            TopicTypeError: A topic carries another type (the first such topic).
        """
        self._check_open()
        self._raise_if_empty()
        missing: list[str] = []
        empty: list[str] = []
        for name in expected:
            found = self.resolve_topic(name)
            if found is None:
                missing.append(name)
            elif self._backend.counts.get(found, 0) == 0:
                missing.append(name)
                empty.append(name)
        if missing:
            raise self._missing_error(missing, empty=empty)
        for name, accepted in expected.items():
            ok = tuple(
                _norm_type(t) for t in ((accepted,) if isinstance(accepted, str) else accepted)
            )
            bag_name = self.resolve_topic(name)
            assert bag_name is not None
            found_types = self._backend.topics[bag_name]
            if any(t not in ok for t in found_types):
                found = " | ".join(found_types)
                raise TopicTypeError(
                    f"bag {self.info.path}: topic {bag_name!r} carries {found}, expected "
                    f"{' or '.join(ok)}; map the stream to a topic of that type",
                    name,
                    found,
                    ok,
                )

    # -- messages
    def _wanted(self, topics: Sequence[str]) -> dict[str, str]:
        """Bag topic -> requested name, after the checks :meth:`messages` documents."""
        self._check_open()
        names = [topics] if isinstance(topics, str) else list(dict.fromkeys(topics))
        self._raise_if_empty()
        wanted: dict[str, str] = {}
        missing = []
        for name in names:
            found = self.resolve_topic(name)
            if found is None:
                missing.append(name)
            else:
                wanted.setdefault(found, name)
        if missing:
            raise self._missing_error(missing)
        for bag_name in wanted:
            try:
                problem = self._backend.problem(bag_name)
            except Exception as err:  # a broken stored definition
                problem = f"its definition cannot be used ({_short(err)})"
            if problem is not None:
                raise BagFormatError(
                    f"bag {self.info.path}: topic {bag_name!r} cannot be decoded: {problem}"
                )
        return wanted

    def messages(self, topics: Sequence[str]) -> Iterator[BagMessage]:
        """Stream the decoded messages of ``topics`` in log-time order.

        Memory stays bounded whatever the bag's length. On a damaged bag every message
        readable before the damage is yielded first, then :class:`BagCorruptError` is raised.
        (One exception: a SQLite3 file whose time index is damaged is read in insertion
        order, the recorder's write order; ``info.damage`` says so.)

        Args:
            topics: topic names (a single string is one topic).

        Raises:
            BagEmptyError: The bag (undamaged) holds no message at all.
            TopicMissingError: A topic is not in the bag (checked at the call).
            BagFormatError: A topic's messages cannot be decoded (unknown type, not CDR).
            BagCorruptError: While iterating, at the first unreadable data.
        """
        return self._stream(self._wanted(topics))

    def field_batches(
        self, topics: Sequence[str], fields: Mapping[str, Sequence[str]], *, size: int = 4096
    ) -> Iterator[FieldBatch]:
        """Stream the header stamps and float fields of ``topics``, many messages at a time.

        The same messages, in the same order, with the same errors as :meth:`messages`,
        reduced to ``header.stamp`` (ns) and the requested fields (``float(msg.<field>)``).
        Messages of a type whose definition is ``std_msgs/Header header`` followed by
        float64 fields (e.g. sensor_msgs/FluidPressure and Temperature) are decoded in bulk
        with numpy; any message that does not fit that layout goes through the generic
        deserialiser, as in :meth:`messages`.

        Args:
            topics: topic names.
            fields: requested topic name -> names of float fields to read (a topic not
                listed reads none).
            size: messages per batch, at most.

        Raises:
            BagEmptyError, TopicMissingError, BagFormatError, BagCorruptError: as
                :meth:`messages`.
        """
        wanted = self._wanted(topics)
        return self._field_stream(wanted, fields, max(1, size))

    def _corrupt(
        self, what: str, read: int, last: int | None, offset: int | None
    ) -> BagCorruptError:
        got = f"{read} message(s) read" + (
            f", the last at t={_fmt_ns(last)}" if last is not None else ""
        )
        used = (
            "the messages before it were delivered"
            if read
            else "no message of the requested topics could be read"
        )
        return BagCorruptError(
            f"bag {self.info.path}: {what} ({got}): the recording was interrupted or the file "
            f"was damaged; {used}. To get more: {_REPAIR_HINT}",
            messages_read=read,
            last_good_ns=last,
            offset=offset,
        )

    def _undecodable(self, err: Exception, read: int, last: int | None) -> BagCorruptError:
        return self._corrupt(
            f"the data cannot be read past this point ({_short(err)})", read, last, None
        )

    def _raw_batches(self, wanted: dict[str, str], size: int) -> Iterator[_RawBatch]:
        """The undecoded messages in batches; the checks and errors of :meth:`messages`.

        An error is raised after the batch of the messages read before it.
        """
        backend = self._backend
        it = backend.iter(frozenset(wanted))
        read = 0
        last: int | None = None
        per_topic: Counter[str] = Counter()
        failure: BagError | None = None
        cause: BaseException | None = None
        ordered = backend.ordered
        try:
            while failure is None:
                self._check_open()
                batch = _RawBatch([], [], [], [], [])
                add_topic, add_type = batch.topic.append, batch.msgtype.append
                add_time, add_data = batch.log_time_ns.append, batch.data.append
                add_codec = batch.codec.append
                prev = last
                try:
                    for topic, msgtype, t, data, codec in it:
                        if ordered and prev is not None and t < prev:
                            failure = self._corrupt(
                                f"its index is inconsistent: log time goes back from "
                                f"{_fmt_ns(prev)} to {_fmt_ns(t)}",
                                read + len(batch.topic),
                                prev,
                                None,
                            )
                            break
                        add_topic(topic)
                        add_type(msgtype)
                        add_time(t)
                        add_data(data)
                        add_codec(codec)
                        prev = t
                        if len(batch.topic) >= size:
                            break
                except _Damage as err:
                    failure, cause = (
                        self._corrupt(err.where(), read + len(batch), prev, err.offset),
                        err,
                    )
                except BagError:
                    raise
                except Exception as err:  # any library error is damage here
                    failure, cause = self._undecodable(err, read + len(batch), prev), err
                n = len(batch)
                if n:
                    read += n
                    last = prev
                    per_topic.update(batch.topic)
                    yield batch
                if n < size:
                    break
            if failure is not None:
                raise failure from cause
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                with contextlib.suppress(Exception):  # the stream is being abandoned
                    close()
        if backend.indexed:
            short = {t: (per_topic[t], backend.counts.get(t, 0)) for t in wanted}
            short = {t: v for t, v in short.items() if v[0] < v[1]}
            if short:
                detail = ", ".join(f"{t}: {got} of {want}" for t, (got, want) in short.items())
                raise self._corrupt(
                    f"fewer messages could be read than its index lists ({detail})",
                    read,
                    last,
                    None,
                )

    def _stream(self, wanted: dict[str, str]) -> Iterator[BagMessage]:
        read = 0
        last: int | None = None
        for batch in self._raw_batches(wanted, 256):
            for topic, msgtype, t, data, codec in zip(
                batch.topic, batch.msgtype, batch.log_time_ns, batch.data, batch.codec, strict=True
            ):
                self._check_open()
                try:
                    msg = codec.decode(data)
                except BagError:
                    raise
                except Exception as err:  # an undecodable message is damage here
                    raise self._undecodable(err, read, last) from err
                yield BagMessage(wanted[topic], msgtype, t, msg)
                read += 1
                last = t

    def _field_stream(
        self, wanted: dict[str, str], fields: Mapping[str, Sequence[str]], size: int
    ) -> Iterator[FieldBatch]:
        names = tuple(dict.fromkeys(wanted.values()))
        index = {bag: names.index(name) for bag, name in wanted.items()}
        spec = {bag: tuple(fields.get(name, ())) for bag, name in wanted.items()}
        width = max((len(v) for v in spec.values()), default=0)
        read = 0
        last: int | None = None
        for batch in self._raw_batches(wanted, size):
            self._check_open()
            out, failure = _decode_fields(batch, index, spec, width, names)
            if len(out):
                yield out
                read += len(out)
                last = int(out.log_time_ns[-1])
            if failure is not None:
                raise self._undecodable(failure, read, last) from failure


def _decode_fields(
    batch: _RawBatch,
    index: dict[str, int],
    spec: dict[str, tuple[str, ...]],
    width: int,
    names: tuple[str, ...],
) -> tuple[FieldBatch, Exception | None]:
    """One raw batch as a FieldBatch; the first message that cannot be decoded ends it."""
    n = len(batch)
    stamps = np.zeros(n, dtype=np.int64)
    values = np.full((n, width), np.nan)
    datas, codecs = batch.data, batch.codec
    # groups of messages with the same codec and size, each in message order
    codec_ids = np.fromiter(map(id, codecs), dtype=np.uint64, count=n)
    sizes = np.fromiter(map(len, datas), dtype=np.int64, count=n)
    order = np.lexsort((sizes, codec_ids))
    cuts = np.flatnonzero((np.diff(codec_ids[order]) != 0) | (np.diff(sizes[order]) != 0)) + 1
    slow = np.ones(n, dtype=bool)
    for rows in np.split(order, cuts):
        first = int(rows[0])
        got = _fixed_layout(
            [datas[i] for i in rows.tolist()], codecs[first], spec[batch.topic[first]]
        )
        if got is not None:
            ok, group_stamps, group_values = got
            done = rows[ok]
            stamps[done] = group_stamps[ok]
            values[done, : group_values.shape[1]] = group_values[ok]
            slow[done] = False
    failure: Exception | None = None
    for i in np.flatnonzero(slow).tolist():
        try:
            msg = codecs[i].decode(datas[i])
        except BagError:
            raise
        except Exception as err:  # an undecodable message is damage here
            failure = err
            n = i
            break
        stamps[i] = _header_stamp_ns(msg)
        for j, name in enumerate(spec[batch.topic[i]]):
            values[i, j] = float(getattr(msg, name))
    topic = np.fromiter(map(index.__getitem__, batch.topic[:n]), dtype=np.intp, count=n)
    log = np.array(batch.log_time_ns[:n], dtype=np.int64)
    fast = n - int(np.count_nonzero(slow[:n]))
    return FieldBatch(names, topic, log, stamps[:n], values[:n], fast), failure


def _fixed_layout(
    datas: list[Any], codec: _Codec, wanted: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Bulk decoding of one group (same codec, same size): (ok, stamps, values)."""
    layout = codec.layout()
    if layout is None or any(f not in layout for f in wanted) or len(datas) < 2:
        return None
    got = _fixed_layout_rows(datas, len(layout))
    if got is None:
        return None
    stamps, values, ok = got
    try:  # the first message, through the generic deserialiser, must read the same
        msg = codec.decode(datas[0])
        same = _header_stamp_ns(msg) == int(stamps[0]) and np.array_equal(
            np.array([float(getattr(msg, f)) for f in layout]).view(np.int64),
            values[0].view(np.int64),
        )
    except Exception:  # undecodable: the generic path finds and reports it
        return None
    if not same:
        return None
    return ok, stamps, values[:, [layout.index(f) for f in wanted]]
