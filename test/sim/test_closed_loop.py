"""The closed-loop rig: the PI law, its anti-windup, the loop on the rig, and the validator on it.

References: a hand-computed PI sequence; the closed-loop transfer function of a first-order
loop (scipy.signal.dlsim of C P / (1 + C P)); a brute-force run without anti-windup; the rig's
own equilibrium (``rig.operating_point``) for the setpoints; the injected fault's onset.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import signal

from tools.events import record_events
from twotank_validation.core.model import load_model
from twotank_validation.online import Alarm, MonitorConfig, OnlineValidator
from twotank_validation.sim import rig, simulator
from twotank_validation.sim.control import (
    CLOSED_LOOP_INPUT_PERIODIC_RTOL,
    ControllerConfig,
    ControllerError,
    PIController,
)
from twotank_validation.sim.scenario import (
    ClosedLoop,
    Scenario,
    ScenarioError,
    iter_scenario,
    scenario_from_dict,
    simulate_scenario,
)

PERIOD = 2048
TS = 0.1
PERIOD_S = PERIOD * TS


# --- the PI law ----------------------------------------------------------------------------


def test_pi_ramp_on_a_constant_error_is_the_hand_computed_sequence() -> None:
    """Constant level error e, zero temperature error: F_k = F0 + kp e (1 + k ts / Ti)."""
    cfg = ControllerConfig(filter_s=0.0, kp_level=0.8, ti_level_s=40.0)
    c = PIController(cfg, (0.3, 0.5))
    e = 0.02
    got = np.array([c.step((cfg.height_setpoint - e, cfg.temperature_setpoint)) for _ in range(50)])
    k = np.arange(50)
    flow = 0.8 + cfg.kp_level * e * (1.0 + k * cfg.ts_s / cfg.ti_level_s)
    frac = 0.3 / 0.8  # the hot fraction of the initial commands, held by a zero error
    np.testing.assert_allclose(got[:, 0], frac * flow, rtol=0, atol=1e-14)
    np.testing.assert_allclose(got[:, 1], (1 - frac) * flow, rtol=0, atol=1e-14)


def test_level_loop_on_a_first_order_plant_follows_the_closed_form() -> None:
    """x+ = a x + b (F - F0); the setpoint step response equals dlsim of C P / (1 + C P)."""
    tau, gain, ts = 122.5, 1.34, TS
    a = math.exp(-ts / tau)
    b = gain * (1.0 - a)
    cfg = ControllerConfig(filter_s=0.0, kp_level=2.0, ti_level_s=60.0, height_setpoint=0.5)
    h0, f0 = 0.47, 0.8
    c = PIController(cfg, (f0 / 2, f0 / 2))
    n = 8000
    x = 0.0
    xs = np.empty(n)
    for k in range(n):
        xs[k] = x
        hot, cold = c.step((h0 + x, cfg.temperature_setpoint))
        x = a * x + b * (hot + cold - f0)
    # C(z) = kp ((z - 1) + ts/Ti) / (z - 1), P(z) = b / (z - a); reference input r - h0
    kp, ki = cfg.kp_level, ts / cfg.ti_level_s
    num = np.polymul([kp, kp * (ki - 1.0)], [b])
    den = np.polyadd(np.polymul([1.0, -1.0], [1.0, -a]), num)
    _, ref = signal.dlsim((num, den, ts), np.full(n, 0.5 - h0))
    np.testing.assert_allclose(xs, ref[:, 0], rtol=0, atol=1e-12)
    assert xs[-1] == pytest.approx(0.03, abs=1e-5)  # integral action: no offset


def _windup_run(tt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Level setpoint 0.75 beyond reach (u_max 0.45 holds at most 0.606) for 1000 s, then 0.55."""
    params = rig.RigParams()
    op = rig.operating_point(params)
    cfg = ControllerConfig(
        ts_s=1.0, height_setpoint=0.75, u_max=0.45, tt_level_s=tt_s, filter_s=0.0
    )
    c = PIController(cfg, op.commands)
    sim = simulator.TankSimulator(params, 1.0, op=op, substeps=10)
    heights, commands = [], []
    for k in range(2000):
        if k == 1000:
            c.set_setpoints(0.55, 0.5)
        y = sim.measure()
        u = c.step(y)
        sim.step(u)
        heights.append(y[0])
        commands.append(u)
    return np.array(heights), np.array(commands)


def test_anti_windup_keeps_the_limits_and_recovers_after_saturation() -> None:
    h_aw, u_aw = _windup_run(60.0)
    h_raw, u_raw = _windup_run(math.inf)  # brute force: no back-calculation
    for u in (u_aw, u_raw):
        assert u.min() >= 0.0
        assert u.max() <= 0.45
    assert np.all(u_aw[900:1000] == pytest.approx(0.45))  # saturated while out of reach
    after_aw, after_raw = h_aw[1000:] - 0.55, h_raw[1000:] - 0.55
    # with anti-windup: leaves the limit at once, reaches the new setpoint in about a minute,
    # undershoots it by less than 40 % of the 0.056 step and settles within 0.005 by 600 s;
    # without it the wound-up integrator keeps the valves at the limit for the whole 1000 s
    assert np.argmax(np.abs(after_aw) < 0.005) < 100
    assert after_aw.min() > -0.4 * 0.056
    assert np.all(np.abs(after_aw[600:]) < 0.005)
    assert np.all(after_raw > 0.05)
    assert np.all(u_raw[1000:, 0] == pytest.approx(0.45))


def test_hold_and_bumpless_resume() -> None:
    cfg = ControllerConfig(hold_samples=8, filter_s=0.0)
    c = PIController(cfg, (0.4, 0.4))
    rng = np.random.default_rng(1)
    sent = [
        c.step((0.47 + 0.01 * rng.standard_normal(), 0.5), (0.01 * k % 0.03, 0.0))
        for k in range(20)
    ]
    held = c.hold()
    np.testing.assert_allclose(held, np.mean(sent[-8:], axis=0), rtol=0, atol=1e-15)
    # frozen: whatever the measurement, the held value, and the integrators do not move
    state = c.integrators
    exc = np.array([0.05, -0.05])
    for y in ((0.2, 0.1), (0.7, 0.9)):  # the output excitation goes on around the held value
        np.testing.assert_allclose(c.step(y, tuple(exc)), held + exc, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(c.integrators, state)
    still = PIController(replace(cfg, excite_when_held=False), (0.4, 0.4))
    still.hold()
    np.testing.assert_array_equal(still.step((0.2, 0.1), (0.05, -0.05)), still.held)
    c.resume()
    # the same measurement and no excitation: the PI part is the held command (bumpless)
    np.testing.assert_allclose(c.step((0.7, 0.9)), held, rtol=0, atol=1e-12)


def test_bad_settings_are_refused_with_the_setting_named() -> None:
    with pytest.raises(ControllerError, match="kp_level"):
        ControllerConfig(kp_level=0.0)
    with pytest.raises(ControllerError, match="excitation_entry"):
        ControllerConfig(excitation_entry="input")
    with pytest.raises(ControllerError, match="u_min"):
        ControllerConfig(u_min=0.6, u_max=0.5)
    with pytest.raises(ControllerError, match="measured"):
        PIController(ControllerConfig(), (0.4, 0.4)).step((math.nan, 0.5))
    with pytest.raises(ScenarioError, match="unknown key"):
        scenario_from_dict({"duration_s": 10, "closed_loop": {"kp": 1}}, "s", "s")
    with pytest.raises(ScenarioError, match="closed_loop setpoints"):
        scenario_from_dict({"duration_s": 10, "closed_loop": {"height_setpoint": 0.9}}, "s", "s")
    with pytest.raises(ScenarioError, match=r"s: .*ti_level_s"):
        scenario_from_dict({"duration_s": 10, "closed_loop": {"ti_level_s": -1}}, "s", "s")


# --- the loop on the rig -------------------------------------------------------------------


def test_closed_loop_rig_settles_at_the_operating_point_of_its_setpoints() -> None:
    """Unmodelled permanent leak and heat loss: the loop still reaches the setpoints, and its
    commands are the rig's equilibrium commands for them (which it was never told)."""
    scenario = Scenario(
        name="settle",
        duration_s=3000.0,
        rms_hot=0.0,
        rms_cold=0.0,
        noise_std_height=0.0,
        noise_std_temperature=0.0,
        leak_per_level=0.1,
        heat_loss_coeff=0.05,
        closed_loop=ClosedLoop(height_setpoint=0.55, temperature_setpoint=0.42),
    )
    _, commands, measured = simulate_scenario(scenario)
    reference = rig.operating_point(scenario.rig_params(), 0.55, 0.42).commands
    np.testing.assert_allclose(measured[-1], (0.55, 0.42), atol=2e-4)
    np.testing.assert_allclose(commands[-1], reference, atol=5e-4)
    assert not np.allclose(reference, scenario.operating_point().commands, atol=0.02)


def test_setpoint_changes_move_the_loop_and_yaml_round_trips() -> None:
    doc = {
        "name": "cl",
        "duration_s": 2500.0,
        "rms_hot": 0.0,
        "rms_cold": 0.0,
        "noise_std_height": 0.0,
        "noise_std_temperature": 0.0,
        "setpoints": ["height=0.4,temperature=0.6@100"],
        "closed_loop": True,
    }
    scenario = scenario_from_dict(doc, "test")
    assert scenario.closed_loop == ClosedLoop()
    assert scenario_from_dict(scenario.to_dict(), "again") == scenario
    _, commands, measured = simulate_scenario(scenario)
    np.testing.assert_allclose(measured[-1], (0.4, 0.6), atol=5e-4)
    reference = rig.operating_point(scenario.rig_params(), 0.4, 0.6).commands
    np.testing.assert_allclose(commands[-1], reference, atol=5e-4)
    # iter_scenario yields what simulate_scenario stores
    first = [row[1:3] for _, row in zip(range(5), iter_scenario(scenario), strict=False)]
    np.testing.assert_array_equal(np.array(first), commands[:5])


# --- the validator on closed-loop data ---------------------------------------------------------

MONITOR = MonitorConfig(input_periodic_rtol=CLOSED_LOOP_INPUT_PERIODIC_RTOL)


def _reports(scenario: Scenario, config: MonitorConfig = MONITOR) -> list:
    """Model B's reports on the scenario, fed as the node's three streams."""
    stamps, commands, measured = simulate_scenario(scenario)
    validator = OnlineValidator(config, [load_model("B")])
    return validator.feed_many(*record_events(stamps, commands, measured))


@pytest.mark.parametrize("entry", ["output", "setpoint"])
def test_closed_loop_recording_validates_model_b(entry: str) -> None:
    scenario = Scenario(
        name="cl", duration_s=10 * PERIOD_S, seed=4, closed_loop=ClosedLoop(excitation=entry)
    )
    reports = _reports(scenario)
    judged = [r for r in reports if r.judged]
    # every quarter period once the loop's start-up has left the 3-period span (period 5 on)
    assert len(judged) >= 4 * 5
    betas = [r.beta_total for r in judged]
    assert max(betas) < 1.0, betas
    assert not any(r.alarm is Alarm.ERROR for r in reports)
    # the default gate (periodic input to 1e-6) judges no closed-loop window: why the
    # closed-loop setting exists
    assert not any(r.judged for r in _reports(scenario, MonitorConfig()))


def test_closed_loop_leak_at_twice_the_stated_limit_is_held_once_the_loop_settles() -> None:
    """The loop answers the leak by opening the valves: the windows spanning that move are not
    judged (the closed-loop gate, as a setpoint change's), and once it has settled the inputs
    sit off the commissioned operating point while the outputs do not move as Model B
    predicts: the operating-point check raises ERROR and holds it while the leak lasts."""
    onset = round(8.3 * PERIOD) * TS
    scenario = Scenario(
        name="leak",
        duration_s=16 * PERIOD_S,
        seed=3,
        faults=(f"leak=0.06@{onset:g}",),
        closed_loop=ClosedLoop(),
    )
    reports = _reports(scenario)
    onset_ns = round(onset / TS) * scenario.ts_ns
    before = [r for r in reports if r.end_ns < onset_ns]
    after = [r for r in reports if r.end_ns >= onset_ns]
    assert sum(r.judged for r in before) >= 8
    assert not any(r.alarm is Alarm.ERROR for r in before)
    assert before[-1].operating_point.startswith("commissioned")
    horizon = onset_ns + round(5 * PERIOD_S * 1e9)
    first = next(i for i, r in enumerate(after) if r.alarm is Alarm.ERROR)
    assert after[first].end_ns <= horizon, [r.beta_total for r in after]
    assert after[first].raised_by == "operating point"
    assert all(r.alarm is Alarm.ERROR for r in after[first:])


def test_closed_loop_setpoint_change_raises_nothing_and_moves_the_reference() -> None:
    """An operator's setpoint change moves the valves as a fault does; the windows of the move
    are not judged, and the settled loop's new point is explained by Model B's steady-state
    gain (the setpoint rule), so the reference follows and nothing is raised."""
    scenario = Scenario(
        name="setpoint",
        duration_s=20 * PERIOD_S,
        seed=5,
        closed_loop=ClosedLoop(),
        setpoints=(f"height=0.52@{round(8.3 * PERIOD) * TS:g}",),
    )
    reports = _reports(scenario)
    judged = [r for r in reports if r.judged]
    assert max(r.beta_total for r in judged) < 1.0
    assert not any(r.alarm is Alarm.ERROR for r in reports)
    assert any(r.operating_point.startswith("moved by a setpoint change") for r in reports)
    # the same scenario with the gate wide open judges the move and raises ERROR on it: why
    # the closed-loop gate is where it is
    wide = _reports(scenario, MonitorConfig(input_periodic_rtol=1.0))
    assert any(r.alarm is Alarm.ERROR for r in wide)


def test_nominal_closed_loop_raises_nothing_over_four_simulated_hours() -> None:
    scenario = Scenario(name="hours", duration_s=4 * 3600.0, seed=11, closed_loop=ClosedLoop())
    reports = _reports(scenario)
    judged = [r for r in reports if r.judged]
    assert len(judged) > 4 * 60  # a window every quarter period, 70 periods
    assert not any(r.invalidated for r in judged), max(r.beta_total for r in judged)
    assert all(r.alarm in (Alarm.OK, Alarm.WARN, Alarm.STALE) for r in reports)


def test_validate_closed_loop_option_judges_a_closed_loop_bag(tmp_path) -> None:
    """`validate` on a closed-loop recording: without --closed-loop no window is judged (exit 4,
    and the message names the option); with it the leak is raised by the operating-point
    check after its onset (the injected one) and nothing before."""
    from twotank_validation import cli  # noqa: PLC0415
    from twotank_validation.bags import write_scenario_bag  # noqa: PLC0415

    onset = 2000.0
    scenario = Scenario(
        name="cl_leak",
        duration_s=18 * PERIOD_S,
        seed=2,
        faults=(f"leak=0.06@{onset:g}",),
        closed_loop=ClosedLoop(),
    )
    bag = tmp_path / "cl.mcap"
    write_scenario_bag(scenario, bag, progress=False)
    base = ["validate", str(bag), "--model", "B", "--no-diagnosis", "--quiet"]
    assert cli.main(base) == cli.EXIT_NOT_JUDGED
    out = tmp_path / "cl.json"
    assert cli.main([*base, "--closed-loop", "--json", str(out)]) == 0
    model = json.loads(out.read_text())["models"]["B"]
    assert model["first_alarm"] is not None
    assert model["first_alarm"] > onset
    errors = [w for w in model["windows"] if w["alarm"] == "ERROR"]
    assert errors
    assert all(w["end"] > onset for w in errors)
