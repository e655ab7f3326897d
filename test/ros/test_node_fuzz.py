"""Hostile input through the validator NODE (rclpy, real topics, simulated clock).

A short bounded version of ``bench/fuzz_node.py`` (:mod:`tools.nodefuzz`):
seeded random hostile stretches, the node-only kinds (``/clock`` jumping back, a wrong-type
publisher from another participant) explicitly, and the regression the fuzzing found. The
references are the injected stretch's own steps and stamps (``nodefuzz.check``).
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from tools import nodefuzz
from twotank_validation.online import Alarm


def _assert_clean(res: nodefuzz.RunResult) -> None:
    assert res.violations == [], (res.seed, res.plan.kinds, res.violations)


@settings(max_examples=1, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_random_hostile_stretches_never_kill_or_fool_the_node(seed):
    _assert_clean(nodefuzz.run(seed))


def test_clock_restart_and_wrong_type_publisher():
    """/clock and stamps jump back (restart), a rogue participant sends the wrong type."""
    res = nodefuzz.run(7, ["clock_back", "wrong_type", "nan"])
    p = res.plan
    assert p.shift_ns < 0
    assert p.rogue_type
    _assert_clean(res)
    g = p.garbage_steps()
    # the checks had something to bite on: windows were judged before and after the stretch
    judged = [(s, m) for s, m in res.outputs.reports if m.judged and m.model == "B"]
    assert any(s < g[0] for s, _ in judged)
    assert any(s > g[-1] for s, _ in judged)
    assert any(f"type {p.rogue_type}" in text for _, _, _, text in res.outputs.statuses)


def test_status_turns_stale_as_soon_as_garbage_arrives():
    """Regression: NaN input left the status OK until the next window boundary (up to a
    period, 204.8 s here): the status reported the last window only."""
    p = nodefuzz.plan(3, ["nan"])
    g0 = p.garbage_steps()[0]
    assert g0 % nodefuzz.PERIOD > 20  # a boundary is far: the old node said OK meanwhile
    p.steps = p.steps[: g0 + 24]
    res = nodefuzz.run(3, the_plan=p, checked=False)
    assert res.worker_alive
    b = [(s, lv, text) for s, m, lv, text in res.outputs.statuses if m == "B"]
    before = [lv for s, lv, _ in b if g0 - 2 <= s < g0]  # strict lockstep there
    assert before
    assert set(before) == {Alarm.OK}  # a judged nominal window before the NaN
    during = [
        (lv, text) for s, lv, text in b if g0 + nodefuzz.STATUS_MARGIN_STEPS <= s < len(p.steps)
    ]
    assert during
    assert all(lv == Alarm.STALE for lv, _ in during), during
    assert any("non-finite" in text for _, text in during)


def test_status_stays_stale_after_a_command_stream_came_back():
    """Regression: flow_cmd replaced by a wrong-type publisher (commands held, no gap flagged):
    once the rogue left, the status said OK again until the next window boundary."""
    p = nodefuzz.plan(1051)  # found by bench/fuzz_node.py --seed 1000
    g = p.garbage_steps()
    assert p.kinds == ["wrong_type"]
    assert p.steps[g[0]].rogue == ["flow_cmd"]
    # all inside the period after the first judged window, the next boundary 40+ steps on
    assert 3 * nodefuzz.PERIOD <= g[0] <= g[-1] < 4 * nodefuzz.PERIOD - 40
    p.steps = p.steps[: g[-1] + 40]
    res = nodefuzz.run(1051, the_plan=p, checked=False)
    after = [(lv, text) for s, _, lv, text in res.outputs.statuses if s > g[-1]]
    assert after
    assert all(lv == Alarm.STALE for lv, _ in after), after
    assert any("stopped streams" in text for _, text in after)


def test_each_status_message_speaks_of_one_window():
    """Regression: /diagnostics went out after each model's report, so the first carried the
    other models' previous window (e.g. B still OK while its new window was not judged)."""
    p = nodefuzz.plan(5, ["duplicate"])
    p.steps = p.steps[: 3 * nodefuzz.PERIOD + 10]  # boundaries at 2 and 3 periods
    res = nodefuzz.run(5, the_plan=p, checked=False)
    both = [ends for _, ends in res.outputs.diag_windows if len(ends) == 2]
    assert len({ends[0] for ends in both}) >= 2  # both windows were seen
    assert all(ends[0] == ends[1] for ends in both), both


def test_status_turns_stale_when_only_old_stamps_arrive():
    """Regression: a stretch of messages stamped in the past (each dropped as out of order)
    completes no sample and flags no gap until fresh data return; the status said OK."""
    p = nodefuzz.plan(2001)  # found by bench/fuzz_node.py --seed 2000
    assert p.kinds == ["backwards"]
    g0 = p.garbage_steps()[0]
    assert g0 % nodefuzz.PERIOD < nodefuzz.PERIOD - 30  # no window boundary soon after
    p.steps = p.steps[: g0 + 20]
    res = nodefuzz.run(2001, the_plan=p, checked=False)
    during = [
        (lv, text)
        for s, _, lv, text in res.outputs.statuses
        if g0 + nodefuzz.STATUS_MARGIN_STEPS <= s < len(p.steps)
    ]
    assert during
    assert all(lv == Alarm.STALE for lv, _ in during), during
    assert any("stale or out-of-order stamps" in text for _, text in during)
