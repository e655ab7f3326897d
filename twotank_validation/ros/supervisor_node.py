"""The supervisor node: the validator's alarm in, the controller's mode out.

Thin adapter over :class:`twotank_validation.online.supervisor.Supervisor` (the rules are
there). Topics (node-relative, remappable), per watched model M:

* in: ``validation/M/invalidated`` (std_msgs/Bool, transient-local, as the validator publishes
  it), ``validation/M/report`` (twotank_validation_msgs/ValidationReport: its header stamp
  feeds the stale rule), and ``validation/M/diagnosis`` (twotank_validation_msgs/Diagnosis,
  as the validator publishes it: the last summary is carried in the state, nothing depends on
  it);
* out: ``control/mode`` (std_msgs/String ``"normal"`` or ``"safe"``, transient-local),
  ``supervisor/state`` (diagnostic_msgs/DiagnosticStatus, transient-local: OK in normal, ERROR
  in safe, the reason as message, the counters as values), the same status on ``/diagnostics``
  every check;
* service ``supervisor/reset`` (std_srvs/Trigger): clears the latch when no fault is present;
* optionally, ``<controller_manager>/switch_controller`` calls (ros2_control) at each
  transition (:mod:`twotank_validation.ros.controller_switch`).

Time is the node's clock (``use_sim_time`` follows ``/clock``); a timer every
``check_period_s`` of it applies the stale rule and the hysteresis. A backward jump of the
clock restarts the supervisor's timing (:class:`~twotank_validation.online.supervisor.Restart`).
Every transition is logged (warning into safe, info back to normal) and published on both
topics.

A managed node (:mod:`twotank_validation.ros.lifecycle`): it watches only while active. An
inactive validator sends no report, which the stale rule treats as a dead one (docs/ros.md,
"Managed nodes"). The rules' settings change at run time (:data:`SUPERVISOR_RUNTIME`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import JumpThreshold
from rclpy.duration import Duration
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger

from twotank_validation.defaults import NS_PER_S
from twotank_validation.online.supervisor import (
    Event,
    Invalidated,
    Mode,
    Report,
    Reset,
    Restart,
    Supervisor,
    SupervisorConfig,
    SupervisorError,
    Tick,
    Transition,
    fault_text,
    judged_age_s,
    report_age_s,
)
from twotank_validation.ros import controller_switch, messages
from twotank_validation.ros.lifecycle import ManagedNode, run_managed
from twotank_validation.ros.params import LATCHED, Param, ParameterError

_DEFAULTS = SupervisorConfig()

SUPERVISOR_PARAMS = (
    Param("models", list(_DEFAULTS.watched), "models whose alarm switches the mode"),
    Param(
        "clear_after_s",
        _DEFAULTS.clear_after_s,
        "time (s) without fault before safe returns to normal",
        0.0,
        1e6,
    ),
    Param(
        "clear_reports",
        _DEFAULTS.clear_reports,
        "reports of each watched model, without fault, before safe returns to normal",
        0,
        1_000_000,
    ),
    Param("latch", _DEFAULTS.latch, "stay safe until the supervisor/reset service is called"),
    Param(
        "stale_after_s",
        _DEFAULTS.stale_after_s,
        "a watched model without a report this long (s, report stamps) switches to safe",
        1e-3,
        1e6,
    ),
    Param(
        "startup_grace_s",
        _DEFAULTS.startup_grace_s,
        "time (s) after start within which a model that has not reported yet is not stale",
        0.0,
        1e6,
    ),
    Param(
        "unjudged_after_s",
        _DEFAULTS.unjudged_after_s,
        "a watched model that reports but has no judged window this long (s) switches to safe "
        "(0: off)",
        0.0,
        1e9,
    ),
    Param(
        "check_period_s",
        1.0,
        "period (s, node clock) of the stale and hysteresis check",
        1e-3,
        3600,
    ),
    *controller_switch.SWITCH_PARAMS,
)


def supervisor_config(values: dict[str, Any]) -> SupervisorConfig:
    """The supervisor settings of the node's parameter values.

    Raises:
        ParameterError: the settings are inconsistent (the message names the parameter).
    """
    try:
        return SupervisorConfig(
            watched=tuple(str(m) for m in values["models"]),
            clear_after_s=float(values["clear_after_s"]),
            clear_reports=int(values["clear_reports"]),
            latch=bool(values["latch"]),
            stale_after_s=float(values["stale_after_s"]),
            startup_grace_s=float(values["startup_grace_s"]),
            unjudged_after_s=float(values["unjudged_after_s"]) or math.inf,
        )
    except SupervisorError as err:
        raise ParameterError(f"cannot start the supervisor: {err}") from err


SUPERVISOR_RUNTIME = frozenset(
    {
        "clear_after_s",
        "clear_reports",
        "latch",
        "stale_after_s",
        "startup_grace_s",
        "unjudged_after_s",
    }
)
"""The supervisor's parameters that change at run time (the state machine's rules, applied at
its next event); ``models`` and ``check_period_s`` are read-only."""


class SupervisorNode(ManagedNode):
    """Switches ``control/mode`` to safe on the watched models' alarm or silence, and back.

    A managed node (:mod:`twotank_validation.ros.lifecycle`): configure builds the state
    machine and the publishers, activate subscribes and starts the check timer.

    Attributes:
        machine: the state machine (its ``log`` holds every transition); built by configure.
        diagnosis: the summary of the last ``validation/M/diagnosis`` of each watched model.
        switch: the ros2_control controller switch (its state ``off`` when not configured);
            built by configure.
        received: messages received per input topic (node-relative name).
        states_published: ``supervisor/state`` messages published.
        modes_published: ``control/mode`` messages published.
    """

    PARAMS = SUPERVISOR_PARAMS
    RUNTIME = SUPERVISOR_RUNTIME
    ROLE = "supervisor"
    OWN_STATUS = True

    def __init__(self, *, name: str = "twotank_supervisor", **kwargs: Any) -> None:
        self.diagnosis: dict[str, str] = {}
        self.received: dict[str, int] = {}
        self.states_published = 0
        self.last_state: DiagnosticStatus | None = None
        self.modes_published = 0
        self._clock_started = False
        self._warned_interval = False
        super().__init__(name, **kwargs)

    def configure_node(self, values: dict[str, Any]) -> None:
        """The state machine of the parameters; the mode and state publishers."""
        self.machine = Supervisor(supervisor_config(values))
        self._check_period_s = float(values["check_period_s"])
        _, self._report_cls = messages.message_classes()
        self._diagnosis_cls = messages.diagnosis_class()
        self._pub_mode = self.configured(
            self.create_lifecycle_publisher(String, "control/mode", LATCHED)
        )
        self._pub_state = self.configured(
            self.create_lifecycle_publisher(DiagnosticStatus, "supervisor/state", LATCHED)
        )
        self.switch = controller_switch.SwitchClient(self, values, self._publish_state)
        self.configured(self.switch.close)

    def check_runtime(self, values: dict[str, Any]) -> Callable[[], None] | None:
        """The new rules (:func:`supervisor_config` checks them), applied at once."""
        config = supervisor_config(values)

        def apply() -> None:
            self.machine.config = config

        return apply if self.is_configured else None

    def activate_node(self) -> None:
        """Subscribe to the watched models, start the check timer, publish the mode."""
        report_cls = self._report_cls
        for m in self.machine.config.watched:
            self.activated(
                self.create_subscription(
                    Bool, f"validation/{m}/invalidated", partial(self._on_invalidated, m), LATCHED
                )
            )
            self.activated(
                self.create_subscription(
                    report_cls, f"validation/{m}/report", partial(self._on_report, m), 10
                )
            )
            self.activated(
                self.create_subscription(
                    self._diagnosis_cls,
                    f"validation/{m}/diagnosis",
                    partial(self._on_diagnosis, m),
                    10,
                )
            )
        self.activated(self.create_service(Trigger, "supervisor/reset", self._on_reset))
        self.activated(self.create_timer(self._check_period_s, self._on_tick))
        # a backward jump of the (simulated) clock restarts the stale rule's timing at once
        handle = self.get_clock().create_jump_callback(
            JumpThreshold(
                min_forward=None, min_backward=Duration(nanoseconds=-1), on_clock_change=False
            ),
            post_callback=self._on_time_jump,
        )
        self.activated(handle.unregister)
        if self.machine.state.now_s is not None:
            # reactivated: what happened while inactive went unseen; the stale rule's timing
            # restarts as after a clock jump
            self.machine.step(self._now_s(), Restart())
        self._publish_mode()
        self._publish_state()

    # ---------------------------------------------------------------- time and events

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds / NS_PER_S

    def _step(self, event: Event) -> Transition | None:
        """Feed one event at the node clock's time; publish and log what changed."""
        now = self._now_s()
        last = self.machine.state.now_s
        if not self._clock_started and now > 0.0:
            # the (simulated) clock starts: the startup grace counts from here, not from 0
            self._clock_started = True
            if last is not None:
                self.machine.step(now, Restart())
        elif last is not None and now < last:
            self.get_logger().warning(
                f"clock jumped back from {last:.3f} s to {now:.3f} s: stale rule restarted"
            )
            self.machine.step(now, Restart())
        s = self.machine.state
        before = (s.faults, s.latched, s.counters)
        tr = self.machine.step(now, event)
        s = self.machine.state
        if tr is not None:
            self._on_transition(tr)
        elif (s.faults, s.latched, s.counters) != before:
            self._publish_state()
        return tr

    def _on_time_jump(self, jump: Any) -> None:
        if jump.delta.nanoseconds < 0 and self.machine.state.now_s is not None:
            now = self._now_s()
            self.get_logger().warning(
                f"clock jumped back from {self.machine.state.now_s:.3f} s to {now:.3f} s: "
                "stale rule restarted"
            )
            self.machine.step(now, Restart())
            self._publish_state()

    def _on_transition(self, tr: Transition) -> None:
        c = self.machine.counters
        text = (
            f"{tr.from_mode.value} -> {tr.to_mode.value} at {tr.time_s:.3f} s: {tr.reason} "
            f"(transition {c.transitions})"
        )
        if tr.to_mode is Mode.SAFE:
            self.get_logger().warning(text)
        else:
            self.get_logger().info(text)
        self._publish_mode()
        self.switch.want(tr.to_mode)
        self._publish_state()

    def _count(self, topic: str) -> None:
        self.received[topic] = self.received.get(topic, 0) + 1

    def _on_invalidated(self, model: str, msg: Bool) -> None:
        self._count(f"validation/{model}/invalidated")
        self._step(Invalidated(model, bool(msg.data)))

    def _on_report(self, model: str, msg: Any) -> None:
        self._count(f"validation/{model}/report")
        stamp = msg.header.stamp
        stamp_s = stamp.sec + stamp.nanosec / NS_PER_S
        last = self.machine.state.last_report_s.get(model)
        stale_s = self.machine.config.stale_after_s
        if last is not None and stamp_s - last > stale_s / 2 and not self._warned_interval:
            self._warned_interval = True
            self.get_logger().warning(
                f"reports of {model} {stamp_s - last:.1f} s apart: stale_after_s = {stale_s} s "
                "leaves little margin; set it to about 3 report intervals (the validator's hop)"
            )
        self._step(Report(model, stamp_s, bool(msg.judged)))

    def _on_diagnosis(self, model: str, msg: Any) -> None:
        self._count(f"validation/{model}/diagnosis")
        self.diagnosis[model] = str(msg.summary)
        self._publish_state()

    def _on_tick(self) -> None:
        if self._now_s() <= 0.0:
            return  # simulated time has not started
        self._step(Tick())
        self._pub_status.publish(DiagnosticArray(status=[self.status()]))
        self.switch.check()  # after: /diagnostics shows a failed switch before its retry

    def _on_reset(self, _req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        before = self.machine.counters.resets_accepted
        tr = self._step(Reset())
        resp.success = self.machine.counters.resets_accepted > before
        resp.message = self.machine.state.last_reset + (
            f"; {tr.to_mode.value}: {tr.reason}" if tr is not None else ""
        )
        self.get_logger().info(f"reset requested: {resp.message}")
        return resp

    # ---------------------------------------------------------------- publishing

    def status(self) -> DiagnosticStatus:
        """The supervisor's state as a DiagnosticStatus (what ``supervisor/state`` carries)."""
        s = self.machine.state
        c = s.counters
        now = s.now_s if s.now_s is not None else self._now_s()
        st = DiagnosticStatus()
        st.level = DiagnosticStatus.ERROR if s.mode is Mode.SAFE else DiagnosticStatus.OK
        st.name = "twotank_validation: supervisor"
        st.hardware_id = self.get_fully_qualified_name()
        st.message = f"{s.mode.value}: {s.reason}" + (" (latched)" if s.latched else "")
        st.level = max(st.level, self.switch.level())
        st.message += self.switch.message()
        values = {
            "mode": s.mode.value,
            "reason": s.reason,
            "latched": str(s.latched).lower(),
            "faults": fault_text(s, now),
            "transitions": str(c.transitions),
            "to_safe": str(c.to_safe),
            "to_normal": str(c.to_normal),
            "to_safe_invalidated": str(c.invalidated),
            "to_safe_stale": str(c.stale),
            "to_safe_unjudged": str(c.unjudged),
            "resets_accepted": str(c.resets_accepted),
            "resets_refused": str(c.resets_refused),
            "last_transition_s": f"{self.machine.log[-1].time_s:.3f}" if self.machine.log else "",
        }
        for m in self.machine.config.watched:
            values[f"report_age_s/{m}"] = f"{report_age_s(s, m, now):.1f}"
            values[f"judged_age_s/{m}"] = f"{judged_age_s(s, m, now):.1f}"
            values[f"invalidated/{m}"] = str(m in s.invalidated).lower()
            if m in self.diagnosis:
                values[f"diagnosis/{m}"] = self.diagnosis[m]
        values.update(self.switch.values())
        st.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        return st

    def _publish_mode(self) -> None:
        self._pub_mode.publish(String(data=self.machine.mode.value))
        self.modes_published += 1

    def _publish_state(self) -> None:
        self.last_state = self.status()
        self._pub_state.publish(self.last_state)
        self.states_published += 1


def main(args: list[str] | None = None) -> int:
    """``ros2 run twotank_validation twotank_supervisor`` entry point."""
    return run_managed(SupervisorNode, args)


if __name__ == "__main__":
    sys.exit(main())
