"""The interface map: which topic, message type and field feeds each model input and output.

A real rig publishes its own topics and types. An :class:`InterfaceMap` binds each input and
output channel, by name, to a :class:`Source`: a topic, its message
type (``pkg/msg/Type``), a field path into the message (``data[1]``, ``position[0]``,
``a.b[2].c``), where the time stamp comes from (``header.stamp`` or the receive/log time) and
the conversion to model units, ``model = (raw - offset) / scale``.

A map of a table (a CSV or Parquet log of a PLC or historian) names a ``column`` per source
instead of topic, type and field, and the table's time column once for the map
(:class:`TimeColumn`); a map is all-topic (a bag) or all-column (a table). Reading tables is
:mod:`twotank_validation.tables`.

Maps come from YAML (:func:`load_interface_map`, :meth:`InterfaceMap.from_dict`), from the
text form of CLI options and node parameters (:func:`source_from_text`,
:func:`interface_map_from_text`), or a preset (the two-tank rig's:
:func:`twotank_validation.online.streams.two_tank_map`, the default). The validator matches
the map's channel names to each model's (:mod:`~twotank_validation.online.channels`).

Extraction (:func:`raw_value`, :func:`extract`, :func:`check_message`) reads attributes by
field name and indexes arrays (numpy arrays, lists, tuples, ``array.array``), so it works on
rosbags' decoded dataclasses, rclpy messages and mcap_ros2's decoded objects alike. Nothing
here imports ROS.
"""

from __future__ import annotations

import array
import dataclasses
import math
import numbers
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final, NamedTuple

import numpy as np
import yaml

from twotank_validation.defaults import NS_PER_S
from twotank_validation.errors import TwotankError

__all__ = [
    "INPUT",
    "OUTPUT",
    "STAMPS",
    "STAMP_HEADER",
    "STAMP_RECEIVE",
    "TABLE_TEXT_FORM",
    "TEXT_FORM",
    "TIME_COLUMNS",
    "TIME_TEXT_FORM",
    "TIME_UNITS",
    "Binding",
    "FieldPath",
    "InterfaceMap",
    "InterfaceMapError",
    "Source",
    "TimeColumn",
    "TopicSources",
    "check_message",
    "convert",
    "extract",
    "format_field_path",
    "interface_map_from_text",
    "load_interface_map",
    "message_fields",
    "message_sources",
    "message_type_name",
    "parse_field_path",
    "raw_value",
    "source_from_text",
    "source_stamp_ns",
    "source_to_text",
    "stamp_ns",
    "time_column_from_text",
]


class InterfaceMapError(TwotankError, ValueError):
    """An interface map is malformed, or a message does not fit it.

    The message names the key or topic, what was found and the fix.
    """


FieldPath = tuple[str | int, ...]
"""A parsed field path: attribute names (str) and array indices (int), outermost first."""

STAMP_HEADER: Final = "header"
"""Stamp from the message's ``header.stamp``."""
STAMP_RECEIVE: Final = "receive"
"""Stamp from the receive time (live) or the log time (bags), for headerless types."""
STAMPS: Final = (STAMP_HEADER, STAMP_RECEIVE)

INPUT: Final = "input"
"""Role of a source that feeds a model input."""
OUTPUT: Final = "output"
"""Role of a source that feeds a model output."""

TEXT_FORM: Final = "NAME=TOPIC:TYPE:FIELD[,scale=S][,offset=O][,stamp=header|receive]"
"""The grammar of :func:`source_from_text` for a bag's source, as shown in error messages."""
TABLE_TEXT_FORM: Final = "NAME=column:COLUMN[,scale=S][,offset=O]"
"""The grammar of :func:`source_from_text` for a table's source (a column)."""
TIME_TEXT_FORM: Final = "COLUMN[,unit=auto|s|ms|us|ns|iso]"
"""The grammar of :func:`time_column_from_text` (a table's time column)."""

TIME_UNITS: Final = ("auto", "s", "ms", "us", "ns", "iso")
"""Units of a table's time column: ``auto`` (numbers are seconds; datetimes and text are
ISO-8601), seconds, milliseconds, microseconds, nanoseconds (numbers), ``iso`` (ISO-8601
text such as ``2024-05-01T12:00:00.800Z``, or a datetime column)."""
TIME_COLUMNS: Final = ("time", "t", "timestamp")
"""Names taken as a table's time column when the map names none (case-insensitive)."""

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_TOPIC = re.compile(r"[~/A-Za-z0-9_{}]+")
_MSGTYPE = re.compile(r"[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*")
_SHORT_MSGTYPE = re.compile(r"([A-Za-z][A-Za-z0-9_]*)/([A-Za-z][A-Za-z0-9_]*)")
_PATH_STEP = re.compile(r"\.?([A-Za-z][A-Za-z0-9_]*)|\[([0-9]+)\]")
_KEYS: Final = ("name", "topic", "type", "field", "stamp", "offset", "scale", "column")
_REQUIRED: Final = ("name", "topic", "type", "field")
_BAG_KEYS: Final = ("topic", "type", "field", "stamp")  # keys a table's source cannot have
_TIME_KEYS: Final = ("column", "unit", "step_s")
_ATTR = {"type": "msgtype"}  # YAML/text key -> Source attribute, where they differ


# --------------------------------------------------------------------------- field paths


def parse_field_path(text: str) -> FieldPath:
    """Parse a field path: a field name, then ``.name`` and ``[index]`` steps.

    Grammar: ``NAME ( "." NAME | "[" DIGITS "]" )*`` with ``NAME = [A-Za-z][A-Za-z0-9_]*``;
    no spaces. Examples: ``hot``, ``data[1]``, ``position[0]``, ``a.b[2].c``.

    Returns:
        The steps, e.g. ``("a", "b", 2, "c")``.

    Raises:
        InterfaceMapError: If the text does not follow the grammar (the message shows where).
    """
    if not isinstance(text, str) or not text:
        raise InterfaceMapError(
            f"field path {text!r} is not a non-empty string; write e.g. 'data' or 'data[1]'"
        )
    steps: list[str | int] = []
    pos = 0
    while pos < len(text):
        m = _PATH_STEP.match(text, pos)
        if m is not None:
            named, dotted = m.group(1) is not None, m.group(0).startswith(".")
            # the first step is a bare name; later ones are .name or [index]
            fits = (named and not dotted) if pos == 0 else (dotted or not named)
        if m is None or not fits:
            raise InterfaceMapError(
                f"field path {text!r}: cannot read {text[pos:]!r} at character {pos}; a path is "
                "a field name followed by .name and [index] steps, e.g. 'data[1]', "
                "'position[0]', 'a.b[2].c'"
            )
        steps.append(m.group(1) if m.group(1) is not None else int(m.group(2)))
        pos = m.end()
    return tuple(steps)


def format_field_path(path: FieldPath) -> str:
    """Text of a parsed field path (inverse of :func:`parse_field_path`, canonical form)."""
    out = ""
    for step in path:
        out += f"[{step}]" if isinstance(step, int) else (f".{step}" if out else step)
    return out


# --------------------------------------------------------------------------- sources


class _BadKeyError(Exception):
    """One invalid key of a source (internal: turned into InterfaceMapError by the callers)."""

    def __init__(self, key: str, detail: str) -> None:
        super().__init__(f"{key}: {detail}")
        self.key = key
        self.detail = detail


def _number(key: str, value: Any) -> float:
    if isinstance(value, str):  # YAML 1.1 reads 1e3 (no dot) as text
        try:
            value = float(value)
        except ValueError:
            raise _BadKeyError(key, f"expected a number, found {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise _BadKeyError(key, f"expected a number, found {value!r} ({type(value).__name__})")
    out = float(value)
    if not math.isfinite(out):
        raise _BadKeyError(key, f"{out!r} is not finite; give a finite number")
    return out


def _checked_values(
    values: Mapping[str, Any], table: bool | None = None
) -> tuple[str, str, str, str, str, float, float, str, FieldPath]:
    """Validate one source's values; the canonical values and the parsed path.

    Args:
        values: Value of each of the eight keys (YAML/text names: ``type``, not ``msgtype``);
            ``column`` empty for a bag's source, ``topic``, ``type``, ``field`` empty and
            ``stamp`` ``header`` for a table's.
        table: The source is a table's (its ``column`` key was given); None: it is when
            ``column`` is not empty.

    Raises:
        _BadKeyError: naming the key and what is wrong with it.
    """
    name, topic, msgtype, field, stamp, column = (
        values[k] for k in ("name", "topic", "type", "field", "stamp", "column")
    )
    if not isinstance(name, str) or not name:
        raise _BadKeyError("name", f"expected a non-empty string, found {name!r}")
    if not _NAME.fullmatch(name):
        raise _BadKeyError(
            "name",
            f"{name!r} is not a signal name: use letters, digits and '_', starting with a "
            "letter (e.g. hot, level)",
        )
    if table or (table is None and column != ""):
        return (name, "", "", "", STAMP_HEADER, *_checked_column(values), ())
    for key, value in (("topic", topic), ("type", msgtype), ("field", field)):
        if not isinstance(value, str) or not value:
            raise _BadKeyError(key, f"expected a non-empty string, found {value!r}")
    if not _TOPIC.fullmatch(topic):
        raise _BadKeyError(
            "topic",
            f"{topic!r} is not a ROS 2 topic name: use letters, digits, '_', '/', '~' and {{}} "
            "(e.g. /tank/pressure)",
        )
    if not _MSGTYPE.fullmatch(msgtype):
        short = _SHORT_MSGTYPE.fullmatch(msgtype)
        hint = f"{short[1]}/msg/{short[2]}" if short else "std_msgs/msg/Float64"
        raise _BadKeyError(
            "type", f"{msgtype!r} is not a ROS 2 message type 'pkg/msg/Type'; e.g. {hint}"
        )
    try:
        path = parse_field_path(field)
    except InterfaceMapError as err:
        raise _BadKeyError("field", str(err)) from None
    if stamp not in STAMPS:
        raise _BadKeyError(
            "stamp",
            f"{stamp!r} is not a stamp source; use 'header' (header.stamp) or 'receive' "
            "(receive/log time, for types without a header)",
        )
    off, sc = _conversion(values)
    return name, topic, msgtype, format_field_path(path), stamp, off, sc, "", path


def _conversion(values: Mapping[str, Any]) -> tuple[float, float]:
    off = _number("offset", values["offset"])
    sc = _number("scale", values["scale"])
    if sc == 0.0:
        raise _BadKeyError(
            "scale",
            "0 is not a scale (model = (raw - offset) / scale); give raw units "
            "per model unit, e.g. 9806.65 Pa per m of water",
        )
    return off, sc


def _checked_column(values: Mapping[str, Any]) -> tuple[float, float, str]:
    """Offset, scale and column of a table's source (the name is checked already)."""
    column = values["column"]
    if not isinstance(column, str) or not column.strip():
        raise _BadKeyError(
            "column", f"expected the name of a table column (a non-empty string), found {column!r}"
        )
    bag_keys = [key for key in ("topic", "type", "field") if values[key] not in ("", None)] + (
        ["stamp"] if values["stamp"] != STAMP_HEADER else []
    )
    if bag_keys:
        raise _BadKeyError(
            "column",
            f"a source reads either a table's column or a bag's topic, but this one gives "
            f"'column' and {bag_keys}: drop {bag_keys} for a CSV/Parquet table (its rows are "
            "stamped by the map's time column), or drop 'column' for a bag",
        )
    return (*_conversion(values), column)


@dataclasses.dataclass(frozen=True)
class Source:
    """Where one model input or output comes from, and its conversion to model units.

    ``model = (raw - offset) / scale`` with ``raw`` the field's (or the cell's) value as a
    float. A bag's source gives ``topic``, ``msgtype`` and ``field`` (``column`` empty); a
    table's gives ``column`` only (``Source("hot", column="valve_hot_pct", scale=100.0)``).

    Attributes:
        name: Signal name, e.g. ``hot`` (letters, digits, ``_``; unique within a map).
        topic: ROS 2 topic, e.g. ``/valves/hot``; empty for a table's source.
        msgtype: ROS 2 message type name ``pkg/msg/Type`` (key ``type`` in YAML and text);
            empty for a table's source.
        field: Field path, e.g. ``data``, ``data[1]``, ``position[0]``, ``a.b[2].c``; stored
            in canonical form (``data[01]`` becomes ``data[1]``); empty for a table's source.
        stamp: ``"header"`` (the message's ``header.stamp``) or ``"receive"`` (receive time
            live, log time in a bag; for types without a header). A table's source leaves it
            at ``"header"``, unused: its rows are stamped by the map's :class:`TimeColumn`.
        offset: Raw value at model 0 (raw units).
        scale: Raw units per model unit; non-zero (negative flips the sign).
        column: The table column (CSV header or Parquet field name, exactly); empty for a
            bag's source.
        path: The parsed field path (derived from ``field``; ``()`` for a table's source).

    Raises:
        InterfaceMapError: If a value is invalid (the message names the attribute and the fix).
    """

    name: str
    topic: str = ""
    msgtype: str = ""
    field: str = ""
    stamp: str = STAMP_HEADER
    offset: float = 0.0
    scale: float = 1.0
    column: str = ""
    path: FieldPath = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        try:
            values = _checked_values(
                {
                    "name": self.name,
                    "topic": self.topic,
                    "type": self.msgtype,
                    "field": self.field,
                    "stamp": self.stamp,
                    "offset": self.offset,
                    "scale": self.scale,
                    "column": self.column,
                }
            )
        except _BadKeyError as bad:
            raise InterfaceMapError(
                f"source {self.name!r}: {_ATTR.get(bad.key, bad.key)}: {bad.detail}"
            ) from None
        for attr, value in zip(
            ("name", "topic", "msgtype", "field", "stamp", "offset", "scale", "column", "path"),
            values,
            strict=True,
        ):
            object.__setattr__(self, attr, value)

    @property
    def is_column(self) -> bool:
        """The source reads a table's column (not a bag's topic)."""
        return self.column != ""

    def to_model(self, raw: float) -> float:
        """Model-unit value of one raw field value: ``(raw - offset) / scale``."""
        return (float(raw) - self.offset) / self.scale

    def to_dict(self) -> dict[str, Any]:
        """The YAML mapping of this source (every key of its kind, in schema order)."""
        if self.is_column:
            return {
                "name": self.name,
                "column": self.column,
                "offset": self.offset,
                "scale": self.scale,
            }
        return {
            "name": self.name,
            "topic": self.topic,
            "type": self.msgtype,
            "field": self.field,
            "stamp": self.stamp,
            "offset": self.offset,
            "scale": self.scale,
        }


def convert(raw: np.ndarray, source: Source) -> np.ndarray:
    """Model-unit values of many raw values at once: ``(raw - offset) / scale`` in float64.

    The same float operations as :meth:`Source.to_model` (and :func:`extract`), so the same
    values bit for bit.

    Args:
        raw: Raw field values, any shape (converted to float64).
        source: The source they were read through.

    Returns:
        float64 array of the shape of ``raw``.
    """
    return (np.asarray(raw, dtype=np.float64) - source.offset) / source.scale


# --------------------------------------------------------------------------- the map


class Binding(NamedTuple):
    """One source of a topic: its role, its index in ``u`` or ``y``, and the source."""

    role: str
    """:data:`INPUT` or :data:`OUTPUT`."""
    position: int
    """Index in the model's inputs (``u``) or outputs (``y``)."""
    source: Source


class TopicSources(NamedTuple):
    """What one topic carries: its message type and the sources read from it."""

    msgtype: str
    bindings: tuple[Binding, ...]


@dataclasses.dataclass(frozen=True)
class TimeColumn:
    """A table's time column: which column stamps the rows, and in what unit.

    Attributes:
        column: Column name (exactly as in the table); empty: the first column named
            ``time``, ``t`` or ``timestamp`` (:data:`TIME_COLUMNS`, case-insensitive).
        unit: One of :data:`TIME_UNITS`: ``s``, ``ms``, ``us``, ``ns`` (numbers since any
            origin), ``iso`` (ISO-8601 text, or a datetime column; naive times are taken as
            UTC), or ``auto`` (the default: a numeric column is seconds, a datetime or text
            column ISO-8601).
        step_s: A table without a time column whose rows are evenly spaced samples (e.g. a
            benchmark file): row k after the header, in file order, is at ``k step_s``
            seconds; ``column`` and ``unit`` then stay unset. None: the time column stamps
            the rows.

    Raises:
        InterfaceMapError: If the column is not a string or the unit is not one of
            :data:`TIME_UNITS`.
    """

    column: str = ""
    unit: str = "auto"
    step_s: float | None = None

    def __post_init__(self) -> None:
        try:
            _checked_time({"column": self.column, "unit": self.unit, "step_s": self.step_s})
        except _BadKeyError as bad:
            raise InterfaceMapError(f"time: {bad.key}: {bad.detail}") from None

    def to_dict(self) -> dict[str, str]:
        """The YAML mapping (keys at their defaults left out)."""
        out: dict[str, Any] = {"column": self.column} if self.column else {}
        out |= {"step_s": self.step_s} if self.step_s is not None else {}
        return out | ({"unit": self.unit} if self.unit != "auto" else {})


def _checked_time(values: Mapping[str, Any]) -> None:
    column, unit = values["column"], values["unit"]
    if not isinstance(column, str):
        raise _BadKeyError(
            "column", f"expected the name of the table's time column, found {column!r}"
        )
    if unit not in TIME_UNITS:
        raise _BadKeyError(
            "unit",
            f"{unit!r} is not a time unit; use one of {list(TIME_UNITS)} (s, ms, us, ns: "
            "numbers; iso: ISO-8601 text such as 2024-05-01T12:00:00.8Z)",
        )
    step = values.get("step_s")
    if step is None:
        return
    if (
        isinstance(step, bool)
        or not isinstance(step, int | float)
        or not math.isfinite(step)
        or step <= 0
        or round(step * NS_PER_S) < 1
    ):
        raise _BadKeyError(
            "step_s", f"{step!r} is not a sample spacing; give the seconds between rows (> 0)"
        )
    if column or unit != "auto":
        raise _BadKeyError(
            "step_s",
            "stamps rows that have no time column: give either step_s (rows evenly spaced) "
            "or the time column's column and unit, not both",
        )


@dataclasses.dataclass(frozen=True)
class InterfaceMap:
    """The sources of a model's inputs and outputs.

    Attributes:
        inputs: One source per input channel; its name is matched to the models' input names
            (the order is the samples' ``u`` columns, not the models').
        outputs: One source per output channel, matched by name likewise.
        time: A table's time column (a map of column sources only; None there means
            ``TimeColumn()``, the column found by name, unit ``auto``). None for a bag's map.
        label: What the map is called in messages (``"the interface map rig.yaml"``, ``"the
            two-tank interface"``); not part of the map's value.

    Raises:
        InterfaceMapError: If either is empty or not made of :class:`Source`, a name is used
            twice, a topic is given two message types, one topic's sources disagree on the
            stamp (one message has one stamp), topic and column sources are mixed, or a map
            of topics is given a time column.
    """

    inputs: tuple[Source, ...]
    outputs: tuple[Source, ...]
    time: TimeColumn | None = None
    label: str = dataclasses.field(default="the interface map", compare=False)

    def __post_init__(self) -> None:
        for role in ("inputs", "outputs"):
            value = getattr(self, role)
            if isinstance(value, Source | str) or not isinstance(value, Sequence):
                raise InterfaceMapError(f"{role}: expected a sequence of Source, found {value!r}")
            object.__setattr__(self, role, tuple(value))
        _check_sources(self.inputs, self.outputs)
        if self.time is not None and not isinstance(self.time, TimeColumn):
            raise InterfaceMapError(f"time: expected a TimeColumn, found {self.time!r}")
        if self.is_table and self.time is None:
            object.__setattr__(self, "time", TimeColumn())
        elif not self.is_table and self.time is not None:
            raise InterfaceMapError(
                "time: a map of topics is stamped by its messages; 'time' names the time "
                "column of a table: drop it, or read a table with column sources"
            )

    # --- construction ---------------------------------------------------------------------

    @classmethod
    def from_dict(cls, doc: Any, source: str = "<dict>") -> InterfaceMap:
        """Build a map from its YAML document (see ``docs/interface.md`` for the schema).

        Args:
            doc: ``{"inputs": [...], "outputs": [...]}``, each entry a mapping with keys
                ``name``, ``topic``, ``type``, ``field`` (required), ``stamp``, ``offset``,
                ``scale`` (optional: ``header``, 0, 1); for a table, ``name`` and ``column``
                (required), ``offset``, ``scale``, and the map's optional ``time``: a column
                name or ``{column: ..., unit: ...}`` (:class:`TimeColumn`).
            source: Label of the document in error messages (the file name).

        Raises:
            InterfaceMapError: Unknown or missing keys, wrong types, invalid values, duplicate
                names, a topic with two types; the message starts with ``source`` and the key
                (e.g. ``rig.yaml: outputs[1].scale: ...``).
        """
        if not isinstance(doc, Mapping):
            raise InterfaceMapError(
                f"{source}: expected a mapping with keys 'inputs' and 'outputs', found "
                f"{type(doc).__name__}"
            )
        unknown = sorted(str(k) for k in set(doc) - {"inputs", "outputs", "time"})
        if unknown:
            raise InterfaceMapError(
                f"{source}: unknown keys {unknown}; allowed: ['inputs', 'outputs', 'time' "
                "(a table's time column)]"
            )
        lists: dict[str, tuple[Source, ...]] = {}
        for role in ("inputs", "outputs"):
            if role not in doc:
                raise InterfaceMapError(f"{source}: missing key '{role}' (a list of sources)")
            entries = doc[role]
            if not isinstance(entries, list) or not entries:
                raise InterfaceMapError(
                    f"{source}: {role}: expected a non-empty list of sources, found {entries!r}"
                )
            lists[role] = tuple(
                _source_from_mapping(e, source, f"{role}[{i}]") for i, e in enumerate(entries)
            )
        time = _time_from_node(doc["time"], source) if "time" in doc else None
        try:
            return cls(lists["inputs"], lists["outputs"], time, f"the interface map {source}")
        except InterfaceMapError as err:
            raise InterfaceMapError(f"{source}: {err}") from None

    def to_dict(self) -> dict[str, Any]:
        """The YAML document of the map (:meth:`from_dict` of it gives an equal map)."""
        doc: dict[str, Any] = {
            "inputs": [s.to_dict() for s in self.inputs],
            "outputs": [s.to_dict() for s in self.outputs],
        }
        if self.time is not None:
            doc["time"] = self.time.to_dict()
        return doc

    @property
    def is_table(self) -> bool:
        """The map reads a table (every source a column), not a bag (every source a topic)."""
        return self.inputs[0].is_column

    # --- views ----------------------------------------------------------------------------

    def sources(self) -> tuple[Source, ...]:
        """Every source: the inputs in the order of ``u``, then the outputs (order of ``y``)."""
        return self.inputs + self.outputs

    @property
    def input_names(self) -> tuple[str, ...]:
        """Names of the inputs, in the order of ``u``."""
        return tuple(s.name for s in self.inputs)

    @property
    def output_names(self) -> tuple[str, ...]:
        """Names of the outputs, in the order of ``y``."""
        return tuple(s.name for s in self.outputs)

    def topics(self) -> dict[str, TopicSources]:
        """Topic -> its message type and the sources read from it (role, index, source).

        Topics in order of first appearance (inputs first); a topic's bindings in map order.

        Raises:
            InterfaceMapError: If the map reads a table (it has columns, no topics).
        """
        if self.is_table:
            raise InterfaceMapError(
                f"the interface map reads the columns {[s.column for s in self.sources()]} of a "
                "table (CSV/Parquet), not topics: give a map of topics (topic, type, field) for "
                "a bag or a live system"
            )
        out: dict[str, tuple[str, list[Binding]]] = {}
        for role, sources in ((INPUT, self.inputs), (OUTPUT, self.outputs)):
            for index, src in enumerate(sources):
                out.setdefault(src.topic, (src.msgtype, []))[1].append(Binding(role, index, src))
        return {t: TopicSources(mt, tuple(b)) for t, (mt, b) in out.items()}


def message_sources(imap: InterfaceMap) -> dict[str, TopicSources]:
    """What each message carries, topic by topic.

    :meth:`InterfaceMap.topics` for a bag's map; for a table's, one pseudo-topic ``""`` (a row)
    carrying every source (inputs, then outputs).
    """
    if not imap.is_table:
        return imap.topics()
    bindings = tuple(Binding(INPUT, i, s) for i, s in enumerate(imap.inputs)) + tuple(
        Binding(OUTPUT, i, s) for i, s in enumerate(imap.outputs)
    )
    return {"": TopicSources("", bindings)}


def _reads(src: Source) -> str:
    return f"column {src.column!r}" if src.is_column else f"topic {src.topic!r}"


def _check_sources(inputs: tuple[Source, ...], outputs: tuple[Source, ...]) -> None:
    names: dict[str, str] = {}
    topics: dict[str, tuple[str, Source]] = {}
    kind: tuple[str, Source] | None = None  # the first source: a bag's or a table's
    for role, sources in (("inputs", inputs), ("outputs", outputs)):
        if not sources:
            raise InterfaceMapError(f"{role}: no sources; give one per model {role[:-1]}")
        for i, src in enumerate(sources):
            where = f"{role}[{i}]"
            if not isinstance(src, Source):
                raise InterfaceMapError(f"{where}: expected a Source, found {src!r}")
            if kind is None:
                kind = (where, src)
            elif src.is_column != kind[1].is_column:
                raise InterfaceMapError(
                    f"{where}: reads {_reads(src)} but {kind[0]} reads {_reads(kind[1])}; a "
                    "map reads either a bag (every source a topic, type and field) or a table "
                    "(every source a column), not both: make every source a column for a "
                    "CSV/Parquet file, or every source a topic for a bag"
                )
            if src.name in names:
                raise InterfaceMapError(
                    f"{where}.name: {src.name!r} is used already by {names[src.name]}; "
                    "names must be unique"
                )
            names[src.name] = where
            if src.is_column:
                continue
            if src.topic in topics:
                first, other = topics[src.topic]
                if other.msgtype != src.msgtype:
                    raise InterfaceMapError(
                        f"{where}.type: topic {src.topic!r} is {src.msgtype} here but "
                        f"{other.msgtype} at {first}; a topic carries one message type"
                    )
                if other.stamp != src.stamp:
                    raise InterfaceMapError(
                        f"{where}.stamp: topic {src.topic!r} is stamped {src.stamp!r} here but "
                        f"{other.stamp!r} at {first}; one topic's sources share one stamp"
                    )
            else:
                topics[src.topic] = (where, src)


def _source_from_mapping(node: Any, source: str, where: str) -> Source:
    if not isinstance(node, Mapping):
        raise InterfaceMapError(
            f"{source}: {where}: expected a mapping with keys {list(_REQUIRED)} (a bag) or "
            f"['name', 'column'] (a table), found {node!r}"
        )
    unknown = sorted(str(k) for k in set(node) - set(_KEYS))
    if unknown:
        raise InterfaceMapError(
            f"{source}: {where}: unknown keys {unknown}; allowed: {list(_KEYS)}"
        )
    if "column" in node:
        bag_keys = [k for k in _BAG_KEYS if k in node]
        if bag_keys:
            raise InterfaceMapError(
                f"{source}: {where}: 'column' reads a table but {bag_keys} read a bag; give "
                f"either 'column' (a CSV/Parquet table, its rows stamped by the map's 'time') "
                f"or 'topic', 'type', 'field' (a bag)"
            )
        required: tuple[str, ...] = ("name", "column")
    else:
        required = _REQUIRED
    missing = [k for k in required if k not in node]
    if missing:
        hint = " (or 'column', for a CSV/Parquet table)" if "topic" in missing else ""
        raise InterfaceMapError(f"{source}: {where}: missing keys {missing}{hint}")
    return _make_source(
        {k: node[k] for k in _KEYS if k in node}, lambda key: f"{source}: {where}.{key}"
    )


def _make_source(values: Mapping[str, Any], where: Any) -> Source:
    """Source from key -> value (YAML/text keys); errors prefixed by ``where(key)``.

    A table's source when the ``column`` key is given (even empty: that is an error).
    """
    try:
        name, topic, msgtype, field, stamp, offset, scale, column, _ = _checked_values(
            {
                "topic": "",
                "type": "",
                "field": "",
                "stamp": STAMP_HEADER,
                "offset": 0.0,
                "scale": 1.0,
                "column": "",
                **values,
            },
            table="column" in values,
        )
    except _BadKeyError as bad:
        raise InterfaceMapError(f"{where(bad.key)}: {bad.detail}") from None
    return Source(name, topic, msgtype, field, stamp, offset, scale, column)


def _time_from_node(node: Any, source: str) -> TimeColumn:
    """The map's ``time`` key: a column name, or a mapping with ``column`` and ``unit``."""
    if isinstance(node, str):
        node = {"column": node}
    if not isinstance(node, Mapping):
        raise InterfaceMapError(
            f"{source}: time: expected a column name or a mapping with keys "
            f"{list(_TIME_KEYS)} (e.g. time: {{column: t, unit: s}}), found {node!r}"
        )
    unknown = sorted(str(k) for k in set(node) - set(_TIME_KEYS))
    if unknown:
        raise InterfaceMapError(
            f"{source}: time: unknown keys {unknown}; allowed: {list(_TIME_KEYS)}"
        )
    values = {"column": "", "unit": "auto", "step_s": None, **node}
    try:
        _checked_time(values)
    except _BadKeyError as bad:
        raise InterfaceMapError(f"{source}: time.{bad.key}: {bad.detail}") from None
    step = values["step_s"]
    return TimeColumn(values["column"], values["unit"], None if step is None else float(step))


def load_interface_map(path: str | Path) -> InterfaceMap:
    """Load an interface map from a YAML file.

    Raises:
        InterfaceMapError: Missing file, YAML syntax error or schema violation (the message
            names the file and the key).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise InterfaceMapError(
            f"cannot read the interface map {path}: {err.strerror or err}; give a YAML file "
            "with 'inputs' and 'outputs' (docs/interface.md)"
        ) from err
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise InterfaceMapError(f"{path}: not valid YAML: {err}") from err
    return InterfaceMap.from_dict(doc, str(path))


# --------------------------------------------------------------------------- text form

_TEXT_OPTIONS: Final = ("scale", "offset", "stamp")


def source_from_text(text: str) -> Source:
    """Parse one source from its text form (CLI options, node parameters).

    Grammar (:data:`TEXT_FORM`, a bag's source; :data:`TABLE_TEXT_FORM`, a table's)::

        NAME=TOPIC:TYPE:FIELD[,scale=S][,offset=O][,stamp=header|receive]
        NAME=column:COLUMN[,scale=S][,offset=O]

    e.g. ``hot=/valves/hot:std_msgs/msg/Float64:data,stamp=receive`` or
    ``hot=column:valve_hot_pct,scale=100``. Options in any order, each at most once; spaces
    around the parts are ignored. Numbers as Python's ``float()`` reads them. A column name
    runs to the first ``,`` (it may hold ``:`` and inner spaces, not ``,``). A topic named
    ``column`` is written ``/column``.

    Raises:
        InterfaceMapError: If the text does not follow the grammar or a value is invalid (the
            message quotes the text and shows the expected form).
    """
    if not isinstance(text, str):
        raise InterfaceMapError(f"source text {text!r} is not a string; expected {TEXT_FORM}")
    name, eq, rest = text.strip().partition("=")
    head, *options = rest.split(",")
    parts = head.split(":")
    table = bool(eq) and len(parts) >= 2 and parts[0].strip() == "column"
    if table and len(parts) == 3 and _MSGTYPE.fullmatch(parts[1].strip()):
        raise InterfaceMapError(
            f"source {text!r} is ambiguous: write a topic named 'column' as '/column' "
            f"({TEXT_FORM}); a table's column is {TABLE_TEXT_FORM}"
        )
    if not eq or (len(parts) != 3 and not table):
        raise InterfaceMapError(
            f"source {text!r} is not {TEXT_FORM}, e.g. "
            "'hot=/valves/hot:std_msgs/msg/Float64:data,stamp=receive' (a bag), nor "
            f"{TABLE_TEXT_FORM}, e.g. 'hot=column:valve_hot_pct,scale=100' (a table)"
        )
    values: dict[str, Any]
    allowed: tuple[str, ...]
    if table:
        values = {"name": name, "column": ":".join(parts[1:])}
        allowed, form = _TEXT_OPTIONS[:2], TABLE_TEXT_FORM
    else:
        values = dict(zip(("name", "topic", "type", "field"), [name, *parts], strict=True))
        allowed, form = _TEXT_OPTIONS, TEXT_FORM
    for option in options:
        key, eq, value = option.partition("=")
        key = key.strip()
        if not eq or key not in allowed:
            raise InterfaceMapError(
                f"source {text!r}: option {option.strip()!r} is not "
                + (
                    "scale=S or offset=O (a table's rows are stamped by the map's time column)"
                    if table
                    else "scale=S, offset=O or stamp=header|receive"
                )
                + f"; expected {form}"
            )
        if key in values:
            raise InterfaceMapError(f"source {text!r}: option {key!r} is given twice")
        values[key] = value
    values = {k: v.strip() for k, v in values.items()}
    return _make_source(values, lambda key: f"source {text!r}: {key}")


def source_to_text(source: Source) -> str:
    """Text form of a source: the inverse of :func:`source_from_text`.

    Options at their defaults are left out; numbers are written exactly (``repr``).

    Raises:
        InterfaceMapError: If a column name cannot be written in the text form (it holds
            ``,`` or starts or ends with a space); such a column is given in YAML.
    """
    if source.is_column:
        col = source.column
        if "," in col or col != col.strip():
            raise InterfaceMapError(
                f"source {source.name!r}: column {col!r} has no text form ({TABLE_TEXT_FORM}: "
                "no ',' and no spaces at the ends); give it in a YAML map"
            )
        text = f"{source.name}=column:{col}"
    else:
        text = f"{source.name}={source.topic}:{source.msgtype}:{source.field}"
    if source.scale != 1.0:
        text += f",scale={source.scale!r}"
    if source.offset != 0.0:
        text += f",offset={source.offset!r}"
    if source.stamp != STAMP_HEADER:
        text += f",stamp={source.stamp}"
    return text


def time_column_from_text(text: str) -> TimeColumn:
    """Parse a table's time column from its text form (:data:`TIME_TEXT_FORM`).

    ``COLUMN[,unit=auto|s|ms|us|ns|iso]``, e.g. ``t``, ``t_ms,unit=ms``, ``stamp,unit=iso``;
    an empty COLUMN (``,unit=ms``) finds the column by name (:data:`TIME_COLUMNS`).

    Raises:
        InterfaceMapError: If the text does not follow the grammar or the unit is unknown.
    """
    if not isinstance(text, str):
        raise InterfaceMapError(f"time text {text!r} is not a string; expected {TIME_TEXT_FORM}")
    column, *options = text.split(",")
    values: dict[str, Any] = {"column": column.strip()}
    for option in options:
        key, eq, value = option.partition("=")
        if not eq or key.strip() != "unit" or "unit" in values:
            raise InterfaceMapError(
                f"time {text!r}: option {option.strip()!r} is not unit=U (once); expected "
                f"{TIME_TEXT_FORM}"
            )
        values["unit"] = value.strip()
    try:
        _checked_time({"unit": "auto", **values})
    except _BadKeyError as bad:
        raise InterfaceMapError(f"time {text!r}: {bad.key}: {bad.detail}") from None
    return TimeColumn(**values)


def interface_map_from_text(
    inputs: Sequence[str], outputs: Sequence[str], time: str | None = None
) -> InterfaceMap:
    """A map from the text forms of its inputs and outputs (e.g. two string-array parameters).

    Args:
        inputs: One :func:`source_from_text` form per model input.
        outputs: One per model output.
        time: A table's time column (:func:`time_column_from_text`), None: found by name
            for a table (none for a bag).

    Raises:
        InterfaceMapError: As :func:`source_from_text` (prefixed ``inputs[i]``/``outputs[i]``)
            and :class:`InterfaceMap`.
    """
    lists: dict[str, list[Source]] = {"inputs": [], "outputs": []}
    for role, texts in (("inputs", inputs), ("outputs", outputs)):
        if isinstance(texts, str):
            raise InterfaceMapError(f"{role}: expected a list of {TEXT_FORM}, found one string")
        for i, text in enumerate(texts):
            try:
                lists[role].append(source_from_text(text))
            except InterfaceMapError as err:
                raise InterfaceMapError(f"{role}[{i}]: {err}") from None
    return InterfaceMap(
        tuple(lists["inputs"]),
        tuple(lists["outputs"]),
        time_column_from_text(time) if time is not None else None,
        "the interface map given as text (--input/--output, inputs/outputs)",
    )


# --------------------------------------------------------------------------- extraction

_ARRAYS = (list, tuple, array.array, np.ndarray)


_FIELDS_OF_TYPE: dict[type, tuple[str, ...] | None] = {}


def _type_fields(cls: type) -> tuple[str, ...] | None:
    """Field names of a message class (cached per class), None if it is not one."""
    if cls not in _FIELDS_OF_TYPE:
        _FIELDS_OF_TYPE[cls] = _declared_fields(cls)
    return _FIELDS_OF_TYPE[cls]


def _declared_fields(cls: type) -> tuple[str, ...] | None:
    if dataclasses.is_dataclass(cls):  # rosbags (its __msgtype__ is a field too)
        return tuple(f.name for f in dataclasses.fields(cls) if not f.name.startswith("_"))
    getter = getattr(cls, "get_fields_and_field_types", None)
    if callable(getter):  # rclpy
        return tuple(getter())
    slots = getattr(cls, "__slots__", None)  # mcap_ros2 and other plain classes
    if isinstance(slots, str):
        slots = (slots,)
    if slots and not issubclass(cls, _ARRAYS):
        return tuple(s for s in slots if not s.startswith("_"))
    return None


def message_fields(obj: Any) -> tuple[str, ...] | None:
    """Field names of a message object, or None if it is not a message.

    rosbags dataclasses: :func:`dataclasses.fields`; rclpy messages:
    ``get_fields_and_field_types()``; otherwise ``__slots__``, then the instance's attributes.
    Names starting with ``_`` are left out.
    """
    fields = _type_fields(type(obj))
    if fields is None and hasattr(obj, "__dict__") and not isinstance(obj, type):
        fields = tuple(k for k in vars(obj) if not k.startswith("_")) or None
    return fields


def message_type_name(msg: Any) -> str:
    """ROS 2 type name ``pkg/msg/Type`` of a message object (else its Python class name)."""
    name = getattr(msg, "__msgtype__", None)  # rosbags
    if isinstance(name, str):
        return name
    cls = type(msg)
    module = cls.__module__.split(".")
    if len(module) >= 2 and module[1] == "msg":  # rclpy: pkg.msg._module.Type
        return f"{module[0]}/msg/{cls.__name__}"
    return cls.__qualname__


def _kind(obj: Any) -> str:
    if isinstance(obj, _ARRAYS):
        return f"an array ({type(obj).__name__}) of length {len(obj)}"
    if message_fields(obj) is not None:
        return f"a {message_type_name(obj)} message"
    text = repr(obj)
    return f"a {type(obj).__name__} ({text if len(text) <= 40 else text[:37] + '...'})"


def _path_error(
    path: FieldPath, msg: Any, topic: str | None, msgtype: str | None, detail: str
) -> InterfaceMapError:
    where = f"topic {topic!r}" if topic is not None else "message"
    found = msgtype if msgtype is not None else message_type_name(msg)
    return InterfaceMapError(
        f"{where} ({found}): field path {format_field_path(path)!r} does not fit the "
        f"message: {detail}"
    )


def raw_value(
    msg: Any, path: FieldPath | str, *, topic: str | None = None, msgtype: str | None = None
) -> float:
    """The raw number a field path reaches in a decoded message, as a float.

    Args:
        msg: rosbags decoded message, rclpy message, or any object with the fields as
            attributes (arrays: numpy arrays, lists, tuples, ``array.array``).
        path: Parsed (:data:`FieldPath`) or text field path.
        topic: Topic, named in errors.
        msgtype: Message type, named in errors (default: found from ``msg``).

    Raises:
        InterfaceMapError: If the path does not fit: a field that is not there (the message
            lists the fields present at that level), an index past the end (names the length),
            an index into a non-array, or a leaf that is not a number.
    """
    steps = parse_field_path(path) if isinstance(path, str) else path
    obj = msg
    for depth, step in enumerate(steps):
        here = format_field_path(steps[:depth]) or "the message"
        if isinstance(step, int):
            if not isinstance(obj, _ARRAYS) or (isinstance(obj, np.ndarray) and obj.ndim != 1):
                raise _path_error(
                    steps,
                    msg,
                    topic,
                    msgtype,
                    f"{here} is {_kind(obj)}, not an array: [{step}] cannot index it",
                )
            if step >= len(obj):
                raise _path_error(
                    steps,
                    msg,
                    topic,
                    msgtype,
                    f"index {step} is out of range: {here} has length {len(obj)}",
                )
            obj = obj[step]
        else:
            fields = message_fields(obj)
            if fields is None or step not in fields:
                if fields is None:
                    detail = f"{here} is {_kind(obj)}, which has no fields; no field {step!r}"
                else:
                    detail = (
                        f"{here} ({message_type_name(obj)}) has no field {step!r}; its fields: "
                        f"{', '.join(fields) or '(none)'}"
                    )
                raise _path_error(steps, msg, topic, msgtype, detail)
            obj = getattr(obj, step)
    if isinstance(obj, bool | numbers.Real):
        return float(obj)
    text = format_field_path(steps)
    if isinstance(obj, _ARRAYS):
        hint = f"; add an index, e.g. {text}[0]" if len(obj) else ""
    elif (fields := message_fields(obj)) is not None:
        hint = f"; its fields: {', '.join(fields)}; continue the path, e.g. {text}.{fields[0]}"
    else:
        hint = ""
    raise _path_error(steps, msg, topic, msgtype, f"{text} is {_kind(obj)}, not a number{hint}")


def extract(msg: Any, source: Source) -> float:
    """Model-unit value of a source in a decoded message: ``(raw - offset) / scale``.

    Raises:
        InterfaceMapError: As :func:`raw_value` (naming the source's topic).
    """
    return source.to_model(raw_value(msg, source.path, topic=source.topic))


def check_message(source: Source, msg: Any, msgtype_found: str) -> None:
    """Check that a topic's message fits a source: its type, field path and stamp.

    For the first message of each topic (replay, live): type equality, then the path as
    :func:`raw_value` walks it, then ``header.stamp`` if the source's stamp is ``header``.

    Args:
        source: The source read from the message.
        msg: A decoded message of ``source.topic``.
        msgtype_found: The topic's message type as the bag or the graph reports it.

    Raises:
        InterfaceMapError: Naming the topic, the type found and what the map asks for.
    """
    if msgtype_found != source.msgtype:
        raise InterfaceMapError(
            f"topic {source.topic!r} carries {msgtype_found}, but the interface map asks for "
            f"{source.msgtype} (source {source.name!r}); set 'type: {msgtype_found}' for it in "
            "the map, with a field path that fits that type"
        )
    raw_value(msg, source.path, topic=source.topic, msgtype=msgtype_found)
    if source.stamp == STAMP_HEADER:
        header = getattr(msg, "header", None) if "header" in (message_fields(msg) or ()) else None
        st = getattr(header, "stamp", None)
        if st is None or not (hasattr(st, "sec") and hasattr(st, "nanosec")):
            raise InterfaceMapError(
                f"topic {source.topic!r} ({msgtype_found}) has no header.stamp to stamp source "
                f"{source.name!r}; set 'stamp: receive' for it (the receive or log time is used)"
            )


def stamp_ns(msg: Any) -> int:
    """Header stamp of a message in integer nanoseconds."""
    st = msg.header.stamp
    return int(st.sec) * NS_PER_S + int(st.nanosec)


def source_stamp_ns(msg: Any, source: Source, receive_ns: int) -> int:
    """Stamp of a source's sample (integer ns): ``header.stamp`` or ``receive_ns``.

    Args:
        msg: The decoded message.
        source: Its source (``stamp`` chooses).
        receive_ns: Receive time (live) or log time (bag), integer nanoseconds.
    """
    return stamp_ns(msg) if source.stamp == STAMP_HEADER else int(receive_ns)
