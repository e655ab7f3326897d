"""Nonparametric frequency response from periodic experiments (docs/theory.md, "Identification").

The estimators of Pintelon & Schoukens, *System Identification: A Frequency Domain Approach*
(2nd ed., 2012), ch. 2-4 and 7, over numpy arrays:

* :func:`period_spectra`: the DFT of every period of a record at chosen lines.
* :func:`frf_from_experiments`: the response at the excited lines from ``E >= n_u``
  experiments (several records, or the periods of one record grouped by the input pattern of
  an orthogonal multisine, :func:`split_by_pattern`), averaged over whole periods, with the
  variance of each entry from the period-to-period spread (input and output noise and their
  correlation, the errors-in-variables form ``G = Y U^+``).
* :func:`best_linear_approximation`: over ``M`` random-phase realisations, the best linear
  approximation, its noise variance and its total variance; their difference is the variance
  of the stochastic nonlinear distortion.
* :func:`distortion_lines`: the output power at the unexcited odd and even lines of an odd
  multisine against the noise floor there.

Written by hand: scipy.signal estimates spectra of stationary random signals by Welch
averaging (``csd``/``welch``), which for periodic excitation leaks and mixes noise with
distortion; no maintained Python library implements these periodic estimators.

Units: a response entry is output units per input unit; frequencies in Hz. ``lines`` are
indices into one period's DFT (line ``k`` lies at ``k / (N ts)`` Hz for a period of ``N``
samples).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.stats

from twotank_validation.errors import IdentificationError

__all__ = [
    "BestLinearApproximation",
    "Distortion",
    "FrequencyResponse",
    "best_linear_approximation",
    "bla_over_experiments",
    "distortion_lines",
    "frf_from_experiments",
    "period_spectra",
    "split_by_pattern",
]


@dataclass(frozen=True)
class FrequencyResponse:
    """A response estimated at lines of a period's DFT.

    Attributes:
        lines: (L,) int, line indices in one period's DFT.
        freqs_hz: (L,) float, their frequencies (Hz).
        g: (L, n_y, n_u) complex, the response (output units per input unit).
        var: (L, n_y, n_u) float, the variance of each entry of ``g`` (``E|g - G|^2``) from
            the noise, as the period-to-period spread shows it.
        n_periods: periods averaged per experiment.
        n_experiments: experiments combined (``>= n_u``).
        noise_var: (L, n_y) float or None: the output noise's variance at each line of the
            record the estimate came from (its DFT scaled by 1 / its length), where the
            estimator gives it (the local polynomial method's residual).
    """

    lines: np.ndarray
    freqs_hz: np.ndarray
    g: np.ndarray
    var: np.ndarray
    n_periods: int
    n_experiments: int
    noise_var: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        """(L, n_y, n_u) float: the standard deviation of each entry."""
        return np.sqrt(self.var)

    def radius(self, level: float = 0.95) -> np.ndarray:
        """(L, n_y, n_u) float: the radius of each entry's confidence disc at ``level``.

        The error is circular complex Gaussian and its variance is estimated from ``P - 1``
        complex degrees of freedom, so ``|g - G|^2 / var ~ F(2, 2 (P - 1))``
        (Pintelon & Schoukens 2012, sec. 2.6); with many periods this tends to
        ``-ln(1 - level)``.
        """
        dof = 2 * max(self.n_periods - 1, 1)
        return np.sqrt(self.var * scipy.stats.f.ppf(level, 2, dof))


@dataclass(frozen=True)
class BestLinearApproximation:
    """The best linear approximation over random-phase realisations.

    Attributes:
        response: the mean response over the realisations; its ``var`` is the total variance
            of the mean (noise and stochastic nonlinear distortion together), from the spread
            over realisations (NaN with one realisation).
        var_noise: (L, n_y, n_u) float, the variance of the mean from the noise alone.
        n_realisations: realisations averaged.
    """

    response: FrequencyResponse
    var_noise: np.ndarray
    n_realisations: int

    @property
    def var_distortion(self) -> np.ndarray:
        """(L, n_y, n_u) float: the variance of the mean from the nonlinear distortion.

        ``max(var_total - var_noise, 0)``, the stochastic distortion; NaN with one realisation.
        """
        return np.maximum(self.response.var - self.var_noise, 0.0)


@dataclass(frozen=True)
class Distortion:
    """Output power at the unexcited lines of an odd multisine, per output.

    Each level is a mean of ``|Y(k)|^2`` (the period-averaged spectrum, unscaled DFT per
    period divided by the period length, output units squared) over the lines of its kind
    inside the band; ``noise`` is the mean variance of that averaged spectrum from the period
    spread at the same lines. A level several times its noise shows distortion of that kind.

    Attributes:
        odd: (n_y,) float, at the odd unexcited lines (detection lines): odd distortion.
        even: (n_y,) float, at the even lines: even distortion.
        noise_odd: (n_y,) float, the noise's contribution at the odd unexcited lines.
        noise_even: (n_y,) float, the noise's contribution at the even lines.
        n_odd: odd unexcited lines used.
        n_even: even lines used.
    """

    odd: np.ndarray
    even: np.ndarray
    noise_odd: np.ndarray
    noise_even: np.ndarray
    n_odd: int
    n_even: int


def period_spectra(x: np.ndarray, period_samples: int, lines: np.ndarray) -> np.ndarray:
    """The DFT of each whole period at the given lines.

    Args:
        x: (n_samples, n_channels) float, whole periods (trailing samples of a partial
            period are refused).
        period_samples: samples per period ``N``.
        lines: (L,) int, line indices ``0 <= k <= N // 2``.

    Returns:
        (n_periods, L, n_channels) complex, ``(1/N) sum_t x(t) exp(-j 2 pi k t / N)`` per
        period (the amplitude of a sine of amplitude ``a`` at line ``k`` is ``a / 2``).
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 2:
        raise IdentificationError(f"a record must be (samples, channels), got shape {x.shape}")
    if period_samples < 2 or x.shape[0] % period_samples:
        raise IdentificationError(
            f"{x.shape[0]} samples are not whole periods of {period_samples}: "
            "cut the record to whole periods (--start/--end) or give the right --period"
        )
    if not np.all(np.isfinite(x)):
        raise IdentificationError(
            "the record holds NaN or infinite samples: cut them out (--start/--end)"
        )
    p = x.shape[0] // period_samples
    spec = np.fft.rfft(x.reshape(p, period_samples, x.shape[1]), axis=1) / period_samples
    return np.asarray(spec[:, np.asarray(lines, dtype=int), :])


def split_by_pattern(
    u: np.ndarray, y: np.ndarray, period_samples: int, rtol: float = 0.05
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The periods of one record grouped by their input pattern.

    An orthogonal multisine (``n_u`` inputs, each period's input ``T[:, b] * u0`` for a
    Hadamard-type matrix ``T``) repeats each pattern over several periods; each group is one
    experiment for :func:`frf_from_experiments`. Periods join the first group whose mean input
    period they match within ``rtol`` of its RMS (a measured input's noise allowed).

    Args:
        u: (n_samples, n_u) float, whole periods.
        y: (n_samples, n_y) float.
        period_samples: samples per period.
        rtol: largest RMS difference of a period from a group's first period, relative.

    Returns:
        The experiments in order of first appearance, each ``(u_e, y_e)`` of whole periods.
    """
    p = u.shape[0] // period_samples
    up = u[: p * period_samples].reshape(p, period_samples, -1)
    yp = y[: p * period_samples].reshape(p, period_samples, -1)
    groups: list[list[int]] = []
    for r in range(p):
        for g in groups:
            ref = up[g[0]]
            scale = float(np.sqrt(np.mean(ref**2))) or 1.0
            if float(np.sqrt(np.mean((up[r] - ref) ** 2))) <= rtol * scale:
                g.append(r)
                break
        else:
            groups.append([r])
    return [(up[g].reshape(-1, up.shape[2]), yp[g].reshape(-1, yp.shape[2])) for g in groups]


def frf_from_experiments(
    experiments: Sequence[tuple[np.ndarray, np.ndarray]],
    period_samples: int,
    lines: np.ndarray,
    ts_s: float,
) -> FrequencyResponse:
    """The response at the lines from ``E >= n_u`` periodic experiments.

    Per experiment ``e`` the spectra are averaged over its ``P_e`` periods; at each line the
    averaged input spectra form ``U`` (``n_u x E``) and the outputs ``Y`` (``n_y x E``), and
    ``G = Y U^+``. Linearised, ``G`` errs by ``sum_e r_e (U^+)_{e,:}`` with ``r_e`` the error of
    ``Y_e - G U_e``; with independent experiments and periods, each entry's variance is
    ``var(G_ci) = sum_e s2_ce |U^+_{ei}|^2`` where ``s2_ce`` is the variance of the mean of
    ``Y_ep - G U_ep`` over the periods (output noise, input noise and their correlation
    together; Pintelon & Schoukens 2012, sec. 2.5 and 7.2).

    Args:
        experiments: ``(u_e, y_e)`` pairs, (P_e N, n_u) and (P_e N, n_y) float, whole periods.
        period_samples: samples per period ``N``.
        lines: (L,) int, the excited lines (``1 <= k <= N // 2``).
        ts_s: sample period (s).

    Returns:
        The response; its variance is NaN where an experiment has one period.

    Raises:
        IdentificationError: fewer experiments than inputs, mismatched channels, or an input
            matrix that does not excite every input independently at some line.
    """
    if not experiments:
        raise IdentificationError("no experiment given")
    lines = np.asarray(lines, dtype=int)
    if lines.size == 0:
        raise IdentificationError("no excited line: give a band with excitation in it")
    n_u = experiments[0][0].shape[1]
    n_y = experiments[0][1].shape[1]
    if len(experiments) < n_u:
        raise IdentificationError(
            f"{n_u} inputs need at least {n_u} experiments with independent inputs, "
            f"got {len(experiments)}: record one per input (or an orthogonal multisine)"
        )
    u_mean, y_mean, periods = [], [], []
    for u, y in experiments:
        if u.shape[1] != n_u or y.shape[1] != n_y or u.shape[0] != y.shape[0]:
            raise IdentificationError("the experiments' channels or lengths do not match")
        us = period_spectra(u, period_samples, lines)
        ys = period_spectra(y, period_samples, lines)
        periods.append((us, ys))
        u_mean.append(us.mean(axis=0))
        y_mean.append(ys.mean(axis=0))
    um = np.stack(u_mean, axis=2)  # (L, n_u, E)
    ym = np.stack(y_mean, axis=2)  # (L, n_y, E)
    cond = np.linalg.cond(um)
    bad = ~np.isfinite(cond) | (cond > 1e8)
    if np.any(bad):
        raise IdentificationError(
            f"the inputs do not excite every input independently at {int(bad.sum())} of "
            f"{lines.size} lines (first {lines[bad][0]}): use experiments with independent "
            "inputs or an orthogonal multisine"
        )
    u_pinv = np.linalg.pinv(um)  # (L, E, n_u)
    g = ym @ u_pinv  # (L, n_y, n_u)
    var = np.zeros(g.shape)
    for e, (us, ys) in enumerate(periods):
        p = us.shape[0]
        if p < 2:
            var[:] = np.nan
            break
        resid = ys - np.einsum("lyu,plu->ply", g, us)  # (P, L, n_y)
        s2 = np.var(resid, axis=0, ddof=1) / p  # variance of the period mean, (L, n_y)
        var += s2[:, :, None] * np.abs(u_pinv[:, e, :])[:, None, :] ** 2
    freqs = lines / (period_samples * ts_s)
    return FrequencyResponse(
        lines=lines,
        freqs_hz=freqs,
        g=g,
        var=var,
        n_periods=min(us.shape[0] for us, _ in periods),
        n_experiments=len(experiments),
    )


def bla_over_experiments(
    experiments: Sequence[tuple[np.ndarray, np.ndarray]],
    period_samples: int,
    lines: np.ndarray,
    ts_s: float,
) -> BestLinearApproximation:
    """The best linear approximation of ``n_u`` inputs from ``E > n_u`` random-phase experiments.

    Each input has phases of its own in every experiment. ``G = Y U^+`` over the
    experiments' period-averaged spectra, as :func:`frf_from_experiments`; the noise variance
    is that function's (from the period spread). The total variance, noise and stochastic
    nonlinear distortion together, comes from the spread of the experiments about the fit:
    at each line and output, ``s2_c = sum_e |Y_ce - (G U)_ce|^2 / (E - n_u)`` and
    ``var(G_ci) = s2_c [(U U^H)^-1]_ii`` (a random-phase realisation's distortion is a new
    draw, uncorrelated with its input, like noise; Pintelon & Schoukens 2012, sec. 3.4 and
    4.3).

    Args:
        experiments: ``(u_e, y_e)`` pairs, (P_e N, n_u) and (P_e N, n_y) float, whole periods;
            ``E > n_u`` of them.
        period_samples: samples per period ``N``.
        lines: (L,) int, the excited lines.
        ts_s: sample period (s).

    Returns:
        The approximation; its response's ``n_periods`` is ``E - n_u + 1``, so that
        :meth:`FrequencyResponse.radius` uses the total variance's degrees of freedom.

    Raises:
        IdentificationError: as :func:`frf_from_experiments`, or no more experiments than
            inputs (nothing left to see the distortion with).
    """
    n_u = experiments[0][0].shape[1] if experiments else 0
    if len(experiments) <= n_u:
        raise IdentificationError(
            f"{n_u} input(s) need more than {n_u} random-phase experiments for the "
            f"distortion's spread, got {len(experiments)}: record more realisations"
        )
    fr = frf_from_experiments(experiments, period_samples, lines, ts_s)
    lines = np.asarray(lines, dtype=int)
    um = np.stack(
        [period_spectra(u, period_samples, lines).mean(axis=0) for u, _ in experiments], axis=2
    )  # (L, n_u, E)
    ym = np.stack(
        [period_spectra(y, period_samples, lines).mean(axis=0) for _, y in experiments], axis=2
    )  # (L, n_y, E)
    resid = ym - fr.g @ um
    dof = len(experiments) - n_u
    s2 = np.sum(np.abs(resid) ** 2, axis=2) / dof  # (L, n_y)
    inv = np.linalg.inv(um @ np.conj(um.transpose(0, 2, 1)))  # (L, n_u, n_u)
    var_total = s2[:, :, None] * np.real(np.diagonal(inv, axis1=1, axis2=2))[:, None, :]
    response = FrequencyResponse(
        lines=fr.lines,
        freqs_hz=fr.freqs_hz,
        g=fr.g,
        var=var_total,
        n_periods=dof + 1,
        n_experiments=fr.n_experiments,
    )
    return BestLinearApproximation(
        response=response, var_noise=fr.var, n_realisations=len(experiments)
    )


def best_linear_approximation(
    realisations: Sequence[Sequence[tuple[np.ndarray, np.ndarray]]],
    period_samples: int,
    lines: np.ndarray,
    ts_s: float,
) -> BestLinearApproximation:
    """The best linear approximation over ``M`` random-phase realisations.

    ``G_BLA = (1/M) sum_m G_m``; the noise variance of the mean is ``(1/M^2) sum_m var_m``
    (each realisation's period-spread variance); the total variance of the mean is the sample
    variance of the ``G_m`` over ``M`` divided by ``M``; the stochastic nonlinear distortion's
    variance is the difference (Pintelon & Schoukens 2012, sec. 4.3, the robust method).

    Args:
        realisations: per realisation, its experiments as for :func:`frf_from_experiments`.
        period_samples: samples per period ``N``.
        lines: (L,) int, the excited lines.
        ts_s: sample period (s).
    """
    if not realisations:
        raise IdentificationError("no realisation given")
    each = [frf_from_experiments(r, period_samples, lines, ts_s) for r in realisations]
    m = len(each)
    gs = np.stack([f.g for f in each])
    g = gs.mean(axis=0)
    var_noise = np.sum([f.var for f in each], axis=0) / m**2
    if m > 1:
        var_total = np.sum(np.abs(gs - g) ** 2, axis=0) / (m * (m - 1))
    else:
        var_total = np.full(g.shape, np.nan)
    first = each[0]
    response = FrequencyResponse(
        lines=first.lines,
        freqs_hz=first.freqs_hz,
        g=g,
        var=var_total,
        # the total variance's degrees of freedom are the realisations' (radius' F quantile)
        n_periods=m if m > 1 else min(f.n_periods for f in each),
        n_experiments=sum(f.n_experiments for f in each),
    )
    return BestLinearApproximation(response=response, var_noise=var_noise, n_realisations=m)


def distortion_lines(
    y: np.ndarray,
    period_samples: int,
    excited: np.ndarray,
    band: tuple[int, int],
) -> Distortion:
    """Output power at the unexcited lines of an odd multisine, against the noise there.

    Args:
        y: (P N, n_y) float, whole periods (de-biased or not: line 0 is never used).
        period_samples: samples per period ``N``.
        excited: (L,) int, the excited lines.
        band: (first, last) line of the excitation band, inclusive; the unexcited lines
            inside it are the detection lines.

    Returns:
        The levels; NaN noise with one period.
    """
    lo, hi = max(int(band[0]), 1), min(int(band[1]), period_samples // 2)
    candidates = np.arange(lo, hi + 1)
    unexcited = np.setdiff1d(candidates, np.asarray(excited, dtype=int))
    odd = unexcited[unexcited % 2 == 1]
    even = unexcited[unexcited % 2 == 0]

    def level(sel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if sel.size == 0:
            nan = np.full(y.shape[1], np.nan)
            return nan, nan
        spec = period_spectra(y, period_samples, sel)  # (P, L, n_y)
        p = spec.shape[0]
        mean = spec.mean(axis=0)
        noise = (
            np.var(spec, axis=0, ddof=1).mean(axis=0) / p if p > 1 else np.full(y.shape[1], np.nan)
        )
        return np.mean(np.abs(mean) ** 2, axis=0), noise

    lo_odd, n_odd = level(odd)
    lo_even, n_even = level(even)
    return Distortion(
        odd=lo_odd,
        even=lo_even,
        noise_odd=n_odd,
        noise_even=n_even,
        n_odd=int(odd.size),
        n_even=int(even.size),
    )
