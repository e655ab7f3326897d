"""Replay a one-hour 10 Hz bag (the three interface topics) for Models A and B.

Usage: scripts/run bench bench_replay.py [--hours 1.0] [--storage mcap] [--repeats 3] [--keep DIR]

Writes the nominal scenario for the given duration into a temporary rosbag2 bag, then times
`replay_bag` (the same reader, extractors and OnlineValidator as `twotank-validation validate`)
and prints the throughput as a multiple of real time (bag seconds per wall second) with the
split between reading/decoding and alignment/validation. Medians over the repeats.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
import time
from pathlib import Path

from twotank_validation import replay
from twotank_validation.bags import scenario as sc
from twotank_validation.model import load_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--keep", help="write the bag here instead of a temporary folder")
    args = parser.parse_args()

    duration = round(args.hours * 3600 / 204.8) * 204.8  # whole periods
    scen = dataclasses.replace(sc.load_scenario("nominal"), duration_s=duration)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.keep) if args.keep else Path(tmp) / "bag"
        t0 = time.perf_counter()
        sc.write_scenario_bag(scen, out, storage=args.storage)
        print(
            f"wrote {duration:.0f} s of 10 Hz data ({scen.n_samples * 3} messages) in {time.perf_counter() - t0:.1f} s"
        )
        models = [load_model("A"), load_model("B")]
        walls, decs, vals = [], [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = replay.replay_bag(out, models)
            walls.append(time.perf_counter() - t0)
            decs.append(res.decode_s)
            vals.append(res.validate_s)
        wall, dec, val = statistics.median(walls), statistics.median(decs), statistics.median(vals)
        judged = sum(r.judged for r in res.reports)
        print(
            f"replay ({args.storage}, models A+B): {len(res.reports)} reports ({judged} judged), complete={res.complete}"
        )
        print(
            f"median wall {wall:.2f} s over {args.repeats} runs: {', '.join(f'{w:.2f}' for w in walls)} s"
        )
        print(
            f"throughput: {duration / wall:,.0f}x real time (reference: 1x = {duration:.0f} s of bag time)"
        )
        print(
            f"split: reading+decoding {dec:.2f} s ({dec / wall:.0%}), aligning+validating {val:.2f} s ({val / wall:.0%})"
        )


if __name__ == "__main__":
    main()
