"""Managed (lifecycle) nodes: the plumbing the validator, supervisor, controller and plant share.

Each of the four is a :class:`ManagedNode` (an ``rclpy.lifecycle.LifecycleNode``) with the
conventional semantics (docs/ros.md, Managed nodes):

* construction declares the parameters (the ones not in the node's ``RUNTIME`` set
  ``read_only``); a value outside its range is kept aside, not raised, and makes configure fail;
* **configure** reads and checks the parameters and builds the node's core (validator, state
  machine, controller, simulator) and its publishers; a bad parameter: FAILURE, the reason
  logged (naming the parameter and the fix), the node stays unconfigured;
* **activate** creates the subscriptions, timers and services and starts the work;
* **deactivate** stops the work, destroys what activate created, and publishes the node's
  ``/diagnostics`` status as ``inactive`` (level WARN, key ``lifecycle_state``) once and then every
  :data:`STATUS_PERIOD_S` of wall time while inactive, so that a monitor sees why it is
  quiet (a node without statuses of its own, the plant or the controller, says ``active``,
  level OK, while active);
* **cleanup** (and **shutdown**, from any state) releases everything configure built
  (publishers, the evidence recorder, worker threads).

A subclass fills in :meth:`ManagedNode.configure_node`, :meth:`~ManagedNode.activate_node`,
:meth:`~ManagedNode.deactivate_node`, :meth:`~ManagedNode.cleanup_node`,
:meth:`~ManagedNode.inactive_names` and, if it has run-time parameters,
:meth:`~ManagedNode.check_runtime`; it creates its entities through
:meth:`~ManagedNode.configured` / :meth:`~ManagedNode.activated` so that the base destroys them.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, ClassVar, TypeVar

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.lifecycle import (
    LifecycleNode,
    LifecyclePublisher,
    LifecycleState,
    TransitionCallbackReturn,
)
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.service import Service
from rclpy.subscription import Subscription
from rclpy.timer import Timer

from twotank_validation.ros.params import Param, ParameterError, check_value, declare, run_node

STATUS_PERIOD_S = 1.0
"""Wall-clock period (s) of the lifecycle status on ``/diagnostics`` (``inactive``; ``active``
too for a node without statuses of its own): a diagnostic aggregator marks a status stale
after a few seconds without one."""

INACTIVE_LEVEL = DiagnosticStatus.WARN
"""Level of the ``inactive`` status: not OK (nothing is being checked or controlled), not
ERROR or STALE (nothing is wrong with the data: the node was told to stop)."""

N = TypeVar("N", bound="ManagedNode")


class ManagedNode(LifecycleNode):
    """A lifecycle node with its parameter table, run-time parameters and entity bookkeeping.

    Class attributes:
        PARAMS: the node's parameter table.
        RUNTIME: the parameters that may change at run time (validated by
            :meth:`check_runtime`); all others are ``read_only``.
        ROLE: the node's role in messages (``"validator"``).
        OWN_STATUS: the node publishes statuses of its own on ``/diagnostics`` while active
            (the validator, the supervisor); otherwise the base publishes ``active`` (OK)
            every :data:`STATUS_PERIOD_S` then.

    Attributes:
        configure_error: why the last configure failed ("" if it did not).
    """

    PARAMS: ClassVar[tuple[Param, ...]] = ()
    RUNTIME: ClassVar[frozenset[str]] = frozenset()
    ROLE: ClassVar[str] = "node"
    OWN_STATUS: ClassVar[bool] = False

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self._declare_errors: dict[str, str] = {}
        declare(self, self.PARAMS, runtime=self.RUNTIME, errors=self._declare_errors)
        self._table = {p.name: p for p in self.PARAMS}
        self.configure_error = ""
        self._configured: list[Any] = []  # entities configure created (cleanup destroys)
        self._activated: list[Any] = []  # entities activate created (deactivate destroys)
        self._status_timer: Any = None  # the lifecycle status's (steady clock)
        self._status_state = "inactive"
        self._pub_status: Any = None
        self.add_on_set_parameters_callback(self._on_set_parameters)

    # ------------------------------------------------------------------ for subclasses

    def configure_node(self, values: dict[str, Any]) -> None:
        """Build the node's core and publishers from its parameter ``values``.

        Raises:
            ParameterError: a value that cannot hold (the message names it and the fix).
        """

    def activate_node(self) -> None:
        """Create subscriptions, timers and services (:meth:`activated`); start working."""

    def deactivate_node(self) -> None:
        """Stop working (what activate created is destroyed by the base afterwards)."""

    def cleanup_node(self) -> None:
        """Release what configure built besides its entities (threads, files)."""

    def inactive_names(self) -> list[str]:
        """The names of the node's ``/diagnostics`` statuses (each said ``inactive``)."""
        return [f"twotank_validation: {self.ROLE}"]

    def check_runtime(self, values: dict[str, Any]) -> Callable[[], None] | None:
        """Check a run-time change (``values``: every parameter, the new ones in).

        Returns:
            What applies it to the configured node (None: nothing to apply now: the node is
            unconfigured (:attr:`is_configured`) and configure reads it).

        Raises:
            ParameterError: the values cannot hold together (the message names the fix).
        """
        return None

    def configured(self, entity: Any) -> Any:
        """Track ``entity`` (created by configure): cleanup destroys it."""
        self._configured.append(entity)
        return entity

    def activated(self, entity: Any) -> Any:
        """Track ``entity`` (created by activate): deactivate destroys it."""
        self._activated.append(entity)
        return entity

    # ------------------------------------------------------------------ state

    @property
    def lifecycle_state(self) -> str:
        """``"unconfigured"``, ``"inactive"``, ``"active"`` or ``"finalized"``."""
        return str(self._state_machine.current_state[1])

    @property
    def is_configured(self) -> bool:
        """The node is configured (inactive or active): its core exists."""
        return self.lifecycle_state in ("inactive", "active")

    @property
    def is_active(self) -> bool:
        """The node is active (working)."""
        return self.lifecycle_state == "active"

    def parameter_values(self) -> dict[str, Any]:
        """The current value of every parameter of the table."""
        return {name: self.get_parameter(name).value for name in self._table}

    # ------------------------------------------------------------------ transitions

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Read and check the parameters, build the core: FAILURE on a bad parameter."""
        values = self.parameter_values()
        try:
            if self._declare_errors:
                raise ParameterError(
                    "; ".join(
                        f"{why} (fix: "
                        + (
                            "ros2 param set it, then configure again)"
                            if name in self.RUNTIME
                            else "set it in the params file or on the command line and restart)"
                        )
                        for name, why in self._declare_errors.items()
                    )
                )
            self._pub_status = self.configured(
                self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            )
            self.configure_node(values)
        except ParameterError as err:
            self.configure_error = str(err)
            self.get_logger().error(
                f"cannot configure the {self.ROLE}: {err} (the node stays unconfigured)"
            )
            self._release_configured()
            return TransitionCallbackReturn.FAILURE
        self.configure_error = ""
        ret = super().on_configure(state)
        self._enter_inactive()
        return ret

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Create subscriptions, timers and services; start working."""
        if self.OWN_STATUS:
            self._stop_status_timer()  # the node's own statuses take over
        ret = super().on_activate(state)  # enables the lifecycle publishers
        self.activate_node()
        if not self.OWN_STATUS:
            self._status_state = "active"
            self.publish_status()
        self.get_logger().info(f"{self.ROLE} active")
        return ret

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop working; say ``inactive`` on ``/diagnostics``."""
        self._stop_active()
        ret = super().on_deactivate(state)
        self._enter_inactive()
        self.get_logger().info(f"{self.ROLE} inactive: not working until activated again")
        return ret

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Release what configure built."""
        self._stop_status_timer()
        self._release_configured()
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Release everything, from any state."""
        self.release()
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised: release everything, back to unconfigured."""
        self.release()
        return TransitionCallbackReturn.SUCCESS  # back to unconfigured

    def release(self) -> None:
        """Stop and release everything, from whatever state (shutdown, destroy_node)."""
        if self._activated:
            self._stop_active()
        self._stop_status_timer()
        self._release_configured()

    def destroy_node(self) -> None:
        """Release everything (as shutdown does), then destroy the node."""
        self.release()
        super().destroy_node()

    # ------------------------------------------------------------------ internals

    def _stop_active(self) -> None:
        self.deactivate_node()
        for entity in reversed(self._activated):
            _destroy(self, entity)
        self._activated.clear()

    def _release_configured(self) -> None:
        self.cleanup_node()
        for entity in reversed(self._configured):
            _destroy(self, entity)
        self._configured.clear()
        self._pub_status = None

    def _enter_inactive(self) -> None:
        self._status_state = "inactive"
        self.publish_status()
        if self._status_timer is None:
            self._status_timer = self.create_timer(
                STATUS_PERIOD_S,
                self.publish_status,
                clock=Clock(clock_type=ClockType.STEADY_TIME),
            )

    def _stop_status_timer(self) -> None:
        if self._status_timer is not None:
            self.destroy_timer(self._status_timer)
            self._status_timer = None

    def publish_status(self) -> None:
        """Publish the node's lifecycle status on ``/diagnostics``.

        ``inactive`` (WARN); or ``active`` (OK) for a node without statuses of its own
        (:attr:`OWN_STATUS`).
        """
        if self._pub_status is None:
            return
        state = self._status_state
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        for name in self.inactive_names():
            st = DiagnosticStatus()
            st.name = name
            st.hardware_id = self.get_fully_qualified_name()
            if state == "active":
                st.level = DiagnosticStatus.OK
                st.message = f"active: the {self.ROLE} is working"
            else:
                st.level = INACTIVE_LEVEL
                st.message = f"inactive: the {self.ROLE} is not working (lifecycle state inactive)"
            st.values = [KeyValue(key="lifecycle_state", value=state)]
            arr.status.append(st)
        self._pub_status.publish(arr)

    def _on_set_parameters(self, params: list[Parameter[Any]]) -> SetParametersResult:
        """Run-time parameters: checked by the table and the node (the settings tree)."""
        mine = [p for p in params if p.name in self._table]
        if not mine:
            return SetParametersResult(successful=True)
        for p in mine:
            if p.name not in self.RUNTIME:  # read_only refuses first; kept as a safeguard
                return SetParametersResult(
                    successful=False,
                    reason=f"parameter {p.name!r} is read-only: set it in the params file or on "
                    "the command line and restart the node",
                )
            problem = check_value(self._table[p.name], p.value)
            if problem is not None:
                return SetParametersResult(successful=False, reason=problem)
        values = {**self.parameter_values(), **{p.name: p.value for p in mine}}
        try:
            apply = self.check_runtime(values)
        except ParameterError as err:
            return SetParametersResult(successful=False, reason=str(err))
        if apply is not None:
            apply()
        for p in mine:
            self._declare_errors.pop(p.name, None)
        names = ", ".join(f"{p.name}={p.value!r}" for p in mine)
        self.get_logger().info(f"parameters changed at run time: {names}")
        return SetParametersResult(successful=True)


def _destroy(node: ManagedNode, entity: Any) -> None:
    """Destroy one entity of ``node`` (publisher, subscription, timer, service)."""
    if isinstance(entity, LifecyclePublisher):
        node.destroy_lifecycle_publisher(entity)
    elif isinstance(entity, Publisher):
        node.destroy_publisher(entity)
    elif isinstance(entity, Subscription):
        node.destroy_subscription(entity)
    elif isinstance(entity, Timer):
        node.destroy_timer(entity)
    elif isinstance(entity, Service):
        node.destroy_service(entity)
    else:  # a callable releasing something else (a clock jump handle)
        entity()


def bring_up(node: N, *, activate: bool = True) -> N:
    """Configure ``node`` (and activate it): what ``live``, the tests and ``main`` do.

    Returns:
        The node, active (or inactive with ``activate=False``).

    Raises:
        ParameterError: configure failed (the node's reason); the node is destroyed.
    """
    if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
        reason = node.configure_error or f"the {node.ROLE} did not configure"
        node.destroy_node()
        raise ParameterError(reason)
    if activate and node.trigger_activate() != TransitionCallbackReturn.SUCCESS:
        node.destroy_node()
        raise ParameterError(f"the {node.ROLE} did not activate")
    return node


def autostart_of(args: list[str] | None) -> tuple[bool, list[str] | None]:
    """``--autostart true|false`` taken out of a node's command line (default true)."""
    argv = list(sys.argv[1:] if args is None else args)
    autostart = True
    if "--autostart" in argv:
        i = argv.index("--autostart")
        text = argv[i + 1].lower() if i + 1 < len(argv) else ""
        if text not in ("true", "false"):
            raise SystemExit("ERROR: --autostart takes true or false")
        autostart = text == "true"
        del argv[i : i + 2]
    return autostart, argv


def run_managed(factory: Callable[[], ManagedNode], args: list[str] | None = None) -> int:
    """Entry point body of a managed node: init, build, configure and activate, spin.

    With ``--autostart false`` the node waits unconfigured for its transitions (``ros2
    lifecycle set``, a lifecycle manager, launch's ``autostart:=false``). A failed configure
    under autostart exits 1 with the reason (the node was destroyed by :func:`bring_up`).
    """
    autostart, argv = autostart_of(args)
    return run_node(factory, argv, prepare=bring_up if autostart else None)
