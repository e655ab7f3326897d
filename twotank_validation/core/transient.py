"""The transient term of a window: estimated from neighbouring lines and removed (issue 32).

Over any window of ``N`` samples an LTI member of the model set gives, for any input,
``Y(n) = G(Omega_n) U(n) + T(Omega_n) + V(n)`` (Pintelon & Schoukens 2012, Sec. 2.6;
Pintelon et al., MSSP 24(3), 2010): ``T`` the transient (the member's initial state minus its
final state, seen through its dynamics), smooth in ``n``. The local polynomial method (ibid.)
estimates ``T`` at a line from the lines around it; here only from lines the excitation does
not drive (``n % n_periods != 0``; every line but ``n`` itself with one period), after the
nominal's ``P23 U`` is removed there, so that the model set's own part at the line judged is
left to Problem 3. The polynomial is fitted to ``A T``, ``A`` the model's denominator (its
parts' poles): a slow pole's transient varies near DC faster than a polynomial follows,
``A T`` does not. Docs: docs/theory.md §20.

What the routes see is a transformed datum (``Y - T_hat``) and response (the noise channel
scaled per bin by ``sqrt(1 + leverage)``); the model error that the estimate picks up from
lines where ``U != 0`` is bounded per bin (``rho``) and taken off that bin's minimum
(:func:`lowered`): nothing in the solvers changes. Written by hand: no maintained library
implements the local polynomial method, and ``identify.lpm`` (a layer above the core)
estimates the response and the transient together, where here the response is the model
set's and only the transient is estimated, from the lines the excitation does not drive.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace
from functools import cache, cached_property

import numpy as np
import scipy.sparse

from twotank_validation.core import lti
from twotank_validation.core.band import masked_beta
from twotank_validation.core.datum import Datum, PeriodicityFinding
from twotank_validation.core.model import LFTModel, PlantResponse
from twotank_validation.core.oppoint import DcTransient
from twotank_validation.core.validate import BetaResult, validate_beta, validation_band


class TransientMethod(enum.StrEnum):
    """How a window's transient term is treated."""

    NONE = "none"
    """Not at all: the window must be periodic and settled (the periodicity gate)."""
    LOCAL_POLYNOMIAL = "local_polynomial"
    """Estimated from the neighbouring lines by a local polynomial and removed."""
    AUTO = "auto"
    """Per window: as ``NONE`` where the periodicity gate passes (the input repeats and the
    plant has settled), as ``LOCAL_POLYNOMIAL`` where the gate would leave it unjudged (docs/
    theory.md §20)."""


@dataclass(frozen=True)
class LocalPolynomial:
    """The linear estimate ``T_hat(n) = sum_j a[n, j] X(k_j)`` of every bin.

    A line ``k`` outside ``0 .. N/2`` is read through the symmetry of a real signal's DFT,
    ``X(k) = conj(X(N - k))`` (``X(-k) = conj(X(k))``), so that DC and Nyquist lie inside
    the fit, not at its edge.

    Attributes:
        lines: (n_bins, m) int, the kept bin each line ``k_j`` reads (``m = 2 half_width``).
        mirror: (n_bins, m) bool, the line is read conjugated (it lies below DC or above
            Nyquist).
        weights: (n_bins, m) float, ``a``: the first row of the least-squares fit's
            pseudo-inverse (polynomial of order ``order`` in ``k - n``); zero at DC.
        leverage: (n_bins,) float, ``sum_j a[n, j]^2``: the estimate's noise variance
            relative to one line's (circular white noise; 0 at DC).
    """

    lines: np.ndarray
    mirror: np.ndarray
    weights: np.ndarray
    leverage: np.ndarray

    @cached_property
    def _operators(self) -> tuple[scipy.sparse.csr_array, ...]:
        """The estimate as sparse matrices: on ``X``, on ``conj(X)``, and in magnitude.

        A window's estimate is then a few sparse products.
        """
        n_bins, m = self.lines.shape
        rows = np.repeat(np.arange(n_bins), m)
        cols = self.lines.ravel()
        flip = self.mirror.ravel()
        a = self.weights.ravel()

        def sparse(values: np.ndarray) -> scipy.sparse.csr_array:
            return scipy.sparse.csr_array((values, (rows, cols)), shape=(n_bins, n_bins))

        return (
            sparse(np.where(flip, 0.0, a)),
            sparse(np.where(flip, a, 0.0)),
            sparse(np.abs(a)),
        )

    @cached_property
    def fit_lines(self) -> np.ndarray:
        """(n_bins,) bool, the bins some bin's fit reads (DC's row reads none)."""
        out = np.zeros(self.lines.shape[0], dtype=bool)
        out[self.lines[1:].ravel()] = True
        return out

    @property
    def noise_scale(self) -> np.ndarray:
        """(n_bins,) float, ``sqrt(1 + leverage)``: the noise of ``V(n) - V_hat(n)``."""
        return np.sqrt(1.0 + self.leverage)

    def apply(self, x: np.ndarray, *, magnitude: bool = False) -> np.ndarray:
        """(n_bins, n_channels): ``sum_j a[n, j] X(k_j)`` at every bin.

        Args:
            x: (n_bins, n_channels), a quantity at the kept bins.
            magnitude: ``sum_j |a[n, j]| |X(k_j)|`` instead (a bound's propagation).
        """
        direct, mirrored, size = self._operators
        if magnitude:
            return np.asarray(size @ np.abs(x))
        return np.asarray(direct @ x + mirrored @ np.conj(x))


@cache  # a pure function of four integers, asked for by every config check and monitor
def local_polynomial(
    n_samples: int, n_periods: int, order: int, half_width: int
) -> LocalPolynomial:
    """The local polynomial estimate of a transient at every kept bin of a window.

    Each bin ``n >= 1`` takes the ``half_width`` nearest usable lines below and above it;
    usable: not DC (the bias is removed there), not ``n`` nor its mirror ``N - n`` (its own
    noise) and, with two or more periods, not a harmonic of the period (whose ``G U`` is
    the model set's to explain). The polynomial ``sum_r c_r ((k - n) / half_width)^r``,
    ``r = 0 .. order``, is fitted by least squares and ``T_hat(n) = c_0``.

    Args:
        n_samples: the window's length ``N`` (``n_periods`` whole periods).
        n_periods: whole periods in the window.
        order: polynomial order ``R`` (>= 0).
        half_width: lines on each side, ``2 half_width >= order + 2`` (one degree of freedom
            left over).

    Raises:
        ValueError: too few lines for the order, or fewer usable lines than the fit needs.
    """
    m = 2 * half_width
    n_bins = n_samples // 2 + 1
    if order < 0 or m < order + 2:
        raise ValueError(
            f"transient_half_width = {half_width} gives {m} lines, too few for a polynomial of "
            f"order {order}: use a half-width of at least {(order + 3) // 2}"
        )
    step = n_periods if n_periods >= 2 else 1
    usable_lines = n_samples - n_samples // step if step > 1 else n_samples - 1
    if usable_lines < m + 2:
        raise ValueError(
            f"the window has {usable_lines} lines the excitation does not drive, fewer than "
            f"the {m + 2} a transient estimate of half-width {half_width} needs: use longer "
            "windows or a smaller transient_half_width"
        )
    lines = np.zeros((n_bins, m), dtype=int)
    mirror = np.zeros((n_bins, m), dtype=bool)
    weights = np.zeros((n_bins, m))
    reach = (half_width + 2) * step
    for n in range(1, n_bins):
        k = np.arange(n - reach, n + reach + 1)
        kept = k % n_samples
        ok = (kept != 0) & (kept != n) & (kept != n_samples - n)
        if step > 1:
            ok &= kept % step != 0
        below, above = k[ok & (k < n)][-half_width:], k[ok & (k > n)][:half_width]
        pick = np.concatenate([below, above])
        kept = pick % n_samples
        flip = kept > n_samples // 2
        basis = np.vander((pick - n) / half_width, order + 1, increasing=True)
        lines[n] = np.where(flip, n_samples - kept, kept)
        mirror[n] = flip
        weights[n] = np.linalg.pinv(basis)[0]
    leverage = np.sum(weights**2, axis=1)
    for shared in (lines, mirror, weights, leverage):  # one estimate serves every caller
        shared.setflags(write=False)
    return LocalPolynomial(lines, mirror, weights, leverage)


def model_poles(model: LFTModel, ts_s: float) -> np.ndarray:
    """(n,) complex, the discrete poles of the model set's parts at ``ts_s``.

    The nominal's (or the generalized plant's) and every perturbation's and noise weight's:
    a member's transient is a rational function of ``exp(j Omega)`` over these (and its
    ``Delta``'s) poles (docs/theory.md §20). Output delays are not poles.
    """
    parts = [model.nominal_discrete(ts_s)] if model.nominal is not None else []
    if model.generalized is not None:
        parts.append(lti.discretise(model.generalized, ts_s, model.intersample))
    parts += [lti.discretise(p.weight, ts_s, model.intersample) for p in model.perturbations]
    parts += [lti.discretise(c.weight, ts_s, model.intersample) for c in model.noise]
    eig = [np.linalg.eigvals(p.a) for p in parts if p.a.size]
    return np.concatenate(eig) if eig else np.zeros(0, complex)


def denominator(poles: np.ndarray, n_samples: int) -> np.ndarray:
    """(N//2 + 1,) complex, ``A(n) = prod_i (1 - lambda_i exp(-j 2 pi n / N))``.

    The transient of a system with these poles is ``I(n) / A(n)``, ``I`` a trigonometric
    polynomial of lower degree: ``A T`` has no pole near the unit circle, and a local
    polynomial follows it where it could not follow ``T`` near a slow pole. Normalised to a
    largest magnitude of 1 (the estimate does not depend on the scale of ``A``).
    """
    theta = 2.0 * np.pi * np.arange(n_samples // 2 + 1) / n_samples
    out = np.ones(theta.size, complex)
    for lam in poles:
        out *= 1.0 - lam * np.exp(-1j * theta)
        out /= np.max(np.abs(out))
    return out


@dataclass(frozen=True)
class TransientEstimate:
    """The local polynomial weighted by a model's denominator, with what it costs.

    ``T_hat(n) = (1 / A(n)) sum_j a_nj A(k_j) R(k_j)`` (:class:`LocalPolynomial` on ``A R``).

    Attributes:
        lpm: the local polynomial.
        den: (n_bins,) complex, ``A(n)`` (:func:`denominator`; ones: plain polynomial).
        noise_scale: (n_bins,) float, ``sqrt(1 + sum_j a_nj^2 |A(k_j)|^2 / |A(n)|^2)``.
    """

    lpm: LocalPolynomial
    den: np.ndarray
    noise_scale: np.ndarray

    @classmethod
    def of(cls, lpm: LocalPolynomial, den: np.ndarray | None = None) -> TransientEstimate:
        """The estimate with denominator ``den`` (None: none, the plain polynomial)."""
        a = np.ones(lpm.lines.shape[0], complex) if den is None else np.asarray(den)
        mag = np.abs(a)
        ratio = mag[lpm.lines] / np.where(mag > 0.0, mag, 1.0)[:, None]
        leverage = np.sum((lpm.weights * ratio) ** 2, axis=1)
        return cls(lpm, a, np.sqrt(1.0 + leverage))

    @cached_property
    def _operators(self) -> tuple[scipy.sparse.csr_array, scipy.sparse.csr_array]:
        """The estimate as two complex sparse matrices, on ``X`` and on ``conj(X)``.

        ``diag(1/A) S diag(A)`` and ``diag(1/A) S' diag(conj A)`` (``S``, ``S'`` the local
        polynomial's direct and mirrored parts), so that a window's estimate is two sparse
        products; the row of DC is empty (its estimate is 0).
        """
        direct, mirrored, _ = self.lpm._operators
        den = np.where(np.abs(self.den) > 0.0, self.den, 1.0)
        inv = scipy.sparse.diags_array(np.r_[0.0, 1.0 / den[1:]])
        return (
            scipy.sparse.csr_array(inv @ direct @ scipy.sparse.diags_array(self.den)),
            scipy.sparse.csr_array(inv @ mirrored @ scipy.sparse.diags_array(np.conj(self.den))),
        )

    def apply(self, x: np.ndarray) -> np.ndarray:
        """(n_bins, n_channels), the estimate from ``x`` at every bin (0 at DC)."""
        on_x, on_conj = self._operators
        return np.asarray(on_x @ x + on_conj @ np.conj(x))

    def bound(self, size: np.ndarray) -> np.ndarray:
        """(n_bins, n_channels), ``sum_j |a_nj| |A(k_j)| size(k_j) / |A(n)|``."""
        mag = np.abs(self.den)[:, None]
        return np.asarray(self.lpm.apply(mag * size, magnitude=True) / mag)


def transient_estimate(
    lpm: LocalPolynomial, model: LFTModel, ts_s: float, n_samples: int
) -> TransientEstimate:
    """The estimate for ``model``'s windows: the local polynomial over ``model``'s poles."""
    return TransientEstimate.of(lpm, denominator(model_poles(model, ts_s), n_samples))


@dataclass(frozen=True)
class DcEstimate:
    """The transient term at DC, interpolated from the lines on both sides of it.

    ``T_hat(0) = Re sum_j c_j X(k_j)`` over the signed lines ``k_j`` (``X(-k) = conj X(k)``),
    ``c_j = a_j A(k_j) / A(0)``: the local polynomial of :func:`local_polynomial` at DC
    through ``A R`` (docs/theory.md §20), the lines symmetric about DC, so that DC lies
    inside the fit. Its real part: the datum at DC is real, and with symmetric lines the
    sum is real up to round-off.

    Attributes:
        lines: (2 half_width,) int, the signed lines read (no DC, no harmonic of the period).
        coef: (2 half_width,) complex, ``c_j``.
    """

    lines: np.ndarray
    coef: np.ndarray

    @property
    def noise_scale(self) -> float:
        """``s_0 = sqrt(1 + sum_j |c_j|^2)``: the noise of ``V(0) - V_hat(0)`` over ``V(0)``'s."""
        return float(np.sqrt(1.0 + np.sum(np.abs(self.coef) ** 2)))

    def _read(self, x: np.ndarray) -> np.ndarray:
        at = x[np.abs(self.lines)]
        return np.where((self.lines < 0)[:, None], np.conj(at), at)

    def apply(self, x: np.ndarray) -> np.ndarray:
        """(n_channels,) float, the estimate at DC from ``x`` (n_bins, n_channels)."""
        return np.real(self.coef @ self._read(np.asarray(x)))

    def bound(self, size: np.ndarray) -> np.ndarray:
        """(n_channels,) float, ``sum_j |c_j| size(|k_j|)``."""
        return np.abs(self.coef) @ np.asarray(size)[np.abs(self.lines)]


def dc_estimate(den: np.ndarray, n_periods: int, order: int, half_width: int) -> DcEstimate:
    """The estimate at DC (:class:`DcEstimate`) for windows of ``n_periods`` periods.

    Args:
        den: (N//2 + 1,) complex, ``A(n)`` (:func:`denominator`).
        n_periods: whole periods per window (with two or more, harmonics are skipped).
        order: polynomial order ``R``.
        half_width: lines on each side of DC (``2 half_width >= order + 2``, as
            :func:`local_polynomial` checks).
    """
    step = n_periods if n_periods >= 2 else 1
    pos = [k for k in range(1, den.size) if step == 1 or k % step][:half_width]
    lines = np.array([-k for k in reversed(pos)] + pos)
    a = np.linalg.pinv(np.vander(lines / half_width, order + 1, increasing=True))[0]
    at = np.where(lines < 0, np.conj(den[np.abs(lines)]), den[np.abs(lines)])
    return DcEstimate(lines, a * at / den[0])


def dc_correction(
    est: DcEstimate,
    datum: Datum,
    resp: PlantResponse,
    dc_resp: PlantResponse,
) -> DcTransient:
    """The transient term at DC of a window, for the operating-point check (§20).

    ``T_hat(0)`` from ``R(k) = Y(k) - P23(k) U(k)`` at the lines ``est`` reads, in the
    output means' units; ``rho_0`` from the member's model error those lines may carry
    (:func:`model_error_reach`), as at every other bin.

    Args:
        est: the estimate at DC (:func:`dc_estimate`) for the datum's window.
        datum: the window's datum (its bins; its means are the check's).
        resp: P at the datum's bins.
        dc_resp: P at z = 1 (:func:`~twotank_validation.core.oppoint.dc_response`).
    """
    r = datum.y_bins - np.einsum("kyu,ku->ky", resp.p23, datum.u_bins)
    scale = datum.convention.dft_scale(datum.n_samples) * datum.n_samples
    s0 = est.noise_scale
    eps = est.bound(model_error_reach(resp, datum.u_bins))
    rho = float(_noise_needed(scaled_noise(dc_resp, np.array([s0])), eps[None, :])[0])
    return DcTransient(shift=est.apply(r) / scale, noise_scale=s0, rho=rho)


def model_error_reach(resp: PlantResponse, u_bins: np.ndarray) -> np.ndarray:
    """(n_bins, ny) float: how far a member's output may differ from the nominal's, per line.

    ``|((G_Delta - G_0) U)_c| <= ||P21[c, :]|| ||P13 U|| / (1 - ||P11||)`` for every
    ``||Delta|| <= 1`` (``G_Delta - G_0 = P21 Delta (I - P11 Delta)^-1 P13``); infinite
    where ``||P11|| >= 1`` and ``P13 U != 0``; 0 where ``U = 0``.

    Args:
        resp: P at the datum's bins.
        u_bins: (n_bins, nu) complex, the inputs' scaled DFT.
    """
    if resp.blocks.nv == 0:
        return np.zeros((u_bins.shape[0], resp.ny))
    if "transient_reach" not in resp.memo:  # what depends on P alone, once per response
        gain = np.linalg.norm(resp.p11, ord=2, axis=(1, 2)) if np.any(resp.p11) else None
        with np.errstate(divide="ignore"):
            amplify = None if gain is None else np.where(gain < 1.0, 1.0 / (1.0 - gain), np.inf)
        resp.memo["transient_reach"] = (amplify, np.linalg.norm(resp.p21, axis=2))
    amplify, rows = resp.memo["transient_reach"]
    drive = np.linalg.norm(np.einsum("kzu,ku->kz", resp.p13, u_bins), axis=1)
    if amplify is not None:
        with np.errstate(invalid="ignore"):
            drive = np.where(drive == 0.0, 0.0, drive * amplify)
    return np.asarray(rows * drive[:, None])


@dataclass(frozen=True)
class TransientRemoved:
    """A datum with its transient term removed, and what the routes must know of it.

    Attributes:
        datum: the datum with ``y_bins`` replaced by ``Y - T_hat`` (DC untouched) and its
            periodicity report cleared of the findings the transient term accounts for
            (input not periodic, output drift, shrinking variation).
        response: P with its noise columns scaled per bin by ``sqrt(1 + leverage)``.
        transient: (n_bins, ny) complex, ``T_hat``.
        rho: (n_bins,) float, per bin, the least ``||W(n)||`` that could produce the model
            error the estimate picked up from its lines (``||P22s(n)^+|| ||eps(n)||``,
            ``eps_c(n) = sum_j |a_nj| reach_c(line_j)``); inf where an output with such an
            error has no noise, or where the noise enters a perturbation (``P12 != 0``).
    """

    datum: Datum
    response: PlantResponse
    transient: np.ndarray
    rho: np.ndarray


def scaled_noise(resp: PlantResponse, scale: np.ndarray) -> PlantResponse:
    """``resp`` with its noise columns (``P12``, ``P22``) multiplied by ``scale`` per bin."""
    p = resp.p.copy()
    nv = resp.blocks.nv
    p[:, :, nv : nv + resp.nw] *= scale[:, None, None]
    return replace(resp, p=p)


_ABSORBED = (
    PeriodicityFinding.INPUT_NOT_PERIODIC,
    PeriodicityFinding.OUTPUT_DRIFTS,
    PeriodicityFinding.VARIATION_SHRINKS,
)


def remove_transient(
    datum: Datum,
    resp: PlantResponse,
    est: TransientEstimate,
    scaled: PlantResponse | None = None,
) -> TransientRemoved:
    """Estimate the transient term of ``datum`` and remove it (docs/theory.md).

    Args:
        datum: the window's datum.
        resp: P at the datum's bins (the nominal's ``P23`` is removed at the fit lines).
        est: the estimate (:func:`transient_estimate`, or :meth:`TransientEstimate.of` a
            :func:`local_polynomial` for the datum's bins and periods).
        scaled: ``scaled_noise(resp, est.noise_scale)`` if already made (a monitor keeps it).
    """
    residual = datum.y_bins - np.einsum("kyu,ku->ky", resp.p23, datum.u_bins)
    t_hat = est.apply(residual)
    s_resp = scaled if scaled is not None else scaled_noise(resp, est.noise_scale)
    if np.any(datum.u_bins[est.lpm.fit_lines] != 0.0):
        rho = _noise_needed(s_resp, est.bound(model_error_reach(resp, datum.u_bins)))
    else:  # no input at the fit lines (a periodic input): no model error picked up, rho = 0
        rho = np.zeros(datum.u_bins.shape[0])
    per = datum.periodicity
    kept = tuple(f for f in per.findings if f not in _ABSORBED)
    cleared = replace(
        per,
        findings=kept,
        input_periodic=True,
        transient_suspected=False,
        last_change=np.zeros_like(per.last_change),
    )
    return TransientRemoved(
        datum=replace(datum, y_bins=datum.y_bins - t_hat, periodicity=cleared),
        response=s_resp,
        transient=t_hat,
        rho=rho,
    )


def _noise_needed(resp: PlantResponse, eps: np.ndarray) -> np.ndarray:
    """(n_bins,) float, ``||P22(n)^+|| ||eps(n)||`` (inf where the noise cannot reach it)."""
    size = np.linalg.norm(eps, axis=1)
    out = np.zeros(size.size)
    live = size > 0.0
    if not live.any():
        return out
    if resp.nw == 0 or np.any(resp.p12[live] != 0.0):
        out[live] = np.inf
        return out
    if "transient_noise_gain" not in resp.memo:  # ||P22(n)^+||, once per response
        sv = np.linalg.svd(resp.p22, compute_uv=False)
        smallest = sv[:, -1] if resp.nw >= resp.ny else np.zeros(sv.shape[0])
        full_rank = smallest > 1e-12 * np.maximum(sv[:, 0], 1e-300)
        with np.errstate(divide="ignore"):
            resp.memo["transient_noise_gain"] = np.where(
                full_rank, 1.0 / np.where(full_rank, smallest, 1.0), np.inf
            )
    gain = resp.memo["transient_noise_gain"]
    out[live] = size[live] * gain[live]
    return out


def lowered(w_min: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """(n_bins,) float, ``max(0, w_min - rho)``: each bin's minimum less the model error's share.

    ``||W||`` is a norm: an error ``e`` in ``Y`` moves a bin's minimum by at most the least
    ``||W||`` producing ``e``, when the noise does not enter the perturbations (``P12 = 0``).
    """
    return np.maximum(0.0, np.asarray(w_min) - rho)


def total_rho(rho: np.ndarray, weights: np.ndarray, mask: np.ndarray | None) -> float:
    """``sqrt(sum_n b_n rho(n)^2)`` over the band: the gate's measure with the transient term."""
    keep = np.ones(rho.size, bool) if mask is None else mask
    if np.any(np.isinf(rho[keep])):
        return math.inf
    return float(np.sqrt(np.sum(weights[keep] * rho[keep] ** 2)))


def validate_with_transient(
    datum: Datum,
    model: LFTModel,
    est: TransientEstimate,
    *,
    method: str = "auto",
    response: PlantResponse | None = None,
    scaled: PlantResponse | None = None,
) -> tuple[BetaResult, float]:
    """β of ``datum`` with its transient term removed, on any route (:func:`validate_beta`).

    The route solves the transformed datum with the scaled response; each bin's minimum is
    then lowered by ``rho`` (:func:`lowered`) and β totalled again over the band.

    Returns:
        The result (``w_min`` and ``beta`` lowered, ``beta_upper`` the transformed datum's
        witness; ``input_leakage`` the total
        ``rho`` over the band) and that total (:func:`total_rho`).
    """
    resp = response if response is not None else model.response(datum.theta, datum.ts_s)
    removed = remove_transient(datum, resp, est, scaled)
    res = validate_beta(removed.datum, model, method=method, response=removed.response)
    mask = validation_band(datum, model)
    low = lowered(res.w_min, removed.rho)
    rho = total_rho(removed.rho, datum.bin_weights, mask)
    beta = masked_beta(low, datum.bin_weights, mask)
    return replace(
        res,
        w_min=low,
        beta=beta,
        beta_upper=max(res.beta_upper, beta),
        input_leakage=rho,
    ), rho
