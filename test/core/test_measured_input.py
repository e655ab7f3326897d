"""Measured inputs (issue 28, item 2): a logged input that repeats only within its noise.

The record is the nominal rig's (the plant sees the clean command); the logged input is the
command plus white noise at 1e-3 of its RMS. References: the noise injected (known to the
test), the triangle inequality for the min-norm noise (docs/theory.md, "Measured inputs")
and the exponential law of a complex Gaussian bin's power.
"""

from __future__ import annotations

import numpy as np
import pytest

from tools.streamfuzz import CONFIG, clean_record
from twotank_validation.core.datum import (
    MEASURED_INPUT_RTOL,
    NormConvention,
    PeriodicityFinding,
    make_datum,
    period_average,
    scaled_dft,
)
from twotank_validation.core.measured import input_noise_effect, input_noise_shift, noise_gain
from twotank_validation.core.model import BlockStructure, LFTModel, load_model
from twotank_validation.core.validate import validate_beta
from twotank_validation.errors import DimensionError

L = CONFIG.period_samples
NOISE = 1e-3


def _record() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, y, n): 4 settled periods of the nominal rig and the logged input's noise."""
    _, u, y = clean_record(6)
    u, y = u[2 * L :], y[2 * L :]
    rms = np.sqrt(np.mean((u - u.mean(0)) ** 2, axis=0))
    n = np.random.default_rng(7).standard_normal(u.shape) * NOISE * rms
    return u, y, n


def _nominal_only(name: str) -> LFTModel:
    """The model's nominal and noise channels, without perturbations."""
    m = load_model(name)
    return LFTModel(
        f"{name}_nominal",
        m.input_names,
        m.output_names,
        BlockStructure(()),
        (),
        m.noise_names,
        nominal=m.nominal,
        noise=m.noise,
    )


@pytest.mark.parametrize("model", [_nominal_only("B"), load_model("B"), load_model("A")])
def test_measured_input_is_judged_with_beta_within_the_noise_effect(model: LFTModel) -> None:
    u, y, n = _record()
    clean = make_datum(u, y, ts_s=CONFIG.ts_s, period_samples=L)
    noisy = make_datum(u + n, y, ts_s=CONFIG.ts_s, period_samples=L, measured=[True, True])
    assert noisy.periodicity.findings == ()  # judged: the gate tolerates the input's noise
    # the noise estimate from the period-to-period spread: a variance with 3 degrees of
    # freedom per sample of the period (4 periods), 3L in all: relative standard error
    # sqrt(2 / 3L) of sigma^2, half that of sigma
    se = 0.5 * np.sqrt(2.0 / (3 * L))
    assert noisy.periodicity.input_noise == pytest.approx([NOISE, NOISE], rel=4 * se)
    resp = model.response(clean.theta, clean.ts_s)
    beta0 = validate_beta(clean, model, response=resp).beta
    beta = validate_beta(noisy, model, response=resp).beta
    # the noise left after averaging over the periods, through the nominal: the triangle
    # inequality bounds |beta - beta0| by it (exact without perturbations)
    left = scaled_dft(period_average(n - n.mean(0), L), NormConvention.POWER)
    shift = input_noise_shift(resp.p22, resp.p23, left, clean.bin_weights)
    assert 0.0 < abs(beta - beta0) <= shift
    # what the window reports (the noise estimated from the data, not known) is the expected
    # shift: shift^2 is a sum of terms a_n |N(n)|^2, exponential variables (a complex
    # Gaussian bin's power) of standard deviation their mean; the estimate sums a_n
    # sigma_n^2 with each sigma_n^2 a sample variance over the p periods (p - 1 complex
    # degrees of freedom: relative standard deviation 1/sqrt(p - 1))
    effect = input_noise_effect(resp.p22, resp.p23, noisy.u_noise_std, clean.bin_weights)
    terms = clean.bin_weights[:, None] * (noise_gain(resp.p22, resp.p23) * noisy.u_noise_std) ** 2
    p = noisy.n_periods
    spread = np.sqrt(np.sum(terms**2) * (1.0 + 1.0 / (p - 1)))
    assert abs(shift**2 - effect**2) <= 4 * spread


def test_commanded_input_with_the_same_noise_is_refused() -> None:
    u, y, n = _record()
    datum = make_datum(u + n, y, ts_s=CONFIG.ts_s, period_samples=L)
    assert PeriodicityFinding.INPUT_NOT_PERIODIC in datum.periodicity.findings
    assert datum.u_noise_std.size == 0  # nothing averaged, nothing estimated
    one = make_datum(u + n, y, ts_s=CONFIG.ts_s, period_samples=L, measured=[False, True])
    assert PeriodicityFinding.INPUT_NOT_PERIODIC in one.periodicity.findings


def test_measured_input_that_changes_more_than_noise_is_refused() -> None:
    u, y, _ = _record()
    changed = u.copy()
    changed[2 * L :] = u.mean(0) + 1.5 * (u[2 * L :] - u.mean(0))  # amplitude up by half
    datum = make_datum(changed, y, ts_s=CONFIG.ts_s, period_samples=L, measured=[True, True])
    assert datum.periodicity.input_noise.max() > MEASURED_INPUT_RTOL
    assert PeriodicityFinding.INPUT_NOT_PERIODIC in datum.periodicity.findings


def test_period_average_keeps_the_harmonics_and_clears_the_rest() -> None:
    u, _, n = _record()
    x = u + n
    full = scaled_dft(x, NormConvention.POWER)
    avg = scaled_dft(period_average(x, L), NormConvention.POWER)
    harmonic = np.arange(full.shape[0]) % (len(x) // L) == 0
    np.testing.assert_allclose(avg[harmonic], full[harmonic], atol=1e-12)
    np.testing.assert_allclose(avg[~harmonic], 0.0, atol=1e-12)


def test_measured_mask_of_the_wrong_size_is_a_clear_error() -> None:
    u, y, _ = _record()
    with pytest.raises(DimensionError, match="measured marks 1 inputs but u has 2"):
        make_datum(u, y, ts_s=CONFIG.ts_s, period_samples=L, measured=[True])


def test_the_noise_effect_under_a_band_counts_the_band_s_bins_only() -> None:
    """The band's β moves only with the noise at its bins: the effect over a band is the
    noise shift of a record whose input noise outside the band is removed (its DFT zeroed
    there), the reference computed from the actual noise, not the estimate."""
    u, y, n = _record()
    model = _nominal_only("B")
    clean = make_datum(u, y, ts_s=CONFIG.ts_s, period_samples=L)
    resp = model.response(clean.theta, clean.ts_s)
    band = clean.freqs_hz >= 0.005
    left = scaled_dft(period_average(n - n.mean(0), L), NormConvention.POWER)
    in_band = input_noise_shift(resp.p22, resp.p23, np.where(band[:, None], left, 0.0),
                                clean.bin_weights)  # fmt: skip
    whole = input_noise_shift(resp.p22, resp.p23, left, clean.bin_weights)
    assert in_band < 0.5 * whole  # most of the noise's effect here lies below 0.005 Hz
    noisy = make_datum(u + n, y, ts_s=CONFIG.ts_s, period_samples=L, measured=[True, True])
    std = noisy.u_noise_std
    effect_band = input_noise_effect(resp.p22, resp.p23, std, clean.bin_weights, band)
    effect_out = input_noise_effect(resp.p22, resp.p23, std, clean.bin_weights, ~band)
    effect = input_noise_effect(resp.p22, resp.p23, std, clean.bin_weights)
    assert effect_band**2 + effect_out**2 == pytest.approx(effect**2, rel=1e-12)
    terms = clean.bin_weights[:, None] * (noise_gain(resp.p22, resp.p23) * std) ** 2
    terms = np.where(band[:, None], terms, 0.0)
    spread = np.sqrt(np.sum(terms**2) * (1.0 + 1.0 / (noisy.n_periods - 1)))
    assert abs(in_band**2 - effect_band**2) <= 4 * spread
