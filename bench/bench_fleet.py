"""Validate a directory of one-hour bags: the serial loop, and a local Dask cluster of 1 and 2.

Usage: scripts/run bench bench_fleet.py [--bags 24] [--hours 1.0] [--repeats 3]
       [--workers 1,2] [--diagnosis] [--keep DIR]

Writes --bags nominal 10 Hz bags of --hours each (noise seed k for bag k; every sixth with a
leak from half-way, so that the summary has alarms) and prints how long writing took. Then
validates the directory as `twotank-validation validate DIR --out OUT` does (models A and B;
the live diagnosis only with --diagnosis), through the same task per recording
(``usecases.ValidateJob``, built from the arguments as the CLI does) and ``fleet.run_fleet``:

* serially in one process (``--serial``, the reference): a child process of its own with
  the workers' environment (single-threaded BLAS), so that the clusters' scheduler threads
  in this process do not weigh on it;
* on a local cluster of each --workers count (``fleet.local_cluster``, as ``--workers N``
  starts), all started and warmed up before the clock runs (each process, this one too,
  first validates a short bag: imports, models, compiled kernels); the start-up is timed
  and printed on its own.

The runs interleave (serial, then each cluster, alternating their order per repeat), so
that a load from other processes that changes while measuring weighs on all alike.

For each: the median wall time over --repeats, the bag time per wall time, the parallel
efficiency (serial time / (workers x time); goal >= 0.85 with 2 workers on 2 cores), the CPU
time of this process and the workers together and its ratio to the serial loop's (the
efficiency the cores would give if nothing else ran on them: Dask's own cost), and the
peak resident memory of each worker after all the runs against the same worker before the
first (bounded: each task streams its bag and returns a summary). Every Dask run's files are
checked against the serial run's, byte for byte. Finally one cold `validate DIR --out OUT
--workers 2` (cluster start-up included) is timed end to end.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import multiprocessing
import os
import resource
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from twotank_validation import cli, fleet
from twotank_validation.bags import write_scenario_bag
from twotank_validation.sim import scenario as sc

GOAL = 0.85  # parallel efficiency with 2 workers on this 2-core machine (issue 19)


def write_bags(root: Path, n: int, hours: float) -> float:
    """n bags in root (kept if there); returns the seconds spent writing."""
    duration = round(hours * 3600 / 204.8) * 204.8  # whole excitation periods
    base = dataclasses.replace(sc.load_scenario("nominal"), duration_s=duration)
    t0 = time.perf_counter()
    for k in range(n):
        out = root / f"bag_{k:02d}"
        if out.exists():
            continue
        faults = (f"leak=0.03@{duration / 2:.0f}",) if k % 6 == 5 else ()
        write_scenario_bag(dataclasses.replace(base, seed=k, faults=faults), out, progress=False)
    return time.perf_counter() - t0


def peak_rss_mb() -> float:
    """This process's peak resident memory (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def warm_up(job: Any, bag: str) -> float:
    """One task on a short bag (imports, models, compiled kernels, as a first task); RSS."""
    fleet.run_task(job, bag)
    return peak_rss_mb()


def files(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.suffix != ".png"}


def cpu_s() -> float:
    """This process's CPU time (s, all threads)."""
    return time.process_time()


def timed_run(
    job: Any, expansion: fleet.Expansion, out: Path, dask: Any, client: Any = None
) -> tuple[float, float, int]:
    """(wall s, CPU s of this process and the workers, exit code) of one run."""
    w0 = client.run(cpu_s) if client is not None else {}
    c0, t0 = cpu_s(), time.perf_counter()
    res = fleet.run_fleet(job, expansion, out, ["A", "B"], dask=dask, figure=False)
    wall, cpu = time.perf_counter() - t0, cpu_s() - c0
    if client is not None:
        w1 = client.run(cpu_s)
        cpu += sum(w1[w] - w0[w] for w in w1)
    return wall, cpu, res.code


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bags", type=int, default=24)
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", default="1,2", help="comma-separated worker counts")
    parser.add_argument("--diagnosis", action="store_true", help="with the live diagnosis")
    parser.add_argument("--keep", help="write the bags here (reused) instead of a temp folder")
    args = parser.parse_args()
    from distributed import Client  # noqa: PLC0415

    os.environ.update(fleet.worker_env())  # for the reference process started below

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.keep) if args.keep else Path(tmp) / "bags"
        root.mkdir(parents=True, exist_ok=True)
        write_s = write_bags(root, args.bags, args.hours)
        bag_h = args.bags * args.hours
        print(f"{args.bags} bags of {args.hours:g} h (10 Hz, 3 topics) in {root}")
        print(f"writing them: {write_s:.1f} s (0 s: reused)")

        argv = ["validate", str(root), "--quiet"] + ([] if args.diagnosis else ["--no-diagnosis"])
        job = cli._validate_job(cli.build_parser().parse_args(argv), fleet=True)
        expansion = fleet.expand_paths([str(root)])
        assert len(expansion.recordings) == args.bags
        outs = Path(tmp) / "out"
        warm = Path(tmp) / "warm"
        if not warm.exists():
            short = dataclasses.replace(sc.load_scenario("nominal"), duration_s=5 * 204.8)
            write_scenario_bag(short, warm, progress=False)
        warm_up(job, str(warm))
        counts = [int(w) for w in args.workers.split(",")]
        with contextlib.ExitStack() as stack:
            clusters, starts, before = {}, {}, {}
            for n in counts:  # all up before the clock runs; the runs interleave (fair under
                t0 = time.perf_counter()  # a load that changes while measuring)
                cluster = stack.enter_context(fleet.local_cluster(n))
                client = stack.enter_context(Client(cluster))
                before[n] = client.run(warm_up, job, str(warm))
                starts[n] = time.perf_counter() - t0
                clusters[n] = (cluster, client)
            times: dict[str, list[float]] = {"serial": [], **{str(n): [] for n in counts}}
            cpus: dict[str, list[float]] = {k: [] for k in times}
            codes = set()
            reference = stack.enter_context(
                ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
            )
            reference.submit(warm_up, job, str(warm)).result()
            for r in range(args.repeats):
                serial_run = reference.submit(timed_run, job, expansion, outs / f"serial{r}", None)
                t, c, code = serial_run.result()
                times["serial"].append(t)
                cpus["serial"].append(c)
                codes.add(code)
                for n in counts if r % 2 == 0 else counts[::-1]:
                    cluster, client = clusters[n]
                    dask = fleet.DaskSettings(scheduler=cluster.scheduler_address)
                    t, c, code = timed_run(job, expansion, outs / f"w{n}_{r}", dask, client)
                    times[str(n)].append(t)
                    cpus[str(n)].append(c)
                    codes.add(code)
            peaks = {n: clusters[n][1].run(peak_rss_mb) for n in counts}
        ref = files(outs / "serial0")
        t_serial = statistics.median(times["serial"])
        print(f"exit code(s) {sorted(codes)}; times are medians of {args.repeats}, interleaved")
        c_serial = statistics.median(cpus["serial"])
        print(
            f"{'mode':<18}{'wall (s)':>9}{'x real time':>13}{'efficiency':>12}{'CPU (s)':>9}"
            f"{'CPU eff.':>10}{'worker RSS before/peak (MB)':>30}"
        )
        print(
            f"{'serial loop':<18}{t_serial:>9.2f}{bag_h * 3600 / t_serial:>13.0f}{'1':>12}"
            f"{c_serial:>9.1f}{'1':>10}"
        )
        efficiency = {}
        for n in counts:
            same = all(
                files(outs / f"w{n}_{r}") == files(outs / f"serial{r}") == ref
                for r in range(args.repeats)
            )
            t = statistics.median(times[str(n)])
            efficiency[n] = t_serial / (n * t)
            rss = ", ".join(f"{before[n][w]:.0f}/{peaks[n][w]:.0f}" for w in sorted(peaks[n]))
            spread = ", ".join(f"{x:.1f}" for x in times[str(n)])
            c = statistics.median(cpus[str(n)])
            print(
                f"{f'{n} worker(s)':<18}{t:>9.2f}{bag_h * 3600 / t:>13.0f}"
                f"{efficiency[n]:>12.2f}{c:>9.1f}{c_serial / c:>10.2f}{rss:>30}   (start-up {starts[n]:.1f} s; runs {spread} s; "
                f"{'identical to serial' if same else 'DIFFERS from serial'})"
            )
            if not same:
                return 1
        spread = ", ".join(f"{x:.1f}" for x in times["serial"])
        print(f"serial runs {spread} s")
        t0 = time.perf_counter()
        code = cli.main([*argv, "--out", str(outs / "cold"), "--workers", "2"])
        print(
            f"cold `validate DIR --out OUT --workers 2` end to end: "
            f"{time.perf_counter() - t0:.1f} s (cluster start, figure and table included), "
            f"exit code {code}"
        )
        print(f"serial process peak RSS: {peak_rss_mb():.0f} MB")
        if 2 in efficiency:
            print(f"efficiency with 2 workers {efficiency[2]:.2f} (goal >= {GOAL})")
        print(f"cores: {os.cpu_count()}; load average {os.getloadavg()[0]:.1f}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
