"""The sources of an interface map: where one model input or output comes from.

A :class:`Source` binds one channel, by name, to a topic, its message type (``pkg/msg/Type``)
and a field path into the message (``data[1]``, ``position[0]``, ``a.b[2].c``; parsed by
:func:`parse_field_path`), where the time stamp comes from (``header.stamp`` or the
receive/log time) and the conversion to model units, ``model = (raw - offset) / scale``
(:func:`convert` for many raw values at once). A table's source names a ``column`` instead;
the table's time column is a :class:`TimeColumn`.

Every value is checked here, once, for every way a source is made: the constructor, the YAML
document (:mod:`~twotank_validation.online.interface_map`) and the text form
(:mod:`~twotank_validation.online.interface_text`). Every problem is an
:class:`InterfaceMapError`. Nothing here imports ROS.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
from collections.abc import Mapping
from typing import Any, Final

import numpy as np

from twotank_validation.defaults import NS_PER_S
from twotank_validation.errors import TwotankError

__all__ = [
    "STAMPS",
    "STAMP_HEADER",
    "STAMP_RECEIVE",
    "TIME_COLUMNS",
    "TIME_UNITS",
    "FieldPath",
    "InterfaceMapError",
    "Source",
    "TimeColumn",
    "convert",
    "format_field_path",
    "parse_field_path",
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


# --------------------------------------------------------------------------- a table's time


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

    def to_dict(self) -> dict[str, Any]:
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
