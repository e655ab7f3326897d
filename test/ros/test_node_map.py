"""The validator node reading a rig's own topics through an interface map (parameters).

In-process, with a real executor and simulated time: valves on two headerless
``std_msgs/msg/Float64`` topics (stamped with the receive time), the level in a
``sensor_msgs/msg/JointState`` (in Pa), the temperature as ``data[1]`` of a
``std_msgs/msg/Float64MultiArray`` (in °C). The reports must equal those of the core fed the
same samples in model units, bit for bit.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from tools import streamfuzz
from twotank_validation.core.model import load_model
from twotank_validation.online import MonitorConfig, OnlineValidator
from twotank_validation.online import streams as itf
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.params import ParameterError
from twotank_validation.ros.validator_node import ValidatorNode

FAST = {"ts_s": 0.8, "period_samples": 256, "hop_samples": 256}  # a window per period
INPUTS = [
    "hot=/valves/hot:std_msgs/msg/Float64:data,stamp=receive",
    "cold=/valves/cold:std_msgs/msg/Float64:data,stamp=receive",
]
OUTPUTS = [
    "height=/tank/joints:sensor_msgs/msg/JointState:position[0],scale=9806.65",
    "temperature=/tank/state:std_msgs/msg/Float64MultiArray:data[1],offset=15,scale=50,"
    "stamp=receive",
]
UNITS = itf.RigUnits()


class MapHarness:
    def __init__(self, outputs=OUTPUTS, **params) -> None:
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        overrides = [Parameter("use_sim_time", value=True)] + [
            Parameter(k, value=v)
            for k, v in {
                **FAST,
                "models": ["B"],
                "stale_timeout_s": 5.0,
                "inputs": INPUTS,
                "outputs": list(outputs),
                **params,
            }.items()
        ]
        self.val = bring_up(ValidatorNode(context=self.ctx, parameter_overrides=overrides))
        self.reports: list = []
        self.val.report_listeners.append(self.reports.append)
        self.src = Node("test_rig", context=self.ctx)
        self.pub_clock = self.src.create_publisher(Clock, "/clock", 10)
        self.pub_hot = self.src.create_publisher(Float64, "/valves/hot", 1000)
        self.pub_cold = self.src.create_publisher(Float64, "/valves/cold", 1000)
        self.pub_joint = self.src.create_publisher(JointState, "/tank/joints", 1000)
        self.pub_state = self.src.create_publisher(Float64MultiArray, "/tank/state", 1000)
        self.diag: list[DiagnosticArray] = []
        self.src.create_subscription(DiagnosticArray, "/diagnostics", self.diag.append, 100)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.val)
        self.ex.add_node(self.src)
        pubs = (self.pub_hot, self.pub_cold, self.pub_joint, self.pub_state)
        assert self.spin_until(lambda: all(p.get_subscription_count() >= 1 for p in pubs))

    def spin_until(self, cond, timeout_s: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while not cond():
            if time.monotonic() > deadline:
                return False
            self.ex.spin_once(timeout_sec=0.005)
        return True

    def send(self, t_ns: int, u, y, *, temperature: bool = True) -> None:
        clock = Clock()
        itf.set_stamp(clock.clock, t_ns)
        self.pub_clock.publish(clock)
        assert self.spin_until(lambda: self.val.get_clock().now().nanoseconds >= t_ns, 2.0)
        joint = JointState()
        itf.set_stamp(joint.header.stamp, t_ns)
        joint.name = ["level"]
        joint.position = [UNITS.pressure_from_level(float(y[0]))]
        state = Float64MultiArray()
        state.data = [-1.0, UNITS.celsius_from_temperature(float(y[1]))]
        n0 = dict(self.val.received)
        self.pub_hot.publish(Float64(data=float(u[0])))
        self.pub_cold.publish(Float64(data=float(u[1])))
        self.pub_joint.publish(joint)
        if temperature:
            self.pub_state.publish(state)
        else:
            n0.pop("/tank/state")  # the temperature's topic
        assert self.spin_until(lambda: all(self.val.received[k] > n0[k] for k in n0), 2.0)

    def close(self) -> None:
        self.val.destroy_node()
        self.src.destroy_node()
        rclpy.shutdown(context=self.ctx)


def test_the_node_reads_a_rigs_own_topics_through_the_map() -> None:
    stamps, u, y = streamfuzz.clean_record(4, 0)  # ts 0.8 s, period 256: 3 windows
    h = MapHarness()
    try:
        for k in range(len(stamps)):
            h.send(int(stamps[k]), u[k], y[k])
        assert h.val.wait_idle()
        h.spin_until(lambda: False, 0.05)
    finally:
        h.close()
    # the reference: the core fed the same samples in model units
    core = OnlineValidator(MonitorConfig(**FAST), [load_model("B")])
    want = []
    for k in range(len(stamps)):
        want += core.feed(itf.FLOW_CMD, int(stamps[k]), (float(u[k, 0]), float(u[k, 1])))
        want += core.feed(itf.HEIGHT, int(stamps[k]), float(y[k, 0]))
        want += core.feed(itf.TEMPERATURE, int(stamps[k]), float(y[k, 1]))
    assert [r.judged for r in want] == [False, True, True]  # windows end at periods 2, 3, 4
    got = h.reports  # an instant's command goes out as soon as both valves' values are in
    assert len(got) == len(want)
    assert sum(r.judged for r in got) >= 1
    for g, w in zip(got, want, strict=True):
        assert (g.start_ns, g.end_ns, g.judged, g.alarm) == (
            w.start_ns,
            w.end_ns,
            w.judged,
            w.alarm,
        )
        assert g.beta == w.beta or (math.isnan(g.beta) and math.isnan(w.beta))


def test_a_temperature_at_half_rate_is_judged_at_the_rate_it_supports() -> None:
    """Valves and level every 0.8 s, temperature every 1.6 s: ts_s 1.6 with oversampling."""
    stamps, u, y = streamfuzz.clean_record(4, 0)
    slow = {"ts_s": 1.6, "period_samples": 128, "hop_samples": 128}
    h = MapHarness(**slow, oversampling=["/valves/hot=2", "/valves/cold=2", "/tank/joints=2"])
    try:
        for k in range(len(stamps)):
            h.send(int(stamps[k]), u[k], y[k], temperature=k % 2 == 0)
        assert h.val.wait_idle()
        h.spin_until(lambda: False, 0.05)
    finally:
        h.close()
    # the reference: the core fed the samples at the supported rate (every other sample of
    # every signal; test_half_rate holds that path to make_datum + validate)
    core = OnlineValidator(MonitorConfig(**slow), [load_model("B")])
    want = []
    for k in range(0, len(stamps), 2):
        want += core.feed(itf.FLOW_CMD, int(stamps[k]), (float(u[k, 0]), float(u[k, 1])))
        want += core.feed(itf.HEIGHT, int(stamps[k]), float(y[k, 0]))
        want += core.feed(itf.TEMPERATURE, int(stamps[k]), float(y[k, 1]))
    assert [r.judged for r in want] == [False, True, True]
    got = h.reports
    assert [(g.start_ns, g.end_ns, g.judged) for g in got] == [
        (w.start_ns, w.end_ns, w.judged) for w in want
    ]
    # (to the ulp: the level and temperature go through Pa and degC and back)
    assert [g.beta for g in got if g.judged] == pytest.approx(
        [w.beta for w in want if w.judged], rel=1e-12
    )


def test_a_topic_that_does_not_fit_the_map_is_refused_with_the_reason() -> None:
    outputs = [OUTPUTS[0].replace("position[0]", "effort[0]"), OUTPUTS[1]]
    stamps, u, y = streamfuzz.clean_record(2, 0)
    h = MapHarness(outputs=outputs)
    try:
        for k in range(8):
            h.send(int(stamps[k]), u[k], y[k])

        def refused() -> bool:
            return any(
                "/tank/joints" in s.message and "effort" in s.message
                for a in h.diag
                for s in a.status
            )

        assert h.spin_until(refused, 5.0)
    finally:
        h.close()


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"inputs": INPUTS, "outputs": [""]}, "inputs and outputs go together"),
        (
            {
                "inputs": [
                    INPUTS[0].replace("std_msgs/msg/Float64", "rig_msgs/msg/Valve"),
                    INPUTS[1].replace("std_msgs/msg/Float64", "rig_msgs/msg/Valve"),
                ]
            },
            "cannot import the message type rig_msgs/msg/Valve",
        ),
        ({"inputs": ["hot=/valves/hot"]}, "cannot start the validator"),
        ({"inputs": INPUTS[:1]}, "names input 'cold', which the interface map given as text"),
        ({"oversampling": ["temp=2"]}, r"oversampling names \['temp'\], which the interface map"),
    ],
)
def test_bad_map_parameters_stop_the_node_with_a_clear_message(params, match) -> None:
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        overrides = [
            Parameter(k, value=v)
            for k, v in {
                **FAST,
                "models": ["B"],
                "inputs": INPUTS,
                "outputs": OUTPUTS,
                **params,
            }.items()
        ]
        with pytest.raises(ParameterError, match=match):
            bring_up(ValidatorNode(context=ctx, parameter_overrides=overrides))
    finally:
        rclpy.shutdown(context=ctx)


def test_clean_record_is_on_the_grid() -> None:
    stamps, u, _ = streamfuzz.clean_record(2, 0)
    assert np.all(np.diff(stamps) == 800_000_000)
    assert u.shape[1] == 2
