"""Simulated two-tank plant node: valve commands in, level and temperature measurements out.

Runs :class:`twotank_validation.sim.simulator.TankSimulator`. Every sample (``ts_s``) it
publishes the measurement taken now on ``height`` (sensor_msgs/FluidPressure, Pa) and
``temperature`` (sensor_msgs/Temperature, degC) stamped with the node's clock, then applies the
latest ``flow_cmd`` for one sample. Faults and unmodeled effects are set at run time through the
string-array parameter ``faults`` (``KIND[:CHANNEL][=MAGNITUDE]@ONSET_S[-END_S]``, see
:mod:`twotank_validation.sim.faults`); setting it replaces the fault set, onsets in simulated
seconds since the plant started. With ``publish_clock`` the node owns the simulated clock and
publishes ``/clock``, ``real_time_factor`` times faster than wall time.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock_type import ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, Temperature

from twotank_validation.defaults import NS_PER_S, TS_S
from twotank_validation.errors import TwotankError
from twotank_validation.online import streams as itf
from twotank_validation.ros import messages
from twotank_validation.ros.params import UNIT_PARAMS, Param, ParameterError, declare, run_node
from twotank_validation.sim import faults, rig, simulator
from twotank_validation.sim.faults import parse_fault

PLANT_PARAMS = (
    Param("ts_s", TS_S, "sample period (s)", 1e-3, 60.0),
    Param("substeps", 0, "RK4 steps per sample (0: automatic, steps of at most 25 ms)", 0, 100000),
    Param("seed", 0, "sensor-noise seed", 0, 2**31 - 1),
    Param("height", 0.47, "operating level (model units)", 0.15, 0.75),
    Param("temperature", 0.5, "operating temperature (model units)", 0.0, 1.0),
    Param("noise_std_height", 0.003, "level sensor noise std (model units)", 0.0, 1.0),
    Param("noise_std_temperature", 0.01, "temperature sensor noise std (model units)", 0.0, 1.0),
    Param(
        "mixing_delay_s",
        15.0,
        "measured-temperature mixing delay at the operating level (s)",
        0.0,
        600.0,
    ),
    Param("faults", [""], "faults, KIND[:CHANNEL][=MAGNITUDE]@ONSET_S[-END_S] each; '' for none"),
    Param(
        "self_timed", True, "publish every ts_s on a timer (false: an external driver calls tick())"
    ),
    Param("publish_clock", False, "own the simulated clock and publish /clock"),
    Param(
        "real_time_factor",
        1.0,
        "simulated seconds per wall second when publishing /clock",
        1e-3,
        1e6,
    ),
    *UNIT_PARAMS,
)


def parse_faults(specs: Sequence[str]) -> list[faults.Fault]:
    """Faults from the parameter's strings (empty strings ignored)."""
    return [parse_fault(s) for s in specs if s.strip()]


class PlantNode(Node):
    """The simulated rig on ROS topics."""

    def __init__(self, *, name: str = "twotank_plant", **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        v = declare(self, PLANT_PARAMS)
        try:
            params = rig.RigParams(
                mixing_delay_s=float(v["mixing_delay_s"]),
                noise_std_height=float(v["noise_std_height"]),
                noise_std_temperature=float(v["noise_std_temperature"]),
            )
            op = rig.operating_point(params, float(v["height"]), float(v["temperature"]))
            self.sim = simulator.TankSimulator(
                params,
                float(v["ts_s"]),
                op=op,
                seed=int(v["seed"]),
                substeps=int(v["substeps"]) or max(4, math.ceil(float(v["ts_s"]) / 0.025 - 1e-9)),
                faults=parse_faults(v["faults"]),
            )
            self.units = itf.RigUnits(
                float(v["pascal_per_unit"]),
                float(v["temperature_offset_c"]),
                float(v["temperature_span_c"]),
            )
        except (TwotankError, ValueError) as err:
            raise ParameterError(f"cannot start the plant: {err}") from err
        self.ts_ns = round(float(v["ts_s"]) * NS_PER_S)
        self.command = op.commands.copy()
        self.last_command_ns: int | None = None
        flow_cls, _ = messages.message_classes()
        self.create_subscription(flow_cls, itf.FLOW_CMD, self._on_flow, 100)
        self.pub_height = self.create_publisher(FluidPressure, itf.HEIGHT, 100)
        self.pub_temperature = self.create_publisher(Temperature, itf.TEMPERATURE, 100)
        self.add_on_set_parameters_callback(self._on_params)
        self._clock_pub = None
        if v["publish_clock"]:
            self._clock_pub = self.create_publisher(Clock, "/clock", 10)
            self._sim_ns = 0
            wall = self.ts_ns / NS_PER_S / float(v["real_time_factor"])
            self.create_timer(
                wall, self._on_clock_tick, clock=rclpy.clock.Clock(clock_type=ClockType.STEADY_TIME)
            )
        elif v["self_timed"]:
            self.create_timer(float(v["ts_s"]), self.tick)

    def _on_flow(self, msg: Any) -> None:
        hot, cold = float(msg.hot), float(msg.cold)
        if np.isfinite(hot) and np.isfinite(cold):
            self.command = np.array([hot, cold])
        self.last_command_ns = itf.stamp_ns(msg)

    def _on_params(self, params: list[Parameter[Any]]) -> SetParametersResult:
        for p in params:
            if p.name == "faults":
                try:
                    faults = parse_faults(p.value)
                except TwotankError as err:
                    return SetParametersResult(successful=False, reason=str(err))
                self.sim.clear_faults()
                for f in faults:
                    self.sim.add_fault(f)
        return SetParametersResult(successful=True)

    def _on_clock_tick(self) -> None:
        assert self._clock_pub is not None
        msg = Clock()
        itf.set_stamp(msg.clock, self._sim_ns)
        self._clock_pub.publish(msg)
        self.tick(self._sim_ns)
        self._sim_ns += self.ts_ns

    def tick(self, stamp_ns: int | None = None) -> None:
        """Publish the measurement now, then advance one sample with the latest command."""
        now = int(self.get_clock().now().nanoseconds) if stamp_ns is None else stamp_ns
        h, t = self.sim.measure()
        hm = FluidPressure()
        itf.set_stamp(hm.header.stamp, now)
        hm.header.frame_id = "tank1_base"
        hm.fluid_pressure = self.units.pressure_from_level(float(h))
        tm = Temperature()
        itf.set_stamp(tm.header.stamp, now)
        tm.header.frame_id = "tank1_base"
        tm.temperature = self.units.celsius_from_temperature(float(t))
        self.pub_height.publish(hm)
        self.pub_temperature.publish(tm)
        self.sim.step(self.command)


def main(args: list[str] | None = None) -> int:
    """``ros2 run twotank_validation twotank_plant`` entry point."""
    return run_node(PlantNode, args)


if __name__ == "__main__":
    sys.exit(main())
