"""Excited lines of a measured input (issue 28, items 1-3): the command's lines, not its noise.

The command is a multisine on chosen lines of the period (both inputs of Model B); the
outputs its steady periodic response through the nominal plus white noise; the logged inputs
the command plus white noise at 1e-3 of its RMS, marked measured (averaged over the periods,
the noise left at every harmonic). Reference: the lines the multisine was built on. The
band's ``excited``, the diagnosis's excited bins and the report's figure all take them from
one function (``core.band.excited_lines``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from twotank_validation.core.band import EXCITED_FLOOR, parse_band
from twotank_validation.core.datum import make_datum
from twotank_validation.core.measured import input_noise_effect
from twotank_validation.core.model import load_model
from twotank_validation.core.validate import validate_beta, validation_band
from twotank_validation.diagnose import excited_bins
from twotank_validation.report import _excited_mask

TS, PERIOD, P = 0.8, 256, 4
N = PERIOD * P
LINES = np.arange(1, 40, 2)  # odd harmonics of the period up to 39


def _record(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, y, logged): the command, the outputs, the command as a sensor reads it."""
    rng = np.random.default_rng(seed)
    spec = np.zeros((PERIOD // 2 + 1, 2), dtype=complex)
    spec[LINES] = np.exp(2j * np.pi * rng.random((LINES.size, 2)))
    one = np.fft.irfft(spec, n=PERIOD, axis=0)
    u = 0.5 + 0.05 * np.tile(one / one.std(axis=0), (P, 1))
    theta = 2 * np.pi * np.arange(N // 2 + 1) / N
    g = load_model("B").response(theta, TS).p23
    y = np.fft.irfft(np.einsum("kij,kj->ki", g, np.fft.rfft(u - 0.5, axis=0)), n=N, axis=0)
    y += rng.normal(0.0, [0.003, 0.01], y.shape)
    rms = np.sqrt(np.mean((u - u.mean(0)) ** 2, axis=0))
    return u, y, u + rng.standard_normal(u.shape) * 1e-3 * rms


def test_a_measured_inputs_noise_is_not_an_excited_line() -> None:
    u, y, logged = _record(5)
    clean = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    noisy = make_datum(logged, y, ts_s=TS, period_samples=PERIOD, measured=[True, True])
    lines = np.zeros(clean.theta.size, dtype=bool)
    lines[LINES * P] = True
    # the noise left in the averaged input sits at every other harmonic, mostly above the floor
    power = np.sum(np.abs(noisy.u_bins) ** 2, axis=1)
    other = (np.arange(power.size) % P == 0) & ~lines
    other[0] = False
    assert np.mean(power[other] > EXCITED_FLOOR * power.max()) > 0.5
    model = load_model("B")
    banded = dataclasses.replace(model, band=parse_band("excited"))
    np.testing.assert_array_equal(validation_band(noisy, banded), lines)
    np.testing.assert_array_equal(validation_band(clean, banded), lines)
    np.testing.assert_array_equal(excited_bins(noisy, EXCITED_FLOOR), np.flatnonzero(lines))
    np.testing.assert_array_equal(_excited_mask(noisy), lines)
    # β over the excited lines moves by no more than the input noise's effect
    resp = model.response(clean.theta, clean.ts_s)
    effect = input_noise_effect(resp.p22, resp.p23, noisy.u_noise_std, clean.bin_weights)
    b_noisy = validate_beta(noisy, banded, response=resp).beta
    b_clean = validate_beta(clean, banded, response=resp).beta
    assert 0.0 < abs(b_noisy - b_clean) <= effect
