"""Long-run checks (issue 7): window accounting, alarm timeline, threads; bench/long_run.py.

The checker (``tools.longrun``) is first fed made-up report timelines with a
dropped window, a duplicate, an alarm that never clears and a false alarm, each of which it
must flag. Then a short live run (14 periods, 0.8 simulated hours, at Ts 0.8 s / 256-sample
periods, a fault coming and going) is judged by the same code as the 24-hour bench, and by direct
assertions whose references are computed here from the sample count, the window settings
and the injected onsets and ends.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from tools import longrun as lr
from twotank_validation.defaults import NS_PER_S
from twotank_validation.online import Alarm, MonitorConfig

TS = 0.8
PERIOD = 256
P = TS * PERIOD  # 204.8 s
TS_NS = round(TS * NS_PER_S)


def rec(j: int, alarm: Alarm = Alarm.OK, *, judged: bool = True, model: str = "B") -> lr.Rec:
    """Report of window j (starting at period j), two periods long."""
    start = round(j * P * NS_PER_S)
    return lr.Rec(
        model,
        start,
        start + (2 * PERIOD - 1) * TS_NS,
        judged,
        "ok" if judged else "settling: 1 period(s) of periodic input are needed",
        0.5 if judged else math.nan,
        alarm == Alarm.ERROR,
        alarm if judged else Alarm.STALE,
    )


def clean(n: int) -> list[lr.Rec]:
    return [rec(0, judged=False)] + [rec(j) for j in range(1, n)]


# ------------------------------------------------------------------------ checker, made up


def test_expected_windows_follow_from_the_sample_count() -> None:
    # 10 periods and a bit: windows end at periods 2..10, i.e. 9 windows
    starts = lr.expected_window_starts_ns(10 * PERIOD + 17, PERIOD, 2, TS_NS)
    assert len(starts) == 9
    assert starts[1] - starts[0] == PERIOD * TS_NS
    assert lr.expected_window_starts_ns(2 * PERIOD - 1, PERIOD, 2, TS_NS) == []


def test_accounting_flags_a_dropped_a_duplicated_and_an_inconsistent_window() -> None:
    n = 10 * PERIOD
    recs = clean(9)
    good = lr.account_windows(recs, "B", n, PERIOD, 2, TS_NS)
    assert good.ok
    assert (good.judged, good.not_judged) == (8, {"settling": 1})
    dropped = lr.account_windows(recs[:4] + recs[5:], "B", n, PERIOD, 2, TS_NS)
    assert not dropped.ok
    assert dropped.missing == [pytest.approx(4 * P)]
    duplicated = lr.account_windows([*recs[:5], recs[4], *recs[5:]], "B", n, PERIOD, 2, TS_NS)
    assert not duplicated.ok
    assert duplicated.duplicated == [pytest.approx(4 * P)]
    bad = [*recs[:3], recs[3]._replace(beta=math.nan), *recs[4:]]
    assert lr.account_windows(bad, "B", n, PERIOD, 2, TS_NS).inconsistent == 1
    late_end = lr.account_windows(recs, "B", n + 3 * PERIOD, PERIOD, 2, TS_NS)
    assert not late_end.ok
    assert len(late_end.missing) == 3


def test_dds_records_must_equal_the_nodes_report_for_report() -> None:
    recs = clean(5)  # the first is not judged: NaN beta equals NaN beta
    assert lr.same_recs(recs, list(recs))
    assert not lr.same_recs(recs[:-1], recs)  # one report lost on the way
    assert not lr.same_recs([*recs[:-1], recs[-1]._replace(alarm=Alarm.ERROR)], recs)


def test_dds_records_may_interleave_models_but_keep_each_models_order() -> None:
    # the node publishes A then B for each window; DDS orders within a topic only
    produced = [rec(j, model=m) for j in range(1, 4) for m in ("A", "B")]
    received = [produced[1], produced[0], *produced[2:]]  # window 1: B's report first
    assert lr.same_recs(received, produced)
    swapped = [produced[2], produced[1], produced[0], *produced[3:]]  # A's windows 2, 1
    assert not lr.same_recs(swapped, produced)
    assert not lr.same_recs([produced[0]._replace(model="B"), *produced[1:]], produced)


def test_timeline_detects_clears_and_flags_an_alarm_that_stays() -> None:
    onset, end = 5.5 * P, 9.5 * P  # window 1 with faulty samples: j = 4 (ends at 6 P)
    spec = f"valve_weak:cold=0.6@{onset}-{end}"
    rule = lr.TimelineRule(detect_windows=3, settle_s=2 * P, clear_windows=3)
    levels = {5: Alarm.ERROR, 6: Alarm.ERROR, 7: Alarm.ERROR, 8: Alarm.ERROR, 9: Alarm.ERROR}
    recs = [rec(0, judged=False)] + [rec(j, levels.get(j, Alarm.OK)) for j in range(1, 20)]
    tl = lr.alarm_timeline(recs, "B", [spec], rule)
    (f,) = tl.faults
    assert f.first_window == 4
    assert (f.detect_window, f.detect_delay_s) == (2, pytest.approx(7 * P - TS - onset))
    assert f.detected_ok
    assert f.cleared_ok
    assert tl.ok
    # windows starting >= end + settle: j >= 12; ERROR on 10..12 still clears by j = 14
    stays = {**levels, **dict.fromkeys(range(10, 20), Alarm.ERROR)}
    recs2 = [rec(0, judged=False)] + [rec(j, stays.get(j, Alarm.OK)) for j in range(1, 20)]
    f2 = lr.alarm_timeline(recs2, "B", [spec], rule).faults[0]
    assert f2.detected_ok
    assert not f2.cleared_ok
    assert f2.clear_window is None
    late = {
        **levels,
        10: Alarm.ERROR,
        11: Alarm.ERROR,
        12: Alarm.ERROR,
        13: Alarm.ERROR,
        14: Alarm.ERROR,
    }
    recs3 = [rec(0, judged=False)] + [rec(j, late.get(j, Alarm.OK)) for j in range(1, 20)]
    assert not lr.alarm_timeline(recs3, "B", [spec], rule).faults[0].cleared_ok
    slow = {7: Alarm.ERROR}  # first ERROR on window 4 from the first faulty one
    recs4 = [rec(0, judged=False)] + [rec(j, slow.get(j, Alarm.OK)) for j in range(1, 20)]
    assert not lr.alarm_timeline(recs4, "B", [spec], rule).faults[0].detected_ok


def test_timeline_counts_an_alarm_away_from_faults() -> None:
    spec = f"leak=0.12@{5.5 * P}-{9.5 * P}"
    levels = {6: Alarm.ERROR, 17: Alarm.ERROR, 18: Alarm.ERROR}
    recs = [rec(0, judged=False)] + [rec(j, levels.get(j, Alarm.OK)) for j in range(1, 25)]
    tl = lr.alarm_timeline(recs, "B", [spec], lr.TimelineRule(settle_s=2 * P))
    assert tl.false_raises == [(pytest.approx(17 * P), pytest.approx(19 * P - TS))]
    assert not tl.ok


def test_flatness_flags_growing_threads_and_memory() -> None:
    def hours(rss_step: int, threads_step: int) -> list[lr.HourSample]:
        return [
            lr.HourSample(h, 10.0 * h, 150_000 + rss_step * h, 20 + threads_step * h, 2, 80_000)
            for h in range(6)
        ]

    tol = lr.FlatTolerance(warmup_h=1)
    flat = lr.flatness(hours(0, 0), tol)
    assert flat is not None
    assert flat.ok
    grow_t = lr.flatness(hours(0, 1), tol)
    assert grow_t is not None
    assert grow_t.threads_grew
    assert not grow_t.ok
    grow_m = lr.flatness(hours(1024, 0), tol)
    assert grow_m is not None
    assert not grow_m.memory_ok
    assert grow_m.rss_slope_kib_per_h == pytest.approx(1024)
    # tracemalloc over hour 3-4 leaves RSS 1 MiB higher from then on: a step, not a slope
    stepped = [
        lr.HourSample(h, 10.0 * h, 150_000 + (1024 if h >= 4 else 0), 20, 2, 80_000)
        for h in range(9)
    ]
    naive = lr.flatness(stepped, tol)
    assert naive is not None
    assert naive.rss_slope_kib_per_h > 100
    traced = lr.flatness(stepped, tol, trace_hour=3)
    assert traced is not None
    assert traced.ok
    assert traced.rss_slope_kib_per_h == pytest.approx(0, abs=1e-6)
    assert traced.rss_step_kib == pytest.approx(1024)
    still_growing = [replace(s, rss_kib=s.rss_kib + 300 * int(s.hour)) for s in stepped]
    growing = lr.flatness(still_growing, tol, trace_hour=3)
    assert growing is not None
    assert not growing.memory_ok


def test_schedule_puts_faults_mid_period_with_nominal_gaps() -> None:
    faults = lr.fault_schedule(
        ["leak=0.1", "valve_weak:hot=0.7", "mixing_delay=45"],
        first_onset_h=0.3,
        on_h=0.3,
        off_h=0.4,
        period_s=P,
        hours=1.75,
    )
    assert faults == ("leak=0.1@1126.4-2150.4", "valve_weak:hot=0.7@3584-4608")


# ------------------------------------------------------------------------------ live run

HOURS = 0.8  # 3600 samples: 14 periods and a bit
# mid-period, 3 periods; two judged nominal windows before it; the run ends with the 3rd
# window starting >= 2 periods after its end (when the alarm must be clear again). The
# 24-hour bench runs eight faults one after another; this keeps the test short.
ON_OFF = [(4.5 * P, 7.5 * P)]
FAULTS = (f"valve_weak:cold=0.6@{ON_OFF[0][0]:.1f}-{ON_OFF[0][1]:.1f}",)


@pytest.fixture(scope="module")
def run() -> tuple[lr.LongRunConfig, lr.LongRunResult]:
    pytest.importorskip("rclpy")
    cfg = lr.LongRunConfig(
        hours=HOURS, ts_s=TS, period_samples=PERIOD, faults=FAULTS, sample_every_s=900.0
    )
    return cfg, lr.run_long_run(cfg)


@pytest.mark.slow
def test_short_live_run_passes_the_bench_checks(run) -> None:
    cfg, res = run
    rule = lr.TimelineRule(settle_s=2 * P, hops_per_period=PERIOD // cfg.hop_samples)
    ev = lr.evaluate(cfg, res, rule=rule, tol=lr.FlatTolerance(0.25))
    # memory: too short a run for a slope to mean anything (the bench judges 24 hours)
    failed = [c for c in ev.checks if not c.ok and not c.name.startswith("memory")]
    assert not failed, failed
    assert [s.hour for s in res.hours] == pytest.approx([0.0, 0.25, 0.5, 0.75, HOURS])


@pytest.mark.slow
def test_short_live_run_reports_every_window_once(run) -> None:
    cfg, res = run
    hop = cfg.hop_samples  # the node's default: a quarter period
    n_samples = round(HOURS * 3600 / TS)  # 3600
    n_windows = (n_samples - 2 * PERIOD) // hop + 1  # windows end every hop from 2 periods on
    settling = PERIOD // hop  # those ending before the settling period and the window are in
    assert res.n_samples == n_samples
    for model in ("A", "B"):
        mine = [r for r in res.dds_recs if r.model == model]
        assert [r.start_ns for r in mine] == [j * hop * TS_NS for j in range(n_windows)]
        assert all(r.end_ns == r.start_ns + (2 * PERIOD - 1) * TS_NS for r in mine)
        assert [r.judged for r in mine] == [False] * settling + [True] * (n_windows - settling)
        assert all(r.quality.startswith("settling") for r in mine[:settling])
        assert all(math.isfinite(r.beta) for r in mine[settling:])
    # what a subscriber received is what the node produced, report for report
    assert lr.same_recs(res.dds_recs, res.listener_recs)


@pytest.mark.slow
def test_short_live_run_alarm_follows_the_faults(run) -> None:
    _, res = run
    b = [r for r in res.dds_recs if r.model == "B"]
    intervals = ON_OFF

    def t(ns: int) -> float:
        return ns / NS_PER_S

    for i, (on, off) in enumerate(intervals):
        first_end = math.ceil(on / P) * P  # the first window with faulty samples ends here
        hits = [r for r in b if on <= t(r.end_ns) < first_end + 2 * P + TS / 2]
        assert any(r.alarm == Alarm.ERROR for r in hits), (on, hits)
        # from the 3rd window starting >= 2 periods after the end up to the next onset: clear
        nxt = intervals[i + 1][0] if i + 1 < len(intervals) else math.inf
        after = [r for r in b if t(r.start_ns) >= off + 4 * P - TS / 2 and t(r.end_ns) < nxt]
        assert after, off
        assert all(r.alarm in (Alarm.OK, Alarm.WARN) for r in after), (off, after)
    before = [r for r in b if r.judged and t(r.end_ns) < intervals[0][0]]
    assert len(before) >= 2
    assert all(r.alarm != Alarm.ERROR for r in before)
    # Model A is invalidated by the data: ERROR from its second judged window on
    a = [r for r in res.dds_recs if r.model == "A" and r.judged]
    assert sum(r.alarm == Alarm.ERROR for r in a[1:]) >= 0.9 * len(a[1:])


@pytest.mark.slow
def test_short_live_run_threads_do_not_grow(run) -> None:
    _, res = run
    first, last = res.hours[1], res.hours[-1]  # a quarter of an hour in, at the end
    assert first.threads > 5  # the nodes and DDS were running
    assert last.threads <= first.threads
    assert last.py_threads <= first.py_threads


@pytest.mark.parametrize("hop", [PERIOD, PERIOD // 2, PERIOD // 4])
def test_expected_windows_every_hop_by_brute_force(hop) -> None:
    """A window ends on every hop boundary once it is whole: enumerate the sample counts."""
    n = 7 * PERIOD + 37
    window = 2 * PERIOD
    want = [
        (count - window) * TS_NS
        for count in range(1, n + 1)
        if count % hop == 0 and count >= window
    ]
    assert lr.expected_window_starts_ns(n, PERIOD, 2, TS_NS, hop_samples=hop) == want


def test_timeline_rule_counts_windows_a_period_apart_at_the_hop() -> None:
    assert lr.TimelineRule().windows(3) == 3
    assert lr.TimelineRule(hops_per_period=4).windows(3) == 9
    default = MonitorConfig(ts_s=0.8, period_samples=256).hop  # the validator's default hop
    assert lr.LongRunConfig(ts_s=0.8, period_samples=256).hop_samples == default
    assert lr.LongRunConfig(validator={"hop_samples": 2048}).hop_samples == 2048
    assert lr.LongRunConfig(validator={"hop_samples": 64}).hop_samples == 64
