"""Isolation figures of the live diagnosis: is the fault behind the alarm named right, and when.

Usage: scripts/run bench bench_isolation.py [--seeds 3] [--phases 0.125,0.375,0.625,0.875]
       [--windows-after W] [--max-updates 3] [--faults SUBSTRING ...] [--closed-loop]
       [--calibrate] [--jobs N]

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

``--calibrate`` runs open and closed loop, adds each fault with a stated limit at the limit
itself (answers near the edge, where they go wrong more often) and Model A on the nominal rig
(its own defect, the missing coupling, expected ``coupling`` on ``temperature``), writes every
answer of every run to ``bench/data/isolation_answers.csv`` and fits the probability that an
answer names the injected fault (``tools/answer_calibration.py``) into
``twotank_validation/diagnose/answer_probability.json``, which the live diagnosis loads. It
prints the map, the reliability table on held-out seeds and the Brier scores. ``--refit``
fits the map again on the stored answers without running anything.
"""

from __future__ import annotations

import argparse
import collections
import concurrent.futures
import csv
import functools
import json
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tools import answer_calibration as cal
from tools.events import record_events
from tools.rig_faults import TWICE_STATED_LIMITS
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

ROOT = Path(__file__).resolve().parent.parent
ANSWERS = ROOT / "bench" / "data" / "isolation_answers.csv"
MAP = ROOT / "twotank_validation" / "diagnose" / "answer_probability.json"
DATE = "2026-11-27"

FAULTS = TWICE_STATED_LIMITS  # each rig fault at twice its stated limit

FAULTS_AT_LIMIT = (  # the stated limits themselves (--calibrate: answers near the edge)
    "leak=0.03",
    "sensor_bias:height=0.025",
    "sensor_bias:temperature=0.08",
    "valve_weak:hot=0.93",
    "valve_weak:cold=0.93",
)


@dataclass(frozen=True)
class Case:
    """One kind of run: a fault (or none) against a model, its expected answer."""

    spec: str  # fault spec without the onset ("" for none)
    model: str = "B"
    want: tuple[str, str] | None = None  # None: expected_effect(fault)
    tag: str = "2x"  # "2x" (the accuracy tables), "1x" (the stated limit) or "design"

    @property
    def label(self) -> str:
        return self.spec or f"Model {self.model} on the nominal rig"


def one_run(  # noqa: PLR0917 - one run's settings
    case: Case, phase: float, seed: int, windows_after: float, max_updates: int, closed: bool
):
    onset = round(((ONSET_PERIOD_CLOSED if closed else ONSET_PERIOD) + phase) * PERIOD_S, 1)
    sc = Scenario(
        name="isolation",
        duration_s=round(onset + windows_after * WINDOW_S, 1),
        seed=seed,
        faults=(f"{case.spec}@{onset}",) if case.spec else (),
        closed_loop=ClosedLoop() if closed else None,
    )
    if not case.spec:
        onset = 0.0  # the model's own defect: present from the start
    stamps, u, y = simulate_scenario(sc)
    doc, _ = load_model_document(case.model)
    dg = LiveDiagnoser(
        catalogue_diagnosis({case.model: doc}), LiveDiagConfig(max_updates=max_updates)
    )
    config = MonitorConfig(input_periodic_rtol=CLOSED_LOOP_INPUT_PERIODIC_RTOL) if closed else None
    v = OnlineValidator(config or MonitorConfig(), [load_model(case.model)], diagnoser=dg)
    reports = v.feed_many(*record_events(stamps, u, y))
    want = case.want or expected_effect(parse_fault(f"{case.spec}@{onset}"))
    want = (str(want[0]), want[1])
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
        "last_conf": answers[-1][1].score if answers else None,
        "alarm_s": alarm,
        "first_right_s": first_right,
        "first_answer_s": answers[0][0] if answers else None,
        "answers": [
            {
                "loop": "closed" if closed else "open",
                "case": case.label,
                "tag": case.tag,
                "model": case.model,
                "seed": seed,
                "phase": phase,
                "update": d.update,
                "t_s": round(t, 1),
                "kind": d.kind,
                "channel": d.channel,
                "score": round(d.score, 6),
                "right": int((d.kind, d.channel) == want),
            }
            for t, d in answers
        ],
    }


def label(kc: tuple[str, str] | None) -> str:
    return "-" if kc is None else (f"{kc[0]}:{kc[1]}" if kc[1] else kc[0])


def run_cases(cases, args, closed: bool, windows_after: float):
    """(case, result) of every case x seed x phase, in that order."""
    phases = [float(p) for p in args.phases.split(",")]
    todo = [(c, ph, seed) for c in cases for seed in range(args.seeds) for ph in phases]
    t0 = time.perf_counter()
    call = functools.partial(
        _one, windows_after=windows_after, max_updates=args.max_updates, closed=closed
    )
    rows = []
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        for i, res in enumerate(pool.map(call, todo)):
            rows.append((todo[i][0], res))
            if (i + 1) % (args.seeds * len(phases)) == 0:
                print(
                    f"  {todo[i][0].label} ({todo[i][0].tag}): done "
                    f"({time.perf_counter() - t0:.0f} s)",
                    flush=True,
                )
    return rows


def _one(item, *, windows_after: float, max_updates: int, closed: bool):
    case, phase, seed = item
    np.seterr(all="ignore")
    return one_run(case, phase, seed, windows_after, max_updates, closed)


def print_accuracy(rows, args, closed: bool, windows_after: float) -> None:
    """The accuracy tables of these runs (docs/diagnosis.md, "How well it names the fault")."""
    phases = args.phases.split(",")
    specs = list(dict.fromkeys(c.label for c, _ in rows))
    print(
        f"\n== {'closed loop (PI)' if closed else 'open loop'}: {len(specs)} faults x "
        f"{args.seeds} seeds x {len(phases)} onsets; Model B, default MonitorConfig, "
        f"{windows_after} windows after the onset, at most {args.max_updates} answers per alarm"
    )
    n = len(rows)
    last_ok = sum(r["last"] == r["want"] for _, r in rows)
    first_ok = sum(r["first"] == r["want"] for _, r in rows)
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
    header += f"{'1st answer (s)':>16}{'1st right (s)':>15}{'worst (s)':>11}{'score':>6}"
    print(header)
    med = statistics.median
    for spec in specs:
        mine = [r for c, r in rows if c.label == spec]
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


def calibrate(rows, command: str) -> None:
    """Write every answer (CSV), fit the probability map, write it with its reliability."""
    records = [a for _, r in rows for a in r["answers"]]
    ANSWERS.parent.mkdir(parents=True, exist_ok=True)
    with open(ANSWERS, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(records[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(records)
    fit(command, command)


def fit(command: str, fitted_by: str) -> None:
    """Fit the map on the stored answers; write it with its held-out reliability; print it."""
    answers = cal.read_answers(ANSWERS)
    table = cal.fit_map(answers)
    pairs = cal.held_out(answers)
    doc = {
        "what": "probability that the live diagnosis's answer names the injected fault, per "
        "kind of answer, as a non-decreasing step function of its score (docs/diagnosis.md, "
        "'The probability of an answer'); fitted by tools/answer_calibration.py on "
        f"{ANSWERS.relative_to(ROOT)}",
        "command": command,
        "fitted_by": fitted_by,
        "date": DATE,
        "brier": cal.scores(answers),
        "reliability": cal.reliability(pairs),
        "kinds": table,
    }
    MAP.write_text(json.dumps(doc, indent=1) + "\n")
    print(
        f"\n{len(answers)} answers in {ANSWERS.relative_to(ROOT)}; map -> {MAP.relative_to(ROOT)}"
    )
    print("\nprobability map (kind: answers, right; score from -> probability):")
    for kind, step in table.items():
        steps = ", ".join(
            f"{s:.3g}->{p:.3f}" for s, p in zip(step["score"], step["probability"], strict=True)
        )
        print(f"  {kind:<12} {step['n']:>4} {step['right']:>4}  {steps}")
    print("\nreliability on held-out seeds (each answer's probability fitted on the other seeds):")
    print(f"{'probability':<14}{'answers':>8}{'mean p':>8}{'observed':>10}{'95 % interval':>16}")
    for row in doc["reliability"]:
        lo, hi = row["bin"]
        print(
            f"{lo:.2f}-{hi:.2f}     {row['n']:>8}{row['mean_probability']:>8.3f}"
            f"{row['observed']:>10.3f}    {row['low']:.3f}-{row['high']:.3f}"
        )
    b = doc["brier"]
    print(
        f"\nBrier score (held out, {b['answers']} answers, {b['right']} right): probability "
        f"{b['calibrated']:.4f}; the raw score read as one {b['raw_score']:.4f}; one constant "
        f"(the overall frequency) {b['constant']:.4f}"
    )


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
    parser.add_argument(
        "--calibrate",
        action="store_true",
        help="open and closed loop, the faults also at their stated limit and Model A on the "
        "nominal rig; write every answer and fit the answers' probability map",
    )
    parser.add_argument(
        "--refit",
        action="store_true",
        help="no runs: fit the map again on the stored answers (the map keeps the command "
        "that recorded them)",
    )
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    args = parser.parse_args()
    command = " ".join(["bash scripts/run bench bench_isolation.py", *sys.argv[1:]])
    print("command: " + command)
    t0 = time.perf_counter()
    if args.refit:
        fit(json.loads(MAP.read_text())["command"], command)
        return

    def chosen(specs):
        return [f for f in specs if not args.faults or any(s in f for s in args.faults)]

    loops = (False, True) if args.calibrate else (args.closed_loop,)
    rows_all = []
    for closed in loops:
        windows_after = args.windows_after or (5.0 if closed else 3.5)
        cases = [Case(f) for f in chosen(FAULTS)]
        extra = []
        if args.calibrate:
            extra = [Case(f, tag="1x") for f in chosen(FAULTS_AT_LIMIT)]
            if not closed:
                extra.append(Case("", model="A", want=("coupling", "temperature"), tag="design"))
        rows = run_cases(cases + extra, args, closed, windows_after)
        print_accuracy([(c, r) for c, r in rows if c.tag == "2x"], args, closed, windows_after)
        rows_all += rows
    if args.calibrate:
        calibrate(rows_all, command)
    print(f"\nwall time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
