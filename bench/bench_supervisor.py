"""The supervisor on nominal closed-loop data: false transitions per 24 simulated hours.

Usage: scripts/run bench bench_supervisor.py [--hours 24] [--seeds 2] [--setpoints]
       [--transient [auto]] [--controller-known]

Each seed is the default scenario in closed loop (the PI loops of
``twotank_validation.sim.control``, the excitation added to their output, the validator's
input periodicity gate opened as ``live --closed-loop`` opens it), simulated for ``--hours``
and fed sample by sample as the three streams into ``OnlineValidator`` (the node's path, the
default alarm, Models A and B). Model B's reports then go through the supervisor as the node
receives them (``online.supervisor.false_transitions``: each report at its stamp, then its
``invalidated`` flag, the staleness timer every second) with the node's default settings. On
nominal data every switch to SAFE is false (goal: 0 per 24 h); the 95 % upper bound of the
rate when none is seen is 3 / exposure. The longest spell between judged windows is printed
beside it (the supervisor's ``unjudged_after_s`` must exceed it). ``--setpoints`` moves the controller's setpoints every
two hours (level 0.44-0.52, temperature 0.47-0.55), as an operator would. ``--transient``
judges with the transient term (``transient: local_polynomial``, ``settle_periods: 0``;
docs/theory.md §20) instead of the opened gate; ``--transient auto`` keeps the opened gate and
judges the windows it leaves unjudged with the term (``transient: auto``);
``--controller-known`` the term on the closed-loop formulation (the rig's PI given to the
validator, docs/theory.md §21).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import statistics
import time

from tools.events import record_events
from twotank_validation.core.model import load_model
from twotank_validation.online import MonitorConfig, OnlineValidator
from twotank_validation.online.supervisor import (
    SupervisorConfig,
    false_transitions,
    report_records,
)
from twotank_validation.sim.control import CLOSED_LOOP_INPUT_PERIODIC_RTOL
from twotank_validation.sim.scenario import ClosedLoop, load_scenario, simulate_scenario

HOUR = 3600.0
SETPOINTS = ("height=0.52", "temperature=0.55", "height=0.44,temperature=0.47", "height=0.47")


def one_seed(
    seed: int, hours: float, setpoints: bool, transient: str = "none", known: bool = False
) -> dict:
    scn = dataclasses.replace(
        load_scenario("nominal"),
        duration_s=round(hours * HOUR / 0.1) * 0.1,
        seed=seed,
        closed_loop=ClosedLoop(),
        setpoints=tuple(
            f"{SETPOINTS[i % len(SETPOINTS)]}@{2 * HOUR * (i + 1):g}"
            for i in range(int(hours // 2) - 1)
        )
        if setpoints
        else (),
    )
    t0 = time.perf_counter()
    stamps, u, y = simulate_scenario(scn)
    t_sim = time.perf_counter() - t0
    config = (
        MonitorConfig(transient="local_polynomial", settle_periods=0)
        if transient == "local_polynomial" or known
        else MonitorConfig(input_periodic_rtol=CLOSED_LOOP_INPUT_PERIODIC_RTOL, transient=transient)
    )
    controller = scn.controller_config().linear() if known else None
    models = [load_model("A"), load_model("B")]
    reports = OnlineValidator(config, models, controller=controller).feed_many(
        *record_events(stamps, u, y)
    )
    mine = [r for r in reports if r.model == "B"]
    judged = [r for r in mine if r.judged]
    out = false_transitions(report_records(mine), SupervisorConfig(), end_s=float(stamps[-1]) / 1e9)
    ends = [r.end_ns / 1e9 for r in judged]
    return {
        "longest_unjudged_s": max((b - a for a, b in itertools.pairwise(ends)), default=0.0),
        "seed": seed,
        "reports": len(mine),
        "judged": len(judged),
        "invalidating": sum(r.invalidated for r in judged),
        "beta_max": max((r.beta_total for r in judged), default=float("nan")),
        "false": out.count,
        "setpoint_changes": len(scn.setpoints),
        "wall_s": time.perf_counter() - t0,
        "sim_s": t_sim,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--setpoints", action="store_true")
    ap.add_argument(
        "--transient",
        nargs="?",
        const="local_polynomial",
        default="none",
        choices=("none", "local_polynomial", "auto"),
        help="the transient term, not the gate (auto: the term where the gate fails)",
    )
    ap.add_argument(
        "--controller-known", action="store_true", help="the closed-loop formulation (§21)"
    )
    args = ap.parse_args()
    rows = [
        one_seed(s, args.hours, args.setpoints, args.transient, args.controller_known)
        for s in range(args.seeds)
    ]
    for r in rows:
        print(
            f"seed {r['seed']}: {args.hours:g} h closed loop, {r['setpoint_changes']} setpoint "
            f"changes; Model B {r['reports']} reports, {r['judged']} judged, "
            f"{r['invalidating']} invalidating, beta_total max {r['beta_max']:.3f}, longest "
            f"spell without a judged window {r['longest_unjudged_s']:.0f} s; "
            f"supervisor: {r['false']} false transitions ({r['wall_s']:.0f} s wall, "
            f"{r['sim_s']:.0f} s simulating)"
        )
    exposure = args.hours * len(rows)
    n_false = sum(r["false"] for r in rows)
    bound = f"; 95 % upper bound {24 * 3 / exposure:.2f} per 24 h" if n_false == 0 else ""
    print(
        f"false transitions: {n_false} in {exposure:g} h = {24 * n_false / exposure:.2f} per 24 h "
        f"(goal 0{bound}); median judged share "
        f"{statistics.median(r['judged'] / max(r['reports'], 1) for r in rows):.1%}"
    )


if __name__ == "__main__":
    main()
