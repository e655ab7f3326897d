"""Shared by the validator-node tests: a node in its own rclpy context, fed a rig record.

The samples go through the node's subscription callbacks as the executor calls them (no DDS
traffic, no spinning): a flow command, a height as fluid pressure and a temperature in
Celsius per sample, in the rig's message units (``streams.RigUnits``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from sensor_msgs.msg import FluidPressure, Temperature

from twotank_validation.online import streams as itf
from twotank_validation.ros import messages
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.validator_node import ValidatorNode


@contextmanager
def validator_node(params: Mapping[str, object], **kwargs: object) -> Iterator[ValidatorNode]:
    """A ValidatorNode on simulated time with ``params`` as parameter overrides; the node and
    its context are torn down on leaving."""
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = bring_up(
            ValidatorNode(
                context=ctx,
                parameter_overrides=[
                    Parameter("use_sim_time", value=True),
                    *[Parameter(k, value=v) for k, v in params.items()],
                ],
                **kwargs,
            )
        )
        try:
            yield node
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def feed_rig_record(
    node: ValidatorNode,
    stamps: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    *,
    after_each: Callable[[int], None] | None = None,
    wait_each: bool = True,
) -> None:
    """Feed samples k = 0..N-1 (stamps (N,) ns; u (N, 2) hot, cold flows; y (N, 2) level,
    temperature in model units) and wait for the node's worker after each; ``after_each(k)``
    runs once sample k has been handled. ``wait_each=False`` hands the node every sample at
    once (a burst) and waits for its worker only at the end."""
    flow_cls, _ = messages.message_classes()
    units = itf.RigUnits()
    for k in range(len(stamps)):
        f, h, t = flow_cls(), FluidPressure(), Temperature()
        for msg in (f, h, t):
            itf.set_stamp(msg.header.stamp, int(stamps[k]))
        f.hot, f.cold = float(u[k, 0]), float(u[k, 1])
        h.fluid_pressure = units.pressure_from_level(float(y[k, 0]))
        t.temperature = units.celsius_from_temperature(float(y[k, 1]))
        node._on_message("flow_cmd", f)
        node._on_message("height", h)
        node._on_message("temperature", t)
        if wait_each:
            assert node.wait_idle()
        if after_each is not None:
            after_each(k)
    assert node.wait_idle()
