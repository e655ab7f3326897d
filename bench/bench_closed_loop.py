"""Detection delay in closed loop beside open loop, the rig's faults at and beyond their limits.

Each run is the default scenario (Model B, the default alarm: a window every quarter period,
the sequential debounce, the operating-point check), one fault from ``8 P + phase P``, open
loop (the excitation's commands to the valves) or closed loop (the PI loops of
``twotank_validation.sim.control``, the excitation added to their output, the validator's
periodicity gate at ``CLOSED_LOOP_INPUT_PERIODIC_RTOL``), and closed loop with the transient
term (``transient: local_polynomial``, ``settle_periods: 0``; docs/theory.md §20), closed
loop in ``transient: auto`` (the gate's windows judged as through the gate, the ones it leaves
unjudged with the term), and the term with the controller known (the closed-loop
formulation, docs/theory.md §21). The faults: each kind with a
stated limit (``tools.rig_faults``) at the limit and at twice it, and the stuck and the
saturating hot valve. Delay: onset to the end of the first window whose alarm is ERROR,
within 6 periods; "-" when none; a false alarm before the onset is counted apart. Prints one
row per fault with the runs detected and the median delay in seconds and periods, per
variant (measured, not asserted)::

    scripts/run bench bench_closed_loop.py [--seeds 3] [--jobs 2] [--only leak] [--variants auto,known]

``--anatomy`` prints instead where each closed-loop delay goes (medians over the runs, in
periods after the onset, window ends; "-": not within the horizon): the largest β of the
judged windows spanning the onset and of those wholly after it, the first window with β > 1,
the first whose operating point is checked (the op tracker calls it steady) and the share of
windows so checked among those ending in (P/4, 4 P], the first with β_total > 1, the first
ERROR and what raised it; beside the variants, the closed loop without the term with the gate
open wide (``input_periodic_rtol`` 1, ``settle_periods`` 0): β without the term.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

from tools.events import record_events
from tools.rig_faults import STATED_LIMITS, scaled
from twotank_validation.core.closed_loop import ClosedLoopJudge
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model
from twotank_validation.core.transient import (
    local_polynomial,
    scaled_noise,
    transient_estimate,
    validate_with_transient,
)
from twotank_validation.core.validate import validate_beta
from twotank_validation.online import Alarm, MonitorConfig, OnlineValidator, WindowReport
from twotank_validation.sim.control import CLOSED_LOOP_INPUT_PERIODIC_RTOL
from twotank_validation.sim.scenario import ClosedLoop, Scenario, simulate_scenario

PERIOD, TS = 2048, 0.1
PERIOD_S = PERIOD * TS
FAULTS = (
    *(scaled(kind, f) for kind in STATED_LIMITS for f in (1.0, 2.0)),
    "valve_stuck:hot=0",
    "valve_saturation:hot=0.38",
)
PHASES = (0.2, 0.45, 0.7, 0.95)
HORIZON_P = 6
ONSET_P = 8  # onsets in period 8: the closed loop's start-up is over and its reference commissioned


@dataclass(frozen=True)
class Variant:
    """One column group: the loop and the validator's settings."""

    closed: bool
    config: Callable[[], MonitorConfig]
    controller_known: bool = False


VARIANTS = {
    "open loop": Variant(False, MonitorConfig),
    "closed loop, gate": Variant(
        True, lambda: MonitorConfig(input_periodic_rtol=CLOSED_LOOP_INPUT_PERIODIC_RTOL)
    ),
    "closed loop, transient term": Variant(
        True, lambda: MonitorConfig(transient="local_polynomial", settle_periods=0)
    ),
    "closed loop, auto": Variant(
        True,
        lambda: MonitorConfig(
            input_periodic_rtol=CLOSED_LOOP_INPUT_PERIODIC_RTOL, transient="auto"
        ),
    ),
    "closed loop, controller known": Variant(
        True, lambda: MonitorConfig(transient="local_polynomial", settle_periods=0), True
    ),
}


@dataclass(frozen=True)
class Outcome:
    """One run: the delay, and what the windows spanning the onset showed."""

    delay: float | None
    """Onset to the first ERROR (s); None: none within the horizon; -1: ERROR before it."""
    leakage: float
    """The largest ``input_leakage`` (``rho_total``) of the judged windows spanning it."""
    beta: float
    """The largest ``beta`` of the judged windows spanning it."""
    unjudged: int
    """Windows spanning it left unjudged."""


def delay_s(spec: str, phase: float, seed: int, variant: str) -> Outcome:
    """Run one fault with one variant (:class:`Outcome`)."""
    chosen = VARIANTS[variant]
    onset = round((ONSET_P + phase) * PERIOD) * TS
    scenario = Scenario(
        name="bench",
        duration_s=(ONSET_P + HORIZON_P + 1) * PERIOD_S,
        seed=seed,
        faults=(f"{spec}@{onset:g}",),
        closed_loop=ClosedLoop() if chosen.closed else None,
    )
    stamps, u, y = simulate_scenario(scenario)
    known = scenario.controller_config().linear() if chosen.controller_known else None
    reports = OnlineValidator(chosen.config(), [load_model("B")], controller=known).feed_many(
        *record_events(stamps, u, y)
    )
    onset_ns = round(onset * 1e9)
    spanning = [r for r in reports if r.start_ns <= onset_ns < r.end_ns]
    judged = [r for r in spanning if r.judged]
    leakage = max((r.input_leakage or 0.0 for r in judged), default=float("nan"))
    beta = max((r.beta for r in judged), default=float("nan"))
    delay = None
    for r in reports:
        t = r.end_ns / 1e9
        if r.alarm is Alarm.ERROR:
            if t < onset:
                delay = -1.0  # a false alarm before the onset
            elif t - onset <= HORIZON_P * PERIOD_S:
                delay = t - onset
            break
    return Outcome(delay, leakage, beta, len(spanning) - len(judged))


def _run(job: tuple[str, float, int, str]) -> Outcome:
    return delay_s(*job)


NO_TERM_GATE_OPEN = Variant(True, lambda: MonitorConfig(input_periodic_rtol=1.0, settle_periods=0))
"""The anatomy's reference: every window judged without the term (the gate open wide)."""
ANATOMY_REFERENCE = "closed loop, no term, gate open"


def anatomy(job: tuple[str, float, int, str]) -> dict[str, float | str]:
    """One run's anatomy (module doc, ``--anatomy``): periods after the onset, window ends."""
    spec, phase, seed, variant = job
    chosen = NO_TERM_GATE_OPEN if variant == ANATOMY_REFERENCE else VARIANTS[variant]
    onset = round((ONSET_P + phase) * PERIOD) * TS
    scenario = Scenario(
        name="bench",
        duration_s=(ONSET_P + HORIZON_P + 1) * PERIOD_S,
        seed=seed,
        faults=(f"{spec}@{onset:g}",),
        closed_loop=ClosedLoop(),
    )
    stamps, u, y = simulate_scenario(scenario)
    known = scenario.controller_config().linear() if chosen.controller_known else None
    reports = OnlineValidator(chosen.config(), [load_model("B")], controller=known).feed_many(
        *record_events(stamps, u, y)
    )
    onset_ns = round(onset * 1e9)

    def after(r: WindowReport) -> float:
        return (r.end_ns - onset_ns) / (PERIOD_S * 1e9)

    rs = [r for r in reports if r.judged and 0 < after(r) <= HORIZON_P]
    checked = [r for r in rs if not math.isnan(r.beta_op) and after(r) > 0.25]
    first = {
        "beta > 1": next((after(r) for r in rs if r.beta > 1), math.inf),
        "op checked": next((after(r) for r in checked), math.inf),
        "beta_total > 1": next((after(r) for r in rs if r.beta_total > 1), math.inf),
        "ERROR": next((after(r) for r in rs if r.alarm is Alarm.ERROR), math.inf),
    }
    return {
        "spanning beta": max((r.beta for r in rs if r.start_ns <= onset_ns), default=math.nan),
        "after beta": max((r.beta for r in rs if r.start_ns > onset_ns), default=math.nan),
        **first,
        "op checked share": sum(1 for r in checked if after(r) <= 4)
        / max(1, sum(1 for r in reports if 0.25 < after(r) <= 4)),
        "raised by": next((str(r.raised_by) for r in rs if r.alarm is Alarm.ERROR), "-"),
    }


def print_anatomy(faults: list[str], names: list[str], seeds: int, jobs: int) -> None:
    """The ``--anatomy`` table (module doc)."""
    keys = ["spanning beta", "after beta", "beta > 1", "op checked", "op checked share"]
    keys += ["beta_total > 1", "ERROR"]
    print(f"| fault | variant | {' | '.join(keys)} | raised by |")
    print("|---|---|" + "---|" * (len(keys) + 1))
    with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
        for spec in faults:
            for variant in [ANATOMY_REFERENCE, *names]:
                runs = [(spec, p, s, variant) for s in range(seeds) for p in PHASES]
                outs = list(pool.map(anatomy, runs))
                cells = []
                for k in keys:
                    med = statistics.median(float(o[k]) for o in outs)
                    cells.append("-" if math.isinf(med) else f"{med:.2f}")
                raised = sorted({str(o["raised by"]) for o in outs})
                print(f"| {spec} | {variant} | {' | '.join(cells)} | {', '.join(raised)} |",
                      flush=True)  # fmt: skip


def window_cost(repeats: int) -> None:
    """Per-window cost on a nominal closed-loop window, Models A and B, interleaved runs."""
    scenario = Scenario(name="cost", duration_s=6 * PERIOD_S, seed=1, closed_loop=ClosedLoop())
    _, u, y = simulate_scenario(scenario)
    datum = make_datum(u[2 * PERIOD : 4 * PERIOD], y[2 * PERIOD : 4 * PERIOD], ts_s=TS,
                       period_samples=PERIOD)  # fmt: skip
    models = [load_model(n) for n in ("A", "B")]
    lpm = local_polynomial(datum.n_samples, 2, 2, 2)
    prepared = []
    for m in models:
        resp = m.response(datum.theta, TS)
        est = transient_estimate(lpm, m, TS, datum.n_samples)
        prepared.append((m, resp, est, scaled_noise(resp, est.noise_scale)))
    judge = ClosedLoopJudge(scenario.controller_config().linear(), lpm)

    def run(kind: str, method: str) -> None:
        for m, resp, est, sc in prepared:
            if kind == "none":
                validate_beta(datum, m, method=method, response=resp)
            elif kind == "transient":
                validate_with_transient(datum, m, est, method=method, response=resp, scaled=sc)
            else:
                judge(datum, m, est, method=method, response=resp, scaled=sc)

    start = time.perf_counter()
    run("known", "auto")  # the loop prepared at this operating point, once
    first = time.perf_counter() - start
    kinds = [(k, meth) for meth in ("auto", "fast") for k in ("none", "transient", "known")]
    times: dict[tuple[str, str], list[float]] = {k: [] for k in kinds}
    for _ in range(repeats):
        for key in kinds:
            start = time.perf_counter()
            run(*key)
            times[key].append(time.perf_counter() - start)
    print(f"window cost, Models A and B, {repeats} interleaved runs (median ms per window):")
    for meth in ("auto", "fast"):
        base = statistics.median(times[("none", meth)])
        row = ", ".join(
            f"{k} {statistics.median(times[(k, meth)]) * 1e3:.2f}"
            f" ({statistics.median(times[(k, meth)]) / base:.2f}x)"
            for k in ("none", "transient", "known")
        )
        print(f"  method {meth}: {row}")
    print(f"  controller known, first window at an operating point: {first * 1e3:.0f} ms")
    lines = [1, 2, 3, 4, 5, 10]
    b = next(p for p in prepared if p[0].name == "B")
    loop = judge.loop(datum, b[0], b[1])
    print(
        f"noise scale s at lines {lines}, Model B: direct "
        f"{', '.join(f'{v:.3g}' for v in b[2].noise_scale[lines])}; closed loop "
        f"{', '.join(f'{v:.3g}' for v in loop.estimate.noise_scale[lines])}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=1, help="processes (default 1)")
    parser.add_argument("--only", default="", help="faults whose spec contains this text")
    parser.add_argument(
        "--variants",
        default="",
        help="variants whose name contains one of these comma-separated texts",
    )
    parser.add_argument(
        "--spanning",
        action="store_true",
        help="also the windows spanning the onset: unjudged, median of the largest "
        "input_leakage and beta",
    )
    parser.add_argument(
        "--anatomy", action="store_true", help="where each closed-loop delay goes (module doc)"
    )
    parser.add_argument(
        "--cost", type=int, default=0, help="only the window cost, this many interleaved runs"
    )
    args = parser.parse_args()
    if args.cost:
        window_cost(args.cost)
        return
    start = time.monotonic()
    faults = [f for f in FAULTS if args.only in f]
    names = [v for v in VARIANTS if any(part in v for part in args.variants.split(","))]
    if args.anatomy:
        closed = [v for v in names if VARIANTS[v].closed]
        print_anatomy(faults, closed, args.seeds, args.jobs)
        return
    cols = ["detected", "median delay s (P)"]
    cols += ["spanning unjudged", "leakage", "beta"] if args.spanning else []
    head = " | ".join(f"{v}: {c}" for v in names for c in cols)
    print(f"| fault | {head} |")
    print("|---|" + "---|" * len(cols) * len(names))
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for spec in faults:
            row = [spec]
            for variant in names:
                jobs = [(spec, p, s, variant) for s in range(args.seeds) for p in PHASES]
                outs = list(pool.map(_run, jobs))
                delays = [o.delay for o in outs]
                found = [d for d in delays if d is not None and d >= 0]
                false = sum(1 for d in delays if d is not None and d < 0)
                row.append(f"{len(found)}/{len(delays)}" + (f" ({false} false)" if false else ""))
                med = statistics.median(found) if found else None
                row.append("-" if med is None else f"{med:.0f} ({med / PERIOD_S:.1f})")
                if args.spanning:
                    row.append(str(sum(o.unjudged for o in outs)))
                    row.append(f"{statistics.median(o.leakage for o in outs):.3g}")
                    row.append(f"{statistics.median(o.beta for o in outs):.2f}")
            print("| " + " | ".join(row) + " |", flush=True)
    print(f"({time.monotonic() - start:.0f} s wall, {args.seeds} seeds x {len(PHASES)} phases)")


if __name__ == "__main__":
    main()
