"""The managed nodes' lifecycle (issue 31, item 1), in-process with a real executor.

The validator is driven through its lifecycle services (``~/change_state``, what ``ros2
lifecycle set`` calls) and fed the nominal rig over DDS (loopback), a sample at a time on the
simulated clock. References: the ROS graph itself (who subscribes and publishes, the node's
own entity lists against a freshly constructed node's), the alarm rule (a judged valid window
is WARN exactly when its beta reaches ``warn_beta``: the report's own beta decides), and
rclpy's parameter services (what ``ros2 param set`` gets back).
"""

from __future__ import annotations

import re
import threading
import time
from functools import cache
from pathlib import Path

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, Temperature
from std_msgs.msg import String

from twotank_validation.bags import open_bag
from twotank_validation.bags.evidence import evidence_bags
from twotank_validation.online import Alarm
from twotank_validation.online import streams as itf
from twotank_validation.ros import messages
from twotank_validation.ros.controller_node import ControllerNode
from twotank_validation.ros.lifecycle import autostart_of, bring_up
from twotank_validation.ros.live import spin_until
from twotank_validation.ros.params import LATCHED, ParameterError
from twotank_validation.ros.plant_node import PlantNode
from twotank_validation.ros.supervisor_node import SupervisorNode
from twotank_validation.ros.validator_node import ValidatorNode

# a window of one period every quarter period, judged from the first period on
FAST = {"ts_s": 0.8, "period_samples": 256, "periods_per_window": 1, "settle_periods": 0}


@cache
def rig_record(n_periods: int):
    from tools.streamfuzz import clean_record  # noqa: PLC0415 (the nominal rig's data)

    return clean_record(n_periods)


def entities(node: Node) -> tuple[int, int, int, int]:
    """(publishers, subscriptions, timers, services) the node holds."""
    return (
        len(list(node.publishers)),
        len(list(node.subscriptions)),
        len(list(node.timers)),
        len(list(node.services)),
    )


class Rig:
    """A validator (unconfigured), and a source node: /clock, the three inputs, listeners."""

    def __init__(self, tmp_path, **params) -> None:
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        overrides = [Parameter("use_sim_time", value=True)] + [
            Parameter(k, value=v)
            for k, v in {
                **FAST,
                "models": ["B"],
                "diagnosis": False,
                "evidence_dir": str(tmp_path / "evidence"),
                **params,
            }.items()
        ]
        self.val = ValidatorNode(context=self.ctx, parameter_overrides=overrides)
        self.fresh = entities(self.val)
        self.src = Node("test_source", context=self.ctx)
        self.flow_cls, report_cls = messages.message_classes()
        self.pub_clock = self.src.create_publisher(Clock, "/clock", 10)
        self.pub_flow = self.src.create_publisher(self.flow_cls, "flow_cmd", 1000)
        self.pub_h = self.src.create_publisher(FluidPressure, "height", 1000)
        self.pub_t = self.src.create_publisher(Temperature, "temperature", 1000)
        self.reports: list = []  # as received over DDS
        self.src.create_subscription(report_cls, "validation/B/report", self.reports.append, 100)
        self.diag: list[DiagnosticStatus] = []
        self.src.create_subscription(
            DiagnosticArray, "/diagnostics", lambda a: self.diag.extend(a.status), 100
        )
        self.change = self.src.create_client(ChangeState, "twotank_validator/change_state")
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.val)
        self.ex.add_node(self.src)
        self.units = itf.RigUnits()
        self.k = 0
        assert self.spin_until(self.change.service_is_ready)

    def spin_until(self, cond, timeout_s: float = 10.0) -> bool:
        return spin_until(self.ex, cond, timeout_s)

    def transition(self, transition_id: int) -> bool:
        """Ask for a transition through ~/change_state (as ``ros2 lifecycle set`` does)."""
        future = self.change.call_async(
            ChangeState.Request(transition=Transition(id=transition_id))
        )
        assert self.spin_until(future.done)
        return bool(future.result().success)

    def feed(self, n: int, *, expect_taken: bool = True) -> None:
        """The next ``n`` samples of the rig record, each once the clock reached it."""
        stamps, u, y = rig_record(8)
        for _ in range(n):
            k, self.k = self.k, self.k + 1
            t = int(stamps[k])
            clk = Clock()
            itf.set_stamp(clk.clock, t)
            self.pub_clock.publish(clk)
            self.spin_until(lambda t=t: self.val.get_clock().now().nanoseconds >= t, 2.0)
            f = self.flow_cls()
            itf.set_stamp(f.header.stamp, t)
            f.hot, f.cold = float(u[k, 0]), float(u[k, 1])
            h = FluidPressure()
            itf.set_stamp(h.header.stamp, t)
            h.fluid_pressure = self.units.pressure_from_level(float(y[k, 0]))
            tm = Temperature()
            itf.set_stamp(tm.header.stamp, t)
            tm.temperature = self.units.celsius_from_temperature(float(y[k, 1]))
            n0 = dict(self.val.received)
            self.pub_flow.publish(f)
            self.pub_h.publish(h)
            self.pub_t.publish(tm)
            if expect_taken:
                assert self.spin_until(
                    lambda n0=n0: all(self.val.received[s] > n0[s] for s in n0), 2.0
                )
        if expect_taken:
            assert self.val.wait_idle()
        self.spin_until(lambda: False, 0.05)  # let the last reports arrive

    def set(self, **values):
        """``ros2 param set`` through the node's parameter service."""
        client = self.src.create_client(SetParameters, "twotank_validator/set_parameters")
        assert self.spin_until(client.service_is_ready)
        req = SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        )
        future = client.call_async(req)
        assert self.spin_until(future.done)
        self.src.destroy_client(client)
        return future.result().results[0]

    def close(self) -> None:
        self.val.destroy_node()
        self.src.destroy_node()
        rclpy.shutdown(context=self.ctx)


def inactive(statuses: list[DiagnosticStatus]) -> bool:
    """The last status says inactive: level WARN (not STALE, not ERROR), lifecycle_state."""
    if not statuses:
        return False
    st = statuses[-1]
    values = {kv.key: kv.value for kv in st.values}
    return (
        st.level == DiagnosticStatus.WARN
        and st.message.startswith("inactive")
        and values.get("lifecycle_state") == "inactive"
    )


def test_validator_transitions_parameters_and_release(tmp_path) -> None:
    rig = Rig(tmp_path)
    try:
        val = rig.val
        # unconfigured: nothing subscribes to the inputs, nothing publishes reports
        assert val.lifecycle_state == "unconfigured"
        assert rig.pub_flow.get_subscription_count() == 0
        assert rig.src.count_publishers("validation/B/report") == 0
        assert rig.transition(Transition.TRANSITION_CONFIGURE)
        assert val.lifecycle_state == "inactive"
        # inactive: the core is built, the inputs are not taken, /diagnostics says inactive
        assert rig.spin_until(lambda: inactive(rig.diag))
        assert rig.pub_flow.get_subscription_count() == 0
        rig.feed(300, expect_taken=False)
        assert not rig.reports
        assert not val.reports
        rig.k = 0  # the same data again once active

        assert rig.transition(Transition.TRANSITION_ACTIVATE)
        assert rig.spin_until(lambda: rig.pub_flow.get_subscription_count() == 1)
        rig.feed(256 + 2 * 64)  # the first window at a period, then a hop each
        judged = [r for r in rig.reports if r.judged]
        assert len(judged) >= 2
        assert all(r.alarm in (Alarm.OK, Alarm.WARN) for r in val.reports)

        # a run-time change: the windows judged from now on are WARN exactly when beta
        # reaches the new warn_beta (the nominal rig's beta is well above 1e-3)
        assert not any(r.alarm is Alarm.WARN for r in val.reports)  # default 0.8: all OK
        assert rig.set(warn_beta=1e-3).successful
        assert val.config.alarm.warn_beta == 1e-3
        n = len(val.reports)
        rig.feed(64)
        after = list(val.reports)[n:]
        assert after
        assert all(r.judged for r in after)
        for r in after:
            assert (r.alarm is Alarm.WARN) == (r.beta >= 1e-3 and not r.invalidated)
        assert any(r.alarm is Alarm.WARN for r in after)

        # refused: a choice outside the tree's, a value outside the range, a read-only one
        bad = rig.set(debounce="eventually")
        assert not bad.successful
        assert "debounce" in bad.reason
        assert "sequential" in bad.reason
        assert rig.set(alarm_windows=0).successful is False
        ro = rig.set(period_samples=128)
        assert not ro.successful
        assert "read-only" in ro.reason
        assert val.get_parameter("period_samples").value == 256
        assert val.config.alarm.debounce == "sequential"
        assert val.config.alarm.alarm_windows == 2

        # deactivate: judging stops, /diagnostics says inactive, the inputs are not taken
        worker = val._worker
        assert rig.transition(Transition.TRANSITION_DEACTIVATE)
        assert not worker.is_alive()
        rig.diag.clear()
        assert rig.spin_until(lambda: inactive(rig.diag))
        assert rig.pub_flow.get_subscription_count() == 0
        n_reports, received = len(rig.reports), dict(val.received)
        rig.feed(128, expect_taken=False)
        assert len(rig.reports) == n_reports
        assert val.received == received

        # reactivate: judging resumes (alignment restarts: a window once a period is in)
        assert rig.transition(Transition.TRANSITION_ACTIVATE)
        assert rig.spin_until(lambda: rig.pub_flow.get_subscription_count() == 1)
        rig.feed(256 + 64)
        assert len(rig.reports) > n_reports
        assert [r for r in list(val.reports)[-2:] if r.judged]

        # cleanup: the node holds what a fresh one holds; the worker and the evidence
        # recorder's writer are stopped
        recorder = val.evidence
        assert recorder is not None
        assert rig.transition(Transition.TRANSITION_DEACTIVATE)
        assert rig.transition(Transition.TRANSITION_CLEANUP)
        assert val.lifecycle_state == "unconfigured"
        assert entities(val) == rig.fresh
        assert val.evidence is None
        assert not recorder._thread.is_alive()
        assert not [t for t in threading.enumerate() if t.name == "twotank_validator_worker"]
        assert rig.src.count_publishers("validation/B/report") == 0
        # and it configures again
        assert rig.transition(Transition.TRANSITION_CONFIGURE)
        assert rig.transition(Transition.TRANSITION_INACTIVE_SHUTDOWN)
        assert val.lifecycle_state == "finalized"
        assert entities(val) == rig.fresh
    finally:
        rig.close()


def test_a_bad_parameter_fails_configure_and_the_node_stays_unconfigured() -> None:
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        # out of range (kept aside at construction), and inconsistent (refused by the tree)
        for params, name in (
            ({"warn_beta": -1.0}, "warn_beta"),
            ({"period_samples": 256, "hop_samples": 100}, "hop_samples"),
        ):
            node = ValidatorNode(
                context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]
            )
            fresh = entities(node)
            assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
            assert node.lifecycle_state == "unconfigured"
            assert name in node.configure_error
            assert entities(node) == fresh  # nothing left behind
            node.destroy_node()
        # a run-time parameter set right fixes it: configure then succeeds
        sup = SupervisorNode(
            context=ctx, parameter_overrides=[Parameter("clear_after_s", value=-1.0)]
        )
        assert sup.lifecycle_state == "unconfigured"
        sup.trigger_configure()
        assert sup.lifecycle_state == "unconfigured"
        assert "clear_after_s" in sup.configure_error
        assert sup.set_parameters([Parameter("clear_after_s", value=5.0)])[0].successful
        sup.trigger_configure()
        assert sup.lifecycle_state == "inactive"
        assert sup.machine.config.clear_after_s == 5.0
        # run time: taken by the state machine, refused when the tree refuses it
        assert sup.set_parameters([Parameter("clear_reports", value=4)])[0].successful
        assert sup.machine.config.clear_reports == 4
        res = sup.set_parameters([Parameter("check_period_s", value=0.5)])[0]
        assert not res.successful
        assert "read-only" in res.reason
        sup.destroy_node()
        # bring_up reports the reason as the old constructors did
        with pytest.raises(ParameterError, match="stale_after_s"):
            bring_up(
                SupervisorNode(
                    context=ctx, parameter_overrides=[Parameter("stale_after_s", value=0.0)]
                )
            )
    finally:
        rclpy.shutdown(context=ctx)


def test_plant_and_controller_stop_publishing_when_inactive_and_release_on_cleanup() -> None:
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        plant = PlantNode(context=ctx, parameter_overrides=[Parameter("self_timed", value=False)])
        ctl = ControllerNode(
            context=ctx, parameter_overrides=[Parameter("self_timed", value=False)]
        )
        fresh = {n.get_name(): entities(n) for n in (plant, ctl)}
        src = Node("listener", context=ctx)
        heights: list = []
        flows: list = []
        diag: list[DiagnosticStatus] = []
        flow_cls, _ = messages.message_classes()
        src.create_subscription(FluidPressure, "height", heights.append, 100)
        src.create_subscription(flow_cls, "flow_cmd", flows.append, 100)
        src.create_subscription(
            DiagnosticArray, "/diagnostics", lambda a: diag.extend(a.status), 100
        )
        mode = src.create_publisher(String, "control/mode", LATCHED)
        ex = SingleThreadedExecutor(context=ctx)
        for n in (plant, ctl, src):
            ex.add_node(n)

        def spin_until(cond, timeout_s: float = 5.0) -> bool:
            deadline = time.monotonic() + timeout_s
            while not cond():
                if time.monotonic() > deadline:
                    return False
                ex.spin_once(timeout_sec=0.005)
            return True

        for n in (plant, ctl):
            bring_up(n)
        assert spin_until(lambda: mode.get_subscription_count() == 1)
        plant.tick(0)
        ctl.tick(0)
        assert spin_until(lambda: len(heights) == 1 and len(flows) == 1)
        for n in (plant, ctl):
            n.trigger_deactivate()
            assert n.lifecycle_state == "inactive"
        names = {"twotank_validation: plant", "twotank_validation: controller"}
        assert spin_until(lambda: names <= {s.name for s in diag if inactive([s])})
        assert mode.get_subscription_count() == 0  # the controller no longer listens
        plant.tick(800_000_000)
        ctl.tick(800_000_000)
        spin_until(lambda: False, 0.2)
        assert len(heights) == 1
        assert len(flows) == 1
        for n in (plant, ctl):
            n.trigger_cleanup()
            assert n.lifecycle_state == "unconfigured"
            assert entities(n) == fresh[n.get_name()]
        for n in (plant, ctl, src):
            n.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def test_an_inactive_validator_is_stale_to_the_supervisor(tmp_path) -> None:
    """Deactivated, the validator sends no report: the supervisor's stale rule switches to
    safe once the newest report stamp is ``stale_after_s`` old, as for a dead validator."""
    rig = Rig(tmp_path)
    try:
        sup = bring_up(
            SupervisorNode(
                context=rig.ctx,
                parameter_overrides=[
                    Parameter("use_sim_time", value=True),
                    Parameter("models", value=["B"]),
                    Parameter("stale_after_s", value=180.0),  # a report every 51.2 s
                    Parameter("check_period_s", value=1.0),
                ],
            )
        )
        rig.ex.add_node(sup)
        bring_up(rig.val)
        assert rig.spin_until(lambda: rig.pub_flow.get_subscription_count() == 1)
        rig.feed(256 + 64)
        assert rig.spin_until(lambda: sup.received.get("validation/B/report", 0) >= 2)
        assert sup.machine.mode.value == "normal"
        last = max(sup.machine.state.last_report_s.values())
        rig.val.trigger_deactivate()
        t = int(rig_record(8)[0][rig.k - 1])
        for _ in range(50):  # 250 s of simulated time, a check every 5 s
            t += 5_000_000_000
            clk = Clock()
            itf.set_stamp(clk.clock, t)
            rig.pub_clock.publish(clk)
            rig.spin_until(lambda t=t: sup.get_clock().now().nanoseconds >= t, 2.0)
            rig.spin_until(lambda: False, 0.01)
        assert sup.machine.mode.value == "safe"
        (tr,) = sup.machine.log
        assert "stale" in tr.reason or "no report" in tr.reason
        assert 180.0 <= tr.time_s - last <= 186.0  # when the rule says (a check every 5 s)
        sup.destroy_node()
    finally:
        rig.close()


def test_the_executables_autostart_unless_told_not_to() -> None:
    assert autostart_of(["--ros-args", "-p", "latch:=true"]) == (
        True,
        ["--ros-args", "-p", "latch:=true"],
    )
    assert autostart_of(["--autostart", "false", "--ros-args"]) == (False, ["--ros-args"])
    with pytest.raises(SystemExit, match="true or false"):
        autostart_of(["--autostart", "maybe"])


def test_the_run_time_parameters_are_parameters_and_documented() -> None:
    """Each managed node's RUNTIME names parameters of its table, and docs/ros.md's table of
    run-time parameters lists exactly them."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "ros.md").read_text()
    section = text.split("**Run-time parameters.**", 1)[1].split("\n\n**", 1)[0]
    rows = {
        m.group(1): set(re.findall(r"`(\w+)`", m.group(2)))
        for m in re.finditer(r"^\| `(twotank_\w+)` \| ([^|]*) \|", section, re.M)
    }
    nodes = (ValidatorNode, SupervisorNode, PlantNode, ControllerNode)
    assert set(rows) == {f"twotank_{n.ROLE}" for n in nodes}
    for cls in nodes:
        assert {p.name for p in cls.PARAMS} >= cls.RUNTIME, cls.ROLE
        assert rows[f"twotank_{cls.ROLE}"] == set(cls.RUNTIME), cls.ROLE


def test_cleanup_during_an_alarm_closes_the_evidence_bag_with_every_sample_fed(tmp_path) -> None:
    """Model A is invalidated by the nominal rig: its alarm rises and the evidence recorder
    writes a bag. Cleaned up while that bag is being written, the node closes it: the bag
    reads back and holds every sample fed up to the cleanup (the reference: the stamps fed)."""
    rig = Rig(tmp_path, models=["A"])
    try:
        bring_up(rig.val)
        assert rig.spin_until(lambda: rig.pub_flow.get_subscription_count() == 1)
        rig.feed(256 + 3 * 64)
        assert any(r.alarm is Alarm.ERROR for r in rig.val.reports)
        assert rig.val.evidence is not None
        assert rig.val.evidence.status().state == "writing"  # the episode is still open
        rig.val.trigger_deactivate()
        rig.val.trigger_cleanup()
        (bag,) = evidence_bags(tmp_path / "evidence")
        with open_bag(bag) as reader:
            stamps = {m.log_time_ns for m in reader.messages(["flow_cmd", "height", "temperature"])}
        fed = rig_record(8)[0][: rig.k]
        assert max(stamps) == int(fed[-1])  # the last sample fed is in the bag
        assert stamps == {int(t) for t in fed if t >= min(stamps)}  # and none missing
    finally:
        rig.close()
