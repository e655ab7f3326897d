"""The controller switch's state machine (ROS-free), against the supervisor's transition log.

The reference is the supervisor's own log: every transition must give exactly one successful
switch to the new mode's controllers (SAFE: fallback on, normal off; NORMAL: the reverse),
in order, whatever the faults in between; a fault is retried only when the node asks again
(its next check), never dropped.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twotank_validation.online.controller_switch import (
    ControllerSwitch,
    Strictness,
    SwitchCall,
    SwitchConfig,
    SwitchState,
)
from twotank_validation.online.supervisor import (
    Invalidated,
    Mode,
    Report,
    Reset,
    Supervisor,
    SupervisorConfig,
    SupervisorError,
    Tick,
)

CFG = SwitchConfig("/cm", ("pi",), ("hold", "log"), Strictness.STRICT, 0.5)
TO_SAFE = (("hold", "log"), ("pi",))
TO_NORMAL = (("pi",), ("hold", "log"))


def lists(call: SwitchCall | None) -> tuple[tuple[str, ...], tuple[str, ...]] | None:
    return None if call is None else (call.activate, call.deactivate)


def test_settings_are_checked() -> None:
    assert not SwitchConfig().enabled  # off by default, with no controller named
    with pytest.raises(SupervisorError, match="no controller is named"):
        SwitchConfig("/cm")
    with pytest.raises(SupervisorError, match=r"\['pi'\] both"):
        SwitchConfig("/cm", ("pi",), ("pi",))
    with pytest.raises(SupervisorError, match="switch_timeout_s"):
        SwitchConfig("/cm", ("pi",), timeout_s=0.0)


def test_off_makes_no_call() -> None:
    sw = ControllerSwitch(SwitchConfig())
    sw.want(Mode.SAFE)
    assert sw.due() is None
    assert sw.status.state is SwitchState.OFF
    assert sw.status.calls == 0


def test_each_transition_of_the_supervisor_gives_one_switch_in_order() -> None:
    """Alarm, hysteresis back, alarm with latch, reset: the calls follow the log."""
    sup = Supervisor(SupervisorConfig(clear_after_s=10.0, clear_reports=2, latch=True))
    sw = ControllerSwitch(CFG)
    sent: list[SwitchCall] = []
    events = [(100.0, Report("B", 100.0)), (100.0, Invalidated("B", False))]
    events += [(105.0, Invalidated("B", True)), (106.0, Tick())]  # safe, latched
    events += [(t, Report("B", t)) for t in (110.0, 115.0, 120.0, 125.0)]
    events += [(126.0, Invalidated("B", False)), (130.0, Report("B", 130.0))]
    events += [(135.0, Report("B", 135.0)), (137.0, Tick()), (140.0, Reset())]  # reset: normal
    events += [(150.0, Invalidated("B", True)), (151.0, Reset())]  # safe; reset refused
    for t, ev in events:
        tr = sup.step(t, ev)
        if tr is not None:
            sw.want(tr.to_mode)
        call = sw.due()  # what the node does at a transition and at each check
        if call is not None:
            sent.append(call)
            sw.answered(call, True)
    assert [tr.to_mode for tr in sup.log] == [Mode.SAFE, Mode.NORMAL, Mode.SAFE]
    assert [c.target for c in sent] == [tr.to_mode for tr in sup.log]
    assert [lists(c) for c in sent] == [TO_SAFE, TO_NORMAL, TO_SAFE]
    assert sw.status.state is SwitchState.IN_PLACE
    assert sw.status.applied is Mode.SAFE


@pytest.mark.parametrize("fault", ["refused", "timed_out", "unavailable", "failed"])
def test_a_fault_is_kept_and_the_same_switch_sent_again_when_asked(fault: str) -> None:
    sw = ControllerSwitch(CFG)
    sw.want(Mode.SAFE)
    call = sw.due()
    assert call is not None
    assert (lists(call), call.attempt) == (TO_SAFE, 1)
    assert sw.due() is None  # one call at a time
    assert sw.status.state is SwitchState.PENDING
    if fault == "refused":
        sw.answered(call, False, "already active")
    elif fault == "timed_out":
        sw.timed_out(call)
    elif fault == "unavailable":
        sw.unavailable(call, "not offered")
    else:
        sw.failed(call, "boom")
    s = sw.status
    assert s.state is SwitchState(fault)
    assert s.state.fault
    assert (s.failures, s.last_fault, s.applied, s.pending) == (
        1,
        SwitchState(fault),
        Mode.NORMAL,
        None,
    )
    retry = sw.due()  # the next check
    assert retry is not None
    assert (lists(retry), retry.attempt) == (TO_SAFE, 2)
    sw.answered(call, True)  # a late answer to the call given up changes nothing
    assert (sw.status.state, sw.status.applied) == (SwitchState.PENDING, Mode.NORMAL)
    sw.answered(retry, True)
    assert (sw.status.state, sw.status.applied, sw.status.calls) == (
        SwitchState.IN_PLACE, Mode.SAFE, 2,
    )  # fmt: skip
    assert sw.status.last_fault is SwitchState(fault)  # kept for the record


def test_a_mode_change_while_a_call_is_on_its_way_is_switched_after_it() -> None:
    sw = ControllerSwitch(CFG)
    sw.want(Mode.SAFE)
    first = sw.due()
    sw.want(Mode.NORMAL)  # back before the answer
    assert sw.due() is None  # still one at a time
    assert first is not None
    sw.answered(first, True)
    assert (sw.status.state, sw.status.applied) == (SwitchState.PENDING, Mode.SAFE)
    back = sw.due()
    assert back is not None
    assert (lists(back), back.attempt) == (TO_NORMAL, 1)
    sw.answered(back, True)
    assert (sw.status.state, sw.status.applied) == (SwitchState.IN_PLACE, Mode.NORMAL)


def test_a_fault_then_a_return_to_the_applied_mode_needs_no_call() -> None:
    sw = ControllerSwitch(CFG)
    sw.want(Mode.SAFE)
    call = sw.due()
    assert call is not None
    sw.answered(call, False, "no")
    sw.want(Mode.NORMAL)  # the controllers never left normal
    assert sw.due() is None
    assert sw.status.state is SwitchState.IN_PLACE


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["bad", "good", "tick", "reset"]),
            st.sampled_from(["ok", "refused", "timed_out", "unavailable", "silent"]),
        ),
        max_size=60,
    ),
    st.booleans(),
)
def test_drawn_runs_follow_the_supervisor_and_never_drop_a_switch(steps, latch) -> None:
    """Drawn alarms, reports, resets and call outcomes; the supervisor's mode is the reference.

    At every step: at most one call on its way; a call sent targets the mode wanted when it is
    sent, which differs from the controllers known to run; the applied mode changes only by a
    successful call. At the end, checks with every call answered ok bring the controllers to
    the supervisor's mode.
    """
    sup = Supervisor(SupervisorConfig(clear_after_s=2.0, clear_reports=1, latch=latch))
    sw = ControllerSwitch(CFG)
    t = 100.0
    open_call: SwitchCall | None = None
    for what, outcome in steps:
        t += 1.0
        ev = {
            "bad": Invalidated("B", True),
            "good": Invalidated("B", False),
            "tick": Report("B", t),
            "reset": Reset(),
        }[what]
        for e in (Report("B", t), ev) if what == "good" else (ev,):
            tr = sup.step(t, e)
            if tr is not None:
                sw.want(tr.to_mode)
        assert sw.status.wanted is sup.mode
        applied = sw.status.applied
        call = sw.due()
        if call is not None:
            assert open_call is None  # one at a time
            assert call.target is sup.mode
            assert call.target is not applied
            assert lists(call) == (TO_SAFE if call.target is Mode.SAFE else TO_NORMAL)
            open_call = call
        if open_call is not None and outcome != "silent":
            before = sw.status.applied
            if outcome == "ok":
                sw.answered(open_call, True)
                assert sw.status.applied is open_call.target
            else:
                fault = {
                    "refused": lambda c: sw.answered(c, False, "no"),
                    "timed_out": sw.timed_out,
                    "unavailable": lambda c: sw.unavailable(c, "not offered"),
                }[outcome]
                fault(open_call)
                assert sw.status.applied is before
                assert sw.status.state.fault
            open_call = None
    if open_call is not None:
        sw.answered(open_call, True)
    for _ in range(3):  # the next checks, every call answered ok
        if (call := sw.due()) is not None:
            sw.answered(call, True)
    assert (sw.status.applied, sw.status.state) == (sup.mode, SwitchState.IN_PLACE)
