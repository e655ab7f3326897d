"""Validate recorded bags through the live validator's code path.

Messages stream from :mod:`twotank_validation.bags.reader`, go through the same extractors as
the ROS node (:mod:`twotank_validation.online.streams`, ROS-free) and the same
:class:`~twotank_validation.online.validator.OnlineValidator` (alignment, windows, gates, alarm,
input faults).
Memory stays bounded: only the window buffer and per-window summaries are kept, plus the samples
of a few windows of interest (largest beta, first alarm) for the figures.

Speed: messages go a few thousand at a time. The reader decodes the three fixed-layout input
types in bulk (:meth:`~twotank_validation.bags.reader.BagReader.field_batches`, the generic
deserialiser for anything else), the extractors' unit conversions run on arrays
(:func:`~twotank_validation.online.streams.stream_values`, the same float operations), and
:meth:`~twotank_validation.online.validator.OnlineValidator.feed_many` aligns regular stretches at
once (the same samples and reports as feeding the messages one by one, which is what it does
with anything irregular). A one-hour 10 Hz bag replays for two models in well under 2 s
(``bench/bench_replay.py``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import twotank_validation.bags as bag_reader
from twotank_validation.core.model import LFTModel
from twotank_validation.defaults import NS_PER_S
from twotank_validation.diagnose import Window
from twotank_validation.online import Alarm, MonitorConfig, OnlineValidator, WindowReport
from twotank_validation.online import streams as itf
from twotank_validation.online.streams import STREAM_KINDS, STREAMS


@dataclass(frozen=True)
class ReplayConfig:
    """How to read a bag.

    Attributes:
        monitor: validator settings (as the node's parameters).
        topics: stream name (``flow_cmd``, ``height``, ``temperature``) -> topic in the bag.
        units: per-rig unit conversion of the measurements.
        jitter_fraction: accepted stamp distance from the sample grid (fraction of ts).
    """

    monitor: MonitorConfig = field(default_factory=MonitorConfig)
    topics: Mapping[str, str] = field(default_factory=lambda: {s: s for s in STREAMS})
    units: itf.RigUnits = field(default_factory=itf.RigUnits)
    jitter_fraction: float = 0.25


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
        path: the bag.
        reports: window reports in order (all models).
        complete: the whole bag was read and every expected topic was present.
        problems: what made the run incomplete or what was refused, in words (the input
            faults in the live node's words).
        counters: aligner counters (duplicates, out of order, gaps, ...).
        messages: messages read.
        decode_s: wall time spent reading and decoding.
        validate_s: wall time spent aligning and validating.
        bag_start_ns: first log time in the bag (reports' times are relative to it in JSON).
        snapshots: windows of interest per model.
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


_BATCH = 4096  # messages decoded and validated at a time


def extractor(stream: str, units: itf.RigUnits) -> Callable[[Any], Any]:
    """Message -> value for one stream (same functions as the live node)."""
    if stream == itf.FLOW_CMD:
        return itf.flow_values
    if stream == itf.HEIGHT:
        return lambda msg: itf.height_value(msg, units)
    return lambda msg: itf.temperature_value(msg, units)


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
    """
    cfg = config or ReplayConfig()
    core = OnlineValidator(cfg.monitor, models, jitter_fraction=cfg.jitter_fraction)
    result = ReplayResult(Path(path))
    with bag_reader.open_bag(path) as bag:
        result.bag_start_ns = bag.info.start_ns or 0
        expected = bag_reader.expected_types()
        wanted = {cfg.topics[s]: expected[s] for s in STREAMS}
        try:
            bag.check_topics(wanted)
        except (bag_reader.TopicMissingError, bag_reader.TopicTypeError) as err:
            result.complete = False
            result.problems.append(str(err))
            present = {t for t in wanted if _usable(bag, t, expected[_stream_of(cfg, t)])}
            if not present:
                return result
            wanted = {t: v for t, v in wanted.items() if t in present}
        except bag_reader.BagEmptyError as err:
            result.complete = False
            result.problems.append(str(err))
            return result
        stream_of = {cfg.topics[s]: s for s in STREAMS}
        fields = {t: itf.STREAM_FIELDS[stream_of[t]] for t in wanted}
        total = sum(bag.info.message_counts.get(bag.resolve_topic(t) or t, 0) for t in wanted)

        def on_report(rep: WindowReport) -> None:
            result.reports.append(rep)
            _keep_if_interesting(result, core, rep)
            if on_window is not None and rep.judged:
                stamps, u, y = core.last_window()
                on_window(rep, WindowSnapshot(rep, stamps, u, y))

        t_dec = t_val = 0.0
        tick = time.perf_counter()
        try:
            for batch in bag.field_batches(list(wanted), fields, size=_BATCH):
                now = time.perf_counter()
                t_dec += now - tick
                # the node's extractors, on arrays; then the node's validator, many at a time
                kinds = np.empty(len(batch), dtype=np.int8)
                values = np.empty((len(batch), 2))
                for j, topic in enumerate(batch.topics):
                    rows = batch.topic == j
                    stream = stream_of[topic]
                    kinds[rows] = STREAM_KINDS[stream]
                    values[rows] = itf.stream_values(stream, batch.values[rows], cfg.units)
                before = result.messages
                result.messages += len(batch)
                core.feed_many(kinds, batch.stamp_ns, values, on_report)
                tick = time.perf_counter()
                t_val += tick - now
                if progress is not None:
                    for m in range((before // 5000 + 1) * 5000, result.messages + 1, 5000):
                        progress(m, total)
        except bag_reader.BagCorruptError as err:
            result.complete = False
            result.problems.append(str(err))
        result.decode_s, result.validate_s = t_dec, t_val
    result.counters = dataclasses.asdict(core.counters())
    result.problems.extend(core.input_problems())
    if progress is not None:
        progress(result.messages, max(result.messages, 1))
    return result


def _usable(bag: bag_reader.BagReader, topic: str, types: tuple[str, ...]) -> bool:
    """The bag holds messages of ``topic`` (``x`` also matches ``/x``) of an accepted type."""
    name = bag.resolve_topic(topic)
    return (
        name is not None
        and bag.info.topics.get(name) in types
        and bag.info.message_counts.get(name, 0) > 0
    )


def _stream_of(cfg: ReplayConfig, topic: str) -> str:
    return next(s for s in STREAMS if cfg.topics[s] == topic)


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
        stamps, u, y = core.last_window()
        snap = WindowSnapshot(rep, stamps, u, y)
        for r in reasons:
            kept[r] = snap


def summary_json(result: ReplayResult) -> dict[str, Any]:
    """The documented JSON (docs/cli.md, "validate JSON"): times in seconds of bag time."""
    t0 = result.bag_start_ns

    def sec(ns: int) -> float:
        return (ns - t0) / NS_PER_S

    models: dict[str, Any] = {}
    for rep in result.reports:
        entry = models.setdefault(rep.model, {"windows": [], "beta_max": None, "first_alarm": None})
        entry["windows"].append(
            {
                "start": sec(rep.start_ns),
                "end": sec(rep.end_ns),
                "beta": rep.beta if rep.judged and math.isfinite(rep.beta) else None,
                "invalidated": bool(rep.invalidated),
                "alarm": rep.alarm.name,
                "reason": None if rep.judged else rep.data_quality,
                "margin": rep.margin if rep.judged and math.isfinite(rep.margin) else None,
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
        "complete": result.complete,
        "problems": list(result.problems),
        "messages": result.messages,
        "counters": dict(result.counters),
        "models": models,
    }


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
    cfg = config or ReplayConfig()
    kept: list[tuple[int, WindowSnapshot]] = []

    def collect(rep: WindowReport, snap: WindowSnapshot) -> None:
        if kept and snap.stamps_ns[0] <= kept[-1][1].stamps_ns[-1]:
            return  # overlaps the last kept window
        kept.append((int(snap.stamps_ns[0]), snap))

    result = replay_bag(path, [model], cfg, on_window=collect)
    t0 = result.bag_start_ns
    mon = cfg.monitor
    windows = [
        Window(snap.u, snap.y, mon.ts_s, mon.period_samples, (start - t0) * 1e-9)
        for start, snap in kept
    ]
    return windows, result
