"""The live validator node at 10 Hz: report latency, CPU and memory over simulated hours.

Usage (DDS on loopback only: scripts/run bench runs it in a private network namespace):
    ROS_DOMAIN_ID=93 bash scripts/run bench bench_node.py [--hours 24]

The validator node runs alone in a child process, exactly as its entry point runs it
(``ValidatorNode`` spun by ``rclpy.spin``, models A and B, default parameters: 10 Hz,
2048-sample period, 2-period windows judged every quarter period) with ``use_sim_time``. This process is the rig: it
publishes ``/clock`` and the three input topics over loopback DDS for every 0.1 s sample of
the nominal scenario (its steady-state period, repeated), as fast as the node takes them (in
lockstep, never sleeping simulated time), and subscribes to the reports.

* Latency: for each window, the time from publishing its last sample to receiving the report
  of every model (measured here, so it includes DDS both ways). Before a window's last
  sample the node has consumed everything else, so the figure is the node's own.
* CPU: the node process's CPU time (all threads, less the thread that answers this
  benchmark's queries) per simulated second = the fraction of one core it needs at 10 Hz.
  With lockstep the node sees the messages one sample at a time, as at 10 Hz.
* Memory: every simulated hour the node process's RSS, the blocks held by Python's allocator
  (``sys.getallocatedblocks``) and the number of objects the garbage collector tracks; and
  tracemalloc's traced memory (with the sites that grew) over ``--trace-hours`` hours from
  the end of the first hour (tracing slows Python several-fold, so it does not run for all
  24 hours; CPU is taken from the untraced hours).

Prints medians and 99th percentiles and the ratios to the goals (latency p99 <= 50 ms, CPU
< 5 % of one core, memory flat). About 10 to 15 minutes of wall time for 24 hours on two
shared cores.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

NS = 1_000_000_000
SYNC_TIMEOUT_S = 10.0  # a message DDS never delivered: count it, go on
LATENCY_GOAL_S = 0.050
CPU_GOAL = 0.05
HOUR_S = 3600


# --------------------------------------------------------------------------------- the node


def rss_kb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1


def child() -> None:
    """The node, spun by rclpy.spin in a thread; this thread answers the benchmark."""
    import gc  # noqa: PLC0415
    import tracemalloc  # noqa: PLC0415

    import rclpy  # noqa: PLC0415
    from rclpy.parameter import Parameter  # noqa: PLC0415

    from twotank_validation.ros.lifecycle import bring_up  # noqa: PLC0415
    from twotank_validation.ros.validator_node import ValidatorNode  # noqa: PLC0415

    rclpy.init()
    node = bring_up(ValidatorNode(parameter_overrides=[Parameter("use_sim_time", value=True)]))
    spinner = threading.Thread(target=rclpy.spin, args=(node,), daemon=True)
    spinner.start()
    out = sys.stdout

    def reply(obj: Any) -> None:
        out.write(json.dumps(obj) + "\n")
        out.flush()

    pauses: list[tuple[int, float]] = []  # garbage collections: generation, seconds
    started = [0.0]

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            started[0] = time.perf_counter()
        else:
            pauses.append((info["generation"], time.perf_counter() - started[0]))

    gc.callbacks.append(on_gc)
    reply({"ready": True})
    first: tracemalloc.Snapshot | None = None
    for line in sys.stdin:
        cmd, *arg = line.split()
        if cmd == "sync":  # wait until the node has taken and processed these messages
            want = dict(zip(node.received, map(int, arg), strict=True))
            deadline = time.monotonic() + SYNC_TIMEOUT_S
            while any(node.received[s] < n for s, n in want.items()):
                if time.monotonic() > deadline:
                    break
                time.sleep(0.0002)
            node.wait_idle()
            reply({"received": dict(node.received)})
        elif cmd == "stats":
            traced = tracemalloc.get_traced_memory()[0] if tracemalloc.is_tracing() else None
            objects = len(gc.get_objects())  # this thread's CPU, left out of the node's
            reply(
                {
                    "cpu_s": time.process_time(),
                    "bench_thread_cpu_s": time.thread_time(),
                    "rss_kb": rss_kb(),
                    "blocks": sys.getallocatedblocks(),
                    "objects": objects,
                    "traced_bytes": traced,
                    "reports_kept": len(node.reports),
                    "counters": dataclasses.asdict(node.core.counters()),
                    "samples": node.core.samples_seen,
                    "gc_pauses": [(g, round(d, 6)) for g, d in pauses if g == 2 or d > 0.002],
                    "gc_count": len(pauses),
                    "node_latency_s": list(node.report_latency_s),
                }
            )
            pauses.clear()
            node.report_latency_s.clear()
        elif cmd == "trace":
            tracemalloc.start()
            reply({"ok": True})
        elif cmd == "mark":  # tracing has run long enough for every buffer to turn over
            first = tracemalloc.take_snapshot()
            reply({"traced_bytes": tracemalloc.get_traced_memory()[0]})
        elif cmd == "untrace":
            assert first is not None
            last = tracemalloc.take_snapshot()
            traced = tracemalloc.get_traced_memory()[0]
            tracemalloc.stop()
            top = [
                f"{st.size_diff / 1024:+.1f} KiB {st.traceback[0].filename}:{st.traceback[0].lineno}"
                for st in last.compare_to(first, "lineno")[:5]
            ]
            reply({"traced_bytes": traced, "top": top})
        elif cmd == "quit":
            break
    node.destroy_node()
    rclpy.shutdown()
    reply({"bye": True})


# ------------------------------------------------------------------------------------ rig


class Child:
    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--child"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.ask(None).get("ready")
        self.deficit = [0, 0, 0]  # flow_cmd, height, temperature messages never delivered

    def sync(self, k: int) -> int:
        """Wait until the node has processed the messages of samples < k; messages lost.

        A message that does not arrive within SYNC_TIMEOUT_S counts as lost (reported at the
        end; the node flags the gap), and later syncs expect one fewer on its topic.
        """
        want = [k - d for d in self.deficit]
        got = list(self.ask("sync " + " ".join(map(str, want)))["received"].values())
        self.deficit = [k - g for g in got]
        return sum(self.deficit)

    def ask(self, cmd: str | None) -> dict[str, Any]:
        assert self.proc.stdin is not None
        assert self.proc.stdout is not None
        if cmd is not None:
            self.proc.stdin.write(cmd + "\n")
            self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("the node process died")
        return dict(json.loads(line))


def steady_period() -> tuple[np.ndarray, np.ndarray]:
    """One period of the nominal scenario in periodic steady state: (u, y), (2048, 2) each."""
    import dataclasses  # noqa: PLC0415

    from twotank_validation.sim import scenario as sc  # noqa: PLC0415

    scen = sc.load_scenario("nominal")
    scen = dataclasses.replace(scen, duration_s=3 * scen.period_samples * scen.ts_s)
    _, u, y = sc.simulate_scenario(scen)
    p = scen.period_samples
    return u[-p:], y[-p:]


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs), q)) if xs else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0, help="simulated hours")
    parser.add_argument("--sync-every", type=int, default=100, help="samples between syncs")
    parser.add_argument(
        "--trace-hours", type=float, default=1.0, help="hours traced by tracemalloc (0: none)"
    )
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child()
        return
    if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") != "LOCALHOST":
        sys.exit("set ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (scripts/run does)")

    import rclpy  # noqa: PLC0415
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415
    from rclpy.node import Node  # noqa: PLC0415
    from rosgraph_msgs.msg import Clock  # noqa: PLC0415
    from sensor_msgs.msg import FluidPressure, Temperature  # noqa: PLC0415

    from twotank_validation.online import MonitorConfig  # noqa: PLC0415
    from twotank_validation.online import streams as itf  # noqa: PLC0415
    from twotank_validation.ros import messages  # noqa: PLC0415
    from twotank_validation.ros.validator_node import VALIDATOR_PARAMS  # noqa: PLC0415

    defaults = {p.name: p.default for p in VALIDATOR_PARAMS}
    ts_ns = round(float(defaults["ts_s"]) * NS)
    period = int(defaults["period_samples"])
    window = period * int(defaults["periods_per_window"])
    # a window closes every hop (the node's default: a quarter period), as MonitorConfig says
    hop = MonitorConfig(period_samples=period, hop_samples=int(defaults["hop_samples"])).hop
    models = list(defaults["models"])
    n = round(args.hours * HOUR_S * NS / ts_ns)
    u, y = steady_period()
    units = itf.RigUnits()
    pressure = units.pressure_from_level(y[:, 0]).tolist()
    celsius = units.celsius_from_temperature(y[:, 1]).tolist()
    hot, cold = u[:, 0].tolist(), u[:, 1].tolist()

    node_proc = Child()
    rclpy.init()
    rig = Node("bench_rig")
    flow_cls, report_cls = messages.message_classes()
    pub_clock = rig.create_publisher(Clock, "/clock", 10)
    pubs = [
        rig.create_publisher(flow_cls, "flow_cmd", 1000),
        rig.create_publisher(FluidPressure, "height", 1000),
        rig.create_publisher(Temperature, "temperature", 1000),
    ]
    got: dict[int, dict[str, float]] = {}  # window end (ns) -> model -> receive time

    def on_report(msg: Any) -> None:
        t = time.perf_counter()
        got.setdefault(itf.stamp_ns(msg), {})[msg.model] = t

    for m in models:
        rig.create_subscription(report_cls, f"validation/{m}/report", on_report, 100)
    ex = SingleThreadedExecutor()
    ex.add_node(rig)

    def spin_until(cond: Any, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while not cond():
            if time.monotonic() > deadline:
                return False
            ex.spin_once(timeout_sec=0.001)
        return True

    ready = spin_until(
        lambda: (
            all(p.get_subscription_count() >= 1 for p in [pub_clock, *pubs])
            and all(rig.count_publishers(f"validation/{m}/report") >= 1 for m in models)
        ),
        20.0,
    )
    if not ready:
        sys.exit("discovery failed: the node's topics did not match")
    time.sleep(0.5)  # let the reliable readers/writers settle
    clk, f, h, tm = Clock(), flow_cls(), FluidPressure(), Temperature()

    def publish(k: int) -> None:
        t = k * ts_ns
        j = k % period
        sec, nsec = divmod(t, NS)
        clk.clock.sec, clk.clock.nanosec = sec, nsec
        pub_clock.publish(clk)
        for msg in (f, h, tm):
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
        f.hot, f.cold = hot[j], cold[j]
        h.fluid_pressure = pressure[j]
        tm.temperature = celsius[j]
        for p, msg in zip(pubs, (f, h, tm), strict=True):
            p.publish(msg)

    hour = round(HOUR_S * NS / ts_ns)
    # tracemalloc: on at hour 1; the reference snapshot after 10 windows (the node's report
    # history and every other buffer have turned over by then); the last after --trace-hours
    trace_from = hour if args.trace_hours > 0 else None
    trace_mark = hour + 10 * period if trace_from is not None else None
    trace_to = trace_mark + round(hour * args.trace_hours) if trace_mark is not None else None
    traced: dict[str, Any] = {}
    latencies: list[tuple[int, float]] = []  # (sample, seconds)
    missing_reports = 0
    stats = [node_proc.ask("stats")]
    stats_at = [0]
    wall0 = time.perf_counter()
    for k in range(n):
        closes = (k + 1) % hop == 0 and k + 1 >= window
        if closes or (k and k % args.sync_every == 0):
            lost = node_proc.sync(k)
        if k and k % hour == 0:
            stats.append(node_proc.ask("stats"))
            stats_at.append(k)
            print(
                f"  {k / hour:5.1f} h simulated, {time.perf_counter() - wall0:6.0f} s wall, "
                f"RSS {stats[-1]['rss_kb'] / 1024:.1f} MiB",
                flush=True,
            )
        if k == trace_from:
            node_proc.ask("trace")
        if k == trace_mark:
            lost = node_proc.sync(k)
            traced["at_mark"] = node_proc.ask("mark")["traced_bytes"]
        if k == trace_to:
            lost = node_proc.sync(k)
            traced |= node_proc.ask("untrace")
        publish(k)
        if closes:
            t0 = time.perf_counter()
            end = k * ts_ns
            if spin_until(lambda e=end: len(got.get(e, {})) == len(models), 5.0):
                latencies.append((k, max(got.pop(end).values()) - t0))
            else:
                missing_reports += 1
        elif k % 50 == 0:
            ex.spin_once(timeout_sec=0)
    lost = node_proc.sync(n)
    if trace_to is not None and trace_to >= n and "at_mark" in traced:
        traced |= node_proc.ask("untrace")
        trace_to = n
    stats.append(node_proc.ask("stats"))
    stats_at.append(n)
    wall = time.perf_counter() - wall0
    node_proc.ask("quit")
    rig.destroy_node()
    rclpy.shutdown()
    print(f"\nmessages published but never delivered to the node: {lost}")
    report(
        args,
        models,
        n,
        ts_ns,
        wall,
        stats,
        stats_at,
        latencies,
        missing_reports,
        traced,
        (trace_from, trace_mark, trace_to),
    )


def report(  # noqa: PLR0917 - the figures of one run
    args: argparse.Namespace,
    models: list[str],
    n: int,
    ts_ns: int,
    wall: float,
    stats: list[dict[str, Any]],
    stats_at: list[int],
    latencies: list[tuple[int, float]],
    missing_reports: int,
    traced: dict[str, Any],
    trace_span: tuple[int | None, int | None, int | None],
) -> None:
    sim_s = n * ts_ns / NS
    t_from, t_mark, t_to = trace_span

    def tracing(k: int) -> bool:
        return t_from is not None and t_to is not None and t_from <= k < t_to

    print(
        f"node at 10 Hz, models {'+'.join(models)}: {args.hours:g} simulated hours "
        f"({n} samples, {3 * n} messages + /clock) in {wall:.0f} s wall "
        f"({sim_s / wall:.0f}x real time)"
    )
    print(f"node's aligner: {stats[-1]['counters']}; samples aligned {stats[-1]['samples']}")
    lat = [x for _, x in latencies]
    clean = [x for k, x in latencies if not tracing(k)]  # tracemalloc slows Python down
    p99 = pct(clean, 99)
    print(
        f"report latency (last sample published -> reports of all models received), "
        f"{len(clean)} windows outside the tracemalloc hours ({missing_reports} windows of "
        f"the run without a report): median {statistics.median(clean) * 1e3:.1f} ms, p99 "
        f"{p99 * 1e3:.1f} ms, max {max(clean) * 1e3:.1f} ms; goal p99 <= "
        f"{LATENCY_GOAL_S * 1e3:.0f} ms: ratio {p99 / LATENCY_GOAL_S:.2f} "
        f"({'met' if p99 <= LATENCY_GOAL_S else 'NOT met'})"
    )
    if len(clean) < len(lat):
        print(
            f"  all {len(lat)} windows, tracemalloc hours included: median "
            f"{statistics.median(lat) * 1e3:.1f} ms, p99 {pct(lat, 99) * 1e3:.1f} ms, "
            f"max {max(lat) * 1e3:.1f} ms"
        )
    inside = [x for st in stats for x in st["node_latency_s"]]  # (all windows)
    if inside:
        print(
            f"  of which inside the node (message that completes the window received -> "
            f"reports published), {len(inside)} windows: median "
            f"{statistics.median(inside) * 1e3:.1f} ms, p99 {pct(inside, 99) * 1e3:.1f} ms, "
            f"max {max(inside) * 1e3:.1f} ms"
        )
    # CPU per simulated second, hour by hour, over the untraced hours
    per_hour, cpu_total, span_total = [], 0.0, 0.0
    for i in range(1, len(stats)):
        if tracing(stats_at[i - 1]):
            continue
        a, b = stats[i - 1], stats[i]
        cpu = (b["cpu_s"] - a["cpu_s"]) - (b["bench_thread_cpu_s"] - a["bench_thread_cpu_s"])
        span = (stats_at[i] - stats_at[i - 1]) * ts_ns / NS
        per_hour.append(cpu / span)
        cpu_total += cpu
        span_total += span
    frac = cpu_total / span_total
    print(
        f"CPU: {cpu_total:.1f} s over {span_total:.0f} simulated s = {frac:.2%} of one core "
        f"(per hour: median {statistics.median(per_hour):.2%}, max {max(per_hour):.2%}); "
        f"goal < {CPU_GOAL:.0%}: ratio {frac / CPU_GOAL:.2f} "
        f"({'met' if frac < CPU_GOAL else 'NOT met'})"
    )
    hours = np.array(stats_at) * ts_ns / NS / HOUR_S
    # flatness after warm-up: from the first hourly reading after hour 1 and after tracing
    i0 = next(
        (
            i
            for i, k in enumerate(stats_at)
            if k >= max(stats_at[min(1, len(stats_at) - 1)], t_to or 0)
        ),
        len(stats_at) - 1,
    )
    for key, unit, scale in (
        ("rss_kb", "MiB", 1 / 1024),
        ("blocks", "k blocks", 1e-3),
        ("objects", "k objects", 1e-3),
    ):
        vals = np.array([st[key] for st in stats], dtype=float) * scale
        line = ", ".join(f"{v:.1f}" for v in vals)
        if len(vals) - i0 >= 3:
            slope = float(np.polyfit(hours[i0:], vals[i0:], 1)[0])
            line += (
                f"  | hour {hours[i0]:.0f} -> {hours[-1]:.0f}: {vals[-1] - vals[i0]:+.2f} {unit} "
                f"({(vals[-1] - vals[i0]) / vals[i0]:+.2%}), fitted slope {slope:+.4f} {unit}/h"
            )
        print(f"{key} ({unit}) per simulated hour: {line}")
    if "top" in traced and t_mark is not None and t_to is not None:
        a, b = t_mark * ts_ns / NS / HOUR_S, t_to * ts_ns / NS / HOUR_S
        grew = traced["traced_bytes"] - traced["at_mark"]
        print(
            f"tracemalloc (on from hour 1): traced Python memory {traced['at_mark'] / 1024:.0f} "
            f"KiB at hour {a:.2f}, {traced['traced_bytes'] / 1024:.0f} KiB at hour {b:.2f}: "
            f"{grew / 1024:+.1f} KiB ({grew / 1024 / (b - a):+.1f} KiB/h); largest changes: "
            + "; ".join(traced["top"])
        )
    pauses = [d for st in stats for _, d in st["gc_pauses"]]
    full = [d for st in stats for g, d in st["gc_pauses"] if g == 2]
    print(
        f"garbage collector in the node: {sum(st['gc_count'] for st in stats)} collections, "
        f"{len(full)} full ones (longest {max(full, default=0) * 1e3:.1f} ms); pauses > 2 ms: "
        f"{len(pauses)}, longest {max(pauses, default=0) * 1e3:.1f} ms"
    )
    print(f"reports kept in the node's history: {stats[-1]['reports_kept']}")


if __name__ == "__main__":
    main()
