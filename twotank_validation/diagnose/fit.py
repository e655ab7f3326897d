"""The fit: scaled errors at the excited bins, effects fitted to them, models judged.

The excited harmonic bins of the windows, the scaled error of a nominal plant there, the
least-squares fit of effects (scipy.optimize.least_squares), and a model judged on the
held-out windows.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.optimize
import scipy.stats

from twotank_validation.core import stats
from twotank_validation.core.band import excited_lines
from twotank_validation.core.datum import Datum
from twotank_validation.core.model import LFTModel
from twotank_validation.core.validate import ValidationResult, inverse_dft, validate
from twotank_validation.diagnose.effects import EffectSpec, Nominal
from twotank_validation.diagnose.inputs import DiagnosisConfig, Window
from twotank_validation.errors import DatumError, ModelError

# --------------------------------------------------------------------------- fit data


@dataclass(frozen=True)
class BinData:
    """Excited harmonic bins of a set of windows, stacked.

    Attributes:
        theta: (k,) float, rad/sample.
        u: (k, nu) complex, input DFT (power convention).
        y: (k, ny) complex, output DFT.
        scale: (k, ny) float, the model's noise amplitude per bin and output.
        window: (k,) int, index of the window each bin comes from.
        n_windows: number of windows stacked.
        noise: (k, ny) float, measurement-noise power of ``y`` at each bin, scaled like the
            error (``|Y|^2 / scale^2`` at the two neighbouring non-harmonic bins, which carry
            noise only); 0 where a window has one period (no such bins).
    """

    theta: np.ndarray
    u: np.ndarray
    y: np.ndarray
    scale: np.ndarray
    window: np.ndarray
    n_windows: int
    noise: np.ndarray


def excited_bins(datum: Datum, floor: float) -> np.ndarray:
    """Indices of the excited harmonic bins of a datum.

    :func:`~twotank_validation.core.band.excited_lines` of the datum's inputs (a measured
    input's lines above its noise), with input power at least ``floor`` times the largest
    harmonic's.
    """
    return np.flatnonzero(excited_lines(datum.u_bins, datum.n_periods, floor, datum.u_noise_std))


def noise_scale(model: LFTModel, theta: np.ndarray, ts_s: float, y_rms: np.ndarray) -> np.ndarray:
    """(k, ny) float: the model's noise amplitude on each output at each bin.

    ``sqrt(sum_j |P_{y_c w_j}|^2)``; an output without a noise channel falls back to 1e-3 of
    the output's RMS (so that its error still counts, on its own scale).
    """
    resp = model.response(theta, ts_s)
    p_w = resp.p22  # (k, ny, nw)
    scale = (
        np.sqrt(np.sum(np.abs(p_w) ** 2, axis=2))
        if p_w.shape[2]
        else np.zeros((theta.size, model.ny))
    )
    fallback = np.maximum(1e-3 * y_rms, 1e-12)[None, :]
    return np.where(scale > 0.0, scale, fallback)


def bin_data(datums: Sequence[Datum], model: LFTModel, floor: float) -> BinData:
    """Stack the excited bins of several datums."""
    parts = []
    for i, d in enumerate(datums):
        idx = excited_bins(d, floor)
        y_rms = np.sqrt(np.sum(d.bin_weights[:, None] * np.abs(d.y_bins) ** 2, axis=0))
        scale = noise_scale(model, d.theta[idx], d.ts_s, y_rms)
        if d.n_samples // d.period_samples >= 2:
            last = d.theta.size - 1
            around = np.abs(d.y_bins[np.clip(idx - 1, 0, last)]) ** 2
            around += np.abs(d.y_bins[np.clip(idx + 1, 0, last)]) ** 2
            noise = 0.5 * around / scale**2
        else:
            noise = np.zeros((idx.size, d.y_bins.shape[1]))
        parts.append(
            (d.theta[idx], d.u_bins[idx], d.y_bins[idx], scale, np.full(idx.size, i), noise)
        )
    theta, u, y, scale, win, noise = (np.concatenate([p[j] for p in parts]) for j in range(6))
    return BinData(theta, u, y, scale, win, len(datums), noise)


def scaled_error(nom: Nominal, data: BinData, ts_s: float) -> np.ndarray:
    """(k, ny) complex: ``(Y - G U) / scale`` at the stacked bins (fast hold response)."""
    g = nom.hold_response(data.theta, ts_s)
    return (data.y - np.einsum("kij,kj->ki", g, data.u)) / data.scale


def cost(nom: Nominal, data: BinData, ts_s: float) -> float:
    """Sum of squared scaled errors (the fit criterion)."""
    return float(np.sum(np.abs(scaled_error(nom, data, ts_s)) ** 2))


def noise_floor(data: BinData) -> float:
    """The cost measurement noise alone would give at these bins (same scaling as :func:`cost`)."""
    return float(np.sum(data.noise))


def output_costs(nom: Nominal, data: BinData, ts_s: float) -> np.ndarray:
    """(ny,) float: :func:`cost` split per output (the sum over the bins of each output)."""
    return np.asarray(np.sum(np.abs(scaled_error(nom, data, ts_s)) ** 2, axis=0), dtype=float)


def output_noise_floors(data: BinData) -> np.ndarray:
    """(ny,) float: :func:`noise_floor` split per output."""
    return np.asarray(np.sum(data.noise, axis=0), dtype=float)


# --------------------------------------------------------------------------- fitting


def _apply_all(nom: Nominal, specs: Sequence[EffectSpec], x: np.ndarray) -> Nominal:
    i = 0
    for s in specs:
        nom = s.apply(nom, x[i : i + s.n_params])
        i += s.n_params
    return nom


def _residual_function(
    nominal: Nominal, specs: Sequence[EffectSpec], data: BinData, ts_s: float
) -> Callable[[np.ndarray], np.ndarray]:
    """``x -> (2 k ny,)`` the scaled error with ``specs`` at ``x``, real parts then imaginary."""

    def residual(x: np.ndarray) -> np.ndarray:
        try:
            e = scaled_error(_apply_all(nominal, specs, x), data, ts_s)
        except ModelError:  # an unstable intermediate: a large, finite penalty
            return np.full(2 * data.y.size, 1e6)
        return np.concatenate([e.real.ravel(), e.imag.ravel()])

    return residual


def fit_effects(
    nominal: Nominal,
    specs: Sequence[EffectSpec],
    data: BinData,
    ts_s: float,
    starts: Sequence[np.ndarray] | None = None,
) -> tuple[np.ndarray, float]:
    """Fit the parameters of ``specs`` jointly by least squares on the scaled error.

    The first parameter of every spec is scanned over its grid (the leading specs' coarsely,
    and also from the given ``starts``), the others at their defaults; the two best points
    start a bounded trust-region fit.

    Returns:
        ``(values, cost)``: fitted parameters (concatenated in spec order) and the cost.
    """
    lower = np.concatenate([s.lower for s in specs]).astype(float)
    upper = np.concatenate([s.upper for s in specs]).astype(float)
    residual = _residual_function(nominal, specs, data, ts_s)

    last = specs[-1]
    offset = sum(s.n_params for s in specs[:-1])
    bases: list[np.ndarray] = []
    if starts:  # the given values of the leading specs (e.g. a single effect's fit)
        given = np.concatenate(list(starts))
        if given.size == offset:
            bases.append(given)
    # a coarse scan of the leading specs' first parameters too: a single effect's fit is
    # biased by the effect it misses (a delay fitted alone absorbs part of a heat loss)
    lead_grids = [
        [np.array([g, *s.defaults], dtype=float) for g in s.grid[:: 2 if len(s.grid) > 8 else 1]]
        for s in specs[:-1]
    ]
    for combo in itertools.product(*lead_grids):
        bases.append(np.concatenate(combo) if combo else np.zeros(0))
    scan = []
    for base in bases:
        for g in last.grid:
            x = np.concatenate([base, [g, *last.defaults]])
            r = residual(x)
            scan.append((float(r @ r), x))
    scan.sort(key=lambda t: t[0])
    best_x, best_c = scan[0][1], scan[0][0]
    for _, x0 in scan[:2]:
        sol = scipy.optimize.least_squares(
            residual, np.clip(x0, lower, upper), bounds=(lower, upper), x_scale="jac", max_nfev=200
        )
        c = float(sol.fun @ sol.fun)
        if c < best_c:
            best_x, best_c = sol.x, c
    return np.asarray(best_x, dtype=float), best_c


# --------------------------------------------------------------------------- how sure


@dataclass(frozen=True)
class Uncertainty:
    """How sure the fitted parameters are: standard errors and confidence intervals.

    Attributes:
        stderr: (p,) float, standard error per parameter (SI units); ``inf`` when the data
            carry no information on it (its column of the Jacobian is zero or degenerate).
        low, high: (p,) float, the confidence interval per parameter, clipped to the search
            bounds; one-sided (from the bound) for a parameter at a bound.
        at_bound: per parameter ``"lower"``, ``"upper"`` or ``""``.
        inflation: factor applied to the covariance for model error: the fit's residual cost
            over what the noise alone gives (at least 1).
        level: confidence level of the interval.
    """

    stderr: np.ndarray
    low: np.ndarray
    high: np.ndarray
    at_bound: tuple[str, ...]
    inflation: float
    level: float

    def to_dict(self, names: Sequence[str]) -> dict[str, dict[str, Any]]:
        """``{name: {"stderr", "ci95": [lo, hi], "at_bound"}}`` (JSON-ready; inf as None)."""

        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        return {
            n: {
                "stderr": num(self.stderr[i]),
                "ci95": [num(self.low[i]), num(self.high[i])],
                "at_bound": self.at_bound[i] or None,
            }
            for i, n in enumerate(names)
        }


def _jacobian(
    residual: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
) -> np.ndarray:
    """(m, p) float: finite-difference Jacobian of ``residual`` at ``x``, inside the bounds.

    Central differences, one-sided at a bound.
    """
    r0 = residual(x)
    jac = np.zeros((r0.size, x.size))
    for i in range(x.size):
        h = 1e-6 * max(abs(x[i]), 1e-3 * (upper[i] - lower[i]), 1e-12)
        up, dn = x.copy(), x.copy()
        if x[i] + h <= upper[i]:
            up[i] += h
        if x[i] - h >= lower[i]:
            dn[i] -= h
        jac[:, i] = (residual(up) - residual(dn)) / (up[i] - dn[i])
    return jac


def fit_uncertainty(  # noqa: PLR0917 - the fit and where it was made
    nominal: Nominal,
    specs: Sequence[EffectSpec],
    data: BinData,
    ts_s: float,
    values: np.ndarray,
    level: float = 0.95,
) -> Uncertainty:
    """Standard errors and confidence intervals of the parameters fitted on ``data``.

    Linearised least squares at the optimum ``values``: with ``J`` the Jacobian of the
    stacked residual (real parts, then imaginary parts, of the scaled error at every bin and
    output) and ``V`` the noise variance of each component, ``BinData.noise / 2`` (the noise
    power of a bin is split equally between its real and imaginary parts), the covariance is
    the sandwich ``(J^T J)^-1 J^T V J (J^T J)^-1`` (the fit is unweighted, the noise
    differs from bin to bin). The same sandwich with ``V = r^2 m / (m - p)`` (the residual
    at the optimum, White's estimator) gives the spread the model error shows where it
    is; each parameter takes the larger of the two standard errors, times
    ``sqrt(max(1, J_fit / ((1 - p/m) F)))``, the fit's residual cost over the cost the noise
    alone gives (``F``, :func:`noise_floor`; ``m`` residual components, ``p`` parameters):
    a residual above the noise is model error (the plant's nonlinearity, an effect outside
    the catalogue), and the part of it the parameters absorb is not in the residual. Without
    a noise estimate (windows of one period) the residual variance ``J_fit / (m - p)`` is
    used for every component. Coverage on the simulated rig: docs/diagnosis.md.

    Args:
        nominal: the plant the effects are added to.
        specs: the effects, in the order of ``values``.
        data: the bins they were fitted on.
        ts_s: sample period, s.
        values: fitted parameters (concatenated in spec order).
        level: confidence level of the interval, in (0, 1).
    """
    lower = np.concatenate([s.lower for s in specs]).astype(float)
    upper = np.concatenate([s.upper for s in specs]).astype(float)
    x = np.asarray(values, dtype=float)
    residual = _residual_function(nominal, specs, data, ts_s)
    r = residual(x)
    jac = _jacobian(residual, x, lower, upper)
    m, p = jac.shape
    fit_cost = float(r @ r)
    floor = noise_floor(data)
    if floor > 0.0:
        var = np.concatenate([data.noise.ravel(), data.noise.ravel()]) / 2.0
        inflation = max(1.0, fit_cost / max((1.0 - p / m) * floor, 1e-300))
    else:
        var = np.full(m, fit_cost / max(m - p, 1))
        inflation = 1.0
    # column scaling (parameters differ by orders of magnitude), then the sandwiches
    norms = np.linalg.norm(jac, axis=0)
    live = norms > 0.0
    stderr = np.full(p, np.inf)
    if np.any(live):
        js = jac[:, live] / norms[live]
        eig, vec = np.linalg.eigh(js.T @ js)
        ok = eig > 1e-10 * float(np.max(eig))
        bread = (vec[:, ok] / eig[ok]) @ vec[:, ok].T

        def spread(v: np.ndarray) -> np.ndarray:
            cov = bread @ (js.T @ (v[:, None] * js)) @ bread
            return np.asarray(np.sqrt(np.maximum(np.diag(cov), 0.0)), dtype=float)

        # the noise's spread, and the spread the residual itself shows (model error is
        # not spread like the noise over the bins); the larger, times the excess cost
        robust = r**2 * m / max(m - p, 1)
        se = np.sqrt(inflation) * np.maximum(spread(var), spread(robust)) / norms[live]
        # a parameter in a direction the data do not fix has no finite error
        blind = np.any(np.abs(vec[:, ~ok]) > 0.1, axis=1)
        stderr[live] = np.where(blind, np.inf, se)
    span = upper - lower
    at_bound = tuple(
        "lower" if v - lo <= 1e-6 * sp else "upper" if hi - v <= 1e-6 * sp else ""
        for v, lo, hi, sp in zip(x, lower, upper, span, strict=True)
    )
    z2 = float(scipy.stats.norm.ppf(0.5 + level / 2.0))
    z1 = float(scipy.stats.norm.ppf(level))
    low = np.maximum(x - z2 * stderr, lower)
    high = np.minimum(x + z2 * stderr, upper)
    for i, b in enumerate(at_bound):
        if b == "lower":
            low[i], high[i] = lower[i], min(x[i] + z1 * stderr[i], upper[i])
        elif b == "upper":
            low[i], high[i] = max(x[i] - z1 * stderr[i], lower[i]), upper[i]
    return Uncertainty(stderr, low, high, at_bound, inflation, level)


# --------------------------------------------------------------------------- judging


@dataclass(frozen=True)
class Assessment:
    """A model judged on the held-out windows.

    Attributes:
        beta: largest validation beta over the held-out windows.
        beta_windows: beta per held-out window.
        rms: per output, RMS over time of the model's periodic simulation error on the
            excited band (model units): what the model gets wrong, noise excluded.
        rms_raw: per output, RMS of the whole simulation error (noise included).
        cost: scaled squared error at the excited bins (the fit criterion).
        residual_tests: the paper's Sec. 2.1 statistics on the held-out window of largest
            beta (``stats.ResidualTests.to_dict()``), or an error string.
        results: the validations, one per held-out window.
        residual_tests_windows: the same statistics on every held-out window, in order.
    """

    beta: float
    beta_windows: list[float]
    rms: dict[str, float]
    rms_raw: dict[str, float]
    cost: float
    residual_tests: dict[str, Any] | str
    results: list[ValidationResult] = field(repr=False, default_factory=list)
    residual_tests_windows: list[dict[str, Any] | str] = field(repr=False, default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "beta": self.beta,
            "beta_windows": self.beta_windows,
            "rms": self.rms,
            "rms_raw": self.rms_raw,
            "cost": self.cost,
            "residual_tests": self.residual_tests,
        }


def assess(
    model: LFTModel, datums: Sequence[Datum], windows: Sequence[Window], config: DiagnosisConfig
) -> Assessment:
    """Validate ``model`` on every held-out datum and measure its simulation error."""
    results = [validate(d, model) for d in datums]
    betas = [float(r.beta) for r in results]
    names = list(model.output_names)
    band = np.zeros(model.ny)
    raw = np.zeros(model.ny)
    for d, r in zip(datums, results, strict=True):
        idx = excited_bins(d, config.excitation_floor)
        e = r.error  # (n_bins, ny) raw error Y - G U
        band += np.sum(d.bin_weights[idx, None] * np.abs(e[idx]) ** 2, axis=0)
        raw += np.sum(d.bin_weights[1:, None] * np.abs(e[1:]) ** 2, axis=0)
    band, raw = np.sqrt(band / len(datums)), np.sqrt(raw / len(datums))
    worst = int(np.argmax(betas))
    every: list[dict[str, Any] | str] = []
    for d, r, w in zip(datums, results, windows, strict=True):
        try:
            every.append(
                stats.residual_tests(
                    inverse_dft(r.error, d.n_samples, d.convention),
                    w.u,
                    output_names=names,
                    input_names=list(model.input_names),
                    max_lag=config.max_lag,
                    alpha=config.alpha,
                ).to_dict()
            )
        except DatumError as err:
            every.append(f"not computed: {err}")
    tests = every[worst]
    data = bin_data(datums, model, config.excitation_floor)
    nominal_cost = float(np.sum(np.abs(_model_scaled_error(model, data, datums[0].ts_s)) ** 2))
    return Assessment(
        beta=max(betas),
        beta_windows=betas,
        rms={n: float(v) for n, v in zip(names, band, strict=True)},
        rms_raw={n: float(v) for n, v in zip(names, raw, strict=True)},
        cost=nominal_cost,
        residual_tests=tests,
        results=results,
        residual_tests_windows=every,
    )


def _model_scaled_error(model: LFTModel, data: BinData, ts_s: float) -> np.ndarray:
    g = model.response(data.theta, ts_s).p23
    return (data.y - np.einsum("kij,kj->ki", g, data.u)) / data.scale
