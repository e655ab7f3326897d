"""Validate recorded bags and tables through the live validator's code path.

Messages stream from :mod:`twotank_validation.bags.reader`, go through the same extractors as
the ROS node (:mod:`twotank_validation.online.streams`, ROS-free) and the same
:class:`~twotank_validation.online.validator.OnlineValidator` (alignment, windows, gates, alarm,
input faults). A CSV or Parquet table (:mod:`twotank_validation.tables`, read through an
interface map of columns) goes the same way, row by row: :func:`replay_table`;
:func:`replay_recording` takes either.
Memory stays bounded: only the window buffer and per-window summaries are kept, plus the samples
of a few windows of interest (largest beta, first alarm) for the figures.

Speed: messages go a few thousand at a time. The reader reads an indexed MCAP bag chunk by
chunk as arrays and decodes the three fixed-layout input types in bulk
(:meth:`~twotank_validation.bags.reader.BagReader.field_batches`, the generic deserialiser for
anything else), the extractors' unit conversions run on arrays
(:func:`~twotank_validation.online.streams.stream_values`, the same float operations), and
:meth:`~twotank_validation.online.validator.OnlineValidator.feed_many` aligns regular stretches at
once (the same samples and reports as feeding the messages one by one, which is what it does
with anything irregular). A one-hour 10 Hz bag replays for two models in about 0.3 s, most of
it the validation of the windows (``bench/bench_replay.py``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import json
import math
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import twotank_validation.bags as bag_reader
from twotank_validation import tables
from twotank_validation.core.model import LFTModel, load_model_document
from twotank_validation.defaults import JITTER_FRACTION, NS_PER_S, PERIOD_SAMPLES, TS_S
from twotank_validation.diagnose import Window
from twotank_validation.diagnose.live_jobs import catalogue_diagnosis
from twotank_validation.diagnose.stretches import WindowFindings
from twotank_validation.errors import TwotankError
from twotank_validation.online import Alarm, MonitorConfig, OnlineValidator, WindowReport
from twotank_validation.online.aligner import COMMAND
from twotank_validation.online.extraction import check_message, extract, source_stamp_ns
from twotank_validation.online.infer import (
    MIN_PERIOD_SAMPLES,
    grid_samples,
    infer_excitation_period,
    infer_sample_period,
    supported_rate,
)
from twotank_validation.online.interface_map import (
    INPUT,
    InterfaceMap,
    TopicSources,
    message_sources,
)
from twotank_validation.online.livediag import LiveDiagConfig, LiveDiagnoser
from twotank_validation.online.sources import STAMP_HEADER, InterfaceMapError, Source, convert
from twotank_validation.online.states import WindowQuality
from twotank_validation.online.streams import two_tank_map


@dataclass(frozen=True)
class ReplayConfig:
    """How to read a recording.

    Attributes:
        monitor: validator settings (as the node's parameters).
        interface: the interface map (:mod:`twotank_validation.online.interface`): each input
            and output channel read from its own topic, type, field and stamp (a bag; the
            messages are decoded from the definitions stored in the bag) or from a table's
            column, with its unit conversion; the channels are matched to the models' by
            name. Default: the two-tank preset
            (:func:`~twotank_validation.online.streams.two_tank_map`; None gives it too). A
            table (:func:`replay_table`) needs a map of columns.
        jitter_fraction: accepted stamp distance from the sample grid (fraction of ts).
        oversampling: messages per sample of topics (a table: channels) published faster
            than ``monitor.ts_s`` (name -> whole number; :attr:`Timing.oversampling`): they
            are decimated to the sample grid.
        diagnosis: run the live diagnosis (:mod:`~twotank_validation.online.livediag`):
            once a model's alarm rises, each report carries the most likely effect in force
            (``WindowReport.diagnosis``), computed synchronously, as the node's answers.
        documents: model name -> model document for the diagnosis; a model not named is
            loaded by its name (the built-in models); a model with neither is not diagnosed.
        diagnosis_config: the live diagnosis's settings.
    """

    monitor: MonitorConfig = field(default_factory=MonitorConfig)
    interface: InterfaceMap = field(default_factory=two_tank_map)
    jitter_fraction: float = JITTER_FRACTION
    oversampling: Mapping[str, int] = field(default_factory=dict)
    diagnosis: bool = False
    documents: Mapping[str, Any] = field(default_factory=dict)
    diagnosis_config: LiveDiagConfig = field(default_factory=LiveDiagConfig)

    def __post_init__(self) -> None:
        given: object = self.interface
        if given is None:  # None: the preset
            object.__setattr__(self, "interface", two_tank_map())
        elif not isinstance(given, InterfaceMap):
            raise ReplayConfigError(
                f"interface: expected an InterfaceMap, found {type(given).__name__}"
            )

    def validator(self, models: Sequence[LFTModel]) -> OnlineValidator:
        """The online validator these settings describe (the one path of every replay)."""
        return OnlineValidator(
            self.monitor,
            models,
            interface=self.interface,
            jitter_fraction=self.jitter_fraction,
            oversampling=self.oversampling,
            diagnoser=self.diagnoser(models) if self.diagnosis else None,
        )

    def diagnoser(self, models: Sequence[LFTModel]) -> LiveDiagnoser:
        """The synchronous live diagnoser of these models (their documents, see ``documents``)."""
        docs = model_documents(models, self.documents)
        cfg = dataclasses.replace(self.diagnosis_config, models=tuple(docs))
        return LiveDiagnoser(catalogue_diagnosis(docs, convention=self.monitor.convention), cfg)


def model_documents(
    models: Sequence[LFTModel], given: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Model name -> document: the given ones, else the built-in model of that name."""
    out: dict[str, Any] = {}
    for m in models:
        if given and m.name in given:
            out[m.name] = given[m.name]
            continue
        with contextlib.suppress(TwotankError, OSError):
            out[m.name] = load_model_document(m.name)[0]
    return out


class ReplayConfigError(TwotankError, ValueError):
    """A replay setting cannot be used as given (the message says what to change)."""


@dataclass(frozen=True)
class WindowSnapshot:
    """Samples of one window kept for figures: stamps (n,), u (n, nu), y (n, ny)."""

    report: WindowReport
    stamps_ns: np.ndarray
    u: np.ndarray
    y: np.ndarray


@dataclass
class ReplayResult:
    """Everything a replay found.

    Attributes:
        path: the bag or the table.
        reports: window reports in order (all models).
        complete: the whole bag was read and every expected topic was present.
        problems: what made the run incomplete or what was refused, in words (the input
            faults in the live node's words).
        counters: aligner counters (duplicates, out of order, gaps, ...).
        messages: messages read (a table: rows read).
        decode_s: wall time spent reading and decoding.
        validate_s: wall time spent aligning and validating.
        bag_start_ns: first log time in the bag, or a table's first time (reports' times are
            relative to it in JSON).
        snapshots: windows of interest per model.
        source: ``"bag"`` or ``"table"``.
        end_ns: last log time in the bag, or a table's last time (0: not known).
    """

    path: Path
    reports: list[WindowReport] = field(default_factory=list)
    complete: bool = True
    problems: list[str] = field(default_factory=list)
    counters: dict[str, int] = field(default_factory=dict)
    messages: int = 0
    decode_s: float = 0.0
    validate_s: float = 0.0
    bag_start_ns: int = 0
    snapshots: dict[str, dict[str, WindowSnapshot]] = field(default_factory=dict)
    source: str = "bag"
    end_ns: int = 0


_BATCH = 4096  # messages decoded and validated at a time
_COLUMNAR = True  # False: the reader's row-by-row reference path (bench/bench_replay.py)
_BULK = True  # False: message by message, the generic decoder's reference path (tests)


def replay_bag(
    path: str | Path,
    models: Sequence[LFTModel],
    config: ReplayConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    on_window: Callable[[WindowReport, WindowSnapshot], None] | None = None,
) -> ReplayResult:
    """Run a bag through the validator.

    Args:
        path: rosbag2 directory (MCAP or SQLite3) or a plain MCAP file.
        models: models to validate.
        config: topics, units and validator settings.
        progress: called with (messages read, messages expected) now and then.
        on_window: called with each judged window's report and its data (stamps, u, y in
            model units), e.g. to diagnose the windows afterwards (``diagnose``).

    Raises:
        BagNotFoundError, BagFormatError: the path is not a readable bag (nothing to report).
        ReplayConfigError: the interface map reads a table's columns.
    """
    cfg = config or ReplayConfig()
    if cfg.interface.is_table:
        raise ReplayConfigError(
            f"{path}: the interface map reads the columns of a table, but this is read as a "
            f"bag; give a CSV or Parquet file ({', '.join(tables.TABLE_SUFFIXES)}), or a map "
            "of topics for a bag"
        )
    core = cfg.validator(models)
    result = ReplayResult(Path(path))
    on_report = _reporter(result, core, on_window)
    with bag_reader.open_bag(path) as bag:
        result.bag_start_ns = bag.info.start_ns or 0
        result.end_ns = bag.info.end_ns or 0
        _feed_bag(bag, core, cfg.interface, result, on_report, progress=progress)
    result.counters = dataclasses.asdict(core.counters())
    result.problems.extend(core.input_problems())
    if progress is not None:
        progress(result.messages, max(result.messages, 1))
    return result


def _reporter(
    result: ReplayResult,
    core: OnlineValidator,
    on_window: Callable[[WindowReport, WindowSnapshot], None] | None,
) -> Callable[[WindowReport], None]:
    """Each report into the result (and the windows of interest), judged ones to ``on_window``."""

    def on_report(rep: WindowReport) -> None:
        result.reports.append(rep)
        _keep_if_interesting(result, core, rep)
        if on_window is not None and rep.judged:
            stamps, u, y = core.last_window(rep.model)
            on_window(rep, WindowSnapshot(rep, stamps, u, y))

    return on_report


def replay_table(
    path: str | Path,
    models: Sequence[LFTModel],
    config: ReplayConfig,
    *,
    progress: Callable[[int, int], None] | None = None,
    on_window: Callable[[WindowReport, WindowSnapshot], None] | None = None,
) -> ReplayResult:
    """Run a CSV or Parquet table through the validator, row by row in time order.

    Each row goes to the validator as one message carrying every channel (the inputs as one
    command, then the outputs), as a bag's message that carries them all would. Cells
    that are empty or not numbers are NaN: their samples are flagged and the windows holding
    them are not judged, with the reason (the columns and first rows are in
    :attr:`ReplayResult.problems`).

    Args:
        path: ``.csv`` or ``.parquet`` file (:func:`twotank_validation.tables.read_table`).
        models: models to validate.
        config: validator settings; ``config.interface`` a map of columns (with the time
            column).
        progress: called with (rows fed, rows) now and then.
        on_window: called with each judged window's report and its data (stamps, u, y in
            model units).

    Raises:
        ReplayConfigError: no map, or a map of topics.
        TableError: the file, a column or a time cell cannot be read (nothing to report).
    """
    imap = _table_map(config, path)
    t_start = time.perf_counter()
    table = tables.read_table(path, imap)
    core = config.validator(models)
    result = ReplayResult(
        Path(path),
        source="table",
        bag_start_ns=int(table.stamps_ns[0]),
        end_ns=int(table.stamps_ns[-1]),
    )
    result.decode_s = time.perf_counter() - t_start
    t_start = time.perf_counter()
    on_report = _reporter(result, core, on_window)
    stamps = table.stamps_ns.tolist()
    rows = np.concatenate([table.inputs, table.outputs], axis=1).tolist()
    for k, stamp in enumerate(stamps):
        # a row is one message of the map's one pseudo-topic: every input and output
        for rep in core.feed("", stamp, tuple(rows[k])):
            on_report(rep)
        if progress is not None and k % 5000 == 4999:
            progress(k + 1, len(stamps))
    for rep in core.flush():
        on_report(rep)
    result.validate_s = time.perf_counter() - t_start
    result.messages = len(stamps)
    for column, (count, row) in table.bad_cells.items():
        result.problems.append(
            f"column {column!r} of {path}: {count} cell(s) empty or not a number (the first in "
            f"row {row} after the header); their samples count as non-finite and the windows "
            "holding them are not judged"
        )
    result.counters = dataclasses.asdict(core.counters())
    result.problems.extend(core.input_problems())
    if progress is not None:
        progress(result.messages, max(result.messages, 1))
    return result


def _table_map(config: ReplayConfig | None, path: str | Path) -> InterfaceMap:
    """The map of columns a table is read through; else a ReplayConfigError with the fix."""
    imap = config.interface if config is not None else None
    if imap is None or not imap.is_table:
        given = "no interface map was given" if imap is None else f"{imap.label} reads topics"
        raise ReplayConfigError(
            f"{path} is a table (CSV/Parquet) but {given}; a table is read through a "
            "map of its columns: --map FILE with a 'column' per source and the time column "
            "(e.g. inputs: [{name: hot, column: valve_hot_pct, scale: 100}, ...], time: "
            "{column: t, unit: s}; docs/interface.md, Tables)"
        )
    return imap


def replay_recording(
    path: str | Path,
    models: Sequence[LFTModel],
    config: ReplayConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    on_window: Callable[[WindowReport, WindowSnapshot], None] | None = None,
) -> ReplayResult:
    """Replay a bag or a table: :func:`replay_table` or :func:`replay_bag`.

    A table is a path with a table's suffix (``.csv``, ``.parquet``, ``.pq``), or any path
    when the map reads columns (an unknown suffix is then a TableError naming it); anything
    else is a bag. Arguments as :func:`replay_bag`.
    """
    if is_table_input(path, config):
        return replay_table(
            path, models, config or ReplayConfig(), progress=progress, on_window=on_window
        )
    return replay_bag(path, models, config, progress=progress, on_window=on_window)


def is_table_input(path: str | Path, config: ReplayConfig | None = None) -> bool:
    """The recording is read as a table: a table's suffix, or a map of columns."""
    return tables.is_table(path) or (config is not None and config.interface.is_table)


def _feed_bag(
    bag: bag_reader.BagReader,
    core: OnlineValidator,
    imap: InterfaceMap,
    result: ReplayResult,
    on_report: Callable[[WindowReport], None],
    *,
    progress: Callable[[int, int], None] | None,
) -> None:
    """An interface map's topics from a bag into the validator: the one path of every bag.

    A topic the map names that is not in the bag, holds no message or carries another type is
    a problem naming the topic, the type found and what the bag holds; the other topics are
    read. Topics of ``Header header`` + float64 types whose sources read plain fields are
    decoded in bulk (:func:`_feed_bulk`); anything else message by message, decoded from the
    bag's definitions, the first message of each topic checked against the map
    (:func:`_feed_messages`).
    """
    topics = message_sources(imap)
    usable = _usable_topics(bag, topics, imap, result)
    if not usable:
        return
    total = sum(bag.info.message_counts.get(bag.resolve_topic(t) or t, 0) for t in usable)
    fields = _bulk_fields(bag, usable, topics) if _BULK else None
    sink = _Sink(core, result, on_report)
    try:
        if fields is not None:
            _feed_bulk(bag, fields, topics, sink, progress=(total, progress))
        else:
            _feed_messages(bag, usable, topics, sink)
        for rep in core.flush():
            on_report(rep)
    except bag_reader.BagCorruptError as err:
        result.complete = False
        result.problems.append(str(err))


def _usable_topics(
    bag: bag_reader.BagReader,
    topics: Mapping[str, TopicSources],
    imap: InterfaceMap,
    result: ReplayResult,
) -> list[str]:
    """The map's topics the bag holds messages of, of the map's type; problems for the rest."""
    if not any(bag.info.message_counts.values()):
        result.complete = False
        result.problems.append(
            f"bag {bag.info.path} holds no messages: record the topics of {imap.label} "
            f"({', '.join(topics)})"
        )
        return []
    usable: list[str] = []
    for topic, sources in topics.items():
        name = bag.resolve_topic(topic)
        found = bag.info.topics.get(name, "") if name is not None else ""
        if name is None:
            listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(bag.info.topics.items()))
            problem = (
                f"topic {topic!r} of {imap.label} is not in the bag {bag.info.path}; it holds: "
                f"{listing or 'no topics'}"
            )
        elif found != sources.msgtype:
            problem = (
                f"topic {topic!r} carries {found}, but {imap.label} asks for "
                f"{sources.msgtype}; set 'type: {found}' in the map with field paths of that type"
            )
        elif bag.info.message_counts.get(name, 0) == 0:
            problem = f"topic {topic!r} of {imap.label} holds no message in the bag {bag.info.path}"
        else:
            usable.append(topic)
            continue
        result.complete = False
        result.problems.append(problem)
    return usable


@dataclass(frozen=True)
class _Sink:
    """Where a recording's values go: the validator, the result and the report callback."""

    core: OnlineValidator
    result: ReplayResult
    on_report: Callable[[WindowReport], None]


def _feed_messages(
    bag: bag_reader.BagReader,
    usable: list[str],
    topics: Mapping[str, TopicSources],
    sink: _Sink,
) -> None:
    """The map's topics message by message, decoded from the bag's definitions."""
    core, result, on_report = sink.core, sink.result, sink.on_report
    checked: set[str] = set()
    refused: set[str] = set()
    bad_values = 0
    t_start = time.perf_counter()
    for m in bag.messages(usable):
        bindings = topics[m.topic].bindings
        if m.topic not in checked:
            checked.add(m.topic)
            try:
                for b in bindings:
                    check_message(b.source, m.msg, m.msgtype)
            except InterfaceMapError as err:
                refused.add(m.topic)
                result.complete = False
                result.problems.append(str(err))
        if m.topic in refused:
            continue
        result.messages += 1
        values = []
        for b in bindings:
            try:
                values.append(extract(m.msg, b.source))
            except InterfaceMapError:
                values.append(math.nan)  # flagged as non-finite
                bad_values += 1
        stamp = source_stamp_ns(m.msg, bindings[0].source, m.log_time_ns)
        for rep in core.feed(m.topic, stamp, tuple(values)):
            on_report(rep)
    if bad_values:
        result.problems.append(
            f"{bad_values} value(s) could not be read through the map's field paths (e.g. an "
            "array shorter than the index); they count as non-finite samples"
        )
    result.decode_s = time.perf_counter() - t_start  # decoding and validating interleave here


def _bulk_fields(
    bag: bag_reader.BagReader, usable: list[str], topics: Mapping[str, TopicSources]
) -> dict[str, tuple[str, ...]] | None:
    """Topic -> the float64 fields the map reads, if every usable topic can be read in bulk.

    That is when each of its sources reads a plain field of the message (no ``.`` or
    ``[i]``) of a ``Header header`` + float64 type (:meth:`BagReader.float_fields`): such a
    message always fits the map (the field is a number, the header has a stamp), and
    ``field_batches`` gives each field as ``float(msg.<field>)`` and ``header.stamp``.
    """
    out: dict[str, tuple[str, ...]] = {}
    for topic in usable:
        layout = bag.float_fields(topic)
        paths = [b.source.path for b in topics[topic].bindings]
        if layout is None or any(
            len(p) != 1 or not isinstance(p[0], str) or p[0] not in layout for p in paths
        ):
            return None
        out[topic] = tuple(dict.fromkeys(str(p[0]) for p in paths))
    return out


def _feed_bulk(
    bag: bag_reader.BagReader,
    fields: dict[str, tuple[str, ...]],
    topics: Mapping[str, TopicSources],
    sink: _Sink,
    *,
    progress: tuple[int, Callable[[int, int], None] | None],
) -> None:
    """The map's topics decoded in bulk and fed many events at a time.

    Each message becomes its events in map order: a whole command where its topic carries
    every input, then one event per output it carries (:meth:`OnlineValidator.feed_many`,
    the same reports as feeding the messages one by one). A map whose inputs are spread over
    several topics feeds message by message instead (the inputs are assembled). The values
    are :func:`~twotank_validation.online.interface.convert`'s, the float operations of
    ``extract``.
    """
    core, result, on_report = sink.core, sink.result, sink.on_report
    total, report_progress = progress
    n_in = core.channels.n_inputs
    width = max(n_in, 1)
    events = all(sum(b.role == INPUT for b in topics[t].bindings) in (0, n_in) for t in fields)
    t_dec = t_val = 0.0
    tick = time.perf_counter()
    try:
        for batch in bag.field_batches(list(fields), fields, size=_BATCH, columnar=_COLUMNAR):
            now = time.perf_counter()
            t_dec += now - tick
            before = result.messages
            result.messages += len(batch)
            if events:
                core.feed_many(*_events(batch, fields, topics, width), on_report)
            else:
                _feed_rows(batch, fields, topics, core, on_report)
            tick = time.perf_counter()
            t_val += tick - now
            if report_progress is not None:
                for m in range((before // 5000 + 1) * 5000, result.messages + 1, 5000):
                    report_progress(m, total)
    finally:
        result.decode_s, result.validate_s = t_dec, t_val


def _converted(
    batch: bag_reader.FieldBatch, fields: tuple[str, ...], source: Source, rows: np.ndarray
) -> np.ndarray:
    """(m,) model-unit values of ``source`` in the batch's ``rows`` of its topic."""
    return convert(batch.values[rows, fields.index(str(source.path[0]))], source)


def _events(
    batch: bag_reader.FieldBatch,
    fields: dict[str, tuple[str, ...]],
    topics: Mapping[str, TopicSources],
    width: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A batch's messages as the validator's events: ``(kinds, stamps_ns, values)``.

    A message of a topic that carries every input gives one command event (its inputs in
    input order), then each output it carries one event, in map order; events in message
    order. Shapes: (e,), (e,) int64, (e, width) float (NaN where unused).
    """
    plans = []
    for name in batch.topics:
        bindings = topics[name].bindings
        ins = sorted((b for b in bindings if b.role == INPUT), key=lambda b: b.position)
        outs = [b for b in bindings if b.role != INPUT]
        plans.append((ins, outs))
    counts = np.array([(1 if ins else 0) + len(outs) for ins, outs in plans], dtype=np.int64)
    per_msg = counts[batch.topic]
    first = np.cumsum(per_msg) - per_msg
    n_ev = int(per_msg.sum())
    kinds = np.empty(n_ev, dtype=np.int8)
    stamps = np.empty(n_ev, dtype=np.int64)
    values = np.full((n_ev, width), np.nan)
    for j, (name, (ins, outs)) in enumerate(zip(batch.topics, plans, strict=True)):
        rows = np.flatnonzero(batch.topic == j)
        if not len(rows):
            continue
        header = topics[name].bindings[0].source.stamp == STAMP_HEADER
        msg_stamps = (batch.stamp_ns if header else batch.log_time_ns)[rows]
        at = first[rows]
        if ins:
            kinds[at] = COMMAND
            stamps[at] = msg_stamps
            for b in ins:
                values[at, b.position] = _converted(batch, fields[name], b.source, rows)
            at = at + 1
        for b in outs:
            kinds[at] = b.position
            stamps[at] = msg_stamps
            values[at, 0] = _converted(batch, fields[name], b.source, rows)
            at = at + 1
    return kinds, stamps, values


def _feed_rows(
    batch: bag_reader.FieldBatch,
    fields: dict[str, tuple[str, ...]],
    topics: Mapping[str, TopicSources],
    core: OnlineValidator,
    on_report: Callable[[WindowReport], None],
) -> None:
    """A batch decoded in bulk, fed message by message (inputs spread over topics)."""
    columns = []
    for j, name in enumerate(batch.topics):
        rows = np.flatnonzero(batch.topic == j)
        bindings = topics[name].bindings
        vals = np.full((len(batch), len(bindings)), np.nan)
        for k, b in enumerate(bindings):
            vals[rows, k] = _converted(batch, fields[name], b.source, rows)
        header = bindings[0].source.stamp == STAMP_HEADER
        columns.append((name, vals.tolist(), header))
    stamps, logs = batch.stamp_ns.tolist(), batch.log_time_ns.tolist()
    for i, j in enumerate(batch.topic.tolist()):
        name, vals, header = columns[j]
        for rep in core.feed(name, stamps[i] if header else logs[i], tuple(vals[i])):
            on_report(rep)


def _keep_if_interesting(result: ReplayResult, core: OnlineValidator, rep: WindowReport) -> None:
    if not rep.judged:
        return
    kept = result.snapshots.setdefault(rep.model, {})
    reasons = []
    best = kept.get("max_beta")
    if best is None or rep.beta > best.report.beta:
        reasons.append("max_beta")
    if rep.alarm is Alarm.ERROR and "first_alarm" not in kept:
        reasons.append("first_alarm")
    if reasons:
        stamps, u, y = core.last_window(rep.model)
        snap = WindowSnapshot(rep, stamps, u, y)
        for r in reasons:
            kept[r] = snap


def warning_kind(text: str) -> str:
    """A warning's kind: its text up to the first number (``"output mean drifts by up to"``).

    The numbers differ from window to window; counting by kind keeps the per-model list short
    on a long run (each window's exact texts stay in its own entry).
    """
    head = re.split(r"[-+]?\d", text, maxsplit=1)[0].strip()
    return head.rstrip(" (:") or text


def summary_json(result: ReplayResult, model_names: Sequence[str] = ()) -> dict[str, Any]:
    """The documented JSON (docs/cli.md, "validate JSON"): times in seconds of bag time.

    Args:
        result: the replay.
        model_names: models to list even if they got no window (the recording too short, a
            topic missing): each with no windows and nothing judged.
    """
    t0 = result.bag_start_ns

    def sec(ns: int) -> float:
        return (ns - t0) / NS_PER_S

    def empty() -> dict[str, Any]:
        return {
            "windows": [],
            "beta_max": None,
            "first_alarm": None,
            "judged": 0,
            "not_judged": 0,
            "not_judged_reasons": {},
            "with_warnings": 0,
            "warnings": {},
        }

    models: dict[str, Any] = {name: empty() for name in model_names}
    for rep in result.reports:
        entry = models.setdefault(rep.model, empty())
        if rep.judged:
            entry["judged"] += 1
        else:
            entry["not_judged"] += 1
            why = reason_category(rep.quality)
            entry["not_judged_reasons"][why] = entry["not_judged_reasons"].get(why, 0) + 1
        if rep.warnings:
            entry["with_warnings"] += 1
            for text in rep.warnings:
                kind = warning_kind(text)
                entry["warnings"][kind] = entry["warnings"].get(kind, 0) + 1
        entry["windows"].append(
            {
                "start": sec(rep.start_ns),
                "end": sec(rep.end_ns),
                "beta": rep.beta if rep.judged and math.isfinite(rep.beta) else None,
                "invalidated": bool(rep.invalidated),
                "alarm": rep.alarm.name,
                "reason": None if rep.judged else rep.data_quality,
                "data_quality": rep.data_quality,
                "margin": rep.margin if rep.judged and math.isfinite(rep.margin) else None,
                "warnings": list(rep.warnings),
                "beta_op": rep.beta_op if math.isfinite(rep.beta_op) else None,
                "beta_total": rep.beta_total if math.isfinite(rep.beta_total) else None,
                "raised_by": str(rep.raised_by),
                "operating_point": rep.operating_point,
                "diagnosis": None if rep.diagnosis is None else rep.diagnosis.to_json(),
            }
        )
        if (
            rep.judged
            and math.isfinite(rep.beta)
            and (entry["beta_max"] is None or rep.beta > entry["beta_max"])
        ):
            entry["beta_max"] = rep.beta
        if rep.alarm is Alarm.ERROR and entry["first_alarm"] is None:
            entry["first_alarm"] = sec(rep.end_ns)
    return {
        "bag": str(result.path),
        "source": result.source,
        "complete": result.complete,
        "problems": list(result.problems),
        "messages": result.messages,
        "counters": dict(result.counters),
        "models": models,
    }


def reason_category(quality: WindowQuality) -> str:
    """The kind of reason a window was not judged, for counting: its typed state.

    A window with unusable samples whose first flagged sample is a gap is
    ``"unusable samples (gap)"``; one still settling ``"settling"``
    (:attr:`~twotank_validation.online.states.WindowQuality.category`).
    """
    return quality.category


@dataclass(frozen=True)
class Timing:
    """The sample and excitation periods a replay uses, where they came from, and doubts.

    Attributes:
        ts_s: sample period (s).
        period_samples: excitation period (samples).
        ts_from: ``"option"``, ``"bag metadata"``, ``"command stamps"`` or ``"default"``.
        period_from: ``"option"``, ``"bag metadata"``, ``"commands"`` or ``"default"``.
        data_ts_s: the grid the command stamps lie on (s), None if not inferred.
        data_period_samples: the shift under which the commands repeat, None if they do not
            repeat in the record (or were not read).
        notes: what was taken or inferred, and why, in words.
        conflicts: options or metadata that the data contradict, with the value the data
            suggest (``"stamps lie on a 0.5 s grid: pass --ts 0.5"``).
        stream_ts_s: each stream's period found in its stamps (s), where it has a grid.
        oversampling: messages per sample of the streams published faster than ``ts_s``
            (stream -> whole number > 1): they are decimated to the sample grid.
    """

    ts_s: float
    period_samples: int
    ts_from: str
    period_from: str
    data_ts_s: float | None = None
    data_period_samples: int | None = None
    notes: tuple[str, ...] = ()
    conflicts: tuple[str, ...] = ()
    stream_ts_s: dict[str, float] = field(default_factory=dict)
    oversampling: dict[str, int] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The JSON form (``timing`` in the validate and diagnose JSON)."""
        return dataclasses.asdict(self) | {
            "notes": list(self.notes),
            "conflicts": list(self.conflicts),
        }


def _metadata_timing(custom: Mapping[str, str]) -> tuple[float | None, int | None]:
    """ts_s and period_samples from a bag's custom_data (a scenario's, or plain keys)."""
    from twotank_validation.bags.scenario_bag import CUSTOM_DATA_KEY  # noqa: PLC0415

    doc: dict[str, Any] = {}
    if CUSTOM_DATA_KEY in custom:
        try:
            loaded = json.loads(custom[CUSTOM_DATA_KEY])
        except ValueError:
            loaded = None
        doc = loaded if isinstance(loaded, dict) else {}
    doc = {k: custom[k] for k in ("ts_s", "period_samples") if k in custom} | doc
    ts = period = None
    with contextlib.suppress(TypeError, ValueError):
        ts = float(doc["ts_s"]) if "ts_s" in doc else None
    with contextlib.suppress(TypeError, ValueError):
        period = int(doc["period_samples"]) if "period_samples" in doc else None
    ts = ts if ts is not None and math.isfinite(ts) and ts > 0 else None
    period = period if period is not None and period >= MIN_PERIOD_SAMPLES else None
    return ts, period


def _command_record(
    bag: bag_reader.BagReader, imap: InterfaceMap
) -> tuple[np.ndarray, np.ndarray] | None:
    """Stamps (n,) ns and model-unit values (n, m) of the commands, None if unreadable.

    The inputs the first input's topic carries (m of them; every input where one topic
    carries the command), stamped as the map says.
    """
    topic = imap.inputs[0].topic
    sources = [s for s in imap.inputs if s.topic == topic]
    return _topic_record(bag, topic, sources)


def _topic_record(
    bag: bag_reader.BagReader,
    topic: str,
    sources: Sequence[Source],
    limit: int | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Stamps (n,) ns and model-unit values (n, len(sources)) of one topic, None if unreadable.

    Read in bulk where the topic's type allows (:func:`_bulk_fields`), else message by
    message. ``limit``: at most this many messages (all if None).
    """
    name = bag.resolve_topic(topic)
    if (
        name is None
        or bag.info.topics.get(name) != sources[0].msgtype
        or not bag.info.message_counts.get(name, 0)
    ):
        return None
    stamps: list[Any] = []
    values: list[Any] = []
    header = sources[0].stamp == STAMP_HEADER
    layout = bag.float_fields(topic)
    plain = layout is not None and all(
        len(s.path) == 1 and isinstance(s.path[0], str) and s.path[0] in layout for s in sources
    )
    with contextlib.suppress(bag_reader.BagCorruptError, InterfaceMapError):
        if plain:
            fields = {topic: tuple(dict.fromkeys(str(s.path[0]) for s in sources))}
            for batch in bag.field_batches([topic], fields, size=_BATCH):
                rows = np.arange(len(batch))
                stamps.append(batch.stamp_ns if header else batch.log_time_ns)
                values.append(
                    np.column_stack([_converted(batch, fields[topic], s, rows) for s in sources])
                )
                if limit is not None and sum(map(len, stamps)) >= limit:
                    break
        else:
            for m in bag.messages([topic]):
                values.append([[extract(m.msg, s) for s in sources]])
                stamps.append([source_stamp_ns(m.msg, sources[0], m.log_time_ns)])
                if limit is not None and len(stamps) >= limit:
                    break
    if not stamps:
        return None
    out_s = np.concatenate([np.asarray(x, dtype=np.int64) for x in stamps])
    out_v = np.concatenate([np.asarray(x, dtype=float) for x in values])
    return (out_s, out_v) if limit is None else (out_s[:limit], out_v[:limit])


_RATE_MESSAGES = 4096
"""Messages per output topic read to find its period (its first ones)."""


def _output_stamps(bag: bag_reader.BagReader, imap: InterfaceMap) -> dict[str, np.ndarray]:
    """Stamps (n,) ns of each output topic's first messages (topics that can be read)."""
    out: dict[str, np.ndarray] = {}
    for src in imap.outputs:
        if src.topic in out:
            continue
        rec = _topic_record(bag, src.topic, [src], limit=_RATE_MESSAGES)
        if rec is not None:
            out[src.topic] = rec[0]
    return out


def _fmt_s(x: float) -> str:
    return f"{x:.9g}"


def resolve_timing(
    path: str | Path,
    config: ReplayConfig | None = None,
    *,
    ts_s: float | None = None,
    period_samples: int | None = None,
) -> Timing:
    """Choose the sample and excitation periods of a recording: option, else metadata, else data.

    An explicit value (``ts_s``, ``period_samples``) always wins; where the bag's metadata
    or the command stream contradicts it, :attr:`Timing.conflicts` says so with the value
    the data suggest. Without one, the bag's metadata (a scenario bag's, or ``ts_s`` and
    ``period_samples`` in its custom_data) are used, else the grid of the command stamps
    (:func:`~twotank_validation.online.infer.infer_sample_period`) and the shift under
    which the commands repeat (:func:`~twotank_validation.online.infer.
    infer_excitation_period`), else the defaults. A table (:func:`is_table_input`) has no
    metadata: its time column and its first input column are the data.

    Args:
        path: the bag or the table.
        config: topics (the command topic is read) or the map, and the window gate's
            tolerance.
        ts_s: sample period given by the user (s), or None.
        period_samples: excitation period given by the user (samples), or None.

    Raises:
        BagError subclasses: the path is not a readable bag.
        TableError, ReplayConfigError: the path is a table that cannot be read through the
            map (or there is no map of columns).
    """
    cfg = config or ReplayConfig()
    imap = cfg.interface
    meta_ts: float | None
    meta_period: int | None
    record: tuple[np.ndarray, np.ndarray] | None
    if is_table_input(path, cfg):
        table = tables.read_table(path, _table_map(cfg, path))
        meta_ts = meta_period = None
        record = (table.stamps_ns, table.inputs)
        command = imap.inputs[0].name
        out_stamps = {
            name: table.stamps_ns[np.isfinite(table.outputs[:, i])]
            for i, name in enumerate(imap.output_names)
        }
    else:
        command = imap.inputs[0].topic
        with bag_reader.open_bag(path) as bag:
            meta_ts, meta_period = _metadata_timing(bag.info.custom_data)
            record = _command_record(bag, imap)
            out_stamps = _output_stamps(bag, imap)
    notes: list[str] = []
    conflicts: list[str] = []
    grid = infer_sample_period(record[0]) if record is not None else None
    data_ts = grid.ts_s if grid is not None and grid.on_grid >= 0.5 else None
    stream_ts = {command: data_ts} if data_ts is not None else {}
    for name, stamps in out_stamps.items():
        g = infer_sample_period(stamps)
        if g is not None and g.on_grid >= 0.5:
            stream_ts[name] = g.ts_s
    # the grid every output has a sample on: a multiple of the commands' step
    rates = (
        supported_rate(data_ts, {k: v for k, v in stream_ts.items() if k != command}, command)
        if data_ts is not None
        else None
    )
    slow = rates is not None and rates.factor > 1
    supported = data_ts * rates.factor if rates is not None and data_ts is not None else None

    def differs(a: float, b: float) -> bool:
        return abs(a - b) > 0.01 * b

    def multiple(a: float, b: float) -> bool:  # a is a whole multiple of b
        return round(a / b) >= 1 and not differs(a, round(a / b) * b)

    def slow_streams() -> str:
        assert data_ts is not None
        return ", ".join(
            f"{name} every {_fmt_s(t)} s"
            for name, t in stream_ts.items()
            if name != command and differs(t, data_ts) and t > data_ts
        )

    if ts_s is not None:
        ts, ts_from = ts_s, "option"
        if data_ts is not None and supported is not None and not multiple(ts_s, supported):
            fix = f"pass --ts {_fmt_s(supported)}"
            if slow:
                conflicts.append(
                    f"--ts {_fmt_s(ts_s)} does not fit the data: {slow_streams()}, the commands "
                    f"every {_fmt_s(data_ts)} s: not every sample would have a value of each; "
                    f"{fix} (the rate the data support)"
                )
            else:
                conflicts.append(
                    f"--ts {_fmt_s(ts_s)} does not fit the data: the command stamps lie on a "
                    f"{_fmt_s(data_ts)} s grid: {fix}"
                )
    elif (
        slow
        and supported is not None
        and data_ts is not None
        and (meta_ts is None or not differs(meta_ts, data_ts))
    ):
        ts, ts_from = supported, "stream rates"
        notes.append(
            f"sample period {_fmt_s(ts)} s, the rate the data support: {slow_streams()}, the "
            f"commands every {_fmt_s(data_ts)} s; the faster streams are decimated to it; "
            "--ts overrides"
        )
    elif meta_ts is not None:
        ts, ts_from = meta_ts, "bag metadata"
        notes.append(f"sample period {_fmt_s(ts)} s from the bag's metadata")
        if data_ts is not None and differs(meta_ts, data_ts):
            conflicts.append(
                f"the bag's metadata say ts {_fmt_s(meta_ts)} s but the command stamps lie on "
                f"a {_fmt_s(data_ts)} s grid: pass --ts {_fmt_s(data_ts)} if the stamps are right"
            )
    elif data_ts is not None and grid is not None:
        ts, ts_from = data_ts, "command stamps"
        notes.append(
            f"sample period {_fmt_s(ts)} s inferred from the command stamps "
            f"({grid.n_stamps} stamps, {100 * grid.on_grid:.1f} % one step apart, "
            f"{grid.steps_missing} step(s) without a message); --ts overrides"
        )
    else:
        ts, ts_from = TS_S, "default"
        notes.append(
            f"sample period {_fmt_s(ts)} s (the default): no --ts, no metadata, and the "
            "command stamps show no grid; pass --ts"
        )
    # the commands' repetition on their own grid, in samples of that grid and in seconds
    data_period = None
    grid_ts = data_ts if data_ts is not None else ts
    if record is not None:
        u = grid_samples(record[0], record[1], grid_ts)
        data_period = infer_excitation_period(u, cfg.monitor.input_periodic_rtol)

    def in_steps(n: int, step_s: float) -> int | None:
        """``n`` samples of ``step_s`` in samples of ``ts``, if a whole number."""
        m = n * step_s / ts
        return round(m) if abs(m - round(m)) <= 1e-6 * max(m, 1.0) and round(m) >= 1 else None

    def period_doubt(given: int, what: str) -> str | None:
        if data_period is None or abs(given * ts - data_period * grid_ts) <= 0.5 * grid_ts:
            return None
        seen = f"the commands repeat every {_fmt_s(data_period * grid_ts)} s"
        here = in_steps(data_period, grid_ts)
        if grid_ts != ts:
            seen += f" ({data_period} samples of {_fmt_s(grid_ts)} s)"
        return (
            f"{what} {given} ({_fmt_s(given * ts)} s at ts {_fmt_s(ts)} s) does not fit the "
            f"data: {seen}: pass --period "
            + (f"{here}" if here is not None else f"{data_period} with --ts {_fmt_s(grid_ts)}")
        )

    if period_samples is not None:
        period, period_from = period_samples, "option"
        if doubt := period_doubt(period_samples, "--period"):
            conflicts.append(doubt)
    elif meta_period is not None and (
        meta_ts is None or (meta_here := in_steps(meta_period, meta_ts)) is not None
    ):
        period, period_from = meta_period, "bag metadata"
        if meta_ts is not None and differs(ts, meta_ts):
            assert meta_here is not None
            period = meta_here
            notes.append(
                f"excitation period {period} samples from the bag's metadata "
                f"({meta_period} samples of {_fmt_s(meta_ts)} s)"
            )
        else:
            notes.append(f"excitation period {period} samples from the bag's metadata")
        if doubt := period_doubt(period, "the bag's metadata period"):
            conflicts.append(doubt)
    elif data_period is not None and (data_here := in_steps(data_period, grid_ts)) is not None:
        period, period_from = data_here, "commands"
        notes.append(
            f"excitation period {period} samples ({_fmt_s(period * ts)} s) inferred from the "
            "commands (the smallest shift under which they repeat); --period overrides"
        )
    else:
        period, period_from = PERIOD_SAMPLES, "default"
        notes.append(
            f"excitation period {period} samples (the default): no --period, no metadata, and "
            "the commands do not repeat within the recording; pass --period"
        )
    # each stream published a whole number of times per sample (> 1) is decimated
    over = {
        name: round(ts / t)
        for name, t in stream_ts.items()
        if round(ts / t) > 1 and multiple(ts, t)
    }
    if over and ts_from != "stream rates":
        notes.append(
            f"ts {_fmt_s(ts)} s spans several messages of "
            + ", ".join(f"{name} (every {n}th kept)" for name, n in over.items())
        )
    return Timing(
        ts_s=ts,
        period_samples=period,
        ts_from=ts_from,
        period_from=period_from,
        data_ts_s=data_ts,
        data_period_samples=data_period,
        notes=tuple(notes),
        conflicts=tuple(conflicts),
        stream_ts_s=stream_ts,
        oversampling=over,
    )


_FIXES: dict[str, str] = {
    "settling": (
        "the recording holds too few whole periods for the settling and window periods: "
        "record longer, or check --period"
    ),
    "input not periodic": (
        "the commands do not repeat every --period samples: pass the excitation period "
        "(--period), or --closed-loop if a controller computed them"
    ),
    "too little excitation": (
        "the inputs hardly move: check the command topic (--topic flow_cmd=...) and that the "
        "excitation was on"
    ),
    "unusable samples (gap)": (
        "samples are missing on the sample grid: check --ts and that every topic was recorded"
    ),
    "unusable samples (non-finite)": (
        "the data hold non-finite or implausible values: check the topics and their units"
    ),
    "unusable samples (off grid)": (
        "stamps fall between the samples of the grid: check --ts (the command stamps' grid)"
    ),
    "unusable samples (no command)": "no valid valve command: check the command topic",
}


def unjudged_models(
    summary: Mapping[str, Any],
    timing: Timing | None = None,
    config: ReplayConfig | None = None,
) -> list[str]:
    """One line per model of which no window could be judged: the main reason and the fix.

    Args:
        summary: :func:`summary_json` of the replay (models without any window listed too).
        timing: the timing used (adds what the data suggest to the fix), or None.
        config: the replay settings (to say how long a recording one window needs).
    """
    out = []
    hints = list(timing.conflicts) if timing is not None else []
    for name, entry in summary["models"].items():
        if entry["judged"]:
            continue
        reasons = entry["not_judged_reasons"]
        if reasons:
            main = max(reasons, key=reasons.get)
            why = f"{main} ({reasons[main]} of {entry['not_judged']} window(s))"
            fix = _FIXES.get(main, "see each window's reason in the JSON")
        elif summary["problems"]:
            why, fix = "no window was formed", summary["problems"][0]
        else:
            why = "the recording holds no whole window"
            fix = "record longer"
            if config is not None:
                mon = config.monitor
                need = (mon.settle_periods + mon.periods_per_window) * mon.period_samples
                fix = (
                    f"one window needs {need} samples ({_fmt_s(need * mon.ts_s)} s: "
                    f"{mon.settle_periods} settling + {mon.periods_per_window} window periods "
                    f"of {mon.period_samples}): record longer or check --period"
                )
        out.append(f"no window of model {name} could be judged: {why}; " + "; ".join([fix, *hints]))
    return out


def windows_from_bag(
    path: str | Path, model: LFTModel, config: ReplayConfig | None = None
) -> tuple[list[Window], ReplayResult]:
    """The judged, non-overlapping windows of a bag, read through the replay path.

    Args:
        path: rosbag2 directory or MCAP file.
        model: the model (the replay validates it on the way; its reports are returned).
        config: topics, units, window settings.

    Returns:
        ``(windows, replay_result)``; windows are in time order, times in s from the bag
        start.

    Raises:
        BagError subclasses: the path is not a readable bag.
    """
    windows, _, result = _windows(replay_bag, path, model, config)
    return windows, result


def windows_from_recording(
    path: str | Path, model: LFTModel, config: ReplayConfig | None = None
) -> tuple[list[Window], ReplayResult]:
    """The judged, non-overlapping windows of a bag or a table (:func:`replay_recording`).

    As :func:`windows_from_bag`; a table's times are in s from its first row.

    Raises:
        BagError subclasses, TableError, ReplayConfigError: as :func:`replay_recording`.
    """
    windows, _, result = _windows(replay_recording, path, model, config)
    return windows, result


def windows_with_findings(
    path: str | Path,
    model: LFTModel,
    config: ReplayConfig | None = None,
    *,
    start: float | str | None = None,
    end: float | str | None = None,
) -> tuple[list[Window], list[WindowFindings], ReplayResult]:
    """As :func:`windows_from_recording`, with what the validator found in each window.

    Args:
        path: the bag or table, as :func:`windows_from_recording`.
        model: the model.
        config: topics, units, window settings.
        start: keep only the windows wholly inside ``start`` .. ``end``: seconds from the
            recording start, or an ISO 8601 time (:func:`range_time_s`); None: from the
            first window.
        end: the end of the range, as ``start``; None: to the last window.

    Returns:
        ``(windows, findings, replay_result)``: one
        :class:`~twotank_validation.diagnose.stretches.WindowFindings` per window (its beta,
        beta_op, data quality and warnings: a transient still decaying, ...).

    Raises:
        ReplayConfigError: a range that ends before it starts, lies outside the recording,
            or holds no whole window; and as :func:`windows_from_recording`.
    """
    windows, reports, result = _windows(replay_recording, path, model, config)
    start_s = None if start is None else range_time_s(start, result.bag_start_ns)
    end_s = None if end is None else range_time_s(end, result.bag_start_ns)
    if start_s is not None and end_s is not None and end_s <= start_s:
        raise ReplayConfigError(
            f"the range ends ({end_s:g} s) before it starts ({start_s:g} s): give --end "
            "after --start"
        )
    length = (result.end_ns - result.bag_start_ns) / NS_PER_S if result.end_ns else math.inf
    for name, t in (("start", start_s), ("end", end_s)):
        if t is not None and not (0.0 <= t <= length):
            raise ReplayConfigError(
                f"--{name} {t:g} s lies outside the recording (0 to {length:.1f} s from its start)"
            )
    lo = -math.inf if start_s is None else start_s
    hi = math.inf if end_s is None else end_s
    keep = [
        i
        for i, w in enumerate(windows)
        if w.start_s >= lo - 1e-9 and w.start_s + w.u.shape[0] * w.ts_s <= hi + 1e-9
    ]
    if windows and not keep:
        spans = ", ".join(
            f"{w.start_s:.1f}-{w.start_s + w.u.shape[0] * w.ts_s:.1f}" for w in windows[:6]
        )
        raise ReplayConfigError(
            f"no whole judged window lies inside {lo:g} .. {hi:g} s; the judged windows span "
            f"{spans}{' ...' if len(windows) > 6 else ''} s: widen the range"
        )
    findings = [
        WindowFindings(
            beta=float(reports[i].beta),
            beta_op=float(reports[i].beta_op),
            data_quality=reports[i].data_quality,
            warnings=tuple(reports[i].warnings),
        )
        for i in keep
    ]
    return [windows[i] for i in keep], findings, result


def range_time_s(value: float | str, start_ns: int) -> float:
    """A range limit in s from the recording start: a number of seconds, or an ISO 8601 time.

    An ISO time without a zone is UTC (``2024-05-01T12:30:00``, ``...+02:00``, ``...Z``).

    Raises:
        ReplayConfigError: neither a number nor an ISO time.
    """
    if not isinstance(value, str):
        return float(value)
    try:
        return float(value)
    except ValueError:
        pass
    try:
        when = datetime.datetime.fromisoformat(value)
    except ValueError:
        raise ReplayConfigError(
            f"{value!r} is neither seconds from the recording start nor an ISO 8601 time "
            "(e.g. 1500 or 2024-05-01T12:30:00+00:00)"
        ) from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=datetime.UTC)
    epoch = datetime.datetime(1970, 1, 1, tzinfo=datetime.UTC)
    ns = (when - epoch) // datetime.timedelta(microseconds=1) * 1000
    return (ns - start_ns) / NS_PER_S


def _windows(
    replay: Callable[..., ReplayResult],
    path: str | Path,
    model: LFTModel,
    config: ReplayConfig | None,
) -> tuple[list[Window], list[WindowReport], ReplayResult]:
    cfg = config or ReplayConfig()
    kept: list[tuple[int, WindowSnapshot]] = []

    def collect(rep: WindowReport, snap: WindowSnapshot) -> None:
        if kept and snap.stamps_ns[0] <= kept[-1][1].stamps_ns[-1]:
            return  # overlaps the last kept window
        kept.append((int(snap.stamps_ns[0]), snap))

    result = replay(path, [model], cfg, on_window=collect)
    t0 = result.bag_start_ns
    mon = cfg.monitor
    windows = [
        Window(snap.u, snap.y, mon.ts_s, mon.period_samples, (start - t0) * 1e-9)
        for start, snap in kept
    ]
    return windows, [snap.report for _, snap in kept], result
