"""Tests of the tank-1 model, its linearisations and the simulator (twotank_validation.sim.rig).

References are independent of the implementation: closed-form equilibria and Jacobians derived
by hand below, exact zero-order-hold discretisations (matrix exponential) and scipy's lsim.
"""

import math
import re

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from hypothesis import given
from hypothesis import strategies as st

from twotank_validation.errors import DatumError, DimensionError, ModelError
from twotank_validation.sim.linearise import LinearModel, linearise_model_a, linearise_model_b
from twotank_validation.sim.rig import OperatingPoint, RigParams, operating_point
from twotank_validation.sim.simulator import SimResult, TankSimulator, simulate

A1, ALPHA, BETA, TAU_V = 91.4, 1.34, 0.6, 0.05
H0, T0 = 0.47, 0.5
F1 = (H0 + BETA) / ALPHA  # 0.79851 outlet flow at the paper's operating point


def analytic_model_b(h, t, th=1.0, tc=0.0, area=A1, alpha=ALPHA, beta=BETA, tau=TAU_V):
    """Hand-derived Jacobian of [f_h, f_c, h, E] at an equilibrium (h, t), E = h t.

    dh/dt = (f_h + f_c - (h + beta)/alpha) / A
    dE/dt = (f_h th + f_c tc - (h + beta)/alpha * E/h) / A
    t = E / h  ->  dt = dE / h - (E / h^2) dh = (dE - t dh) / h
    """
    f1 = (h + beta) / alpha
    a = np.array(
        [
            [-1 / tau, 0, 0, 0],
            [0, -1 / tau, 0, 0],
            [1 / area, 1 / area, -1 / (alpha * area), 0],
            [th / area, tc / area, (-t / alpha + f1 * t / h) / area, -f1 / (h * area)],
        ]
    )
    b = np.array([[1 / tau, 0], [0, 1 / tau], [0, 0], [0, 0]])
    c = np.array([[0, 0, 1, 0], [0, 0, -t / h, 1 / h]])
    return a, b, c, np.zeros((2, 2))


def zoh_step_response(model, u_step, n, ts):
    """Output of the ZOH discretisation x(k+1) = Ad x(k) + Bd u, y(k) = C x(k) for a step u."""
    nx, nu = model.b.shape
    m = np.zeros((nx + nu, nx + nu))
    m[:nx, :nx] = model.a
    m[:nx, nx:] = model.b
    e = scipy.linalg.expm(m * ts)
    ad, bd = e[:nx, :nx], e[:nx, nx:]
    x = np.zeros(nx)
    y = np.empty((n, model.c.shape[0]))
    for k in range(n):
        y[k] = model.c @ x
        x = ad @ x + bd @ u_step
    return y


# --- parameters and operating point -------------------------------------------------------


def test_operating_point_matches_closed_form():
    op = operating_point(RigParams())
    assert op.out_flow == pytest.approx(1.07 / 1.34, rel=1e-15)
    assert op.hot_flow == pytest.approx(1.07 / 1.34 * 0.5, rel=1e-15)
    assert op.cold_flow == pytest.approx(1.07 / 1.34 * 0.5, rel=1e-15)
    np.testing.assert_array_equal(op.commands, [op.hot_flow, op.cold_flow])
    assert op.commands.shape == (2,)


@given(
    h=st.floats(0.15, 0.75),
    t=st.floats(0.05, 0.95),
    tc=st.floats(-0.2, 0.2),
    th=st.floats(0.8, 1.5),
)
def test_operating_point_is_an_equilibrium(h, t, tc, th):
    params = RigParams(hot_supply_temp=th, cold_supply_temp=tc)
    try:
        op = operating_point(params, h, t)
    except ModelError:
        # Only legitimate when a flow would leave [0, 1]: check that independently.
        f1 = (h + BETA) / ALPHA
        fh = f1 * (t - tc) / (th - tc)
        assert not (0 <= fh <= 1 and 0 <= f1 - fh <= 1)
        return
    f1 = (h + BETA) / ALPHA
    assert op.hot_flow + op.cold_flow - f1 == pytest.approx(0, abs=1e-14)  # mass balance
    assert op.hot_flow * th + op.cold_flow * tc - f1 * t == pytest.approx(0, abs=1e-14)  # energy


@pytest.mark.parametrize(
    ("height", "temperature", "named"),
    [(0.1, 0.5, "height=0.1"), (0.8, 0.5, "height=0.8"), (0.47, 1.2, "temperature=1.2")],
)
def test_operating_point_outside_valid_range_raises(height, temperature, named):
    with pytest.raises(ModelError, match=re.escape(named)):
        operating_point(RigParams(), height, temperature)


def test_operating_point_height_message_names_valid_range():
    with pytest.raises(ModelError, match=r"0\.15\.\.0\.75"):
        operating_point(RigParams(), 0.8)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"area": 0.0},
        {"outlet_alpha": -1.0},
        {"valve_tau_s": 0.0},
        {"mixing_delay_s": -1.0},
        {"mixing_lag_s": -0.1},
        {"noise_std_height": -1e-3},
        {"noise_std_temperature": float("nan")},
        {"area": float("inf")},
        {"hot_supply_temp": 0.0},
        {"mixing_ref_level": 0.0},
    ],
)
def test_rig_params_validate(kwargs):
    name = next(iter(kwargs))
    with pytest.raises(ModelError, match=name):
        RigParams(**kwargs)


def test_operating_point_rejects_non_equilibrium():
    with pytest.raises(ModelError, match="equilibrium"):
        OperatingPoint(height=0.47, temperature=0.5, hot_flow=0.4, cold_flow=0.4, out_flow=0.9)


# --- linearisations -----------------------------------------------------------------------


def test_model_a_matches_paper_numbers():
    params = RigParams()
    model = linearise_model_a(params, operating_point(params))
    assert model.state_names == ("hot_flow", "cold_flow", "height", "temperature")
    assert model.input_names == ("hot", "cold")
    assert model.output_names == ("height", "temperature")
    # Time constants from the eigenvalues: valves, height alpha A1, temperature A1 h1 / f1.
    taus = np.sort(-1.0 / np.linalg.eigvals(model.a).real)
    np.testing.assert_allclose(taus, [TAU_V, TAU_V, A1 * H0 / F1, ALPHA * A1], rtol=1e-12)
    assert taus[2] == pytest.approx(53.80, abs=0.005)  # paper: 53.8 s
    assert taus[3] == pytest.approx(122.48, abs=0.005)  # paper: 122.5 s
    gain = -model.c @ np.linalg.solve(model.a, model.b) + model.d
    np.testing.assert_allclose(gain, [[ALPHA, ALPHA], [1 / F1, 0.0]], rtol=1e-12, atol=1e-15)
    assert gain[1, 0] == pytest.approx(1.2523, abs=5e-5)  # paper: 1.25
    np.testing.assert_allclose(model.dc_gain(), gain, rtol=1e-14, atol=1e-15)
    # Decoupled: height does not see the temperature state and vice versa.
    assert model.a[2, 3] == 0.0
    assert model.a[3, 2] == 0.0
    np.testing.assert_array_equal(model.c, [[0, 0, 1, 0], [0, 0, 0, 1]])


def test_model_a_temperature_channel_is_first_order_lag():
    """t1/f_h = (1/f1) / (1 + A1 h1/f1 s) * 1/(1 + tau_v s), independent of the cold flow."""
    params = RigParams()
    model = linearise_model_a(params, operating_point(params))
    s = 1j * 2 * np.pi * np.array([1e-4, 3e-3, 0.02, 1.0])
    for k, si in enumerate(s):
        g = model.c @ np.linalg.solve(si * np.eye(4) - model.a, model.b) + model.d
        lag = 1 / (1 + TAU_V * si)
        assert g[1, 0] == pytest.approx((1 / F1) / (1 + A1 * H0 / F1 * si) * lag, rel=1e-12), k
        assert g[0, 0] == pytest.approx(ALPHA / (1 + ALPHA * A1 * si) * lag, rel=1e-12), k
        assert g[0, 1] == pytest.approx(g[0, 0], rel=1e-12)
        assert abs(g[1, 1]) < 1e-15


def test_model_b_matches_analytic_jacobian():
    params = RigParams()
    op = operating_point(params)
    model = linearise_model_b(params, op)
    a, b, c, d = analytic_model_b(H0, T0)
    np.testing.assert_allclose(model.a, a, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(model.b, b, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(model.c, c, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(model.d, d, atol=1e-15)
    # The temperature output t1 = (E1 - 0.5 h1) / 0.47 at the operating point.
    np.testing.assert_allclose(model.c[1], [0, 0, -0.5 / 0.47, 1 / 0.47], rtol=1e-12)
    assert model.state_names == ("hot_flow", "cold_flow", "height", "energy")


def test_model_b_height_row_equals_model_a():
    params = RigParams()
    op = operating_point(params)
    ma, mb = linearise_model_a(params, op), linearise_model_b(params, op)
    np.testing.assert_array_equal(ma.a[:3], mb.a[:3])
    np.testing.assert_array_equal(ma.b[:3], mb.b[:3])
    np.testing.assert_array_equal(ma.c[0], mb.c[0])
    # Model B's temperature DC gain (full balance) is (1 - t1)/f1 and -t1/f1, unlike Model A.
    np.testing.assert_allclose(
        mb.dc_gain(), [[ALPHA, ALPHA], [(1 - T0) / F1, -T0 / F1]], rtol=1e-12
    )


@given(h=st.floats(0.15, 0.75), t=st.floats(0.1, 0.9), beta=st.floats(0.3, 0.9))
def test_model_b_jacobian_at_random_points(h, t, beta):
    params = RigParams(outlet_beta=beta, cold_supply_temp=0.1)
    try:
        op = operating_point(params, h, t)
    except ModelError:
        return
    model = linearise_model_b(params, op)
    a, b, c, _ = analytic_model_b(h, t, tc=0.1, beta=beta)
    np.testing.assert_allclose(model.a, a, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(model.b, b, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(model.c, c, rtol=1e-12, atol=1e-15)


def test_linear_model_checks_dimensions():
    with pytest.raises(DimensionError, match=r"\(3, 2\)"):
        LinearModel(
            a=np.zeros((3, 3)),
            b=np.zeros((3, 3)),
            c=np.zeros((2, 3)),
            d=np.zeros((2, 2)),
            state_names=("x1", "x2", "x3"),
        )


def test_linear_model_arrays_are_read_only():
    params = RigParams()
    model = linearise_model_b(params, operating_point(params))
    with pytest.raises(ValueError, match="read-only"):
        model.a[0, 0] = 1.0


# --- simulator ----------------------------------------------------------------------------


def test_steady_state_holds_for_1000_s():
    params = RigParams(mixing_delay_s=10.0, mixing_lag_s=5.0)
    op = operating_point(params, 0.6, 0.3)
    res = simulate(params, np.tile(op.commands, (10_000, 1)), 0.1, op=op)
    expected = [op.hot_flow, op.cold_flow, op.height, op.temperature]
    np.testing.assert_allclose(res.states, np.tile(expected, (10_000, 1)), rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.clean, np.tile([0.6, 0.3], (10_000, 1)), rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.time_s[-1], 999.9, rtol=1e-12)


@pytest.mark.parametrize("valve", [0, 1])
def test_small_step_matches_model_b(valve):
    params = RigParams()
    op = operating_point(params)
    ts, n = 0.1, 6000
    du = np.zeros(2)
    du[valve] = 1e-3
    res = simulate(params, np.tile(op.commands + du, (n, 1)), ts)
    sim_dev = res.clean - [op.height, op.temperature]
    lin = zoh_step_response(linearise_model_b(params, op), du, n, ts)
    # Height is linear in the states (error: RK4 only); temperature has the 1e-3 nonlinearity.
    for out, tol in ((0, 1e-5), (1, 1e-2)):
        scale = np.abs(lin[:, out]).max()
        assert scale > 1e-4  # the step excites both outputs
        err = np.abs(sim_dev[:, out] - lin[:, out]).max() / scale
        assert err < tol, (valve, out, err)
    if valve == 1:
        # Model A predicts no temperature response to cold water: the check discriminates.
        lin_a = zoh_step_response(linearise_model_a(params, op), du, n, ts)
        assert np.abs(sim_dev[:, 1] - lin_a[:, 1]).max() > 0.5 * np.abs(sim_dev[:, 1]).max()


def test_measurement_is_strictly_proper():
    params = RigParams()
    op = operating_point(params)
    u = np.tile(op.commands, (5, 1))
    u[2] += [0.5, 0.0]  # an impulse-like command at sample 2 only
    res = simulate(params, u)
    np.testing.assert_allclose(res.clean[:3], [[H0, T0]] * 3, rtol=0, atol=1e-15)
    assert abs(res.clean[3, 0] - H0) > 1e-8  # sample 3 sees command 2
    assert res.states[3, 0] > op.hot_flow + 0.1


def test_saturation_of_commands():
    params = RigParams()
    op = operating_point(params)
    u = np.tile(op.commands, (200, 1))
    u[50:, 0] = 3.0
    u[100:, 1] = -2.0
    res = simulate(params, u)
    clipped = simulate(params, np.clip(u, 0, 1))
    np.testing.assert_array_equal(res.commands, np.clip(u, 0, 1))
    np.testing.assert_array_equal(res.states, clipped.states)
    assert res.states[:, :2].max() <= 1.0
    assert res.states[:, :2].min() >= 0.0


def test_simulate_equals_stepping_the_simulator():
    params = RigParams(mixing_delay_s=7.0, mixing_lag_s=3.0, noise_std_height=0.01)
    op = operating_point(params)
    rng = np.random.default_rng(1)
    u = op.commands + 0.05 * rng.standard_normal((300, 2))
    res = simulate(params, u, 0.2, seed=4, substeps=5)
    sim = TankSimulator(params, 0.2, seed=4, substeps=5)
    for k in range(300):
        assert sim.time_s == pytest.approx(res.time_s[k], rel=1e-15)
        np.testing.assert_array_equal(sim.measure(), res.measured[k])
        np.testing.assert_array_equal(sim.state, res.states[k])
        sim.step(u[k])


def test_noise_is_seeded_and_has_requested_std():
    params = RigParams(noise_std_height=0.01, noise_std_temperature=0.02)
    op = operating_point(params)
    u = np.tile(op.commands, (5000, 1))
    r1 = simulate(params, u, seed=3)
    r2 = simulate(params, u, seed=3)
    r3 = simulate(params, u, seed=4)
    np.testing.assert_array_equal(r1.measured, r2.measured)
    assert np.mean(r1.measured != r3.measured) > 0.99
    np.testing.assert_array_equal(r1.clean, r3.clean)
    noise = r1.measured - r1.clean
    # Sample std of 5000 normals: relative standard error 1 %; allow 5 %.
    np.testing.assert_allclose(noise.std(axis=0), [0.01, 0.02], rtol=0.05)
    np.testing.assert_allclose(noise.mean(axis=0), [0, 0], atol=5 * 0.02 / math.sqrt(5000))
    assert abs(np.corrcoef(noise.T)[0, 1]) < 0.06
    quiet = simulate(RigParams(), u, seed=3)
    np.testing.assert_allclose(r1.clean, quiet.clean, rtol=0, atol=0)


def test_mixing_delay_shifts_measured_temperature():
    params = RigParams(mixing_delay_s=10.0)
    op = operating_point(params, 0.6, 0.5)
    ts, n = 0.1, 3000
    u = np.tile(op.commands + np.array([0.05, 0.0]), (n, 1))
    res = simulate(params, u, ts, op=op)
    t = res.time_s
    height, bulk = res.states[:, 2], res.states[:, 3]
    measured = res.clean[:, 1]
    # Reference: bulk temperature at t - tau(h(t)), tau = 10 s * h / 0.47 (bulk = op before 0).
    tau = 10.0 * height / 0.47
    assert tau[0] == pytest.approx(10.0 * 0.6 / 0.47)
    assert tau[-1] - tau[0] > 0.5  # the level rises, so the delay really varies
    reference = np.interp(t - tau, t, bulk, left=op.temperature)
    amplitude = np.ptp(bulk)
    # Residual: sample-grid interpolation of the reference (~4e-5); a floor lookup gives ~5e-4.
    assert np.abs(measured - reference).max() < 2e-4 * amplitude
    # Without the level dependence the fit would be clearly worse.
    fixed = np.interp(t - tau[0], t, bulk, left=op.temperature)
    assert np.abs(measured - fixed).max() > 10 * np.abs(measured - reference).max()
    # Level-neutral step (hot up, cold down): constant delay, estimated by least squares.
    res = simulate(params, np.tile(op.commands + np.array([0.03, -0.03]), (n, 1)), ts, op=op)
    np.testing.assert_allclose(res.states[:, 2], 0.6, rtol=0, atol=1e-12)
    measured, bulk = res.clean[:, 1], res.states[:, 3]
    shifts = np.arange(0.0, 20.0, 0.01)
    sse = [np.sum((measured - np.interp(t - s, t, bulk, left=T0)) ** 2) for s in shifts]
    assert shifts[int(np.argmin(sse))] == pytest.approx(10.0 * 0.6 / 0.47, abs=0.02)


def test_mixing_lag_is_first_order():
    params = RigParams(mixing_lag_s=20.0)
    op = operating_point(params)
    ts, n = 0.1, 3000
    u = np.tile(op.commands + np.array([0.05, -0.03]), (n, 1))
    res = simulate(params, u, ts, op=op)
    bulk = res.states[:, 3]
    lag = scipy.signal.lti([1.0], [20.0, 1.0])
    _, reference, _ = scipy.signal.lsim(lag, bulk, res.time_s, X0=[op.temperature * 20.0])
    amplitude = np.ptp(bulk)
    assert amplitude > 0.01
    assert np.abs(res.clean[:, 1] - reference).max() < 1e-4 * amplitude
    np.testing.assert_array_equal(res.clean[:, 0], res.states[:, 2])  # level is not lagged


def test_nan_command_raises():
    params = RigParams()
    op = operating_point(params)
    u = np.tile(op.commands, (10, 1))
    u[4, 1] = np.nan
    with pytest.raises(DatumError, match="sample 4"):
        simulate(params, u)
    u[4, 1] = np.inf
    with pytest.raises(DatumError, match="NaN/inf"):
        simulate(params, u)
    sim = TankSimulator(params)
    with pytest.raises(DatumError, match="not finite"):
        sim.step(np.array([np.nan, 0.4]))


@pytest.mark.parametrize("shape", [(5, 3), (10,), (0, 2), (2, 2, 2)])
def test_wrong_command_shape_raises_with_shape(shape):
    with pytest.raises(DatumError, match=re.escape(str(shape))):
        simulate(RigParams(), np.full(shape, 0.4))


def test_step_wrong_shape_raises():
    sim = TankSimulator(RigParams())
    with pytest.raises(DatumError, match=r"\(3,\)"):
        sim.step(np.array([0.4, 0.4, 0.4]))


def test_empty_tank_raises_model_error():
    with pytest.raises(ModelError, match="empty"):
        simulate(RigParams(), np.zeros((1000, 2)))


def test_too_coarse_substep_raises():
    with pytest.raises(ModelError, match="substeps >= 4"):
        TankSimulator(RigParams(), 0.5, substeps=1)
    with pytest.raises(ModelError, match="ts_s"):
        TankSimulator(RigParams(), 0.0)


def test_sim_result_is_read_only_and_shaped():
    params = RigParams()
    res = simulate(params, np.tile(operating_point(params).commands, (7, 1)))
    assert isinstance(res, SimResult)
    assert res.time_s.shape == (7,)
    assert res.commands.shape == res.measured.shape == res.clean.shape == (7, 2)
    assert res.states.shape == (7, 4)
    with pytest.raises(ValueError, match="read-only"):
        res.measured[0, 0] = 0.0


# --- regression against the simulator as it was before faults were added -------------------
# The values below were printed by the fault-free rig.py of commit 75e6a05 (before Fault,
# add_fault and RigParams.ambient_temperature existed) for exactly these inputs. They pin the
# no-fault behaviour: the fault machinery must not change a single bit of it.


def test_no_fault_run_is_bit_identical_to_recorded_run():
    """Pure float arithmetic (no lag: no exp, no noise), so exact on any IEEE platform."""
    params = RigParams()
    op = operating_point(params)
    u = np.tile(op.commands, (600, 1))
    u[100:, 0] += 0.1
    u[300:, 1] -= 0.05
    for res in (simulate(params, u), simulate(params, u, faults=())):
        np.testing.assert_array_equal(res.clean[199], [0.480354826021074, 0.5102580098208036])
        np.testing.assert_array_equal(res.clean[599], [0.5003136349378631, 0.5485517769252172])
        np.testing.assert_array_equal(
            res.states[599],
            [0.4992537313432835, 0.3492537313432836, 0.5003136349378631, 0.5485517769252172],
        )
        np.testing.assert_array_equal(res.measured, res.clean)
        assert float(res.states.sum()) == pytest.approx(1118.232924333763, rel=1e-14)


def test_no_fault_run_with_delay_lag_noise_matches_recorded_run():
    """Mixing delay, lag (one math.exp) and seeded noise: to 1e-12, robust to another libm.

    A behavioural change (delay, lag, noise order, RK4) moves these by far more than 1e-12.
    """
    params = RigParams(
        mixing_delay_s=7.0, mixing_lag_s=3.0, noise_std_height=0.01, noise_std_temperature=0.02
    )
    op = operating_point(params, 0.5, 0.45)
    rng = np.random.default_rng(11)
    u = op.commands + 0.05 * rng.standard_normal((400, 2))
    res = simulate(params, u, 0.2, op=op, seed=4, substeps=5)
    recorded = {
        57: (
            [0.4978377730636994, 0.47420332400676557],
            [0.500378851912859, 0.45040763156513736],
            [0.47405260954379147, 0.4550241013635938, 0.500378851912859, 0.45119431180520364],
        ),
        199: (
            [0.5013860235845923, 0.4347250982544192],
            [0.5016340018556525, 0.4504001992483018],
            [0.38769390138382764, 0.5277886514401197, 0.5016340018556525, 0.4504087508420978],
        ),
        399: (
            [0.5082616200177966, 0.43108863498335526],
            [0.500193973146285, 0.451405206118797],
            [0.4277527831976016, 0.3832900361914647, 0.500193973146285, 0.45183793092807534],
        ),
    }
    for k, (measured, clean, states) in recorded.items():
        np.testing.assert_allclose(res.measured[k], measured, rtol=1e-12, err_msg=str(k))
        np.testing.assert_allclose(res.clean[k], clean, rtol=1e-12, err_msg=str(k))
        np.testing.assert_allclose(res.states[k], states, rtol=1e-12, err_msg=str(k))
    assert float(res.measured.sum()) == pytest.approx(380.6084823450976, rel=1e-12)
    assert float(res.clean.sum()) == pytest.approx(380.572716648948, rel=1e-12)
    assert float(res.states.sum()) == pytest.approx(709.3670836829892, rel=1e-12)


def test_rig_params_ambient_temperature_default_and_validation():
    assert RigParams().ambient_temperature == 0.3
    with pytest.raises(ModelError, match="ambient_temperature"):
        RigParams(ambient_temperature=float("nan"))


# ------------------------------------------------- permanent leak and heat loss (diagnosis)


@given(
    lam=st.floats(min_value=0.0, max_value=1.0),
    q=st.floats(min_value=0.0, max_value=1.0),
)
def test_permanent_leak_and_heat_loss_change_the_jacobian_as_derived_by_hand(lam, q):
    """Leak lambda h1 and loss q (t1 - t_amb): d/dh and d/dE terms derived by hand.

    A1 dh/dt = ... - lambda h          -> dA[h, h] = -lambda / A1
    A1 dE/dt = ... - lambda h (E/h) - q (E/h - t_amb)
             -> dA[E, E] = -(lambda + q / h0) / A1,  dA[E, h] = + q t0 / (h0 A1)
    """
    base = RigParams()
    params = RigParams(leak_per_level=lam, heat_loss_coeff=q)
    op0, op = operating_point(base), operating_point(params)
    assert op.height == op0.height
    assert op.temperature == op0.temperature
    delta = linearise_model_b(params, op).a - linearise_model_b(base, op0).a
    expect = np.zeros((4, 4))
    expect[2, 2] = -lam / A1
    expect[3, 3] = -(lam + q / H0) / A1
    expect[3, 2] = q * T0 / (H0 * A1)
    np.testing.assert_allclose(delta, expect, atol=1e-12)
    # Model A (height held in the energy balance): the temperature state decays faster by the
    # same total rate; the height row as in B.
    delta_a = linearise_model_a(params, op).a - linearise_model_a(base, op0).a
    expect_a = np.zeros((4, 4))
    expect_a[2, 2] = -lam / A1
    expect_a[3, 3] = -(lam + q / H0) / A1
    np.testing.assert_allclose(delta_a, expect_a, atol=1e-12)


def test_operating_point_with_leak_and_heat_loss_is_an_equilibrium_of_the_simulator():
    params = RigParams(leak_per_level=0.6, heat_loss_coeff=0.5)
    op = operating_point(params)
    cmds = np.tile(op.commands, (3000, 1))
    sim = simulate(params, cmds, 0.5, op=op)
    np.testing.assert_allclose(sim.measured[-1], [op.height, op.temperature], atol=1e-9)
