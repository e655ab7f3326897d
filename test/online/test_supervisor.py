"""The supervisor: its state machine against a reference re-statement of the rules, and the node.

The reference below recomputes every quantity from the event history (the last flag, the
newest report, the start of the good spell as the first event of the current run of events
without fault, the reports counted in that run) rather than updating it step by step; only
the mode and the latch are carried from event to event, as the documented rules require.
The node runs in-process with a SingleThreadedExecutor on a simulated /clock driven by the
test, which also plays the validator's topics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cache
from itertools import groupby

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.context import Context
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String
from supervisor_harness import Harness

from twotank_validation.online import streams as itf
from twotank_validation.online.supervisor import (
    Counters,
    Invalidated,
    Mode,
    Report,
    ReportRecord,
    Reset,
    Restart,
    Supervisor,
    SupervisorConfig,
    SupervisorError,
    Tick,
    false_transitions,
    replay,
    report_records,
)
from twotank_validation.ros import messages
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.params import LATCHED, ParameterError
from twotank_validation.ros.supervisor_node import SupervisorNode

# ------------------------------------------------------------------ the reference


def ref_faults(cfg, history, i, t):
    """Faults at event i (time t) from the history alone: [(kind, model, age)]."""
    restart = max((j for j in range(i + 1) if history[j][1][0] == "restart"), default=0)
    start = history[restart][0]
    out = []
    for m in cfg.watched:
        flags = [ev[2] for _, ev in history[: i + 1] if ev[0] == "flag" and ev[1] == m]
        if flags and flags[-1]:
            out.append(("invalidated", m, None))
        since = history[restart : i + 1]
        stamps = [ev[2] for _, ev in since if ev[0] == "report" and ev[1] == m]
        judged = [ev[2] for _, ev in since if ev[0] == "report" and ev[1] == m and ev[3]]
        if stamps:
            age = t - max(stamps)
            if age > cfg.stale_after_s:
                out.append(("stale", m, age))
            elif judged and t - max(judged) > cfg.unjudged_after_s:
                out.append(("unjudged", m, t - max(judged)))
            elif not judged and t - start > max(cfg.unjudged_after_s, cfg.startup_grace_s):
                out.append(("unjudged", m, t - start))
        elif t - start > cfg.startup_grace_s:
            out.append(("stale", m, t - start))
    return out


def ref_text(faults):
    text = {
        "invalidated": "invalidated: model {m}",
        "stale": "stale: no report from {m} for {a:.1f} s",
        "unjudged": "unjudged: no judged window of {m} for {a:.1f} s",
    }
    return "; ".join(text[k].format(m=m, a=a) for k, m, a in faults)


@dataclass
class RefRun:
    modes: list = field(default_factory=list)
    log: list = field(default_factory=list)
    counters: list = field(default_factory=list)


def reference(cfg, events):
    """Run the documented rules over [(t, event)]; events: ("flag", m, v), ("report", m, stamp,
    judged), ("reset",), ("tick",), ("restart",)."""
    mode, latched = "normal", False
    to_safe = to_normal = n_inv = n_stale = n_unj = acc = ref = 0
    faults_at = []
    run = RefRun()
    for i, (t, ev) in enumerate(events):
        faults = ref_faults(cfg, events, i, t)
        faults_at.append(bool(faults))
        # the good spell: the run of events without fault ending here, since the last restart
        restart = max((j for j in range(i + 1) if events[j][1][0] == "restart"), default=0)
        k = i
        while k > restart and not faults_at[k - 1]:
            k -= 1
        reset_ok = False
        if ev[0] == "reset":
            if faults:
                ref += 1
            else:
                acc += 1
                latched = False
                reset_ok = True
        if mode == "normal" and faults:
            mode, latched = "safe", cfg.latch
            to_safe += 1
            kinds = {f[0] for f in faults}
            n_inv += "invalidated" in kinds
            n_stale += "stale" in kinds
            n_unj += "unjudged" in kinds
            run.log.append((t, "normal", "safe", ref_text(faults)))
        elif mode == "safe" and not faults and not latched:
            since = events[k][0]
            reports = {
                m: sum(
                    1
                    for _, e in events[k : i + 1]
                    if e[0] == "report" and e[1] == m and e[3]  # judged reports only
                )
                for m in cfg.watched
            }
            if t - since >= cfg.clear_after_s and all(
                n >= cfg.clear_reports for n in reports.values()
            ):
                mode = "normal"
                to_normal += 1
                n = min(reports.values())
                run.log.append(
                    (
                        t,
                        "safe",
                        "normal",
                        ("reset and " if reset_ok else "")
                        + f"recovered: valid for {t - since:.1f} s and {n} report(s) of each "
                        "watched model",
                    )
                )
        run.modes.append(mode)
        run.counters.append((to_safe, to_normal, n_inv, n_stale, n_unj, acc, ref))
    return run


def to_event(ev):
    kind = ev[0]
    if kind == "flag":
        return Invalidated(ev[1], ev[2])
    if kind == "report":
        return Report(ev[1], ev[2], ev[3])
    return {"reset": Reset(), "tick": Tick(), "restart": Restart()}[kind]


def run_machine(cfg, events):
    sup = Supervisor(cfg)
    modes, counters = [], []
    for t, ev in events:
        sup.step(t, to_event(ev))
        modes.append(sup.mode.value)
        c = sup.counters
        counters.append(
            (
                c.to_safe,
                c.to_normal,
                c.invalidated,
                c.stale,
                c.unjudged,
                c.resets_accepted,
                c.resets_refused,
            )
        )
    log = [(tr.time_s, tr.from_mode.value, tr.to_mode.value, tr.reason) for tr in sup.log]
    return sup, modes, counters, log


# ------------------------------------------------------------------ exhaustive: hypothesis

configs = st.builds(
    SupervisorConfig,
    watched=st.sampled_from([("B",), ("A",), ("A", "B"), ("B", "A")]),
    clear_after_s=st.sampled_from([0.0, 3.0, 10.0]),
    clear_reports=st.integers(0, 3),
    latch=st.booleans(),
    stale_after_s=st.sampled_from([4.0, 15.0, 60.0]),
    startup_grace_s=st.sampled_from([0.0, 8.0, 30.0, 200.0]),
    unjudged_after_s=st.sampled_from([5.0, 25.0, 100.0, math.inf]),
)
# weighted draws: reports, flags and ticks often, resets now and then, restarts rarely
KINDS = ["report"] * 8 + ["flag"] * 4 + ["tick"] * 4 + ["reset"] * 2 + ["restart"]
raw_events = st.lists(
    st.tuples(
        st.sampled_from([0.0, 0.0, 0.5, 1.0, 1.0, 2.5, 2.5, 6.0, 20.0]),  # time step
        st.sampled_from(KINDS),
        st.sampled_from(["A", "B", "B", "C"]),  # C is never watched
        st.booleans(),  # a flag's value
        st.sampled_from([0.0, 0.5, 3.0, 9.0, -2.0]),  # a report's stamp: this much earlier
        st.sampled_from([True, True, True, False]),  # a report's window was judged
    ),
    min_size=15,
    max_size=80,
)


def timed(raw):
    """[(t, event)] with non-decreasing time, except that a restart may jump back."""
    t, out = 100.0, []
    for dt, kind, model, value, lag, judged in raw:
        t = max(0.0, t - 3 * dt) if kind == "restart" else t + dt
        if kind == "report":
            out.append((t, ("report", model, t - lag, judged)))
        elif kind == "flag":
            out.append((t, ("flag", model, value)))
        else:
            out.append((t, (kind,)))
    return out


@settings(max_examples=300)
@given(cfg=configs, raw=raw_events)
def test_state_machine_equals_reference_on_drawn_sequences(cfg, raw) -> None:
    events = timed(raw)
    sup, modes, counters, log = run_machine(cfg, events)
    ref = reference(cfg, events)
    assert modes == ref.modes
    assert counters == ref.counters
    assert log == ref.log
    assert sup.counters.transitions == len(sup.log)


# ------------------------------------------------------------------ hand-written cases


def test_hysteresis_time_and_reports() -> None:
    cfg = SupervisorConfig(clear_after_s=10.0, clear_reports=2, stale_after_s=100.0)
    sup = Supervisor(cfg)
    sup.step(0.0, Report("B", 0.0))
    sup.step(5.0, Invalidated("B", True))
    assert sup.mode is Mode.SAFE
    assert sup.log[-1].reason == "invalidated: model B"
    sup.step(6.0, Invalidated("B", False))  # good from 6 s
    sup.step(7.0, Report("B", 7.0))
    sup.step(12.0, Report("B", 12.0))  # 2 reports, but only 6 s
    sup.step(15.9, Tick())
    assert sup.mode is Mode.SAFE
    sup.step(16.0, Tick())  # 10 s and 2 reports
    assert sup.mode is Mode.NORMAL
    assert sup.log[-1].time_s == 16.0
    # a blip breaks the spell: time and reports count again from its end
    sup.step(20.0, Invalidated("B", True))
    sup.step(21.0, Invalidated("B", False))
    sup.step(25.0, Report("B", 25.0))
    sup.step(31.0, Tick())  # 10 s but one report
    assert sup.mode is Mode.SAFE
    sup.step(32.0, Report("B", 32.0))
    assert sup.mode is Mode.NORMAL
    assert sup.counters == Counters(to_safe=2, to_normal=2, invalidated=2)
    assert [tr.to_mode for tr in sup.log] == [Mode.SAFE, Mode.NORMAL] * 2


def test_unjudged_reports_keep_the_validator_alive_but_do_not_clear_safe() -> None:
    """A window the validator could not judge (e.g. the valves held in safe mode spoil the
    windows) is no evidence that the model holds: SAFE stays until judged valid reports come."""
    cfg = SupervisorConfig(clear_after_s=10.0, clear_reports=2, stale_after_s=30.0)
    sup = Supervisor(cfg)
    sup.step(0.0, Report("B", 0.0))
    sup.step(1.0, Invalidated("B", True))
    sup.step(2.0, Invalidated("B", False))
    for t in range(5, 100, 5):  # unjudged reports only: alive (not stale), not cleared
        sup.step(float(t), Report("B", float(t), judged=False))
        sup.step(float(t), Tick())
    assert sup.mode is Mode.SAFE
    assert not sup.state.faults
    sup.step(100.0, Report("B", 100.0))
    assert sup.mode is Mode.SAFE  # one judged report of the two needed
    sup.step(105.0, Report("B", 105.0))
    assert sup.mode is Mode.NORMAL
    assert "2 report(s)" in sup.log[-1].reason


def test_a_validator_that_reports_but_judges_nothing_switches_to_safe() -> None:
    """Alive but blind (e.g. a valve at its limit leaves no excitation): after
    unjudged_after_s without a judged window the model is not being checked."""
    cfg = SupervisorConfig(stale_after_s=30.0, unjudged_after_s=100.0, startup_grace_s=50.0)
    sup = Supervisor(cfg)
    sup.step(0.0, Report("B", 0.0))
    for t in range(10, 101, 10):
        sup.step(float(t), Report("B", float(t), judged=False))
    assert sup.mode is Mode.NORMAL  # 100 s without a judged window: not more than the limit
    sup.step(110.0, Report("B", 110.0, judged=False))
    assert sup.mode is Mode.SAFE
    assert sup.log[-1].reason == "unjudged: no judged window of B for 110.0 s"
    assert sup.counters.unjudged == 1
    # judged windows again, and valid: back to normal after the hysteresis
    for t in range(120, 400, 50):
        sup.step(float(t), Report("B", float(t)))
    assert sup.mode is Mode.NORMAL
    # never judged from the start: the startup grace applies if it is longer
    late = Supervisor(SupervisorConfig(unjudged_after_s=10.0, startup_grace_s=60.0))
    for t in range(0, 61, 5):
        late.step(float(t), Report("B", float(t), judged=False))
    assert late.mode is Mode.NORMAL
    late.step(61.0, Report("B", 61.0, judged=False))
    assert late.mode is Mode.SAFE


def test_latch_holds_until_an_accepted_reset() -> None:
    cfg = SupervisorConfig(latch=True, clear_after_s=5.0, clear_reports=1, stale_after_s=100.0)
    sup = Supervisor(cfg)
    sup.step(0.0, Invalidated("B", True))
    assert sup.mode is Mode.SAFE
    assert sup.state.latched
    ok, answer = sup.reset(1.0)  # the fault is still there: refused
    assert not ok
    assert answer == "refused: invalidated: model B"
    sup.step(2.0, Invalidated("B", False))
    for t in range(3, 60, 5):
        sup.step(float(t), Report("B", float(t)))
    assert sup.mode is Mode.SAFE  # valid for 55 s, but latched
    ok, answer = sup.reset(60.0)
    assert ok
    assert sup.mode is Mode.NORMAL
    assert sup.log[-1].time_s == 60.0
    assert sup.log[-1].reason.startswith("reset and recovered: valid for 58.0 s")
    assert answer.startswith("latch cleared; normal: reset and recovered")
    # a reset accepted before the hysteresis is satisfied: the latch goes, the hysteresis stays
    sup.step(70.0, Invalidated("B", True))
    sup.step(71.0, Invalidated("B", False))
    ok, _ = sup.reset(72.0)
    assert ok
    assert sup.mode is Mode.SAFE
    assert not sup.state.latched
    sup.step(74.0, Report("B", 74.0))
    assert sup.mode is Mode.SAFE  # 3 s
    sup.step(76.0, Tick())
    assert sup.mode is Mode.NORMAL  # 5 s and a report, no second reset needed
    assert sup.counters.resets_accepted == 2
    assert sup.counters.resets_refused == 1


def test_stale_validator_switches_to_safe_and_recovers_when_reports_resume() -> None:
    cfg = SupervisorConfig(clear_after_s=10.0, clear_reports=2, stale_after_s=30.0)
    sup = Supervisor(cfg)
    for t in range(0, 151, 5):
        sup.step(float(t), Report("B", float(t) - 1.0))  # each window ended 1 s before
        sup.step(float(t), Invalidated("B", False))
    for t in range(151, 182):
        sup.step(float(t), Tick())
        if t <= 179:  # newest stamp 149: 30 s old at 179, not more
            assert sup.mode is Mode.NORMAL, t
    assert sup.mode is Mode.SAFE
    assert sup.log[-1].time_s == 180.0
    assert sup.log[-1].reason == "stale: no report from B for 31.0 s"
    assert sup.counters.stale == 1
    assert sup.counters.invalidated == 0
    sup.step(200.0, Report("B", 199.0))  # reports resume: this one counts
    sup.step(205.0, Report("B", 204.0))
    sup.step(209.0, Tick())
    assert sup.mode is Mode.SAFE
    sup.step(210.0, Tick())
    assert sup.mode is Mode.NORMAL
    assert sup.log[-1].reason == "recovered: valid for 10.0 s and 2 report(s) of each watched model"


def test_startup_grace_and_unwatched_models() -> None:
    cfg = SupervisorConfig(watched=("A", "B"), startup_grace_s=50.0, stale_after_s=20.0)
    sup = Supervisor(cfg)
    sup.step(10.0, Tick())  # the start
    sup.step(30.0, Report("A", 30.0))
    sup.step(40.0, Invalidated("C", True))  # not watched
    sup.step(45.0, Report("C", 45.0))
    sup.step(50.0, Report("A", 50.0))
    sup.step(60.0, Tick())
    assert sup.mode is Mode.NORMAL  # B silent for 50 s since the start: not more
    sup.step(61.0, Tick())
    assert sup.mode is Mode.SAFE
    assert sup.log[-1].reason == "stale: no report from B for 51.0 s"


def test_time_goes_back_only_through_a_restart() -> None:
    cfg = SupervisorConfig(stale_after_s=10.0, startup_grace_s=20.0)
    sup = Supervisor(cfg)
    sup.step(100.0, Report("B", 100.0))
    sup.step(101.0, Invalidated("B", True))
    with pytest.raises(SupervisorError, match="time went back"):
        sup.step(99.0, Tick())
    with pytest.raises(SupervisorError, match="finite"):
        sup.step(math.nan, Tick())
    sup.step(5.0, Restart())
    assert sup.mode is Mode.SAFE  # the mode and the flags stay
    assert sup.state.invalidated == frozenset({"B"})
    assert sup.state.last_report_s == {}  # the report times go, the grace runs from 5 s
    assert sup.state.start_s == 5.0
    sup.step(6.0, Invalidated("B", False))
    sup.step(25.0, Tick())  # no report since the restart, 20 s: not more than the grace
    assert sup.state.faults == ()
    sup.step(25.5, Tick())
    assert sup.state.faults == (("stale", "B"),)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"watched": ()}, "at least one model"),
        ({"watched": ("B", "B")}, "twice"),
        ({"clear_after_s": -1.0}, "clear_after_s"),
        ({"stale_after_s": 0.0}, "stale_after_s"),
        ({"startup_grace_s": math.inf}, "startup_grace_s"),
        ({"clear_reports": -1}, "clear_reports"),
    ],
)
def test_bad_settings_name_the_setting(kwargs, match) -> None:
    with pytest.raises(SupervisorError, match=match):
        SupervisorConfig(**kwargs)


# ------------------------------------------------------------------ false transitions

HOP_S = 51.2  # the default report interval: a window every quarter of a 204.8 s period


def nominal_records(hours: float, hop_s: float = HOP_S, t0: float = 600.0):
    n = int(hours * 3600 / hop_s)
    return [ReportRecord(t0 + k * hop_s, "B", False) for k in range(n)]


def test_false_transitions_count_injected_spurious_alarms_and_silences() -> None:
    cfg = SupervisorConfig()  # the defaults: stale after 180 s, back after 204.8 s
    clean = nominal_records(24.0)
    res = false_transitions(clean, cfg, tick_s=5.0)
    assert res.count == 0
    assert res.transitions == ()
    assert res.duration_s == pytest.approx(clean[-1].stamp_s - clean[0].stamp_s)
    # injected: two one-window false alarms and one 400 s silence of the validator
    spurious = {100, 900}
    records = [
        ReportRecord(r.stamp_s, r.model, k in spurious)
        for k, r in enumerate(clean)
        if not 1200 <= k < 1208  # 8 reports missing: 460.8 s without a report
    ]
    res = false_transitions(records, cfg, tick_s=5.0)
    assert len(res.false_safe) == 3
    assert [tr.time_s for tr in res.false_safe][:2] == [clean[100].stamp_s, clean[900].stamp_s]
    assert res.false_safe[2].reason.startswith("stale: no report from B")
    assert clean[1199].stamp_s + 180.0 < res.false_safe[2].time_s <= clean[1199].stamp_s + 185.0
    assert res.false_normal == ()
    assert res.per_24h == pytest.approx(3 * 86400.0 / res.duration_s)
    # the same alarms inside a declared fault interval (the first) are not false
    t1 = clean[100].stamp_s
    res = false_transitions(records, cfg, [(t1 - 10.0, t1)], tick_s=5.0)
    assert len(res.false_safe) == 2
    # and a recovery while a fault is declared active is a false return to normal
    res = false_transitions(records, cfg, [(t1 - 10.0, t1 + 1000.0)], tick_s=5.0)
    assert len(res.false_normal) == 1


def test_false_transitions_settings_are_checked() -> None:
    with pytest.raises(SupervisorError, match="lag_s"):
        false_transitions([], SupervisorConfig(), lag_s=-1.0)
    with pytest.raises(SupervisorError, match="ends before"):
        false_transitions([], SupervisorConfig(), [(10.0, 5.0)])
    with pytest.raises(SupervisorError, match="tick_s"):
        replay([], SupervisorConfig(), tick_s=0.0)


@cache
def rig_reports():
    """The validator's reports on the nominal rig (ts 0.8 s, period 256, a window every 64)."""
    from tools.streamfuzz import clean_record as rig_record  # noqa: PLC0415 (same rig data)
    from twotank_validation.core.model import load_model  # noqa: PLC0415
    from twotank_validation.online import MonitorConfig, monitor_record  # noqa: PLC0415

    stamps, u, y = rig_record(12)
    cfg = MonitorConfig(ts_s=0.8, period_samples=256, hop_samples=64)
    return monitor_record(stamps, u, y, cfg, [load_model("A"), load_model("B")])


def test_nominal_rig_reports_give_no_false_transition() -> None:
    """Model B on the nominal rig: no transition; Model A (wrong) trips at its first ERROR."""
    records = report_records(rig_reports())
    hop_s = 64 * 0.8
    b = [r for r in records if r.model == "B"]
    assert len(b) >= 30
    cfg = SupervisorConfig(
        watched=("B",), stale_after_s=3 * hop_s, clear_after_s=204.8, startup_grace_s=900.0
    )
    res = false_transitions(records, cfg)
    assert res.count == 0
    assert res.transitions == ()
    # the same function sees Model A's alarm: one switch, at A's first ERROR report
    res_a = false_transitions(records, SupervisorConfig(watched=("A",), stale_after_s=3 * hop_s))
    first_error = next(r.stamp_s for r in records if r.model == "A" and r.invalidated)
    assert [tr.time_s for tr in res_a.false_safe] == [first_error]
    assert res_a.false_safe[0].reason == "invalidated: model A"


# ------------------------------------------------------------------ the node


@pytest.fixture
def harness(request):
    h = Harness(**getattr(request, "param", {}))
    yield h
    h.close()


def test_node_switches_on_invalidated_and_back_after_hysteresis(harness) -> None:
    h = harness
    h.flag(False)  # the validator's initial latched value
    for t in range(100, 120, 5):
        h.window(float(t), False)
    h.window(120.0, True)
    assert h.spin_until(lambda: h.modes[-1:] == ["safe"])
    v = h.state_values()
    assert h.states[-1].level == DiagnosticStatus.ERROR
    assert v["mode"] == "safe"
    assert v["reason"] == "invalidated: model B"
    assert v["transitions"] == "1"
    assert v["to_safe_invalidated"] == "1"
    assert v["last_transition_s"] == "120.000"
    h.window(125.0, False)  # good from 125 s (the report came while still invalidated)
    h.window(130.0, False)
    h.clock_to(134.0)
    assert h.sup.machine.mode is Mode.SAFE
    h.window(135.0, False)  # 10 s and 2 reports
    assert h.spin_until(lambda: h.modes[-1:] == ["normal"])
    h.sync()
    assert h.modes == ["normal", "safe", "normal"]
    v = h.state_values()
    assert h.states[-1].level == DiagnosticStatus.OK
    assert v["transitions"] == "2"
    assert v["to_normal"] == "1"
    assert v["last_transition_s"] == "135.000"
    log = h.sup.machine.log
    assert [(tr.time_s, tr.to_mode) for tr in log] == [(120.0, Mode.SAFE), (135.0, Mode.NORMAL)]
    # each transition was published on supervisor/state: the states seen carry 1 then 2
    counts = [{kv.key: kv.value for kv in s.values}["transitions"] for s in h.states]
    assert [k for k, _ in groupby(counts)] == ["0", "1", "2"]
    # the validator's diagnosis (what its node publishes): its summary carried in the state,
    # nothing else changes
    d = messages.diagnosis_class()(model="B", kind="leak", summary="leak: 0.04")
    h.pub_diagnosis.publish(d)
    assert h.spin_until(lambda: h.state_values().get("diagnosis/B") == "leak: 0.04")
    assert h.sup.machine.mode is Mode.NORMAL


@pytest.mark.parametrize("harness", [{"latch": True}], indirect=True)
def test_node_latch_holds_until_the_reset_service(harness) -> None:
    h = harness
    h.flag(False)
    h.window(100.0, False)
    h.window(105.0, True)
    assert h.spin_until(lambda: h.modes[-1:] == ["safe"])
    h.clock_to(106.0)
    resp = h.call_reset()  # still invalidated: refused
    assert not resp.success
    assert resp.message == "refused: invalidated: model B"
    for t in range(110, 160, 5):
        h.window(float(t), False)
    h.sync()
    assert h.modes == ["normal", "safe"]  # good for 45 s, but latched
    assert h.state_values()["latched"] == "true"
    resp = h.call_reset()
    assert resp.success
    assert "reset and recovered" in resp.message
    assert h.spin_until(lambda: h.modes[-1:] == ["normal"])
    v = h.state_values()
    assert v["resets_refused"] == "1"
    assert v["resets_accepted"] == "1"
    assert v["transitions"] == "2"
    assert h.sup.machine.log[-1].time_s == 155.0


def test_node_stale_rule_triggers_when_reports_stop(harness) -> None:
    h = harness
    h.flag(False)
    for t in range(100, 151, 5):
        h.window(float(t), False)
    h.clock_to(179.0)  # newest stamp 149.5: 29.5 s old
    assert h.sup.machine.mode is Mode.NORMAL
    h.clock_to(180.0)  # 30.5 s: more than stale_after_s
    assert h.spin_until(lambda: h.modes[-1:] == ["safe"])
    v = h.state_values()
    assert v["reason"] == "stale: no report from B for 30.5 s"
    assert v["to_safe_stale"] == "1"
    # a late subscriber gets the current mode (transient-local)
    late: list[str] = []
    h.src.create_subscription(String, "control/mode", lambda m: late.append(m.data), LATCHED)
    assert h.spin_until(lambda: late == ["safe"])
    # reports resume: back after 10 s and 2 reports
    h.window(200.0, False)
    h.window(205.0, False)
    h.clock_to(209.0)
    assert h.sup.machine.mode is Mode.SAFE
    h.clock_to(210.0)
    assert h.spin_until(lambda: h.modes[-1:] == ["normal"])
    assert h.sup.machine.log[-1].time_s == 210.0
    assert h.sup.machine.counters == Counters(to_safe=1, to_normal=1, stale=1)


def test_node_restarts_its_timing_when_the_clock_jumps_back(harness) -> None:
    h = harness
    h.flag(False)
    for t in range(100, 141, 5):
        h.window(float(t), True)  # invalidated: safe
    assert h.sup.machine.mode is Mode.SAFE
    msg = Clock()
    itf.set_stamp(msg.clock, 20_000_000_000)  # the simulation restarted: 20 s
    h.pub_clock.publish(msg)
    assert h.spin_until(lambda: h.sup.machine.state.start_s == 20.0)
    assert h.sup.machine.state.last_report_s == {}
    assert h.sup.machine.mode is Mode.SAFE  # the mode stays; time runs on from 20 s
    h.t = 20.0
    h.window(25.0, False)
    h.window(30.0, False)
    h.clock_to(34.0)  # the timer still ticks after the jump
    assert h.sup.machine.state.now_s == 34.0
    h.window(35.0, False)  # 10 s and 2 reports since the flag fell at 25 s
    assert h.spin_until(lambda: h.modes[-1:] == ["normal"])
    assert h.sup.machine.log[-1].time_s == 35.0


def test_node_refuses_invalid_parameters() -> None:
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        with pytest.raises(ParameterError, match="twice"):
            bring_up(
                SupervisorNode(
                    context=ctx, parameter_overrides=[Parameter("models", value=["B", "B"])]
                )
            )
        with pytest.raises(ParameterError, match="stale_after_s"):
            bring_up(
                SupervisorNode(
                    context=ctx, parameter_overrides=[Parameter("stale_after_s", value=0.0)]
                )
            )
    finally:
        rclpy.shutdown(context=ctx)
