"""The sample and excitation periods of a recording: the option, else metadata, else the data."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

import twotank_validation.bags as bag_reader
from twotank_validation import tables
from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.online.extraction import extract, source_stamp_ns
from twotank_validation.online.infer import (
    MIN_PERIOD_SAMPLES,
    grid_samples,
    infer_excitation_period,
    infer_sample_period,
    supported_rate,
)
from twotank_validation.online.interface_map import InputKind, InterfaceMap
from twotank_validation.online.sources import STAMP_HEADER, InterfaceMapError, Source
from twotank_validation.replay.config import ReplayConfig
from twotank_validation.replay.feed import BATCH, converted
from twotank_validation.replay.recording import Recording, is_table_input, table_map
from twotank_validation.replay.timebase import BagClocks, bag_clocks


class TimingSetting(StrEnum):
    """A timing setting that the data can contradict."""

    TS = "ts_s"
    """The sample period (s)."""
    PERIOD = "period_samples"
    """The excitation period (samples)."""


class GivenBy(StrEnum):
    """Who gave a timing value the data contradict."""

    OPTION = "option"
    METADATA = "bag metadata"


@dataclass(frozen=True)
class TimingConflict:
    """A timing value given (option or metadata) that the data contradict.

    Attributes:
        setting: which setting.
        given_by: who gave it.
        value: the value given (s for ``TS``, samples for ``PERIOD``).
        suggested: the value the data suggest (same unit).
        suggested_ts_s: for a period that is no whole number of samples of ``ts``: the sample
            period (s) at which ``suggested`` holds; None otherwise.
        text: the conflict in words (``"... pass --ts 0.5"``).
    """

    setting: TimingSetting
    given_by: GivenBy
    value: float
    suggested: float
    suggested_ts_s: float | None
    text: str


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
        findings: the conflicts, typed (:class:`TimingConflict`: the setting, who gave it,
            its value and the value the data suggest); ``conflicts`` holds their words.
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
    findings: tuple[TimingConflict, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """The JSON form (``timing`` in the validate and diagnose JSON; conflicts in words)."""
        out = dataclasses.asdict(self) | {
            "notes": list(self.notes),
            "conflicts": list(self.conflicts),
        }
        del out["findings"]
        return out


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


def _measured_commands(imap: InterfaceMap, table: bool) -> np.ndarray:
    """(m,) bool: which of the command record's inputs are measured (:func:`_command_record`)."""
    topic = imap.inputs[0].topic
    return np.array(
        [
            kind is InputKind.MEASURED
            for src, kind in zip(imap.inputs, imap.kinds, strict=True)
            if table or src.topic == topic
        ]
    )


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
            for batch in bag.field_batches([topic], fields, size=BATCH):
                rows = np.arange(len(batch))
                stamps.append(batch.stamp_ns if header else batch.log_time_ns)
                values.append(
                    np.column_stack([converted(batch, fields[topic], s, rows) for s in sources])
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


def fmt_s(x: float) -> str:
    """A time or period in s as the messages show it (9 significant digits)."""
    return f"{x:.9g}"


def resolve_timing(
    path: str | Path | Recording,
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
        path: the bag or the table, or the recording opened once
            (:func:`~twotank_validation.replay.recording.open_recording`: the replay reads it
            next).
        config: topics (the command topic is read) or the map, and the window gate's
            tolerance.
        ts_s: sample period given by the user (s), or None.
        period_samples: excitation period given by the user (samples), or None.

    Raises:
        BagError subclasses: the path is not a readable bag.
        TableError, ReplayConfigError: the path is a table that cannot be read through the
            map (or there is no map of columns).
        TimeBaseError: the map stamps some sources by their header and others by the log
            time, and in this bag the two clocks disagree
            (:meth:`~twotank_validation.replay.timebase.BagClocks.base`).
    """
    cfg = config or ReplayConfig()
    imap = cfg.interface
    clocks: BagClocks | None = None
    meta_ts: float | None
    meta_period: int | None
    record: tuple[np.ndarray, np.ndarray] | None
    rec = path if isinstance(path, Recording) else None
    where = path.given if isinstance(path, Recording) else path
    is_table = is_table_input(path, cfg)
    if is_table:
        if rec is not None and rec.table is not None:
            table = rec.table
        else:
            table = tables.read_table(where, table_map(cfg, where))
        meta_ts = meta_period = None
        record = (table.stamps_ns, table.inputs)
        command = imap.inputs[0].name
        out_stamps = {
            name: table.stamps_ns[np.isfinite(table.outputs[:, i])]
            for i, name in enumerate(imap.output_names)
        }
    else:
        command = imap.inputs[0].topic
        with contextlib.ExitStack() as stack:
            bag = rec.bag if rec is not None else None
            if bag is None:
                bag = stack.enter_context(bag_reader.open_bag(where))
            meta_ts, meta_period = _metadata_timing(bag.info.custom_data)
            record = _command_record(bag, imap)
            out_stamps = _output_stamps(bag, imap)
            clocks = bag_clocks(bag, imap)
    notes: list[str] = []
    conflicts: list[TimingConflict] = []
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
            f"{name} every {fmt_s(t)} s"
            for name, t in stream_ts.items()
            if name != command and differs(t, data_ts) and t > data_ts
        )

    if ts_s is not None:
        ts, ts_from = ts_s, "option"
        if data_ts is not None and supported is not None and not multiple(ts_s, supported):
            fix = f"pass --ts {fmt_s(supported)}"
            if slow:
                text = (
                    f"--ts {fmt_s(ts_s)} does not fit the data: {slow_streams()}, the commands "
                    f"every {fmt_s(data_ts)} s: not every sample would have a value of each; "
                    f"{fix} (the rate the data support)"
                )
            else:
                text = (
                    f"--ts {fmt_s(ts_s)} does not fit the data: the command stamps lie on a "
                    f"{fmt_s(data_ts)} s grid: {fix}"
                )
            conflicts.append(
                TimingConflict(TimingSetting.TS, GivenBy.OPTION, ts_s, supported, None, text)
            )
    elif (
        slow
        and supported is not None
        and data_ts is not None
        and (meta_ts is None or not differs(meta_ts, data_ts))
    ):
        ts, ts_from = supported, "stream rates"
        notes.append(
            f"sample period {fmt_s(ts)} s, the rate the data support: {slow_streams()}, the "
            f"commands every {fmt_s(data_ts)} s; the faster streams are decimated to it; "
            "--ts overrides"
        )
    elif meta_ts is not None:
        ts, ts_from = meta_ts, "bag metadata"
        notes.append(f"sample period {fmt_s(ts)} s from the bag's metadata")
        if data_ts is not None and differs(meta_ts, data_ts):
            text = (
                f"the bag's metadata say ts {fmt_s(meta_ts)} s but the command stamps lie on "
                f"a {fmt_s(data_ts)} s grid: pass --ts {fmt_s(data_ts)} if the stamps are right"
            )
            conflicts.append(
                TimingConflict(TimingSetting.TS, GivenBy.METADATA, meta_ts, data_ts, None, text)
            )
    elif data_ts is not None and grid is not None:
        ts, ts_from = data_ts, "command stamps"
        notes.append(
            f"sample period {fmt_s(ts)} s inferred from the command stamps "
            f"({grid.n_stamps} stamps, {100 * grid.on_grid:.1f} % one step apart, "
            f"{grid.steps_missing} step(s) without a message); --ts overrides"
        )
    else:
        ts, ts_from = TS_S, "default"
        notes.append(
            f"sample period {fmt_s(ts)} s (the default): no --ts, no metadata, and the "
            "command stamps show no grid; pass --ts"
        )
    if clocks is not None:  # one time base, or the mixture refused (TimeBaseError)
        base = clocks.base(cfg.jitter_fraction * ts)
        if base.note is not None:
            notes.insert(0, base.note)
    # the commands' repetition on their own grid, in samples of that grid and in seconds
    data_period = None
    grid_ts = data_ts if data_ts is not None else ts
    if record is not None:
        u = grid_samples(record[0], record[1], grid_ts)
        data_period = infer_excitation_period(
            u, cfg.monitor.input_periodic_rtol, _measured_commands(imap, is_table)
        )

    def in_steps(n: int, step_s: float) -> int | None:
        """``n`` samples of ``step_s`` in samples of ``ts``, if a whole number."""
        m = n * step_s / ts
        return round(m) if abs(m - round(m)) <= 1e-6 * max(m, 1.0) and round(m) >= 1 else None

    def period_doubt(given: int, by: GivenBy) -> TimingConflict | None:
        if data_period is None or abs(given * ts - data_period * grid_ts) <= 0.5 * grid_ts:
            return None
        seen = f"the commands repeat every {fmt_s(data_period * grid_ts)} s"
        here = in_steps(data_period, grid_ts)
        if grid_ts != ts:
            seen += f" ({data_period} samples of {fmt_s(grid_ts)} s)"
        what = "--period" if by is GivenBy.OPTION else "the bag's metadata period"
        text = (
            f"{what} {given} ({fmt_s(given * ts)} s at ts {fmt_s(ts)} s) does not fit the "
            f"data: {seen}: pass --period "
            + (f"{here}" if here is not None else f"{data_period} with --ts {fmt_s(grid_ts)}")
        )
        if here is not None:
            return TimingConflict(TimingSetting.PERIOD, by, given, here, None, text)
        return TimingConflict(TimingSetting.PERIOD, by, given, data_period, grid_ts, text)

    if period_samples is not None:
        period, period_from = period_samples, "option"
        if doubt := period_doubt(period_samples, GivenBy.OPTION):
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
                f"({meta_period} samples of {fmt_s(meta_ts)} s)"
            )
        else:
            notes.append(f"excitation period {period} samples from the bag's metadata")
        if doubt := period_doubt(period, GivenBy.METADATA):
            conflicts.append(doubt)
    elif data_period is not None and (data_here := in_steps(data_period, grid_ts)) is not None:
        period, period_from = data_here, "commands"
        notes.append(
            f"excitation period {period} samples ({fmt_s(period * ts)} s) inferred from the "
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
            f"ts {fmt_s(ts)} s spans several messages of "
            + ", ".join(f"{name} (1 sample in {n} kept)" for name, n in over.items())
        )
    return Timing(
        ts_s=ts,
        period_samples=period,
        ts_from=ts_from,
        period_from=period_from,
        data_ts_s=data_ts,
        data_period_samples=data_period,
        notes=tuple(notes),
        conflicts=tuple(c.text for c in conflicts),
        stream_ts_s=stream_ts,
        oversampling=over,
        findings=tuple(conflicts),
    )
