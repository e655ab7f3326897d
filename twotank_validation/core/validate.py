"""Validate an LFT model against a datum: Problem 3 at every bin and the total beta."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from twotank_validation.core import fast, lti, solvers
from twotank_validation.core.band import (
    Band,
    band_mask,
    masked_beta,
    outside_lines,
    periodic_lines,
)
from twotank_validation.core.columns import column_mean
from twotank_validation.core.datum import (
    Datum,
    NormConvention,
    PeriodicityFinding,
    fold_pulse,
    folded_leakage,
    leakage_bound,
    periodicity_text,
    scaled_dft,
)
from twotank_validation.core.datum import pulse_moment as datum_pulse_moment
from twotank_validation.core.model import LFTModel, PlantResponse
from twotank_validation.core.noise_budget import (
    NOISE_BETA_WARN,
    NOISE_WARN_CONFIDENCE,
    expected_noise_beta,
    noise_beta_lower,
    noise_floor,
    spread_of_std,
)
from twotank_validation.defaults import METHODS, Method
from twotank_validation.errors import DimensionError, ModelError

_PULSE_DECAY = 1e-12
LEAKAGE_NOTE = (
    "leakage bound left out (null) where it exceeds the largest output line |Y_i(n)|: Ljung's "
    "worst case over input histories says nothing about these data there; the periodicity "
    "findings judge the leakage instead (a transient, an input that does not repeat)"
)


@dataclass(frozen=True)
class ValidationResult:
    """Everything a report needs about one model against one datum.

    Attributes:
        model_name: model name.
        convention: norm convention of ``||w||`` (named in every report).
        method: solver that ran (``"closed_form"``, ``"fast"`` or ``"sdp"``).
        method_reason: why that solver was chosen (for the fast path, also how many bins
            fell back to the per-bin SDP).
        freqs_hz: (n_bins,) float, bin frequencies.
        theta: (n_bins,) float, rad/sample.
        bin_weights: (n_bins,) float, multiplicity of each one-sided bin.
        w_min: (n_bins,) float, lower bound on min ||W(n)|| (exact for the closed form).
        w_upper: (n_bins,) float, ||W(n)|| of the feasible witness.
        beta: ``sqrt(sum_n weight_n w_min(n)^2)``: a lower bound on the smallest ||w||;
            ``beta > 1`` invalidates the model.
        beta_upper: the same from the witness (an upper bound).
        solution: per-bin witnesses.
        error: (n_bins, ny) complex, ``E(n) = Y(n) - P23 U(n)`` (raw output error).
        leakage: (ny,) float, Ljung's bound on |R_i(n)| (same at every bin).
        n_samples: record length.
        ts_s: sample period (s).
        compute_time_s: wall time of the per-bin solve.
        fallback_bins: bins the fast path handed to the per-bin SDP (0 for other methods).
        warnings: what makes the verdict weaker than it looks, in words (a transient in the
            record, an input whose change from period to period may decide the verdict,
            inputs that do not move, a model without noise channels or with an infinite
            β); empty when there is nothing to say.
        findings: the periodicity findings among the warnings, typed (:class:`Caveats`).
        input_leakage: how far the input's change from period to period may move β
            (:func:`input_leakage`; 0 for a periodic input).
        band: the model's validation band (``None``: every bin).
        band_mask: (n_bins,) bool, the bins β counts (all with no band).
        beta_outside: the same total over the bins outside the band, in units of w (0
            with no band): how much of the data the model set is not claimed to explain.
        lines_outside: up to five ``(Hz, sqrt(weight) min||W(n)||)`` pairs, the bins outside
            the band that carry most of ``beta_outside``.
        periodic_outside: up to five ``(Hz, |Y|/noise std)`` pairs, the harmonic bins outside
            the band where an output repeats far above its period-to-period noise
            (:func:`~twotank_validation.core.band.periodic_lines`): a disturbance or
            nonlinear distortion, not noise.
        leakage_exceeds_data: (ny,) bool, outputs whose leakage bound exceeds the largest
            ``|Y_i(n)|`` over the bins: there the bound says nothing, and :meth:`summary`
            leaves it out (``None``) with :data:`LEAKAGE_NOTE`. Not a warning: β does not
            use the bound, so the verdict is no weaker for it.
        noise_beta: the β the datum's noise alone is expected to cost under the model's
            noise weights, over the band (:func:`noise_beta`; NaN with one period); above
            :data:`~twotank_validation.core.noise_budget.NOISE_BETA_WARN` it is a warning.
        noise_floor: (n_bins,) float, its per-bin terms: the min ``||W(n)||`` the noise alone
            is expected to cost at each bin (:func:`noise_cost`; NaN with one period),
            comparable to ``w_min``.
    """

    model_name: str
    convention: NormConvention
    method: str
    method_reason: str
    freqs_hz: np.ndarray
    theta: np.ndarray
    bin_weights: np.ndarray
    w_min: np.ndarray
    w_upper: np.ndarray
    beta: float
    beta_upper: float
    solution: solvers.BinSolutions
    error: np.ndarray
    leakage: np.ndarray
    n_samples: int
    ts_s: float
    compute_time_s: float
    fallback_bins: int = 0
    warnings: tuple[str, ...] = ()
    findings: tuple[PeriodicityFinding, ...] = ()
    input_leakage: float = 0.0
    band: Band | None = None
    band_mask: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    beta_outside: float = 0.0
    lines_outside: tuple[tuple[float, float], ...] = ()
    periodic_outside: tuple[tuple[float, float], ...] = ()
    leakage_exceeds_data: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    noise_beta: float = math.nan
    noise_floor: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def invalidated(self) -> bool:
        """True when the datum invalidates the model (beta > 1; sound by the lower bound)."""
        return self.beta > 1.0

    @property
    def margin(self) -> float:
        """``1 - beta``: positive while the model is not invalidated, negative once it is."""
        return 1.0 - self.beta

    def time_domain_noise(self) -> np.ndarray:
        """(n_samples, nw) float, the minimising w(k) by inverse DFT."""
        return inverse_dft(self.solution.w, self.n_samples, self.convention)

    def time_domain_perturbation(self) -> np.ndarray:
        """(n_samples, nv) float, the witness v(k) by inverse DFT."""
        return inverse_dft(self.solution.v, self.n_samples, self.convention)

    def summary(self) -> dict[str, Any]:
        """JSON-serialisable numbers (the band's entries only where the model has a band)."""
        out: dict[str, Any] = {
            "model": self.model_name,
            "beta": self.beta,
            "beta_upper": self.beta_upper,
            "invalidated": self.invalidated,
            "margin": self.margin,
            "norm_convention": self.convention.value,
            "norm_description": self.convention.description,
            "method": self.method,
            "method_reason": self.method_reason,
            "max_bin_gap": float(np.max(self.solution.gap)) if self.solution.gap.size else 0.0,
            "uncertified_bins": int(np.sum(~self.solution.certified)),
            "fallback_bins": self.fallback_bins,
            "leakage_bound": self.leakage.tolist(),
            "compute_time_s": self.compute_time_s,
            "noise_beta": self.noise_beta if math.isfinite(self.noise_beta) else None,
        }
        if np.any(self.leakage_exceeds_data):  # the bound says nothing there: left out
            out["leakage_bound"] = [
                None if over else float(b)
                for b, over in zip(self.leakage, self.leakage_exceeds_data, strict=True)
            ]
            out["leakage_exceeds_data"] = self.leakage_exceeds_data.tolist()
            out["leakage_note"] = LEAKAGE_NOTE
        if self.band is not None:
            out["band"] = self.band.to_dict()
            out["band_bins"] = int(np.sum(self.band_mask))
            out["beta_outside"] = self.beta_outside
            out["lines_outside"] = [list(p) for p in self.lines_outside]
            out["periodic_outside"] = [list(p) for p in self.periodic_outside]
        return out


def inverse_dft(values: np.ndarray, n_samples: int, convention: NormConvention) -> np.ndarray:
    """Time signal from one-sided scaled DFT bins (real signal, conjugate-symmetric spectrum).

    Args:
        values: (n_samples//2 + 1, k) complex, scaled DFT bins.
        n_samples: record length N.
        convention: the DFT prefactor used.

    Returns:
        (n_samples, k) float.
    """
    return np.fft.irfft(values / convention.dft_scale(n_samples), n=n_samples, axis=0)


def total_beta(per_bin: np.ndarray, weights: np.ndarray) -> float:
    """``sqrt(sum_n weight_n per_bin(n)^2)`` over one-sided bins."""
    with np.errstate(invalid="ignore"):
        return float(np.sqrt(np.dot(weights, per_bin * per_bin)))


def check_compatible(datum: Datum, model: LFTModel) -> None:
    """Raise ``DimensionError`` unless the model's inputs and outputs match the datum's."""
    if (model.nu, model.ny) != (datum.n_inputs, datum.n_outputs):
        raise DimensionError(
            f"model {model.name!r} has {model.nu} inputs {list(model.input_names)} and {model.ny} "
            f"outputs {list(model.output_names)}, but the datum has {datum.n_inputs} inputs and "
            f"{datum.n_outputs} outputs: pass the model that matches the recorded channels"
        )


def pulse_response(model: LFTModel, ts_s: float, max_samples: int = 200_000) -> np.ndarray:
    """(n, ny, nu) pulse response of the discretised nominal, long enough to decay to 1e-12."""
    sys = model.nominal_discrete(ts_s)
    lag = max((round(t / ts_s) for t in sys.output_delays_s), default=0)  # delayed rows
    if sys.n_states == 0:
        return lti.impulse_response(sys, 1 + lag)
    rad = float(np.max(np.abs(np.linalg.eigvals(sys.a))))
    if rad >= 1.0:
        raise ModelError(f"nominal of {model.name!r} is unstable: no pulse response bound")
    n = int(min(max_samples, max(16, np.ceil(np.log(_PULSE_DECAY) / np.log(max(rad, 1e-300))) + 2)))
    return lti.impulse_response(sys, n + lag)


def pulse_moment(model: LFTModel, ts_s: float) -> np.ndarray:
    """(ny, nu) float, ``sum_k k |p_ij(k)|`` of the discretised nominal (memoised per model)."""
    key = ("pulse_moment", float(ts_s))
    if key not in model.cache:
        model.cache[key] = datum_pulse_moment(pulse_response(model, ts_s))
    moment: np.ndarray = model.cache[key]
    return moment


def input_leakage(datum: Datum, model: LFTModel, response: PlantResponse | None = None) -> float:
    """How far the input's change from period to period may move β: ``rho``, in units of w.

    The leakage transient of that change (:func:`~twotank_validation.core.datum.
    input_leakage_transient`, through the model's nominal; its folded pulse response kept
    in the model's cache) is de-meaned as the datum's
    outputs are and transformed as they are (``R(n)``, the datum's convention); ``rho`` is
    the norm of the smallest noise that produces it, ``sqrt(sum_n weight_n
    |P22(n)^+ R(n)|^2)``: what the model's noise weights must spend on it. Adding it to
    the data moves β by at most that much (the triangle inequality, for models whose noise
    does not enter the perturbations' inputs, ``P12 = 0``, as Models A and B), so a
    verdict whose β lies further than ``rho`` from 1 does not hang on it. Infinite where
    some output leaks without a noise weight to take it; 0 for a periodic input.

    Args:
        datum: the datum (its ``periodicity.last_change``).
        model: the model.
        response: P at the datum's bins, if already evaluated.
    """
    per = datum.periodicity
    if per.input_periodic or per.n_periods < 2:
        return 0.0
    key = ("folded_pulse", float(datum.ts_s), datum.period_samples, datum.n_samples)
    if key not in model.cache:  # every window of a monitor folds the same
        model.cache[key] = fold_pulse(
            pulse_response(model, datum.ts_s), datum.period_samples, datum.n_samples
        )
    r = folded_leakage(model.cache[key], per.last_change, datum.n_periods, datum.n_samples)
    leak = scaled_dft(r - column_mean(r), datum.convention)  # (n_bins, ny)
    resp = response if response is not None else model.response(datum.theta, datum.ts_s)
    if "noise_pinv" not in resp.memo:
        resp.memo["noise_pinv"] = np.linalg.pinv(resp.p22) if resp.nw else None
    pinv = resp.memo["noise_pinv"]
    size = float(np.max(np.abs(leak))) if leak.size else 0.0
    if size == 0.0:
        return 0.0
    if pinv is None:
        return math.inf
    w = np.einsum("kwy,ky->kw", pinv, leak)
    missed = np.abs(np.einsum("kyw,kw->ky", resp.p22, w) - leak)
    if float(np.max(missed)) > 1e-9 * size:
        return math.inf  # an output the noise cannot reach leaks
    return total_beta(np.linalg.norm(w, axis=1), datum.bin_weights)


def bin_response(model: LFTModel, n_samples: int, ts_s: float) -> PlantResponse:
    """P at the bins ``2 pi n / N``, ``n = 0 .. N//2``, of a datum of ``n_samples`` samples.

    Memoised on the model per ``(ts_s, n_samples)`` (every window of a monitor has the same
    bins): the response and what the solvers memoise on it are computed once.
    """
    key = ("bin_response", float(ts_s), int(n_samples))
    if key not in model.cache:
        theta = 2.0 * np.pi * np.arange(n_samples // 2 + 1) / n_samples
        model.cache[key] = model.response(theta, ts_s)
    resp: PlantResponse = model.cache[key]
    return resp


@dataclass(frozen=True)
class BetaResult:
    """What a window's report needs of :func:`validate`: the same numbers, bit for bit.

    Attributes:
        method: solver that ran (``"closed_form"``, ``"fast"`` or ``"sdp"``).
        freqs_hz: (n_bins,) float, bin frequencies.
        w_min: (n_bins,) float, lower bound on min ||W(n)|| per bin.
        beta: ``sqrt(sum_n weight_n w_min(n)^2)``.
        beta_upper: the same from the witness.
        warnings, findings, input_leakage, beta_outside, lines_outside, noise_beta,
            noise_floor: as :class:`ValidationResult`'s (``noise_floor`` empty where the
            caveats were not computed).
    """

    method: str
    freqs_hz: np.ndarray
    w_min: np.ndarray
    beta: float
    beta_upper: float
    warnings: tuple[str, ...] = ()
    findings: tuple[PeriodicityFinding, ...] = ()
    input_leakage: float = 0.0
    beta_outside: float = 0.0
    lines_outside: tuple[tuple[float, float], ...] = ()
    noise_beta: float = math.nan
    noise_floor: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def margin(self) -> float:
        """``1 - beta``."""
        return 1.0 - self.beta


def validate_beta(
    datum: Datum,
    model: LFTModel,
    *,
    method: str = "auto",
    response: PlantResponse | None = None,
    command_bins: np.ndarray | None = None,
    caveats: bool = True,
) -> BetaResult:
    """β of :func:`validate` without the witness, the output error and the leakage bound.

    Where the closed form runs, only its per-bin minimum is computed (no perturbations
    Delta); on the other routes this is :func:`validate`. Same arguments and errors;
    ``caveats=False``: where the closed form runs, no caveats either (no warnings or
    findings, ``noise_beta`` NaN: for a caller that reads β alone).
    """
    if method not in METHODS:
        raise ModelError(f"unknown method {method!r}; use one of {METHODS}")
    check_compatible(datum, model)
    resp = response if response is not None else model.response(datum.theta, datum.ts_s)
    route = _route(resp, method)
    if route.method != Method.CLOSED_FORM or route.refused:
        res = validate(datum, model, method=method, response=resp, command_bins=command_bins)
        return BetaResult(
            res.method,
            res.freqs_hz,
            res.w_min,
            res.beta,
            res.beta_upper,
            res.warnings,
            res.findings,
            res.input_leakage,
            res.beta_outside,
            res.lines_outside,
            res.noise_beta,
            res.noise_floor,
        )
    assert route.structure is not None
    lower = solvers.closed_form_bins(resp, datum.u_bins, datum.y_bins, route.structure)[0]
    mask = validation_band(datum, model, command_bins)
    beta = masked_beta(lower, datum.bin_weights, mask)
    said = result_caveats(datum, model, beta, resp, mask) if caveats else Caveats()
    return BetaResult(
        Method.CLOSED_FORM.value,
        datum.freqs_hz,
        lower,
        beta,
        beta,  # the closed form's witness attains the minimum: upper = lower
        said.texts,
        said.findings,
        said.input_leakage,
        0.0 if mask is None else masked_beta(lower, datum.bin_weights, ~mask),
        () if mask is None else outside_lines(lower, datum.bin_weights, datum.freqs_hz, mask),
        said.noise_beta,
        said.noise_floor,
    )


def validation_band(
    datum: Datum, model: LFTModel, command_bins: np.ndarray | None = None
) -> np.ndarray | None:
    """(n_bins,) bool, the bins of ``datum`` in the model's band; ``None`` without a band.

    Args:
        datum: the datum.
        model: the model (its ``band``).
        command_bins: (n_bins, n_inputs) complex, the command's scaled DFT where it differs
            from the datum's inputs (a measured input); default the datum's ``u_bins``, whose
            lines must then stand above a measured input's noise (``u_noise_std``,
            :func:`~twotank_validation.core.band.excited_lines`).
    """
    if model.band is None:
        return None
    if command_bins is not None:
        return band_mask(datum.freqs_hz, model.band, command_bins, datum.n_periods)
    return band_mask(datum.freqs_hz, model.band, datum.u_bins, datum.n_periods, datum.u_noise_std)


def leakage_exceeds_data(leak: np.ndarray, y_bins: np.ndarray) -> np.ndarray:
    """(ny,) bool: outputs whose leakage bound exceeds the largest ``|Y_i(n)|`` over the bins.

    The bound on ``|R_i(n)|`` is the same at every bin; where it is larger than every line of
    the output it bounds, it says nothing about the data (Ljung's bound takes the worst
    input history, ``max|u|`` for the whole change, and ``sum_k k |p(k)|`` grows with the
    nominal's slowest time constant in samples).

    Args:
        leak: (ny,) float, the bound (:func:`~twotank_validation.core.datum.leakage_bound`).
        y_bins: (n_bins, ny) complex, the outputs' scaled DFT.
    """
    top = np.max(np.abs(y_bins), axis=0) if y_bins.shape[0] else np.zeros(y_bins.shape[1])
    return np.asarray(leak > top, dtype=bool)


def validate(
    datum: Datum,
    model: LFTModel,
    *,
    method: str = "auto",
    progress: Callable[[int], None] | None = None,
    response: PlantResponse | None = None,
    command_bins: np.ndarray | None = None,
) -> ValidationResult:
    """Solve Problem 3 at every bin and total it into beta.

    ``method="auto"`` takes the exact closed form where the structure decouples per output,
    else the batched fast path where it covers the structure (at most
    :data:`fast.MAX_BLOCKS` blocks), else the per-bin cvxpy SDP; ``result.method_reason``
    says which and why.

    Args:
        datum: the checked, transformed experiment.
        model: the model set.
        method: ``"auto"``, ``"closed_form"``, ``"fast"`` (batched dual, any covered
            structure) or ``"sdp"`` (per-bin cvxpy reference).
        progress: per-bin progress callback (SDP path; the fast path reports all bins at
            the end).
        response: P at ``datum.theta`` if already evaluated (saves the evaluation).
        command_bins: (n_bins, n_inputs) complex, the command's scaled DFT where it differs
            from the datum's inputs (for the model's band ``excited``; default ``u_bins``).

    Problem 3 is solved at every bin; β totals the bins of the model's band
    (:func:`validation_band`; every bin without one) and ``beta_outside`` the rest.

    Raises:
        DimensionError: model and datum channels differ.
        ModelError: unknown method, or the closed form or the fast path asked for where it
            does not apply.
    """
    if method not in METHODS:
        raise ModelError(f"unknown method {method!r}; use one of {METHODS}")
    check_compatible(datum, model)
    resp = response if response is not None else model.response(datum.theta, datum.ts_s)
    start = time.perf_counter()
    fallback_bins = 0
    error: np.ndarray | None = None
    route = _route(resp, method)
    if route.refused:
        raise ModelError(f"{route.refused} model {model.name!r}: {route.reason}; use method='sdp'")
    reason = route.reason
    if route.method == Method.SDP:
        sol = solvers.solve_sdp(resp, datum.u_bins, datum.y_bins, progress=progress)
    elif route.method == Method.FAST:
        sol, fallback_bins, done, error = _solve_fast(resp, datum, progress)
        reason = f"{reason}; {done}"
    else:
        assert route.structure is not None
        sol = solvers.solve_closed_form(resp, datum.u_bins, datum.y_bins, route.structure)
    elapsed = time.perf_counter() - start
    if error is None:
        error = datum.y_bins - np.einsum("kij,kj->ki", resp.p23, datum.u_bins)
    leak = leakage_bound(
        pulse_moment(model, datum.ts_s), datum.u_max, datum.n_samples, datum.convention
    )
    mask = validation_band(datum, model, command_bins)
    beta = masked_beta(sol.lower, datum.bin_weights, mask)
    caveats = result_caveats(datum, model, beta, resp, mask)
    everywhere = np.ones(datum.freqs_hz.size, dtype=bool)
    return ValidationResult(
        model_name=model.name,
        convention=datum.convention,
        method=sol.method,
        method_reason=reason,
        freqs_hz=datum.freqs_hz,
        theta=datum.theta,
        bin_weights=datum.bin_weights,
        w_min=sol.lower,
        w_upper=sol.upper,
        beta=beta,
        beta_upper=masked_beta(sol.upper, datum.bin_weights, mask),
        solution=sol,
        error=error,
        leakage=leak,
        n_samples=datum.n_samples,
        ts_s=datum.ts_s,
        compute_time_s=elapsed,
        fallback_bins=fallback_bins,
        warnings=caveats.texts,
        findings=caveats.findings,
        input_leakage=caveats.input_leakage,
        band=model.band,
        band_mask=everywhere if mask is None else mask,
        beta_outside=0.0 if mask is None else masked_beta(sol.lower, datum.bin_weights, ~mask),
        lines_outside=()
        if mask is None
        else outside_lines(sol.lower, datum.bin_weights, datum.freqs_hz, mask),
        periodic_outside=()
        if mask is None
        else periodic_lines(datum.y_bins, datum.noise_std, datum.freqs_hz, mask),
        leakage_exceeds_data=leakage_exceeds_data(leak, datum.y_bins),
        noise_beta=caveats.noise_beta,
        noise_floor=caveats.noise_floor,
    )


_STILL = 1e-9
"""Inputs whose largest deviation from their mean is below this (relative to max(1, |mean|))
do not move."""


@dataclass(frozen=True)
class Caveats:
    """What makes a verdict on a datum weaker than it looks (:func:`result_caveats`).

    Attributes:
        findings: the datum's periodicity findings that weaken this verdict, typed: every
            one but ``INPUT_NOT_PERIODIC``, which counts only where the input's leakage may
            reach the verdict (``input_leakage >= |1 - beta|``).
        input_leakage: how far the input's change from period to period may move β
            (:func:`input_leakage`; 0 for a periodic input).
        texts: every caveat in words, one sentence each with what to do.
        noise_beta: the β the datum's noise alone is expected to cost, over the band
            (:func:`noise_cost`; NaN with one period or without noise channels).
        noise_floor: (n_bins,) float, its per-bin terms (:func:`noise_cost`); empty where
            the caveats were not computed.
    """

    findings: tuple[PeriodicityFinding, ...] = ()
    input_leakage: float = 0.0
    texts: tuple[str, ...] = ()
    noise_beta: float = math.nan
    noise_floor: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class NoiseCost:
    """What a datum's noise alone is expected to cost under a model's noise weights.

    Attributes:
        beta: the expected noise-only β over the band, ``sqrt(Σ_n b_n floor(n)²)``.
        lower: its lower bound at
            :data:`~twotank_validation.core.noise_budget.NOISE_WARN_CONFIDENCE`.
        floor: (n_bins,) float, the per-bin min ``||W(n)||`` the noise alone is expected to
            cost (:func:`~twotank_validation.core.noise_budget.noise_floor`), at every bin,
            comparable to ``w_min``.

    All NaN with one period (no spread) or without noise channels.
    """

    beta: float
    lower: float
    floor: np.ndarray


def noise_cost(
    datum: Datum,
    model: LFTModel,
    response: PlantResponse | None = None,
    mask: np.ndarray | None = None,
) -> NoiseCost:
    """The β the datum's noise alone is expected to cost, its lower bound and per-bin floor.

    ``sqrt(Σ_n b_n Σ_c σ_c(n)² |P22(n)⁺ e_c|²)`` over the band's bins, with ``σ_c(n)`` the
    outputs' noise estimated from the period-to-period spread (``Datum.noise_std``, each bin
    taking its nearest harmonic's; :mod:`~twotank_validation.core.noise_budget`,
    docs/theory.md §13); the floor is the per-bin root ``sqrt(Σ_c σ_c(n)² |P22(n)⁺ e_c|²)``
    at every bin (the band decides only what the total counts).
    """
    if datum.n_periods < 2 or model.nw == 0:
        return NoiseCost(math.nan, math.nan, np.full(datum.freqs_hz.shape, math.nan))
    resp = response if response is not None else model.response(datum.theta, datum.ts_s)
    if "noise_gain2" not in resp.memo:
        if "noise_pinv" not in resp.memo:
            resp.memo["noise_pinv"] = np.linalg.pinv(resp.p22)
        resp.memo["noise_gain2"] = np.sum(np.abs(resp.memo["noise_pinv"]) ** 2, axis=1)
    gain2 = resp.memo["noise_gain2"]
    spread = spread_of_std([datum.noise_std], datum.n_periods)
    return NoiseCost(
        expected_noise_beta(spread.var, gain2, datum.bin_weights, mask),
        noise_beta_lower(spread, gain2, datum.bin_weights, mask, NOISE_WARN_CONFIDENCE),
        noise_floor(spread.var, gain2),
    )


def noise_beta_bounds(
    datum: Datum,
    model: LFTModel,
    response: PlantResponse | None = None,
    mask: np.ndarray | None = None,
) -> tuple[float, float]:
    """The β the datum's noise alone is expected to cost under the model's noise weights.

    :func:`noise_cost`'s estimate and lower bound.

    Returns:
        ``(estimate, lower)``: the estimate and its lower bound at
        :data:`~twotank_validation.core.noise_budget.NOISE_WARN_CONFIDENCE`; NaN with one
        period (no spread) or without noise channels.
    """
    cost = noise_cost(datum, model, response, mask)
    return cost.beta, cost.lower


def noise_beta(
    datum: Datum,
    model: LFTModel,
    response: PlantResponse | None = None,
    mask: np.ndarray | None = None,
) -> float:
    """The estimate of :func:`noise_beta_bounds` alone."""
    return noise_beta_bounds(datum, model, response, mask)[0]


def noise_budget_warning(beta_noise: float, lower: float) -> tuple[str, ...]:
    """The warning for noise weights that alone use most of β's budget, if they do.

    ``lower`` (:func:`noise_beta_bounds`, the estimate ``beta_noise``'s lower bound) above
    :data:`NOISE_BETA_WARN`: one sentence with the fix; otherwise nothing.
    """
    if not lower > NOISE_BETA_WARN:
        return ()
    return (
        f"the noise alone is expected to cost beta {beta_noise:.3g} (at least {lower:.3g}) "
        "under the model's noise "
        f"weights (beta^2 {beta_noise**2:.2f} of its budget 1: the output channels share one "
        "unit-norm w): a beta near or above 1 may be the noise weights', not the model's; "
        "set them from the data (twotank-validation calibrate RECORDING --model MODEL "
        "--noise-from-data --out-model NEW.yaml)",
    )


def result_caveats(
    datum: Datum,
    model: LFTModel,
    beta: float,
    response: PlantResponse | None = None,
    mask: np.ndarray | None = None,
) -> Caveats:
    """What makes a verdict on this datum weaker than it looks: typed, and in words.

    An input that does not repeat exactly (a closed loop answers the noise) is a caveat
    only where its leakage may decide the verdict: :func:`input_leakage` at least β's
    distance from 1. A closed loop's steady answer to the noise stays far below it; a
    reference that ramps does not.

    Args:
        datum: the datum (its periodicity findings are repeated here).
        model: the model.
        beta: the result's β.
        response: P at the datum's bins, if already evaluated.
        mask: (n_bins,) bool, the bins of the model's band (``None``: every bin).
    """
    per = datum.periodicity
    rho = 0.0 if per.input_periodic else input_leakage(datum, model, response)
    findings: list[PeriodicityFinding] = []
    out: list[str] = []
    for finding in per.findings:
        if finding is not PeriodicityFinding.INPUT_NOT_PERIODIC:
            findings.append(finding)
            out.append(periodicity_text(finding, per))
        elif not rho < abs(beta - 1.0):  # NaN and infinite included
            findings.append(finding)
            out.append(
                f"{finding}: its change from one period to the next (up to "
                f"{float(per.input_variation.max()):.3g} of its RMS) leaks into beta; were it a "
                f"steady trend, by up to {rho:.3g}, no less than beta's distance from 1 "
                f"({abs(beta - 1.0):.3g}): the verdict may be the input's, not the model's; "
                "judge windows where the input repeats (a steady reference)"
            )
    still = datum.u_max <= _STILL * np.maximum(1.0, np.abs(datum.u_bias))
    if np.all(still):
        out.append(
            "the inputs do not move (largest deviation from their mean "
            f"{float(np.max(datum.u_max)):.3g}): nothing excites the plant, so the datum tests "
            "only the noise model; record with the excitation on"
        )
    if mask is not None and not np.any(mask):
        out.append(
            f"the band ({model.band.text if model.band else 'none'}) holds no bin of this "
            "record: beta is 0 because nothing was judged; widen the band or excite it"
        )
    if model.nw == 0:
        out.append(
            f"model {model.name} has no noise channels: measured data, which always hold noise, "
            "invalidate it whatever its plant; add a noise section with the sensors' noise"
        )
    elif not np.isfinite(beta):
        out.append(
            "beta is infinite: at some bins no noise of the model can reach the output error "
            "(an output without a noise weight, or a weight that vanishes there); give every "
            "measured output a noise weight"
        )
    cost = noise_cost(datum, model, response, mask)
    out.extend(noise_budget_warning(cost.beta, cost.lower))
    return Caveats(tuple(findings), rho, tuple(out), cost.beta, cost.floor)


def result_warnings(
    datum: Datum, model: LFTModel, beta: float, response: PlantResponse | None = None
) -> tuple[str, ...]:
    """What makes a verdict on this datum weaker than it looks, in words (:func:`result_caveats`).

    Returns:
        One sentence per finding, each saying what to do; empty if there is none.
    """
    return result_caveats(datum, model, beta, response).texts


def takes_fast_path(resp: PlantResponse, method: str) -> bool:
    """Whether :func:`validate` with this ``method`` takes the fast path for ``resp``.

    ``"fast"`` always; ``"auto"`` where the closed form does not apply and the fast path
    covers the structure (both ask :func:`_route`, so as :func:`validate` chooses).
    """
    return method in METHODS and _route(resp, method).method == Method.FAST


def takes_closed_form(resp: PlantResponse, method: str) -> bool:
    """Whether :func:`validate` with this ``method`` runs the closed form on ``resp``."""
    if method not in METHODS:
        return False
    route = _route(resp, method)
    return route.method == Method.CLOSED_FORM and not route.refused


@dataclass(frozen=True)
class _Route:
    """The solver :func:`validate` runs, and why.

    Attributes:
        method: the solver: ``Method.CLOSED_FORM``, ``Method.FAST`` or ``Method.SDP`` (where
            the request is refused, the one asked for).
        reason: why (the start of ``ValidationResult.method_reason``); where the request is
            refused, why it does not apply.
        refused: empty, or what does not apply (``validate`` raises ``ModelError``).
        structure: the decoupled structure, where the closed form runs.
    """

    method: Method
    reason: str
    refused: str = ""
    structure: solvers.DecoupledStructure | None = None


def _route(resp: PlantResponse, method: str) -> _Route:
    """The solver route of ``method`` on ``resp``, memoised on the response."""
    key = ("route", str(method))
    if key not in resp.memo:
        resp.memo[key] = _find_route(resp, method)
    route: _Route = resp.memo[key]
    return route


def _find_route(resp: PlantResponse, method: str) -> _Route:  # noqa: PLR0911 - one return per route
    """The solver route, written once: which solver ``method`` (one of METHODS) runs on ``resp``.

    ``"sdp"`` and ``"fast"`` as asked (``"fast"`` refused where it does not cover the
    structure); ``"closed_form"`` where the structure decouples per output (else refused);
    ``"auto"``: the closed form where it applies, else the fast path where it covers the
    structure, else the SDP.
    """
    if method == Method.SDP:
        return _Route(Method.SDP, "SDP relaxation (requested)")
    if method == Method.FAST:
        covered, cover = fast.coverage(resp.blocks, resp.nw)
        if not covered:
            return _Route(Method.FAST, cover, refused="fast path does not cover")
        return _Route(Method.FAST, f"fast batched dual (requested): {cover}")
    structure, why = solvers.decoupled_structure(resp)
    if method == Method.CLOSED_FORM and structure is None:
        return _Route(Method.CLOSED_FORM, why, refused="closed form does not apply to")
    covered, cover = fast.coverage(resp.blocks, resp.nw)
    if structure is not None:
        return _Route(Method.CLOSED_FORM, f"closed form: {why}", structure=structure)
    if covered:
        return _Route(
            Method.FAST, f"fast batched dual: closed form not applicable ({why}); {cover}"
        )
    return _Route(
        Method.SDP,
        f"SDP relaxation: closed form not applicable ({why}); fast path not applicable ({cover})",
    )


def solve_bins(
    resp: PlantResponse, u_bins: np.ndarray, y_bins: np.ndarray, *, method: str = "auto"
) -> solvers.BinSolutions:
    """Problem 3 at the given bins, on the route :func:`validate` takes for ``method``.

    Args:
        resp: P at the bins, (n_bins, ...).
        u_bins: (n_bins, nu) complex, scaled DFT of the inputs at those bins.
        y_bins: (n_bins, ny) complex, scaled DFT of the outputs.
        method: as :func:`validate`.

    Raises:
        ModelError: unknown method, or a route asked for where it does not apply.
    """
    if method not in METHODS:
        raise ModelError(f"unknown method {method!r}; use one of {METHODS}")
    route = _route(resp, method)
    if route.refused:
        raise ModelError(f"{route.refused} this model: {route.reason}; use method='sdp'")
    if route.method == Method.SDP:
        return solvers.solve_sdp(resp, u_bins, y_bins)
    if route.method == Method.FAST:
        return fast.solve_fast(resp, u_bins, y_bins).solutions
    assert route.structure is not None
    return solvers.solve_closed_form(resp, u_bins, y_bins, route.structure)


def lower_bins(
    resp: PlantResponse, u_bins: np.ndarray, y_bins: np.ndarray, *, method: str = "auto"
) -> np.ndarray:
    """``solve_bins(...).lower``, bit for bit; where the closed form runs, without its witness.

    Returns:
        (n_bins,) float, the lower bound on min ||W(n)|| at each bin.
    """
    if method in METHODS and takes_closed_form(resp, method):
        structure = _route(resp, method).structure
        assert structure is not None
        return solvers.closed_form_bins(resp, u_bins, y_bins, structure)[0]
    return solve_bins(resp, u_bins, y_bins, method=method).lower


def _solve_fast(
    resp: PlantResponse, datum: Datum, progress: Callable[[int], None] | None
) -> tuple[solvers.BinSolutions, int, str, np.ndarray]:
    """The fast path on every bin.

    Returns:
        Solutions, bins that fell back, a line saying so, and the output error
        ``Y - P23 U`` (n_bins, ny) it computed on the way.
    """
    res = fast.solve_fast(resp, datum.u_bins, datum.y_bins)
    st = res.stats
    if progress is not None:
        progress(st.n_bins)
    line = (
        f"{st.n_direct + st.n_dual} of {st.n_bins} bins solved ({st.n_compiled} by the "
        f"compiled per-bin kernel{' sized for this structure' if st.kernel_sized else ''}, "
        f"{st.n_direct + st.n_dual - st.n_compiled} by the batched "
        f"numpy dual), {st.n_fallback} fell back to the per-bin SDP"
    )
    return res.solutions, st.n_fallback, line, res.error
