"""Long run of the live composition: resources, window accounting and the alarm timeline.

Runs :func:`twotank_validation.ros.live.run_live` (excitation, plant and validator nodes,
simulated ``/clock``, loopback DDS) with plant faults that come and go, and checks what a
control stack relying on the alarm needs:

* **resources** every simulated hour: process RSS and thread count (``/proc/self/status``),
  Python threads (``threading.active_count``), GC-tracked objects; optionally tracemalloc's
  growth over one hour. After a warm-up the fitted slopes must stay under stated tolerances
  and the thread count must not grow.
* **window accounting**: the number of windows each model must have reported follows from
  the number of samples and the window settings alone (:func:`expected_window_starts_ns`);
  the reports received over DDS on ``validation/M/report`` must be exactly those windows,
  contiguous, none missing or repeated, each judged (finite beta) or not judged with a
  reason, and equal to what the node handed its report listeners.
* **alarm timeline** against the injected faults (:func:`alarm_timeline`): ERROR within
  ``detect_windows`` windows of each onset, back to OK/WARN within ``clear_windows`` windows
  once the windows no longer see the fault (``settle_s`` after its end), no ERROR raised on a
  window that overlaps no fault (plus ``settle_s``).

The checks are ROS-free functions of compact per-report records (:class:`Rec`), so tests can
feed them made-up timelines; :func:`run_long_run` needs rclpy.
"""

from __future__ import annotations

import gc
import math
import threading
import time
import tracemalloc
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from twotank_validation.defaults import NS_PER_S, PERIOD_SAMPLES, TS_S
from twotank_validation.online import Alarm, MonitorConfig, WindowReport
from twotank_validation.sim.faults import parse_fault

HOUR_S = 3600.0
DDS_WAIT_S = 2.0  # wall time a report may take over loopback DDS before it counts as lost


class Rec(NamedTuple):
    """One report, reduced to what the checks need (a few dozen bytes, no spectrum).

    Attributes:
        model: model name.
        start_ns: stamp of the window's first sample (ns).
        end_ns: stamp of its last sample (ns).
        judged: the window was judged.
        quality: ``"ok"`` (and what was recovered, the warnings) or why it was not judged.
        beta: total min ||w|| (NaN when not judged).
        invalidated: raw verdict.
        alarm: debounced alarm level after the window.
    """

    model: str
    start_ns: int
    end_ns: int
    judged: bool
    quality: str
    beta: float
    invalidated: bool
    alarm: Alarm


def rec_of_report(rep: WindowReport) -> Rec:
    """Record of a core report (what the node handed its listeners)."""
    return Rec(
        rep.model,
        rep.start_ns,
        rep.end_ns,
        rep.judged,
        rep.data_quality,
        float(rep.beta),
        rep.invalidated,
        Alarm(rep.alarm),
    )


def rec_of_message(msg: Any) -> Rec:
    """Record of a ``ValidationReport`` message (what a subscriber received)."""

    def ns(t: Any) -> int:
        return int(t.sec) * NS_PER_S + int(t.nanosec)

    return Rec(
        msg.model,
        ns(msg.window_start),
        ns(msg.window_end),
        bool(msg.judged),
        msg.data_quality,
        float(msg.beta),
        bool(msg.invalidated),
        Alarm(int(msg.alarm_level)),
    )


def same_recs(a: Sequence[Rec], b: Sequence[Rec]) -> bool:
    """Equal record lists, each model's reports in the same order (NaN betas compare equal).

    Each model's reports travel on a topic of their own, and DDS keeps the order within a
    topic, not across topics: a subscriber may get window k's report of model B before that
    of model A although the node published A first. So the lists are compared model by
    model, in order, record for record.
    """
    if len(a) != len(b):
        return False
    key = [r.model for r in a]
    order_a = sorted(range(len(a)), key=lambda i: key[i])  # stable: order within a model kept
    order_b = sorted(range(len(b)), key=lambda i: b[i].model)
    for x, y in zip([a[i] for i in order_a], [b[i] for i in order_b], strict=True):
        bx, by = x.beta, y.beta
        if x._replace(beta=0.0) != y._replace(beta=0.0):
            return False
        if not (bx == by or (math.isnan(bx) and math.isnan(by))):
            return False
    return True


# ------------------------------------------------------------------------ window accounting


def expected_window_starts_ns(  # noqa: PLR0917 (the window settings, in their usual order)
    n_samples: int,
    period_samples: int,
    periods_per_window: int,
    ts_ns: int,
    t0_ns: int = 0,
    hop_samples: int | None = None,
) -> list[int]:
    """Start stamps (ns) of every window a validator must report for ``n_samples`` samples.

    A window of ``periods_per_window`` periods ends at every hop boundary (``hop_samples``,
    default one period) once that many periods were seen:
    ``max(0, (n_samples - periods_per_window * period_samples) // hop + 1)`` windows, the j-th
    starting at sample ``j * hop``.
    """
    hop = hop_samples or period_samples
    n = max(0, (n_samples - periods_per_window * period_samples) // hop + 1)
    return [t0_ns + j * hop * ts_ns for j in range(n)]


def reason_class(quality: str) -> str:
    """Short class of a not-judged reason: the text before its first colon."""
    return quality.split(":", 1)[0].strip() or "(empty reason)"


@dataclass
class WindowAccount:
    """What one model's reports cover, against the windows that must exist.

    Attributes:
        model: model name.
        expected: windows that must have been reported.
        reported: reports received.
        judged: judged reports.
        not_judged: not-judged reports by :func:`reason_class`.
        missing: expected window starts (s) with no report.
        duplicated: window starts (s) reported more than once.
        unexpected: reported window starts (s) that are not expected windows.
        out_of_order: reports whose start is not after the previous one's.
        bad_span: reports whose end is not start + (window - 1) samples.
        inconsistent: reports whose judged flag, reason and beta disagree (judged needs
            reason ``ok`` and a finite beta; not judged needs another reason and NaN beta).
    """

    model: str
    expected: int
    reported: int
    judged: int
    not_judged: dict[str, int]
    missing: list[float] = field(default_factory=list)
    duplicated: list[float] = field(default_factory=list)
    unexpected: list[float] = field(default_factory=list)
    out_of_order: int = 0
    bad_span: int = 0
    inconsistent: int = 0

    @property
    def ok(self) -> bool:
        """Every expected window reported exactly once, in order, each accounted for."""
        return (
            self.reported == self.expected
            and not (self.missing or self.duplicated or self.unexpected)
            and self.out_of_order == self.bad_span == self.inconsistent == 0
        )


def account_windows(  # noqa: PLR0917 (the window settings, in their usual order)
    recs: Sequence[Rec],
    model: str,
    n_samples: int,
    period_samples: int,
    periods_per_window: int,
    ts_ns: int,
    hop_samples: int | None = None,
) -> WindowAccount:
    """Check ``model``'s reports against the windows ``n_samples`` samples must give."""
    starts = expected_window_starts_ns(
        n_samples, period_samples, periods_per_window, ts_ns, hop_samples=hop_samples
    )
    want = set(starts)
    mine = [r for r in recs if r.model == model]
    span_ns = (periods_per_window * period_samples - 1) * ts_ns
    seen: Counter[int] = Counter(r.start_ns for r in mine)
    acc = WindowAccount(
        model=model,
        expected=len(starts),
        reported=len(mine),
        judged=sum(r.judged for r in mine),
        not_judged=dict(Counter(reason_class(r.quality) for r in mine if not r.judged)),
        missing=[s / NS_PER_S for s in starts if s not in seen],
        duplicated=sorted(s / NS_PER_S for s, c in seen.items() if c > 1),
        unexpected=sorted(s / NS_PER_S for s in seen if s not in want),
    )
    prev: int | None = None
    for r in mine:
        if prev is not None and r.start_ns <= prev:
            acc.out_of_order += 1
        prev = r.start_ns
        if r.end_ns - r.start_ns != span_ns:
            acc.bad_span += 1
        if r.judged:
            good = r.quality.startswith("ok") and math.isfinite(r.beta)  # or "ok; warning: ..."
        else:
            good = r.quality not in ("", "ok") and math.isnan(r.beta) and not r.invalidated
        acc.inconsistent += not good
    return acc


# ---------------------------------------------------------------------------- alarm timeline


@dataclass(frozen=True)
class TimelineRule:
    """When the alarm timeline matches the injected faults.

    Attributes:
        detect_windows: ERROR must be reached on one of the first ``detect_windows`` windows
            that contain faulty samples (docs/detection.md, "Stated limits": within 3 windows).
        settle_s: after a fault ends, windows starting before ``end + settle_s`` may still
            see it (transients of the level, time constant about 122 s; the fault's end is
            a step of its own). Windows overlapping ``[onset, end + settle_s)`` belong to
            the fault.
        clear_windows: ERROR must be gone (OK or WARN) by the ``clear_windows``-th window
            starting at or after ``end + settle_s`` and stay gone until the next fault;
            the node's ``clear_windows`` (3 valid windows in a row) is the least possible.
        hops_per_period: windows judged per period (period / hop). The two window counts
            above are for one window per period; with ``q`` per period they mean the window
            that ends as much later: ``(k - 1) q + 1``.
    """

    detect_windows: int = 3
    settle_s: float = 409.6
    clear_windows: int = 3
    hops_per_period: int = 1

    def windows(self, k: int) -> int:
        """``k`` windows a period apart, as a count of windows at this rule's hop."""
        return (k - 1) * self.hops_per_period + 1


@dataclass
class FaultOutcome:
    """How the alarm followed one injected fault.

    Attributes:
        spec: fault spec string.
        onset_s / end_s: when the fault was active (simulated s).
        first_window: index (into the model's reports) of window 1, the first with faulty
            samples; None if the run ended first.
        detect_window: 1-based window number (from window 1) of the first ERROR; None if
            none before the fault's windows ended.
        detect_delay_s: that window's end stamp minus the onset.
        error_inside: (ERROR windows, windows) among those entirely inside the fault.
        clear_window: index of the window from which the alarm stays OK/WARN up to the next
            fault (or the end of the run); None if it does not.
        clear_after_end_s: that window's end stamp minus the fault's end.
        clear_window_after_settle: 1-based number of that window counted from the first
            window starting at or after ``end + settle_s`` (<= 0: cleared earlier).
        detected_ok / cleared_ok: the rule's verdicts.
    """

    spec: str
    onset_s: float
    end_s: float
    first_window: int | None = None
    detect_window: int | None = None
    detect_delay_s: float = math.nan
    error_inside: tuple[int, int] = (0, 0)
    clear_window: int | None = None
    clear_after_end_s: float = math.nan
    clear_window_after_settle: int | None = None
    detected_ok: bool = False
    cleared_ok: bool = False


@dataclass
class Timeline:
    """Alarm timeline of one model against the injected faults.

    Attributes:
        model: model name.
        faults: one outcome per fault, in onset order.
        nominal_windows: judged windows overlapping no fault span.
        nominal_invalidated: of those, windows with a raw invalidating verdict.
        nominal_beta_max: largest beta on them (NaN if none).
        false_raises: ``(start_s, end_s)`` of nominal windows on which ERROR was raised
            (ERROR after a window that was not ERROR).
        error_windows: ERROR windows in all.
    """

    model: str
    faults: list[FaultOutcome]
    nominal_windows: int = 0
    nominal_invalidated: int = 0
    nominal_beta_max: float = math.nan
    false_raises: list[tuple[float, float]] = field(default_factory=list)
    error_windows: int = 0

    @property
    def ok(self) -> bool:
        """Every fault detected and cleared in time, no false alarm."""
        return not self.false_raises and all(f.detected_ok and f.cleared_ok for f in self.faults)


def fault_intervals(specs: Sequence[str]) -> list[tuple[str, float, float]]:
    """``(spec, onset_s, end_s)`` of fault specs, in onset order (end may be inf)."""
    out = []
    for spec in specs:
        f = parse_fault(spec)
        out.append((spec, f.onset_s, f.end_s))
    return sorted(out, key=lambda x: x[1])


def alarm_timeline(
    recs: Sequence[Rec], model: str, specs: Sequence[str], rule: TimelineRule
) -> Timeline:
    """Match ``model``'s alarm levels against the faults ``specs`` under ``rule``."""
    mine = [r for r in recs if r.model == model]
    start = [r.start_ns / NS_PER_S for r in mine]
    end = [r.end_ns / NS_PER_S for r in mine]
    error = [r.alarm == Alarm.ERROR for r in mine]
    faults = fault_intervals(specs)
    spans = [(on, off + rule.settle_s) for _, on, off in faults]

    def overlaps(i: int, a: float, b: float) -> bool:
        return start[i] < b and end[i] >= a

    tl = Timeline(model=model, faults=[], error_windows=sum(error))
    n = len(mine)
    for j, (spec, on, off) in enumerate(faults):
        out = FaultOutcome(spec, on, off)
        tl.faults.append(out)
        idx = [i for i in range(n) if overlaps(i, on, off + rule.settle_s)]
        if not idx:
            continue
        out.first_window = idx[0]
        hit = next((i for i in idx if error[i]), None)
        if hit is not None:
            out.detect_window = hit - idx[0] + 1
            out.detect_delay_s = end[hit] - on
            out.detected_ok = out.detect_window <= rule.windows(rule.detect_windows)
        inside = [i for i in range(n) if start[i] >= on and end[i] < off]
        out.error_inside = (sum(error[i] for i in inside), len(inside))
        # the alarm must stay clear from some window on, up to the next fault's first window
        nxt_on = faults[j + 1][1] if j + 1 < len(faults) else math.inf
        upto = next((i for i in range(n) if end[i] >= nxt_on), n)
        after_end = [i for i in range(idx[0], upto) if end[i] >= off]
        settled = next((i for i in range(n) if start[i] >= off + rule.settle_s), None)
        if not after_end or settled is None or settled >= upto:
            continue  # the run (or the next fault) came first: nothing to judge
        clear = upto
        while clear > after_end[0] and mine[clear - 1].alarm in (Alarm.OK, Alarm.WARN):
            clear -= 1
        if clear < upto:
            out.clear_window = clear
            out.clear_after_end_s = end[clear] - off
            out.clear_window_after_settle = clear - settled + 1
            out.cleared_ok = out.clear_window_after_settle <= rule.windows(rule.clear_windows)
    betas = []
    for i in range(n):
        if any(overlaps(i, a, b) for a, b in spans):
            continue
        if mine[i].judged:
            tl.nominal_windows += 1
            tl.nominal_invalidated += mine[i].invalidated
            betas.append(mine[i].beta)
        if error[i] and (i == 0 or not error[i - 1]):
            tl.false_raises.append((start[i], end[i]))
    tl.nominal_beta_max = max(betas) if betas else math.nan
    return tl


def error_fraction(recs: Sequence[Rec], model: str, skip_judged: int = 1) -> tuple[int, int]:
    """(ERROR windows, judged windows) of ``model`` after its first ``skip_judged`` judged.

    ERROR needs ``alarm_windows`` (2) invalidating windows in a row, so the first judged
    window cannot be ERROR.
    """
    judged = [r for r in recs if r.model == model and r.judged][skip_judged:]
    return sum(r.alarm == Alarm.ERROR for r in judged), len(judged)


# ----------------------------------------------------------------------------- resources


@dataclass(frozen=True)
class HourSample:
    """Process resources at the end of a simulated hour.

    Attributes:
        hour: simulated hours completed.
        wall_s: wall time since the run's first sample (s).
        rss_kib: resident set size (KiB, ``VmRSS``).
        threads: threads of the process (``/proc/self/status`` ``Threads``: DDS included).
        py_threads: Python threads alive (``threading.active_count``).
        gc_objects: objects tracked by the garbage collector.
        traced_kib: tracemalloc's traced memory (KiB) while tracing, else None.
    """

    hour: float
    wall_s: float
    rss_kib: int
    threads: int
    py_threads: int
    gc_objects: int
    traced_kib: float | None = None


def proc_status() -> tuple[int, int]:
    """``(VmRSS in KiB, Threads)`` of this process."""
    rss = threads = -1
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1])
        elif line.startswith("Threads:"):
            threads = int(line.split()[1])
    return rss, threads


def sample_resources(hour: float, wall_s: float) -> HourSample:
    """Take an :class:`HourSample` now."""
    rss, threads = proc_status()
    traced = tracemalloc.get_traced_memory()[0] / 1024 if tracemalloc.is_tracing() else None
    return HourSample(
        hour, wall_s, rss, threads, threading.active_count(), len(gc.get_objects()), traced
    )


@dataclass(frozen=True)
class FlatTolerance:
    """What "flat" means over the hours after ``warmup_h``.

    Attributes:
        warmup_h: hours left out (imports, first windows, allocator pools filling).
        rss_kib_per_h: largest accepted fitted RSS slope (KiB per simulated hour).
        gc_objects_per_h: largest accepted fitted slope of GC-tracked objects per hour (the
            checker keeps one small tuple per report: about 35 per hour at 2 models and one
            window per period; the bench adds the report rate's excess at a shorter hop).
    """

    warmup_h: float = 2.0
    rss_kib_per_h: float = 100.0
    gc_objects_per_h: float = 200.0


@dataclass(frozen=True)
class Flatness:
    """Fitted slopes and deltas of the hourly samples after warm-up.

    Attributes:
        first / last: first sample after warm-up and the last sample.
        rss_slope_kib_per_h / gc_slope_per_h: least-squares slopes over the hours after
            warm-up (NaN with fewer than two samples).
        threads_grew: the process's or Python's thread count grew (any hour after warm-up
            above the first hour after warm-up).
        memory_ok: both slopes finite and within tolerance.
        rss_step_kib: RSS step fitted across the tracemalloc hour (0 without tracing).
    """

    first: HourSample
    last: HourSample
    rss_slope_kib_per_h: float
    gc_slope_per_h: float
    threads_grew: bool
    memory_ok: bool
    rss_step_kib: float = 0.0

    @property
    def ok(self) -> bool:
        """Memory flat and no thread growth."""
        return self.memory_ok and not self.threads_grew


def _slope_and_step(
    hours: np.ndarray, values: np.ndarray, step_at: float | None
) -> tuple[float, float]:
    """Least-squares ``(slope, step)`` of ``values`` over ``hours``.

    A change of level at ``step_at`` is fitted as a step (a second intercept), not as slope.
    """
    cols = [hours, np.ones_like(hours)]
    if step_at is not None and (hours < step_at).any() and (hours >= step_at).any():
        cols.append((hours >= step_at).astype(float))
    if len(hours) < len(cols):
        return math.nan, 0.0
    coef = np.linalg.lstsq(np.stack(cols, axis=1), values, rcond=None)[0]
    return float(coef[0]), float(coef[2]) if len(coef) > 2 else 0.0


def flatness(
    samples: Sequence[HourSample], tol: FlatTolerance, trace_hour: int | None = None
) -> Flatness | None:
    """Judge the samples taken at or after ``tol.warmup_h``; None if there are none.

    With ``trace_hour``, tracemalloc ran from that hour to the next: its own allocations
    raise RSS once (over that hour and the next, as the allocator keeps the freed pages).
    The sample at ``trace_hour + 1`` is left out and the level after it is fitted as a
    step (reported as ``rss_step_kib``), so the slope measures growth, not the tracing.
    """
    after = [s for s in samples if s.hour >= tol.warmup_h]
    if not after:
        return None
    first, last = after[0], after[-1]
    step_at = None
    if trace_hour is not None:
        step_at = trace_hour + 1.5
        after = [s for s in after if abs(s.hour - (trace_hour + 1)) > 1e-6]
    h = np.array([s.hour for s in after])
    rss_slope, rss_step = _slope_and_step(h, np.array([s.rss_kib for s in after], float), step_at)
    gc_slope, _ = _slope_and_step(h, np.array([s.gc_objects for s in after], float), step_at)
    grew = any(s.threads > first.threads or s.py_threads > first.py_threads for s in after)
    memory_ok = (
        math.isfinite(rss_slope)
        and rss_slope <= tol.rss_kib_per_h
        and gc_slope <= tol.gc_objects_per_h
    )
    return Flatness(first, last, rss_slope, gc_slope, grew, memory_ok, rss_step)


# ------------------------------------------------------------------------------- the run


@dataclass(frozen=True)
class LongRunConfig:
    """A long run.

    Attributes:
        hours: simulated hours.
        ts_s: sample period (s).
        period_samples: excitation period (samples).
        faults: fault specs ``KIND[:CHANNEL][=MAG]@ONSET_S[-END_S]``.
        models: model names.
        seed: plant noise seed.
        trace_hour: simulated hour (0-based) traced by tracemalloc; None: no tracing.
        validator: extra validator parameters (node defaults otherwise).
        sample_every_s: simulated seconds between resource samples (an hour; shorter in
            short tests).
    """

    hours: float = 24.0
    ts_s: float = TS_S
    period_samples: int = PERIOD_SAMPLES
    faults: tuple[str, ...] = ()
    models: tuple[str, ...] = ("A", "B")
    seed: int = 0
    trace_hour: int | None = None
    validator: dict[str, Any] = field(default_factory=dict)
    sample_every_s: float = HOUR_S

    @property
    def period_s(self) -> float:
        """Excitation period (s)."""
        return self.ts_s * self.period_samples

    @property
    def hop_samples(self) -> int:
        """Samples between the validator's windows (its ``hop_samples`` parameter's meaning)."""
        return MonitorConfig(
            ts_s=self.ts_s,
            period_samples=self.period_samples,
            hop_samples=int(self.validator.get("hop_samples", 0)),
        ).hop


@dataclass
class LongRunResult:
    """What :func:`run_long_run` measured.

    Attributes:
        n_samples: samples simulated.
        listener_recs: records of the reports the node handed its listeners, in order.
        dds_recs: records of the report messages received on ``validation/M/report``.
        hours: resource samples: before the first sample (hour 0), every
            ``sample_every_s`` simulated seconds and at the end.
        trace_growth_kib: tracemalloc's growth over the traced hour (KiB), if traced.
        trace_top: the traced hour's largest growing allocation sites.
        wall_s: wall time of the run.
        counters: aligner counters.
        dds_given_up: reports produced but not received over DDS within ``DDS_WAIT_S``
            (they appear as missing windows).
    """

    n_samples: int
    listener_recs: list[Rec]
    dds_recs: list[Rec]
    hours: list[HourSample]
    trace_growth_kib: float | None
    trace_top: list[str]
    wall_s: float
    counters: dict[str, int]
    dds_given_up: int = 0


def run_long_run(
    cfg: LongRunConfig, progress: Callable[[HourSample], None] | None = None
) -> LongRunResult:
    """Run the live composition for ``cfg.hours`` simulated hours (needs rclpy).

    Reports are collected twice: from the validator's listener (in process) and as
    ``ValidationReport`` messages over DDS by an extra subscriber node kept in lockstep.
    Only compact records are kept (``keep_reports=False``, ``record_samples=False``).
    """
    from rclpy.context import Context  # noqa: PLC0415 (ROS-free import of the checks)
    from rclpy.node import Node  # noqa: PLC0415

    from twotank_validation.ros import messages  # noqa: PLC0415
    from twotank_validation.ros.live import LiveConfig, run_live  # noqa: PLC0415

    live = LiveConfig(
        duration_s=cfg.hours * HOUR_S,
        ts_s=cfg.ts_s,
        period_samples=cfg.period_samples,
        models=cfg.models,
        faults=cfg.faults,
        seed=cfg.seed,
        validator=dict(cfg.validator),
        record_samples=False,
        keep_reports=False,
    )
    n_steps = live.n_steps
    listener: list[Rec] = []
    dds: list[Rec] = []
    hours: list[HourSample] = []
    steps_per_hour = round(HOUR_S / cfg.ts_s)
    steps_per_sample = round(cfg.sample_every_s / cfg.ts_s)
    trace: dict[str, Any] = {}
    lost: dict[str, Any] = {"n": 0, "since": None}
    t_start = time.monotonic()

    def attach(ctx: Context) -> tuple[list[Node], Callable[[int], bool]]:
        node = Node("twotank_longrun_listener", context=ctx)
        _, report_cls = messages.message_classes()
        for m in cfg.models:
            node.create_subscription(
                report_cls,
                f"validation/{m}/report",
                lambda msg: dds.append(rec_of_message(msg)),
                100,
            )

        def synced(_k: int) -> bool:
            # lockstep for reports too: every report produced so far has arrived over DDS.
            # A report that does not arrive within DDS_WAIT_S is given up on (and shows as
            # missing in the accounting) instead of stopping the run.
            if len(dds) + lost["n"] >= len(listener):
                lost["since"] = None
                return True
            now = time.monotonic()
            if lost["since"] is None:
                lost["since"] = now
            elif now - lost["since"] > DDS_WAIT_S:
                lost["n"] = len(listener) - len(dds)
                lost["since"] = None
                return True
            return False

        return [node], synced

    def tracing(hour: float) -> None:
        h = round(hour)
        if h == cfg.trace_hour and not tracemalloc.is_tracing():
            tracemalloc.start()
            trace["first"] = tracemalloc.take_snapshot()
            trace["mem0"] = tracemalloc.get_traced_memory()[0]
        elif cfg.trace_hour is not None and h == cfg.trace_hour + 1 and tracemalloc.is_tracing():
            snap = tracemalloc.take_snapshot()
            trace["growth"] = (tracemalloc.get_traced_memory()[0] - trace["mem0"]) / 1024
            stats = snap.compare_to(trace.pop("first"), "lineno")
            trace["top"] = [str(s) for s in stats[:5]]
            tracemalloc.stop()

    def on_step(k: int) -> None:
        if (k + 1) % steps_per_sample and k + 1 != n_steps:
            return
        hour = (k + 1) / steps_per_hour
        if cfg.trace_hour is not None and "top" not in trace:
            tracing(hour)  # a function of its own: the snapshots are gone before sampling
        sample = sample_resources(hour, time.monotonic() - t_start)
        hours.append(sample)
        if progress is not None:
            progress(sample)

    hours.append(sample_resources(0.0, 0.0))
    if progress is not None:
        progress(hours[0])
    result = run_live(
        live,
        on_report=lambda rep: listener.append(rec_of_report(rep)),
        on_step=on_step,
        context=None,
        attach=attach,
    )
    if tracemalloc.is_tracing():
        tracemalloc.stop()
    return LongRunResult(
        n_samples=n_steps,
        listener_recs=listener,
        dds_recs=dds,
        hours=hours,
        trace_growth_kib=trace.get("growth"),
        trace_top=trace.get("top", []),
        wall_s=result.wall_s,
        counters=result.counters,
        dds_given_up=lost["n"],
    )


def _num(x: float) -> str:
    return f"{x:.3f}".rstrip("0").rstrip(".")


def fault_schedule(
    kinds: Sequence[str],
    *,
    first_onset_h: float,
    on_h: float,
    off_h: float,
    period_s: float,
    hours: float,
) -> tuple[str, ...]:
    """Fault specs: ``kinds`` (``KIND[:CHANNEL][=MAG]``) one after another.

    Each lasts ``on_h`` hours, with ``off_h`` nominal hours before the next, the first from
    ``first_onset_h``; only faults followed by ``off_h`` nominal hours before the run ends
    are kept. Onsets and ends are put half a period off the window boundaries (a sensor bias
    starting at a boundary is invisible, docs/detection.md, "Stated limits").
    """

    def mid_period(t_s: float) -> float:
        return (math.floor(t_s / period_s) + 0.5) * period_s

    out = []
    t = first_onset_h
    for kind in kinds:
        if t + on_h + off_h > hours + 1e-9:
            break
        on, off = mid_period(t * HOUR_S), mid_period((t + on_h) * HOUR_S)
        out.append(f"{kind}@{_num(on)}-{_num(off)}")
        t += on_h + off_h
    return tuple(out)


# ------------------------------------------------------------------------------ verdicts


class Check(NamedTuple):
    """One pass/fail line."""

    name: str
    ok: bool
    detail: str


@dataclass
class Evaluation:
    """Everything judged about a run.

    Attributes:
        accounts: per model, the window accounting of the reports received over DDS.
        dds_equals_listener: the DDS reports equal the listener's, field by field.
        timelines: per model, the alarm timeline against the faults.
        flat: resource flatness (None: no hour after warm-up).
        checks: the pass/fail lines.
    """

    accounts: dict[str, WindowAccount]
    dds_equals_listener: bool
    timelines: dict[str, Timeline]
    flat: Flatness | None
    checks: list[Check]

    @property
    def ok(self) -> bool:
        """Every check passed."""
        return all(c.ok for c in self.checks)


def evaluate(
    cfg: LongRunConfig,
    res: LongRunResult,
    *,
    rule: TimelineRule | None = None,
    tol: FlatTolerance | None = None,
    alarm_model: str = "B",
    periods_per_window: int = 2,
) -> Evaluation:
    """Judge a run: window accounting, alarm timeline, resource flatness.

    Windows are accounted for every model; the alarm timeline of ``alarm_model`` is checked
    against ``cfg.faults``. Model A's alarm is not checked against the faults (the data
    invalidate A throughout); :func:`error_fraction` describes it.
    """
    rule = rule or TimelineRule(hops_per_period=cfg.period_samples // cfg.hop_samples)
    tol = tol or FlatTolerance()
    ts_ns = round(cfg.ts_s * NS_PER_S)
    checks: list[Check] = []
    accounts = {
        m: account_windows(
            res.dds_recs,
            m,
            res.n_samples,
            cfg.period_samples,
            periods_per_window,
            ts_ns,
            hop_samples=cfg.hop_samples,
        )
        for m in cfg.models
    }
    for m, acc in accounts.items():
        checks.append(
            Check(
                f"windows of model {m}: all {acc.expected} reported once, in order",
                acc.ok,
                f"{acc.reported} reported of {acc.expected} expected; missing {len(acc.missing)}, "
                f"duplicated {len(acc.duplicated)}, unexpected {len(acc.unexpected)}, "
                f"out of order {acc.out_of_order}, bad span {acc.bad_span}, "
                f"inconsistent {acc.inconsistent}; judged {acc.judged}, not judged "
                f"{sum(acc.not_judged.values())} {acc.not_judged}",
            )
        )
    same = same_recs(res.dds_recs, res.listener_recs)
    checks.append(
        Check(
            "reports received over DDS = reports the node produced",
            same,
            f"{len(res.dds_recs)} received, {len(res.listener_recs)} produced",
        )
    )
    timelines = {m: alarm_timeline(res.dds_recs, m, cfg.faults, rule) for m in cfg.models}
    tl = timelines.get(alarm_model)
    if tl is not None:
        for f in tl.faults:
            checks.append(
                Check(
                    f"model {alarm_model} {f.spec}: ERROR within "
                    f"{rule.windows(rule.detect_windows)} windows",
                    f.detected_ok,
                    "no ERROR"
                    if f.detect_window is None
                    else f"window {f.detect_window}, {f.detect_delay_s:.0f} s after onset",
                )
            )
            checks.append(
                Check(
                    f"model {alarm_model} {f.spec}: OK again within "
                    f"{rule.windows(rule.clear_windows)} windows "
                    f"once settled ({rule.settle_s:g} s after end)",
                    f.cleared_ok,
                    "never cleared"
                    if f.clear_window is None
                    else f"{f.clear_after_end_s:.0f} s after end, window "
                    f"{f.clear_window_after_settle} after settling",
                )
            )
        checks.append(
            Check(
                f"model {alarm_model}: no ERROR raised on windows away from faults",
                not tl.false_raises,
                f"{len(tl.false_raises)} raised on {tl.nominal_windows} nominal judged windows "
                f"({tl.nominal_invalidated} raw invalidations, beta max "
                f"{tl.nominal_beta_max:.3f})",
            )
        )
    flat = flatness(res.hours, tol, cfg.trace_hour)
    if flat is not None:
        checks.append(
            Check(
                "threads not growing",
                not flat.threads_grew,
                f"process threads {flat.first.threads} -> {flat.last.threads} "
                f"(max {max(s.threads for s in res.hours if s.hour >= tol.warmup_h)}), "
                f"Python threads {flat.first.py_threads} -> {flat.last.py_threads}",
            )
        )
        checks.append(
            Check(
                f"memory flat (RSS slope <= {tol.rss_kib_per_h:g} KiB/h, GC objects <= "
                f"{tol.gc_objects_per_h:g}/h after {tol.warmup_h:g} h)",
                flat.memory_ok,
                f"RSS {flat.first.rss_kib / 1024:.1f} -> {flat.last.rss_kib / 1024:.1f} MiB, "
                f"slope {flat.rss_slope_kib_per_h:+.1f} KiB/h; GC objects "
                f"{flat.first.gc_objects} -> {flat.last.gc_objects}, slope "
                f"{flat.gc_slope_per_h:+.1f}/h",
            )
        )
    return Evaluation(accounts, same, timelines, flat, checks)
