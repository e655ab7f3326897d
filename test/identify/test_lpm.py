"""The local polynomial method against a plant started off its steady state."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from twotank_validation.errors import IdentificationError
from twotank_validation.identify.lpm import local_polynomial

TS = 0.5
SYS = scipy.signal.dlti([0.05, 0.03], [1.0, -1.6, 0.68], dt=TS)  # poles 0.8 ± 0.2j


def _true(lines: np.ndarray, m: int) -> np.ndarray:
    return scipy.signal.dfreqresp(SYS, w=2 * np.pi * lines / m)[1]


def _record(m: int, lines: np.ndarray, seed: int, noise: float, periods: int = 1):
    rng = np.random.default_rng(seed)
    n = m // periods
    spec = np.zeros(n // 2 + 1, complex)
    spec[lines] = np.exp(2j * np.pi * rng.uniform(size=lines.size))
    u = np.tile(np.fft.irfft(spec, n=n), periods)
    u /= np.sqrt(np.mean(u**2))
    ss = SYS._as_ss()
    x0 = np.array([5.0, -3.0])  # far from the periodic steady state
    _, y, _ = scipy.signal.dlsim(ss, u, x0=x0)
    y = y[:, 0] + noise * rng.standard_normal(m)
    return u[:, None], y[:, None]


def test_one_period_with_a_transient_recovers_the_plant_where_the_plain_ratio_does_not():
    m = 1024
    lines = np.arange(1, 300)
    u, y = _record(m, lines, 1, 0.0)
    est = lines[5:-5]
    fr = local_polynomial(u, y, est, TS, degree=2)
    true = _true(est, m)
    lpm_err = np.abs(fr.g[:, 0, 0] - true)
    plain = np.fft.rfft(y[:, 0])[est] / np.fft.rfft(u[:, 0])[est]
    plain_err = np.abs(plain - true)
    assert np.median(lpm_err) < 0.02 * np.median(plain_err)
    assert np.max(lpm_err / np.abs(true)) < 1e-2


def test_lpm_bounds_cover_with_noise():
    m = 2048
    lines = np.arange(1, 600)
    est = lines[10:-10:7]
    hits = total = 0
    for seed in range(10):
        u, y = _record(m, lines, 10 + seed, 0.01)
        fr = local_polynomial(u, y, est, TS, degree=2)
        err2 = np.abs(fr.g[:, 0, 0] - _true(est, m)) ** 2
        hits += int(np.sum(err2 <= fr.radius(0.95)[:, 0, 0] ** 2))
        total += est.size
    assert 0.88 <= hits / total <= 0.99


def test_whole_periods_still_settling_use_the_unexcited_neighbours():
    """Four periods after a start-up: the transient lies on the lines between the harmonics."""
    p, n = 4, 512
    lines = np.arange(1, 150)
    u, y = _record(p * n, lines, 3, 1e-4, periods=p)
    est = p * lines[3:-3]
    fr = local_polynomial(u, y, est, TS, degree=2, n_periods=p)
    true = _true(est, p * n)
    mean_period = (
        np.fft.rfft(y[:, 0].reshape(p, n).mean(axis=0))[lines[3:-3]]
        / np.fft.rfft(u[:n, 0])[lines[3:-3]]
    )
    assert np.median(np.abs(fr.g[:, 0, 0] - true)) < 0.1 * np.median(np.abs(mean_period - true))


def test_a_line_without_excitation_is_refused():
    m = 512
    u, y = _record(m, np.arange(1, 50), 0, 0.0)
    u[:] = 0.0
    with pytest.raises(IdentificationError, match=r"too little excitation|not excited"):
        local_polynomial(u, y, np.array([20]), TS)
