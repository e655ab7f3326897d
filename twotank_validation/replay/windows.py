"""The judged, non-overlapping windows of a recording, for ``diagnose`` and ``calibrate``."""

from __future__ import annotations

import datetime
import math
from collections.abc import Callable
from pathlib import Path

from twotank_validation.core.model import LFTModel
from twotank_validation.defaults import NS_PER_S
from twotank_validation.diagnose import Window
from twotank_validation.diagnose.stretches import WindowFindings
from twotank_validation.online import WindowReport
from twotank_validation.replay.config import (
    ReplayConfig,
    ReplayConfigError,
    ReplayResult,
    WindowSnapshot,
)
from twotank_validation.replay.feed import replay_bag, replay_recording
from twotank_validation.replay.recording import Recording


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
    path: str | Path | Recording,
    model: LFTModel,
    config: ReplayConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[list[Window], ReplayResult]:
    """The judged, non-overlapping windows of a bag or a table (:func:`replay_recording`).

    As :func:`windows_from_bag`; a table's times are in s from its first row. ``progress``
    as :func:`replay_recording`'s.

    Raises:
        BagError subclasses, TableError, ReplayConfigError, ReplayInterrupted: as
            :func:`replay_recording`.
    """
    windows, _, result = _windows(replay_recording, path, model, config, progress)
    return windows, result


def windows_with_findings(
    path: str | Path | Recording,
    model: LFTModel,
    config: ReplayConfig | None = None,
    *,
    start: float | str | None = None,
    end: float | str | None = None,
    progress: Callable[[int, int], None] | None = None,
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
        progress: as :func:`replay_recording`'s.

    Returns:
        ``(windows, findings, replay_result)``: one
        :class:`~twotank_validation.diagnose.stretches.WindowFindings` per window (its beta,
        beta_op, data quality and warnings: a transient still decaying, ...).

    Raises:
        ReplayConfigError: a range that ends before it starts, lies outside the recording,
            or holds no whole window; and as :func:`windows_from_recording`.
    """
    windows, reports, result = _windows(replay_recording, path, model, config, progress)
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
    path: str | Path | Recording,
    model: LFTModel,
    config: ReplayConfig | None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[list[Window], list[WindowReport], ReplayResult]:
    cfg = config or ReplayConfig()
    kept: list[tuple[int, WindowSnapshot]] = []

    def collect(rep: WindowReport, snap: WindowSnapshot) -> None:
        if kept and snap.stamps_ns[0] <= kept[-1][1].stamps_ns[-1]:
            return  # overlaps the last kept window
        kept.append((int(snap.stamps_ns[0]), snap))

    result = replay(path, [model], cfg, on_window=collect, progress=progress)
    t0 = result.bag_start_ns
    mon = cfg.monitor
    windows = [
        Window(snap.u, snap.y, mon.ts_s, mon.period_samples, (start - t0) * 1e-9, snap.measured)
        for start, snap in kept
    ]
    return windows, [snap.report for _, snap in kept], result
