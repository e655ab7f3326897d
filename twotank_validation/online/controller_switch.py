"""The supervisor's controller switch: which ros2_control controllers run, as a state machine.

An output of the supervisor's transitions (:mod:`twotank_validation.online.supervisor`), beside
its ``control/mode`` topic: in ``SAFE`` the configured *fallback* controllers run and the
*normal* ones are deactivated, in ``NORMAL`` the reverse. The supervisor's latch, hysteresis
and reset rules decide the mode; this module only follows it. It is ROS-free: the node
(:mod:`twotank_validation.ros.controller_switch`) sends the calls this machine asks for to the
controller manager's ``switch_controller`` service and reports their outcome back.

The rules:

* **Start.** The controllers are taken to be in the normal set (the controller stack is
  brought up with its normal controllers; the supervisor starts in ``NORMAL``): no call.
* **A transition** (:meth:`ControllerSwitch.want`) sets the wanted mode; the node then asks
  :meth:`ControllerSwitch.due` at once.
* **One call at a time.** :meth:`ControllerSwitch.due` returns the call to send when the
  controllers are not known to be in the wanted mode and no call is pending, and marks it
  pending; otherwise None.
* **Outcome.** An answer with ``ok`` puts the controllers in the call's mode (if the wanted
  mode changed meanwhile, the node asks :meth:`~ControllerSwitch.due` again at once). A
  refusal (``ok`` false), no answer within the timeout, a service that is not offered, or a
  call that fails is a fault (:class:`SwitchState`), counted and kept as the last fault; the
  controllers stay where they were known to be.
* **Retry.** After a fault the same switch is sent again at the supervisor's next check (its
  timer, every ``check_period_s``), and at every check after that until it succeeds or the
  wanted mode is reached otherwise: a switch is never dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import StrEnum

from twotank_validation.online.supervisor import Mode, SupervisorError


class Strictness(StrEnum):
    """The ``strictness`` of a ``SwitchController`` call (the upstream constant's name).

    ``STRICT``: the controller manager switches nothing if anything is wrong (an unknown
    controller, one already active or not active, one that fails to activate).
    ``BEST_EFFORT``: it switches what it can and skips the rest.
    """

    STRICT = "STRICT"
    BEST_EFFORT = "BEST_EFFORT"


class SwitchState(StrEnum):
    """Where the controller switch stands; the value is what ``supervisor/state`` carries."""

    OFF = "off"
    """No controller manager configured: no call is ever made."""
    IN_PLACE = "in_place"
    """The controllers are in the wanted mode's set (the last call succeeded, or none needed)."""
    PENDING = "pending"
    """A call is on its way; no answer yet."""
    REFUSED = "refused"
    """The controller manager answered ``ok`` false."""
    TIMED_OUT = "timed_out"
    """No answer within the switch timeout."""
    UNAVAILABLE = "unavailable"
    """The controller manager's ``switch_controller`` service is not offered."""
    FAILED = "failed"
    """The call could not be made or raised."""

    @property
    def fault(self) -> bool:
        """A failed switch (retried at the next check)."""
        return self in _FAULTS


_FAULTS = frozenset(
    (SwitchState.REFUSED, SwitchState.TIMED_OUT, SwitchState.UNAVAILABLE, SwitchState.FAILED)
)


@dataclass(frozen=True)
class SwitchConfig:
    """Which controllers the supervisor switches, and how.

    Attributes:
        controller_manager: the controller manager's node name (its service is
            ``<controller_manager>/switch_controller``); ``""``: the switch is off.
        normal_controllers: the controllers that run in ``NORMAL`` (deactivated in ``SAFE``).
        fallback_controllers: the controllers that run in ``SAFE`` (deactivated in ``NORMAL``).
        strictness: the calls' strictness.
        timeout_s: a call without an answer after this long (s, wall clock) is a fault; also
            sent as the call's ``timeout`` (the controller manager's own limit).
    """

    controller_manager: str = ""
    normal_controllers: tuple[str, ...] = ()
    fallback_controllers: tuple[str, ...] = ()
    strictness: Strictness = Strictness.STRICT
    timeout_s: float = 2.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.timeout_s) and self.timeout_s > 0):
            raise SupervisorError(
                f"switch_timeout_s must be finite and > 0 (s), found {self.timeout_s}"
            )
        if not self.enabled:
            return
        names = (*self.normal_controllers, *self.fallback_controllers)
        if not names:
            raise SupervisorError(
                f"controller_manager is {self.controller_manager!r} but no controller is named: "
                "set normal_controllers and/or fallback_controllers (or controller_manager '' "
                "for no switch)"
            )
        if any(not isinstance(n, str) or not n for n in names):
            raise SupervisorError(f"controller names must be non-empty strings, found {names}")
        both = set(self.normal_controllers) & set(self.fallback_controllers)
        if both:
            raise SupervisorError(
                f"controller(s) {sorted(both)} both in normal_controllers and "
                "fallback_controllers: a controller runs in one mode only"
            )

    @property
    def enabled(self) -> bool:
        """A controller manager is configured."""
        return bool(self.controller_manager)


@dataclass(frozen=True)
class SwitchCall:
    """One ``SwitchController`` call: the mode it puts the controllers in, and its lists.

    Attributes:
        target: the mode whose controllers it activates.
        activate: the controllers to activate.
        deactivate: the controllers to deactivate.
        attempt: its number among the calls for this target since the wanted mode last changed
            (1 = first; retries count up).
    """

    target: Mode
    activate: tuple[str, ...]
    deactivate: tuple[str, ...]
    attempt: int


def call_for(config: SwitchConfig, target: Mode, attempt: int = 1) -> SwitchCall:
    """The call that puts the controllers in ``target``'s set (SAFE: fallback on, normal off)."""
    normal, fallback = config.normal_controllers, config.fallback_controllers
    if target is Mode.SAFE:
        return SwitchCall(target, fallback, normal, attempt)
    return SwitchCall(target, normal, fallback, attempt)


@dataclass(frozen=True)
class SwitchStatus:
    """The switch's state (replaced whole, never changed in place).

    Attributes:
        state: where it stands.
        wanted: the supervisor's mode: the controllers should be in its set.
        applied: the mode whose controllers are known to run.
        pending: the call on its way, None if none.
        attempt: calls sent for the current wanted mode (0 before any).
        calls: calls sent since the start.
        failures: faults since the start.
        last_fault: the last fault's state, None before any.
        message: the controller manager's answer text (or the fault's cause) of the last call.
    """

    state: SwitchState = SwitchState.IN_PLACE
    wanted: Mode = Mode.NORMAL
    applied: Mode = Mode.NORMAL
    pending: SwitchCall | None = None
    attempt: int = 0
    calls: int = 0
    failures: int = 0
    last_fault: SwitchState | None = None
    message: str = ""


class ControllerSwitch:
    """The switch's state machine (see the module's rules); the node drives it.

    Attributes:
        config: the settings.
        status: the current status.
    """

    def __init__(self, config: SwitchConfig) -> None:
        self.config = config
        state = SwitchState.IN_PLACE if config.enabled else SwitchState.OFF
        self.status = SwitchStatus(state=state)

    def want(self, mode: Mode) -> None:
        """The supervisor switched to ``mode``: its controllers are wanted."""
        if mode is not self.status.wanted:
            self.status = replace(self.status, wanted=mode, attempt=0)

    def due(self) -> SwitchCall | None:
        """The call to send now (marked pending), or None (off, in place, or one pending)."""
        s = self.status
        if not self.config.enabled or s.pending is not None:
            return None
        if s.applied is s.wanted:
            if s.state is not SwitchState.IN_PLACE:
                self.status = replace(s, state=SwitchState.IN_PLACE)
            return None
        call = call_for(self.config, s.wanted, s.attempt + 1)
        self.status = replace(
            s, state=SwitchState.PENDING, pending=call, attempt=call.attempt, calls=s.calls + 1
        )
        return call

    def answered(self, call: SwitchCall, ok: bool, message: str = "") -> None:
        """The controller manager answered ``call``; ``ok`` false is a refusal."""
        if call is not self.status.pending:
            return  # an answer to a call already given up (timed out): ignored
        if ok:
            s = replace(self.status, pending=None, applied=call.target, message=message)
            state = SwitchState.IN_PLACE if s.applied is s.wanted else SwitchState.PENDING
            self.status = replace(s, state=state)
        else:
            self._fault(SwitchState.REFUSED, message)

    def timed_out(self, call: SwitchCall) -> None:
        """No answer to ``call`` within the timeout (the node has given it up)."""
        if call is self.status.pending:
            self._fault(SwitchState.TIMED_OUT, f"no answer within {self.config.timeout_s} s")

    def unavailable(self, call: SwitchCall, message: str) -> None:
        """``call`` could not be sent: the service is not offered."""
        if call is self.status.pending:
            self._fault(SwitchState.UNAVAILABLE, message)

    def failed(self, call: SwitchCall, message: str) -> None:
        """``call`` raised (``message``: the error)."""
        if call is self.status.pending:
            self._fault(SwitchState.FAILED, message)

    def _fault(self, state: SwitchState, message: str) -> None:
        s = self.status
        self.status = replace(
            s, state=state, pending=None, failures=s.failures + 1, last_fault=state, message=message
        )
