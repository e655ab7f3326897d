"""Controller node: the rig's PI loops on ROS topics, the excitation added, safe mode on request.

Every ``ts_s`` (or when an external driver calls :meth:`ControllerNode.tick`) it publishes on
``flow_cmd`` the valve commands of :class:`twotank_validation.sim.control.PIController` for the
latest ``height`` and ``temperature`` measurements, with the periodic excitation (the
excitation node's generator, same parameters) added to its output or to its setpoints
(``excitation_entry``). It replaces the excitation node in the closed-loop rig: the validator
is fed the same ``flow_cmd`` as before.

``control/mode`` (std_msgs/String, transient-local, so a late-joining controller gets the
last mode) switches it:

* ``"safe"``: the valves are held at the mean command of the last excitation period (one
  period of commands averages the zero-mean excitation out: the last good operating point)
  and the PI state is frozen; with ``excitation_entry = "output"`` and ``excite_when_held``
  (the default) the excitation goes on around the held commands, so that the validator keeps
  judging the model (open loop, the paper's experiment) and the supervisor sees whether the
  fault lasts;
* ``"normal"``: the PI loops resume bumplessly (integrators re-initialised from the held
  output) and the excitation goes on at the phase time has reached.

Each switch is logged and counted (:attr:`ControllerNode.transitions`).
"""

from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np
from sensor_msgs.msg import FluidPressure, Temperature
from std_msgs.msg import String

from twotank_validation.defaults import NS_PER_S, TS_S
from twotank_validation.errors import TwotankError
from twotank_validation.online import streams as itf
from twotank_validation.ros import messages
from twotank_validation.ros.lifecycle import ManagedNode, run_managed
from twotank_validation.ros.params import (
    LATCHED,
    UNIT_PARAMS,
    Param,
    ParameterError,
    design_of,
    design_params,
)
from twotank_validation.sim import control, excitation, rig

MODE_TOPIC = "control/mode"
"""Topic of the requested mode (std_msgs/String, transient-local)."""

MODES = ("normal", "safe")
"""The modes ``control/mode`` may ask for."""

_CC = control.ControllerConfig()

CONTROLLER_PARAMS = (
    Param("ts_s", TS_S, "sample period (s)", 1e-3, 60.0),
    *design_params(excitation.RIG_DESIGN),
    Param("height_setpoint", _CC.height_setpoint, "level setpoint (model units)", 0.15, 0.75),
    Param(
        "temperature_setpoint",
        _CC.temperature_setpoint,
        "temperature setpoint (model units)",
        0.0,
        1.0,
    ),
    Param("kp_level", _CC.kp_level, "level loop gain (total flow per unit level)", 1e-6, 1e3),
    Param("ti_level_s", _CC.ti_level_s, "level loop integral time (s)", 1e-3, 1e6),
    Param(
        "tt_level_s",
        _CC.tt_level_s,
        "level loop anti-windup tracking time (s, >= ts_s; .inf: no anti-windup)",
        1e-3,
    ),
    Param(
        "kp_temperature",
        _CC.kp_temperature,
        "temperature loop gain (hot fraction per unit temperature)",
        1e-6,
        1e3,
    ),
    Param("ti_temperature_s", _CC.ti_temperature_s, "temperature integral time (s)", 1e-3, 1e6),
    Param(
        "tt_temperature_s",
        _CC.tt_temperature_s,
        "temperature anti-windup tracking time (s, >= ts_s; .inf: no anti-windup)",
        1e-3,
    ),
    Param("u_min", _CC.u_min, "lowest valve command (model units)", 0.0, 1.0),
    Param("u_max", _CC.u_max, "highest valve command (model units)", 0.0, 1.0),
    Param("filter_s", _CC.filter_s, "measurement low-pass time constant (s; 0: off)", 0.0, 1e4),
    Param(
        "excitation_entry",
        _CC.excitation_entry,
        "where the excitation enters: output (valve commands) or setpoint",
        choices=control.EXCITATION_ENTRIES,
    ),
    Param(
        "excite_when_held",
        _CC.excite_when_held,
        "safe mode: keep the output excitation on the held valves (the validator keeps judging)",
    ),
    Param("rms_hot", 0.05, "output entry: hot valve RMS deviation (model units)", 0.0, 0.5),
    Param("rms_cold", 0.2, "output entry: cold valve RMS deviation (model units)", 0.0, 0.5),
    Param(
        "setpoint_rms_height", 0.02, "setpoint entry: level setpoint RMS (model units)", 0.0, 0.5
    ),
    Param(
        "setpoint_rms_temperature",
        0.05,
        "setpoint entry: temperature setpoint RMS (model units)",
        0.0,
        0.5,
    ),
    Param(
        "self_timed", True, "publish every ts_s on a timer (false: an external driver calls tick())"
    ),
    *UNIT_PARAMS,
)


class ControllerNode(ManagedNode):
    """PI control of level and temperature through the two valves, excitation added.

    A managed node (:mod:`twotank_validation.ros.lifecycle`): configure builds the PI
    controller, the excitation table and the ``flow_cmd`` publisher; activate subscribes to
    the measurements and the mode and starts the sample timer; inactive, it publishes no
    command (the valves keep the last one). Every parameter is read-only.
    """

    PARAMS = CONTROLLER_PARAMS
    ROLE = "controller"

    def __init__(self, *, name: str = "twotank_controller", **kwargs: Any) -> None:
        self.mode = "normal"
        self.transitions = 0
        self.k = 0
        self.height: float | None = None
        self.temperature: float | None = None
        self.last_measurement_ns: dict[str, int] = {}
        self.last_command: np.ndarray | None = None
        super().__init__(name, **kwargs)

    def configure_node(self, values: dict[str, Any]) -> None:
        """The PI controller, the excitation table and the command publisher."""
        v = values
        ts_s, period = float(v["ts_s"]), int(v["period_samples"])
        entry = str(v["excitation_entry"])
        try:
            cfg = control.ControllerConfig(
                ts_s=ts_s,
                height_setpoint=float(v["height_setpoint"]),
                temperature_setpoint=float(v["temperature_setpoint"]),
                kp_level=float(v["kp_level"]),
                ti_level_s=float(v["ti_level_s"]),
                tt_level_s=float(v["tt_level_s"]),
                kp_temperature=float(v["kp_temperature"]),
                ti_temperature_s=float(v["ti_temperature_s"]),
                tt_temperature_s=float(v["tt_temperature_s"]),
                u_min=float(v["u_min"]),
                u_max=float(v["u_max"]),
                excitation_entry=entry,
                hold_samples=period,
                filter_s=float(v["filter_s"]),
                excite_when_held=bool(v["excite_when_held"]),
            )
            rms = (
                (float(v["rms_hot"]), float(v["rms_cold"]))
                if entry == "output"
                else (float(v["setpoint_rms_height"]), float(v["setpoint_rms_temperature"]))
            )
            design = design_of(v)
            exc_cfg = excitation.ExcitationConfig(
                ts_s=ts_s,
                rms=rms,
                settle_periods=0,
                record_periods=design.cycle_periods,
                design=design,
            )
            op = rig.operating_point(rig.RigParams(), cfg.height_setpoint, cfg.temperature_setpoint)
            if entry == "output":  # checks that the excitation fits the valves at the setpoint
                excitation.excitation_commands(exc_cfg, op.commands)
            self.table = excitation.excitation_period(exc_cfg)  # (cycle, 2) deviations
            self.controller = control.PIController(cfg, op.commands)
            self.units = itf.RigUnits(
                float(v["pascal_per_unit"]),
                float(v["temperature_offset_c"]),
                float(v["temperature_span_c"]),
            )
        except (TwotankError, ValueError) as err:
            raise ParameterError(f"cannot start the controller: {err}") from err
        self.ts_s = ts_s
        self.ts_ns = round(ts_s * NS_PER_S)
        self.self_timed = bool(v["self_timed"])
        flow_cls, _ = messages.message_classes()
        self._cls = flow_cls
        self.pub = self.configured(self.create_lifecycle_publisher(flow_cls, itf.FLOW_CMD, 100))

    def activate_node(self) -> None:
        """Subscribe to the measurements and the mode; start the sample timer."""
        self.activated(self.create_subscription(FluidPressure, itf.HEIGHT, self._on_height, 100))
        self.activated(
            self.create_subscription(Temperature, itf.TEMPERATURE, self._on_temperature, 100)
        )
        self.activated(self.create_subscription(String, MODE_TOPIC, self._on_mode, LATCHED))
        if self.self_timed:
            self.activated(self.create_timer(self.ts_s, self.tick))

    # --- inputs ---------------------------------------------------------------------------

    def _on_height(self, msg: FluidPressure) -> None:
        value = self.units.level_from_pressure(float(msg.fluid_pressure))
        if math.isfinite(value):
            self.height = value
            self.last_measurement_ns[itf.HEIGHT] = itf.stamp_ns(msg)

    def _on_temperature(self, msg: Temperature) -> None:
        value = self.units.temperature_from_celsius(float(msg.temperature))
        if math.isfinite(value):
            self.temperature = value
            self.last_measurement_ns[itf.TEMPERATURE] = itf.stamp_ns(msg)

    def _on_mode(self, msg: String) -> None:
        self.set_mode(msg.data)

    def set_mode(self, mode: str) -> bool:
        """Switch to ``mode`` (``"normal"`` or ``"safe"``); False for an unknown value.

        Asking for the mode already active changes nothing (and counts no transition).
        """
        mode = mode.strip().lower()
        if mode not in MODES:
            self.get_logger().warning(
                f"control/mode {mode!r} ignored: expected one of {list(MODES)}"
            )
            return False
        if mode == self.mode:
            return True
        if mode == "safe":
            held = self.controller.hold()
            self.get_logger().warning(
                f"safe mode: valves held at hot {held[0]:.4f}, cold {held[1]:.4f} (mean of the "
                "last excitation period), PI frozen"
                + (
                    ", excitation on"
                    if self.controller.config.excite_when_held
                    and self.controller.config.excitation_entry == "output"
                    else ""
                )
            )
        else:
            self.controller.resume()
            self.get_logger().info("normal mode: PI resumed from the held commands")
        self.mode = mode
        self.transitions += 1
        return True

    # --- output ---------------------------------------------------------------------------

    def command(self) -> np.ndarray:
        """(2,) the command of the current sample (advances the PI state)."""
        exc = self.table[self.k % len(self.table)]
        if self.height is None or self.temperature is None:
            return self.controller.open_command(exc)
        return self.controller.step((self.height, self.temperature), exc)

    def tick(self, stamp_ns: int | None = None) -> None:
        """Publish the command of this sample, from the latest measurements."""
        now = int(self.get_clock().now().nanoseconds) if stamp_ns is None else stamp_ns
        hot, cold = self.command()
        self.last_command = np.array([hot, cold])
        msg = self._cls()
        itf.set_stamp(msg.header.stamp, now)
        msg.hot = float(hot)
        msg.cold = float(cold)
        self.pub.publish(msg)
        self.k += 1


def main(args: list[str] | None = None) -> int:
    """``ros2 run twotank_validation twotank_controller`` entry point."""
    return run_managed(ControllerNode, args)


if __name__ == "__main__":
    sys.exit(main())
