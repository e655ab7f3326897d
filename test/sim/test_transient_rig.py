"""The transient term on the simulated rig in closed loop (docs/theory.md §20, issue 32).

References: the injected fault's onset and the scenario's setpoint change (the simulator's
own record of when they happen), and the same recording through the closed-loop gate
without the transient term (``CLOSED_LOOP_INPUT_PERIODIC_RTOL``).
"""

from __future__ import annotations

import pytest

from tools.events import record_events
from twotank_validation.core.model import load_model
from twotank_validation.online import Alarm, MonitorConfig, OnlineValidator
from twotank_validation.sim.control import CLOSED_LOOP_INPUT_PERIODIC_RTOL
from twotank_validation.sim.scenario import ClosedLoop, Scenario, simulate_scenario

PERIOD, TS = 2048, 0.1
PERIOD_NS = round(PERIOD * TS * 1e9)
ONSET_S = round(4.3 * PERIOD) * TS
ONSET_NS = round(ONSET_S * 1e9)
TRANSIENT = MonitorConfig(transient="local_polynomial", settle_periods=0)
GATE = MonitorConfig(input_periodic_rtol=CLOSED_LOOP_INPUT_PERIODIC_RTOL)


def _reports(scenario: Scenario, config: MonitorConfig) -> list:
    stamps, commands, measured = simulate_scenario(scenario)
    validator = OnlineValidator(config, [load_model("B")])
    return validator.feed_many(*record_events(stamps, commands, measured))


def _spanning(reports: list) -> list:
    """The reports of the windows that hold the onset (or the setpoint change)."""
    return [r for r in reports if r.start_ns <= ONSET_NS < r.end_ns]


@pytest.mark.parametrize("fault", ["sensor_bias:height=0.05", "leak=0.06"])
def test_a_fault_starting_inside_a_window_is_still_detected(fault: str) -> None:
    """A sensor's step is not smooth in frequency and a leak is no initial condition: the
    transient term absorbs neither, so the windows spanning the onset invalidate and ERROR
    comes within 1.5 periods (the closed-loop gate alone: 3 periods and more)."""
    scenario = Scenario(
        name="f", duration_s=7 * PERIOD * TS, seed=3, faults=(f"{fault}@{ONSET_S:g}",),
        closed_loop=ClosedLoop(),
    )  # fmt: skip
    reports = _reports(scenario, TRANSIENT)
    before = [r for r in reports if r.end_ns < ONSET_NS]
    assert all(r.judged for r in before[4:])  # the loop's start-up is judged too
    assert not any(r.invalidated for r in before)
    assert any(r.judged and r.beta > 1.0 for r in _spanning(reports))
    first = next(r for r in reports if r.alarm is Alarm.ERROR)
    assert first.end_ns - ONSET_NS <= 1.5 * PERIOD_NS
    assert first.raised_by == "dynamics"


def test_a_setpoint_change_in_closed_loop_raises_nothing_with_the_transient_term() -> None:
    scenario = Scenario(
        name="sp", duration_s=8 * PERIOD * TS, seed=5, closed_loop=ClosedLoop(),
        setpoints=(f"height=0.52@{ONSET_S:g}",),
    )  # fmt: skip
    reports = _reports(scenario, TRANSIENT)
    spanning = _spanning(reports)
    assert len(spanning) >= 4
    assert all(r.judged for r in spanning)
    judged = [r for r in reports if r.judged]
    assert len(judged) >= len(reports) - 2  # all but the first windows' start-up
    assert max(r.beta_total for r in judged) < 1.0
    assert not any(r.alarm is Alarm.ERROR for r in reports)
    # the reference: the closed-loop gate leaves every window spanning the move unjudged
    assert not any(r.judged for r in _spanning(_reports(scenario, GATE)))
