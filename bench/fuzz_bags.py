"""Fuzz the bag reader: damaged bags must give a BagError (or read), never another error or a hang.

Usage (inside the project venv)::

    bash scripts/run bench fuzz_bags.py --seconds 300 --seed 1

Small golden bags of every storage (rosbag2 MCAP and SQLite3 written by rosbags, plain MCAP
files written by mcap_ros2 with zstd, lz4 and no compression) are generated with
``test/data/make_bags.py`` and damaged case by case: cut at a random byte, random bytes
flipped, a range overwritten with noise or zeros, a range deleted, metadata.yaml garbled.
Each case opens the bag, checks the interface topics and reads every message. Cases run in a
worker process; the parent kills it when one case takes longer than ``--timeout`` seconds
and counts a hang. Case i depends only on (seed, i), so ``--seed S --case I`` replays one.

Prints the cases run and the outcomes by class, and exits 1 on any exception that is not a
BagError or any hang (the failing cases are listed with their seed and index).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import multiprocessing as mp
import random
import shutil
import sys
import tempfile
import time
import traceback
from collections import Counter
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def _make_bags_module() -> Any:
    spec = importlib.util.spec_from_file_location(
        "make_bags", ROOT / "test" / "data" / "make_bags.py"
    )
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["make_bags"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def build_fixtures(out: Path) -> dict[str, tuple[Path, str | None]]:
    """Fixture bags: name -> (bag path, file inside it to damage, None if the bag is the file)."""
    mb = _make_bags_module()
    msgs = sorted(mb.samples(12), key=lambda m: m.log_time_ns)
    fixtures: dict[str, tuple[Path, str | None]] = {}
    for storage in ("mcap", "sqlite3"):
        bag = mb.write_rosbag2(out / f"rosbag2_{storage}", storage, msgs)
        inner = next(p.name for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
        fixtures[f"rosbag2_{storage}"] = (bag, inner)
    old = mb.write_rosbag2(out / "rosbag2_sqlite3_humble", "sqlite3", msgs, definitions=False)
    fixtures["rosbag2_sqlite3_humble"] = (old, "rosbag2_sqlite3_humble.db3")
    for comp in ("zstd", "lz4", "none"):
        path = mb.write_plain_mcap(
            out / f"plain_{comp}.mcap", msgs, chunk_size=600, compression=comp
        )
        fixtures[f"plain_{comp}"] = (path, None)
    return fixtures


def mutate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """A damaged copy of ``data`` and a description of the damage."""
    n = len(data)
    kind = rng.choice(["cut", "flip", "flip", "noise", "zero", "delete"])
    if kind == "cut" or n < 2:
        at = rng.randrange(0, max(n, 1))
        return data[:at], f"cut at {at}"
    buf = bytearray(data)
    if kind == "flip":
        k = rng.randint(1, 8)
        spots = sorted(rng.randrange(n) for _ in range(k))
        for at in spots:
            buf[at] ^= 1 << rng.randrange(8)
        return bytes(buf), f"flip bits at {spots}"
    at = rng.randrange(n)
    length = min(n - at, rng.choice([1, 4, 8, 16, 64, 256]))
    if kind == "noise":
        buf[at : at + length] = bytes(rng.randrange(256) for _ in range(length))
        return bytes(buf), f"noise {length} bytes at {at}"
    if kind == "zero":
        buf[at : at + length] = bytes(length)
        return bytes(buf), f"zero {length} bytes at {at}"
    del buf[at : at + length]
    return bytes(buf), f"delete {length} bytes at {at}"


def make_case(
    fixtures: dict[str, tuple[Path, str | None]], work: Path, seed: int, index: int
) -> tuple[Path, str]:
    """Write case ``index`` of ``seed`` under ``work``; return the path to open and a label."""
    rng = random.Random(f"{seed}:{index}")
    name = rng.choice(sorted(fixtures))
    src, inner = fixtures[name]
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    if inner is None:
        data, what = mutate(src.read_bytes(), rng)
        target = work / src.name
        target.write_bytes(data)
        return target, f"{name}: {what}"
    bag = work / src.name
    shutil.copytree(src, bag)
    victim = "metadata.yaml" if rng.random() < 0.1 else inner
    data, what = mutate((bag / victim).read_bytes(), rng)
    (bag / victim).write_bytes(data)
    return bag, f"{name}/{victim}: {what}"


def run_case(path: Path) -> str:
    """Open, check and read a bag; the outcome class name ("ok" if it all read)."""
    from twotank_validation import bags  # noqa: PLC0415 - imported in the worker

    try:
        with bags.open_bag(path) as bag:
            checks = (bags.TopicMissingError, bags.TopicTypeError, bags.BagEmptyError)
            with contextlib.suppress(*checks):  # a refusal is a valid outcome; read anyway
                bag.check_topics(bags.expected_types())
            for _ in bag.messages(list(bag.info.topics)):
                pass
    except bags.BagError as err:
        return type(err).__name__
    return "ok"


def _worker(
    conn: Connection,
    seed: int,
    first: int,
    work: Path,
    fixtures: dict[str, tuple[Path, str | None]],
) -> None:
    index = first
    while True:
        path, label = make_case(fixtures, work, seed, index)
        conn.send(("start", index, label))
        try:
            outcome = run_case(path)
            conn.send(("done", index, outcome, ""))
        except Exception as err:  # that is what the fuzzing looks for
            conn.send(("fail", index, type(err).__name__, traceback.format_exc()))
        index += 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="how long to fuzz")
    parser.add_argument("--seed", type=int, default=0, help="seed of the case sequence")
    parser.add_argument("--timeout", type=float, default=20.0, help="seconds a case may take")
    parser.add_argument("--case", type=int, default=None, help="replay this one case and exit")
    args = parser.parse_args(argv)

    tmp = Path(tempfile.mkdtemp(prefix="fuzz_bags_"))
    try:
        if args.case is not None:
            fixtures = build_fixtures(tmp / "fixtures")
            path, label = make_case(fixtures, tmp / "case", args.seed, args.case)
            print(f"case {args.seed}:{args.case} {label}")
            print("outcome:", run_case(path))
            return 0
        return _fuzz(args, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _fuzz(args: argparse.Namespace, tmp: Path) -> int:
    ctx = mp.get_context("spawn")
    outcomes: Counter[str] = Counter()
    failures: list[str] = []
    deadline = time.monotonic() + args.seconds
    next_index = 0
    fixtures = build_fixtures(tmp / "fixtures")
    while time.monotonic() < deadline:
        parent, child = ctx.Pipe()
        proc = ctx.Process(
            target=_worker, args=(child, args.seed, next_index, tmp / "case", fixtures)
        )
        proc.start()
        current: tuple[int, str] | None = None
        started = time.monotonic()
        try:
            while time.monotonic() < deadline:
                limit = args.timeout if current is not None else 120.0  # worker start-up
                if not parent.poll(max(0.0, min(limit - (time.monotonic() - started), 1.0))):
                    if time.monotonic() - started > limit:
                        what = current[1] if current else "starting the worker"
                        idx = current[0] if current else next_index
                        failures.append(f"HANG (> {limit:g} s) case {args.seed}:{idx} {what}")
                        outcomes["HANG"] += 1
                        next_index = idx + 1
                        break
                    if not proc.is_alive():
                        if current is None:
                            print("ERROR: the fuzz worker failed before its first case")
                            return 2
                        failures.append(f"worker died (exit {proc.exitcode}) at {current}")
                        outcomes["CRASH"] += 1
                        next_index = (current[0] if current else next_index) + 1
                        break
                    continue
                msg = parent.recv()
                if msg[0] == "start":
                    current = (msg[1], msg[2])
                    started = time.monotonic()
                    continue
                _, idx, outcome, tb = msg
                next_index = idx + 1
                if msg[0] == "fail":
                    label = current[1] if current else "?"
                    failures.append(
                        f"NOT A BagError: {outcome} in case {args.seed}:{idx} {label}\n{tb}"
                    )
                    outcomes[f"NOT BagError: {outcome}"] += 1
                else:
                    outcomes[outcome] += 1
                current = None
                started = time.monotonic()
        finally:
            proc.kill()
            proc.join()
    total = sum(outcomes.values())
    print(f"cases run: {total} (seed {args.seed}, {args.seconds:.0f} s)")
    for outcome, count in sorted(outcomes.items(), key=lambda kv: -kv[1]):
        print(f"  {outcome:<28} {count}")
    for line in failures:
        print(line)
    if failures:
        print(f"FAILED: {len(failures)} case(s); replay one with --seed S --case I")
        return 1
    print("OK: every damaged bag gave a BagError or was read")
    return 0


if __name__ == "__main__":
    sys.exit(main())
