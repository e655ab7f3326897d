"""Isolation figures of the live diagnosis: is the fault behind the alarm named right, and when.

Usage: scripts/run bench bench_isolation.py [--seeds 3] [--phases 0.125,0.375,0.625,0.875]
       [--windows-after W] [--max-updates 3] [--faults SUBSTRING ...] [--closed-loop]

Each rig fault at twice its stated limit (docs/detection.md, "Stated limits", the default
alarm: leak 0.03, level bias 0.025, temperature bias 0.08, valve loss 7 %), and the faults
without a stated limit at a size of the detection matrix that the default alarm detects
(sensor delay 10 s on the level, 30 s on the temperature, mixing delay 35 s, heat loss 0.2,
a permanently stuck hot valve, a hot valve that opens no further than 0.38, a hot supply
0.15 cooler), starts at ``(6 + phase) P`` (P = 204.8 s; three non-overlapping nominal
windows before it) in the default scenario with noise seed ``seed``. The samples are fed
as events into ``OnlineValidator`` with the default ``MonitorConfig`` (a window every
quarter period, the sequential debounce, the operating-point check), Model B, and a
synchronous ``LiveDiagnoser`` (the bag replay path; the node computes the same answers in
the background). A run lasts ``--windows-after``
windows after the onset.

Scored against ``expected_effect(fault)``: **top-1 accuracy** of the last answer of each
run (and of the first), the **confusion matrix** (rows: the fault; columns: the answer,
``-`` for none), and the **time to the first correct name**: from the onset to the end of
the window whose report carried the first answer that names the fault.
"""

from __future__ import annotations

import argparse
import collections
import statistics
import sys
import time

import numpy as np

from tools.events import record_events
from twotank_validation.core.model import load_model, load_model_document
from twotank_validation.diagnose.kinds import expected_effect
from twotank_validation.diagnose.live_jobs import catalogue_diagnosis
from twotank_validation.online import Alarm, MonitorConfig, OnlineValidator
from twotank_validation.online.livediag import LiveDiagConfig, LiveDiagnoser
from twotank_validation.sim.control import CLOSED_LOOP_INPUT_PERIODIC_RTOL
from twotank_validation.sim.faults import parse_fault
from twotank_validation.sim.scenario import ClosedLoop, Scenario, simulate_scenario

PERIOD_S = 204.8
WINDOW_S = 2 * PERIOD_S
ONSET_PERIOD = 6
ONSET_PERIOD_CLOSED = 8

FAULTS = (
    "leak=0.06",
    "sensor_bias:height=0.05",
    "sensor_bias:temperature=0.16",
    "valve_weak:hot=0.86",
    "valve_weak:cold=0.86",
    "sensor_delay:height=10",
    "sensor_delay:temperature=30",
    "mixing_delay=35",
    "heat_loss=0.2",
    "valve_stuck:hot=0",
    "valve_saturation:hot=0.38",
    "hot_supply=-0.15",
)


def one_run(  # noqa: PLR0917 - one run's settings
    spec: str, phase: float, seed: int, windows_after: float, max_updates: int, closed: bool
):
    onset = round(((ONSET_PERIOD_CLOSED if closed else ONSET_PERIOD) + phase) * PERIOD_S, 1)
    sc = Scenario(
        name="isolation",
        duration_s=round(onset + windows_after * WINDOW_S, 1),
        seed=seed,
        faults=(f"{spec}@{onset}",),
        closed_loop=ClosedLoop() if closed else None,
    )
    stamps, u, y = simulate_scenario(sc)
    doc, _ = load_model_document("B")
    dg = LiveDiagnoser(catalogue_diagnosis({"B": doc}), LiveDiagConfig(max_updates=max_updates))
    config = MonitorConfig(input_periodic_rtol=CLOSED_LOOP_INPUT_PERIODIC_RTOL) if closed else None
    v = OnlineValidator(config or MonitorConfig(), [load_model("B")], diagnoser=dg)
    reports = v.feed_many(*record_events(stamps, u, y))
    want = expected_effect(parse_fault(f"{spec}@{onset}"))
    alarm = next((r.end_ns / 1e9 - onset for r in reports if r.alarm is Alarm.ERROR), None)
    answers = []
    for r in reports:
        d = r.diagnosis
        if d is not None and (not answers or answers[-1][1] is not d):
            answers.append((r.end_ns / 1e9 - onset, d))
    first_right = next((t for t, d in answers if (d.kind, d.channel) == want), None)
    return {
        "want": want,
        "first": (answers[0][1].kind, answers[0][1].channel) if answers else None,
        "last": (answers[-1][1].kind, answers[-1][1].channel) if answers else None,
        "last_conf": answers[-1][1].confidence if answers else None,
        "alarm_s": alarm,
        "first_right_s": first_right,
        "first_answer_s": answers[0][0] if answers else None,
    }


def label(kc: tuple[str, str] | None) -> str:
    return "-" if kc is None else (f"{kc[0]}:{kc[1]}" if kc[1] else kc[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--phases", default="0.125,0.375,0.625,0.875")
    parser.add_argument(
        "--windows-after", type=float, help="default 3.5, closed loop 5 (it detects later)"
    )
    parser.add_argument("--max-updates", type=int, default=3)
    parser.add_argument("--faults", nargs="*", help="only faults containing one of these")
    parser.add_argument("--closed-loop", action="store_true", help="the rig under PI control")
    args = parser.parse_args()
    if args.windows_after is None:
        args.windows_after = 5.0 if args.closed_loop else 3.5
    phases = [float(p) for p in args.phases.split(",")]
    faults = [f for f in FAULTS if not args.faults or any(s in f for s in args.faults)]
    print("command: " + " ".join(["bench_isolation.py", *sys.argv[1:]]))
    print(
        f"{len(faults)} faults x {args.seeds} seeds x {len(phases)} onsets; "
        f"{'closed loop (PI)' if args.closed_loop else 'open loop'}; Model B, default "
        f"MonitorConfig, {args.windows_after} windows after the onset, at most "
        f"{args.max_updates} answers per alarm"
    )
    t0 = time.perf_counter()
    rows = []
    for spec in faults:
        for seed in range(args.seeds):
            for phase in phases:
                rows.append(
                    (
                        spec,
                        one_run(
                            spec,
                            phase,
                            seed,
                            args.windows_after,
                            args.max_updates,
                            args.closed_loop,
                        ),
                    )
                )
        print(f"  {spec}: done ({time.perf_counter() - t0:.0f} s)", flush=True)
    n = len(rows)
    last_ok = sum(r["last"] == r["want"] for _, r in rows)
    first_ok = sum(r["first"] == r["want"] for _, r in rows)
    print()
    print(f"top-1 accuracy, last answer:  {last_ok}/{n} = {last_ok / n:.0%} (goal >= 90 %)")
    print(f"top-1 accuracy, first answer: {first_ok}/{n} = {first_ok / n:.0%}")
    alarmed = [r for _, r in rows if r["alarm_s"] is not None]
    if alarmed and len(alarmed) < n:
        ok = sum(r["last"] == r["want"] for r in alarmed)
        print(
            f"over the {len(alarmed)} runs whose alarm rose (the others: no window judged "
            f"after the onset, or none invalid): {ok}/{len(alarmed)} = {ok / len(alarmed):.0%}"
        )
    print()
    header = f"{'fault':<30}{'runs':>5}{'last ok':>9}{'first ok':>9}{'alarm (s)':>11}"
    header += f"{'1st answer (s)':>16}{'1st right (s)':>15}{'worst (s)':>11}{'conf':>6}"
    print(header)
    med = statistics.median
    for spec in faults:
        mine = [r for s, r in rows if s == spec]
        right = [r["first_right_s"] for r in mine if r["first_right_s"] is not None]
        alarms = [r["alarm_s"] for r in mine if r["alarm_s"] is not None]
        firsts = [r["first_answer_s"] for r in mine if r["first_answer_s"] is not None]
        confs = [r["last_conf"] for r in mine if r["last_conf"] is not None]

        def fmt(xs: list[float]) -> str:
            return f"{med(xs):.0f}" if xs else "-"

        print(
            f"{spec:<30}{len(mine):>5}"
            f"{sum(r['last'] == r['want'] for r in mine):>6}/{len(mine):<2}"
            f"{sum(r['first'] == r['want'] for r in mine):>6}/{len(mine):<2}"
            f"{fmt(alarms):>11}{fmt(firsts):>16}{fmt(right):>15}"
            f"{(f'{max(right):.0f}' if right else '-'):>11}{(f'{med(confs):.2f}' if confs else '-'):>6}"
        )
    right_all = [r["first_right_s"] for _, r in rows if r["first_right_s"] is not None]
    if right_all:
        m = med(right_all)
        print(
            f"\ntime from onset to the first correct name: median {m:.0f} s = "
            f"{m / PERIOD_S:.2f} periods = {m / WINDOW_S:.2f} windows; named right at some "
            f"point in {len(right_all)}/{n} runs"
        )
    print("\nconfusion matrix (last answer; rows: the fault's expected answer):")
    wants = sorted({label(r["want"]) for _, r in rows})
    got = collections.Counter((label(r["want"]), label(r["last"])) for _, r in rows)
    cols = sorted({g for _, g in got} | set(wants))
    width = max(len(c) for c in cols) + 1
    print(" " * 24 + "".join(f"{c:>{width}}" for c in cols))
    for w in wants:
        print(f"{w:<24}" + "".join(f"{got.get((w, c), 0) or '.':>{width}}" for c in cols))
    print(f"\nwall time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
