"""Excitation node: periodic valve commands (issue #2's generator) on ``flow_cmd``.

Publishes ``offset + excitation_period[k mod cycle]`` every ``ts_s`` (or when an external
driver calls :meth:`ExcitationNode.tick`), stamped with the node's clock.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from rclpy.node import Node

from twotank_validation.defaults import NS_PER_S, TS_S
from twotank_validation.errors import TwotankError
from twotank_validation.online import streams as itf
from twotank_validation.ros import messages
from twotank_validation.ros.params import (
    Param,
    ParameterError,
    declare,
    design_of,
    design_params,
    run_node,
)
from twotank_validation.sim import excitation, rig

EXCITATION_PARAMS = (
    Param("ts_s", TS_S, "sample period (s)", 1e-3, 60.0),
    *design_params(excitation.RIG_DESIGN),
    Param("rms_hot", 0.05, "hot valve RMS deviation (model units)", 0.0, 0.5),
    Param("rms_cold", 0.2, "cold valve RMS deviation (model units)", 0.0, 0.5),
    Param("height", 0.47, "operating level the offsets are computed for (model units)", 0.15, 0.75),
    Param("temperature", 0.5, "operating temperature (model units)", 0.0, 1.0),
    Param(
        "self_timed", True, "publish every ts_s on a timer (false: an external driver calls tick())"
    ),
)
"""The excitation node's parameters: the design's (:func:`design_params`), the amplitudes
and the operating point."""


class ExcitationNode(Node):
    """Periodic excitation of both valves around the operating point."""

    def __init__(self, *, name: str = "twotank_excitation", **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        v = declare(self, EXCITATION_PARAMS)
        try:
            design = design_of(v)
            cfg = excitation.ExcitationConfig(
                ts_s=float(v["ts_s"]),
                rms=(float(v["rms_hot"]), float(v["rms_cold"])),
                settle_periods=0,
                record_periods=design.cycle_periods,
                design=design,
            )
            op = rig.operating_point(rig.RigParams(), float(v["height"]), float(v["temperature"]))
            self.table = excitation.excitation_commands(
                cfg, op.commands
            )  # (cycle, 2): one period per realisation, checked in [0, 1]
        except (TwotankError, ValueError) as err:
            raise ParameterError(f"cannot start the excitation: {err}") from err
        self.ts_ns = round(float(v["ts_s"]) * NS_PER_S)
        self.k = 0
        flow_cls, _ = messages.message_classes()
        self._cls = flow_cls
        self.pub = self.create_publisher(flow_cls, itf.FLOW_CMD, 100)
        if v["self_timed"]:
            self.create_timer(float(v["ts_s"]), self.tick)

    def command(self, k: int) -> np.ndarray:
        """(2,) the command of sample k."""
        return np.asarray(self.table[k % len(self.table)])

    def tick(self, stamp_ns: int | None = None) -> None:
        """Publish the next command."""
        now = int(self.get_clock().now().nanoseconds) if stamp_ns is None else stamp_ns
        hot, cold = self.command(self.k)
        msg = self._cls()
        itf.set_stamp(msg.header.stamp, now)
        msg.hot = float(hot)
        msg.cold = float(cold)
        self.pub.publish(msg)
        self.k += 1


def main(args: list[str] | None = None) -> int:
    """``ros2 run twotank_validation twotank_excitation`` entry point."""
    return run_node(ExcitationNode, args)


if __name__ == "__main__":
    sys.exit(main())
