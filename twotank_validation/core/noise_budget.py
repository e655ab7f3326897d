"""Noise weights and β's budget: what the noise alone costs, and weights set from the data.

β is the norm of one unknown input ``w`` shared by every output channel (docs/theory.md §13).
Noise alone, through weights ``W_c(n)`` on the outputs, costs

    β_noise² = Σ_n b_n Σ_c |E_c(n)|² |P22(n)⁺ e_c|²,

which for diagonal weights is ``Σ_c Σ_n b_n |E_c(n)|² / |W_c(n)|²``: every output adds its
own share. Weights equal to each output's noise RMS make each share about 1, so β from the
noise alone is about ``√n_y``. The noise's per-bin variance ``σ_c(n)²`` is estimated from the
period-to-period spread (:func:`~twotank_validation.core.datum.noise_estimate`) at the
harmonic bins, and given to every other bin from its nearest harmonic (a smooth noise
spectrum). Pure functions over numpy arrays; units: ``Y(n)`` as the datum scales it (model
units times the convention's DFT prefactor), weights in model units per unit of ``w``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.special
import scipy.stats

from twotank_validation.core.datum import NormConvention, noise_estimate
from twotank_validation.errors import DatumError

NOISE_BETA_WARN = 0.9
"""A window warns when the β its noise alone is expected to cost, under the model's noise
weights, is above this (81 % of β² = 1) with confidence :data:`NOISE_WARN_CONFIDENCE`: a β
above 1 is then as likely the noise weights' as the model's (docs/theory.md §13)."""

NOISE_WARN_CONFIDENCE = 0.9
"""The warning needs the lower bound of this confidence (:func:`noise_beta_lower`) above
:data:`NOISE_BETA_WARN`."""

NOISE_QUANTILE = 0.99
"""Default probability that the noise alone costs at most the budget on a window."""

NOISE_BUDGET = 0.8
"""Default share of β the noise alone may cost at :data:`NOISE_QUANTILE` (β² 0.64): below the
warning (:data:`NOISE_BETA_WARN`), and the rest of β's unit budget left to what the noise is
not (docs/theory.md §13)."""


@dataclass(frozen=True)
class NoiseSpread:
    """Per-bin noise variance of the outputs' ``Y(n)``, from the period-to-period spread.

    Attributes:
        var: (n_bins, n_outputs) float, ``E|E_c(n)|²`` at every kept bin ``0 .. N//2``: the
            nearest harmonic's estimate (0 at DC: the mean is removed with the bias).
        harmonic: (n_bins,) int, the harmonic (index into ``harmonic_var``) each bin takes.
        harmonic_var: (n_harmonics, n_outputs) float, the estimate at the harmonic bins
            ``n = p m``, ``m = 0 .. L//2``, pooled (averaged) over the windows.
        dof: complex degrees of freedom of each harmonic estimate: ``(p - 1)`` per window.
        n_periods: periods per window ``p``.
    """

    var: np.ndarray
    harmonic: np.ndarray
    harmonic_var: np.ndarray
    dof: float
    n_periods: int


def noise_spread(
    records: Sequence[np.ndarray], period_samples: int, convention: NormConvention
) -> NoiseSpread:
    """The outputs' noise per bin, from the period-to-period spread of one or more windows.

    Args:
        records: each (n_samples, n_outputs) float, de-biased outputs (model units) of a
            window of whole periods; every window of the same length.
        period_samples: samples per period ``L``.
        convention: the norm convention (the DFT prefactor of ``Y(n)``).

    Raises:
        DatumError: no window, windows of different shapes, or one period per window (no
            spread to estimate from).
    """
    if not records:
        raise DatumError("no window to estimate the noise from")
    shapes = {np.shape(r) for r in records}
    if len(shapes) != 1:
        raise DatumError(f"the windows differ in shape ({sorted(shapes)}): cut them alike")
    n = np.shape(records[0])[0]
    p = n // period_samples
    if p < 2:
        raise DatumError(
            "one period per window: the noise cannot be estimated from the period-to-period "
            "spread; use windows of two or more periods (--periods-per-window)"
        )
    std = [noise_estimate(np.asarray(r, float), period_samples, convention) for r in records]
    return spread_of_std(std, p)


def spread_of_std(noise_std: Sequence[np.ndarray], n_periods: int) -> NoiseSpread:
    """:class:`NoiseSpread` from windows' :func:`~twotank_validation.core.datum.noise_estimate`.

    Args:
        noise_std: each (n_bins, n_outputs) float, a window's per-bin noise standard
            deviation (``Datum.noise_std``: estimated at the harmonic bins, NaN elsewhere).
        n_periods: periods per window ``p`` (>= 2).
    """
    n_bins = noise_std[0].shape[0]
    p = int(n_periods)
    harmonics = np.arange(0, n_bins, p)
    harmonic_var = np.mean([np.asarray(s)[harmonics] ** 2 for s in noise_std], axis=0)
    m = np.clip(np.rint(np.arange(n_bins) / p).astype(int), 1, max(harmonics.size - 1, 1))
    var = harmonic_var[m].copy()
    var[0] = 0.0
    return NoiseSpread(var, m, harmonic_var, float((p - 1) * len(noise_std)), p)


def noise_gain2(p22: np.ndarray) -> np.ndarray:
    """``|P22(n)⁺ e_c|²``: the least ``||w||²`` per unit ``|E_c(n)|²`` of output ``c``.

    Args:
        p22: (n_bins, n_outputs, nw) complex, the noise channels' response.

    Returns:
        (n_bins, n_outputs) float; ``1/|W_c(n)|²`` for diagonal weights.
    """
    return np.asarray(np.sum(np.abs(np.linalg.pinv(p22)) ** 2, axis=1))


def noise_floor(var: np.ndarray, gain2: np.ndarray) -> np.ndarray:
    """The min ``||W(n)||`` the noise alone is expected to cost per bin.

    ``sqrt(Σ_c σ_c(n)² g_c(n))``: the per-bin terms of :func:`expected_noise_beta`
    (``noise_beta² = Σ_n b_n floor(n)²`` over the bins β counts), in the units of the
    per-bin minimum ``w_min``, so the two compare bin by bin: a bin near its floor is noise,
    one far above it is what the model misses.

    Args:
        var: (n_bins, n_outputs) float, ``σ_c(n)²`` (:attr:`NoiseSpread.var`).
        gain2: (n_bins, n_outputs) float, :func:`noise_gain2` of the model's noise channels.

    Returns:
        (n_bins,) float (units of ``||w||``); NaN where the noise could not be estimated.
    """
    return np.asarray(np.sqrt(np.sum(var * gain2, axis=1)))


def expected_noise_beta(
    var: np.ndarray, gain2: np.ndarray, bin_weights: np.ndarray, mask: np.ndarray | None = None
) -> float:
    """The β the noise alone is expected to cost: ``sqrt(Σ_n b_n Σ_c σ_c(n)² g_c(n))``.

    Args:
        var: (n_bins, n_outputs) float, ``σ_c(n)²`` (:attr:`NoiseSpread.var`).
        gain2: (n_bins, n_outputs) float, :func:`noise_gain2` of the model's noise channels.
        bin_weights: (n_bins,) float, ``b_n``.
        mask: (n_bins,) bool, the bins β counts (the band); None: every bin.

    Returns:
        The expected noise-only β, ``sqrt(E β_noise²)`` (units of ``||w||``); NaN where the
        noise could not be estimated.
    """
    b = bin_weights if mask is None else np.where(mask, bin_weights, 0.0)
    total = float(np.sum(b[:, None] * var * gain2))
    return math.sqrt(total) if total >= 0.0 else math.nan


def _per_harmonic(spread: NoiseSpread, a: np.ndarray) -> np.ndarray:
    """(n_harmonics, n_outputs): the bins' terms ``a`` summed per harmonic they take."""
    size = spread.harmonic_var.shape[0]
    return np.stack(
        [np.bincount(spread.harmonic, weights=col, minlength=size) for col in a.T], axis=1
    )


def noise_beta_lower(
    spread: NoiseSpread,
    gain2: np.ndarray,
    bin_weights: np.ndarray,
    mask: np.ndarray | None = None,
    confidence: float = 0.9,
) -> float:
    """A lower confidence bound on the noise-only β that :func:`expected_noise_beta` estimates.

    The estimate ``Σ_m c_m σ̂_m²`` sums the harmonics' and outputs' estimates (each a gamma of
    ``spread.dof`` complex degrees of freedom times its true value), taken as one gamma of
    ``d = (Σ c_m σ_m²)² / Σ c_m² σ_m⁴ · dof`` degrees of freedom (its first two moments);
    the bound is ``sqrt(estimate / G_conf)`` with ``G_conf`` the gamma's ``confidence``
    quantile (mean 1). A window of few periods estimates its noise loosely: a warning on the
    bound is not raised by the estimate's own scatter.

    Returns:
        The bound (units of ``||w||``); NaN where the estimate is.
    """
    b = bin_weights if mask is None else np.where(mask, bin_weights, 0.0)
    a = b[:, None] * spread.var * gain2  # (n_bins, n_outputs): each output's own estimate
    total = float(a.sum())
    if not (math.isfinite(total) and total > 0.0):
        return math.nan if not math.isfinite(total) else 0.0
    per_harm = _per_harmonic(spread, a)
    unbias = 1.0 / (1.0 + 1.0 / spread.dof)  # E σ̂⁴ = σ⁴ (1 + 1/dof)
    d = total**2 * spread.dof / (unbias * float(np.sum(per_harm**2)))
    top = float(scipy.special.gammaincinv(d, confidence)) / d  # the gamma's quantile, mean 1
    return math.sqrt(total / top)


def _real_bin(n_bins: int, n_samples: int) -> np.ndarray:
    """(n_bins,) bool, the bins whose DFT is real (DC, and Nyquist for an even record)."""
    real = np.zeros(n_bins, bool)
    real[0] = True
    if n_samples % 2 == 0:
        real[-1] = True
    return real


@dataclass(frozen=True)
class NoiseWeights:
    """Flat noise weights set from the period-to-period spread (:func:`noise_weights`).

    Attributes:
        gains: (n_outputs,) float, each output's weight ``W_c`` (model units per unit of
            ``w``), as the weight's shape (``shape``) times this gain.
        noise_rms: (n_outputs,) float, ``sqrt(Σ_n b_n σ_c(n)² / shape_c(n)²)`` over the bins
            counted: each output's noise as its weight's shape sees it (the noise RMS over
            those bins for a flat weight in the power convention).
        quantile: the probability that the noise alone costs at most ``budget``.
        budget: the β the noise alone may cost at ``quantile``.
        expected_beta: ``sqrt(E β_noise²)`` on a window like the fit windows, with these gains.
        spread: relative standard deviation of ``β_noise²`` (one window's noise and the
            estimate's, together).
        dof: the weights' estimate's effective complex degrees of freedom, per output.
        n_outputs: ``n_y``, the channels that share ``w``.
    """

    gains: np.ndarray
    noise_rms: np.ndarray
    quantile: float
    budget: float
    expected_beta: float
    spread: float
    dof: np.ndarray
    n_outputs: int


def noise_weights(
    spread: NoiseSpread,
    bin_weights: np.ndarray,
    n_samples: int,
    *,
    mask: np.ndarray | None = None,
    shape: np.ndarray | None = None,
    quantile: float = NOISE_QUANTILE,
    budget: float = NOISE_BUDGET,
) -> NoiseWeights:
    """Noise weights whose noise-only β is at most ``budget`` with probability ``quantile``.

    The weights are ``W_c(n) = g_c shape_c(n)``; the probability is over a window like the
    fit windows and the fit's own scatter (docs/theory.md §13).

    Each output gets an equal share of the budget, ``g_c² = k Ĝ_c`` with
    ``Ĝ_c = Σ_n b_n σ̂_c(n)² / shape_c(n)²`` the expected cost of output ``c``'s noise under
    the shape. Then ``β_noise² = T / k`` with ``T = Σ_c Q_c / Ĝ_c`` (``Q_c`` the noise's
    cost on a new window); ``T`` is approximated by a scaled chi-square with its first two
    moments (Satterthwaite 1946), counting the new window's noise (each complex bin's
    ``|E|²/σ²`` exponential, a real bin's chi-square with one degree of freedom) and the
    estimate's (a gamma of ``dof`` per output), and ``k = T_q / budget²``. For many bins and
    periods, ``T → n_y`` and ``W_c → √n_y σ_c / budget``.

    Args:
        spread: the noise per bin (:func:`noise_spread`).
        bin_weights: (n_bins,) float, ``b_n`` of a window.
        n_samples: the window's length ``N``.
        mask: (n_bins,) bool, the bins β counts (the band); None: every bin.
        shape: (n_bins, n_outputs) float > 0, the weights' magnitude shape; None: flat.
        quantile: in (0, 1).
        budget: > 0, the noise-only β at ``quantile``.

    Raises:
        DatumError: a bad quantile or budget, no bin counted, an output without noise, or
            too few degrees of freedom to estimate the noise (``dof <= 2``).
    """
    if not 0.0 < quantile < 1.0:
        raise DatumError(f"quantile={quantile} must be in (0, 1)")
    if not (math.isfinite(budget) and budget > 0.0):
        raise DatumError(f"budget={budget} must be positive")
    var = spread.var
    n_bins, ny = var.shape
    b = bin_weights if mask is None else np.where(mask, bin_weights, 0.0)
    inv2 = np.ones_like(var) if shape is None else 1.0 / np.asarray(shape, float) ** 2
    a = b[:, None] * var * inv2  # (n_bins, ny): each bin's expected cost per unit gain²
    g_hat = a.sum(axis=0)
    if not np.all(g_hat > 0.0) or not np.all(np.isfinite(g_hat)):
        raise DatumError(
            "an output shows no noise over the bins counted (or the band holds none of its "
            "bins): its weight cannot be set from the data"
        )
    # squares of the estimated variances, unbiased: E σ̂⁴ = σ⁴ (1 + 1/dof) for a gamma σ̂²
    unbias = 1.0 / (1.0 + 1.0 / spread.dof)
    # the new window's noise: a b_n |E|²-term per bin, var a² (complex) or 2 a² (real bin)
    real = _real_bin(n_bins, n_samples)
    rel_q = unbias * np.sum(np.where(real[:, None], 2.0, 1.0) * a**2, axis=0) / g_hat**2
    # the estimate's: the bins sharing a harmonic share its estimate, (p-1) dof per window
    per_harm = _per_harmonic(spread, a)
    dof = g_hat**2 * spread.dof / (unbias * np.sum(per_harm**2, axis=0))
    if np.any(dof <= 2.0):
        raise DatumError(
            f"the noise estimate has {float(dof.min()):.3g} degrees of freedom (at least 3 "
            "needed): use more windows or more periods per window"
        )
    mean_r = dof / (dof - 1.0)  # E[Q/Ĝ] = E[1/Ĝ] E[Q], Ĝ/G ~ Gamma(dof, 1/dof)
    second = (1.0 + rel_q) * dof**2 / ((dof - 1.0) * (dof - 2.0))
    m_t = float(mean_r.sum())
    v_t = float(np.sum(second - mean_r**2))
    scale, h = v_t / (2.0 * m_t), 2.0 * m_t**2 / v_t
    t_q = float(scale * scipy.stats.chi2.ppf(quantile, h))
    k = t_q / budget**2
    return NoiseWeights(
        gains=np.sqrt(k * g_hat),
        noise_rms=np.sqrt(g_hat),
        quantile=float(quantile),
        budget=float(budget),
        expected_beta=math.sqrt(m_t / k),
        spread=math.sqrt(v_t) / m_t,
        dof=dof,
        n_outputs=ny,
    )


def noise_beta_quantile(weights: NoiseWeights, q: float) -> float:
    """The noise-only β at probability ``q`` under the fitted weights' distribution.

    The inverse of :func:`noise_weights`'s choice: ``budget`` at its own ``quantile``.
    """
    m_t = weights.expected_beta**2
    v_t = (weights.spread * m_t) ** 2
    scale, h = v_t / (2.0 * m_t), 2.0 * m_t**2 / v_t
    return math.sqrt(float(scale * scipy.stats.chi2.ppf(q, h)))


__all__ = [
    "NOISE_BETA_WARN",
    "NOISE_BUDGET",
    "NOISE_QUANTILE",
    "NOISE_WARN_CONFIDENCE",
    "NoiseSpread",
    "NoiseWeights",
    "expected_noise_beta",
    "noise_beta_lower",
    "noise_beta_quantile",
    "noise_floor",
    "noise_gain2",
    "noise_spread",
    "noise_weights",
    "spread_of_std",
]
