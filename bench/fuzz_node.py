"""Fuzz the validator node (rclpy, real topics, simulated clock) with hostile streams.

Usage: scripts/run bench fuzz_node.py [--seconds 600] [--seed 0] [--case I]

Runs `tools.nodefuzz.run` on consecutive seeds until the time is up. Each
run starts a fresh ValidatorNode (models A and B, Ts = 0.8 s, 256-sample periods,
use_sim_time) in its own rclpy context and drives /clock and its inputs in lockstep: 3-4
periods of the nominal rig, a hostile stretch (streamfuzz's random stamps, NaN/inf, 1e300,
bursts, silences, stamps going back, duplicates; plus the wrong message type on an input from
another participant, /clock and stamps jumping back or forward), clean data up to 10 periods,
then the inputs stop. Prints runs per hostile kind and every broken invariant with its seed;
`--case SEED` replays one run and prints what the node published. Exits 1 on any violation.
Run it inside a private network namespace (see README, "Network").
"""

from __future__ import annotations

import argparse
import collections
import sys
import time

from tools import nodefuzz
from twotank_validation.online import Alarm


def replay(seed: int) -> int:
    res = nodefuzz.run(seed)
    p = res.plan
    g = p.garbage_steps()
    print(f"seed {seed}: kinds {p.kinds}, stretch steps {p.span_steps}, garbage steps ", end="")
    print(f"{g[0]}..{g[-1]} ({len(g)})" if g else "none", end="")
    print(f", clock shift {p.shift_ns / 1e9:+.1f} s, rogue type {p.rogue_type or '-'}")
    for step, msg in res.outputs.reports:
        print(
            f"  step {step:5d} {msg.model} window {nodefuzz._ns_ns(msg.window_start) / 1e9:9.1f}.."
            f"{nodefuzz._ns_ns(msg.window_end) / 1e9:9.1f} s judged {msg.judged!s:5} beta "
            f"{msg.beta:7.3f} {Alarm(msg.alarm_level).name:5} {msg.data_quality[:70]}"
        )
    for v in res.violations:
        print("  VIOLATION", v)
    print(f"  {res.wall_s:.1f} s wall, {res.undelivered} messages not delivered")
    return 1 if res.violations else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--case", type=int, default=None, help="replay this seed, verbosely")
    args = parser.parse_args()
    if args.case is not None:
        return replay(args.case)
    kinds: collections.Counter[str] = collections.Counter()
    runs = reports = statuses = undelivered = 0
    bad = []
    start = time.perf_counter()
    seed = args.seed
    while time.perf_counter() - start < args.seconds:
        res = nodefuzz.run(seed)
        runs += 1
        reports += len(res.outputs.reports)
        statuses += len(res.outputs.statuses)
        undelivered += res.undelivered
        kinds.update(res.plan.kinds)
        if res.violations:
            bad.append((seed, res.plan.kinds, res.violations))
            print(f"seed {seed} {res.plan.kinds}: {res.violations}", flush=True)
        seed += 1
    wall = time.perf_counter() - start
    print(
        f"{runs} node runs (seeds {args.seed}..{seed - 1}) in {wall:.0f} s "
        f"({wall / max(runs, 1):.1f} s each): {reports} reports, {statuses} statuses received, "
        f"{undelivered} input messages not delivered"
    )
    print("hostile kinds used: " + ", ".join(f"{k} {n}" for k, n in sorted(kinds.items())))
    print(f"runs with a broken invariant: {len(bad)}")
    for seed_, k, v in bad[:20]:
        print(f"  seed {seed_} {k}: {v}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
