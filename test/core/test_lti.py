"""Tests of core.lti: realisation, zero-order hold, frequency and pulse responses.

References: closed-form ZOH of a first-order lag, scipy's cont2discrete applied to the
transfer function (not the state space), scipy's dfreqresp/dimpulse, and direct evaluation
of C (zI - A)^-1 B + D with a linear solve per frequency.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.signal
from hypothesis import given
from hypothesis import strategies as st

from twotank_validation.core import lti
from twotank_validation.core.lti import StateSpace
from twotank_validation.errors import DimensionError, ModelError, UnstableModelError


def _direct_response(a, b, c, d, z):
    """C (zI - A)^-1 B + D at each z, one linear solve per point."""
    eye = np.eye(a.shape[0])
    return np.array([c @ np.linalg.solve(zz * eye - a, b) + d for zz in z])


def _poly_tf(num, den, z):
    return np.polyval(num, z) / np.polyval(den, z)


# --------------------------------------------------------------------------- realisation


@pytest.mark.parametrize(
    ("num", "den"),
    [
        ([2.0], [5.0, 1.0]),
        ([16.5, 0.1], [20.0, 1.0]),
        ([1.0, 0.5, 2.0], [1.0, 3.0, 2.0]),
        ([0.0, 0.0, 3.0], [0.0, 1.0, 1.0]),  # leading zeros are trimmed
        ([0.0], [1.0, 2.0]),
    ],
)
@pytest.mark.filterwarnings("ignore::scipy.signal.BadCoefficients")
def test_from_transfer_function_continuous_response(num, den):
    sys = lti.from_transfer_function(num, den)
    assert not sys.is_discrete
    assert sys.shape == (1, 1)
    s = 1j * np.array([0.0, 0.01, 0.3, 2.0, 50.0])
    got = _direct_response(sys.a, sys.b, sys.c, sys.d, s)[:, 0, 0]
    np.testing.assert_allclose(got, _poly_tf(num, den, s), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize(
    ("tau", "k", "dt"), [(5.0, 2.0, 1.0), (53.8, 1.25, 1.0), (0.05, 1.0, 1.0), (0.25, 0.05, 0.1)]
)
def test_zoh_first_order_lag_closed_form(tau, k, dt):
    sys = lti.discretise(lti.from_transfer_function([k], [tau, 1.0]), dt)
    assert sys.dt_s == dt
    assert sys.n_states == 1
    pole = np.exp(-dt / tau)
    assert sys.a[0, 0] == pytest.approx(pole, rel=1e-12)
    # Discrete tf k (1 - e^{-T/tau}) / (z - e^{-T/tau}): first pulse coefficient and DC gain.
    assert (sys.c @ sys.b)[0, 0] == pytest.approx(k * (1 - pole), rel=1e-10)
    assert sys.d[0, 0] == 0.0
    dc = (sys.c @ np.linalg.solve(np.eye(1) - sys.a, sys.b) + sys.d)[0, 0]
    assert dc == pytest.approx(k, rel=1e-10)
    theta = np.array([0.0, 0.1, 1.0, np.pi])
    z = np.exp(1j * theta)
    np.testing.assert_allclose(
        lti.frequency_response(sys, theta)[:, 0, 0], k * (1 - pole) / (z - pole), rtol=1e-10
    )


@pytest.mark.parametrize(
    ("num", "den", "dt"),
    [
        ([16.5, 0.1], [20.0, 1.0], 1.0),
        ([1.0, 0.5, 2.0], [1.0, 3.0, 2.0], 0.3),
        ([4.0], [1.0, 0.4, 4.0], 0.2),  # lightly damped pair
        ([1.0, -1.0], [1.0, 2.0, 3.0, 1.0], 0.5),
    ],
)
def test_discretise_matches_scipy_on_transfer_function(num, den, dt):
    numd, dend, _ = scipy.signal.cont2discrete((num, den), dt, method="zoh")
    sys = lti.discretise(lti.from_transfer_function(num, den), dt)
    theta = np.linspace(0.0, np.pi, 17)
    z = np.exp(1j * theta)
    ref = _poly_tf(np.ravel(numd), dend, z)
    np.testing.assert_allclose(lti.frequency_response(sys, theta)[:, 0, 0], ref, rtol=1e-9)


def test_discretise_static_and_discrete_systems():
    k = np.array([[1.0, 2.0], [3.0, 4.0]])
    s = lti.discretise(lti.static_gain(k), 0.5)
    assert s.dt_s == 0.5
    assert s.n_states == 0
    np.testing.assert_array_equal(s.d, k)
    np.testing.assert_array_equal(lti.frequency_response(s, np.array([0.0, 1.0]))[1].real, k)
    d = StateSpace([[0.5]], [[1.0]], [[1.0]], [[0.0]], 0.5)
    assert lti.discretise(d, 0.5) is d
    with pytest.raises(ModelError, match=r"sample period 0\.5 s but the datum has 0\.25 s"):
        lti.discretise(d, 0.25)


def test_static_transfer_function_is_a_gain_away_from_dc():
    # 3/2 at s = j and s = 10 j (s = 0 is covered by the static-gain test below).
    sys = lti.from_transfer_function([3.0], [2.0])
    got = _direct_response(sys.a, sys.b, sys.c, sys.d, np.array([1j, 10j]))[:, 0, 0]
    np.testing.assert_allclose(got, [1.5, 1.5])


def test_static_transfer_function_is_stable_and_finite():
    sys = lti.from_transfer_function([0.5], [1.0])
    lti.check_stable(sys, "constant tf")
    resp = lti.frequency_response(lti.discretise(sys, 1.0), np.array([0.0, 1.0]))
    np.testing.assert_allclose(resp[:, 0, 0], [0.5, 0.5])


def test_a_zero_numerator_is_a_zero_gain_without_states_or_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sys = lti.from_transfer_function([0.0, 0.0], [0.5, 1.0])
    assert sys.n_states == 0
    np.testing.assert_allclose(sys.d, [[0.0]])


def test_improper_transfer_function():
    with pytest.raises(ModelError, match=r"num=.*den=.* is improper"):
        lti.from_transfer_function([1.0, 0.0, 1.0], [1.0, 1.0])
    # Equal degrees (biproper) are fine: s / (s + 1) has D = 1.
    assert lti.from_transfer_function([1.0, 0.0], [1.0, 1.0]).d[0, 0] == pytest.approx(1.0)


def test_improper_transfer_function_message_is_legible():
    with pytest.raises(ModelError) as info:
        lti.from_transfer_function([1.0, 0.0, 1.0], [1.0, 1.0])
    assert "num=[1.0, 0.0, 1.0] den=[1.0, 1.0]" in str(info.value)


@pytest.mark.parametrize("den", [[0.0, 0.0], [], [0.0]])
def test_zero_denominator(den):
    with pytest.raises(ModelError, match=r"denominator .* is zero"):
        lti.from_transfer_function([1.0], den)


# --------------------------------------------------------------------------- StateSpace checks


@pytest.mark.parametrize("which", ["A", "B", "C", "D"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_matrices(which, bad):
    mats = {"A": [[-1.0, 0.0], [0.0, -2.0]], "B": [[1.0], [1.0]], "C": [[1.0, 0.0]], "D": [[0.0]]}
    m = np.array(mats[which])
    m[0, 0] = bad
    mats[which] = m
    with pytest.raises(ModelError, match=f"matrix {which} holds NaN or inf"):
        StateSpace(mats["A"], mats["B"], mats["C"], mats["D"])


@pytest.mark.parametrize(
    ("a", "b", "c", "d", "msg"),
    [
        (np.zeros((2, 3)), np.zeros((2, 1)), np.zeros((1, 3)), np.zeros((1, 1)), "square"),
        (np.zeros((2, 2)), np.zeros((3, 1)), np.zeros((1, 2)), np.zeros((1, 1)), "disagree"),
        (np.zeros((2, 2)), np.zeros((2, 1)), np.zeros((1, 3)), np.zeros((1, 1)), "disagree"),
        (np.zeros((2, 2)), np.zeros((2, 1)), np.zeros((1, 2)), np.zeros((2, 1)), "disagree"),
        (np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((1, 2)), np.zeros((1, 1)), "disagree"),
    ],
)
def test_inconsistent_shapes(a, b, c, d, msg):
    with pytest.raises(DimensionError, match=msg):
        StateSpace(a, b, c, d)


@pytest.mark.parametrize("dt", [0.0, -1.0, np.nan, np.inf])
def test_bad_sample_period(dt):
    with pytest.raises(ModelError, match="sample period must be positive"):
        StateSpace([[0.5]], [[1.0]], [[1.0]], [[0.0]], dt)


def test_static_gain_shapes():
    s = lti.static_gain(np.ones((3, 2)))
    assert s.shape == (3, 2)
    assert s.n_states == 0
    assert s.b.shape == (0, 2)
    assert s.c.shape == (3, 0)
    assert lti.static_gain(2.0).shape == (1, 1)


# --------------------------------------------------------------------------- stability


@pytest.mark.parametrize(
    "a",
    [
        [[0.1]],  # unstable real pole
        [[0.0]],  # integrator
        [[0.0, 1.0], [-4.0, 0.0]],  # undamped oscillator, poles +-2j
        [[-1.0, 0.0], [0.0, 0.5]],
    ],
)
def test_check_stable_continuous_unstable(a):
    n = len(a)
    sys = StateSpace(a, np.ones((n, 1)), np.ones((1, n)), [[0.0]])
    with pytest.raises(UnstableModelError, match="my plant is not stable"):
        lti.check_stable(sys, "my plant")


@pytest.mark.parametrize(
    "a",
    [
        [[1.0]],  # pole on the unit circle
        [[-1.2]],
        [[0.0, 1.0], [-1.0, 0.0]],  # poles +-j on the unit circle
        [[0.5, 0.0], [0.0, 1.01]],
    ],
)
def test_check_stable_discrete_unstable(a):
    n = len(a)
    sys = StateSpace(a, np.ones((n, 1)), np.ones((1, n)), [[0.0]], 1.0)
    with pytest.raises(UnstableModelError, match="not stable"):
        lti.check_stable(sys, "weight")


def test_check_stable_passes_for_stable():
    lti.check_stable(StateSpace([[-0.01, 5.0], [0.0, -3.0]], [[1.0], [1.0]], [[1.0, 0]], 0), "c")
    # |p| = 0.99 < 1, and an (unstable as continuous) positive pole is fine in discrete time.
    lti.check_stable(
        StateSpace([[0.99, 0.0], [0.0, -0.5]], np.ones((2, 1)), np.ones((1, 2)), 0, 1), "d"
    )
    lti.check_stable(lti.static_gain(5.0), "gain")
    lti.check_stable(lti.discretise(lti.from_transfer_function([1.0], [100.0, 1.0]), 1.0), "zoh")


def test_zoh_of_stable_is_stable_and_of_unstable_is_unstable():
    stable = lti.from_transfer_function([1.0], [1.0, 0.2, 1.0])
    lti.check_stable(lti.discretise(stable, 0.5), "zoh")
    unstable = lti.from_transfer_function([1.0], [1.0, -0.2, 1.0])
    with pytest.raises(UnstableModelError):
        lti.check_stable(lti.discretise(unstable, 0.5), "zoh")


# --------------------------------------------------------------------------- frequency response


def test_frequency_response_needs_discrete():
    with pytest.raises(ModelError, match="discrete"):
        lti.frequency_response(lti.from_transfer_function([1.0], [1.0, 1.0]), np.array([0.1]))


def test_frequency_response_siso_vs_dfreqresp():
    num, den = [1.0, 0.5, 2.0], [1.0, 3.0, 2.0]
    sys = lti.discretise(lti.from_transfer_function(num, den), 0.4)
    theta = np.linspace(0.0, np.pi, 33)
    dl = scipy.signal.dlti(sys.a, sys.b, sys.c, sys.d, dt=0.4)
    _, ref = scipy.signal.dfreqresp(dl, w=theta)
    np.testing.assert_allclose(lti.frequency_response(sys, theta)[:, 0, 0], ref, rtol=1e-10)


@given(
    n=st.integers(min_value=1, max_value=5),
    p=st.integers(min_value=1, max_value=3),
    m=st.integers(min_value=1, max_value=3),
    seed=st.integers(min_value=0, max_value=2**31 - 1),
)
def test_frequency_response_mimo_vs_direct(n, p, m, seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, n))
    a = 0.9 * a / max(1.0, np.max(np.abs(np.linalg.eigvals(a))))
    b, c, d = rng.normal(size=(n, m)), rng.normal(size=(p, n)), rng.normal(size=(p, m))
    sys = StateSpace(a, b, c, d, 0.1)
    theta = np.array([0.0, 0.05, 0.7, 2.0, np.pi])
    got = lti.frequency_response(sys, theta)
    assert got.shape == (5, p, m)
    np.testing.assert_allclose(
        got, _direct_response(a, b, c, d, np.exp(1j * theta)), rtol=1e-8, atol=1e-10
    )


@pytest.mark.parametrize("pole", [0.5, -0.3, 0.95])
def test_frequency_response_defective_jordan_block(pole):
    # Double pole as a Jordan block: A is not diagonalisable, so the per-bin solve is used.
    a = np.array([[pole, 1.0], [0.0, pole]])
    b = np.array([[0.0], [1.0]])
    c = np.array([[1.0, 0.0]])
    sys = StateSpace(a, b, c, [[0.2]], 1.0)
    theta = np.linspace(0.0, np.pi, 9)
    z = np.exp(1j * theta)
    ref = 1.0 / (z - pole) ** 2 + 0.2  # closed form C (zI - J)^-1 B + D
    np.testing.assert_allclose(lti.frequency_response(sys, theta)[:, 0, 0], ref, rtol=1e-12)


def test_frequency_response_defective_mimo():
    # 3x3 Jordan block plus a separate pole, two inputs and outputs.
    a = np.array(
        [[0.6, 1.0, 0.0, 0.0], [0.0, 0.6, 1.0, 0.0], [0.0, 0.0, 0.6, 0.0], [0.0, 0.0, 0.0, -0.4]]
    )
    rng = np.random.default_rng(9)
    b, c, d = rng.normal(size=(4, 2)), rng.normal(size=(2, 4)), rng.normal(size=(2, 2))
    sys = StateSpace(a, b, c, d, 0.5)
    theta = np.array([0.0, 0.3, 1.9, np.pi])
    np.testing.assert_allclose(
        lti.frequency_response(sys, theta),
        _direct_response(a, b, c, d, np.exp(1j * theta)),
        rtol=1e-10,
    )


def test_frequency_response_nearly_defective():
    # Poles 0.5 and 0.5 + 1e-7: eigenvectors nearly parallel (ill-conditioned diagonalisation).
    delta = 1e-7
    a = np.array([[0.5, 1.0], [0.0, 0.5 + delta]])
    sys = StateSpace(a, [[0.0], [1.0]], [[1.0, 0.0]], [[0.0]], 1.0)
    theta = np.linspace(0.01, np.pi, 25)
    z = np.exp(1j * theta)
    ref = 1.0 / ((z - 0.5) * (z - 0.5 - delta))
    np.testing.assert_allclose(lti.frequency_response(sys, theta)[:, 0, 0], ref, rtol=1e-6)


# --------------------------------------------------------------------------- impulse response


@given(
    n=st.integers(min_value=1, max_value=4),
    p=st.integers(min_value=1, max_value=3),
    m=st.integers(min_value=1, max_value=3),
    seed=st.integers(min_value=0, max_value=2**31 - 1),
)
def test_impulse_response_vs_dimpulse(n, p, m, seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, n))
    a = 0.95 * a / max(1.0, np.max(np.abs(np.linalg.eigvals(a))))
    b, c, d = rng.normal(size=(n, m)), rng.normal(size=(p, n)), rng.normal(size=(p, m))
    sys = StateSpace(a, b, c, d, 0.2)
    n_coeffs = 30
    got = lti.impulse_response(sys, n_coeffs)
    assert got.shape == (n_coeffs, p, m)
    _, ys = scipy.signal.dimpulse((a, b, c, d, 0.2), n=n_coeffs)
    ref = np.stack(ys, axis=2)  # one (n_coeffs, p) array per input
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("delta", [0.0, 1e-7, 1e-3])
def test_impulse_response_jordan_and_nearly_defective(delta):
    # [[a, 1], [0, a + delta]]: delta = 0 is a Jordan block (the per-sample recursion);
    # small delta makes the eigenvector basis ill-conditioned. Closed form of C A^(k-1) B:
    # k-th coefficient = sum_{i+j=k-2} a^i (a + delta)^j, i.e. (k-1) a^(k-2) when delta = 0.
    a = 0.9
    sys = StateSpace([[a, 1.0], [0.0, a + delta]], [[0.0], [1.0]], [[1.0, 0.0]], [[0.0]], 1.0)
    n_coeffs = 200
    got = lti.impulse_response(sys, n_coeffs)[:, 0, 0]
    k = np.arange(2, n_coeffs)
    if delta == 0.0:
        ref_tail = (k - 1) * a ** (k - 2.0)
    else:
        ref_tail = ((a + delta) ** (k - 1) - a ** (k - 1)) / delta
    ref = np.concatenate([[0.0, 0.0], ref_tail])
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-9 * np.max(ref))


def test_impulse_response_first_order_closed_form():
    tau, k, dt = 4.0, 3.0, 1.0
    sys = lti.discretise(lti.from_transfer_function([k], [tau, 1.0]), dt)
    pole = np.exp(-dt / tau)
    got = lti.impulse_response(sys, 20)[:, 0, 0]
    ref = np.concatenate([[0.0], k * (1 - pole) * pole ** np.arange(19)])
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-15)
    # The pulse sums to the DC gain (geometric series).
    long = lti.impulse_response(sys, 400)[:, 0, 0]
    assert long.sum() == pytest.approx(k, rel=1e-10)


def test_impulse_response_static_gain():
    sys = lti.static_gain([[1.0, 2.0]], dt_s=1.0)
    got = lti.impulse_response(sys, 4)
    np.testing.assert_array_equal(got[0], [[1.0, 2.0]])
    np.testing.assert_array_equal(got[1:], 0.0)


# --------------------------------------------------------------------------- output delays


@given(
    delay_samples=st.integers(min_value=0, max_value=6),
    pole=st.floats(min_value=0.1, max_value=0.9),
)
def test_integer_output_delay_equals_shift_register(delay_samples, pole):
    """A delay of k samples on the output is the system followed by a k-state shift register."""
    dt = 0.5
    sys = StateSpace([[pole]], [[1.0]], [[2.0]], [[0.3]], dt, (delay_samples * dt,))
    # Reference: plant state x0 then registers r_i(k) = y(k - i), i = 1..k_delay, where
    # y = 2 x0 + 0.3 u; the output is the last register (or y itself without delay).
    n = 1 + delay_samples
    a = np.zeros((n, n))
    b = np.zeros((n, 1))
    c = np.zeros((1, n))
    a[0, 0], b[0, 0] = pole, 1.0
    if delay_samples == 0:
        c[0, 0], d = 2.0, np.array([[0.3]])
    else:
        a[1, 0], b[1, 0] = 2.0, 0.3
        for i in range(2, n):
            a[i, i - 1] = 1.0
        c[0, n - 1], d = 1.0, np.zeros((1, 1))
    ref = StateSpace(a, b, c, d, dt)
    theta = np.linspace(0.01, np.pi, 37)
    np.testing.assert_allclose(
        lti.frequency_response(sys, theta), lti.frequency_response(ref, theta), atol=1e-12
    )
    np.testing.assert_allclose(
        lti.impulse_response(sys, 20), lti.impulse_response(ref, 20), atol=1e-12
    )


def test_fractional_delay_is_a_pure_phase_and_survives_discretisation():
    cont = StateSpace([[-0.5]], [[1.0]], [[1.0]], [[0.0]], None, (1.25,))
    disc = lti.discretise(cont, 0.5)
    assert disc.output_delays_s == (1.25,)
    plain = lti.discretise(StateSpace([[-0.5]], [[1.0]], [[1.0]], [[0.0]]), 0.5)
    theta = np.linspace(0.0, np.pi, 11)
    ratio = lti.frequency_response(disc, theta) / lti.frequency_response(plain, theta)
    np.testing.assert_allclose(ratio[:, 0, 0], np.exp(-1j * theta * 2.5), atol=1e-12)


def test_bad_output_delays_are_refused():
    with pytest.raises(DimensionError, match="one delay"):
        StateSpace([[-1.0]], [[1.0]], [[1.0], [2.0]], [[0.0], [0.0]], None, (1.0,))
    with pytest.raises(ModelError, match=">= 0"):
        StateSpace([[-1.0]], [[1.0]], [[1.0]], [[0.0]], None, (-1.0,))
    assert StateSpace([[-1.0]], [[1.0]], [[1.0]], [[0.0]], None, (0.0,)).output_delays_s == ()
