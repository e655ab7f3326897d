"""CDR decoding: type stores, stored definitions, per-channel codecs and the bulk decoder.

Custom types are rebuilt from the definitions stored in the bag (``_typestore_from``). Where
a bag carries none (SQLite3 bags of ROS 2 Humble and older), the ROS 2 Kilted types and this
package's ``twotank_validation_msgs`` (from ``<sys.prefix>/share/twotank_validation_msgs/msg``,
a colcon prefix in ``AMENT_PREFIX_PATH``, or the repository's ``msg/``) are used instead
(``_default_fielddefs``, ``_fill_defaults``). A :class:`_Codec` decodes one channel's
messages (rosbags, or mcap_ros2 for plain MCAP files; :class:`_Decoders` chooses per
channel). ``_decode_fields`` reduces a :class:`_RawBatch` of undecoded messages to a
:class:`~twotank_validation.bags.records.FieldBatch`: in bulk with numpy
(``_fixed_layout_rows``) where the type is ``std_msgs/Header header`` followed by float64
fields, through the generic deserialiser otherwise.

This module imports rosbags and mcap-ros2-support, never rclpy.
"""

from __future__ import annotations

import contextlib
import functools
import io
import os
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
from mcap.records import Schema as McapSchema
from mcap_ros2.decoder import DecoderFactory
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from twotank_validation.bags.bag_errors import BagError
from twotank_validation.bags.records import FieldBatch
from twotank_validation.defaults import NS_PER_S

_MSG_PACKAGE: Final = "twotank_validation_msgs"
_OWN_TYPES: Final = ("FlowCommand", "ValidationReport")


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


# --------------------------------------------------------------------------- columns

_MAX_PATTERNS: Final = 8  # distinct headers read in bulk per group; more go generically
_ENCAPSULATION: Final = {(0, 1): "<", (0, 0): ">"}  # CDR little / big endian


def _layout_rows(rows: np.ndarray, n_floats: int) -> tuple[str, int, np.ndarray] | None:
    """Where the stamp and the float64 fields of ``rows`` (m, size) sit, read off row 0.

    Returns ``(byte order, offset of the first float64, fixed)`` where ``fixed`` (size,) bool
    marks every byte that is neither the stamp nor a float64 field, or None if row 0 is not
    ``Header header`` + ``n_floats`` float64 in CDR (encapsulation, a terminated frame_id,
    the floats 8-aligned after it and nothing after them).
    """
    size = rows.shape[1]
    if size < 16:
        return None
    order = _ENCAPSULATION.get((int(rows[0, 0]), int(rows[0, 1])))
    if order is None:
        return None
    strlen = int(rows[0, 12:16].view(f"{order}u4")[0])
    at = 4 + ((12 + strlen + 7) & ~7)  # first float64, 8-aligned after the frame_id
    if strlen < 1 or at + 8 * n_floats != size:
        return None
    fixed = np.ones(size, dtype=bool)
    fixed[4:12] = False
    fixed[at:] = False
    return order, at, fixed


def _bulk_group(
    rows: np.ndarray, codec: _Codec, n_floats: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Decode equal-size messages of one codec in bulk, header by header.

    Rows are grouped by their bytes outside the stamp and the float64 fields (encapsulation,
    frame_id, padding): within such a group the generic deserialiser reads every message
    alike, so it decodes the group's first message and the others are read at the same
    offsets with numpy (the stamp as int32 sec + uint32 nanosec, the floats as float64, in
    the encapsulation's byte order). A group whose first message the generic deserialiser
    reads otherwise (or refuses) is left to it, message by message.

    Args:
        rows: (m, size) uint8, the messages' CDR bytes.
        codec: their codec (``codec.layout()`` gives ``n_floats`` names).
        n_floats: float64 fields after the header.

    Returns:
        ``(ok (m,) bool, stamp_ns (m,) int64, values (m, n_floats) float64)``: the rows read
        in bulk and their stamps and fields (meaningless where not ok).
    """
    m, size = rows.shape
    ok = np.zeros(m, dtype=bool)
    stamps = np.zeros(m, dtype=np.int64)
    values = np.zeros((m, n_floats))
    todo = np.ones(m, dtype=bool)
    names = codec.layout() or ()
    for _ in range(_MAX_PATTERNS):
        left = np.flatnonzero(todo)
        if len(left) == 0:
            break
        first = int(left[0])
        got = _layout_rows(rows[first : first + 1], n_floats)
        if got is None:  # the encapsulation and frame_id length of the first: generic
            if size < 16:
                break
            head = np.r_[0:4, 12:16]
            same = (rows[np.ix_(left, head)] == rows[first, head]).all(axis=1)
            todo[left[same]] = False
            continue
        order, at, fixed = got
        part = rows[left]
        same = (part[:, fixed] == rows[first, fixed]).all(axis=1)
        members = left[same]
        todo[members] = False
        block = np.ascontiguousarray(rows[members])
        k = len(members)
        sec = np.ndarray((k,), dtype=f"{order}i4", buffer=block, offset=4, strides=(size,))
        nsec = np.ndarray((k,), dtype=f"{order}u4", buffer=block, offset=8, strides=(size,))
        vals = np.ndarray(
            (k, n_floats), dtype=f"{order}f8", buffer=block, offset=at, strides=(size, 8)
        ).astype(np.float64)
        st = sec.astype(np.int64) * NS_PER_S + nsec.astype(np.int64)
        try:  # the first of them, through the generic deserialiser, must read the same
            msg = codec.decode(rows[first].tobytes())
            agree = _header_stamp_ns(msg) == int(st[0]) and np.array_equal(
                np.array([float(getattr(msg, f)) for f in names]).view(np.int64),
                vals[0].view(np.int64),
            )
        except Exception:  # undecodable: the generic path finds and reports it
            agree = False
        if agree:
            ok[members] = True
            stamps[members] = st
            values[members] = vals
    return ok, stamps, values


def _decode_columns(
    cols: Any,
    index: Mapping[str, int],
    spec: Mapping[str, tuple[str, ...]],
    width: int,
    names: tuple[str, ...],
) -> tuple[FieldBatch, Exception | None]:
    """Columns of undecoded messages as a FieldBatch; the first undecodable message ends it.

    ``cols`` is a :class:`~twotank_validation.bags.columnar._Columns`. Messages of a channel
    whose type is ``Header header`` + float64 fields are grouped by size and decoded in bulk
    (:func:`_bulk_group`); the rest go through the channel's generic deserialiser, in
    message order. The same stamps and values, bit for bit, as the generic deserialiser.
    """
    n = len(cols)
    stamps = np.zeros(n, dtype=np.int64)
    values = np.full((n, width), np.nan)
    chans = cols.channels
    slow = np.ones(n, dtype=bool)
    if n:
        key = cols.chan.astype(np.int64) * (len(cols.bufs) + 1) + cols.buf
        order = np.lexsort((cols.size, key))
        ks, ss = key[order], cols.size[order]
        cuts = np.flatnonzero((ks[1:] != ks[:-1]) | (ss[1:] != ss[:-1])) + 1
        for rows in np.split(order, cuts):
            first = int(rows[0])
            topic, _, codec = chans[int(cols.chan[first])]
            wanted = spec[topic]
            layout = codec.layout()
            if layout is None or any(f not in layout for f in wanted) or len(rows) < 2:
                continue
            size = int(cols.size[first])
            buf = cols.bufs[int(cols.buf[first])]
            windows = np.lib.stride_tricks.sliding_window_view(buf, size)  # a view, no copy
            block = windows[cols.start[rows]]
            ok, group_stamps, group_values = _bulk_group(block, codec, len(layout))
            done = rows[ok]
            stamps[done] = group_stamps[ok]
            pick = [layout.index(f) for f in wanted]
            values[done, : len(pick)] = group_values[ok][:, pick]
            slow[done] = False
    if cols.beyond is not None:
        slow[cols.beyond] = True
    failure: Exception | None = None
    for i in np.flatnonzero(slow).tolist():
        topic, _, codec = chans[int(cols.chan[i])]
        try:
            msg = codec.decode(cols.data(i))
        except BagError:
            raise
        except Exception as err:  # an undecodable message is damage here
            failure = err
            n = i
            break
        if cols.beyond is not None and cols.beyond[i]:
            failure = OverflowError("a log time past 2**63 ns (the year 2262)")
            n = i
            break
        stamps[i] = _header_stamp_ns(msg)
        for j, name in enumerate(spec[topic]):
            values[i, j] = float(getattr(msg, name))
    chan_topic = np.array([index[c[0]] for c in chans], dtype=np.intp)
    topic_idx = chan_topic[cols.chan[:n]] if n else np.zeros(0, dtype=np.intp)
    log = np.asarray(cols.log_time_ns[:n], dtype=np.int64)
    fast = n - int(np.count_nonzero(slow[:n]))
    return FieldBatch(names, topic_idx, log, stamps[:n], values[:n], fast), failure
