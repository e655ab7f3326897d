"""The interface map: which source feeds each model input and output, and its YAML form.

An :class:`InterfaceMap` binds each input and output channel, by name, to a
:class:`~twotank_validation.online.sources.Source`; a map is all-topic (a bag or a live
system) or all-column (a table, stamped by its
:class:`~twotank_validation.online.sources.TimeColumn`). :meth:`InterfaceMap.topics` (and
:func:`message_sources`) say what each message carries. Maps come from YAML
(:func:`load_interface_map`, :meth:`InterfaceMap.from_dict`), from text
(:mod:`~twotank_validation.online.interface_text`), or a preset (the two-tank rig's:
:func:`twotank_validation.online.streams.two_tank_map`). Nothing here imports ROS.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final, NamedTuple

import yaml

from twotank_validation.online.sources import (
    InterfaceMapError,
    Source,
    TimeColumn,
    _BadKeyError,
    _checked_time,
    _make_source,
)

__all__ = [
    "INPUT",
    "OUTPUT",
    "Binding",
    "InputKind",
    "InterfaceMap",
    "TopicSources",
    "load_interface_map",
    "message_sources",
]

INPUT: Final = "input"
"""Role of a source that feeds a model input."""
OUTPUT: Final = "output"
"""Role of a source that feeds a model output."""

_KEYS: Final = ("name", "topic", "type", "field", "stamp", "offset", "scale", "column")
_REQUIRED: Final = ("name", "topic", "type", "field")
_BAG_KEYS: Final = ("topic", "type", "field", "stamp")  # keys a table's source cannot have
_TIME_KEYS: Final = ("column", "unit", "step_s")
_KIND_KEY: Final = "kind"  # an input's key only


class InputKind(enum.StrEnum):
    """What an input's source carries: the command sent, or a sensor's reading of the input."""

    COMMANDED = "commanded"
    """The command sent (default): it repeats exactly from period to period."""
    MEASURED = "measured"
    """Logged by a sensor (a flow meter, a force cell): it repeats only within its noise."""

    @classmethod
    def parse(cls, value: Any, where: str) -> InputKind:
        """The kind named by ``value``.

        Raises:
            InterfaceMapError: ``value`` names no kind (the message starts with ``where``).
        """
        try:
            return cls(value)
        except ValueError:
            raise InterfaceMapError(
                f"{where}: {value!r} is not an input kind; use 'commanded' (the command sent, "
                "repeating exactly; the default) or 'measured' (a sensor's reading of the "
                "input, repeating within its noise)"
            ) from None


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
        input_kinds: One :class:`InputKind` per input (empty: every input commanded); YAML
            key ``kind`` of an input.

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
    input_kinds: tuple[InputKind, ...] = ()

    def __post_init__(self) -> None:
        for role in ("inputs", "outputs"):
            value = getattr(self, role)
            if isinstance(value, Source | str) or not isinstance(value, Sequence):
                raise InterfaceMapError(f"{role}: expected a sequence of Source, found {value!r}")
            object.__setattr__(self, role, tuple(value))
        _check_sources(self.inputs, self.outputs)
        kinds = tuple(InputKind.parse(k, "input_kinds") for k in self.input_kinds)
        if kinds and len(kinds) != len(self.inputs):
            raise InterfaceMapError(
                f"input_kinds: {len(kinds)} kinds for {len(self.inputs)} inputs; give one per "
                "input (or none: every input commanded)"
            )
        object.__setattr__(
            self, "input_kinds", () if all(k is InputKind.COMMANDED for k in kinds) else kinds
        )
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
                name or ``{column: ..., unit: ...}`` (:class:`TimeColumn`). An input may say
                ``kind: commanded`` (default) or ``kind: measured`` (:class:`InputKind`).
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
        kinds: list[InputKind] = []
        for role in ("inputs", "outputs"):
            if role not in doc:
                raise InterfaceMapError(f"{source}: missing key '{role}' (a list of sources)")
            entries = doc[role]
            if not isinstance(entries, list) or not entries:
                raise InterfaceMapError(
                    f"{source}: {role}: expected a non-empty list of sources, found {entries!r}"
                )
            sources = []
            for i, node in enumerate(entries):
                where = f"{role}[{i}]"
                entry = node
                if isinstance(entry, Mapping) and _KIND_KEY in entry:
                    if role == "outputs":
                        raise InterfaceMapError(
                            f"{source}: {where}.kind: only an input has a kind ('commanded' or "
                            "'measured'); an output is always measured: drop 'kind'"
                        )
                    kinds.append(InputKind.parse(entry[_KIND_KEY], f"{source}: {where}.kind"))
                    entry = {k: v for k, v in entry.items() if k != _KIND_KEY}
                elif role == "inputs":
                    kinds.append(InputKind.COMMANDED)
                sources.append(_source_from_mapping(entry, source, where))
            lists[role] = tuple(sources)
        time = _time_from_node(doc["time"], source) if "time" in doc else None
        try:
            return cls(
                lists["inputs"],
                lists["outputs"],
                time,
                f"the interface map {source}",
                tuple(kinds),
            )
        except InterfaceMapError as err:
            raise InterfaceMapError(f"{source}: {err}") from None

    def to_dict(self) -> dict[str, Any]:
        """The YAML document of the map (:meth:`from_dict` of it gives an equal map)."""
        doc: dict[str, Any] = {
            "inputs": [
                s.to_dict() | ({_KIND_KEY: str(k)} if k is InputKind.MEASURED else {})
                for s, k in zip(self.inputs, self.kinds, strict=True)
            ],
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
    def kinds(self) -> tuple[InputKind, ...]:
        """Each input's kind, in the order of ``u`` (commanded where none was given)."""
        return self.input_kinds or (InputKind.COMMANDED,) * len(self.inputs)

    @property
    def measured_inputs(self) -> tuple[str, ...]:
        """Names of the measured inputs (:attr:`InputKind.MEASURED`), in the order of ``u``."""
        return tuple(
            s.name for s, k in zip(self.inputs, self.kinds, strict=True) if k is InputKind.MEASURED
        )

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
