"""Tests of twotank_validation.core.datum: record checks, scaled DFT, periodicity, noise, leakage.

References are computed independently of the package: Parseval's identity on the time
samples, closed-form DFTs of sinusoids, the variance of the DFT of white noise, and
closed-form pulse-response moments of a first-order discrete system.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.signal
from hypothesis import given
from hypothesis import strategies as st

from twotank_validation.core.datum import (
    NormConvention,
    assess_periodicity,
    check_record,
    leakage_bound,
    make_datum,
    noise_estimate,
    one_sided_weights,
    pulse_moment,
    scaled_dft,
)
from twotank_validation.errors import DatumError, DimensionError, TwotankError

CONVENTIONS = [NormConvention.POWER, NormConvention.ENERGY]


def _energy(x: np.ndarray, convention: NormConvention) -> np.ndarray:
    """The time-domain side of Parseval per channel: mean square (POWER) or sum of squares."""
    if convention is NormConvention.POWER:
        return np.mean(x**2, axis=0)
    return np.sum(x**2, axis=0)


# --------------------------------------------------------------------------- Parseval


@given(
    period=st.integers(min_value=2, max_value=40),
    n_periods=st.integers(min_value=1, max_value=6),
    n_in=st.integers(min_value=1, max_value=3),
    n_out=st.integers(min_value=1, max_value=3),
    seed=st.integers(min_value=0, max_value=2**31 - 1),
    convention=st.sampled_from(CONVENTIONS),
)
def test_parseval_holds_over_kept_bins(period, n_periods, n_in, n_out, seed, convention):
    rng = np.random.default_rng(seed)
    n = period * n_periods
    u = rng.normal(size=(n, n_in)) + rng.normal(size=n_in)
    y = 3.0 * rng.normal(size=(n, n_out)) - 2.0
    d = make_datum(u, y, ts_s=0.5, period_samples=period, convention=convention)

    yc = y - y.mean(axis=0)
    uc = u - u.mean(axis=0)
    lhs_y = np.sum(d.bin_weights[:, None] * np.abs(d.y_bins) ** 2, axis=0)
    lhs_u = np.sum(d.bin_weights[:, None] * np.abs(d.u_bins) ** 2, axis=0)
    np.testing.assert_allclose(lhs_y, _energy(yc, convention), rtol=1e-10)
    np.testing.assert_allclose(lhs_u, _energy(uc, convention), rtol=1e-10)
    assert d.y_bins.shape == (n // 2 + 1, n_out)
    assert d.u_bins.shape == (n // 2 + 1, n_in)


@pytest.mark.parametrize(("n", "expected"), [(8, [1, 2, 2, 2, 1]), (7, [1, 2, 2, 2]), (2, [1, 1])])
def test_one_sided_weights_by_hand(n, expected):
    np.testing.assert_array_equal(one_sided_weights(n), expected)


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_scaled_dft_matches_direct_sum(convention):
    # Direct evaluation of c_N sum_k x(k) exp(-j 2 pi k n / N) (no FFT).
    rng = np.random.default_rng(3)
    n = 15
    x = rng.normal(size=(n, 2))
    k = np.arange(n)
    bins = np.arange(n // 2 + 1)
    kernel = np.exp(-2j * np.pi * np.outer(bins, k) / n)
    c_n = 1.0 / n if convention is NormConvention.POWER else 1.0 / np.sqrt(n)
    np.testing.assert_allclose(scaled_dft(x, convention), c_n * kernel @ x, atol=1e-12)


def test_theta_and_frequency_grid():
    n, ts = 12, 0.25
    d = make_datum(np.zeros(n) + np.arange(n) % 4, np.zeros(n), ts_s=ts, period_samples=4)
    np.testing.assert_allclose(d.theta, 2 * np.pi * np.arange(7) / 12)
    np.testing.assert_allclose(d.freqs_hz, np.arange(7) / (12 * ts))
    assert d.n_periods == 3
    np.testing.assert_array_equal(d.harmonic_bins, [True, False, False, True, False, False, True])


def test_convention_accepts_strings():
    u = np.tile([1.0, -1.0, 0.0], 2)
    d = make_datum(u, u, ts_s=1.0, period_samples=3, convention="energy")
    assert d.convention is NormConvention.ENERGY
    with pytest.raises(ValueError, match="bogus"):
        make_datum(u, u, ts_s=1.0, period_samples=3, convention="bogus")


# --------------------------------------------------------------------------- bias


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_constant_offset_changes_only_bias(convention):
    rng = np.random.default_rng(11)
    n, period = 60, 20
    u = rng.normal(size=(n, 2))
    y = rng.normal(size=(n, 2))
    offset = np.array([5.0, -123.4])
    d0 = make_datum(u, y, ts_s=1.0, period_samples=period, convention=convention)
    d1 = make_datum(u, y + offset, ts_s=1.0, period_samples=period, convention=convention)
    np.testing.assert_allclose(d1.y_bias - d0.y_bias, offset, rtol=1e-12)
    np.testing.assert_allclose(d1.y_bias, y.mean(axis=0) + offset, rtol=1e-12)
    np.testing.assert_allclose(d1.y_bins, d0.y_bins, atol=1e-12)
    np.testing.assert_allclose(d1.noise_std, d0.noise_std, atol=1e-12)
    # DC bin is zero after bias removal, for u and y.
    assert np.max(np.abs(d1.y_bins[0])) < 1e-12
    assert np.max(np.abs(d1.u_bins[0])) < 1e-12
    np.testing.assert_allclose(d1.u_bias, u.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(d1.u_max, np.max(np.abs(u - u.mean(axis=0)), axis=0))


# --------------------------------------------------------------------------- sinusoids


@pytest.mark.parametrize("convention", CONVENTIONS)
@pytest.mark.parametrize(("period", "n_periods", "harmonic"), [(16, 4, 3), (15, 3, 1), (10, 5, 4)])
def test_sinusoid_lands_in_one_bin(convention, period, n_periods, harmonic):
    amp, phase = 2.5, 0.7
    n = period * n_periods
    k = np.arange(n)
    y = amp * np.cos(2 * np.pi * harmonic * k / period + phase)
    d = make_datum(y, y, ts_s=1.0, period_samples=period, convention=convention)
    target = harmonic * n_periods
    # Closed form: sum_k A cos(...) e^{-j theta k} = (N A / 2) e^{j phase} at the bin.
    expected = (amp / 2) if convention is NormConvention.POWER else amp * np.sqrt(n) / 2
    mags = np.abs(d.y_bins[:, 0])
    assert mags[target] == pytest.approx(expected, rel=1e-10)
    assert np.angle(d.y_bins[target, 0]) == pytest.approx(phase, abs=1e-10)
    others = np.delete(mags, target)
    assert np.max(others) < 1e-10 * expected


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_nyquist_sinusoid_full_amplitude(convention):
    # cos(pi k) is real at the Nyquist bin: |Y| = A (POWER) or A sqrt(N) (ENERGY), weight 1.
    n_periods, period, amp = 3, 8, 1.5
    n = n_periods * period
    y = amp * np.cos(np.pi * np.arange(n))
    d = make_datum(y, y, ts_s=1.0, period_samples=period, convention=convention)
    expected = amp if convention is NormConvention.POWER else amp * np.sqrt(n)
    assert abs(d.y_bins[-1, 0]) == pytest.approx(expected, rel=1e-12)
    assert d.bin_weights[-1] == 1.0


# --------------------------------------------------------------------------- periodicity


def _periodic_record(rng, period=25, n_periods=5):
    u_one = rng.normal(size=(period, 2))
    y_one = rng.normal(size=(period, 2))
    return np.tile(u_one, (n_periods, 1)), np.tile(y_one, (n_periods, 1))


def test_exactly_periodic_record():
    u, y = _periodic_record(np.random.default_rng(1))
    d = make_datum(u, y, ts_s=1.0, period_samples=25)
    rep = d.periodicity
    assert rep.n_periods == 5
    assert rep.period_samples == 25
    assert rep.input_periodic
    assert not rep.transient_suspected
    assert rep.is_periodic
    assert rep.input_variation.shape == (4, 2)
    assert rep.output_variation.shape == (4, 2)
    assert np.max(rep.input_variation) < 1e-12
    assert np.max(rep.output_drift) < 1e-12
    assert rep.messages == ()


def test_decaying_exponential_flags_transient():
    u, y = _periodic_record(np.random.default_rng(2))
    k = np.arange(y.shape[0])
    y = y + 3.0 * np.exp(-k / 20.0)[:, None]
    rep = make_datum(u, y, ts_s=1.0, period_samples=25).periodicity
    assert rep.input_periodic
    assert rep.transient_suspected
    assert not rep.is_periodic
    assert np.all(rep.output_drift > 0.05)
    assert any("output mean drifts" in m for m in rep.messages)


def test_slow_drift_alone_flags_transient():
    # A slowly decaying exponential: the variation between periods stays nearly constant,
    # so only the drift of the period means (over 5 % of the RMS) reveals the transient.
    u, y = _periodic_record(np.random.default_rng(7))
    k = np.arange(y.shape[0])
    y = y + 2.0 * np.exp(-k / 500.0)[:, None]
    rep = make_datum(u, y, ts_s=1.0, period_samples=25).periodicity
    assert np.all(rep.output_variation[0] < 2 * rep.output_variation[-1])
    assert np.all(rep.output_drift > 0.05)
    assert rep.transient_suspected
    assert [m for m in rep.messages if "shrinks" in m] == []


def test_shrinking_variation_flags_transient_without_drift():
    # A zero-mean decaying oscillation at a non-harmonic frequency: the period means barely
    # move, but the period-to-period variation shrinks.
    period, p = 40, 6
    k = np.arange(period * p)
    u = np.tile(np.sin(2 * np.pi * np.arange(period) / period), p)
    y = np.tile(np.cos(2 * np.pi * np.arange(period) / period), p)
    y = y + np.exp(-k / 50.0) * np.sin(2 * np.pi * 0.37 * k)
    rep = assess_periodicity(
        (u - u.mean())[:, None], (y - y.mean())[:, None], period_samples=period
    )
    assert rep.output_variation[0, 0] > 2 * rep.output_variation[-1, 0]
    assert rep.transient_suspected
    assert any("shrinks" in m for m in rep.messages)


def test_non_periodic_input_reported():
    rng = np.random.default_rng(3)
    u = rng.normal(size=(100, 1))
    y = rng.normal(size=(100, 1))
    rep = make_datum(u, y, ts_s=1.0, period_samples=20).periodicity
    assert not rep.input_periodic
    assert not rep.is_periodic
    assert any("input not periodic" in m for m in rep.messages)


def test_single_period_message():
    u, y = _periodic_record(np.random.default_rng(4), n_periods=1)
    rep = make_datum(u, y, ts_s=1.0, period_samples=25).periodicity
    assert rep.n_periods == 1
    assert any("one period only" in m for m in rep.messages)


# --------------------------------------------------------------------------- noise estimate


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_noise_estimate_matches_white_noise_theory(convention):
    rng = np.random.default_rng(2024)
    period, p, sigma = 200, 8, 0.3
    n = period * p
    k = np.arange(n)
    signal = np.stack(
        [np.sin(2 * np.pi * 3 * k / period), np.cos(2 * np.pi * 7 * k / period) + 0.5], axis=1
    )
    y = signal + sigma * rng.normal(size=(n, 2))
    y = y - y.mean(axis=0)
    est = noise_estimate(y, period, convention)
    assert est.shape == (n // 2 + 1, 2)
    # The unscaled DFT of N white samples of variance sigma^2 has E|X|^2 = N sigma^2, so the
    # scaled bin has std c_N sqrt(N) sigma.
    c_n = 1.0 / n if convention is NormConvention.POWER else 1.0 / np.sqrt(n)
    theory = c_n * np.sqrt(n) * sigma
    harmonic = np.arange(n // 2 + 1) % p == 0
    ms = np.sqrt(np.mean(est[harmonic] ** 2, axis=0))
    np.testing.assert_allclose(ms, theory, rtol=0.1)
    assert np.all(np.isnan(est[~harmonic]))
    assert np.all(np.isfinite(est[harmonic]))


def test_noise_estimate_exact_for_hand_example():
    # Two periods of length 2: period DFTs S_r = [x0 + x1, x0 - x1].
    y = np.array([[1.0], [2.0], [3.0], [5.0]])
    est = noise_estimate(y, 2, NormConvention.ENERGY)
    s0 = np.array([3.0, 8.0])  # DC of each period
    s1 = np.array([-1.0, -2.0])  # Nyquist of each period
    var0 = np.var(s0, ddof=1)
    var1 = np.var(s1, ddof=1)
    c_n = 1.0 / 2.0  # 1/sqrt(4)
    # Full-record bins 0, 1, 2: harmonics of the period are bins 0 and 2.
    assert est[0, 0] == pytest.approx(c_n * np.sqrt(2 * var0))
    assert np.isnan(est[1, 0])
    assert est[2, 0] == pytest.approx(c_n * np.sqrt(2 * var1))


def test_noise_estimate_nan_for_single_period():
    rng = np.random.default_rng(5)
    y = rng.normal(size=(64, 2))
    assert np.all(np.isnan(noise_estimate(y, 64, NormConvention.POWER)))
    d = make_datum(y, y, ts_s=1.0, period_samples=64)
    assert np.all(np.isnan(d.noise_std))


def test_noise_estimate_zero_for_noiseless_periodic():
    u, y = _periodic_record(np.random.default_rng(6), period=16, n_periods=4)
    d = make_datum(u, y, ts_s=1.0, period_samples=16)
    harmonic = d.harmonic_bins
    assert np.max(d.noise_std[harmonic]) < 1e-12
    assert np.all(np.isnan(d.noise_std[~harmonic]))


# --------------------------------------------------------------------------- leakage


def _first_order_moment(a: float, b: float, n_coeffs: int) -> float:
    """sum_{k=1}^{K-1} k |a|^(k-1) |b| in closed form (K = n_coeffs)."""
    r = abs(a)
    kk = n_coeffs
    return abs(b) * (1 - kk * r ** (kk - 1) + (kk - 1) * r**kk) / (1 - r) ** 2


def _first_order_pulse(a: float, b: float, n_coeffs: int) -> np.ndarray:
    pulse = np.zeros((n_coeffs, 1, 1))
    pulse[1:, 0, 0] = b * a ** np.arange(n_coeffs - 1)
    return pulse


@pytest.mark.parametrize("a", [0.9, -0.7, 0.5])
def test_pulse_moment_closed_form(a):
    b, n_coeffs = 0.3, 400
    got = pulse_moment(_first_order_pulse(a, b, n_coeffs))
    assert got.shape == (1, 1)
    assert got[0, 0] == pytest.approx(_first_order_moment(a, b, n_coeffs), rel=1e-12)
    # The infinite sum |b| / (1 - |a|)^2 is essentially reached with 400 coefficients.
    assert got[0, 0] == pytest.approx(abs(b) / (1 - abs(a)) ** 2, rel=1e-9)


def test_pulse_moment_ignores_feedthrough():
    # p(0) (direct feedthrough) causes no leakage: weight k = 0.
    pulse = np.zeros((3, 2, 2))
    pulse[0] = 100.0
    pulse[1] = [[1.0, -2.0], [0.0, 3.0]]
    pulse[2] = [[0.5, 0.0], [-1.0, 0.0]]
    np.testing.assert_allclose(pulse_moment(pulse), [[1.0 + 2 * 0.5, 2.0], [2 * 1.0, 3.0]])


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_leakage_bound_by_hand(convention):
    moment = np.array([[2.0, 2.0], [2.0, 3.0]])
    u_max = np.array([2.0, 0.5])
    n = 16
    c_n = 1.0 / 16.0 if convention is NormConvention.POWER else 1.0 / 4.0
    got = leakage_bound(moment, u_max, n, convention)
    assert got.shape == (2,)
    # 2 c_N sum_j max|u_j| moment_ij: [2*2 + 2*0.5, 2*2 + 3*0.5] = [5, 5.5].
    np.testing.assert_allclose(got, 2.0 * c_n * np.array([5.0, 5.5]), rtol=1e-12)


@pytest.mark.parametrize("convention", CONVENTIONS)
@pytest.mark.parametrize("a", [0.95, -0.8])
def test_leakage_bound_bounds_actual_leakage(convention, a):
    b = 0.4
    rng = np.random.default_rng(17)
    n, period = 512, 128
    u = rng.uniform(-1.0, 1.0, size=n)
    u = u - u.mean()  # so the de-biased input is the input the system saw (zero before)
    y = scipy.signal.lfilter([0.0, b], [1.0, -a], u)  # p(k) = a^(k-1) b, at rest at k = 0
    d = make_datum(u, y, ts_s=1.0, period_samples=period, convention=convention)
    assert not d.periodicity.input_periodic
    z = np.exp(1j * d.theta)
    plant = b / (z - a)
    leak = np.abs(d.y_bins[:, 0] - plant * d.u_bins[:, 0])
    bound = leakage_bound(pulse_moment(_first_order_pulse(a, b, 600)), d.u_max, n, convention)
    assert np.all(leak <= bound[0] * (1 + 1e-9))
    # The transient is real: leakage is not negligible against the bound somewhere.
    assert np.max(leak[1:]) > 1e-3 * bound[0]


# --------------------------------------------------------------------------- bad input


def _ok(n=40):
    return np.ones((n, 2)), np.ones((n, 2))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("which", ["u", "y"])
def test_non_finite_samples_rejected(bad, which):
    u, y = _ok()
    (u if which == "u" else y)[7, 1] = bad
    with pytest.raises(DatumError, match=rf"{which} holds 1 NaN/inf values \(first at sample 7"):
        make_datum(u, y, ts_s=1.0, period_samples=10)


def test_too_short_record():
    u, y = _ok(7)
    with pytest.raises(DatumError, match=r"too short: 7 samples .*\(10 samples\)"):
        check_record(u, y, 10)


def test_not_whole_periods_suggests_samples_to_keep():
    u, y = _ok(47)
    with pytest.raises(DatumError, match=re.escape("keep the last 40 samples")) as info:
        make_datum(u, y, ts_s=1.0, period_samples=10)
    assert "4.700 periods" in str(info.value)


def test_mismatched_lengths():
    with pytest.raises(DatumError, match="u has 40 samples but y has 30"):
        check_record(np.ones(40), np.ones(30), 10)


@pytest.mark.parametrize("period", [1, 0, -3, 2.5])
def test_bad_period(period):
    u, y = _ok()
    with pytest.raises(DatumError, match=f"period_samples must be an integer >= 2, found {period}"):
        make_datum(u, y, ts_s=1.0, period_samples=period)


@pytest.mark.parametrize("ts", [0.0, -0.1, np.nan, np.inf])
def test_bad_sample_period(ts):
    u, y = _ok()
    with pytest.raises(DatumError, match="sample period must be positive and finite"):
        make_datum(u, y, ts_s=ts, period_samples=10)


@pytest.mark.parametrize("which", ["u", "y"])
def test_three_dimensional_arrays(which):
    u, y = _ok()
    arr = np.ones((40, 2, 2))
    args = (arr, y) if which == "u" else (u, arr)
    with pytest.raises(DimensionError, match=rf"{which} must be \(n_samples, n_channels\)"):
        make_datum(*args, ts_s=1.0, period_samples=10)


def test_errors_share_package_root():
    with pytest.raises(TwotankError):
        check_record(np.ones(5), np.ones(5), 10)


def test_check_record_promotes_1d():
    u2, y2 = check_record(np.arange(6.0), np.arange(6.0), 3)
    assert u2.shape == (6, 1)
    assert y2.shape == (6, 1)
