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
the first whose operating point is checked as steady (the op tracker calls it steady) and
the share of windows so checked among those ending in (P/4, 4 P], the first whose operating
point checked with the transient term at DC (a window that is not steady, §20) exceeds 1,
the first with β_total > 1, the first ERROR and what raised it; beside the variants, the closed loop without the term with the gate
open wide (``input_periodic_rtol`` 1, ``settle_periods`` 0): β without the term.

``--dc-term`` measures the operating point's check with the term at DC (docs/theory.md §20)
offline, apart from the tracker's reference: on every window the op tracker does not call
steady, whatever its reference's state, bin 0 of the deviation from the reference (the two periods before the onset)
less the transient term interpolated at DC from the lines ±1, ±3 (§20's estimate, the model's
denominator, order 2), Problem 3 at DC on it (:func:`check_operating_point`, the drift
allowance) divided by the noise scale ``s_0`` and lowered by ``ρ_0`` (§20's bound on the
model error picked up from the fit lines). Per fault (or ``setpoint:SPEC``, a setpoint change
the model explains), medians over the runs: the first window whose term-aware ``β_op`` > 1,
the ERROR of ``transient: auto`` as it is and with that ``β_op`` on the windows it does not
call steady (the sequential debounce from the onset on), and the largest term-aware
``β_op`` over the runs.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from tools.events import record_events
from tools.rig_faults import STATED_LIMITS, scaled
from twotank_validation.core.closed_loop import ClosedLoopJudge
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model
from twotank_validation.core.oppoint import (
    OperatingPoint,
    check_operating_point,
    combined_beta,
    dc_response,
)
from twotank_validation.core.transient import (
    denominator,
    local_polynomial,
    model_error_reach,
    model_poles,
    scaled_noise,
    transient_estimate,
    validate_with_transient,
)
from twotank_validation.core.validate import validate_beta
from twotank_validation.online import (
    Alarm,
    AlarmState,
    MonitorConfig,
    OnlineValidator,
    WindowReport,
)
from twotank_validation.online.alarm import update_alarm
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


def fault_run(
    spec: str, phase: float, seed: int, chosen: Variant
) -> tuple[float, list[WindowReport]]:
    """Simulate one fault from ``8 P + phase P`` and validate it: (onset s, Model B's reports)."""
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
    return onset, reports


def delay_s(spec: str, phase: float, seed: int, variant: str) -> Outcome:
    """Run one fault with one variant (:class:`Outcome`)."""
    onset, reports = fault_run(spec, phase, seed, VARIANTS[variant])
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
    onset, reports = fault_run(spec, phase, seed, chosen)
    onset_ns = round(onset * 1e9)

    def after(r: WindowReport) -> float:
        return (r.end_ns - onset_ns) / (PERIOD_S * 1e9)

    rs = [r for r in reports if r.judged and 0 < after(r) <= HORIZON_P]
    checked = [
        r
        for r in rs
        if not math.isnan(r.beta_op)
        and after(r) > 0.25
        and "transient term at DC" not in r.operating_point
    ]
    first = {
        "beta > 1": next((after(r) for r in rs if r.beta > 1), math.inf),
        "op checked": next((after(r) for r in checked), math.inf),
        "op at DC > 1": next(
            (after(r) for r in rs if r.beta_op > 1 and "transient term at DC" in r.operating_point),
            math.inf,
        ),
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


DC_LINES = np.array([-3, -1, 1, 3])
"""The lines the DC estimate reads (two periods per window: the odd lines, not harmonics)."""


def dc_term_check(job: tuple[str, float, int]) -> dict[str, float]:
    """One run of ``--dc-term`` (module doc): periods after the onset, window ends."""
    spec, phase, seed = job
    onset = round((ONSET_P + phase) * PERIOD) * TS
    setpoint = spec.removeprefix("setpoint:") if spec.startswith("setpoint:") else None
    scenario = Scenario(
        name="bench",
        duration_s=(ONSET_P + HORIZON_P + 1) * PERIOD_S,
        seed=seed,
        faults=() if setpoint else (f"{spec}@{onset:g}",),
        setpoints=(f"{setpoint}@{onset:g}",) if setpoint else (),
        closed_loop=ClosedLoop(),
    )
    stamps, u, y = simulate_scenario(scenario)
    config = VARIANTS["closed loop, auto"].config()
    model = load_model("B")
    reports = OnlineValidator(config, [model]).feed_many(*record_events(stamps, u, y))
    n, k0 = 2 * PERIOD, round(onset / TS)
    ref = make_datum(u[k0 - n : k0], y[k0 - n : k0], ts_s=TS, period_samples=PERIOD)
    reference = OperatingPoint(ref.u_bias, ref.y_bias)
    resp = model.response(ref.theta, TS)
    den = denominator(model_poles(model, TS), n)
    a = np.linalg.pinv(np.vander(DC_LINES / 2.0, 3, increasing=True))[0]
    a_den = a * np.array([den[k] if k > 0 else np.conj(den[-k]) for k in DC_LINES]) / den[0]
    s0 = float(np.sqrt(1.0 + np.sum(np.abs(a_den) ** 2)))
    p22_pinv = float(np.linalg.norm(np.linalg.pinv(dc_response(model, TS).p22[0]), 2))
    onset_ns = round(onset * 1e9)
    first_op, err_now, err_dc, largest = math.inf, math.inf, math.inf, 0.0
    state = AlarmState()
    for r in reports:
        after = (r.end_ns - onset_ns) / (PERIOD_S * 1e9)
        if not (0 < after <= HORIZON_P and r.judged):
            continue
        e = int(np.searchsorted(stamps, r.end_ns)) + 1
        d = make_datum(u[e - n : e], y[e - n : e], ts_s=TS, period_samples=PERIOD)
        res = d.y_bins - np.einsum("kyu,ku->ky", resp.p23, d.u_bins)
        at = np.array([res[k] if k > 0 else np.conj(res[-k]) for k in DC_LINES])
        t0 = np.real(np.sum(a_den[:, None] * at, axis=0))  # bin 0 of a real signal is real
        reach = model_error_reach(resp, d.u_bins)[np.abs(DC_LINES)]
        rho = p22_pinv * float(np.linalg.norm(np.abs(a_den) @ reach)) / s0
        chk = check_operating_point(model, TS, reference, OperatingPoint(d.u_bias, d.y_bias - t0),
                                    n_samples=n, allowance=config.op.drift_allowance)  # fmt: skip
        op_term = max(0.0, chk.beta / s0 - rho)
        largest = max(largest, op_term)
        if op_term > 1.0:
            first_op = min(first_op, after)
        op = r.beta_op if not math.isnan(r.beta_op) else op_term
        total = combined_beta(r.beta, op)
        state = update_alarm(state, config.alarm, judged=True, invalidated=total > 1.0,
                             beta=total, weight=(config.hop_samples or PERIOD // 4) / PERIOD)  # fmt: skip
        if state.level is Alarm.ERROR:
            err_dc = min(err_dc, after)
        if r.alarm is Alarm.ERROR:
            err_now = min(err_now, after)
    return {"op > 1": first_op, "ERROR auto": err_now, "ERROR dc": err_dc, "largest": largest}


def print_dc_term(specs: list[str], seeds: int, jobs: int) -> None:
    """The ``--dc-term`` table (module doc)."""
    keys = ["op > 1", "ERROR auto", "ERROR dc"]
    print(f"| fault | {' | '.join(keys)} | largest term-aware beta_op | runs |")
    print("|---|" + "---|" * (len(keys) + 2))
    with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
        for spec in specs:
            outs = list(
                pool.map(dc_term_check, [(spec, p, s) for s in range(seeds) for p in PHASES])
            )
            cells = []
            for k in keys:
                med = statistics.median(o[k] for o in outs)
                found = sum(1 for o in outs if math.isfinite(o[k]))
                cells.append(f"{found}/{len(outs)}, " + ("-" if math.isinf(med) else f"{med:.2f}"))
            largest = max(o["largest"] for o in outs)
            print(f"| {spec} | {' | '.join(cells)} | {largest:.2f} | {len(outs)} |", flush=True)


def print_anatomy(faults: list[str], names: list[str], seeds: int, jobs: int) -> None:
    """The ``--anatomy`` table (module doc)."""
    keys = ["spanning beta", "after beta", "beta > 1", "op checked", "op checked share"]
    keys += ["op at DC > 1", "beta_total > 1", "ERROR"]
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
        "--dc-term",
        default="",
        help="semicolon-separated faults or setpoint:SPEC: the term-aware op check offline "
        "(module doc)",
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
    if args.dc_term:
        print_dc_term(args.dc_term.split(";"), args.seeds, args.jobs)
        return
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
