"""Tests of the faults and unmodelled effects of the simulator (sim.faults.Fault).

References are closed forms derived here from the balances
A1 dh/dt = f_h + f_c - f1 - leak, A1 d(h t)/dt = f_h t_h + f_c t_c - (f1 + leak) t - q (t - t_amb)
with f1 = (h + beta) / alpha, and fault-free runs of the same simulator (shifted, compared).
"""

import math

import numpy as np
import pytest

from twotank_validation.errors import DatumError, ModelError
from twotank_validation.sim.faults import FAULT_KINDS, Fault
from twotank_validation.sim.rig import RigParams, operating_point
from twotank_validation.sim.simulator import TankSimulator, simulate

ALPHA, BETA = 1.34, 0.6
TS = 0.5  # coarse samples (substep 0.125 s, the RK4 limit) keep the long settling runs fast


def settle(params, u_const, onset_s, faults, *, op=None, duration_s=1500.0, ts=TS):
    """Run from ``op`` under a constant command for ``onset_s + duration_s`` seconds."""
    n = round((onset_s + duration_s) / ts)
    return simulate(params, np.tile(u_const, (n, 1)), ts, op=op, faults=faults)


def first_sample_at_or_after(t, ts):
    """Smallest k with k ts >= t, computed by search (independent of the simulator's formula)."""
    k = 0
    while k * ts < t - 1e-9 * ts:
        k += 1
    return k


# --- the Fault record -----------------------------------------------------------------------


def test_fault_kinds_and_defaults():
    assert FAULT_KINDS == (
        "leak",
        "sensor_bias",
        "valve_stuck",
        "valve_weak",
        "sensor_delay",
        "mixing_delay",
        "heat_loss",
        "valve_saturation",
        "hot_supply",
    )
    f = Fault("leak", 1000.0, 0.02)
    assert (f.kind, f.onset_s, f.magnitude, f.channel, f.end_s) == (
        "leak",
        1000.0,
        0.02,
        "",
        math.inf,
    )
    assert Fault("valve_stuck", 0, 0, "hot").onset_s == 0.0  # ints accepted, 0 magnitude ok
    assert isinstance(Fault("valve_stuck", 0, 0, "hot").magnitude, float)
    with pytest.raises(AttributeError):
        f.magnitude = 0.1  # type: ignore[misc]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"kind": "leek", "onset_s": 1.0, "magnitude": 0.1}, r"'leek'.*'leak'"),
        ({"kind": "leak", "onset_s": -1.0, "magnitude": 0.1}, r"onset_s=-1\.0.*>= 0"),
        ({"kind": "leak", "onset_s": math.nan, "magnitude": 0.1}, r"onset_s=nan"),
        ({"kind": "leak", "onset_s": math.inf, "magnitude": 0.1}, r"onset_s=inf"),
        ({"kind": "leak", "onset_s": 5.0, "magnitude": 0.1, "end_s": 5.0}, r"end_s=5\.0.*later"),
        ({"kind": "leak", "onset_s": 5.0, "magnitude": 0.1, "end_s": math.nan}, r"end_s=nan"),
        ({"kind": "leak", "onset_s": 1.0, "magnitude": math.nan}, r"magnitude=nan.*not finite"),
        ({"kind": "leak", "onset_s": 1.0, "magnitude": -0.01}, r"magnitude=-0\.01.*\[0, 1\]"),
        ({"kind": "leak", "onset_s": 1.0, "magnitude": 1.5}, r"magnitude=1\.5.*outflow"),
        ({"kind": "leak", "onset_s": 1.0, "magnitude": True}, r"magnitude=True.*real number"),
        ({"kind": "leak", "onset_s": 1.0, "magnitude": 0.1, "channel": "hot"}, 'channel=""'),
        ({"kind": "heat_loss", "onset_s": 1.0, "magnitude": -0.05}, r"heat_loss.*\[0, 1\]"),
        ({"kind": "valve_weak", "onset_s": 1.0, "magnitude": 0.0, "channel": "hot"}, r"\(0, 1\]"),
        ({"kind": "valve_weak", "onset_s": 1.0, "magnitude": 1.2, "channel": "hot"}, r"\(0, 1\]"),
        ({"kind": "valve_weak", "onset_s": 1.0, "magnitude": 0.7}, r"channel=''.*'hot', 'cold'"),
        ({"kind": "valve_stuck", "onset_s": 1.0, "magnitude": 0.0, "channel": "height"}, "cold"),
        ({"kind": "valve_stuck", "onset_s": 1.0, "magnitude": math.inf, "channel": "hot"}, "inf"),
        ({"kind": "sensor_bias", "onset_s": 1.0, "magnitude": 0.1}, r"'height', 'temperature'"),
        ({"kind": "sensor_bias", "onset_s": 1.0, "magnitude": 0.1, "channel": "hot"}, "'hot'"),
        ({"kind": "sensor_bias", "onset_s": 1.0, "magnitude": 2.0, "channel": "height"}, r"-1"),
        ({"kind": "sensor_delay", "onset_s": 1.0, "magnitude": -1.0, "channel": "height"}, "600"),
        ({"kind": "mixing_delay", "onset_s": 1.0, "magnitude": 1e4}, r"magnitude=10000\.0"),
        ({"kind": 3, "onset_s": 1.0, "magnitude": 0.1}, r"kind=3"),
    ],
)
def test_bad_fault_parameters_raise_with_clear_message(kwargs, message):
    with pytest.raises(ModelError, match=message):
        Fault(**kwargs)


def test_simulator_rejects_non_fault():
    with pytest.raises(ModelError, match="not a Fault"):
        TankSimulator(RigParams(), faults=[("leak", 1.0, 0.1)])  # type: ignore[list-item]
    sim = TankSimulator(RigParams())
    with pytest.raises(ModelError, match="not a Fault"):
        sim.add_fault({"kind": "leak"})  # type: ignore[arg-type]


def test_simulate_still_validates_commands_with_faults():
    with pytest.raises(DatumError, match="NaN/inf"):
        simulate(RigParams(), [[0.4, math.nan]], faults=[Fault("leak", 0.0, 0.01)])


# --- no fault, pending faults: nothing changes -----------------------------------------------


def all_kinds(onset_s, end_s=math.inf):
    return [
        Fault("leak", onset_s, 0.05, end_s=end_s),
        Fault("sensor_bias", onset_s, 0.1, "height", end_s=end_s),
        Fault("sensor_bias", onset_s, -0.1, "temperature", end_s=end_s),
        Fault("valve_stuck", onset_s, 0.0, "hot", end_s=end_s),
        Fault("valve_weak", onset_s, 0.6, "cold", end_s=end_s),
        Fault("sensor_delay", onset_s, 4.0, "height", end_s=end_s),
        Fault("sensor_delay", onset_s, 2.5, "temperature", end_s=end_s),
        Fault("mixing_delay", onset_s, 20.0, end_s=end_s),
        Fault("heat_loss", onset_s, 0.05, end_s=end_s),
    ]


@pytest.mark.parametrize("mixing_delay_s", [0.0, 6.0])
def test_pending_faults_leave_the_run_bit_identical(mixing_delay_s):
    params = RigParams(
        mixing_delay_s=mixing_delay_s,
        mixing_lag_s=2.0,
        noise_std_height=0.01,
        noise_std_temperature=0.01,
    )
    op = operating_point(params)
    rng = np.random.default_rng(5)
    u = op.commands + 0.05 * rng.standard_normal((600, 2))
    nominal = simulate(params, u, 0.1, seed=2)
    pending = simulate(params, u, 0.1, seed=2, faults=all_kinds(60.0))  # run ends at 59.9 s
    for name in ("measured", "clean", "states"):
        np.testing.assert_array_equal(getattr(pending, name), getattr(nominal, name))
    active = simulate(params, u, 0.1, seed=2, faults=all_kinds(30.0))
    np.testing.assert_array_equal(active.states[:301], nominal.states[:301])
    np.testing.assert_array_equal(active.measured[:300], nominal.measured[:300])
    assert np.all(active.measured[300:] != nominal.measured[300:])  # every kind shows at once
    # Deterministic under the seed, and the noise is the same draw as without faults.
    again = simulate(params, u, 0.1, seed=2, faults=all_kinds(30.0))
    np.testing.assert_array_equal(again.measured, active.measured)
    np.testing.assert_allclose(
        active.measured - active.clean, nominal.measured - nominal.clean, rtol=0, atol=1e-15
    )


# --- leak, weak valve, heat loss: steady states from the balances ----------------------------


def test_leak_steady_state_level_from_mass_balance():
    params = RigParams()
    op = operating_point(params)
    leak, onset = 0.02, 100.0
    res = settle(params, op.commands, onset, [Fault("leak", onset, leak)])
    inflow = op.hot_flow + op.cold_flow
    # (h + beta) / alpha + leak = inflow
    h_expected = ALPHA * (inflow - leak) - BETA
    assert op.height - h_expected == pytest.approx(ALPHA * leak, rel=1e-12)  # 2.7 % of range
    k_on = round(onset / TS)
    np.testing.assert_array_equal(res.states[: k_on + 1, 2], op.height)  # nothing before onset
    assert res.states[k_on + 1, 2] < op.height
    # 1500 s = 12 time constants alpha A1 of the level: residual 6e-6 of the step.
    assert res.states[-1, 2] == pytest.approx(h_expected, abs=1e-6)
    assert res.clean[-1, 0] == pytest.approx(h_expected, abs=1e-6)
    # The leak leaves at the tank temperature: the temperature balance is unchanged.
    t_expected = (op.hot_flow * 1.0 + op.cold_flow * 0.0) / inflow
    assert res.states[-1, 3] == pytest.approx(t_expected, abs=1e-9)


def test_leak_ends_and_level_recovers():
    params = RigParams()
    op = operating_point(params)
    res = settle(params, op.commands, 0.0, [Fault("leak", 10.0, 0.05, end_s=400.0)])
    k_end = round(400.0 / TS)
    # While it leaks the level falls; after the end it rises back to the nominal level.
    assert np.all(np.diff(res.states[21 : k_end + 1, 2]) < 0)
    assert np.all(np.diff(res.states[k_end + 1 :, 2]) > 0)
    assert res.states[-1, 2] == pytest.approx(op.height, abs=5e-4)


def test_weak_valve_steady_state_from_mass_and_energy_balance():
    params = RigParams()
    op = operating_point(params, 0.4, 0.6)
    gain = 0.7
    res = settle(params, op.commands, 50.0, [Fault("valve_weak", 50.0, gain, "hot")], op=op)
    fh, fc = gain * op.hot_flow, op.cold_flow
    np.testing.assert_allclose(res.states[-1, :2], [fh, fc], rtol=1e-12)
    assert res.states[-1, 2] == pytest.approx(ALPHA * (fh + fc) - BETA, abs=1e-6)
    # Energy: fh th + fc tc = (fh + fc) t.
    assert res.states[-1, 3] == pytest.approx(fh / (fh + fc), abs=1e-9)
    np.testing.assert_array_equal(res.commands, np.tile(op.commands, (len(res.commands), 1)))


@pytest.mark.parametrize("ambient", [0.3, 0.8])
def test_heat_loss_steady_temperature_from_energy_balance(ambient):
    params = RigParams(ambient_temperature=ambient)
    op = operating_point(params)
    q = 0.05
    res = settle(params, op.commands, 50.0, [Fault("heat_loss", 50.0, q)], duration_s=1000.0)
    f1 = op.hot_flow + op.cold_flow
    # 0 = fh th + fc tc - f1 t - q (t - t_amb)  ->  t = (fh th + fc tc + q t_amb) / (f1 + q)
    t_expected = (op.hot_flow * 1.0 + op.cold_flow * 0.0 + q * ambient) / (f1 + q)
    assert abs(t_expected - op.temperature) > 0.005  # a visible effect
    assert np.sign(t_expected - op.temperature) == np.sign(ambient - op.temperature)
    # Time constant A1 h / (f1 + q) = 50.5 s; 1000 s = 20 of them.
    assert res.states[-1, 3] == pytest.approx(t_expected, abs=1e-8)
    np.testing.assert_allclose(res.states[:, 2], op.height, rtol=0, atol=1e-12)  # mass unchanged


def test_leak_and_heat_loss_combine_in_closed_form():
    params = RigParams()
    op = operating_point(params, 0.6, 0.4)
    leak, q = 0.03, 0.08
    faults = [Fault("leak", 20.0, leak), Fault("heat_loss", 40.0, q)]
    res = settle(params, op.commands, 40.0, faults, op=op)
    inflow = op.hot_flow + op.cold_flow
    assert res.states[-1, 2] == pytest.approx(ALPHA * (inflow - leak) - BETA, abs=1e-6)
    # Outflow f1 + leak = inflow at steady state.
    t_expected = (op.hot_flow + q * 0.3) / (inflow + q)
    assert res.states[-1, 3] == pytest.approx(t_expected, abs=1e-7)


# --- valves -------------------------------------------------------------------------------


def test_stuck_valve_freezes_at_its_actual_flow_and_ignores_commands():
    params = RigParams()
    op = operating_point(params)
    ts, n = 0.1, 3000
    u = np.tile(op.commands, (n, 1))
    u[100:, 0] = 0.6  # hot command step at 10 s; the valve lag is 0.05 s
    u[1000:, 0] = 0.2  # after the fault: must be ignored
    u[1500:, 1] = 0.5  # the cold valve is healthy
    res = simulate(params, u, ts, faults=[Fault("valve_stuck", 10.1, 0.0, "hot")])
    nominal = simulate(params, u, ts)
    k_on = 101
    frozen = res.states[k_on, 0]
    assert frozen == nominal.states[k_on, 0]  # its actual flow at onset ...
    assert op.hot_flow + 0.5 * (0.6 - op.hot_flow) < frozen < 0.6 - 1e-3  # ... mid-transient
    np.testing.assert_array_equal(res.states[k_on:, 0], frozen)
    np.testing.assert_array_equal(res.states[: k_on + 1], nominal.states[: k_on + 1])
    np.testing.assert_array_equal(res.states[:, 1], nominal.states[:, 1])
    assert nominal.states[-1, 0] == pytest.approx(0.2, abs=1e-12)  # a healthy valve moves
    # From sample 1500 the level is linear and first order (tau_h = alpha A1) towards the mass
    # balance of the frozen hot flow, driven by the cold step through the valve lag tau_v:
    # h(T) = h_new + (h_start - h_old) e^(-T/tau_h) + (h_old - h_new) g(T), with the two-pole
    # step response 1 - g(T) = 1 - (tau_h e^(-T/tau_h) - tau_v e^(-T/tau_v)) / (tau_h - tau_v).
    tau_h, tau_v = ALPHA * 91.4, 0.05
    h_old = ALPHA * (frozen + op.cold_flow) - BETA
    h_new = ALPHA * (frozen + 0.5) - BETA
    h_start = res.states[1500, 2]
    elapsed = (np.arange(1500, n) - 1500) * ts
    g = (tau_h * np.exp(-elapsed / tau_h) - tau_v * np.exp(-elapsed / tau_v)) / (tau_h - tau_v)
    reference = h_new + (h_start - h_old) * np.exp(-elapsed / tau_h) + (h_old - h_new) * g
    assert abs(h_new - h_start) > 0.05
    # Residual: RK4 error on the 0.05 s valve mode (substep 0.025 s), about 1e-8.
    np.testing.assert_allclose(res.states[1500:, 2], reference, rtol=0, atol=5e-8)


def test_stuck_valve_with_end_resumes_following_command():
    params = RigParams()
    op = operating_point(params)
    u = np.tile(op.commands, (400, 1))
    u[:, 1] = 0.3
    res = simulate(params, u, 0.1, faults=[Fault("valve_stuck", 5.0, 0.0, "cold", end_s=20.0)])
    np.testing.assert_array_equal(res.states[50:201, 1], res.states[50, 1])
    assert res.states[-1, 1] == pytest.approx(0.3, abs=1e-12)


def test_weak_and_stuck_on_both_valves():
    params = RigParams()
    op = operating_point(params)
    u = np.tile(op.commands, (200, 1))
    u[100:] = [0.9, 0.1]
    faults = [Fault("valve_weak", 0.0, 0.5, "hot"), Fault("valve_weak", 0.0, 0.5, "hot")]
    res = simulate(params, u, 0.1, faults=[*faults, Fault("valve_stuck", 0.0, 0.0, "cold")])
    # Weak factors multiply (0.25); the stuck cold valve keeps its initial flow.
    assert res.states[-1, 0] == pytest.approx(0.25 * 0.9, rel=1e-12)
    np.testing.assert_array_equal(res.states[:, 1], op.cold_flow)


# --- sensors ------------------------------------------------------------------------------


def excitation(op, n, seed=0, hold=150, amplitude=0.08):
    """Random steps of both valves, held ``hold`` samples."""
    rng = np.random.default_rng(seed)
    steps = amplitude * rng.uniform(-1, 1, (n // hold + 1, 2))
    return op.commands + np.repeat(steps, hold, axis=0)[:n]


def test_sensor_bias_shifts_measurement_exactly_after_onset_and_not_before():
    params = RigParams(mixing_delay_s=5.0, noise_std_height=0.005, noise_std_temperature=0.01)
    op = operating_point(params)
    u = excitation(op, 1000)
    nominal = simulate(params, u, 0.1, seed=9)
    faults = [
        Fault("sensor_bias", 30.0, 0.04, "height"),
        Fault("sensor_bias", 50.0, -0.03, "temperature", end_s=80.0),
    ]
    res = simulate(params, u, 0.1, seed=9, faults=faults)
    np.testing.assert_array_equal(res.states, nominal.states)  # the plant is not affected
    shift = res.measured - nominal.measured
    expected = np.zeros_like(shift)
    expected[300:, 0] = 0.04
    expected[500:800, 1] = -0.03
    np.testing.assert_allclose(shift, expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(shift[:300], 0.0)
    np.testing.assert_allclose(res.clean - nominal.clean, expected, rtol=0, atol=1e-15)


def test_sensor_delay_on_sample_grid_equals_shifted_clean_signal():
    params = RigParams(mixing_lag_s=5.0, noise_std_height=0.01)
    op = operating_point(params)
    ts, n, delay, onset = 0.1, 1500, 5.0, 60.0
    u = excitation(op, n)
    nominal = simulate(params, u, ts, seed=1)
    res = simulate(params, u, ts, seed=1, faults=[Fault("sensor_delay", onset, delay, "height")])
    k_on, lag = 600, 50
    np.testing.assert_array_equal(res.clean[:k_on], nominal.clean[:k_on])
    np.testing.assert_allclose(
        res.clean[k_on:, 0], nominal.clean[k_on - lag : n - lag, 0], rtol=0, atol=1e-14
    )
    np.testing.assert_array_equal(res.clean[:, 1], nominal.clean[:, 1])  # other channel clean
    np.testing.assert_array_equal(res.states, nominal.states)
    # The delay is visible: the shifted signal differs from the unshifted one.
    assert np.abs(res.clean[k_on:, 0] - nominal.clean[k_on:, 0]).max() > 1e-3
    # Noise is added after the delay (a fresh draw, not a delayed one).
    np.testing.assert_allclose(
        res.measured - res.clean, nominal.measured - nominal.clean, rtol=0, atol=1e-15
    )


def test_sensor_delay_between_samples_interpolates_clean_signal():
    params = RigParams(mixing_delay_s=8.0, mixing_lag_s=2.0)
    op = operating_point(params)
    ts, substeps, n, delay, onset = 0.1, 4, 2000, 3.337, 40.0
    u = excitation(op, n, seed=3)
    res = simulate(params, u, ts, faults=[Fault("sensor_delay", onset, delay, "temperature")])
    # Reference: the fault-free signal at every substep (one RK4 step per sample of ts / 4 does
    # the same arithmetic), delayed by linear interpolation.
    fine = simulate(params, np.repeat(u, substeps, axis=0), ts / substeps, substeps=1)
    t = res.time_s
    reference = np.interp(t - delay, fine.time_s, fine.clean[:, 1])
    k_on = 400
    np.testing.assert_array_equal(res.clean[:k_on, 1], fine.clean[: k_on * substeps : 4, 1])
    amplitude = np.ptp(fine.clean[:, 1])
    assert amplitude > 0.02
    err = np.abs(res.clean[k_on:, 1] - reference[k_on:]).max()
    assert err < 1e-12
    # Nearby whole-sample shifts are clearly different: the fractional delay is resolved.
    for whole in (3.3, 3.4):
        off = np.interp(t - whole, fine.time_s, fine.clean[:, 1])
        assert np.abs(res.clean[k_on:, 1] - off[k_on:]).max() > 1e-5 * amplitude


def bulk_at_substeps(params, u, ts, op=None, substeps=4):
    """(time, bulk temperature) at every substep grid point of a fault-free run.

    One RK4 step per sample of ts / substeps does the same arithmetic as substeps per sample.
    """
    fine = simulate(params, np.repeat(u, substeps, axis=0), ts / substeps, op=op, substeps=1)
    return fine.time_s, fine.states[:, 3]


def test_mixing_delay_fault_takes_effect_at_onset():
    params = RigParams()  # no mixing delay before the fault
    op = operating_point(params, 0.6, 0.5)
    ts, n, onset, delay = 0.1, 3000, 100.0, 10.0
    # Level-neutral excitation (hot and cold in opposition): the delay is constant.
    rng = np.random.default_rng(2)
    d = np.repeat(0.04 * rng.uniform(-1, 1, n // 200 + 1), 200)[:n]
    u = op.commands + np.column_stack([d, -d])
    res = simulate(params, u, ts, op=op, faults=[Fault("mixing_delay", onset, delay)])
    np.testing.assert_allclose(res.states[:, 2], 0.6, rtol=0, atol=1e-12)
    t, bulk, measured = res.time_s, res.states[:, 3], res.clean[:, 1]
    k_on = 1000
    np.testing.assert_array_equal(measured[:k_on], bulk[:k_on])  # undelayed before onset
    tau = delay * 0.6 / 0.47  # proportional to the level, as RigParams.mixing_delay_s
    t_fine, bulk_fine = bulk_at_substeps(params, u, ts, op=op)
    reference = np.interp(t - tau, t_fine, bulk_fine)
    amplitude = np.ptp(bulk[k_on:])
    assert amplitude > 0.01
    np.testing.assert_allclose(measured[k_on:], reference[k_on:], rtol=0, atol=1e-11)
    shifts = np.arange(0.0, 20.0, 0.01)
    sse = [np.sum((measured[k_on:] - np.interp(t - s, t, bulk)[k_on:]) ** 2) for s in shifts]
    assert shifts[int(np.argmin(sse))] == pytest.approx(tau, abs=0.02)


def test_mixing_delay_fault_replaces_the_rig_delay_and_ends():
    params = RigParams(mixing_delay_s=4.0)
    op = operating_point(params, 0.47, 0.5)
    ts, n = 0.1, 2000
    rng = np.random.default_rng(4)
    d = np.repeat(0.04 * rng.uniform(-1, 1, n // 100 + 1), 100)[:n]
    u = op.commands + np.column_stack([d, -d])
    fault = Fault("mixing_delay", 50.0, 12.0, end_s=150.0)
    res = simulate(params, u, ts, faults=[fault])
    t, bulk, measured = res.time_s, res.states[:, 3], res.clean[:, 1]
    t_fine, bulk_fine = bulk_at_substeps(params, u, ts)
    np.testing.assert_allclose(res.states[:, 2], 0.47, rtol=0, atol=1e-12)  # tau = delay
    for window, tau in ((slice(100, 500), 4.0), (slice(500, 1500), 12.0), (slice(1500, n), 4.0)):
        ref = np.interp(t - tau, t_fine, bulk_fine)[window]
        np.testing.assert_allclose(measured[window], ref, rtol=0, atol=1e-11, err_msg=str(tau))
    assert np.abs(np.interp(t - 4.0, t, bulk) - measured)[500:1500].max() > 1e-3  # it changed


# --- timing of onsets and ends --------------------------------------------------------------


@pytest.mark.parametrize("onset", [0.0, 3.0, 3.05, 3.0999, 3.1, 7.3 - 4.2])
@pytest.mark.parametrize("ts", [0.1, 0.25])
def test_onset_respected_to_within_one_sample(onset, ts):
    params = RigParams()
    op = operating_point(params)
    u = np.tile(op.commands, (80, 1))
    k_expected = first_sample_at_or_after(onset, ts)
    assert 0 <= k_expected * ts - onset < ts
    bias = simulate(params, u, ts, faults=[Fault("sensor_bias", onset, 0.1, "temperature")])
    affected = np.flatnonzero(bias.clean[:, 1] != op.temperature)
    assert affected[0] == k_expected
    leak = simulate(params, u, ts, faults=[Fault("leak", onset, 0.1)])
    moved = np.flatnonzero(leak.states[:, 2] != op.height)
    assert moved[0] == k_expected + 1  # the state moves during the sample after onset


def test_fault_at_1000_s_and_active_faults():
    params = RigParams()
    op = operating_point(params)
    fault = Fault("leak", 1000.0, 0.02, end_s=1000.5)
    sim = TankSimulator(params, 0.1, faults=[fault])
    assert sim.faults == (fault,)
    for _ in range(9999):
        sim.step(op.commands)
    assert sim.active_faults == ()
    np.testing.assert_array_equal(sim.state, [op.hot_flow, op.cold_flow, 0.47, 0.5])
    sim.step(op.commands)
    assert sim.time_s == pytest.approx(1000.0)
    assert sim.active_faults == (fault,)
    np.testing.assert_array_equal(sim.state[2], 0.47)  # takes effect from now
    sim.step(op.commands)
    assert sim.state[2] < 0.47
    for _ in range(4):
        sim.step(op.commands)
    assert sim.active_faults == ()  # removed at 1000.5 s
    assert sim.faults == (fault,)


# --- live use: add_fault, clear_faults -------------------------------------------------------


def test_add_fault_with_past_onset_takes_effect_immediately():
    params = RigParams()
    op = operating_point(params)
    sim = TankSimulator(params, 0.1)
    for _ in range(50):
        sim.step(op.commands)
    bias = Fault("sensor_bias", 1.0, 0.05, "height")  # onset 1 s, now 5 s
    sim.add_fault(bias)
    assert sim.active_faults == (bias,)
    assert sim.clean_output[0] == pytest.approx(op.height + 0.05, abs=1e-15)
    stuck = Fault("valve_stuck", 0.0, 0.0, "hot")
    sim.add_fault(stuck)
    flow = sim.state[0]
    for _ in range(20):
        sim.step([1.0, op.cold_flow])
    assert sim.state[0] == flow
    assert sim.active_faults == (bias, stuck)
    sim.clear_faults()
    assert sim.active_faults == ()
    assert sim.faults == ()
    assert sim.clean_output[0] == sim.state[2]  # bias gone at once
    sim.step([1.0, op.cold_flow])
    assert sim.state[0] > flow + 0.5  # the valve follows its command again


def test_add_fault_before_onset_equals_registering_at_start():
    """Delay faults added mid-run grow the delay buffers without losing recorded history."""
    params = RigParams(mixing_delay_s=3.0, mixing_lag_s=1.0, noise_std_temperature=0.01)
    op = operating_point(params)
    ts, n = 0.1, 1500
    u = excitation(op, n, seed=7, hold=60)
    faults = [
        Fault("mixing_delay", 80.0, 15.0),
        Fault("sensor_delay", 90.0, 6.0, "temperature"),
        Fault("sensor_delay", 100.0, 2.0, "height"),
        Fault("sensor_delay", 110.0, 3.0, "temperature"),
        Fault("valve_weak", 120.0, 0.8, "cold"),
    ]
    reference = simulate(params, u, ts, seed=3, faults=faults)
    sim = TankSimulator(params, ts, seed=3)
    for k in range(n):
        if k == 300:  # 30 s: long before any onset minus its delay
            for fault in faults:
                sim.add_fault(fault)
        np.testing.assert_array_equal(sim.measure(), reference.measured[k], err_msg=str(k))
        sim.step(u[k])
    # Same through the constructor, stepping the simulator by hand.
    sim = TankSimulator(params, ts, seed=3, faults=faults)
    for k in range(n):
        np.testing.assert_array_equal(sim.measure(), reference.measured[k])
        sim.step(u[k])


def test_add_fault_mid_run_holds_unrecorded_past():
    """Documented: a sensor delay added late sees the signal as constant before it was added."""
    params = RigParams()
    op = operating_point(params)
    sim = TankSimulator(params, 0.1)
    u = np.array([op.hot_flow + 0.1, op.cold_flow])
    for _ in range(100):
        sim.step(u)
    level_now = sim.state[2]
    sim.add_fault(Fault("sensor_delay", 0.0, 5.0, "height"))
    assert sim.clean_output[0] == level_now  # 5 s ago is before registration
    for _ in range(10):
        sim.step(u)
    assert sim.clean_output[0] == level_now
    assert sim.state[2] > level_now + 1e-4


def test_clear_and_readd_same_faults_is_seamless():
    """The plant node updates its fault list by clear_faults() and add_fault() for each."""
    params = RigParams(mixing_delay_s=4.0, mixing_lag_s=1.0, noise_std_height=0.01)
    op = operating_point(params)
    u = excitation(op, 800, seed=2, hold=50)
    faults = all_kinds(20.0, end_s=60.0)
    reference = simulate(params, u, 0.1, seed=5, faults=faults)
    sim = TankSimulator(params, 0.1, seed=5, faults=faults)
    for k in range(800):
        if k in {100, 250, 400, 650}:  # before, during (twice) and after the faults
            sim.clear_faults()
            for fault in faults:
                sim.add_fault(fault)
        np.testing.assert_array_equal(sim.measure(), reference.measured[k], err_msg=str(k))
        sim.step(u[k])


def test_longer_delay_added_late_holds_oldest_retained_value():
    """Documented: a delay reaching past the retained history reads its oldest value."""
    params = RigParams()
    op = operating_point(params)
    ts, n = 0.1, 900
    u = np.tile([op.hot_flow + 0.1, op.cold_flow], (n, 1))  # the level rises monotonically
    level = simulate(params, u, ts).clean[:, 0]
    sim = TankSimulator(params, ts)
    measured = []
    for k in range(n):
        if k == 500:  # 50 s
            sim.add_fault(Fault("sensor_delay", 50.0, 2.0, "height"))  # retains about 2 s
        if k == 600:  # 60 s: total delay 12 s, but only about 2 s are retained
            sim.add_fault(Fault("sensor_delay", 60.0, 10.0, "height"))
        measured.append(sim.clean_output[0])
        sim.step(u[k])
    measured = np.array(measured)
    assert np.all(measured[500:520] == level[500])  # nothing retained before registration
    np.testing.assert_allclose(measured[520:600], level[500:580], rtol=0, atol=1e-14)
    held = measured[600]
    # Held at the oldest retained value (from 57.9-58 s), not the current one or the 48 s one.
    assert level[579] <= held <= level[580]
    assert np.all(measured[600:690] == held)
    np.testing.assert_allclose(measured[700:], level[580:780], rtol=0, atol=1e-14)


def test_stepping_with_faults_equals_simulate():
    params = RigParams(mixing_delay_s=5.0, noise_std_height=0.01, noise_std_temperature=0.01)
    op = operating_point(params)
    u = excitation(op, 500, seed=8, hold=40)
    faults = all_kinds(10.0, end_s=35.0)
    res = simulate(params, u, 0.2, seed=6, substeps=5, faults=faults)
    sim = TankSimulator(params, 0.2, seed=6, substeps=5, faults=faults)
    for k in range(500):
        np.testing.assert_array_equal(sim.measure(), res.measured[k])
        np.testing.assert_array_equal(sim.clean_output, res.clean[k])
        np.testing.assert_array_equal(sim.state, res.states[k])
        sim.step(u[k])
