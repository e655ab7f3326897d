"""This checkout's replay and window paths against another revision's, in one run.

Usage: scripts/run bench bench_revisions.py [--against REV] [--hours 1.0] [--rounds 5]
       [--repeats 3]

Writes the nominal scenario for ``--hours`` into a temporary rosbag2 bag (with this checkout's
writer), extracts ``REV`` (default: ``HEAD~1``) with ``git archive`` into a temporary folder,
then times, in alternating rounds so that a change of machine load hits both alike, in a
fresh process per round and tree (same interpreter and venv, the tree first on
``PYTHONPATH``):

* ``replay_bag`` of the bag for Models A and B with the default settings (the two-tank
  interface): reading, decoding, aligning, validating, the reports;
* the window path alone: the same hour as aligned samples through ``OnlineValidator.
  feed_many`` (one command and one message per output per sample).

Each process prints its median over ``--repeats`` runs (after one warm-up run) and a digest
of every report (model, window, judged, beta, beta_op, alarm, data quality, bit for bit), so
the run also shows whether both trees give the same reports. Prints the medians of the
rounds' medians and the ratio this/REV for each path.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

from twotank_validation import bags
from twotank_validation.sim import scenario as sc

ROOT = Path(__file__).resolve().parents[1]


def child_code() -> str:
    """The program each round runs in a fresh process (only APIs both trees have)."""
    return r"""
import hashlib, json, statistics, struct, sys, time
import numpy as np
from twotank_validation import replay
from twotank_validation.core.model import load_model
from twotank_validation.online import MonitorConfig, OnlineValidator
from twotank_validation.online.aligner import COMMAND

path, record, repeats = sys.argv[1], sys.argv[2], int(sys.argv[3])
models = [load_model("A"), load_model("B")]

def digest(reports):
    h = hashlib.sha256()
    for r in reports:
        h.update(repr((r.model, r.start_ns, r.end_ns, r.judged, r.alarm.name,
                       r.data_quality)).encode())
        h.update(struct.pack("<dd", r.beta, r.beta_op))
    return h.hexdigest()[:16]

def timed(run):
    walls, out = [], None
    for k in range(repeats + 1):  # the first run warms up (imports, caches)
        t0 = time.perf_counter()
        out = run()
        if k:
            walls.append(time.perf_counter() - t0)
    return statistics.median(walls), out

replay_s, res = timed(lambda: replay.replay_bag(path, models).reports)
data = np.load(record)
n = len(data["stamps"])
kinds = np.concatenate([np.full(n, COMMAND), np.zeros(n, int), np.ones(n, int)])
stamps = np.tile(data["stamps"], 3)
values = np.full((3 * n, 2), np.nan)
values[:n] = data["u"]
values[n:2 * n, 0] = data["y"][:, 0]
values[2 * n:, 0] = data["y"][:, 1]
order = np.argsort(stamps + np.where(kinds == COMMAND, 0, 1), kind="stable")
kinds, stamps, values = kinds[order].astype(np.int8), stamps[order], values[order]

def windows():
    return OnlineValidator(MonitorConfig(), models).feed_many(kinds, stamps, values)

window_s, reps = timed(windows)
print(json.dumps({"replay_s": replay_s, "replay_digest": digest(res),
                  "window_s": window_s, "window_digest": digest(reps)}))
"""


def run_round(tree: Path, bag: Path, record: Path, repeats: int) -> dict[str, object]:
    """One fresh process on ``tree``: its medians and digests."""
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1")
    out = subprocess.run(
        [sys.executable, "-c", child_code(), str(bag), str(record), str(repeats)],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode != 0:
        sys.exit(f"the round on {tree} failed:\n{out.stderr[-3000:]}")
    result: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def extract(rev: str, into: Path) -> Path:
    """``git archive REV`` unpacked into ``into``; the tree's root."""
    archive = into / "rev.tar"
    subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", "-o", str(archive), rev], check=True
    )
    tree = into / "tree"
    with tarfile.open(archive) as tar:
        tar.extractall(tree, filter="data")
    return tree


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", default="HEAD~1", help="the revision to compare with")
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    import numpy as np  # noqa: PLC0415

    rev = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", args.against],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    duration = round(args.hours * 3600 / 204.8) * 204.8
    scen = dataclasses.replace(sc.load_scenario("nominal"), duration_s=duration)
    with tempfile.TemporaryDirectory() as tmp:
        bag = bags.write_scenario_bag(scen, Path(tmp) / "bag")
        stamps, u, y = sc.simulate_scenario(scen)
        record = Path(tmp) / "record.npz"
        np.savez(record, stamps=stamps, u=u, y=y)
        old = extract(rev, Path(tmp))
        trees = {"this checkout": ROOT, f"{rev}": old}
        got: dict[str, list[dict[str, object]]] = {name: [] for name in trees}
        t0 = time.perf_counter()
        for _ in range(args.rounds):
            for name, tree in trees.items():
                got[name].append(run_round(tree, bag, record, args.repeats))
        wall = time.perf_counter() - t0
    print(
        f"{duration:.0f} s of 10 Hz data, Models A and B, {args.rounds} alternating rounds of "
        f"{args.repeats} timed runs each ({wall:.0f} s wall, load average "
        f"{os.getloadavg()[0]:.2f})"
    )
    medians: dict[str, dict[str, float]] = {}
    for name, rounds in got.items():
        medians[name] = {
            key: statistics.median(float(r[key]) for r in rounds)  # type: ignore[arg-type]
            for key in ("replay_s", "window_s")
        }
        digests = {(r["replay_digest"], r["window_digest"]) for r in rounds}
        print(
            f"{name:>14}: replay_bag median {medians[name]['replay_s']:.3f} s "
            f"({duration / medians[name]['replay_s']:,.0f}x real time), window path "
            f"(feed_many) {medians[name]['window_s']:.3f} s; report digests {sorted(digests)}"
        )
    this, other = medians["this checkout"], medians[rev]
    same = {(r["replay_digest"], r["window_digest"]) for r in got["this checkout"]} == {
        (r["replay_digest"], r["window_digest"]) for r in got[rev]
    }
    print(
        f"ratio this/{rev}: replay {this['replay_s'] / other['replay_s']:.3f}, window path "
        f"{this['window_s'] / other['window_s']:.3f}; the same reports bit for bit: {same}"
    )


if __name__ == "__main__":
    main()
