"""Replay a one-hour 10 Hz bag (the three interface topics) for Models A and B.

Usage: scripts/run bench bench_replay.py [--hours 1.0] [--storage mcap] [--repeats 5]
       [--baseline-repeats 3] [--map-repeats 3] [--keep DIR]

Writes the nominal scenario for the given duration into a temporary rosbag2 bag, then times
`replay_bag` (the same reader, extractors and OnlineValidator as `twotank-validation validate`)
and prints the throughput as a multiple of real time (bag seconds per wall second), decoding
included, with the split between reading/decoding and alignment/validation, and its ratio to
the goal (2,000x real time). In the same run it times the per-message path the replay used
before batching (reader.messages -> rosbags deserialiser -> extractors -> OnlineValidator.feed,
one message at a time) on the same bag, checks that both give the same reports, and prints
the speed-up; and the replay through the shipped interface map (message by message, decoded
from the bag's definitions: the path a rig's own types take), with the same check. Medians
over the repeats.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import tempfile
import time
from pathlib import Path

from twotank_validation import bags, replay
from twotank_validation.core.model import LFTModel, load_model
from twotank_validation.online import STREAMS, OnlineValidator, WindowReport
from twotank_validation.online import streams as itf
from twotank_validation.online.interface import default_interface_map
from twotank_validation.sim import scenario as sc

GOAL = 2000.0  # times real time (issue 6)


def per_message(path: Path, models: list[LFTModel]) -> list[WindowReport]:
    """The replay loop before batching: one decoded message, one extractor call, one feed."""
    cfg = replay.ReplayConfig()
    core = OnlineValidator(cfg.monitor, models, jitter_fraction=cfg.jitter_fraction)
    reports: list[WindowReport] = []
    with bags.open_bag(path) as bag:
        for m in bag.messages(list(STREAMS)):
            value = replay.extractor(m.topic, cfg.units)(m.msg)
            reports += core.feed(m.topic, itf.stamp_ns(m.msg), value)
    return reports


def same(a: list[WindowReport], b: list[WindowReport]) -> bool:
    return len(a) == len(b) and all(
        (x.model, x.start_ns, x.end_ns, x.judged, x.alarm, x.data_quality)
        == (y.model, y.start_ns, y.end_ns, y.judged, y.alarm, y.data_quality)
        and (x.beta == y.beta or (math.isnan(x.beta) and math.isnan(y.beta)))
        for x, y in zip(a, b, strict=True)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline-repeats", type=int, default=3, help="0 skips the baseline")
    parser.add_argument(
        "--map-repeats",
        type=int,
        default=3,
        help="runs through the shipped interface map (0: skip)",
    )
    parser.add_argument("--keep", help="write the bag here instead of a temporary folder")
    args = parser.parse_args()

    duration = round(args.hours * 3600 / 204.8) * 204.8  # whole periods
    scen = dataclasses.replace(sc.load_scenario("nominal"), duration_s=duration)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.keep) if args.keep else Path(tmp) / "bag"
        if out.exists():
            print(f"using the bag in {out}")
        else:
            t0 = time.perf_counter()
            bags.write_scenario_bag(scen, out, storage=args.storage)
            print(
                f"wrote {duration:.0f} s of 10 Hz data ({scen.n_samples * 3} messages) "
                f"in {time.perf_counter() - t0:.1f} s"
            )
        models = [load_model("A"), load_model("B")]
        walls, decs, vals = [], [], []
        res = None
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = replay.replay_bag(out, models)
            walls.append(time.perf_counter() - t0)
            decs.append(res.decode_s)
            vals.append(res.validate_s)
        assert res is not None
        wall, dec, val = statistics.median(walls), statistics.median(decs), statistics.median(vals)
        judged = sum(r.judged for r in res.reports)
        speed = duration / wall
        print(
            f"replay ({args.storage}, models A+B): {res.messages} messages, {len(res.reports)} "
            f"reports ({judged} judged), complete={res.complete}"
        )
        print(
            f"median wall {wall:.3f} s over {args.repeats} runs: "
            f"{', '.join(f'{w:.3f}' for w in walls)} s"
        )
        print(
            f"split: reading+decoding {dec:.3f} s ({dec / wall:.0%}), aligning+validating "
            f"{val:.3f} s ({val / wall:.0%}), rest (opening, model responses) "
            f"{wall - dec - val:.3f} s"
        )
        print(
            f"throughput: {speed:,.0f}x real time; goal >= {GOAL:,.0f}x: ratio {speed / GOAL:.2f} "
            f"({'met' if speed >= GOAL else 'NOT met'})"
        )
        if args.baseline_repeats > 0:
            base_walls = []
            reports: list[WindowReport] = []
            for _ in range(args.baseline_repeats):
                t0 = time.perf_counter()
                reports = per_message(out, models)
                base_walls.append(time.perf_counter() - t0)
            base = statistics.median(base_walls)
            print(
                f"per-message path (before batching), same bag: median {base:.2f} s = "
                f"{duration / base:,.0f}x real time; speed-up {base / wall:.1f}x; "
                f"same reports: {same(res.reports, reports)}"
            )
        if args.map_repeats > 0:
            cfg = replay.ReplayConfig(interface=default_interface_map())
            map_walls = []
            mapped = res
            for _ in range(args.map_repeats):
                t0 = time.perf_counter()
                mapped = replay.replay_bag(out, models, cfg)
                map_walls.append(time.perf_counter() - t0)
            mwall = statistics.median(map_walls)
            print(
                f"through the shipped interface map (message by message, decoded from the bag's "
                f"definitions), same bag: median {mwall:.2f} s = {duration / mwall:,.0f}x real "
                f"time; {mwall / wall:.1f}x the batched path's time; "
                f"same reports: {same(res.reports, mapped.reports)}"
            )


if __name__ == "__main__":
    main()
