"""A supervisor node with a test node playing the validator's topics and /clock.

Used by the supervisor's node tests (``test/online/test_supervisor.py``) and, with a fake
controller manager beside it, by the controller switch's (``test/ros/test_controller_switch.py``).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger

from twotank_validation.online import streams as itf
from twotank_validation.ros import messages
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.live import spin_until
from twotank_validation.ros.params import LATCHED
from twotank_validation.ros.supervisor_node import SupervisorNode


class Harness:
    """A supervisor node and a test node playing the validator's topics and /clock."""

    DEFAULTS: ClassVar[dict[str, Any]] = {
        "models": ["B"],
        "clear_after_s": 10.0,
        "clear_reports": 2,
        "stale_after_s": 30.0,
        "startup_grace_s": 120.0,  # the first report comes at 100 s
        "check_period_s": 1.0,
    }

    def __init__(self, **params) -> None:
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        values = {**self.DEFAULTS, **params}
        overrides = [Parameter("use_sim_time", value=True)] + [
            Parameter(k, value=v) for k, v in values.items()
        ]
        self.src = Node("test_validator", context=self.ctx)
        extra = self.add_nodes()
        self.sup = bring_up(SupervisorNode(context=self.ctx, parameter_overrides=overrides))
        _, self.report_cls = messages.message_classes()
        self.pub_clock = self.src.create_publisher(Clock, "/clock", 10)
        self.pub_flag = self.src.create_publisher(Bool, "validation/B/invalidated", LATCHED)
        self.pub_report = self.src.create_publisher(self.report_cls, "validation/B/report", 10)
        self.pub_diagnosis = self.src.create_publisher(
            messages.diagnosis_class(), "validation/B/diagnosis", 10
        )
        self.modes: list[str] = []
        self.states: list[DiagnosticStatus] = []
        # transient-local like the publishers, deep enough to keep every message
        keep_all = QoSProfile(
            depth=1000,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        self.src.create_subscription(String, "control/mode", self._on_mode, keep_all)
        self.src.create_subscription(
            DiagnosticStatus, "supervisor/state", self.states.append, keep_all
        )
        self.reset_client = self.src.create_client(Trigger, "supervisor/reset")
        self.ex = SingleThreadedExecutor(context=self.ctx)
        for n in (*extra, self.sup, self.src):
            self.ex.add_node(n)
        assert self.spin_until(
            lambda: (
                self.pub_report.get_subscription_count() >= 1
                and self.pub_flag.get_subscription_count() >= 1
                and self.pub_diagnosis.get_subscription_count() >= 1
                and self.modes == ["normal"]
                and len(self.states) >= 1  # the initial state, latched (a loaded machine
                # may match the subscription after the first spin)
                and self.ready()
            )
        )
        self.t = 0.0

    def add_nodes(self) -> list[Node]:
        """Nodes to spin beside the supervisor and the test node (made before the supervisor)."""
        return []

    def ready(self) -> bool:
        """What else must hold before a test starts."""
        return True

    def _on_mode(self, msg: String) -> None:
        self.modes.append(msg.data)

    def spin_until(self, cond, timeout_s: float = 10.0) -> bool:
        return spin_until(self.ex, cond, timeout_s)

    def clock_to(self, t_s: float) -> None:
        """Advance /clock one check period (1 s) at a time; each tick processed."""
        while self.t < t_s:
            self.t = min(t_s, math.floor(self.t) + 1.0)
            msg = Clock()
            itf.set_stamp(msg.clock, round(self.t * 1e9))
            self.pub_clock.publish(msg)
            assert self.spin_until(lambda: self.sup.get_clock().now().nanoseconds / 1e9 >= self.t)
            if self.t == math.floor(self.t):  # a timer period: wait for the tick
                assert self.spin_until(
                    lambda: (self.sup.machine.state.now_s or 0.0) >= self.t, 2.0
                ), self.t

    def _received(self, topic: str) -> int:
        return self.sup.received.get(topic, 0)

    def report(self, stamp_s: float, judged: bool = True) -> None:
        msg = self.report_cls()
        itf.set_stamp(msg.header.stamp, round(stamp_s * 1e9))
        msg.model = "B"
        msg.judged = judged
        n = self._received("validation/B/report")
        self.pub_report.publish(msg)
        assert self.spin_until(lambda: self._received("validation/B/report") > n)

    def flag(self, value: bool) -> None:
        n = self._received("validation/B/invalidated")
        self.pub_flag.publish(Bool(data=value))
        assert self.spin_until(lambda: self._received("validation/B/invalidated") > n)

    def window(self, t_s: float, invalidated: bool) -> None:
        """One window of the validator at t_s: its report (stamped 0.5 s before), its flag."""
        self.clock_to(t_s)
        self.report(t_s - 0.5)
        self.flag(invalidated)

    def call_reset(self) -> Trigger.Response:
        assert self.reset_client.wait_for_service(timeout_sec=5.0)
        future = self.reset_client.call_async(Trigger.Request())
        assert self.spin_until(future.done)
        return future.result()

    def state_values(self) -> dict[str, str]:
        """The values of the last supervisor/state, once the last published one has arrived.

        (The topic is reliable with a history of one, as a latched state is: a state published
        right after another may replace it before it is delivered, so the test waits for the
        last one, not for a count.)
        """
        assert self.spin_until(self._last_state_arrived)
        return {kv.key: kv.value for kv in self.states[-1].values}

    def _last_state_arrived(self) -> bool:
        return bool(self.states) and self.states[-1] == self.sup.last_state

    def sync(self) -> None:
        """Wait until every mode and state the node published has reached the test."""
        assert self.spin_until(
            lambda: len(self.modes) >= self.sup.modes_published and self._last_state_arrived()
        )

    def close(self) -> None:
        self.sup.destroy_node()
        self.src.destroy_node()
        rclpy.shutdown(context=self.ctx)
