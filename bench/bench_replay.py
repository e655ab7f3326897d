"""Replay a one-hour 10 Hz bag (the three interface topics) for Models A and B.

Usage: scripts/run bench bench_replay.py [--hours 1.0] [--storage mcap] [--repeats 5]
       [--baseline-repeats 3] [--keep DIR]

Writes the nominal scenario for the given duration into a temporary rosbag2 bag, then times
`replay_bag` (the same reader, interface map and OnlineValidator as `twotank-validation validate`)
and prints the throughput as a multiple of real time (bag seconds per wall second), decoding
included, and its ratio to the goal (30,000x real time). It prints the split of the wall time
between reading (the undecoded messages as arrays: chunks decompressed, records found),
decoding (stamps and fields, timed as reading+decoding over the same bag less reading),
validating (aligning and the windows, timed inside the replay) and the rest (opening the bag,
building the validator, reports). In the same run it times the two earlier paths on the same
bag and checks that each gives the same reports: the reader's row-by-row path (messages read
one by one through rosbags, then packed into batches and decoded in bulk where the layout
repeats: `field_batches(columnar=False)`), and the per-message path (reader.messages ->
rosbags deserialiser -> the fields read directly -> OnlineValidator.feed, one message at a
time). Medians over the repeats.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import tempfile
import time
from pathlib import Path

from tools.events import two_tank_value
from twotank_validation import bags, replay
from twotank_validation.core.model import LFTModel, load_model
from twotank_validation.online import STREAMS, OnlineValidator, WindowReport
from twotank_validation.online import streams as itf
from twotank_validation.replay import feed as replay_feed
from twotank_validation.sim import scenario as sc

GOAL = 30_000.0  # times real time (issue 19)


def per_message(path: Path, models: list[LFTModel]) -> list[WindowReport]:
    """The replay loop before batching: one decoded message, one extractor call, one feed."""
    cfg = replay.ReplayConfig()
    core = OnlineValidator(cfg.monitor, models, jitter_fraction=cfg.jitter_fraction)
    reports: list[WindowReport] = []
    with bags.open_bag(path) as bag:
        for m in bag.messages(list(STREAMS)):
            value = two_tank_value(m.topic, m.msg, itf.RigUnits())
            reports += core.feed(m.topic, itf.stamp_ns(m.msg), value)
    return reports


def rows_path(path: Path, models: list[LFTModel]) -> replay.ReplayResult:
    """replay_bag through the reader's row-by-row path (field_batches(columnar=False))."""
    replay_feed._COLUMNAR = False
    try:
        return replay.replay_bag(path, models)
    finally:
        replay_feed._COLUMNAR = True


def read_and_decode(path: Path) -> tuple[float, float]:
    """Wall times of reading alone and of reading + decoding, the replay's topics and fields."""
    topics = list(STREAMS)
    with bags.open_bag(path) as bag:
        t0 = time.perf_counter()
        for _ in bag._column_batches(bag._wanted(topics), replay_feed.BATCH):
            pass
        read = time.perf_counter() - t0
    with bags.open_bag(path) as bag:
        t0 = time.perf_counter()
        fields = {
            t: tuple(b.source.field for b in ts.bindings)
            for t, ts in itf.two_tank_map().topics().items()
        }
        for _ in bag.field_batches(topics, fields, size=replay_feed.BATCH):
            pass
        both = time.perf_counter() - t0
    return read, both


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
        walls, decs, vals, reads, boths = [], [], [], [], []
        res = None
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = replay.replay_bag(out, models)
            walls.append(time.perf_counter() - t0)
            decs.append(res.decode_s)
            vals.append(res.validate_s)
            read, both = read_and_decode(out)
            reads.append(read)
            boths.append(both)
        assert res is not None
        wall, dec, val = statistics.median(walls), statistics.median(decs), statistics.median(vals)
        read, both = statistics.median(reads), statistics.median(boths)
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
            f"split: reading {read:.3f} s ({read / wall:.0%}), decoding {both - read:.3f} s "
            f"({(both - read) / wall:.0%}) [reading+decoding in the replay {dec:.3f} s], "
            f"aligning+validating {val:.3f} s ({val / wall:.0%}), rest (opening, validator, "
            f"reports) {wall - dec - val:.3f} s ({(wall - dec - val) / wall:.0%})"
        )
        print(
            f"throughput: {speed:,.0f}x real time; goal >= {GOAL:,.0f}x: ratio {speed / GOAL:.2f} "
            f"({'met' if speed >= GOAL else 'NOT met'}); without validating "
            f"{duration / (wall - val):,.0f}x"
        )
        if args.baseline_repeats > 0:
            row_walls, row_decs = [], []
            rows = res
            for _ in range(args.baseline_repeats):
                t0 = time.perf_counter()
                rows = rows_path(out, models)
                row_walls.append(time.perf_counter() - t0)
                row_decs.append(rows.decode_s)
            rwall = statistics.median(row_walls)
            print(
                f"row-by-row reader path (field_batches(columnar=False)), same bag: median "
                f"{rwall:.3f} s = {duration / rwall:,.0f}x real time (reading+decoding "
                f"{statistics.median(row_decs):.3f} s); speed-up {rwall / wall:.1f}x; "
                f"same reports: {same(res.reports, rows.reports)}"
            )
            base_walls = []
            reports: list[WindowReport] = []
            for _ in range(args.baseline_repeats):
                t0 = time.perf_counter()
                reports = per_message(out, models)
                base_walls.append(time.perf_counter() - t0)
            base = statistics.median(base_walls)
            print(
                f"per-message path, same bag: median {base:.2f} s = "
                f"{duration / base:,.0f}x real time; speed-up {base / wall:.1f}x; "
                f"same reports: {same(res.reports, reports)}"
            )


if __name__ == "__main__":
    main()
