"""The nonparametric response, its σ and the distortion levels against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from twotank_validation.errors import IdentificationError
from twotank_validation.identify.nonparametric import (
    best_linear_approximation,
    bla_over_experiments,
    distortion_lines,
    frf_from_experiments,
    split_by_pattern,
)

N = 256
TS = 0.1


def _multisine(lines: np.ndarray, rng: np.random.Generator, n: int = N) -> np.ndarray:
    spec = np.zeros(n // 2 + 1, complex)
    spec[lines] = np.exp(2j * np.pi * rng.uniform(size=lines.size))
    x = np.fft.irfft(spec, n=n)
    return x / np.sqrt(np.mean(x**2))


def _steady(g_lines: np.ndarray, u_period: np.ndarray, n: int = N) -> np.ndarray:
    """Periodic steady-state output of a linear plant: (n, n_y) from (n, n_u) and the plant's
    response at every line 0..n//2, (n//2+1, n_y, n_u)."""
    uf = np.fft.rfft(u_period, axis=0)
    yf = np.einsum("kyu,ku->ky", g_lines, uf)
    return np.fft.irfft(yf, n=n, axis=0)


def test_siso_noise_free_equals_the_plant_and_sigma_is_zero():
    a, b = 0.7, 0.3
    z = np.exp(2j * np.pi * np.arange(N // 2 + 1) / N)
    g = (b / (z - a))[:, None, None]
    lines = np.arange(1, 40)
    u = _multisine(lines, np.random.default_rng(0))[:, None]
    y = _steady(g, u)
    fr = frf_from_experiments([(np.tile(u, (4, 1)), np.tile(y, (4, 1)))], N, lines, TS)
    np.testing.assert_allclose(fr.g[:, 0, 0], g[lines, 0, 0], rtol=1e-10, atol=1e-12)
    assert np.max(fr.var) < 1e-25
    np.testing.assert_allclose(fr.freqs_hz, lines / (N * TS))


def _coverage(n_periods: int, input_noise: float, seeds: range) -> float:
    a, b = 0.8, 0.2
    z = np.exp(2j * np.pi * np.arange(N // 2 + 1) / N)
    g = (b / (z - a))[:, None, None]
    lines = np.arange(1, 60, 2)
    hits = total = 0
    for seed in seeds:
        rng = np.random.default_rng(seed)
        u0 = _multisine(lines, rng)[:, None]
        y0 = _steady(g, u0)
        u = np.tile(u0, (n_periods, 1)) + input_noise * rng.standard_normal((n_periods * N, 1))
        y = np.tile(y0, (n_periods, 1)) + 0.05 * rng.standard_normal((n_periods * N, 1))
        fr = frf_from_experiments([(u, y)], N, lines, TS)
        err2 = np.abs(fr.g[:, 0, 0] - g[lines, 0, 0]) ** 2
        hits += int(np.sum(err2 <= fr.radius(0.95)[:, 0, 0] ** 2))
        total += lines.size
    return hits / total


@pytest.mark.parametrize("n_periods", [4, 16])
def test_siso_95_percent_bounds_cover_as_stated_with_output_noise(n_periods: int):
    assert 0.90 <= _coverage(n_periods, 0.0, range(12)) <= 0.98


def test_siso_95_percent_bounds_cover_with_input_noise_too():
    # errors in variables: noise on the measured input as well as on the output
    assert 0.90 <= _coverage(16, 0.03, range(12, 24)) <= 0.98


def test_sigma_matches_the_monte_carlo_spread():
    """The stated variance equals the spread of the estimate over independent noise draws."""
    a, b = 0.6, 0.4
    z = np.exp(2j * np.pi * np.arange(N // 2 + 1) / N)
    g = (b / (z - a))[:, None, None]
    lines = np.arange(3, 50, 3)
    u0 = _multisine(lines, np.random.default_rng(5))[:, None]
    y0 = _steady(g, u0)
    p = 8
    est, stated = [], []
    for seed in range(300):
        rng = np.random.default_rng(1000 + seed)
        u = np.tile(u0, (p, 1)) + 0.02 * rng.standard_normal((p * N, 1))
        y = np.tile(y0, (p, 1)) + 0.05 * rng.standard_normal((p * N, 1))
        fr = frf_from_experiments([(u, y)], N, lines, TS)
        est.append(fr.g[:, 0, 0])
        stated.append(fr.var[:, 0, 0])
    spread = np.var(np.array(est), axis=0)
    mean_stated = np.mean(np.array(stated), axis=0)
    np.testing.assert_allclose(mean_stated, spread, rtol=0.25)


def _mimo_plant() -> np.ndarray:
    z = np.exp(2j * np.pi * np.arange(N // 2 + 1) / N)
    g = np.zeros((N // 2 + 1, 3, 2), complex)
    for c in range(3):
        for i in range(2):
            a = 0.4 + 0.15 * c + 0.1 * i
            g[:, c, i] = (1.0 - a + 0.1 * c) / (z - a)
    return g


def test_mimo_from_two_experiments_equals_the_plant():
    g = _mimo_plant()
    lines = np.arange(1, 30)
    rng = np.random.default_rng(1)
    exps = []
    for _ in range(2):
        u = np.stack([_multisine(lines, rng), _multisine(lines, rng)], axis=1)
        exps.append((np.tile(u, (3, 1)), np.tile(_steady(g, u), (3, 1))))
    fr = frf_from_experiments(exps, N, lines, TS)
    np.testing.assert_allclose(fr.g, g[lines], rtol=1e-9, atol=1e-12)


def test_orthogonal_multisine_periods_split_into_experiments():
    """A Hadamard pattern [[1, 1], [1, -1]] over the periods gives two experiments in one record."""
    g = _mimo_plant()
    lines = np.arange(1, 30)
    rng = np.random.default_rng(2)
    s1, s2 = _multisine(lines, rng), _multisine(lines, rng)
    u_a = np.stack([s1, s2], axis=1)
    u_b = np.stack([s1, -s2], axis=1)
    periods = [u_a, u_b] * 3
    u = np.concatenate(periods)
    y = np.concatenate([_steady(g, up) for up in periods])
    y = y + 1e-3 * rng.standard_normal(y.shape)
    exps = split_by_pattern(u, y, N)
    assert len(exps) == 2
    assert all(e[0].shape[0] == 3 * N for e in exps)
    fr = frf_from_experiments(exps, N, lines, TS)
    err = np.abs(fr.g - g[lines])
    assert np.all(err <= 5 * np.sqrt(fr.var))


def test_one_experiment_for_two_inputs_is_refused():
    lines = np.arange(1, 10)
    u = np.random.default_rng(0).standard_normal((2 * N, 2))
    with pytest.raises(IdentificationError, match="at least 2 experiments"):
        frf_from_experiments([(u, u[:, :1])], N, lines, TS)


def test_partial_period_and_nan_are_refused():
    lines = np.arange(1, 10)
    u = np.ones((N + 3, 1))
    with pytest.raises(IdentificationError, match="whole periods"):
        frf_from_experiments([(u, u)], N, lines, TS)
    u = np.ones((2 * N, 1))
    u[5] = np.nan
    with pytest.raises(IdentificationError, match="NaN"):
        frf_from_experiments([(u, u)], N, lines, TS)


def test_bla_of_a_cubic_is_bussgang_and_distortion_matches_the_hermite_closed_form():
    """y = u + a u^3 with a random-phase multisine u of unit RMS: the BLA is 1 + 3 a
    (Bussgang, the multisine asymptotically Gaussian) and the residual a (u^3 - 3u) has
    autocorrelation 6 a^2 R(tau)^3, so its power at a line is 6 a^2 times the triple circular
    convolution of the input's line powers."""
    a = 0.05
    n = 2048
    lines = np.arange(1, 301)  # the closed form is asymptotic in the number of lines
    m = 24
    reals = []
    for seed in range(m):
        rng = np.random.default_rng(seed)
        u = _multisine(lines, rng, n)
        y = u + a * u**3 + 1e-3 * rng.standard_normal(n * 2).reshape(2, n)
        reals.append([(np.tile(u, 2)[:, None], y.reshape(-1, 1))])
    bla = best_linear_approximation(reals, n, lines, TS)
    g = bla.response.g[:, 0, 0]
    ci = 3 * np.sqrt(bla.response.var[:, 0, 0])
    assert np.mean(np.abs(g - (1 + 3 * a)) <= ci) > 0.9
    # the closed form of the distortion's variance at each excited line, for one realisation
    power = np.zeros(n)
    power[lines] = power[n - lines] = 1.0
    power /= power.sum()  # two-sided line powers of a unit-RMS signal
    r = np.fft.ifft(power) * n  # autocorrelation R(tau), R(0) = 1
    s_res = np.real(np.fft.fft(6 * a**2 * r**3)) / n  # residual's line powers (two-sided)
    u_line = power[lines]  # |U(k)|^2 per line for the DFT scaled by 1/n
    var_one = s_res[lines] / u_line  # E|G_m - G_BLA|^2 from distortion, per realisation
    stated = bla.var_distortion[:, 0, 0] * m  # per-realisation variance stated by the estimator
    ratio = np.mean(stated) / np.mean(var_one)
    assert 0.85 < ratio < 1.15, ratio
    assert np.all(bla.var_noise < 0.05 * bla.response.var)


def _odd_multisine_with_detection(
    n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    odd = np.arange(1, 120, 2)
    keep = np.ones(odd.size, bool)
    keep[rng.integers(0, 4) :: 4] = False  # one odd detection line in every group of four
    lines = odd[keep]
    return _multisine(lines, rng, n), lines


@pytest.mark.parametrize(("kind", "shows"), [("odd", "odd"), ("even", "even")])
def test_distortion_lines_tell_odd_from_even_nonlinearity(kind: str, shows: str):
    n, p = 1024, 6
    rng = np.random.default_rng(7)
    u, lines = _odd_multisine_with_detection(n, rng)
    y0 = u + (0.05 * u**3 if kind == "odd" else 0.1 * u**2)
    y = np.tile(y0, p)[:, None] + 1e-3 * rng.standard_normal((p * n, 1))
    d = distortion_lines(y, n, lines, (1, 119))
    levels = {"odd": d.odd[0] / d.noise_odd[0], "even": d.even[0] / d.noise_even[0]}
    other = "even" if shows == "odd" else "odd"
    assert levels[shows] > 100
    assert levels[other] < 3


def _two_input_cubic(a: float, seeds: range, n: int = 1024, p: int = 2):
    """x = G u with a static 2 x 2 G, y_c = x_c + a x_c^3 (per output), random-phase
    multisines of unit RMS on both inputs, phases of their own in every experiment."""
    g = np.array([[1.0, 0.5], [-0.4, 0.8]])
    lines = np.arange(1, 201)
    experiments = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        u = np.column_stack([_multisine(lines, rng, n), _multisine(lines, rng, n)])
        x = u @ g.T
        y0 = x + a * x**3
        y = np.tile(y0, (p, 1)) + 1e-3 * rng.standard_normal((p * n, 2))
        experiments.append((np.tile(u, (p, 1)), y))
    return g, lines, experiments


def test_two_input_bla_is_bussgang_per_output_and_its_spread_shows_the_distortion():
    """Stein's lemma on a Gaussian x_c: the BLA's row c is E[f'(x_c)] G_c = (1 + 3 a s_c^2) G_c
    with s_c^2 the RMS^2 of x_c (the multisines are asymptotically Gaussian). The 95 % discs
    from the spread over 12 experiments cover it at about 95 % of the entries; the noise alone
    (period spread) would state far too small a variance; a linear plant's spread is the
    noise's."""
    a, n = 0.05, 1024
    g, lines, experiments = _two_input_cubic(a, range(12), n)
    bla = bla_over_experiments(experiments, n, lines, TS)
    s2 = np.sum(g**2, axis=1)  # each input unit RMS, independent
    want = (1 + 3 * a * s2)[:, None] * g
    inside = np.abs(bla.response.g - want[None]) <= bla.response.radius(0.95)
    assert 0.9 < inside.mean() < 0.99, inside.mean()
    assert np.median(bla.var_distortion / bla.var_noise) > 50
    _, _, linear = _two_input_cubic(0.0, range(12), n)
    lin = bla_over_experiments(linear, n, lines, TS)
    ratio = np.median(lin.response.var / lin.var_noise)
    assert 0.6 < ratio < 1.6, ratio


def test_two_inputs_need_more_experiments_than_inputs_for_the_spread():
    _, lines, experiments = _two_input_cubic(0.05, range(2))
    with pytest.raises(IdentificationError, match="more realisations"):
        bla_over_experiments(experiments, 1024, lines, TS)
