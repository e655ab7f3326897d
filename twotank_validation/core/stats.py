"""Probabilistic residual tests: whiteness and input–residual cross-correlation.

These are the classical statistical model-validation tests (L. Ljung, *System
Identification*, 1987, Sec. 16.6) that R. S. Smith (Automatica 31(11), 1995,
Sec. 2.1) contrasts with the deterministic worst-case validation test. The residual is

    eps(k) = y_measured(k) - y_model(k),   k = 0 .. N-1,

with ``y_model`` the simulated output of the nominal model driven by the measured
inputs ``u``. Both tests remove the sample mean first, so a constant bias in the
residual is *not* detected by them.

* **Whiteness.** With the biased sample autocovariance
  ``R_eps(tau) = (1/N) sum_k eps(k+tau) eps(k)``, the statistic
  ``zeta = N / R_eps(0)^2 * sum_{tau=1..M} R_eps(tau)^2`` is asymptotically
  chi^2(M) when eps is white. For a simulation (output-error) residual the
  disturbance is usually coloured even when the model is right, so failing this test
  says that the residual is not white, not necessarily that the model is wrong.
* **Cross-correlation.** ``R_eps_u(tau) = (1/N) sum_k eps(k+tau) u(k)`` for the
  causal lags ``tau = 0 .. M-1`` (residual after input). If eps is independent of
  u, ``sqrt(N) r`` with ``r = [R_eps_u(tau)]_tau`` is asymptotically N(0, P) with
  ``P[t1, t2] = sum_k R_eps(k) R_u(k + t1 - t2)``, and
  ``zeta = N r^T P^{-1} r`` is asymptotically chi^2(M). P accounts for the colour of
  *both* the residual and the input.

Estimating P (a deliberate choice, see ``asymptotic_covariance``): by default the sum
over k runs over *all* available sample lags, ``|k| <= N-1``. That estimate is the
inverse transform of the product of the two periodograms, hence positive
semidefinite by construction, and it is calibrated for strongly coloured residuals.
Ljung's truncation at ``|k| <= M`` (``covariance_lags=M``) can give an indefinite P
and over-reject badly when the residual is low-pass and the input broadband (the
usual output-error situation: about 30 % rejections at a nominal 5 % for an AR(1)
residual with pole 0.95 and a PRBS input, N = 2000, M = 25); it stays available for
comparison.

``residual_tests`` runs one whiteness test per output and one cross-correlation test
per (output, input) pair, each at level alpha; the overall ``passed`` is their
conjunction, so its family-wise false-rejection rate is larger than alpha.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.stats
from numpy.typing import ArrayLike, NDArray

from twotank_validation.errors import DatumError

__all__ = [
    "MIN_SAMPLES_PER_LAG",
    "CrossCorrelationResult",
    "ResidualTests",
    "WhitenessResult",
    "asymptotic_covariance",
    "autocovariance",
    "cross_correlation_test",
    "cross_covariance",
    "residual_tests",
    "whiteness_test",
]

MIN_SAMPLES_PER_LAG = 4
"""The record must have at least ``MIN_SAMPLES_PER_LAG * max_lag`` samples."""

_RCOND = 1e-10
"""Eigenvalues of P at or below ``_RCOND * max eigenvalue`` are dropped (pseudo-inverse)."""

_ZERO_VARIANCE_RTOL = 1e-12
"""A signal whose standard deviation is below this fraction of its magnitude is constant."""

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------- results


@dataclass(frozen=True, eq=False)
class WhitenessResult:
    """Outcome of the whiteness (autocorrelation) test of one residual channel.

    Attributes:
        statistic: ``zeta = N * sum_{tau=1..M} r(tau)^2``, asymptotically chi^2(M).
        dof: Degrees of freedom M (= ``max_lag``).
        p_value: ``P(chi^2(M) >= statistic)``.
        threshold: ``chi^2(M)`` quantile at ``1 - alpha``.
        alpha: Significance level of the test.
        passed: ``statistic <= threshold`` (whiteness not rejected).
        autocorrelation: (max_lag + 1,) float, read-only; ``r(tau) = R_eps(tau) /
            R_eps(0)`` for ``tau = 0 .. max_lag`` (so ``r(0) = 1``).
        band: Per-lag band ``z_{1-alpha/2} / sqrt(N)``; under whiteness each
            ``r(tau)``, ``tau >= 1``, lies inside ``+-band`` with probability 1 - alpha.
    """

    statistic: float
    dof: int
    p_value: float
    threshold: float
    alpha: float
    passed: bool
    autocorrelation: FloatArray
    band: float

    def to_dict(self) -> dict[str, object]:
        """Return the result as JSON-serialisable plain Python values."""
        return {
            "statistic": float(self.statistic),
            "dof": int(self.dof),
            "p_value": float(self.p_value),
            "threshold": float(self.threshold),
            "alpha": float(self.alpha),
            "passed": bool(self.passed),
            "autocorrelation": [float(v) for v in self.autocorrelation],
            "band": float(self.band),
        }


@dataclass(frozen=True, eq=False)
class CrossCorrelationResult:
    """Outcome of the input–residual cross-correlation test of one (output, input) pair.

    Attributes:
        statistic: ``zeta = N r^T P^{-1} r`` (pseudo-inverse if P is ill-conditioned).
        dof: Degrees of freedom: ``max_lag``, or the rank kept by the pseudo-inverse.
        p_value: ``P(chi^2(dof) >= statistic)``.
        threshold: ``chi^2(dof)`` quantile at ``1 - alpha``.
        alpha: Significance level of the test.
        passed: ``statistic <= threshold`` (independence not rejected).
        cross_correlation: (max_lag,) float, read-only; ``R_eps_u(tau) /
            sqrt(R_eps(0) R_u(0))`` for the causal lags ``tau = 0 .. max_lag-1``.
        band: (max_lag,) float, read-only; per-lag band ``z_{1-alpha/2} *
            sqrt(P[tau, tau] / N) / sqrt(R_eps(0) R_u(0))`` of the normalised
            cross-correlation under independence (it accounts for the colour of both
            signals, so it is wider than ``z / sqrt(N)`` when both are low-pass).
        pseudo_inverse_used: True if P was singular or ill-conditioned (eigenvalues
            at or below ``1e-10`` times the largest were dropped and ``dof`` reduced).
    """

    statistic: float
    dof: int
    p_value: float
    threshold: float
    alpha: float
    passed: bool
    cross_correlation: FloatArray
    band: FloatArray
    pseudo_inverse_used: bool

    def to_dict(self) -> dict[str, object]:
        """Return the result as JSON-serialisable plain Python values."""
        return {
            "statistic": float(self.statistic),
            "dof": int(self.dof),
            "p_value": float(self.p_value),
            "threshold": float(self.threshold),
            "alpha": float(self.alpha),
            "passed": bool(self.passed),
            "cross_correlation": [float(v) for v in self.cross_correlation],
            "band": [float(v) for v in self.band],
            "pseudo_inverse_used": bool(self.pseudo_inverse_used),
        }


@dataclass(frozen=True, eq=False)
class ResidualTests:
    """All residual tests of a multi-output record.

    Attributes:
        whiteness: One result per output name.
        cross_correlation: One result per ``(output name, input name)`` pair.
        passed: True if every individual test passed (each is run at level
            ``alpha``, so the family-wise rejection rate under the null is larger).
        max_lag: Number of lags M used by every test.
        alpha: Significance level of every individual test.
    """

    whiteness: dict[str, WhitenessResult]
    cross_correlation: dict[tuple[str, str], CrossCorrelationResult]
    passed: bool
    max_lag: int
    alpha: float

    def to_dict(self) -> dict[str, object]:
        """Return JSON-serialisable plain Python values.

        Returns:
            ``{"passed", "max_lag", "alpha", "whiteness": {output: {...}},
            "cross_correlation": {output: {input: {...}}}}``; the inner dicts are the
            ``to_dict()`` of the individual results.
        """
        cross: dict[str, dict[str, dict[str, object]]] = {}
        for (out_name, in_name), result in self.cross_correlation.items():
            cross.setdefault(out_name, {})[in_name] = result.to_dict()
        return {
            "passed": bool(self.passed),
            "max_lag": int(self.max_lag),
            "alpha": float(self.alpha),
            "whiteness": {name: res.to_dict() for name, res in self.whiteness.items()},
            "cross_correlation": cross,
        }


# --------------------------------------------------------------------------- validation


def _check_signal(x: ArrayLike, name: str) -> FloatArray:
    """Return ``x`` as a finite (N,) float64 array or raise DatumError naming ``name``."""
    arr = np.asarray(x)
    if arr.dtype.kind not in "biuf":
        raise DatumError(f"{name} must be a real numeric array; got dtype {arr.dtype}.")
    if arr.ndim != 1:
        raise DatumError(
            f"{name} must be one-dimensional with shape (n_samples,); got shape {arr.shape}. "
            "Pass one channel at a time or use residual_tests for (n_samples, n) arrays."
        )
    arr = arr.astype(np.float64)
    _check_finite(arr, name)
    return arr


def _check_finite(arr: FloatArray, name: str) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        index = first[0] if len(first) == 1 else first
        raise DatumError(
            f"{name} contains {int(bad.sum())} non-finite value(s) (NaN or inf), first at "
            f"index {index}; remove or interpolate them before validating."
        )


def _check_max_lag(max_lag: object, name: str = "max_lag") -> int:
    if isinstance(max_lag, bool) or not isinstance(max_lag, numbers.Integral):
        raise DatumError(f"{name} must be an integer; got {max_lag!r}.")
    if max_lag < 1:
        raise DatumError(f"{name} must be at least 1; got {max_lag}.")
    return int(max_lag)


def _check_alpha(alpha: object) -> float:
    if isinstance(alpha, bool) or not isinstance(alpha, numbers.Real):
        raise DatumError(f"alpha must be a real number in (0, 1); got {alpha!r}.")
    value = float(alpha)
    if not 0.0 < value < 1.0:  # also rejects NaN
        raise DatumError(f"alpha must lie strictly between 0 and 1; got {alpha!r}.")
    return value


def _check_length(n_samples: int, max_lag: int, name: str) -> None:
    needed = MIN_SAMPLES_PER_LAG * max_lag
    if n_samples < needed:
        raise DatumError(
            f"{name} has {n_samples} samples but max_lag={max_lag} needs at least {needed} "
            f"({MIN_SAMPLES_PER_LAG} * max_lag); use a longer record or a smaller max_lag."
        )


def _check_variance(x: FloatArray, name: str) -> None:
    scale = float(np.max(np.abs(x)))
    spread = float(np.std(x))
    if spread == 0.0 or spread <= _ZERO_VARIANCE_RTOL * scale:
        raise DatumError(
            f"{name} has zero variance (constant value {float(x[0])!r}); the correlation "
            "tests need a varying signal (a constant residual is a pure bias, a constant "
            "input carries no excitation)."
        )


def _check_same_length(a: FloatArray, b: FloatArray, name_a: str, name_b: str) -> None:
    if a.shape[0] != b.shape[0]:
        raise DatumError(
            f"{name_a} has {a.shape[0]} samples but {name_b} has {b.shape[0]}; both must be "
            "sampled at the same instants (same length)."
        )


# --------------------------------------------------------------------------- correlations


def _raw_cross_covariance(a: FloatArray, b: FloatArray, max_lag: int) -> FloatArray:
    """``(1/N) sum_k a(k+tau) b(k)``, tau = 0..max_lag, of demeaned a, b by FFT.

    A transform length ``n >= N + max_lag`` makes the circular correlation equal to the
    linear one at these lags. Lags ``>= N`` are zero.
    """
    n_samples = a.shape[0]
    n_fft = scipy.fft.next_fast_len(n_samples + max_lag, real=True)
    spectrum = np.fft.rfft(a, n_fft) * np.conj(np.fft.rfft(b, n_fft))
    full = np.fft.irfft(spectrum, n_fft)
    out = np.zeros(max_lag + 1)
    n_valid = min(max_lag, n_samples - 1) + 1
    out[:n_valid] = full[:n_valid] / n_samples
    return out


def autocovariance(x: ArrayLike, max_lag: int) -> FloatArray:
    """Biased sample autocovariance of a demeaned signal.

    Args:
        x: (n_samples,) float signal, finite.
        max_lag: Largest lag (>= 0); lags at or beyond ``n_samples`` are zero.

    Returns:
        (max_lag + 1,) float: ``R(tau) = (1/N) sum_{k=0}^{N-1-tau} xc(k+tau) xc(k)``
        for ``tau = 0 .. max_lag`` with ``xc = x - mean(x)``.

    Raises:
        DatumError: If ``x`` is not a finite 1-D array or ``max_lag`` is negative.
    """
    arr = _check_signal(x, "x")
    lag = _check_nonnegative_lag(max_lag)
    centred = arr - arr.mean()
    return _raw_cross_covariance(centred, centred, lag)


def cross_covariance(residual: ArrayLike, u: ArrayLike, max_lag: int) -> FloatArray:
    """Biased sample cross-covariance, residual after input (causal lags).

    Args:
        residual: (n_samples,) float residual eps, finite.
        u: (n_samples,) float input, finite, same length.
        max_lag: Largest lag (>= 0); lags at or beyond ``n_samples`` are zero.

    Returns:
        (max_lag + 1,) float: ``R_eps_u(tau) = (1/N) sum_{k=0}^{N-1-tau} epsc(k+tau)
        uc(k)`` for ``tau = 0 .. max_lag``, both signals demeaned.

    Raises:
        DatumError: On non-finite or non-1-D data, mismatched lengths, negative lag.
    """
    eps = _check_signal(residual, "residual")
    inp = _check_signal(u, "u")
    _check_same_length(eps, inp, "residual", "u")
    lag = _check_nonnegative_lag(max_lag)
    return _raw_cross_covariance(eps - eps.mean(), inp - inp.mean(), lag)


def _check_nonnegative_lag(max_lag: object) -> int:
    if isinstance(max_lag, bool) or not isinstance(max_lag, numbers.Integral) or max_lag < 0:
        raise DatumError(f"max_lag must be a non-negative integer; got {max_lag!r}.")
    return int(max_lag)


def _full_sum_covariance_sequence(eps: FloatArray, u: FloatArray, n_lags: int) -> FloatArray:
    """``c(d) = sum_{|k|<=N-1} R_eps(k) R_u(k+d)``, d = 0..n_lags-1, eps and u demeaned.

    The two-sided sample autocovariances have transforms ``|E|^2/N`` and ``|U|^2/N``, so
    c is the inverse transform of ``|E|^2 |U|^2 / N^2`` (non-negative: c is a positive
    semidefinite sequence). The linear convolution has support ``|d| <= 2N-2``; a
    transform length ``n >= 2N + n_lags - 2`` keeps the lags ``0..n_lags-1`` unaliased.
    """
    n_samples = eps.shape[0]
    n_fft = scipy.fft.next_fast_len(2 * n_samples + n_lags, real=True)
    power_eps = np.abs(np.fft.rfft(eps, n_fft)) ** 2
    power_u = np.abs(np.fft.rfft(u, n_fft)) ** 2
    full = np.fft.irfft(power_eps * power_u, n_fft)
    return np.asarray(full[:n_lags] / n_samples**2, dtype=np.float64)


def _truncated_covariance_sequence(
    eps: FloatArray, u: FloatArray, n_lags: int, covariance_lags: int
) -> FloatArray:
    """``c(d) = sum_{|k|<=K} R_eps(k) R_u(k+d)``, d = 0..n_lags-1 (Ljung's truncation)."""
    r_eps = _raw_cross_covariance(eps, eps, covariance_lags)
    r_u = _raw_cross_covariance(u, u, covariance_lags + n_lags - 1)
    two_sided_eps = np.concatenate([r_eps[:0:-1], r_eps])  # k = -K .. K
    two_sided_u = np.concatenate([r_u[:0:-1], r_u])  # j = -(K+n-1) .. K+n-1
    # valid correlation: out[s] = sum_i two_sided_u[s + i] * two_sided_eps[i],
    # s = d + n_lags - 1 for d = -(n_lags-1) .. n_lags-1.
    out = np.correlate(two_sided_u, two_sided_eps, mode="valid")
    return np.asarray(out[n_lags - 1 :], dtype=np.float64)


def asymptotic_covariance(
    residual: ArrayLike,
    u: ArrayLike,
    n_lags: int,
    *,
    covariance_lags: int | None = None,
) -> FloatArray:
    """Estimate P, the asymptotic covariance of ``sqrt(N) [R_eps_u(tau)]_{tau=0..n_lags-1}``.

    Under independence of eps and u, ``P[t1, t2] = c(t1 - t2)`` with
    ``c(d) = sum_k R_eps(k) R_u(k + d)`` (symmetric Toeplitz). The sample
    autocovariances replace the true ones.

    Args:
        residual: (n_samples,) float residual, finite.
        u: (n_samples,) float input, finite, same length.
        n_lags: Number of cross-covariance lags M (>= 1); P is (M, M).
        covariance_lags: None (default) sums over all available lags ``|k| <= N-1``,
            which gives a positive semidefinite P; an integer K >= 0 truncates the sum
            at ``|k| <= K`` as in Ljung (1987), which can give an indefinite P (K = 0
            assumes a white residual).

    Returns:
        (n_lags, n_lags) float, symmetric.

    Raises:
        DatumError: On invalid data, mismatched lengths or invalid lag counts.
    """
    eps = _check_signal(residual, "residual")
    inp = _check_signal(u, "u")
    _check_same_length(eps, inp, "residual", "u")
    lags = _check_max_lag(n_lags, "n_lags")
    eps = eps - eps.mean()
    inp = inp - inp.mean()
    if covariance_lags is None:
        seq = _full_sum_covariance_sequence(eps, inp, lags)
    else:
        k_max = _check_nonnegative_lag(covariance_lags)
        seq = _truncated_covariance_sequence(eps, inp, lags, k_max)
    idx = np.arange(lags)
    return np.asarray(seq[np.abs(idx[:, None] - idx[None, :])], dtype=np.float64)


def _chi2_quadratic_form(r: FloatArray, P: FloatArray) -> tuple[float, int, bool]:
    """Return ``(r^T P^+ r, rank kept, pseudo-inverse used)`` for symmetric P.

    Eigenvalues at or below ``_RCOND * max eigenvalue`` (including negative ones, which a
    truncated estimate can produce) are dropped.

    Raises:
        DatumError: If P has no positive eigenvalue.
    """
    eigenvalues, eigenvectors = np.linalg.eigh(P)
    largest = float(eigenvalues[-1])
    if not largest > 0.0:
        raise DatumError(
            "the estimated covariance P of the cross-correlations has no positive "
            f"eigenvalue (largest {largest!r}); use covariance_lags=None (all lags)."
        )
    keep = eigenvalues > _RCOND * largest
    projections = eigenvectors[:, keep].T @ r
    value = float(np.sum(projections**2 / eigenvalues[keep]))
    rank = int(np.count_nonzero(keep))
    return value, rank, rank < r.shape[0]


def _readonly(x: FloatArray) -> FloatArray:
    out = np.array(x, dtype=np.float64, copy=True)
    out.flags.writeable = False
    return out


# --------------------------------------------------------------------------- tests


def _whiteness(eps: FloatArray, max_lag: int, alpha: float) -> WhitenessResult:
    """Whiteness test on a validated residual."""
    n_samples = eps.shape[0]
    r_eps = _raw_cross_covariance(eps - eps.mean(), eps - eps.mean(), max_lag)
    autocorrelation = r_eps / r_eps[0]
    statistic = float(n_samples * np.sum(autocorrelation[1:] ** 2))
    threshold = float(scipy.stats.chi2.isf(alpha, max_lag))
    return WhitenessResult(
        statistic=statistic,
        dof=max_lag,
        p_value=float(scipy.stats.chi2.sf(statistic, max_lag)),
        threshold=threshold,
        alpha=alpha,
        passed=bool(statistic <= threshold),
        autocorrelation=_readonly(autocorrelation),
        band=float(scipy.stats.norm.isf(alpha / 2.0) / math.sqrt(n_samples)),
    )


def _cross(
    eps: FloatArray,
    inp: FloatArray,
    max_lag: int,
    alpha: float,
    covariance_lags: int | None,
) -> CrossCorrelationResult:
    """Cross-correlation test on a validated (residual, input) pair."""
    n_samples = eps.shape[0]
    eps_c = eps - eps.mean()
    inp_c = inp - inp.mean()
    r = _raw_cross_covariance(eps_c, inp_c, max_lag - 1)  # tau = 0 .. M-1
    var_eps = float(np.dot(eps_c, eps_c) / n_samples)
    var_u = float(np.dot(inp_c, inp_c) / n_samples)
    P = asymptotic_covariance(eps_c, inp_c, max_lag, covariance_lags=covariance_lags)
    quad, dof, pinv_used = _chi2_quadratic_form(r, P)
    statistic = n_samples * quad
    threshold = float(scipy.stats.chi2.isf(alpha, dof))
    norm = math.sqrt(var_eps * var_u)
    lag_sd = np.sqrt(np.clip(np.diag(P), 0.0, None) / n_samples) / norm
    z = float(scipy.stats.norm.isf(alpha / 2.0))
    return CrossCorrelationResult(
        statistic=statistic,
        dof=dof,
        p_value=float(scipy.stats.chi2.sf(statistic, dof)),
        threshold=threshold,
        alpha=alpha,
        passed=bool(statistic <= threshold),
        cross_correlation=_readonly(r / norm),
        band=_readonly(z * lag_sd),
        pseudo_inverse_used=pinv_used,
    )


def whiteness_test(residual: ArrayLike, max_lag: int = 25, alpha: float = 0.01) -> WhitenessResult:
    """Test whether a residual is white (Ljung 1987, Sec. 16.6).

    Args:
        residual: (n_samples,) float residual eps, finite, not constant,
            ``n_samples >= 4 * max_lag``.
        max_lag: Number of lags M tested (``tau = 1 .. M``), >= 1.
        alpha: Significance level in (0, 1).

    Returns:
        The statistic ``N / R_eps(0)^2 * sum_{tau=1..M} R_eps(tau)^2`` compared with
        its asymptotic chi^2(M) distribution.

    Raises:
        DatumError: On NaN/inf, wrong shape, too short a record, a constant residual,
            a non-integer or non-positive ``max_lag``, or ``alpha`` outside (0, 1).
    """
    lag = _check_max_lag(max_lag)
    level = _check_alpha(alpha)
    eps = _check_signal(residual, "residual")
    _check_length(eps.shape[0], lag, "residual")
    _check_variance(eps, "residual")
    return _whiteness(eps, lag, level)


def cross_correlation_test(
    residual: ArrayLike,
    u: ArrayLike,
    max_lag: int = 25,
    alpha: float = 0.01,
    *,
    covariance_lags: int | None = None,
) -> CrossCorrelationResult:
    """Test whether a residual is uncorrelated with past and present input (Ljung 16.6).

    Args:
        residual: (n_samples,) float residual eps, finite, not constant,
            ``n_samples >= 4 * max_lag``.
        u: (n_samples,) float input, finite, not constant.
        max_lag: Number of lags M tested (``tau = 0 .. M-1``, residual after input).
        alpha: Significance level in (0, 1).
        covariance_lags: How P is estimated, see ``asymptotic_covariance``; keep the
            default None unless comparing with Ljung's truncated estimate.

    Returns:
        The statistic ``N r^T P^{-1} r`` compared with chi^2(M) (or chi^2(rank) with a
        pseudo-inverse if P is ill-conditioned).

    Raises:
        DatumError: On NaN/inf, wrong shapes, mismatched lengths, too short a record,
            constant residual or input, invalid ``max_lag`` or ``alpha``.
    """
    lag = _check_max_lag(max_lag)
    level = _check_alpha(alpha)
    eps = _check_signal(residual, "residual")
    inp = _check_signal(u, "u")
    _check_same_length(eps, inp, "residual", "u")
    _check_length(eps.shape[0], lag, "residual")
    _check_variance(eps, "residual")
    _check_variance(inp, "u")
    return _cross(eps, inp, lag, level, covariance_lags)


def _as_columns(x: ArrayLike, name: str) -> FloatArray:
    """Return ``x`` as a finite (n_samples, n) float64 array; 1-D becomes one column."""
    arr = np.asarray(x)
    if arr.dtype.kind not in "biuf":
        raise DatumError(f"{name} must be a real numeric array; got dtype {arr.dtype}.")
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise DatumError(
            f"{name} must have shape (n_samples, n_channels) or (n_samples,); "
            f"got shape {arr.shape}."
        )
    arr = arr.astype(np.float64)
    _check_finite(arr, name)
    return arr


def _names(names: Sequence[str] | None, count: int, prefix: str, what: str) -> list[str]:
    if names is None:
        return [f"{prefix}{i}" for i in range(count)]
    if isinstance(names, str):
        raise DatumError(f"{what} must be a sequence of strings, not the single string {names!r}.")
    out = list(names)
    if len(out) != count:
        raise DatumError(f"{what} has {len(out)} name(s) {out!r} but the array has {count}.")
    if not all(isinstance(n, str) for n in out):
        raise DatumError(f"{what} must all be strings; got {out!r}.")
    if len(set(out)) != len(out):
        raise DatumError(f"{what} must be unique; got {out!r}.")
    return out


def residual_tests(
    residual: ArrayLike,
    inputs: ArrayLike,
    *,
    output_names: Sequence[str] | None = None,
    input_names: Sequence[str] | None = None,
    max_lag: int = 25,
    alpha: float = 0.01,
) -> ResidualTests:
    """Run the whiteness and cross-correlation tests on every output and input channel.

    Args:
        residual: (n_samples, n_outputs) float residual (1-D means one output).
        inputs: (n_samples, n_inputs) float inputs (1-D means one input); zero
            columns run whiteness tests only.
        output_names: n_outputs unique names (default ``y0, y1, ...``).
        input_names: n_inputs unique names (default ``u0, u1, ...``).
        max_lag: Number of lags M of every test.
        alpha: Significance level of every individual test, in (0, 1).

    Returns:
        One whiteness result per output, one cross-correlation result per
        (output, input) pair, and their conjunction ``passed``.

    Raises:
        DatumError: On NaN/inf, bad shapes, mismatched lengths or name counts, too
            short a record, a constant channel, invalid ``max_lag`` or ``alpha``.
    """
    lag = _check_max_lag(max_lag)
    level = _check_alpha(alpha)
    eps = _as_columns(residual, "residual")
    inp = _as_columns(inputs, "inputs")
    _check_same_length(eps, inp, "residual", "inputs")
    _check_length(eps.shape[0], lag, "residual")
    outs = _names(output_names, eps.shape[1], "y", "output_names")
    ins = _names(input_names, inp.shape[1], "u", "input_names")
    if eps.shape[1] == 0:
        raise DatumError("residual has no output column (shape (n_samples, 0)).")
    for j, name in enumerate(outs):
        _check_variance(eps[:, j], f"residual column {name!r}")
    for j, name in enumerate(ins):
        _check_variance(inp[:, j], f"input column {name!r}")

    whiteness = {name: _whiteness(eps[:, i], lag, level) for i, name in enumerate(outs)}
    cross = {
        (out_name, in_name): _cross(eps[:, i], inp[:, j], lag, level, None)
        for i, out_name in enumerate(outs)
        for j, in_name in enumerate(ins)
    }
    passed = all(r.passed for r in whiteness.values()) and all(r.passed for r in cross.values())
    return ResidualTests(
        whiteness=whiteness,
        cross_correlation=cross,
        passed=passed,
        max_lag=lag,
        alpha=level,
    )
