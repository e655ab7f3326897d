"""Tests of twotank_validation.core.stats: residual whiteness and cross-correlation tests."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import scipy.signal
import scipy.stats
from hypothesis import given
from hypothesis import strategies as st

from twotank_validation.core.stats import (
    CrossCorrelationResult,
    ResidualTests,
    WhitenessResult,
    _chi2_quadratic_form,
    asymptotic_covariance,
    autocovariance,
    cross_correlation_test,
    cross_covariance,
    residual_tests,
    whiteness_test,
)
from twotank_validation.errors import DatumError

N_SEEDS = 300
N_SAMPLES = 2000
LAGS = 25
LEVEL = 0.05
# Rejection rate of a calibrated test over N_SEEDS independent runs: alpha +- 3 sigma.
SIGMA = math.sqrt(LEVEL * (1 - LEVEL) / N_SEEDS)
LOW, HIGH = LEVEL - 3 * SIGMA, LEVEL + 3 * SIGMA


# --------------------------------------------------------------------------- references


def loop_cross_covariance(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """Direct double loop: (1/N) sum_k ac(k+tau) bc(k), tau = 0..max_lag."""
    n = len(a)
    ac = [float(v) - sum(a) / n for v in a]
    bc = [float(v) - sum(b) / n for v in b]
    out = []
    for tau in range(max_lag + 1):
        total = 0.0
        for k in range(n - tau):
            total += ac[k + tau] * bc[k]
        out.append(total / n)
    return np.array(out)


def loop_p_matrix(a: np.ndarray, u: np.ndarray, n_lags: int, k_max: int) -> np.ndarray:
    """P[t1, t2] = sum_{|k|<=k_max} R_a(k) R_u(k + t1 - t2), from the loop references."""
    n = len(a)
    r_a = loop_cross_covariance(a, a, n - 1)
    r_u = loop_cross_covariance(u, u, n - 1)

    def at(r: np.ndarray, k: int) -> float:
        return float(r[abs(k)]) if abs(k) < n else 0.0

    P = np.zeros((n_lags, n_lags))
    for t1 in range(n_lags):
        for t2 in range(n_lags):
            P[t1, t2] = sum(at(r_a, k) * at(r_u, k + t1 - t2) for k in range(-k_max, k_max + 1))
    return P


def ar1(rng: np.random.Generator, pole: float, n: int = N_SAMPLES) -> np.ndarray:
    return np.asarray(scipy.signal.lfilter([1.0], [1.0, -pole], rng.standard_normal(n)))


def prbs(rng: np.random.Generator, n: int = N_SAMPLES, hold: int = 5) -> np.ndarray:
    return np.repeat(np.sign(rng.standard_normal(n // hold)), hold)


def naive_cross_statistic(eps: np.ndarray, u: np.ndarray, n_lags: int) -> float:
    """zeta with P = R_eps(0) R_u(0) I, i.e. ignoring the colour of both signals."""
    r = cross_covariance(eps, u, n_lags - 1)
    var_eps, var_u = float(autocovariance(eps, 0)[0]), float(autocovariance(u, 0)[0])
    return len(eps) * float(np.sum(r**2)) / (var_eps * var_u)


# --------------------------------------------------------------------------- correlations


def test_autocovariance_matches_direct_loop() -> None:
    rng = np.random.default_rng(1)
    x = 3.0 + ar1(rng, 0.7, 257)
    np.testing.assert_allclose(autocovariance(x, 40), loop_cross_covariance(x, x, 40), atol=1e-12)


def test_cross_covariance_matches_direct_loop_and_lag_direction() -> None:
    rng = np.random.default_rng(2)
    u = rng.standard_normal(301) - 1.5
    eps = rng.standard_normal(301) + 0.4 * np.roll(u, 3)
    expected = loop_cross_covariance(eps, u, 30)
    np.testing.assert_allclose(cross_covariance(eps, u, 30), expected, atol=1e-12)
    # eps(k) contains u(k-3): the residual follows the input, so the peak is at tau = +3.
    assert int(np.argmax(np.abs(expected))) == 3


def test_lags_beyond_record_are_zero() -> None:
    x = np.array([1.0, -2.0, 0.5, 4.0])
    got = autocovariance(x, 6)
    np.testing.assert_allclose(got, [*loop_cross_covariance(x, x, 3), 0, 0, 0], atol=1e-14)


@given(
    n=st.integers(min_value=2, max_value=60),
    max_lag=st.integers(min_value=0, max_value=70),
    seed=st.integers(min_value=0, max_value=2**32 - 1),
)
def test_cross_covariance_matches_loop_property(n: int, max_lag: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=n) * 10, rng.normal(size=n)
    expected = loop_cross_covariance(a, b, min(max_lag, n - 1))
    expected = np.concatenate([expected, np.zeros(max_lag + 1 - len(expected))])
    np.testing.assert_allclose(cross_covariance(a, b, max_lag), expected, atol=1e-12)


def test_asymptotic_covariance_matches_loop_full_and_truncated() -> None:
    rng = np.random.default_rng(3)
    eps, u = ar1(rng, 0.8, 90), ar1(rng, -0.5, 90)
    full_ref = loop_p_matrix(eps, u, 6, 89)
    np.testing.assert_allclose(asymptotic_covariance(eps, u, 6), full_ref, rtol=1e-10, atol=1e-12)
    trunc_ref = loop_p_matrix(eps, u, 6, 6)
    got = asymptotic_covariance(eps, u, 6, covariance_lags=6)
    np.testing.assert_allclose(got, trunc_ref, rtol=1e-10, atol=1e-12)
    assert not np.allclose(got, full_ref)  # the truncation does make a difference here
    # Truncating beyond the record is the same estimate as the full sum (two code paths).
    np.testing.assert_allclose(
        asymptotic_covariance(eps, u, 6, covariance_lags=200), full_ref, rtol=1e-10, atol=1e-12
    )


def test_full_sum_covariance_is_positive_semidefinite_where_truncation_is_not() -> None:
    rng = np.random.default_rng(4)
    eps, u = ar1(rng, 0.95), prbs(rng)
    assert np.linalg.eigvalsh(asymptotic_covariance(eps, u, LAGS)).min() > 0
    assert np.linalg.eigvalsh(asymptotic_covariance(eps, u, LAGS, covariance_lags=LAGS)).min() < 0


# --------------------------------------------------------------------------- identities


def test_whiteness_statistic_is_n_times_sum_of_squared_autocorrelations() -> None:
    rng = np.random.default_rng(5)
    eps = ar1(rng, 0.2, 500)
    res = whiteness_test(eps, max_lag=10, alpha=0.05)
    r = res.autocorrelation
    assert r.shape == (11,)
    assert r[0] == pytest.approx(1.0)
    assert res.statistic == pytest.approx(500 * float(np.sum(r[1:] ** 2)), rel=1e-12)
    R = loop_cross_covariance(eps, eps, 10)
    assert res.statistic == pytest.approx(500 / R[0] ** 2 * float(np.sum(R[1:] ** 2)), rel=1e-9)
    assert res.dof == 10
    assert res.threshold == pytest.approx(scipy.stats.chi2.ppf(0.95, 10))
    assert res.p_value == pytest.approx(scipy.stats.chi2.sf(res.statistic, 10))
    assert res.band == pytest.approx(scipy.stats.norm.ppf(0.975) / math.sqrt(500))


def test_cross_statistic_matches_explicit_formula() -> None:
    rng = np.random.default_rng(6)
    u = ar1(rng, 0.6, 400)
    eps = ar1(rng, 0.3, 400)
    res = cross_correlation_test(eps, u, max_lag=8, alpha=0.05)
    R_eu = loop_cross_covariance(eps, u, 7)
    P = loop_p_matrix(eps, u, 8, 399)
    assert res.statistic == pytest.approx(400 * R_eu @ np.linalg.solve(P, R_eu), rel=1e-8)
    assert res.dof == 8
    assert not res.pseudo_inverse_used
    norm = math.sqrt(loop_cross_covariance(eps, eps, 0)[0] * loop_cross_covariance(u, u, 0)[0])
    np.testing.assert_allclose(res.cross_correlation, R_eu / norm, rtol=1e-9)
    band = scipy.stats.norm.ppf(0.975) * math.sqrt(P[0, 0] / 400) / norm
    np.testing.assert_allclose(res.band, np.full(8, band), rtol=1e-9)


@pytest.mark.parametrize("test", ["whiteness", "cross"])
def test_passed_agrees_with_p_value(test: str) -> None:
    for seed in range(40):
        rng = np.random.default_rng(seed)
        eps = ar1(rng, 0.05, 400)
        u = rng.standard_normal(400)
        res: WhitenessResult | CrossCorrelationResult
        if test == "whiteness":
            res = whiteness_test(eps, 10, 0.2)
        else:
            res = cross_correlation_test(eps, u, 10, 0.2)
        assert res.passed == (res.p_value >= 0.2)
        assert res.passed == (res.statistic <= res.threshold)


@given(
    scale_eps=st.floats(min_value=1e-3, max_value=1e3) | st.floats(min_value=-1e3, max_value=-1e-3),
    scale_u=st.floats(min_value=1e-3, max_value=1e3),
    offset=st.floats(min_value=-1e3, max_value=1e3),
)
def test_statistics_invariant_under_affine_rescaling(
    scale_eps: float, scale_u: float, offset: float
) -> None:
    rng = np.random.default_rng(7)
    eps, u = ar1(rng, 0.4, 300), ar1(rng, 0.8, 300)
    w0, c0 = whiteness_test(eps, 10), cross_correlation_test(eps, u, 10)
    w1 = whiteness_test(scale_eps * eps + offset, 10)
    c1 = cross_correlation_test(scale_eps * eps + offset, scale_u * u - offset, 10)
    assert w1.statistic == pytest.approx(w0.statistic, rel=1e-7)
    assert c1.statistic == pytest.approx(c0.statistic, rel=1e-7)
    np.testing.assert_allclose(
        np.sign(scale_eps) * c1.cross_correlation, c0.cross_correlation, rtol=1e-6, atol=1e-12
    )


def test_quadratic_form_pseudo_inverse_on_singular_matrix() -> None:
    v = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]]).T / np.array([1.0, math.sqrt(2)])
    P = v @ np.diag([4.0, 0.5]) @ v.T  # rank 2, exactly singular
    r = 2.0 * v[:, 0] + 3.0 * v[:, 1]
    value, rank, used = _chi2_quadratic_form(r, P)
    assert (rank, used) == (2, True)
    assert value == pytest.approx(2.0**2 / 4.0 + 3.0**2 / 0.5)
    value, rank, used = _chi2_quadratic_form(r, np.diag([4.0, 0.5, 1.0]))
    assert (rank, used) == (3, False)
    assert value == pytest.approx(4 / 4 + (3 / math.sqrt(2)) ** 2 * 3)
    with pytest.raises(DatumError, match="no positive eigenvalue"):
        _chi2_quadratic_form(r, -np.eye(3))


# --------------------------------------------------------------------------- calibration


def rejection_rate(statistics: list[float], dof: int = LAGS) -> float:
    threshold = scipy.stats.chi2.isf(LEVEL, dof)
    return float(np.mean(np.array(statistics) > threshold))


def test_whiteness_calibrated_on_white_gaussian_residuals() -> None:
    rejections = [
        not whiteness_test(np.random.default_rng(s).standard_normal(N_SAMPLES), LAGS, LEVEL).passed
        for s in range(N_SEEDS)
    ]
    assert LOW <= np.mean(rejections) <= HIGH


def test_cross_correlation_calibrated_with_coloured_input_naive_is_not() -> None:
    proper, naive = [], []
    for s in range(N_SEEDS):
        rng = np.random.default_rng(1000 + s)
        u = ar1(rng, 0.9)  # low-pass input, independent of the residual
        eps = rng.standard_normal(N_SAMPLES)
        res = cross_correlation_test(eps, u, LAGS, LEVEL)
        assert res.dof == LAGS
        assert not res.pseudo_inverse_used
        proper.append(res.statistic)
        naive.append(naive_cross_statistic(eps, u, LAGS))
    assert LOW <= rejection_rate(proper) <= HIGH
    # Treating the lags as independent (P = R_eps(0) R_u(0) I) ignores the input colour.
    assert rejection_rate(naive) > HIGH


def test_cross_correlation_calibrated_for_output_error_residual_truncation_is_not() -> None:
    """Low-pass residual with PRBS input: the usual output-error validation situation.

    Ljung's truncation of the P-sum at |k| <= M gives an indefinite P and over-rejects;
    the default all-lags estimate stays calibrated.
    """
    proper, truncated, pinv = [], [], 0
    for s in range(N_SEEDS):
        rng = np.random.default_rng(2000 + s)
        eps, u = ar1(rng, 0.95), prbs(rng)
        proper.append(cross_correlation_test(eps, u, LAGS, LEVEL).statistic)
        res = cross_correlation_test(eps, u, LAGS, LEVEL, covariance_lags=LAGS)
        truncated.append(not res.passed)
        pinv += res.pseudo_inverse_used
        assert res.pseudo_inverse_used == (res.dof < LAGS)
    assert LOW <= rejection_rate(proper) <= HIGH
    assert np.mean(truncated) > HIGH
    assert pinv > N_SEEDS // 2


# --------------------------------------------------------------------------- power


def test_whiteness_rejects_ar1_residual() -> None:
    rng = np.random.default_rng(8)
    res = whiteness_test(ar1(rng, 0.5), LAGS, 0.01)
    assert not res.passed
    assert res.p_value < 1e-6
    assert res.autocorrelation[1] == pytest.approx(0.5, abs=0.1)
    assert abs(res.autocorrelation[1]) > res.band


def test_cross_correlation_rejects_residual_driven_by_input() -> None:
    rng = np.random.default_rng(9)
    u = prbs(rng, hold=1)  # white binary input: no correlation between neighbouring lags
    unmodelled = scipy.signal.lfilter([0.0, 0.2, 0.1], [1.0, -0.6], u)
    eps = unmodelled + 0.5 * rng.standard_normal(N_SAMPLES)
    res = cross_correlation_test(eps, u, LAGS, 0.01)
    assert not res.passed
    assert res.p_value < 1e-6
    # the unmodelled dynamics has one sample delay: lag 0 is inside the band, lag 1 is not
    assert abs(res.cross_correlation[0]) < res.band[0] < abs(res.cross_correlation[1])


def test_cross_correlation_ignores_anticausal_dependence() -> None:
    """Residual ahead of the input (feedback) is outside the tested causal lags."""
    rng = np.random.default_rng(10)
    eps = rng.standard_normal(N_SAMPLES)
    u = np.roll(eps, 3) + 0.1 * rng.standard_normal(N_SAMPLES)  # u(k) = eps(k-3)
    assert cross_correlation_test(eps, u, LAGS, 0.01).passed
    assert not cross_correlation_test(u, eps, LAGS, 0.01).passed


def test_band_widens_for_coloured_signals() -> None:
    rng = np.random.default_rng(11)
    white = cross_correlation_test(rng.standard_normal(N_SAMPLES), prbs(rng, hold=1), LAGS, 0.05)
    z = scipy.stats.norm.ppf(0.975) / math.sqrt(N_SAMPLES)
    np.testing.assert_allclose(white.band, z, rtol=0.15)
    coloured = cross_correlation_test(ar1(rng, 0.9), ar1(rng, 0.9), LAGS, 0.05)
    assert np.all(coloured.band > 2 * z)


# --------------------------------------------------------------------------- residual_tests


def test_residual_tests_multi_channel_and_to_dict() -> None:
    rng = np.random.default_rng(12)
    u = np.column_stack([prbs(rng), ar1(rng, 0.8)])
    eps = np.column_stack(
        [
            rng.standard_normal(N_SAMPLES),  # clean
            ar1(rng, 0.5) + scipy.signal.lfilter([0.0, 0.3], [1.0, -0.5], u[:, 1]),
        ]
    )
    res = residual_tests(eps, u, output_names=["h1", "h2"], input_names=["q1", "q2"], alpha=0.01)
    assert isinstance(res, ResidualTests)
    assert set(res.whiteness) == {"h1", "h2"}
    assert set(res.cross_correlation) == {("h1", "q1"), ("h1", "q2"), ("h2", "q1"), ("h2", "q2")}
    assert (res.max_lag, res.alpha) == (25, 0.01)
    assert res.whiteness["h1"].passed
    assert res.cross_correlation[("h1", "q1")].passed
    assert res.cross_correlation[("h1", "q2")].passed
    assert not res.whiteness["h2"].passed
    assert not res.cross_correlation[("h2", "q2")].passed
    assert not res.passed
    # same numbers as the single-channel functions
    single = cross_correlation_test(eps[:, 1], u[:, 1], 25, 0.01)
    assert res.cross_correlation[("h2", "q2")].statistic == pytest.approx(single.statistic)

    d = res.to_dict()
    text = json.dumps(d, allow_nan=False)
    back = json.loads(text)
    assert back == d
    assert back["passed"] is False
    assert back["whiteness"]["h2"]["passed"] is False
    assert len(back["whiteness"]["h1"]["autocorrelation"]) == 26
    assert len(back["cross_correlation"]["h2"]["q2"]["band"]) == 25
    assert set(back["cross_correlation"]["h1"]) == {"q1", "q2"}
    assert type(back["cross_correlation"]["h1"]["q1"]["dof"]) is int


def test_residual_tests_passes_clean_record_with_default_names() -> None:
    rng = np.random.default_rng(13)
    res = residual_tests(rng.standard_normal(N_SAMPLES), prbs(rng), max_lag=20, alpha=0.001)
    assert res.passed
    assert set(res.whiteness) == {"y0"}
    assert set(res.cross_correlation) == {("y0", "u0")}
    assert res.whiteness["y0"].dof == 20


def test_results_are_immutable() -> None:
    rng = np.random.default_rng(14)
    res = cross_correlation_test(rng.standard_normal(200), rng.standard_normal(200), 10)
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.statistic = 0.0  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        res.cross_correlation[0] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        whiteness_test(rng.standard_normal(200), 10).autocorrelation[0] = 2.0


# --------------------------------------------------------------------------- bad input


GOOD = np.random.default_rng(15).standard_normal(200)
GOOD_U = np.random.default_rng(16).standard_normal(200)


def with_value(x: np.ndarray, index: int, value: float) -> np.ndarray:
    y = x.copy()
    y[index] = value
    return y


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: whiteness_test(with_value(GOOD, 17, np.nan), 10), r"non-finite.*index 17"),
        (lambda: whiteness_test(with_value(GOOD, 3, np.inf), 10), r"residual.*non-finite"),
        (lambda: cross_correlation_test(GOOD, with_value(GOOD_U, 5, -np.inf), 10), r"u .*index 5"),
        (lambda: whiteness_test(GOOD[:39], 10), r"39 samples.*max_lag=10.*at least 40"),
        (lambda: cross_correlation_test(GOOD[:99], GOOD_U[:99], 25), r"at least 100"),
        (lambda: whiteness_test(np.full(200, 3.0), 10), r"zero variance.*3\.0"),
        (lambda: whiteness_test(np.full(200, 0.1), 10), r"zero variance"),
        (lambda: cross_correlation_test(GOOD, np.full(200, 2.0), 10), r"u has zero variance"),
        (lambda: cross_correlation_test(GOOD, GOOD_U[:150], 10), r"200 samples.*u has 150"),
        (lambda: whiteness_test(GOOD, 10, alpha=0.0), r"alpha.*between 0 and 1"),
        (lambda: whiteness_test(GOOD, 10, alpha=1.0), r"alpha"),
        (lambda: cross_correlation_test(GOOD, GOOD_U, 10, alpha=-0.1), r"alpha"),
        (lambda: whiteness_test(GOOD, 10, alpha=float("nan")), r"alpha"),
        (lambda: whiteness_test(GOOD, 0), r"max_lag must be at least 1"),
        (lambda: whiteness_test(GOOD, 2.5), r"max_lag must be an integer"),  # type: ignore[arg-type]
        (lambda: whiteness_test(GOOD.reshape(100, 2), 10), r"shape \(100, 2\)"),
        (lambda: whiteness_test(GOOD.astype(complex), 10), r"real numeric"),
        (lambda: cross_correlation_test(GOOD, GOOD_U, 10, covariance_lags=-1), r"non-negative"),
        (lambda: autocovariance(GOOD, -1), r"non-negative"),
        (
            lambda: residual_tests(np.column_stack([GOOD, GOOD]), GOOD_U, output_names=["a"]),
            r"output_names has 1 name",
        ),
        (
            lambda: residual_tests(GOOD, np.column_stack([GOOD_U, GOOD_U]), input_names=["q", "q"]),
            r"unique",
        ),
        (lambda: residual_tests(GOOD, GOOD_U, output_names="h1"), r"single string"),
        (
            lambda: residual_tests(np.column_stack([GOOD, np.ones(200)]), GOOD_U, max_lag=10),
            r"residual column 'y1' has zero variance",
        ),
        (
            lambda: residual_tests(GOOD, np.column_stack([GOOD_U, with_value(GOOD_U, 9, np.nan)])),
            r"inputs.*\(9, 1\)",
        ),
        (lambda: residual_tests(GOOD, GOOD_U[:190], max_lag=10), r"inputs has 190"),
        (lambda: residual_tests(np.zeros((200, 0)), GOOD_U, max_lag=10), r"no output column"),
        (lambda: residual_tests(GOOD.reshape(2, 10, 10), GOOD_U), r"shape \(2, 10, 10\)"),
    ],
)
def test_bad_input_raises_datum_error(call: object, match: str) -> None:
    assert callable(call)
    with pytest.raises(DatumError, match=match):
        call()


def test_datum_error_is_value_error() -> None:
    with pytest.raises(ValueError, match="alpha"):
        whiteness_test(GOOD, 10, alpha=2.0)
