"""Deadline and liveliness on the verdict topics, seen from DDS (issue 31, item 4).

The references are DDS's own: the QoS the graph reports for the validator's publishers, and
the events a real rclpy subscriber gets (deadline missed, liveliness changed, incompatible QoS)
with a real executor. A short hop (ts_s 0.01 s, a 16-sample period: hop 0.04 s) makes the
offered deadline 0.12 s, so the events come within a second.
"""

from __future__ import annotations

import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool, Float64

from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.params import VERDICT_DEADLINE_HOPS, VERDICT_LEASE_S
from twotank_validation.ros.validator_node import ValidatorNode

TS_S, PERIOD = 0.01, 16
HOP_S = PERIOD // 4 * TS_S
OFFERED_S = VERDICT_DEADLINE_HOPS * HOP_S


@pytest.fixture
def graph():
    ctx = Context()
    rclpy.init(context=ctx)
    overrides = [
        Parameter("ts_s", value=TS_S),
        Parameter("period_samples", value=PERIOD),
        Parameter("models", value=["B"]),
        Parameter("diagnosis", value=False),
    ]
    val = bring_up(ValidatorNode(context=ctx, parameter_overrides=overrides))
    sub = Node("verdict_consumer", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(val)
    ex.add_node(sub)
    try:
        yield ctx, val, sub, ex
    finally:
        ex.shutdown()
        sub.destroy_node()
        if val.handle is not None:
            val.destroy_node()
        rclpy.shutdown(context=ctx)


def _spin_until(ex, done, timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and not done():
        ex.spin_once(timeout_sec=0.05)
    return done()


def test_publishers_offer_deadline_and_liveliness(graph) -> None:
    _ctx, val, sub, ex = graph
    for topic, durability in (
        ("/validation/B/report", DurabilityPolicy.VOLATILE),
        ("/validation/B/margin", DurabilityPolicy.VOLATILE),
        ("/validation/B/invalidated", DurabilityPolicy.TRANSIENT_LOCAL),
    ):
        assert _spin_until(ex, lambda t=topic: sub.get_publishers_info_by_topic(t))
        (info,) = sub.get_publishers_info_by_topic(topic)
        qos = info.qos_profile
        assert qos.deadline == Duration(nanoseconds=round(OFFERED_S * 1e9)), topic
        assert qos.liveliness == LivelinessPolicy.AUTOMATIC, topic
        assert qos.liveliness_lease_duration == Duration(seconds=VERDICT_LEASE_S), topic
        assert qos.reliability == ReliabilityPolicy.RELIABLE, topic
        assert qos.durability == durability, topic
    del val


def test_subscriber_hears_a_stopped_and_a_dead_validator(graph) -> None:
    """The alarm topic's state arrives; no new verdict follows (no data): deadline missed;
    the validator goes away: liveliness lost. A stricter deadline than offered is refused."""
    _ctx, val, sub, ex = graph
    missed, alive, incompatible, got = [], [], [], []
    events = SubscriptionEventCallbacks(
        deadline=missed.append,
        liveliness=alive.append,
        incompatible_qos=incompatible.append,
    )
    requested = QoSProfile(
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
        deadline=Duration(seconds=2 * OFFERED_S),
        liveliness=LivelinessPolicy.AUTOMATIC,
        liveliness_lease_duration=Duration(seconds=2 * VERDICT_LEASE_S),
    )
    sub.create_subscription(
        Bool, "validation/B/invalidated", got.append, requested, event_callbacks=events
    )
    strict = QoSProfile(depth=1, deadline=Duration(seconds=OFFERED_S / 2))
    refused: list = []
    sub.create_subscription(
        Float64,
        "validation/B/margin",
        lambda _m: None,
        strict,
        event_callbacks=SubscriptionEventCallbacks(incompatible_qos=refused.append),
    )
    assert _spin_until(ex, lambda: got and alive and alive[-1].alive_count == 1)
    assert got[0].data is False
    assert _spin_until(ex, lambda: missed)
    assert missed[-1].total_count >= 1
    assert _spin_until(ex, lambda: refused)
    ex.remove_node(val)
    val.destroy_node()
    assert _spin_until(ex, lambda: alive[-1].alive_count == 0)
    assert not incompatible
