"""The fit: scaled errors at the excited bins, effects fitted to them, models judged.

The excited harmonic bins of the windows, the scaled error of a nominal plant there, the
least-squares fit of effects (scipy.optimize.least_squares), and a model judged on the
held-out windows.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.optimize

from twotank_validation.core import stats
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

    Harmonic: n a multiple of the number of periods, 0 < n < N/2; excited: input power at
    least ``floor`` times the largest harmonic's.
    """
    n_per = datum.n_samples // datum.period_samples
    n = np.arange(datum.theta.size)
    harmonic = (n % n_per == 0) & (n > 0) & (n < datum.n_samples // 2)
    power = np.sum(np.abs(datum.u_bins) ** 2, axis=1)
    top = float(np.max(power[harmonic], initial=0.0))
    if top <= 0.0:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(harmonic & (power >= floor * top))


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


# --------------------------------------------------------------------------- fitting


def _apply_all(nom: Nominal, specs: Sequence[EffectSpec], x: np.ndarray) -> Nominal:
    i = 0
    for s in specs:
        nom = s.apply(nom, x[i : i + s.n_params])
        i += s.n_params
    return nom


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

    def residual(x: np.ndarray) -> np.ndarray:
        try:
            e = scaled_error(_apply_all(nominal, specs, x), data, ts_s)
        except ModelError:  # an unstable intermediate: a large, finite penalty
            return np.full(2 * data.y.size, 1e6)
        return np.concatenate([e.real.ravel(), e.imag.ravel()])

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
    """

    beta: float
    beta_windows: list[float]
    rms: dict[str, float]
    rms_raw: dict[str, float]
    cost: float
    residual_tests: dict[str, Any] | str
    results: list[ValidationResult] = field(repr=False, default_factory=list)

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
    tests: dict[str, Any] | str
    try:
        residual = inverse_dft(
            results[worst].error, datums[worst].n_samples, datums[worst].convention
        )
        tests = stats.residual_tests(
            residual,
            windows[worst].u,
            output_names=names,
            input_names=list(model.input_names),
            max_lag=config.max_lag,
            alpha=config.alpha,
        ).to_dict()
    except DatumError as err:
        tests = f"not computed: {err}"
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
    )


def _model_scaled_error(model: LFTModel, data: BinData, ts_s: float) -> np.ndarray:
    g = model.response(data.theta, ts_s).p23
    return (data.y - np.einsum("kij,kj->ki", g, data.u)) / data.scale
