"""The supervisor's ros2_control switch against a fake controller manager, in-process.

The supervisor node, a fake controller manager (test/fake_controller_manager.py: upstream's
switch semantics on the vendored SwitchController interface) and a test node playing the
validator's topics and /clock run on one SingleThreadedExecutor. The reference for the calls
is the supervisor's own transition log and the fake's controllers: after each transition
exactly the new mode's controllers are active. Timeouts are wall clock (0.3 s here).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any, ClassVar

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from fake_controller_manager import FakeControllerManager
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger
from supervisor_harness import Harness

from twotank_validation.online.supervisor import Mode
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.params import ParameterError
from twotank_validation.ros.supervisor_node import SupervisorNode, main

NORMAL, FALLBACK = "pi_controller", "hold_controller"


class Rig(Harness):
    """The supervisor harness with a fake controller manager and the /diagnostics statuses."""

    DEFAULTS: ClassVar[dict[str, Any]] = {
        **Harness.DEFAULTS,
        "controller_manager": "/controller_manager",
        "normal_controllers": [NORMAL],
        "fallback_controllers": [FALLBACK],
        "switch_timeout_s": 0.3,
    }

    def add_nodes(self) -> list[Node]:
        self.cm = FakeControllerManager([NORMAL], [FALLBACK, "other"], context=self.ctx)
        self.diags: list[DiagnosticStatus] = []
        self.src.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)
        return [self.cm]

    def ready(self) -> bool:
        return (
            self.sup.switch.service != "/controller_manager/switch_controller"
            or self.sup.switch._client.service_is_ready()
        )

    def _on_diag(self, msg: DiagnosticArray) -> None:
        self.diags.extend(s for s in msg.status if s.name.endswith("supervisor"))

    def wait_switch(self, state: str) -> dict[str, str]:
        assert self.spin_until(lambda: self.sup.switch.machine.status.state.value == state), (
            self.sup.switch.machine.status
        )
        return self.state_values()

    def close(self) -> None:
        self.cm.release()
        self.cm.destroy_node()
        super().close()


@pytest.fixture
def rig(request):
    r = Rig(**getattr(request, "param", {}))
    yield r
    r.close()


def calls(r: Rig) -> list[tuple[tuple[str, ...], tuple[str, ...]]]:
    return [(q.activate, q.deactivate) for q in r.cm.requests]


TO_SAFE = ((FALLBACK,), (NORMAL,))
TO_NORMAL = ((NORMAL,), (FALLBACK,))


def test_alarm_switches_to_the_fallback_and_hysteresis_back(rig) -> None:
    r = rig
    r.window(100.0, False)
    r.window(105.0, False)
    assert r.cm.requests == []  # the stack starts in normal: no call
    r.window(110.0, True)
    assert r.spin_until(lambda: r.modes[-1:] == ["safe"])
    v = r.wait_switch("in_place")
    assert calls(r) == [TO_SAFE]
    assert r.cm.active() == {FALLBACK}
    req = r.cm.requests[0]
    assert (req.strictness, req.timeout_s) == (2, pytest.approx(0.3))  # STRICT, the timeout
    assert (v["switch_wanted"], v["switch_applied"], v["switch_calls"]) == ("safe", "safe", "1")
    for t in (115.0, 120.0, 124.0):  # good from 115 s: not yet 10 s
        r.window(t, False)
    assert r.sup.machine.mode is Mode.SAFE
    assert len(r.cm.requests) == 1
    r.window(125.0, False)  # 10 s and 2 judged reports: back to normal, the reverse switch
    assert r.spin_until(lambda: r.modes[-1:] == ["normal"])
    r.wait_switch("in_place")
    assert calls(r) == [TO_SAFE, TO_NORMAL]
    assert r.cm.active() == {NORMAL}
    assert [tr.to_mode for tr in r.sup.machine.log] == [Mode.SAFE, Mode.NORMAL]
    r.clock_to(130.0)  # checks while in place make no call
    assert len(r.cm.requests) == 2


@pytest.mark.parametrize("rig", [{"latch": True}], indirect=True)
def test_latch_holds_the_fallback_until_reset(rig) -> None:
    r = rig
    r.window(100.0, False)
    r.window(105.0, True)
    r.wait_switch("in_place")
    assert r.cm.active() == {FALLBACK}
    for t in range(110, 140, 5):
        r.window(float(t), False)
    assert r.sup.machine.mode is Mode.SAFE  # good for 25 s, but latched
    assert calls(r) == [TO_SAFE]
    client = r.src.create_client(Trigger, "supervisor/reset")
    assert client.wait_for_service(timeout_sec=5.0)
    future = client.call_async(Trigger.Request())
    assert r.spin_until(future.done)
    assert future.result().success  # the hysteresis is met: back to normal at the reset
    assert r.spin_until(lambda: r.modes[-1:] == ["normal"])
    r.wait_switch("in_place")
    assert calls(r) == [TO_SAFE, TO_NORMAL]
    assert r.cm.active() == {NORMAL}


def test_a_refused_switch_is_a_published_fault_and_retried_at_each_check(rig) -> None:
    r = rig
    r.window(100.0, False)
    r.cm.refuse = True
    r.window(105.0, True)
    v = r.wait_switch("refused")
    assert r.states[-1].level == DiagnosticStatus.ERROR  # safe anyway
    assert (v["switch"], v["switch_last_fault"], v["switch_message"]) == (
        "refused", "refused", "refused (test)",
    )  # fmt: skip
    assert (v["switch_attempt"], v["switch_failures"], v["switch_applied"]) == ("1", "1", "normal")
    r.clock_to(106.0)  # the next check: sent again, refused again
    assert r.spin_until(lambda: r.sup.switch.machine.status.failures == 2)
    assert calls(r) == [TO_SAFE, TO_SAFE]
    assert r.state_values()["switch_attempt"] == "2"
    # /diagnostics carries the same typed state (published at the check, before the retry)
    assert r.spin_until(lambda: any(_kv(s).get("switch") == "refused" for s in r.diags))
    failed = [s for s in r.diags if _kv(s).get("switch") == "refused"]
    assert all(s.level == DiagnosticStatus.ERROR for s in failed)  # safe anyway
    r.cm.refuse = False
    r.clock_to(107.0)
    v = r.wait_switch("in_place")
    assert calls(r) == [TO_SAFE] * 3
    assert r.cm.active() == {FALLBACK}
    assert (v["switch_failures"], v["switch_last_fault"]) == ("2", "refused")
    # a refused switch back in normal mode: the state is normal, its level WARN
    r.cm.refuse = True
    for t in (110.0, 115.0, 120.0):
        r.window(t, False)
    assert r.spin_until(lambda: r.modes[-1:] == ["normal"])
    v = r.wait_switch("refused")
    assert r.states[-1].level == DiagnosticStatus.WARN
    assert r.states[-1].message.endswith("; controller switch to normal refused (attempt 1)")
    assert (v["mode"], v["switch_wanted"], v["switch_applied"]) == ("normal", "normal", "safe")
    assert r.cm.active() == {FALLBACK}


def test_a_switch_without_answer_times_out_is_published_and_retried(rig) -> None:
    r = rig
    r.window(100.0, False)
    r.cm.hang = True
    t0 = time.monotonic()
    r.window(105.0, True)
    v = r.wait_switch("timed_out")
    assert time.monotonic() - t0 >= 0.3  # not before the timeout
    assert v["switch_message"] == "no answer within 0.3 s"
    assert r.cm.active() == {NORMAL}
    r.cm.release()  # the held call is dropped unanswered by the fake
    r.cm.hang = False
    r.clock_to(106.0)  # the next check sends it again
    r.wait_switch("in_place")
    assert calls(r) == [TO_SAFE, TO_SAFE]
    assert r.cm.active() == {FALLBACK}
    assert r.state_values()["switch_failures"] == "1"


@pytest.mark.parametrize("rig", [{"controller_manager": "/nobody"}], indirect=True)
def test_a_controller_manager_not_there_is_a_fault_retried(rig) -> None:
    r = rig
    r.window(100.0, True)
    v = r.wait_switch("unavailable")
    assert v["switch_message"] == "/nobody/switch_controller is not offered"
    r.clock_to(101.0)
    assert r.spin_until(lambda: r.sup.switch.machine.status.failures == 2)
    assert r.cm.requests == []


@pytest.mark.parametrize("rig", [{"controller_manager": ""}], indirect=True)
def test_switch_off_makes_no_call(rig) -> None:
    r = rig
    r.window(100.0, False)
    r.window(105.0, True)
    assert r.spin_until(lambda: r.modes[-1:] == ["safe"])
    r.clock_to(110.0)
    assert r.cm.requests == []
    assert r.sup.switch.service == ""
    assert not any(k.startswith("switch") for k in r.state_values())
    assert r.states[-1].level == DiagnosticStatus.ERROR


def _kv(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_without_the_interface_package_the_switch_names_what_to_install(
    monkeypatch, capsys
) -> None:
    for mod in ("controller_manager_msgs", "controller_manager_msgs.srv"):
        monkeypatch.setitem(sys.modules, mod, None)  # import fails as if not installed
    rc = main(["--ros-args", "-p", "controller_manager:=/cm", "-p", "normal_controllers:=[pi]"])
    err = capsys.readouterr().err.strip()
    assert rc == 1
    assert err.count("\n") == 0, err  # one line, no traceback
    assert "controller_manager_msgs is not installed" in err
    assert "ros-$ROS_DISTRO-controller-manager-msgs" in err
    # the switch off: the supervisor starts as before, the package never imported
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = bring_up(SupervisorNode(context=ctx))
        assert node.switch.service == ""
        node.destroy_node()
        with pytest.raises(ParameterError, match="controller_manager_msgs is not installed"):
            bring_up(
                SupervisorNode(
                    context=ctx,
                    parameter_overrides=[
                        Parameter("controller_manager", value="/cm"),
                        Parameter("fallback_controllers", value=["hold"]),
                    ],
                )
            )
    finally:
        rclpy.shutdown(context=ctx)


def _doc_cell(text: str):
    text = text.replace("`", "").strip()
    if text in ("true", "false"):
        return text == "true"
    if text.startswith("[") and text.endswith("]"):
        return [t.strip().strip('"') for t in text[1:-1].split(",")] if text != "[]" else []
    if text == '""':
        return ""
    try:
        return float(text)
    except ValueError:
        return text


def test_docs_list_the_supervisor_parameters_with_their_defaults_and_ranges() -> None:
    """docs/ros.md's supervisor table against SUPERVISOR_PARAMS (the switch's included)."""
    from twotank_validation.ros.supervisor_node import SUPERVISOR_PARAMS  # noqa: PLC0415

    text = (Path(__file__).resolve().parents[2] / "docs" / "ros.md").read_text()
    section = text.split("\n## Supervisor\n")[1].split("\n## ")[0]
    header = "| parameter | default | range | meaning |"
    rows = {}
    for line in section.split(header)[1].strip().splitlines()[1:]:
        if not line.startswith("|"):
            break
        name, default, rng, _ = (c.strip() for c in line.strip("|").split("|", 3))
        rows[name.strip("`")] = (default, rng)
    assert set(rows) == {p.name for p in SUPERVISOR_PARAMS}
    for p in SUPERVISOR_PARAMS:
        default, rng = rows[p.name]
        assert _doc_cell(default) == p.default, p.name
        if p.choices:
            assert sorted(c.strip() for c in rng.split(",")) == sorted(p.choices), p.name
        elif p.low is not None:
            low, high = (float(x) for x in rng.replace("–", " ").split())
            assert (low, high) == (p.low, p.high), p.name


def test_the_supervisor_reads_what_the_validator_publishes() -> None:
    """Each validation/ topic the supervisor subscribes to is one the validator publishes,
    with the same type (the node graph is the reference)."""
    from twotank_validation.ros.validator_node import ValidatorNode  # noqa: PLC0415

    ctx = Context()
    rclpy.init(context=ctx)
    try:
        ab = Parameter("models", value=["B"])
        val = bring_up(ValidatorNode(context=ctx, parameter_overrides=[ab]))
        # a name of its own: a supervisor of an earlier test, destroyed, may linger in the graph
        # under the default name until discovery drops it (seen under load)
        sup = bring_up(
            SupervisorNode(name="supervisor_graph_probe", context=ctx, parameter_overrides=[ab])
        )
        expected = {"/validation/B/invalidated", "/validation/B/report", "/validation/B/diagnosis"}
        subs: set[tuple[str, tuple[str, ...]]] = set()
        deadline = time.monotonic() + 10.0  # the graph cache fills asynchronously (under load)
        while time.monotonic() < deadline:
            subs = {
                (t, tuple(ty))
                for t, ty in val.get_subscriber_names_and_types_by_node(sup.get_name(), "/")
                if t.startswith("/validation/")
            }
            if {t for t, _ in subs} >= expected:
                break
            time.sleep(0.05)
        pubs = {
            (t, tuple(ty))
            for t, ty in val.get_publisher_names_and_types_by_node(val.get_name(), "/")
        }
        assert {t for t, _ in subs} == expected
        assert subs <= pubs, subs - pubs
        val.destroy_node()
        sup.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
