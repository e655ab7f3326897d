"""The closed-loop formulation (docs/theory.md §21, issue 32 item 3).

References: the direct Problem 3 on the same ``(U, Y)`` (the per-bin closure must not change
β); a member of the model set simulated in the time domain inside the loop (the nominal and
the perturbation's weight stepped sample by sample with a discrete PI, a real Δ of norm
≤ 1) from hypothesis-drawn states of plant, weight and controller; the direct formulation's
leakage on the same windows.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from transient_plant import MODEL, PERIOD, PERIODS, TS, N, multisine

from twotank_validation.core import lti
from twotank_validation.core.closed_loop import (
    ClosedLoopJudge,
    FixedController,
    LoopAtBins,
    PIPair,
    close_loop,
    closed_loop_judge,
    closed_loop_poles,
    controller_of,
    delayed_measurement,
    feedback_response,
    validate_closed_loop,
)
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model
from twotank_validation.core.transient import (
    local_polynomial,
    transient_estimate,
    validate_with_transient,
)
from twotank_validation.core.validate import validate_beta
from twotank_validation.errors import ModelError, ModelFileError

LPM = local_polynomial(N, PERIODS, 2, 2)
KP, TI_S = 0.3, 2.0
_G = TS * KP / TI_S
# u = kp (r - y) + x, x+ = x + g (r - y), reading y one sample late (as the rig's loop)
PI = delayed_measurement(lti.StateSpace([[1.0]], [[_G, -_G]], [[1.0]], [[KP, -KP]], dt_s=TS), 1)


def _in_loop(
    e: np.ndarray,
    delta: float,
    x_g: np.ndarray,
    x_w: np.ndarray,
    x_k: np.ndarray,
    noise: np.ndarray,
    setpoint: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """A member ``(1 + delta W) G`` under ``u = PI (r - y) + e``, stepped sample by sample."""
    g = MODEL.nominal_discrete(TS)
    w = lti.discretise(MODEL.perturbations[0].weight, TS)
    u = np.zeros(e.size)
    y = np.zeros(e.size)
    for k in range(e.size):
        u[k] = (PI.c @ x_k)[0] + PI.d[0, 0] * setpoint[k] + e[k]  # D's y part is 0 (delay)
        y0 = (g.c @ x_g)[0] + g.d[0, 0] * u[k]
        y[k] = y0 + delta * ((w.c @ x_w)[0] + w.d[0, 0] * y0) + noise[k]
        x_g = g.a @ x_g + g.b[:, 0] * u[k]
        x_w = w.a @ x_w + w.b[:, 0] * y0
        x_k = PI.a @ x_k + PI.b @ np.array([setpoint[k], y[k]])
    return u, y


def test_the_loop_is_stable_and_the_delay_is_a_state() -> None:
    poles = closed_loop_poles(MODEL.nominal_discrete(TS), PI)
    assert poles.size == 2 + 2  # plant 2, integrator 1, the late measurement 1
    assert np.max(np.abs(poles)) < 0.99
    # K_y at the bins against the transfer function kp + g z^-1 / (1 - z^-1), times z^-1
    theta = np.linspace(0.1, 3.0, 7)
    z = np.exp(1j * theta)
    expected = (KP + _G / (z - 1.0)) / z
    got = feedback_response(PI, np.concatenate([[0.0], theta]))
    np.testing.assert_allclose(got[1:, 0, 0], expected, rtol=1e-12)
    assert got[0, 0, 0] == 0.0  # DC stays in the direct form


def test_the_closed_loop_problem_is_the_direct_one_per_bin() -> None:
    """Any (U, Y): β of the closed LFT on (U + K_y Y, Y) is β of P on (U, Y), bin by bin."""
    rng = np.random.default_rng(7)
    u = multisine(1, 0.3) + 0.05 * rng.standard_normal(N)
    y = 0.1 * rng.standard_normal(N) + np.convolve(u, np.ones(6) / 2.0)[:N]
    datum = make_datum(u[:, None], y[:, None], ts_s=TS, period_samples=PERIOD)
    resp = MODEL.response(datum.theta, TS)
    direct = validate_beta(datum, MODEL, response=resp)
    k_y = feedback_response(PI, datum.theta)
    r = datum.u_bins + (k_y @ datum.y_bins[:, :, None])[:, :, 0]
    closed_resp = close_loop(resp, k_y)
    assert np.max(np.abs(closed_resp.p11[1:])) > 0.01  # the loop couples z to v and w
    closed = validate_beta(replace(datum, u_bins=r), MODEL, response=closed_resp, method="fast")
    assert direct.beta > 1.0  # data no member explains: the comparison is not 0 == 0
    np.testing.assert_allclose(closed.w_min, direct.w_min, rtol=1e-6, atol=1e-9)
    assert closed.beta == pytest.approx(direct.beta, rel=1e-7)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    delta=st.floats(-1.0, 1.0),
    scale=st.floats(0.0, 5.0),
    seed=st.integers(0, 2**16),
)
def test_a_member_in_the_loop_from_any_initial_state_is_never_invalidated(
    delta: float, scale: float, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    e = multisine(seed, 0.3)
    noise = 0.01 * rng.standard_normal(N)  # RMS 0.5 of the noise weight
    states = [scale * rng.standard_normal(n) for n in (2, 1, PI.n_states)]
    u, y = _in_loop(e, delta, *states, noise, np.zeros(N))
    datum = make_datum(u[:, None], y[:, None], ts_s=TS, period_samples=PERIOD)
    loop = LoopAtBins.of(PI, MODEL, MODEL.response(datum.theta, TS), LPM, datum)
    res, rho = validate_closed_loop(datum, MODEL, loop)
    assert rho < 1e-3  # E_hat is the excitation: nothing picked up from the lines
    assert res.beta < 1.0


def test_the_loop_compensation_leaks_into_the_direct_form_not_into_the_closed_one() -> None:
    """Started far from its periodic steady state, the loop answers with U at every line;
    the direct formulation picks that up as model error, the closed one does not."""
    rng = np.random.default_rng(11)
    e = multisine(11, 0.3)
    u, y = _in_loop(e, 0.8, np.array([4.0, -3.0]), np.array([2.0]), np.array([-3.0, 1.0]),
                    0.01 * rng.standard_normal(N), np.zeros(N))  # fmt: skip
    datum = make_datum(u[:, None], y[:, None], ts_s=TS, period_samples=PERIOD)
    resp = MODEL.response(datum.theta, TS)
    _, rho_direct = validate_with_transient(datum, MODEL, transient_estimate(LPM, MODEL, TS, N))
    res, rho = validate_closed_loop(datum, MODEL, LoopAtBins.of(PI, MODEL, resp, LPM, datum))
    assert rho_direct > 0.1
    assert rho < 1e-3 * rho_direct
    assert res.beta < 1.0


@pytest.mark.parametrize(("at", "step"), [(0.3, 0.05), (0.55, 0.05), (0.8, 0.05), (0.3, 0.4)])
def test_a_setpoint_change_inside_the_window_raises_nothing(at: float, step: float) -> None:
    """The setpoint is not recorded: its step is part of E_hat, its share bounded through
    ``rho``; a step large against the excitation fills the gate and the judge takes the
    direct formulation (docs/theory.md §21)."""
    rng = np.random.default_rng(5)
    setpoint = np.where(np.arange(N) >= round(at * N), step, 0.0)
    u, y = _in_loop(multisine(5, 0.3), -0.9, np.zeros(2), np.zeros(1), np.zeros(2),
                    0.01 * rng.standard_normal(N), setpoint)  # fmt: skip
    datum = make_datum(u[:, None], y[:, None], ts_s=TS, period_samples=PERIOD)
    resp = MODEL.response(datum.theta, TS)
    closed, rho = validate_closed_loop(datum, MODEL, LoopAtBins.of(PI, MODEL, resp, LPM, datum))
    est = transient_estimate(LPM, MODEL, TS, N)
    res, rho_judged = ClosedLoopJudge(FixedController(PI), LPM)(datum, MODEL, est, response=resp)
    if step < 0.1:
        assert 0.0 < rho < 1.0  # judged on the closed loop, the step's share bounded
        assert closed.beta < 1.0
        assert rho_judged == rho
    else:
        assert rho > 1.0
        assert rho_judged == validate_with_transient(datum, MODEL, est)[1] < 1.0
    assert res.beta < 1.0


def test_a_controller_that_is_not_the_models_shape_is_refused() -> None:
    datum = make_datum(multisine(0, 0.3)[:, None], multisine(1, 0.3)[:, None], ts_s=TS,
                       period_samples=PERIOD)  # fmt: skip
    two = FixedController(lti.StateSpace([], [], [], np.zeros((2, 4)), dt_s=TS))
    with pytest.raises(ModelError, match="needs 2"):
        LoopAtBins.of(two.system, MODEL, MODEL.response(datum.theta, TS), LPM, datum)


def test_bad_settings_fail_up_front_with_the_fix() -> None:
    pi = FixedController(PI)
    with pytest.raises(ModelError, match="set transient to local_polynomial"):
        closed_loop_judge(pi, None, [MODEL], 2)
    with pytest.raises(ModelError, match="set periods_per_window >= 2"):
        closed_loop_judge(pi, LPM, [MODEL], 1)
    pair = PIPair(ts_s=TS, kp=(1.0, 1.0), ti_s=(10.0, 10.0), filter_s=0.0)
    with pytest.raises(ModelError, match="give a controller of its channels"):
        closed_loop_judge(pair, LPM, [MODEL], 2)
    assert closed_loop_judge(pi, LPM, [MODEL], 2) is not None


def test_a_window_the_controller_cannot_be_linearised_at_is_judged_directly() -> None:
    """The rig's PI pair at shut valves (no total flow, no hot fraction): the direct form."""
    rng = np.random.default_rng(2)
    u = np.column_stack([multisine(2, 0.3), multisine(3, 0.3)])  # mean 0: no flow
    y = 0.01 * rng.standard_normal((N, 2))
    datum = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    two = load_model("B")
    est = transient_estimate(LPM, two, TS, N)
    pair = PIPair(ts_s=TS, kp=(0.9, 0.7), ti_s=(122.5, 53.8), filter_s=2.0)
    res, rho = ClosedLoopJudge(pair, LPM)(datum, two, est)
    ref, ref_rho = validate_with_transient(datum, two, est)
    assert (res.beta, rho) == (ref.beta, ref_rho)


def test_a_controller_file_in_the_lti_form_is_the_system(tmp_path) -> None:
    path = tmp_path / "k.yaml"
    path.write_text(
        yaml.safe_dump(
            {"lti": {"ss": {"A": PI.a.tolist(), "B": PI.b.tolist(), "C": PI.c.tolist(),
                            "D": PI.d.tolist(), "dt_s": TS}}}
        )
    )  # fmt: skip
    got = controller_of(str(path), TS)
    assert isinstance(got, FixedController)
    theta = np.linspace(0.0, 3.0, 9)
    np.testing.assert_allclose(
        feedback_response(got.system, theta), feedback_response(PI, theta), rtol=1e-12
    )
    with pytest.raises(ModelFileError, match=r"discrete at the monitor's 0\.5 s"):
        controller_of(str(path), 0.5)
    path.write_text("pid: {kp: 1}\n")
    with pytest.raises(ModelFileError, match="not a controller"):
        controller_of(str(path), TS)
