"""Fuzz the online validator with hostile message streams for a while.

Usage: scripts/run bench fuzz_streams.py [--seconds 300] [--seed 0]

Runs `tools.streamfuzz.run` on consecutive seeds until the time is up (each
run: 4 clean periods of the nominal rig, a hostile stretch of random stamps, NaN/inf, huge
values, bursts, silences, clock jumps and malformed values, then 5 clean periods) and prints
how many runs, which hostile kinds, how many DatumErrors (malformed values, documented) and
every broken invariant (a crash, a judged window overlapping the hostile stretch, a
non-finite judged beta, no recovery to judged windows and Model B OK).
"""

from __future__ import annotations

import argparse
import collections
import time

from tools import streamfuzz
from twotank_validation.core.model import load_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    models = [load_model("A"), load_model("B")]
    kinds: collections.Counter[str] = collections.Counter()
    runs = errors = windows = 0
    bad = []
    start = time.perf_counter()
    seed = args.seed
    while time.perf_counter() - start < args.seconds:
        res = streamfuzz.run(seed, models)
        runs += 1
        errors += len(res.errors)
        windows += len(res.reports)
        kinds.update(str(k) for k in res.kinds)
        if res.violations:
            bad.append((seed, res.kinds, res.violations))
        seed += 1
    wall = time.perf_counter() - start
    print(f"{runs} hostile runs (seeds {args.seed}..{seed - 1}) in {wall:.0f} s, {windows} reports")
    print("hostile kinds used: " + ", ".join(f"{k} {n}" for k, n in sorted(kinds.items())))
    print(f"DatumErrors for malformed values (documented, validator went on): {errors}")
    print(f"runs with a broken invariant: {len(bad)}")
    for seed_, k, v in bad[:20]:
        print(f"  seed {seed_} {k}: {v}")


if __name__ == "__main__":
    main()
