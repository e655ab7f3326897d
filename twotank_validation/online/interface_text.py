"""The text form of an interface map: sources and time columns as one line each.

The form of CLI options (``--input``, ``--output``, ``--time``) and node parameters
(``inputs``, ``outputs``): :data:`TEXT_FORM` for a bag's source, :data:`TABLE_TEXT_FORM` for
a table's, :data:`TIME_TEXT_FORM` for a table's time column. :func:`source_to_text` is the
inverse of :func:`source_from_text`. The values are checked as every source's are
(:mod:`~twotank_validation.online.sources`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from twotank_validation.online.interface_map import InputKind, InterfaceMap
from twotank_validation.online.sources import (
    _MSGTYPE,
    STAMP_HEADER,
    InterfaceMapError,
    Source,
    TimeColumn,
    _BadKeyError,
    _checked_time,
    _make_source,
)

__all__ = [
    "TABLE_TEXT_FORM",
    "TEXT_FORM",
    "TIME_TEXT_FORM",
    "input_texts",
    "interface_map_from_text",
    "source_from_text",
    "source_to_text",
    "time_column_from_text",
]

TEXT_FORM: Final = "NAME=TOPIC:TYPE:FIELD[,scale=S][,offset=O][,stamp=header|receive]"
"""The grammar of :func:`source_from_text` for a bag's source, as shown in error messages.

An input of :func:`interface_map_from_text` may add ``,kind=commanded|measured`` (either
form; :class:`~twotank_validation.online.interface_map.InputKind`)."""
TABLE_TEXT_FORM: Final = "NAME=column:COLUMN[,scale=S][,offset=O]"
"""The grammar of :func:`source_from_text` for a table's source (a column)."""
TIME_TEXT_FORM: Final = "COLUMN[,unit=auto|s|ms|us|ns|iso]"
"""The grammar of :func:`time_column_from_text` (a table's time column)."""

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
    kinds: list[InputKind] = []
    for role, texts in (("inputs", inputs), ("outputs", outputs)):
        if isinstance(texts, str):
            raise InterfaceMapError(f"{role}: expected a list of {TEXT_FORM}, found one string")
        for i, text in enumerate(texts):
            try:
                plain, kind = _input_kind(text, role == "inputs")
                lists[role].append(source_from_text(plain))
            except InterfaceMapError as err:
                raise InterfaceMapError(f"{role}[{i}]: {err}") from None
            if role == "inputs":
                kinds.append(kind)
    return InterfaceMap(
        tuple(lists["inputs"]),
        tuple(lists["outputs"]),
        time_column_from_text(time) if time is not None else None,
        "the interface map given as text (--input/--output, inputs/outputs)",
        tuple(kinds),
    )


def input_texts(imap: InterfaceMap) -> list[str]:
    """The text forms of a map's inputs, a measured one's with ``,kind=measured``.

    :func:`interface_map_from_text` of these and the outputs' :func:`source_to_text` gives
    the map's inputs and their kinds back.
    """
    return [
        source_to_text(s) + (",kind=measured" if k is InputKind.MEASURED else "")
        for s, k in zip(imap.inputs, imap.kinds, strict=True)
    ]


def _input_kind(text: Any, is_input: bool) -> tuple[Any, InputKind]:
    """An input's text without its ``kind=commanded|measured`` option, and the kind.

    Raises:
        InterfaceMapError: a bad kind, a kind given twice, or a kind on an output.
    """
    if not isinstance(text, str):
        return text, InputKind.COMMANDED
    head, *options = text.split(",")
    marked = [o for o in options if o.partition("=")[0].strip() == "kind"]
    if not marked:
        return text, InputKind.COMMANDED
    if not is_input:
        raise InterfaceMapError(
            f"source {text!r}: only an input has a kind (commanded or measured); an output is "
            "always measured: drop 'kind='"
        )
    if len(marked) > 1:
        raise InterfaceMapError(f"source {text!r}: option 'kind' is given twice")
    kind = InputKind.parse(marked[0].partition("=")[2].strip(), f"source {text!r}: kind")
    return ",".join([head, *(o for o in options if o not in marked)]), kind
