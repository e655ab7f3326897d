"""The live view's cost: report-to-page latency, and the validator's CPU with the view attached.

Usage: scripts/run bench bench_view.py [--hours 6] [--reports 200] [--interval 0.05]
       [--repeats 5]

Writes the leak scenario (Ts 0.1 s, period 2048: windows of 4096 samples, 2049 bins) for
``--hours`` into a temporary bag, then:

1. Latency. Replays it once (``validate``'s job: the same OnlineValidator path) to collect
   its reports, then pushes ``--reports`` of them through a :class:`ViewServer` one every
   ``--interval`` s while a headless Chromium page (tools/browser.py) shows them; the page
   notes, at the animation frame that draws a report, the wall time since the server pushed
   it (one clock: the same machine). p50 and p99; the goal is p99 <= 200 ms.
2. CPU. Replays the bag as fast as it goes (``ValidateJob.run``, models A and B, the live
   diagnosis off so that the validator's own work is smallest and the view's share largest),
   without the view and with it (server, every report pushed, one page connected), and
   takes the CPU time of the thread that replays (the validator's) and of this whole process
   (its threads, the server's included; Chromium is a process of its own and not counted,
   but it runs on the same cores meanwhile). Medians over ``--repeats`` runs each, and their
   ratio; the goal is within 10 %. The runs with and without alternate, so that the
   machine's load falls on both alike.

Run it inside the loopback-only namespace (``unshare -n``), like the tests.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from tools.browser import headless_page
from twotank_validation.bags import write_scenario_bag
from twotank_validation.online import WindowReport
from twotank_validation.sim import scenario as sc
from twotank_validation.usecases import ValidateJob
from twotank_validation.view import ViewServer

GOAL_P99_MS = 200.0
GOAL_CPU_RATIO = 1.10


def _bag(hours: float, folder: Path) -> Path:
    base = sc.load_scenario("leak")
    s = dataclasses.replace(base, duration_s=hours * 3600.0, faults=("leak=0.04@1500",))
    return write_scenario_bag(s, folder / "leak", storage="mcap")


def _job(bag: Path) -> ValidateJob:
    return ValidateJob(str(bag), models=("A", "B"), diagnosis=False)


def _wait(page: Any, n: int, timeout_s: float = 30.0) -> None:
    page.wait_for_function(f"window.twotankView.latencies.length >= {n}", timeout=timeout_s * 1000)


def latency(bag: Path, n: int, interval: float) -> np.ndarray:
    """(n,) ms from each report pushed to the page's frame that draws it."""
    reports: list[tuple[WindowReport, int]] = []
    _job(bag).run(on_report=lambda r, s: reports.append((r, s)))
    if len(reports) < n:
        raise SystemExit(f"the bag gave {len(reports)} reports, fewer than {n}: raise --hours")
    with ViewServer(title="bench") as view, headless_page(bypass_csp=True) as page:
        page.goto(view.url)
        page.wait_for_function("window.twotankView.connected")
        t0 = time.monotonic()
        for k, (rep, start) in enumerate(reports[:n]):
            due = t0 + k * interval
            time.sleep(max(due - time.monotonic(), 0.0))
            view.publish_report(rep, start)
        _wait(page, n)
        ms = page.evaluate("window.twotankView.latencies.map(x => x.ms)")
    return np.asarray(ms[:n], dtype=float)


def cpu(bag: Path, with_view: bool) -> tuple[float, float, int]:
    """CPU seconds of one replay: its thread's, the whole process's; the reports pushed."""
    job = _job(bag)
    if not with_view:
        c0, t0 = time.process_time(), time.thread_time()
        job.run()
        return time.thread_time() - t0, time.process_time() - c0, 0
    with ViewServer(title="bench") as view, headless_page(bypass_csp=True) as page:
        page.goto(view.url)
        page.wait_for_function("window.twotankView.connected")
        c0, t0 = time.process_time(), time.thread_time()
        job.run(on_report=view.publish_report)
        spent = time.thread_time() - t0, time.process_time() - c0
        _wait(page, view.published)  # the page got them all (not counted: after the run)
        return *spent, view.published


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, default=6.0)
    ap.add_argument("--reports", type=int, default=200)
    ap.add_argument("--interval", type=float, default=0.05)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bag = _bag(args.hours, Path(tmp))
        ms = latency(bag, args.reports, args.interval)
        p50, p99 = np.percentile(ms, [50, 99])
        print(
            f"latency, report pushed -> page drew it, {ms.size} reports one every "
            f"{args.interval * 1000:.0f} ms: p50 {p50:.1f} ms, p99 {p99:.1f} ms, max "
            f"{ms.max():.1f} ms (goal p99 <= {GOAL_P99_MS:.0f} ms: "
            f"{'met' if p99 <= GOAL_P99_MS else 'NOT met'})"
        )
        cpu(bag, False)  # warm: imports, the models' responses
        without: list[tuple[float, float, int]] = []
        withv: list[tuple[float, float, int]] = []
        for _ in range(args.repeats):  # interleaved: the machine's load hits both alike
            without.append(cpu(bag, False))
            withv.append(cpu(bag, True))
        print(
            f"CPU of a {args.hours:g} h replay (models A and B, {withv[0][2]} reports), "
            f"medians of {args.repeats}, without the view / with it and a page:"
        )
        for k, what in ((0, "the validator's thread"), (1, "the whole process")):
            a = statistics.median(r[k] for r in without)
            b = statistics.median(r[k] for r in withv)
            print(
                f"  {what}: {a:.3f} s / {b:.3f} s; ratio {b / a:.3f} (goal <= "
                f"{GOAL_CPU_RATIO:.2f}: {'met' if b / a <= GOAL_CPU_RATIO else 'NOT met'})"
            )


if __name__ == "__main__":
    main()
