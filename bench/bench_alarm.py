"""The alarm against persistent faults: how soon it fires, whether it holds, how it clears.

Usage: scripts/run bench bench_alarm.py [--limits default|period] [--seeds 2] [--jobs 2]
       [--nominal-hours 24]

Each rig fault at its stated limit (docs/detection.md, "Stated limits": ``--limits default``,
the default alarm's, or ``period``, the period/count alarm's) and at twice it,
persistent for one hour, at several onset phases and ``--seeds`` noise seeds, on the default
scenario (Ts 0.1 s, period 2048, Model B). The onsets are at eight phases spread over a
period (0.03 to 0.94 of it after a period boundary, off the quarter-period hop grid). The
same simulated samples go through the online validator (the node's and replay's path) under
two alarms:

* ``period/count``: one window per period, ERROR after 2 invalidating windows in a row, no
  operating-point check (the alarm of the defaults without the check);
* ``hop/seq + op``: a window every quarter period, the sequential debounce and the
  operating-point check.

Printed per fault and size: detection delay from the onset (median and worst, s and periods),
the share of the fault's hour after the first detection spent in ERROR (median and worst),
the time from the fault's end to the alarm clearing (median and worst), and runs that never
cleared. Then ``--nominal-hours`` of nominal data per seed with setpoint changes every two
hours (level and temperature moved within the model's range), through the new alarm: false
alarms, and the 95 % upper bound of their rate (3 / exposure when there are none).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import statistics
import time
from concurrent.futures import ProcessPoolExecutor

from tools.events import record_events
from twotank_validation.core.model import load_model
from twotank_validation.online import Alarm, AlarmConfig, MonitorConfig, OnlineValidator
from twotank_validation.online.op_tracker import OpPointConfig
from twotank_validation.sim import scenario as sc

P_S = 204.8
HOUR = 3600.0
WARMUP = 5 * P_S  # onsets after 5 periods: two judged windows and a commissioned reference
AFTER = 8 * P_S  # simulated after the fault ends, to see the alarm clear
PHASES = (0.03, 0.16, 0.29, 0.42, 0.55, 0.68, 0.81, 0.94)  # off the hop grid, spread over P
FAULTS_DEFAULT = (  # (spec at the default alarm's stated limit, spec at twice it)
    ("leak=0.03", "leak=0.06"),
    ("sensor_bias:height=0.025", "sensor_bias:height=0.05"),
    ("sensor_bias:temperature=0.08", "sensor_bias:temperature=0.16"),
    ("valve_weak:hot=0.93", "valve_weak:hot=0.86"),
    ("valve_weak:cold=0.93", "valve_weak:cold=0.86"),
    ("valve_stuck:hot", None),
    ("valve_stuck:cold", None),
)
FAULTS_PERIOD = (  # (spec at the period/count alarm's stated limit, spec at twice it)
    ("leak=0.06", "leak=0.12"),
    ("sensor_bias:height=0.05", "sensor_bias:height=0.1"),
    ("sensor_bias:temperature=0.15", "sensor_bias:temperature=0.3"),
    ("valve_weak:hot=0.85", "valve_weak:hot=0.7"),
    ("valve_weak:cold=0.88", "valve_weak:cold=0.76"),
    ("valve_stuck:hot", None),
    ("valve_stuck:cold", None),
)
CONFIGS = {
    "period/count": MonitorConfig(
        hop_samples=2048, alarm=AlarmConfig(debounce="count"), op=OpPointConfig(enabled=False)
    ),
    "hop/seq + op": MonitorConfig(hop_samples=512, alarm=AlarmConfig(debounce="sequential")),
}
SETPOINTS = ("height=0.52", "temperature=0.55", "height=0.44,temperature=0.47", "height=0.47")


def one_run(job):
    """(spec, seed, phase) -> {config: (delay_s, in_error_share, clear_s)}."""
    spec, seed, phase = job
    onset = WARMUP + phase * P_S
    end = onset + HOUR
    scn = dataclasses.replace(
        sc.load_scenario("nominal"),
        duration_s=round((end + AFTER) / 0.1) * 0.1,
        faults=(f"{spec}@{onset:.1f}-{end:.1f}",),
        seed=seed,
    )
    stamps, u, y = sc.simulate_scenario(scn)
    ev = record_events(stamps, u, y)
    out = {}
    for name, cfg in CONFIGS.items():
        reports = OnlineValidator(cfg, [load_model("B")]).feed_many(*ev)
        t_end = [r.end_ns / 1e9 for r in reports]
        errs = [
            t for t, r in zip(t_end, reports, strict=True) if r.alarm is Alarm.ERROR and t > onset
        ]
        if not errs or errs[0] > end:
            out[name] = (None, None, None)
            continue
        first = errs[0]
        during = [r for t, r in zip(t_end, reports, strict=True) if first <= t <= end]
        share = sum(r.alarm is Alarm.ERROR for r in during) / len(during)
        after = [
            t
            for t, r in zip(t_end, reports, strict=True)
            if t > end and r.alarm is not Alarm.ERROR and r.judged
        ]
        clear = (after[0] - end) if after else None
        out[name] = (first - onset, share, clear)
    return spec, seed, phase, out


def nominal_run(seed: int, hours: float):
    n_sp = int(hours // 2)
    setpoints = tuple(
        f"{SETPOINTS[i % len(SETPOINTS)]}@{(i + 1) * 2 * HOUR:.1f}" for i in range(n_sp - 1)
    )
    scn = dataclasses.replace(
        sc.load_scenario("nominal"), duration_s=hours * HOUR, setpoints=setpoints, seed=seed
    )
    stamps, u, y = sc.simulate_scenario(scn)
    reports = OnlineValidator(CONFIGS["hop/seq + op"], [load_model("B")]).feed_many(
        *record_events(stamps, u, y)
    )
    judged = [r for r in reports if r.judged]
    errors = sum(
        1
        for a, b in itertools.pairwise(reports)
        if b.alarm is Alarm.ERROR and a.alarm is not Alarm.ERROR
    )
    moved = sum("setpoint change, reference moved" in r.operating_point for r in reports)
    invalid = sum(r.invalidated for r in judged)
    worst = max((r.beta_total for r in judged), default=float("nan"))
    return seed, len(setpoints), moved, len(judged), invalid, errors, worst


def fmt(xs, scale=1.0, unit="s"):
    xs = [x for x in xs if x is not None]
    if not xs:
        return "-"
    med, worst = statistics.median(xs), max(xs)
    if unit == "%":
        return f"{100 * med:.0f} % / {100 * min(xs):.0f} %"
    return f"{med:.0f} / {worst:.0f} s ({med / P_S:.2f} / {worst / P_S:.2f} P)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--limits",
        choices=("default", "period"),
        default="default",
        help="whose stated limits the faults are at (the default alarm's, or the "
        "period/count alarm's)",
    )
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--nominal-hours", type=float, default=24.0)
    args = ap.parse_args()
    faults = FAULTS_DEFAULT if args.limits == "default" else FAULTS_PERIOD
    print(f"faults at the {args.limits} alarm's stated limits and at twice them")
    jobs = [
        (spec, seed, phase)
        for pair in faults
        for spec in pair
        if spec is not None
        for seed in range(args.seeds)
        for phase in PHASES
    ]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(one_run, jobs))
        nominal = list(pool.map(nominal_run, range(args.seeds), [args.nominal_hours] * args.seeds))
    print(
        f"{len(jobs)} fault runs and {args.seeds} x {args.nominal_hours:g} nominal hours in {time.perf_counter() - t0:.0f} s"
    )
    print()
    print(
        "| fault | alarm | detected | delay median / worst | share of the hour in ERROR after detection, median / worst | time to clear, median / worst | never cleared |"
    )
    print("|---|---|---|---|---|---|---|")
    for pair in faults:
        for spec in pair:
            if spec is None:
                continue
            rows = [r for s, _, _, r in results if s == spec]
            for name in CONFIGS:
                got = [r[name] for r in rows]
                found = [g for g in got if g[0] is not None]
                print(
                    f"| {spec} | {name} | {len(found)}/{len(got)} | {fmt([g[0] for g in found])} | "
                    f"{fmt([g[1] for g in found], unit='%')} | {fmt([g[2] for g in found])} | "
                    f"{sum(g[2] is None for g in found)} |"
                )
    print()
    exposure = sum(args.nominal_hours for _ in nominal)
    errors = sum(n[5] for n in nominal)
    for seed, n_sp, moved, judged, invalid, errs, worst in nominal:
        print(
            f"nominal seed {seed}: {args.nominal_hours:g} h, {n_sp} setpoint changes, reference moved "
            f"{moved} times; {judged} windows judged, {invalid} invalidating, {errs} ERROR episodes; "
            f"largest beta_total {worst:.3f}"
        )
    bound = (3.0 if errors == 0 else float("nan")) / exposure * 24.0
    print(
        f"false alarms: {errors} in {exposure:g} h"
        + (f"; 95 % upper bound {bound:.2f} per 24 h" if errors == 0 else "")
    )


if __name__ == "__main__":
    main()
