"""The operating-point check: the zero-frequency bin against a reference operating point.

References independent of the code under test:

* the rig's equilibrium equations (``sim.rig.operating_point`` for a setpoint; the mass and
  energy balances solved here with ``scipy.optimize.brentq`` for a leak, a heat loss and a
  weak valve), not the simulator's integration;
* the closed form of Problem 3 at one bin with the inputs at the reference, written out by
  hand: ``beta_op = sqrt(sum_i (max(|dy_i| - allowance, 0) / W_n,i)^2)``;
* the per-bin SDP, a second solver, against the closed form.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from tools.events import record_events
from twotank_validation.core.model import load_model
from twotank_validation.core.oppoint import (
    OperatingPoint,
    check_operating_point,
    combined_beta,
    dead_band,
)
from twotank_validation.online import Alarm, MonitorConfig, OnlineValidator
from twotank_validation.online.op_tracker import OpPointConfig, OpState
from twotank_validation.online.window import verdict_text
from twotank_validation.sim import rig
from twotank_validation.sim import scenario as sc

MODEL_B = load_model("B")
NOISE = np.array([0.01, 0.03])  # Model B's flat noise weights (level, temperature)
ALLOW = OpPointConfig().drift_allowance
P_S = 204.8  # period (s)


def by_hand(dy: np.ndarray, allowance: float = ALLOW) -> float:
    return float(np.sqrt(np.sum((np.maximum(np.abs(dy) - allowance, 0.0) / NOISE) ** 2)))


# --- the core check ---------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["auto", "sdp"])
@pytest.mark.parametrize(
    "target", [(0.49, 0.5), (0.47, 0.53), (0.44, 0.47), (0.55, 0.5), (0.47, 0.56)]
)
def test_a_setpoint_move_of_the_rig_is_explained_by_model_b(target, method) -> None:
    """Two equilibria of the rig: the move of the means is within Model B's DC uncertainty."""
    params = rig.RigParams()
    a = rig.operating_point(params, 0.47, 0.5)
    b = rig.operating_point(params, *target)
    ref = OperatingPoint(a.commands, np.array([a.height, a.temperature]))
    new = OperatingPoint(b.commands, np.array([b.height, b.temperature]))
    chk = check_operating_point(MODEL_B, 0.1, ref, new, n_samples=4096, method=method)
    assert chk.explained
    # the same move with the inputs left at the reference is not: the outputs moved alone
    alone = check_operating_point(
        MODEL_B,
        0.1,
        ref,
        OperatingPoint(ref.u, new.y),
        n_samples=4096,
        method=method,
        allowance=ALLOW,
    )
    assert alone.beta == pytest.approx(by_hand(new.y - ref.y), rel=1e-9)
    assert alone.explained == (by_hand(new.y - ref.y) <= 1.0)


def test_the_closed_form_and_the_sdp_agree_on_random_moves() -> None:
    rng = np.random.default_rng(3)
    ref = OperatingPoint(np.array([0.4, 0.4]), np.array([0.47, 0.5]))
    for _ in range(10):
        new = OperatingPoint(ref.u + rng.normal(0, 0.02, 2), ref.y + rng.normal(0, 0.03, 2))
        for model in (MODEL_B, load_model("A")):
            cf = check_operating_point(model, 0.1, ref, new, n_samples=4096, allowance=0.001)
            sdp = check_operating_point(
                model, 0.1, ref, new, n_samples=4096, allowance=0.001, method="sdp"
            )
            assert cf.beta == pytest.approx(sdp.beta, rel=1e-5, abs=1e-7)


def test_energy_convention_scales_the_bin_by_sqrt_n() -> None:
    ref = OperatingPoint(np.zeros(2), np.zeros(2))
    new = OperatingPoint(np.zeros(2), np.array([0.02, 0.0]))
    power = check_operating_point(MODEL_B, 0.1, ref, new, n_samples=4096, allowance=0.0)
    energy = check_operating_point(
        MODEL_B, 0.1, ref, new, n_samples=4096, allowance=0.0, convention="energy"
    )
    assert power.beta == pytest.approx(2.0, rel=1e-12)
    assert energy.beta == pytest.approx(2.0 * 64.0, rel=1e-12)


def test_dead_band_and_combination() -> None:
    np.testing.assert_allclose(
        dead_band(np.array([0.01, -0.01, 0.001]), np.array([0.002, 0.002, 0.002])),
        [0.008, -0.008, 0.0],
    )
    assert combined_beta(0.6, 0.8) == pytest.approx(1.0)


# --- the rig's equilibria under persistent faults ---------------------------------------------


def equilibrium(
    params: rig.RigParams, hot: float, cold: float, *, leak=0.0, heat_loss=0.0, hot_gain=1.0
) -> np.ndarray:
    """(level, temperature) where the mass and energy balances hold with the commands held."""
    fh, fc = hot_gain * hot, cold
    level = brentq(lambda h: params.outlet_flow(h) + leak - fh - fc, 1e-6, 5.0, xtol=1e-14)
    inflow = fh + fc
    temp = (
        fh * params.hot_supply_temp
        + fc * params.cold_supply_temp
        + heat_loss * params.ambient_temperature
    ) / (inflow + heat_loss)
    return np.array([level, temp])


def scenario(faults=(), setpoints=(), periods=16, **kw) -> sc.Scenario:
    base = sc.load_scenario("nominal")
    return dataclasses.replace(
        base,
        ts_s=0.8,
        period_samples=256,
        duration_s=periods * P_S,
        faults=tuple(faults),
        setpoints=tuple(setpoints),
        **kw,
    )


def run(scn: sc.Scenario, config: MonitorConfig | None = None, models=(MODEL_B,)):
    stamps, u, y = sc.simulate_scenario(scn)
    cfg = config or MonitorConfig(ts_s=scn.ts_s, period_samples=scn.period_samples)
    core = OnlineValidator(cfg, list(models))
    return core, core.feed_many(*record_events(stamps, u, y))


ONSET, END = 5 * P_S, 13 * P_S


@pytest.mark.parametrize(
    ("fault", "effect"),
    [
        ("leak=0.04", {"leak": 0.04}),
        ("valve_weak:hot=0.9", {"hot_gain": 0.9}),
        ("heat_loss=0.3", {"heat_loss": 0.3}),
        ("sensor_bias:height=0.02", None),
        ("sensor_bias:temperature=0.1", None),
        ("valve_stuck:hot", None),
    ],
)
def test_a_persistent_fault_holds_error_to_its_end_and_clears_after(fault, effect) -> None:
    scn = scenario([f"{fault}@{ONSET}-{END}"], periods=20)
    _, reports = run(scn)
    judged = [r for r in reports if r.judged]
    # before: nominal, commissioned, no alarm
    before = [r for r in judged if r.end_ns / 1e9 < ONSET]
    assert before
    assert all(r.alarm is Alarm.OK for r in before)
    # from the second window after the onset to the last window before the end: ERROR
    # (the first invalidating window raises WARN: two in a row raise ERROR)
    second = [r.end_ns for r in judged if r.start_ns / 1e9 > ONSET][1]
    held = [r for r in judged if second <= r.end_ns and r.end_ns / 1e9 <= END]
    assert len(held) >= 5
    assert all(r.alarm is Alarm.ERROR for r in held), [
        (r.end_ns / 1e9, r.alarm.name, r.beta, r.beta_op) for r in held
    ]
    # the settled windows are invalidated by the operating point
    settled = [r for r in held if math.isfinite(r.beta_op)]
    assert len(settled) >= 3
    assert all(r.raised_by in ("operating point", "dynamics and operating point") for r in settled)
    if effect is not None:
        # beta_op against the rig's equilibrium with the commands held at their mean
        params = scn.rig_params()
        hot, cold = scn.operating_point().commands
        shift = equilibrium(params, hot, cold, **effect) - equilibrium(params, hot, cold)
        for r in settled:
            assert r.beta_op == pytest.approx(by_hand(shift), rel=0.08)
    # after the end: OK again within the transient and the clearing windows
    after = [r for r in judged if r.start_ns / 1e9 > END + 2 * P_S]
    assert after
    assert after[-1].alarm is Alarm.OK
    assert all(not math.isfinite(r.beta_op) or r.beta_op < 0.5 for r in after)


@pytest.mark.parametrize("hop", [256, 64])
@pytest.mark.parametrize(
    "setpoint", ["height=0.53", "temperature=0.55", "height=0.42,temperature=0.46"]
)
def test_a_setpoint_change_raises_no_alarm_and_moves_the_reference(setpoint, hop) -> None:
    """Also with windows every quarter period: the windows that refine the reference are a
    period apart, so two overlapping windows of a plant still settling do not fix it early."""
    cfg = MonitorConfig(ts_s=0.8, period_samples=256, hop_samples=hop)
    core, reports = run(scenario(setpoints=[f"{setpoint}@{6 * P_S}"]), cfg)
    judged = [r for r in reports if r.judged]
    assert all(not r.invalidated for r in judged)
    assert all(r.alarm in (Alarm.OK, Alarm.WARN) for r in judged)
    moved = [r for r in judged if "setpoint change, reference moved" in r.operating_point]
    assert len(moved) == 1
    ref = core.operating_points()["B"]
    assert ref["state"] == OpState.MOVED
    # the reference moved to where a run that starts at the new point commissions its own
    # (the means under the excitation sit a little off the equilibrium, which depends on it)
    keys = {k: float(v) for k, v in (part.split("=") for part in setpoint.split(","))}
    target = np.array([keys.get("height", 0.47), keys.get("temperature", 0.5)])
    there, _ = run(scenario(periods=8, height=target[0], temperature=target[1]), cfg)
    np.testing.assert_allclose(ref["y"], there.operating_points()["B"]["y"], atol=0.0015)
    nominal, _ = run(scenario(periods=8), cfg)
    base = nominal.operating_points()["B"]
    params = rig.RigParams()
    moved_u = rig.operating_point(params, *target).commands - rig.operating_point(params).commands
    np.testing.assert_allclose(np.subtract(ref["u"], base["u"]), moved_u, atol=1e-9)


def test_a_given_reference_catches_a_plant_that_starts_faulty() -> None:
    scn = scenario(["sensor_bias:height=0.03@1"], periods=8)
    # commissioned: the bias is part of the reference, nothing is seen
    _, reports = run(scn)
    assert not any(r.invalidated for r in reports)
    # given (the healthy rig's means under its excitation): the bias is seen and held
    core_clean, _ = run(scenario(periods=8))
    ref = core_clean.operating_points()["B"]
    given = MonitorConfig(
        ts_s=0.8,
        period_samples=256,
        op=OpPointConfig(reference_u=tuple(ref["u"]), reference_y=tuple(ref["y"])),
    )
    core, reports = run(scn, given)
    judged = [r for r in reports if r.judged and math.isfinite(r.beta_op)]
    assert judged
    want = by_hand(np.array([0.03, 0.0]))
    assert all(r.beta_op == pytest.approx(want, rel=0.05) for r in judged)
    assert reports[-1].alarm is Alarm.ERROR
    assert core.operating_points()["B"]["state"] == OpState.GIVEN
    # a reset goes back to the given reference, not to commissioning
    core.reset_operating_points()
    assert core.operating_points()["B"]["state"] == OpState.GIVEN


def test_reset_commissions_again_on_the_current_plant() -> None:
    scn = scenario(["sensor_bias:temperature=0.1@1000"], periods=14)
    core, reports = run(scn)
    assert reports[-1].alarm is Alarm.ERROR
    core.reset_operating_points()
    assert core.operating_points()["B"]["state"] == OpState.COMMISSIONING
    assert core.operating_points()["B"]["u"] is None


def test_the_check_can_be_switched_off() -> None:
    off = MonitorConfig(ts_s=0.8, period_samples=256, op=OpPointConfig(enabled=False))
    _, reports = run(scenario([f"leak=0.04@{ONSET}"]), off)
    judged = [r for r in reports if r.judged]
    assert all(math.isnan(r.beta_op) for r in judged)
    assert all(r.beta_total == r.beta for r in judged)
    assert all(r.operating_point.startswith("off") for r in judged)


def test_the_report_message_carries_the_operating_point() -> None:
    from twotank_validation.ros import messages  # noqa: PLC0415 - ROS only here

    _, report_cls = messages.message_classes()
    _, reports = run(scenario([f"sensor_bias:height=0.03@{ONSET}"], periods=10))
    rep = next(r for r in reports if r.raised_by == "operating point")
    msg = messages.report_message(rep, report_cls)
    assert (msg.beta_op, msg.beta_total) == (rep.beta_op, rep.beta_total)
    assert (msg.raised_by, msg.operating_point) == ("operating point", rep.operating_point)
    assert msg.invalidated
    assert msg.beta == rep.beta < 1.0  # the dynamics alone do not invalidate it


def test_the_fast_path_and_the_sdp_agree_for_a_structured_model(tmp_path) -> None:
    """Model B with an input-multiplicative block on both valves: not output-decoupled, so
    the zero-frequency bin goes the fast path; the per-bin SDP is the second solver."""
    from importlib import resources  # noqa: PLC0415

    import yaml  # noqa: PLC0415

    from twotank_validation.core.oppoint import dc_response  # noqa: PLC0415
    from twotank_validation.core.validate import takes_fast_path  # noqa: PLC0415
    from twotank_validation.defaults import Method  # noqa: PLC0415

    doc = yaml.safe_load(
        resources.files("twotank_validation").joinpath("models/model_b.yaml").read_text()
    )
    doc["name"] = "B_valves"
    doc["perturbations"].append(
        {
            "name": "valves",
            "kind": "input_multiplicative",
            "inputs": ["hot", "cold"],
            "weight": {"gain": 0.05},
        }
    )
    path = tmp_path / "b_valves.yaml"
    path.write_text(yaml.safe_dump(doc))
    model = load_model(str(path))
    assert takes_fast_path(dc_response(model, 0.1), Method.AUTO)
    rng = np.random.default_rng(5)
    ref = OperatingPoint(np.array([0.4, 0.4]), np.array([0.47, 0.5]))
    for _ in range(6):
        new = OperatingPoint(ref.u + rng.normal(0, 0.02, 2), ref.y + rng.normal(0, 0.03, 2))
        fast = check_operating_point(model, 0.1, ref, new, n_samples=4096, allowance=0.001)
        sdp = check_operating_point(
            model, 0.1, ref, new, n_samples=4096, allowance=0.001, method="sdp"
        )
        assert fast.beta == pytest.approx(sdp.beta, rel=1e-5, abs=1e-7)


# --- a fault before the reference is commissioned ---------------------------------------------

EARLY = 700.0  # s: before the second commissioning window a period after the first (818 s)


def test_a_fault_before_commissioning_is_not_taken_for_the_reference() -> None:
    """A leak from 700 s, before the reference could be commissioned: its transient
    invalidates the model (β > 1); the windows after it are not known-healthy, so they must
    not become the reference, and the alarm must not return to OK while the leak goes on.

    References: the scenario's fault schedule (the leak lasts to the end), and a reference
    given from the healthy rig, against which the same windows are invalidated by the
    operating point (the leak is there to see in every steady window after it)."""
    scn = scenario([f"leak=0.04@{EARLY}"], periods=16)
    core, reports = run(scn)
    judged = [r for r in reports if r.judged]
    first = next(i for i, r in enumerate(judged) if r.invalidated)
    assert judged[first].end_ns / 1e9 > EARLY
    after = judged[first:]
    assert all(r.alarm is not Alarm.OK for r in after), [
        (r.end_ns / 1e9, r.alarm.name, r.operating_point) for r in after if r.alarm is Alarm.OK
    ]
    ref = core.operating_points()["B"]
    assert ref["state"] == OpState.SUSPENDED
    assert ref["u"] is None
    # every valid window after it says why it is not OK (typed and in words)
    quiet = [r for r in after if not r.invalidated and r.alarm is Alarm.WARN]
    assert quiet
    assert all(r.op_state is OpState.SUSPENDED for r in quiet)
    assert all("reset_operating_point" in r.operating_point for r in quiet)
    assert all("operating point not checked" in verdict_text(r) for r in quiet)
    # the independent reference: against the healthy rig's reference the leak is seen
    healthy, _ = run(scenario(periods=8))
    given = MonitorConfig(
        ts_s=0.8,
        period_samples=256,
        op=OpPointConfig(
            reference_u=tuple(healthy.operating_points()["B"]["u"]),
            reference_y=tuple(healthy.operating_points()["B"]["y"]),
        ),
    )
    _, seen = run(scn, given)
    steady = [r for r in seen if r.judged and math.isfinite(r.beta_op) and r.start_ns / 1e9 > 1200]
    assert len(steady) >= 10
    assert all(r.raised_by.operating_point and r.alarm is Alarm.ERROR for r in steady)


def test_a_nominal_run_still_commissions_and_stays_ok() -> None:
    core, reports = run(scenario(periods=16))
    judged = [r for r in reports if r.judged]
    assert len(judged) >= 40
    assert all(r.alarm is Alarm.OK for r in judged)
    assert core.operating_points()["B"]["state"] == OpState.COMMISSIONED


def test_reset_commissions_after_a_suspension_once_the_plant_is_healthy() -> None:
    """The leak from 700 s ends at 1600 s: the reference stays suspended (its end's
    transient ERROR clears to WARN, never OK) until reset_operating_point; then it
    commissions on the healthy plant and the alarm returns to OK. Reference: the healthy
    run's own commissioned reference."""
    scn = scenario([f"leak=0.04@{EARLY}-1600"], periods=20)
    stamps, u, y = sc.simulate_scenario(scn)
    core = OnlineValidator(
        MonitorConfig(ts_s=scn.ts_s, period_samples=scn.period_samples), [MODEL_B]
    )
    cut = int(np.searchsorted(stamps, round(3000 * 1e9)))
    before = core.feed_many(*record_events(stamps[:cut], u[:cut], y[:cut]))
    late = [r for r in before if r.judged and r.start_ns / 1e9 > 1700]
    assert late
    assert all(r.alarm is not Alarm.OK and r.op_state is OpState.SUSPENDED for r in late)
    assert late[-1].alarm is Alarm.WARN
    assert not late[-1].invalidated
    core.reset_operating_points()
    assert core.operating_points()["B"]["state"] == OpState.COMMISSIONING
    rest = core.feed_many(*record_events(stamps[cut:], u[cut:], y[cut:]))
    assert core.operating_points()["B"]["state"] == OpState.COMMISSIONED
    assert rest[-1].alarm is Alarm.OK
    healthy, _ = run(scenario(periods=8))
    np.testing.assert_allclose(
        core.operating_points()["B"]["y"], healthy.operating_points()["B"]["y"], atol=0.0015
    )
