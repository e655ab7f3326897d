"""The identification's excitation design: odd lines with detection lines, low crest factor."""

from __future__ import annotations

import numpy as np
import pytest

from twotank_validation.errors import DatumError
from twotank_validation.sim.excitation import (
    crest_factor,
    low_crest_multisine,
    odd_multisine_lines,
)

N, TS = 1024, 0.1


def test_odd_lines_with_one_left_out_in_every_group():
    lines = odd_multisine_lines(N, TS, 0.01, 2.0, group=4, rng=np.random.default_rng(1))
    odd = np.arange(lines.first, lines.last + 1, 2)
    assert np.all(lines.excited % 2 == 1)
    assert np.all(lines.detection % 2 == 1)
    np.testing.assert_array_equal(np.sort(np.r_[lines.excited, lines.detection]), odd)
    # exactly one detection line in each whole group of four consecutive odd lines
    groups = np.searchsorted(odd, lines.detection) // 4
    np.testing.assert_array_equal(groups, np.arange(odd.size // 4))
    assert lines.first / (N * TS) >= 0.01
    assert lines.last / (N * TS) <= 2.0


def test_no_odd_line_in_the_band_is_a_clear_error():
    with pytest.raises(DatumError, match="no odd line"):
        odd_multisine_lines(N, TS, 0.0195, 0.0196, group=4, rng=np.random.default_rng(0))


def test_low_crest_multisine_keeps_the_flat_spectrum_and_beats_schroeder_phases():
    """Reference: Schroeder's phases, the closed-form low-crest design for flat spectra
    (phi_k = -pi k (k - 1) / F), crest factor about 1.7; random phases give about 3-4."""
    lines = np.arange(1, 201)
    x = low_crest_multisine(N, lines, np.random.default_rng(3), iterations=150)
    spec = np.fft.rfft(x)
    mags = np.abs(spec[lines])
    np.testing.assert_allclose(mags, mags[0], rtol=1e-9)  # flat at the lines
    others = np.setdiff1d(np.arange(spec.size), lines)
    assert np.max(np.abs(spec[others])) < 1e-9 * mags[0]  # nothing elsewhere
    k = np.arange(1, lines.size + 1)
    schroeder = np.zeros(N // 2 + 1, complex)
    schroeder[lines] = np.exp(-1j * np.pi * k * (k - 1) / lines.size)
    cf_schroeder = crest_factor(np.fft.irfft(schroeder, n=N))
    random = np.zeros(N // 2 + 1, complex)
    random[lines] = np.exp(2j * np.pi * np.random.default_rng(3).uniform(size=lines.size))
    cf_random = crest_factor(np.fft.irfft(random, n=N))
    cf = crest_factor(x)
    assert cf < cf_schroeder < cf_random
    assert np.sqrt(np.mean(x**2)) == pytest.approx(1.0)
