"""The supervisor's ros2_control switch: ``SwitchController`` calls to a controller manager.

The ROS side of :mod:`twotank_validation.online.controller_switch` (the rules are there): the
supervisor node declares :data:`SWITCH_PARAMS`, builds a :class:`SwitchClient` and tells it
its transitions (:meth:`SwitchClient.want`) and checks (:meth:`SwitchClient.check`); the
client sends ``controller_manager_msgs/srv/SwitchController`` calls to
``<controller_manager>/switch_controller`` asynchronously (never waiting in a callback), gives
a call up after ``switch_timeout_s`` of wall clock, and reports every change of the switch's
state through ``on_change`` (the node publishes ``supervisor/state``) and the log.

The interface package ``controller_manager_msgs`` comes with ros2_control in a ROS 2 install;
it is not on PyPI. With ``controller_manager`` left ``""`` (the default) it is never imported,
and the supervisor runs as without the switch; set without the package, the node stops with
:class:`~twotank_validation.ros.params.ParameterError` naming what to install.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.node import Node
from rclpy.task import Future

from twotank_validation.online.controller_switch import (
    ControllerSwitch,
    Strictness,
    SwitchCall,
    SwitchConfig,
    SwitchState,
)
from twotank_validation.online.supervisor import Mode, SupervisorError
from twotank_validation.ros.params import Param, ParameterError

_DEFAULTS = SwitchConfig()

SWITCH_PARAMS = (
    Param(
        "controller_manager",
        _DEFAULTS.controller_manager,
        "controller manager whose switch_controller service the supervisor calls (e.g. "
        "/controller_manager); empty: no controller switch",
    ),
    Param(
        "normal_controllers",
        list(_DEFAULTS.normal_controllers) or [""],
        "ros2_control controllers active in normal mode (deactivated in safe); '' for none",
    ),
    Param(
        "fallback_controllers",
        list(_DEFAULTS.fallback_controllers) or [""],
        "ros2_control controllers active in safe mode (deactivated in normal); '' for none",
    ),
    Param(
        "switch_strictness",
        _DEFAULTS.strictness.value,
        "strictness of the switch_controller calls",
        choices=tuple(s.value for s in Strictness),
    ),
    Param(
        "switch_timeout_s",
        _DEFAULTS.timeout_s,
        "a switch_controller call without an answer this long (s, wall clock) is a fault, "
        "retried at the next check",
        1e-3,
        3600.0,
    ),
)

MISSING_TYPE = (
    "parameter 'controller_manager' is {name!r} but the interface package "
    "controller_manager_msgs is not installed: install ros2_control's interfaces "
    "(apt-get install ros-$ROS_DISTRO-controller-manager-msgs, or build ros2_control in the "
    "workspace), or set controller_manager to '' to run the supervisor without the switch"
)


def switch_config(values: Mapping[str, Any]) -> SwitchConfig:
    """The switch settings of the supervisor node's parameter values.

    Raises:
        ParameterError: inconsistent settings (the message names the parameter).
    """
    try:
        return SwitchConfig(
            controller_manager=str(values["controller_manager"]).rstrip("/"),
            normal_controllers=tuple(str(c) for c in values["normal_controllers"] if c),
            fallback_controllers=tuple(str(c) for c in values["fallback_controllers"] if c),
            strictness=Strictness(str(values["switch_strictness"])),
            timeout_s=float(values["switch_timeout_s"]),
        )
    except SupervisorError as err:
        raise ParameterError(f"cannot start the supervisor: {err}") from err


def switch_service_type(controller_manager: str) -> Any:
    """``controller_manager_msgs.srv.SwitchController``.

    Raises:
        ParameterError: the package is not installed (the message says what to install).
    """
    try:
        from controller_manager_msgs.srv import SwitchController  # noqa: PLC0415
    except ImportError as err:
        raise ParameterError(MISSING_TYPE.format(name=controller_manager)) from err
    return SwitchController


class SwitchClient:
    """Sends the switch machine's calls to the controller manager, asynchronously.

    Attributes:
        machine: the state machine (:class:`ControllerSwitch`).
    """

    def __init__(
        self, node: Node, values: Mapping[str, Any], on_change: Callable[[], None]
    ) -> None:
        self.machine = ControllerSwitch(switch_config(values))
        self._node = node
        self._on_change = on_change
        self._client: Any = None
        cfg = self.machine.config
        if cfg.enabled:
            self._srv = switch_service_type(cfg.controller_manager)
            self._client = node.create_client(
                self._srv, f"{cfg.controller_manager}/switch_controller"
            )
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)

    @property
    def service(self) -> str:
        """The service's resolved name (``""`` when off)."""
        return self._client.service_name if self._client is not None else ""

    def close(self) -> None:
        """Destroy the service client (the supervisor's cleanup); calls stop."""
        if self._client is not None:
            self._node.destroy_client(self._client)
            self._client = None

    def want(self, mode: Mode) -> None:
        """A supervisor transition to ``mode``: switch to its controllers now."""
        if self._client is None:
            return
        self.machine.want(mode)
        self.check()

    def check(self) -> None:
        """The supervisor's check: send the due call (a first one or a retry), if any."""
        if self._client is None:
            return
        before = self.machine.status.state
        call = self.machine.due()
        if call is not None:
            self._send(call)
        elif self.machine.status.state is not before:
            self._on_change()

    def _send(self, call: SwitchCall) -> None:
        log = self._node.get_logger()
        if not self._client.service_is_ready():
            self.machine.unavailable(call, f"{self.service} is not offered")
            log.error(
                f"controller switch to {call.target.value} (attempt {call.attempt}): "
                f"{self.service} is not offered; retried at the next check"
            )
            self._on_change()
            return
        cfg = self.machine.config
        req = self._srv.Request()
        req.activate_controllers = list(call.activate)
        req.deactivate_controllers = list(call.deactivate)
        req.strictness = getattr(self._srv.Request, cfg.strictness.value)
        req.activate_asap = False
        req.timeout.sec = int(cfg.timeout_s)
        req.timeout.nanosec = round((cfg.timeout_s - int(cfg.timeout_s)) * 1e9) % 1_000_000_000
        try:
            future = self._client.call_async(req)
        except Exception as err:  # rclpy raises several types for a call it cannot make
            self.machine.failed(call, f"{type(err).__name__}: {err}")
            log.error(f"controller switch to {call.target.value} failed: {err}; retried")
            self._on_change()
            return
        log.info(
            f"controller switch to {call.target.value} (attempt {call.attempt}): activate "
            f"{list(call.activate)}, deactivate {list(call.deactivate)}"
        )
        timer: list[Any] = []
        timer.append(
            self._node.create_timer(
                cfg.timeout_s, partial(self._on_timeout, call, future, timer), clock=self._wall
            )
        )
        future.add_done_callback(partial(self._on_done, call, timer))
        self._on_change()

    def _drop_timer(self, timer: list[Any]) -> None:
        while timer:
            self._node.destroy_timer(timer.pop())

    def _on_timeout(self, call: SwitchCall, future: Future[Any], timer: list[Any]) -> None:
        self._drop_timer(timer)
        if future.done():
            return
        self._client.remove_pending_request(future)
        future.cancel()
        self.machine.timed_out(call)
        self._node.get_logger().error(
            f"controller switch to {call.target.value} (attempt {call.attempt}): no answer "
            f"from {self.service} within {self.machine.config.timeout_s} s; retried at the "
            "next check"
        )
        self._on_change()

    def _on_done(self, call: SwitchCall, timer: list[Any], future: Future[Any]) -> None:
        self._drop_timer(timer)
        if future.cancelled() or call is not self.machine.status.pending:
            return
        log = self._node.get_logger()
        err = future.exception()
        if err is not None:
            self.machine.failed(call, f"{type(err).__name__}: {err}")
            log.error(f"controller switch to {call.target.value} failed: {err}; retried")
        else:
            resp: Any = future.result()
            message = str(getattr(resp, "message", ""))  # older interfaces have no message
            self.machine.answered(call, bool(resp.ok), message)
            if resp.ok:
                log.info(f"controller switch to {call.target.value} done")
            else:
                log.error(
                    f"controller switch to {call.target.value} (attempt {call.attempt}) "
                    f"refused by {self.service}: {message!r}; retried at the next check"
                )
            if resp.ok and (nxt := self.machine.due()) is not None:
                self._send(nxt)  # the wanted mode changed while the call was on its way
                return
        self._on_change()

    # ---------------------------------------------------------------- publishing

    def level(self) -> bytes:
        """The least diagnostic level the switch asks for: WARN on a fault and on its retry."""
        s = self.machine.status
        failing = s.state.fault or (s.state is SwitchState.PENDING and s.attempt > 1)
        return DiagnosticStatus.WARN if failing else DiagnosticStatus.OK

    def message(self) -> str:
        """The suffix of the status message while the switch has failed (``""`` otherwise)."""
        s = self.machine.status
        if not s.state.fault:
            return ""
        return f"; controller switch to {s.wanted.value} {s.state.value} (attempt {s.attempt})"

    def values(self) -> dict[str, str]:
        """The switch's keys on ``supervisor/state`` and ``/diagnostics`` (none when off)."""
        s = self.machine.status
        if s.state is SwitchState.OFF:
            return {}
        return {
            "switch": s.state.value,
            "switch_wanted": s.wanted.value,
            "switch_applied": s.applied.value,
            "switch_attempt": str(s.attempt),
            "switch_calls": str(s.calls),
            "switch_failures": str(s.failures),
            "switch_last_fault": s.last_fault.value if s.last_fault is not None else "",
            "switch_message": s.message,
        }
