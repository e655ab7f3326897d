"""Hostile message streams through a live :class:`ValidatorNode`, and the invariants it keeps.

The node-level counterpart of :mod:`tools.streamfuzz`: the same hostile
stretches (its generator and its clean rig record), but sent over real topics to a
``ValidatorNode`` running with ``use_sim_time`` in its own rclpy context, plus what only a node
sees: ``/clock`` jumping backwards (a simulation restart) or forwards, and messages of the wrong
type on an input topic from another participant. A driver node publishes ``/clock`` and the
three inputs in lockstep (at every step: the clock, the node has the step's messages, its
worker is idle, a separate collector node has every report published so far); the collector
records what the node publishes (reports, margins, the invalidated alarm, ``/diagnostics``),
tagged with the step it arrived in.

A run: clean nominal rig data for 3 to 4 periods, a hostile stretch of 1/8 to 2 periods, clean
data again up to 10 periods; then the inputs stop and the clock runs on. Invariants
(:func:`check`), against the stamps and steps of what the driver actually corrupted:

* the node survives: no exception out of a callback, its worker thread alive at the end;
* no report published once the garbage started judges a window that overlaps the hostile
  stretch (its stamps on the clean timeline, and where the clock was shifted, the shifted
  ones); every judged beta and margin is finite, and every margin message is finite or NaN;
* from a few steps after the first garbage until the first judged window after it, every
  ``/diagnostics`` status is STALE or ERROR (never OK or WARN), and a wrong-type publisher is
  named in a status;
* after the stretch: Model B's windows are judged again, the last one OK, ``invalidated``
  False and the last status OK (the clean data are the nominal rig, which B explains);
* every ``/diagnostics`` message speaks of one window for all models;
* when the inputs stop, the status goes STALE naming a stopped stream (the watchdog lives).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, Temperature
from std_msgs.msg import Bool, Float64, String

from tools import streamfuzz
from twotank_validation.core.model import LFTModel, load_model
from twotank_validation.defaults import NS_PER_S
from twotank_validation.online import Alarm
from twotank_validation.online import streams as itf
from twotank_validation.ros import messages
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.live import spin_until
from twotank_validation.ros.validator_node import ValidatorNode

CONFIG = streamfuzz.CONFIG
TS_NS = round(CONFIG.ts_s * NS_PER_S)
PERIOD = CONFIG.period_samples
N_PERIODS = 10

DATA_KINDS = tuple(k for k in streamfuzz.HOSTILE_KINDS if k != "malformed")
"""streamfuzz's kinds a message can carry (a malformed value cannot be put in a message)."""
NODE_KINDS = (*DATA_KINDS, "wrong_type", "clock_back", "clock_skip")
"""Plus: an input stream sent with the wrong message type by another participant;
``/clock`` and the stamps jumping back (a simulation restart) or forward for the stretch."""

MAX_STAMP_NS = 2**31 * NS_PER_S  # builtin_interfaces/Time.sec is an int32
STATUS_MARGIN_STEPS = 4  # detection latency allowed: a gap shows 2 samples on, a stop 2 s on
STOP_STEPS = 6  # steps of clock without inputs at the end (> stale_timeout_s = 2 s)
_LEAN: dict[str, Any] = {"start_parameter_services": False, "enable_rosout": False}
_WRONG_TYPES: dict[str, tuple[type, ...]] = {
    "flow_cmd": (Float64, String, FluidPressure),
    "height": (Float64, String, Temperature),
    "temperature": (Float64, String, FluidPressure),
}


@dataclass
class Step:
    """What the driver sends at one step.

    Attributes:
        clean_ns: stamp of the step's sample in the clean record.
        clock_ns: ``/clock``.
        events: ``(stream, stamp_ns, value)`` on the input topics, in order (model units).
        rogue: streams on which a wrong-type message is published instead.
        garbage: the step differs from the clean one (exact duplicates aside).
    """

    clean_ns: int
    clock_ns: int
    events: list[tuple[str, int, Any]]
    rogue: list[str] = field(default_factory=list)
    garbage: bool = False


@dataclass
class Plan:
    """A run's steps and its hostile stretch.

    Attributes:
        steps: one per sample of the clean record.
        kinds: hostile kinds used.
        span_steps: (first, last) step of the drawn hostile stretch.
        shift_ns: ``/clock`` and stamp shift of the stretch (clock kinds), else 0.
        rogue_type: message type the rogue publisher uses ("" if none).
    """

    steps: list[Step]
    kinds: list[str]
    span_steps: tuple[int, int]
    shift_ns: int = 0
    rogue_type: str = ""

    def garbage_steps(self) -> list[int]:
        """Steps that differ from the clean data."""
        return [i for i, s in enumerate(self.steps) if s.garbage]


def _step_events(t: int, u: np.ndarray, y: np.ndarray) -> list[tuple[str, int, Any]]:
    return [
        ("flow_cmd", t, (float(u[0]), float(u[1]))),
        ("height", t, float(y[0])),
        ("temperature", t, float(y[1])),
    ]


def _same(a: list[tuple[str, int, Any]], b: list[tuple[str, int, Any]]) -> bool:
    """Equal event lists, exact repeats aside (NaN never equals anything: garbage)."""
    return sorted(set(map(repr, a))) == sorted(set(map(repr, b))) and not any(
        "nan" in repr(e) or "inf" in repr(e) for e in a
    )


def plan(seed: int, kinds: list[str] | None = None) -> Plan:
    """The steps of run ``seed`` (kinds drawn from :data:`NODE_KINDS` unless given)."""
    rng = np.random.default_rng(seed)
    stamps, u, y = streamfuzz.clean_record(N_PERIODS, seed % 4)
    if kinds is None:
        kinds = [
            str(k) for k in rng.choice(NODE_KINDS, size=int(rng.integers(1, 5)), replace=False)
        ]
    if "clock_back" in kinds and "clock_skip" in kinds:
        kinds.remove(str(rng.choice(["clock_back", "clock_skip"])))
    first = 3 * PERIOD + int(rng.integers(0, PERIOD))
    last = min(first + int(rng.integers(PERIOD // 8, 2 * PERIOD)), 6 * PERIOD)
    lo, hi = int(stamps[first]), int(stamps[last])
    data_kinds = [k for k in kinds if k in DATA_KINDS]
    shift = 0
    if "clock_back" in kinds:  # back by up to 400 s: a restarted simulation
        shift = -int(rng.integers(1, 500)) * TS_NS
    elif "clock_skip" in kinds:  # forward by up to 2 h (past the aligner's 1 h jump limit)
        shift = int(rng.integers(1, 9000)) * TS_NS
    rogue_stream = str(rng.choice(list(_WRONG_TYPES))) if "wrong_type" in kinds else ""
    rogue_cls = _WRONG_TYPES[rogue_stream][int(rng.integers(3))] if rogue_stream else None
    steps = []
    for k in range(stamps.size):
        t = int(stamps[k])
        clean = _step_events(t, u[k], y[k])
        if not first <= k <= last:
            steps.append(Step(t, t, clean))
            continue
        events = clean
        if data_kinds:
            events, _ = streamfuzz.hostile_events(rng, clean, (lo, hi), kinds=data_kinds)
        events = [(s, (st + shift) % MAX_STAMP_NS, v) for s, st, v in events]
        rogue = [rogue_stream] if rogue_stream else []
        events = [e for e in events if e[0] not in rogue]
        garbage = shift != 0 or bool(rogue) or not _same(events, clean)
        steps.append(Step(t, t + shift, events, rogue, garbage))
    rogue_type = ""
    if rogue_cls is not None:
        rogue_type = f"{rogue_cls.__module__.split('.')[0]}/msg/{rogue_cls.__name__}"
    return Plan(steps, kinds, (first, last), shift, rogue_type)


# ------------------------------------------------------------------ the ROS side


@dataclass
class Outputs:
    """What the collector received, each tagged with the driver's step at arrival.

    Attributes:
        reports: ``(step, ValidationReport)``.
        margins: ``(step, model, value)``.
        invalidated: ``(step, model, value)``.
        statuses: ``(step, model name, level, message)`` of every DiagnosticStatus.
        diag_windows: ``(step, window ends)``: per DiagnosticArray, the ``window_end_s`` of
            its statuses (those that carry one).
    """

    reports: list[tuple[int, Any]] = field(default_factory=list)
    margins: list[tuple[int, str, float]] = field(default_factory=list)
    invalidated: list[tuple[int, str, bool]] = field(default_factory=list)
    statuses: list[tuple[int, str, int, str]] = field(default_factory=list)
    diag_windows: list[tuple[int, tuple[str, ...]]] = field(default_factory=list)


@dataclass
class RunResult:
    """One run: its plan, what the node published, and broken invariants."""

    seed: int
    plan: Plan
    outputs: Outputs
    violations: list[str] = field(default_factory=list)
    undelivered: int = 0
    wall_s: float = 0.0
    worker_alive: bool = True


class _Collector:
    """A separate node that records everything the validator publishes."""

    def __init__(self, ctx: Context, models: list[str], report_cls: Any) -> None:
        self.node = Node("nodefuzz_collector", context=ctx, **_LEAN)
        self.out = Outputs()
        self.step = -1
        self.diag_count = 0  # /diagnostics messages received
        latched = QoSProfile(
            depth=1,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        for m in models:
            self.node.create_subscription(
                report_cls, f"validation/{m}/report", self._on_report, 1000
            )
            self.node.create_subscription(
                Float64, f"validation/{m}/margin", self._margin_cb(m), 1000
            )
            self.node.create_subscription(
                Bool, f"validation/{m}/invalidated", self._invalid_cb(m), latched
            )
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 1000)

    def _on_report(self, msg: Any) -> None:
        self.out.reports.append((self.step, msg))

    def _margin_cb(self, model: str) -> Callable[[Float64], None]:
        return lambda msg: self.out.margins.append((self.step, model, msg.data))

    def _invalid_cb(self, model: str) -> Callable[[Bool], None]:
        return lambda msg: self.out.invalidated.append((self.step, model, msg.data))

    def _on_diag(self, msg: DiagnosticArray) -> None:
        self.diag_count += 1
        ends = tuple(kv.value for st in msg.status for kv in st.values if kv.key == "window_end_s")
        self.out.diag_windows.append((self.step, ends))
        for st in msg.status:
            model = st.name.rsplit(" ", 1)[-1]
            self.out.statuses.append((self.step, model, st.level[0], st.message))


def _spin_until(ex: SingleThreadedExecutor, cond: Callable[[], bool], timeout_s: float) -> bool:
    return spin_until(ex, cond, timeout_s, poll_s=0.002)


_MODELS: list[LFTModel] = []


def _models() -> list[LFTModel]:
    if not _MODELS:
        _MODELS.extend([load_model("A"), load_model("B")])
    return _MODELS


def _ns_ns(t: Any) -> int:
    return int(t.sec) * NS_PER_S + int(t.nanosec)


class _Driver:
    """Validator, driver and collector nodes in one context; a rogue in another."""

    def __init__(self, extra_params: dict[str, Any] | None = None) -> None:
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        params = {
            "use_sim_time": True,
            "ts_s": CONFIG.ts_s,
            "period_samples": CONFIG.period_samples,
            **(extra_params or {}),
        }
        self.val = bring_up(
            ValidatorNode(
                models=_models(),
                context=self.ctx,
                parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
            )
        )
        self.published = 0
        self._count_lock = threading.Lock()
        self.val.report_listeners.append(self._count)
        # count the node's /diagnostics messages too (the worker and the watchdog publish)
        self.diag_published = 0
        publish = self.val._pub_status.publish

        def counted(msg: DiagnosticArray) -> None:
            with self._count_lock:
                self.diag_published += 1
            publish(msg)

        self.val._pub_status.publish = counted
        self.flow_cls, report_cls = messages.message_classes()
        self.src = Node("nodefuzz_driver", context=self.ctx, **_LEAN)
        self.pub_clock = self.src.create_publisher(Clock, "/clock", 10)
        self.pubs = {
            "flow_cmd": self.src.create_publisher(self.flow_cls, "flow_cmd", 1000),
            "height": self.src.create_publisher(FluidPressure, "height", 1000),
            "temperature": self.src.create_publisher(Temperature, "temperature", 1000),
        }
        self.col = _Collector(self.ctx, [m.name for m in self.val.models], report_cls)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        for n in (self.val, self.src, self.col.node):
            self.ex.add_node(n)
        self.units = itf.RigUnits()
        self.rogue_ctx: Context | None = None
        self.rogue_node: Node | None = None
        self.rogue_pub: Any = None
        ok = _spin_until(
            self.ex,
            lambda: (
                all(p.get_subscription_count() >= 1 for p in self.pubs.values())
                and self.col.node.count_publishers("/diagnostics") >= 1
                and all(
                    self.col.node.count_publishers(f"validation/{m.name}/report") >= 1
                    for m in self.val.models
                )
            ),
            10.0,
        )
        if not ok:
            raise RuntimeError("discovery between the driver, collector and validator failed")

    def _count(self, _rep: Any) -> None:
        with self._count_lock:
            self.published += 1

    def message(self, stream: str, stamp: int, value: Any) -> Any:
        if stream == "flow_cmd":
            msg = self.flow_cls()
            msg.hot, msg.cold = float(value[0]), float(value[1])
        elif stream == "height":
            msg = FluidPressure()
            msg.fluid_pressure = float(self.units.pressure_from_level(value))
        else:
            msg = Temperature()
            msg.temperature = float(self.units.celsius_from_temperature(value))
        itf.set_stamp(msg.header.stamp, stamp)
        return msg

    # -- the rogue participant (DDS refuses two types on one topic in one participant)

    def rogue_start(self, stream: str, type_name: str) -> bool:
        cls = {"Float64": Float64, "String": String}.get(type_name.rsplit("/", 1)[-1])
        cls = (
            cls
            or {"FluidPressure": FluidPressure, "Temperature": Temperature}[
                type_name.rsplit("/", 1)[-1]
            ]
        )
        self.rogue_ctx = Context()
        rclpy.init(context=self.rogue_ctx)
        self.rogue_node = Node("nodefuzz_rogue", context=self.rogue_ctx, **_LEAN)
        self.rogue_pub = self.rogue_node.create_publisher(cls, stream, 10)
        topic = self.val.resolve_topic_name(stream)
        return _spin_until(
            self.ex,
            lambda: any(
                i.topic_type == type_name for i in self.val.get_publishers_info_by_topic(topic)
            ),
            10.0,
        )

    def rogue_send(self) -> None:
        msg = self.rogue_pub.msg_type()
        if isinstance(msg, Float64):
            msg.data = 1.0
        elif isinstance(msg, String):
            msg.data = "height 0.47 m"
        self.rogue_pub.publish(msg)

    def rogue_stop(self, stream: str) -> bool:
        if self.rogue_node is None or self.rogue_ctx is None:
            return True
        self.rogue_node.destroy_node()
        rclpy.shutdown(context=self.rogue_ctx)
        self.rogue_node = self.rogue_ctx = self.rogue_pub = None
        topic = self.val.resolve_topic_name(stream)
        return _spin_until(self.ex, lambda: self.val.count_publishers(topic) <= 1, 10.0)

    def close(self) -> None:
        if self.rogue_ctx is not None and self.rogue_node is not None:
            self.rogue_node.destroy_node()
            rclpy.shutdown(context=self.rogue_ctx)
        for n in (self.val, self.src, self.col.node):
            n.destroy_node()
        rclpy.shutdown(context=self.ctx)


def run(
    seed: int,
    kinds: list[str] | None = None,
    the_plan: Plan | None = None,
    *,
    checked: bool = True,
) -> RunResult:
    """Drive one run (``the_plan``, or planned from the seed) through a fresh validator node.

    The invariants are checked (:func:`check`) unless ``checked`` is false (a truncated plan).
    """
    p = the_plan or plan(seed, kinds)
    start = time.perf_counter()
    drv = _Driver()
    res = RunResult(seed, p, drv.col.out)
    rogue_stream = next((s.rogue[0] for s in p.steps if s.rogue), "")
    rogue_first = next((i for i, s in enumerate(p.steps) if s.rogue), -1)
    rogue_last = max((i for i, s in enumerate(p.steps) if s.rogue), default=-1)
    garbage = p.garbage_steps()
    g0 = garbage[0] if garbage else len(p.steps)
    try:
        for i, step in enumerate(p.steps):
            drv.col.step = i
            if i == rogue_first and not drv.rogue_start(rogue_stream, p.rogue_type):
                res.violations.append("setup: the validator never saw the rogue publisher")
            # strict lockstep from just before the garbage until a window is judged after it
            # (the checks compare steps there) and at the end; a lighter one elsewhere
            strict = g0 - 3 <= i and (
                i >= len(p.steps) - 3
                or not any(m.judged and s > g0 + 2 for s, m in drv.col.out.reports[-4:])
            )
            _drive(drv, res, step, strict=strict)
            if i == rogue_last and not drv.rogue_stop(rogue_stream):
                res.violations.append("setup: the rogue publisher never left the graph")
            if res.violations and res.violations[-1].startswith("crash"):
                return res
        # the inputs stop; the clock runs on
        t_end = p.steps[-1].clock_ns
        for j in range(1, STOP_STEPS + 1):
            drv.col.step = len(p.steps) + j - 1
            _drive(drv, res, Step(-1, t_end + j * TS_NS, []), strict=True, watchdog=True)
            if res.violations and res.violations[-1].startswith("crash"):
                return res
        worker = drv.val._worker
        res.worker_alive = worker is not None and worker.is_alive()
    finally:
        drv.close()
        res.wall_s = time.perf_counter() - start
    if checked:
        check(res)
    return res


def _drive(
    drv: _Driver, res: RunResult, step: Step, *, strict: bool = True, watchdog: bool = False
) -> None:
    """One step: the clock, then the inputs, delivered.

    ``strict``: the clock is delivered before the inputs are sent, and the worker is idle and
    the collector has every report before the step ends. ``watchdog``: also wait for a
    ``/diagnostics`` message at this step.
    """
    val, ex = drv.val, drv.ex
    n_diag = drv.diag_published
    try:
        clk = Clock()
        itf.set_stamp(clk.clock, step.clock_ns)
        drv.pub_clock.publish(clk)
        if strict:
            _spin_until(ex, lambda: val.get_clock().now().nanoseconds == step.clock_ns, 2.0)
        want = dict(val.received)
        for stream, stamp, value in step.events:
            drv.pubs[stream].publish(drv.message(stream, stamp, value))
            want[stream] += 1
        for _ in step.rogue:
            drv.rogue_send()
        if not _spin_until(
            ex,
            lambda: (
                all(val.received[k] >= want[k] for k in want)
                and val.get_clock().now().nanoseconds == step.clock_ns
            ),
            2.0,
        ):
            res.undelivered += sum(want[k] - val.received[k] for k in want)
        if watchdog:  # the watchdog (every 0.5 s of ROS time) has published at this step
            _spin_until(ex, lambda: drv.diag_published > n_diag, 0.5)
        if strict:
            if not val.wait_idle(10.0):
                res.violations.append("crash: the worker did not finish its queue in 10 s")
            col = drv.col
            _spin_until(
                ex,
                lambda: (
                    len(col.out.reports) >= drv.published and col.diag_count >= drv.diag_published
                ),
                2.0,
            )
    except Exception as err:  # a callback raised: in a real process the node would be dead
        res.violations.append(f"crash: {type(err).__name__}: {err}")


def check(res: RunResult) -> None:
    """Append every broken invariant to ``res.violations``."""
    p, out, v = res.plan, res.outputs, res.violations
    n = len(p.steps)
    if not res.worker_alive:
        v.append("the validator's worker thread died")
    garbage = p.garbage_steps()
    for _, msg in out.reports:
        if msg.judged and not (math.isfinite(msg.beta) and math.isfinite(msg.margin)):
            v.append(f"{msg.model}: judged window with beta {msg.beta}, margin {msg.margin}")
    for step, model, m in out.margins:
        if math.isinf(m):
            v.append(f"{model}: margin {m} published at step {step}")
    if garbage:
        g0, g1 = garbage[0], garbage[-1]
        # the stretch on the clean timeline (clean stamps = step * Ts), and as sent if shifted
        clean_lo, clean_hi = p.steps[g0].clean_ns, p.steps[g1].clean_ns
        # and where the clock was shifted, the stretch as sent: windows of it can only be
        # completed while it arrives (clean data after it jump back to the clean timeline,
        # and may then reuse those stamps, legitimately)
        spans = [(clean_lo, clean_hi, n)]
        if p.shift_ns:
            spans.append((clean_lo + p.shift_ns, clean_hi + p.shift_ns, g1 + 2))
        for step, msg in out.reports:
            if step < g0 or not msg.judged:
                continue
            a, b = _ns_ns(msg.window_start), _ns_ns(msg.window_end)
            for lo, hi, until_step in spans:
                if step <= until_step and a <= hi and b >= lo:
                    v.append(
                        f"{msg.model}: window {a / 1e9:.1f}..{b / 1e9:.1f} s overlaps the hostile "
                        f"stretch {lo / 1e9:.1f}..{hi / 1e9:.1f} s and was judged at step {step} "
                        f"(beta {msg.beta:.3g})"
                    )
        judged_after = [s for s, msg in out.reports if msg.judged and s >= g0]
        until = judged_after[0] if judged_after else n
        for step, model, level, text in out.statuses:
            if g0 + STATUS_MARGIN_STEPS <= step < until and level in (Alarm.OK, Alarm.WARN):
                v.append(
                    f"status of {model} {Alarm(level).name} at step {step} during garbage "
                    f"(steps {g0}..{g1}, first judged window after it at step {until}): {text}"
                )
                break
        if p.rogue_type and not any(
            f"type {p.rogue_type}" in text for step, _, _, text in out.statuses if step >= g0
        ):
            v.append(f"no status named the wrong-type publisher ({p.rogue_type})")
        after = [msg for s, msg in out.reports if msg.model == "B" and s > g1]
        after = [m for m in after if _ns_ns(m.window_start) > clean_hi]
        if not any(m.judged for m in after):
            v.append(f"no judged window of B after the hostile stretch ({p.kinds})")
        elif after[-1].alarm_level != Alarm.OK:
            v.append(f"B's alarm did not recover: {Alarm(after[-1].alarm_level).name}")
    for step, ends in out.diag_windows:
        if len(set(ends)) > 1:
            v.append(f"a /diagnostics message mixes windows ending at {ends} s (step {step})")
            break
    inval_b = [x for _, m, x in out.invalidated if m == "B"]
    if not inval_b or inval_b[-1]:
        v.append(f"B's invalidated topic did not end False ({inval_b[-3:]})")
    last_b = [(s, lv, t) for s, m, lv, t in out.statuses if m == "B" and s < n]
    if not last_b or last_b[-1][1] != Alarm.OK:
        v.append(f"B's last status before the inputs stopped is not OK: {last_b[-1:]}")
    stopped = [t for s, m, lv, t in out.statuses if s >= n and lv == Alarm.STALE and "stopped" in t]
    if not stopped:
        v.append("no STALE 'stopped' status once the inputs stopped (watchdog dead?)")
