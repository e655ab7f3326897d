"""A fake ros2_control controller manager: ``switch_controller`` with upstream's semantics.

The node serves ``<name>/switch_controller`` (controller_manager_msgs/srv/SwitchController,
the vendored interface of test/interfaces/) over a set of known controllers, each active or
not, as ros2_control's controller manager decides a switch (controller_manager.cpp, its
``switch_controller``; the service's own comments):

* a name to deactivate that is unknown or not active, or a name to activate that is unknown or
  already active (and not also deactivated), is a conflict;
* ``STRICT``: any conflict refuses the whole switch (``ok`` false, nothing changes);
* ``BEST_EFFORT``: conflicting names are skipped, the rest is switched, ``ok`` true, unless
  every name to activate or every name to deactivate is unknown (``ok`` false);
* other strictness values (AUTO, FORCE_AUTO resolve controller chains, which a fake without
  chains cannot) are refused.

Two faults on demand: ``refuse`` answers ``ok`` false to everything; ``hang`` never answers
(the call waits, as on a controller manager stuck in its control loop) until :meth:`release`
drops it.
Every request is kept in ``requests``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from controller_manager_msgs.srv import SwitchController
from rclpy.node import Node
from rclpy.task import Future


@dataclass(frozen=True)
class Request:
    """One request as received: activate, deactivate, strictness, timeout (s)."""

    activate: tuple[str, ...]
    deactivate: tuple[str, ...]
    strictness: int
    timeout_s: float


class FakeControllerManager(Node):
    """Serves ``switch_controller`` over ``controllers`` (name -> active).

    Attributes:
        controllers: each known controller and whether it is active.
        requests: every request received, oldest first.
        refuse: answer ``ok`` false to every request (nothing changes).
        hang: answer nothing (until :meth:`release`).
    """

    def __init__(
        self, active: Iterable[str], inactive: Iterable[str], *, name: str = "controller_manager",
        **kwargs: Any,
    ) -> None:  # fmt: skip
        super().__init__(name, **kwargs)
        self.controllers = dict.fromkeys(active, True) | dict.fromkeys(inactive, False)
        self.requests: list[Request] = []
        self.refuse = False
        self.hang = False
        self._held: list[Future[Any]] = []
        self.create_service(SwitchController, "~/switch_controller", self._on_switch)

    def active(self) -> set[str]:
        """The active controllers."""
        return {c for c, on in self.controllers.items() if on}

    def release(self) -> None:
        """Drop the held calls: they switch nothing (their late answers say so)."""
        held, self._held = self._held, []
        for f in held:
            f.set_result("dropped")

    async def _on_switch(self, req: Any, resp: Any) -> Any:
        timeout_s = req.timeout.sec + req.timeout.nanosec * 1e-9
        self.requests.append(
            Request(
                tuple(req.activate_controllers),
                tuple(req.deactivate_controllers),
                int(req.strictness),
                timeout_s,
            )
        )
        if self.hang:
            hold: Future[Any] = Future()
            self._held.append(hold)
            if await hold == "dropped":
                resp.ok, resp.message = False, "dropped unanswered (test)"
                return resp
        if self.refuse:
            resp.ok, resp.message = False, "refused (test)"
            return resp
        resp.ok, resp.message = self.switch(
            tuple(req.activate_controllers), tuple(req.deactivate_controllers), req.strictness
        )
        return resp

    def switch(
        self, activate: tuple[str, ...], deactivate: tuple[str, ...], strictness: int
    ) -> tuple[bool, str]:
        """Upstream's decision on one switch; applies it and returns (ok, message)."""
        R = SwitchController.Request
        if strictness not in (R.STRICT, R.BEST_EFFORT):
            return False, f"strictness {strictness} not supported by the fake"
        known = self.controllers
        conflicts: list[str] = []
        off = []
        for c in deactivate:
            if c not in known:
                conflicts.append(f"could not deactivate unknown controller {c!r}")
            elif not known[c]:
                conflicts.append(f"could not deactivate {c!r}: not active")
            else:
                off.append(c)
        on = []
        for c in activate:
            if c not in known:
                conflicts.append(f"could not activate unknown controller {c!r}")
            elif known[c] and c not in deactivate:
                conflicts.append(f"could not activate {c!r}: already active")
            else:
                on.append(c)
        if conflicts and strictness == R.STRICT:
            return False, "; ".join(conflicts)
        if (activate and all(c not in known for c in activate)) or (
            deactivate and all(c not in known for c in deactivate)
        ):
            return False, "; ".join(conflicts)
        for c in off:
            known[c] = False
        for c in on:
            known[c] = True
        return True, "; ".join(conflicts)
