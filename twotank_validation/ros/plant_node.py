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
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import rclpy
from rclpy.clock_type import ClockType
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, Temperature

from twotank_validation.defaults import NS_PER_S, TS_S
from twotank_validation.errors import TwotankError
from twotank_validation.online import streams as itf
from twotank_validation.ros import messages
from twotank_validation.ros.lifecycle import ManagedNode, run_managed
from twotank_validation.ros.params import UNIT_PARAMS, Param, ParameterError
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


PLANT_RUNTIME = frozenset({"faults"})
"""The plant's parameters that change at run time: ``faults`` (replaces the fault set);
every other one is read-only."""


class PlantNode(ManagedNode):
    """The simulated rig on ROS topics.

    A managed node (:mod:`twotank_validation.ros.lifecycle`): configure builds the simulator
    and the publishers; activate subscribes to ``flow_cmd`` and starts the sample (or
    ``/clock``) timer; inactive, the simulated time stands still.
    """

    PARAMS = PLANT_PARAMS
    RUNTIME = PLANT_RUNTIME
    ROLE = "plant"

    def __init__(self, *, name: str = "twotank_plant", **kwargs: Any) -> None:
        self.last_command_ns: int | None = None
        self._clock_pub: Any = None
        self._sim_ns = 0
        super().__init__(name, **kwargs)

    def configure_node(self, values: dict[str, Any]) -> None:
        """The simulator and the measurement (and ``/clock``) publishers."""
        v = values
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
        self.ts_s = float(v["ts_s"])
        self.ts_ns = round(self.ts_s * NS_PER_S)
        self.command = op.commands.copy()
        self.self_timed = bool(v["self_timed"])
        self.real_time_factor = float(v["real_time_factor"])
        pub = self.create_lifecycle_publisher
        self.pub_height = self.configured(pub(FluidPressure, itf.HEIGHT, 100))
        self.pub_temperature = self.configured(pub(Temperature, itf.TEMPERATURE, 100))
        self._clock_pub = None
        if v["publish_clock"]:
            self._clock_pub = self.configured(pub(Clock, "/clock", 10))

    def activate_node(self) -> None:
        """Subscribe to ``flow_cmd``; start the sample (or ``/clock``) timer."""
        flow_cls, _ = messages.message_classes()
        self.activated(self.create_subscription(flow_cls, itf.FLOW_CMD, self._on_flow, 100))
        if self._clock_pub is not None:
            wall = self.ts_s / self.real_time_factor
            self.activated(
                self.create_timer(
                    wall,
                    self._on_clock_tick,
                    clock=rclpy.clock.Clock(clock_type=ClockType.STEADY_TIME),
                )
            )
        elif self.self_timed:
            self.activated(self.create_timer(self.ts_s, self.tick))

    def check_runtime(self, values: dict[str, Any]) -> Callable[[], None] | None:
        """A new fault set (parsed now: a bad one is refused with the reason)."""
        try:
            new = parse_faults(values["faults"])
        except TwotankError as err:
            raise ParameterError(f"parameter 'faults': {err}") from err

        def apply() -> None:
            self.sim.clear_faults()
            for f in new:
                self.sim.add_fault(f)

        return apply if self.is_configured else None

    def _on_flow(self, msg: Any) -> None:
        hot, cold = float(msg.hot), float(msg.cold)
        if np.isfinite(hot) and np.isfinite(cold):
            self.command = np.array([hot, cold])
        self.last_command_ns = itf.stamp_ns(msg)

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
    return run_managed(PlantNode, args)


if __name__ == "__main__":
    sys.exit(main())
