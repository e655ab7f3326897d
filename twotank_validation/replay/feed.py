"""A bag or a table through the validator: :func:`replay_bag`, :func:`replay_table`.

:func:`replay_recording` takes either; both feed the one :class:`OnlineValidator` path.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import twotank_validation.bags as bag_reader
from twotank_validation import tables
from twotank_validation.core.model import LFTModel
from twotank_validation.errors import interruption
from twotank_validation.online import Alarm, OnlineValidator, WindowReport
from twotank_validation.online.aligner import COMMAND
from twotank_validation.online.extraction import check_message, extract, source_stamp_ns
from twotank_validation.online.interface_map import (
    INPUT,
    InterfaceMap,
    TopicSources,
    message_sources,
)
from twotank_validation.online.sources import STAMP_HEADER, InterfaceMapError, Source, convert
from twotank_validation.replay.config import (
    ReplayConfig,
    ReplayConfigError,
    ReplayInterrupted,
    ReplayResult,
    TimeBase,
    WindowSnapshot,
)
from twotank_validation.replay.recording import Recording, is_table_input, table_map
from twotank_validation.replay.timebase import stamp_base

BATCH = 4096  # messages decoded and validated at a time


_COLUMNAR = True  # False: the reader's row-by-row reference path (bench/bench_replay.py)


_BULK = True  # False: message by message, the generic decoder's reference path (tests)


def replay_bag(
    path: str | Path | Recording,
    models: Sequence[LFTModel],
    config: ReplayConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    on_window: Callable[[WindowReport, WindowSnapshot], None] | None = None,
    on_report: OnReport | None = None,
) -> ReplayResult:
    """Run a bag through the validator.

    Args:
        path: rosbag2 directory (MCAP or SQLite3) or a plain MCAP file, or the bag opened
            once (:func:`~twotank_validation.replay.recording.open_recording`).
        models: models to validate.
        config: topics, units and validator settings.
        progress: called with (messages read, messages expected) now and then.
        on_window: called with each judged window's report and its data (stamps, u, y in
            model units), e.g. to diagnose the windows afterwards (``diagnose``).
        on_report: called with every report as it comes (judged or not, once it is in the
            result) and the time its JSON times count from (ns): to stream the results.

    Raises:
        BagNotFoundError, BagFormatError: the path is not a readable bag (nothing to report).
        ReplayConfigError: the interface map reads a table's columns.
        ReplayInterrupted: SIGINT or SIGTERM (a KeyboardInterrupt) stopped the replay; it
            carries the result up to then.
        TimeBaseError: the map stamps some sources by their header and others by the log
            time, and in this bag the two clocks disagree
            (:func:`~twotank_validation.replay.timebase.stamp_base`).
    """
    cfg = config or ReplayConfig()
    where = path.given if isinstance(path, Recording) else path
    if cfg.interface.is_table:
        raise ReplayConfigError(
            f"{where}: the interface map reads the columns of a table, but this is read as a "
            f"bag; give a CSV or Parquet file ({', '.join(tables.TABLE_SUFFIXES)}), or a map "
            "of topics for a bag"
        )
    core = cfg.validator(models)
    result = ReplayResult(Path(where))
    report = _reporter(result, core, on_window, on_report)
    with _interruptible(result, core), _bag_of(path) as bag:
        base = stamp_base(bag, cfg.interface, cfg.jitter_fraction * cfg.monitor.ts_s)
        result.time_base, result.bag_start_ns = base.base, base.origin_ns
        result.end_ns = 0 if base.base is TimeBase.HEADER else bag.info.end_ns or 0
        _feed_bag(bag, core, cfg.interface, result, report, progress=progress)
    result.counters = dataclasses.asdict(core.counters())
    result.problems.extend(core.input_problems())
    if progress is not None:
        progress(result.messages, max(result.messages, 1))
    return result


@contextlib.contextmanager
def _bag_of(path: str | Path | Recording) -> Iterator[bag_reader.BagReader]:
    """The recording's open reader (left open), or the bag at ``path`` opened and closed."""
    if not isinstance(path, Recording):
        with bag_reader.open_bag(path) as bag:
            yield bag
        return
    if path.bag is None:
        raise ReplayConfigError(f"{path.path} was opened as a table: replay it as a table")
    yield path.bag


OnReport = Callable[[WindowReport, int], None]
"""Told each report as it comes and the time (ns) its JSON times count from."""


def _reporter(
    result: ReplayResult,
    core: OnlineValidator,
    on_window: Callable[[WindowReport, WindowSnapshot], None] | None,
    on_report: OnReport | None = None,
) -> Callable[[WindowReport], None]:
    """What is done with each report as it comes.

    Into the result (and the windows of interest), judged ones to ``on_window``, then every
    one to ``on_report``.
    """

    def report(rep: WindowReport) -> None:
        result.reports.append(rep)
        _keep_if_interesting(result, core, rep)
        if on_window is not None and rep.judged:
            stamps, u, y = core.last_window(rep.model)
            on_window(rep, WindowSnapshot(rep, stamps, u, y, core.measured_of(rep.model)))
        if on_report is not None:
            on_report(rep, result.bag_start_ns)

    return report


@contextlib.contextmanager
def _interruptible(result: ReplayResult, core: OnlineValidator) -> Iterator[None]:
    """A KeyboardInterrupt (SIGINT, SIGTERM) inside becomes :class:`ReplayInterrupted`.

    It carries the result up to then (the reports judged, the counters): nothing is lost.
    """
    try:
        yield
    except KeyboardInterrupt as stop:
        if isinstance(stop, ReplayInterrupted):
            raise
        result.interrupted = True
        result.complete = False
        result.counters = dataclasses.asdict(core.counters())
        raise ReplayInterrupted(result, interruption(stop).signum) from stop


def replay_table(
    path: str | Path | Recording,
    models: Sequence[LFTModel],
    config: ReplayConfig,
    *,
    progress: Callable[[int, int], None] | None = None,
    on_window: Callable[[WindowReport, WindowSnapshot], None] | None = None,
    on_report: OnReport | None = None,
) -> ReplayResult:
    """Run a CSV or Parquet table through the validator, row by row in time order.

    Each row goes to the validator as one message carrying every channel (the inputs as one
    command, then the outputs), as a bag's message that carries them all would. Cells
    that are empty or not numbers are NaN: their samples are flagged and the windows holding
    them are not judged, with the reason (the columns and first rows are in
    :attr:`ReplayResult.problems`).

    Args:
        path: ``.csv`` or ``.parquet`` file (:func:`twotank_validation.tables.read_table`), or
            the table read once (:func:`~twotank_validation.replay.recording.open_recording`).
        models: models to validate.
        config: validator settings; ``config.interface`` a map of columns (with the time
            column).
        progress: called with (rows fed, rows) now and then.
        on_window: called with each judged window's report and its data (stamps, u, y in
            model units).
        on_report: as :func:`replay_bag`'s.

    Raises:
        ReplayConfigError: no map, or a map of topics.
        TableError: the file, a column or a time cell cannot be read (nothing to report).
        ReplayInterrupted: as :func:`replay_bag`.
    """
    rec = path if isinstance(path, Recording) else None
    where = path.given if isinstance(path, Recording) else path
    imap = table_map(config, where)
    t_start = time.perf_counter()
    if rec is not None and rec.table is not None:
        table, read_s = rec.table, rec.read_s
    else:
        table = tables.read_table(where, imap)
        read_s = time.perf_counter() - t_start
    core = config.validator(models)
    result = ReplayResult(
        Path(where),
        source="table",
        bag_start_ns=int(table.stamps_ns[0]),
        end_ns=int(table.stamps_ns[-1]),
        time_base=TimeBase.TIME_COLUMN,
    )
    result.decode_s = read_s
    t_start = time.perf_counter()
    report = _reporter(result, core, on_window, on_report)
    stamps = table.stamps_ns.tolist()
    rows = np.concatenate([table.inputs, table.outputs], axis=1).tolist()
    with _interruptible(result, core):
        for k, stamp in enumerate(stamps):
            # a row is one message of the map's one pseudo-topic: every input and output
            for rep in core.feed("", stamp, tuple(rows[k])):
                report(rep)
            result.messages = k + 1
            if progress is not None and k % 5000 == 4999:
                progress(k + 1, len(stamps))
        for rep in core.flush():
            report(rep)
    result.validate_s = time.perf_counter() - t_start
    result.messages = len(stamps)
    for column, (count, row) in table.bad_cells.items():
        result.problems.append(
            f"column {column!r} of {where}: {count} cell(s) empty or not a number (the first in "
            f"row {row} after the header); their samples count as non-finite and the windows "
            "holding them are not judged"
        )
    result.counters = dataclasses.asdict(core.counters())
    result.problems.extend(core.input_problems())
    if progress is not None:
        progress(result.messages, max(result.messages, 1))
    return result


def replay_recording(
    path: str | Path | Recording,
    models: Sequence[LFTModel],
    config: ReplayConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    on_window: Callable[[WindowReport, WindowSnapshot], None] | None = None,
    on_report: OnReport | None = None,
) -> ReplayResult:
    """Replay a bag or a table: :func:`replay_table` or :func:`replay_bag`.

    A table is a path with a table's suffix (``.csv``, ``.parquet``, ``.pq``), or any path
    when the map reads columns (an unknown suffix is then a TableError naming it); anything
    else is a bag. Arguments as :func:`replay_bag`.
    """
    if is_table_input(path, config):
        return replay_table(
            path,
            models,
            config or ReplayConfig(),
            progress=progress,
            on_window=on_window,
            on_report=on_report,
        )
    return replay_bag(
        path, models, config, progress=progress, on_window=on_window, on_report=on_report
    )


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

    def seen(self, last_ns: int) -> None:
        """A stamp fed: the recording's end in a header time base is its latest."""
        if self.result.time_base is TimeBase.HEADER and last_ns > self.result.end_ns:
            self.result.end_ns = last_ns


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
        sink.seen(stamp)
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
        for batch in bag.field_batches(list(fields), fields, size=BATCH, columnar=_COLUMNAR):
            now = time.perf_counter()
            t_dec += now - tick
            before = result.messages
            result.messages += len(batch)
            if len(batch):
                sink.seen(int(batch.stamp_ns.max()))
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


def converted(
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
                values[at, b.position] = converted(batch, fields[name], b.source, rows)
            at = at + 1
        for b in outs:
            kinds[at] = b.position
            stamps[at] = msg_stamps
            values[at, 0] = converted(batch, fields[name], b.source, rows)
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
            vals[rows, k] = converted(batch, fields[name], b.source, rows)
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
        snap = WindowSnapshot(rep, stamps, u, y, core.measured_of(rep.model))
        for r in reasons:
            kept[r] = snap
