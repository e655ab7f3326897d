"""What the identified weights must be at each excited line, and the numbers of the report.

The identified model set is ``H = (I + W Δ) G`` row by row: output ``c`` carries a scalar
output-multiplicative perturbation ``W_c δ_c`` (``|δ_c| <= 1``) and a flat noise weight
``N_c`` (docs/theory.md §19, §13).

* :func:`perturbation_requirement`: at line ``k``, the experiment that drives input ``i``
  alone is explained by output ``c``'s block only if ``|W_c| >= |H_ci - G_ci| / |G_ci|``; the
  same weight serves every input, so ``r_c(k) = max_i |H_ci - G_ci| / |G_ci|``. ``H`` is
  known to within its confidence disc of radius ``ρ_ci`` (noise and distortion together), so
  the requirement lies in ``[max_i max(|Ĥ - G| - ρ, 0) / |G|, max_i (|Ĥ - G| + ρ) / |G|]``.
  Its central value is what :attr:`~.pipeline.Identification.relative_error` gives and what
  the weight shapes calibrate scales are fitted over.
* :func:`noise_requirement`: the flat noise weight ``N_c`` that
  :func:`~twotank_validation.core.noise_budget.noise_weights` sets is proportional to the
  noise's RMS; at line ``k`` the weight a noise of that line's level everywhere would need is
  ``N_c σ_c(k) / σ̄_c`` (``σ̄_c`` the RMS of ``σ_c`` over the lines). Lines above ``N_c``
  are where the flat weight is tight (the noise there spends more than its share of β).
* :func:`validation_requirement`: calibrate's own per-bin requirement
  (:func:`~twotank_validation.calibrate.scaling.bin_requirement`) for the written model set on
  its fit windows: the smallest weight each line needs, with the noise weights as written,
  for the window to stay valid within the line's equal share of β².
* :func:`report_numbers`: all three, with the response, its σ's, the nominal and the written
  weights' magnitudes at the lines, as the report draws them and the JSON holds them.

Pure functions over numpy arrays but :func:`output_noise_at_lines` and
:func:`validation_requirement`, which read windows.
Units: responses in output model units per input model unit; the perturbation weight
dimensionless; the noise weight in output model units per unit of ``w``; frequencies in Hz.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from twotank_validation.calibrate.calibration import CalibrationConfig
from twotank_validation.calibrate.scaling import (
    WindowProblem,
    bin_requirement,
    choose_blocks,
    weight_gain,
)
from twotank_validation.core import lti
from twotank_validation.core.datum import NormConvention
from twotank_validation.core.model import model_from_dict
from twotank_validation.core.noise_budget import noise_spread
from twotank_validation.diagnose.inputs import DiagnosisError, Window, split_windows
from twotank_validation.errors import DatumError
from twotank_validation.identify.pipeline import Identification, IdentifiedModel

__all__ = [
    "LEVEL",
    "PerturbationRequirement",
    "ReportNumbers",
    "noise_requirement",
    "output_noise_at_lines",
    "perturbation_requirement",
    "report_numbers",
    "validation_requirement",
    "weight_magnitude",
]

LEVEL = 0.95
"""Confidence of the measured response's disc the requirement's interval is drawn from."""


@dataclass(frozen=True)
class PerturbationRequirement:
    """What an output-multiplicative weight per output must be at each line.

    Attributes:
        entry: (L, n_y, n_u) ``|Ĥ - G| / |G|`` per entry.
        entry_lo: (L, n_y, n_u) ``max(|Ĥ - G| - ρ, 0) / |G|``.
        entry_hi: (L, n_y, n_u) ``(|Ĥ - G| + ρ) / |G|``.
        required: (L, n_y) ``entry`` at its largest over the inputs.
        lo: (L, n_y) ``entry_lo`` at its largest over the inputs.
        hi: (L, n_y) ``entry_hi`` at its largest over the inputs.
    """

    entry: np.ndarray
    entry_lo: np.ndarray
    entry_hi: np.ndarray
    required: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def perturbation_requirement(
    measured: np.ndarray, radius: np.ndarray, nominal: np.ndarray
) -> PerturbationRequirement:
    """The output-multiplicative weight each line requires to cover the nominal's error.

    Args:
        measured: (L, n_y, n_u) complex, the measured response ``Ĥ``.
        radius: (L, n_y, n_u) float >= 0, the radius of ``Ĥ``'s confidence disc (same units).
        nominal: (L, n_y, n_u) complex, the nominal ``G`` at the same lines.

    Returns:
        The requirement (dimensionless); ``inf`` where the nominal is 0 and the error is not.
    """
    err = np.abs(np.asarray(measured) - np.asarray(nominal))
    mag = np.abs(np.asarray(nominal))
    rad = np.asarray(radius, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        entry = np.where(err > 0.0, err / mag, 0.0)
        lo = np.where(err > rad, (err - rad) / mag, 0.0)
        hi = np.where(err + rad > 0.0, (err + rad) / mag, 0.0)
    return PerturbationRequirement(entry, lo, hi, entry.max(axis=2), lo.max(axis=2), hi.max(axis=2))


def noise_requirement(noise_var: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """(L, n_y) the noise weight each line would need: ``N_c σ_c(k) / σ̄_c``.

    Args:
        noise_var: (L, n_y) float, the output noise's variance at each line (any scale
            common to the lines of an output: it cancels).
        gains: (n_y,) the flat noise weights ``N_c`` (output model units per unit of ``w``).
    """
    var = np.asarray(noise_var, float)
    rms = np.sqrt(np.mean(var, axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(rms > 0.0, np.sqrt(var) / rms, 0.0) * np.asarray(gains, float)[None]
    return np.asarray(out)


def weight_magnitude(
    num: Sequence[float], den: Sequence[float], freqs_hz: np.ndarray
) -> np.ndarray:
    """(F,) ``|W(j 2π f)|`` of a continuous weight ``num/den`` (descending powers of s).

    The identified model is evaluated exactly at the bins (``intersample: exact``), so this is
    the magnitude ``validate`` uses.
    """
    sys = lti.from_transfer_function(num, den)
    return np.abs(lti.continuous_response(sys, 2 * np.pi * np.asarray(freqs_hz, float))[:, 0, 0])


def output_noise_at_lines(ident: Identification, windows: Sequence[Window]) -> np.ndarray | None:
    """(L, n_y) the outputs' noise variance at the response's lines, or None.

    From the period-to-period spread of the windows (two or more periods each), else the
    local polynomial method's residual; None where neither is at hand.
    """
    lines = ident.response.lines
    if windows and all(w.n_periods >= 2 for w in windows):
        try:
            spread = noise_spread(
                [w.y - w.y.mean(axis=0) for w in windows],
                windows[0].period_samples,
                NormConvention.POWER,
            )
        except DatumError:
            return None
        return np.asarray(spread.harmonic_var[lines])
    return ident.response.noise_var


def validation_requirement(
    windows: Sequence[Window],
    document: dict[str, Any],
    lines: np.ndarray,
    outputs: Sequence[str],
) -> np.ndarray | None:
    """(L, n_y) calibrate's per-bin requirement on the written weights, at the lines.

    For each output's block of the model ``document`` and each fit window (the first half,
    as ``calibrate`` splits them), :func:`~twotank_validation.calibrate.scaling.bin_requirement`
    gives the smallest factor on the written weight each excited bin needs, the other blocks
    and the noise as written; times the weight's magnitude there, the largest over the fit
    windows. 0: the line needs none of the weight (the noise explains it); inf: no weight
    explains it within its share; NaN: not judged (no such block, or the line is not an
    active bin). None: nothing can be held out (one window of one period).
    """
    try:
        fit_w, _ = split_windows(windows)
    except DiagnosisError:
        return None
    model = model_from_dict(document, "identified")
    names = {p["name"] for p in document.get("perturbations", [])}
    floor = CalibrationConfig().excitation_floor
    out = np.full((lines.size, len(outputs)), np.nan)
    problems = [WindowProblem.of(w.datum(), model) for w in fit_w]
    line_of = {int(k): row for row, k in enumerate(lines)}
    for col, name in enumerate(outputs):
        if f"{name}_multiplicative" not in names:
            continue
        (block,) = choose_blocks(model, [f"{name}_multiplicative"])
        for w, problem in zip(fit_w, problems, strict=True):
            req = bin_requirement(problem, block, floor)
            gain = weight_gain(block, problem.datum.theta[req.bins], w.ts_s)
            for b, factor, g in zip(req.bins, req.factor, gain, strict=True):
                # a window of P periods has line k at bin k P
                row = line_of.get(int(b) // w.n_periods) if b % w.n_periods == 0 else None
                if row is not None:
                    out[row, col] = np.fmax(out[row, col], factor * g)
    return out


@dataclass(frozen=True)
class ReportNumbers:
    """The numbers behind the report's figures, per excited line.

    Attributes:
        freqs_hz: (L,) the excited lines in the band.
        measured: (L, n_y, n_u) complex, the measured response.
        std_noise: (L, n_y, n_u) its standard deviation from the noise.
        std_distortion: (L, n_y, n_u) from the stochastic nonlinear distortion (0 but for the
            best linear approximation).
        radius: (L, n_y, n_u) the radius of its :data:`LEVEL` disc (both together).
        nominal: (L, n_y, n_u) complex, the fitted nominal.
        perturbation: the perturbation weights' requirement.
        weight: (L, n_y) the written perturbation weights' magnitude (0: none written).
        covered: (L, n_y) bool, ``weight >= perturbation.required``.
        noise_required: (L, n_y) or None, :func:`noise_requirement`.
        noise_gains: (n_y,) the written flat noise weights.
        validation_required: (L, n_y) or None, :func:`validation_requirement`.
    """

    freqs_hz: np.ndarray
    measured: np.ndarray
    std_noise: np.ndarray
    std_distortion: np.ndarray
    radius: np.ndarray
    nominal: np.ndarray
    perturbation: PerturbationRequirement
    weight: np.ndarray
    covered: np.ndarray
    noise_required: np.ndarray | None
    noise_gains: np.ndarray
    validation_required: np.ndarray | None = None

    @property
    def validation_covered(self) -> np.ndarray | None:
        """(L, n_y) bool: the written weight at least calibrate's requirement (NaN: True)."""
        if self.validation_required is None:
            return None
        need = np.nan_to_num(self.validation_required, nan=0.0)
        return np.asarray(self.weight >= need * (1.0 - 1e-9))

    def to_json(self) -> dict[str, Any]:
        """Plain lists: complex values as ``[re, im]`` pairs, per line first."""

        def c(x: np.ndarray) -> Any:
            return np.stack([x.real, x.imag], axis=-1).tolist()

        def num(x: np.ndarray | None) -> Any:
            """NaN as null, inf as the string "inf" (JSON has neither)."""
            if x is None:
                return None
            return [[None if np.isnan(v) else ("inf" if np.isinf(v) else float(v)) for v in row]
                    for row in x]  # fmt: skip

        p = self.perturbation
        return {
            "freqs_hz": self.freqs_hz.tolist(),
            "level": LEVEL,
            "measured": c(self.measured),
            "std_noise": self.std_noise.tolist(),
            "std_distortion": self.std_distortion.tolist(),
            "radius": self.radius.tolist(),
            "nominal": c(self.nominal),
            "perturbation": {
                "required": p.required.tolist(),
                "required_lo": p.lo.tolist(),
                "required_hi": p.hi.tolist(),
                "weight": self.weight.tolist(),
                "covered": self.covered.tolist(),
                "calibrate_required": num(self.validation_required),
                "calibrate_covered": (
                    None if self.validation_covered is None else self.validation_covered.tolist()
                ),
            },
            "noise": {
                "required": None if self.noise_required is None else self.noise_required.tolist(),
                "weight": self.noise_gains.tolist(),
            },
        }


def report_numbers(
    ident: Identification,
    made: IdentifiedModel,
    outputs: Sequence[str],
    noise_var: np.ndarray | None = None,
    validation_required: np.ndarray | None = None,
) -> ReportNumbers:
    """The report's numbers from the identification and the written model set.

    Args:
        ident: the identification.
        made: the model set written from it.
        outputs: the output names (the perturbation blocks are ``<output>_multiplicative``).
        noise_var: (L, n_y) the outputs' noise variance at the lines
            (:func:`output_noise_at_lines`); None: no noise requirement.
        validation_required: (L, n_y) :func:`validation_requirement`, or None.
    """
    fr = ident.response
    f = fr.freqs_hz
    nominal = ident.nominal.response(f)
    radius = fr.radius(LEVEL)
    req = perturbation_requirement(fr.g, radius, nominal)
    by_name = {name: (num, den) for name, num, den in made.weights()}
    weight = np.zeros((f.size, len(outputs)))
    for col, out in enumerate(outputs):
        if (tf := by_name.get(f"{out}_multiplicative")) is not None:
            weight[:, col] = weight_magnitude(*tf, f)
    var_noise = np.minimum(ident.var_noise, fr.var)
    return ReportNumbers(
        freqs_hz=f,
        measured=fr.g,
        std_noise=np.sqrt(var_noise),
        std_distortion=np.sqrt(np.maximum(fr.var - var_noise, 0.0)),
        radius=radius,
        nominal=nominal,
        perturbation=req,
        weight=weight,
        covered=weight >= req.required,
        noise_required=None
        if noise_var is None
        else noise_requirement(noise_var, made.noise.gains),
        noise_gains=np.asarray(made.noise.gains, float),
        validation_required=validation_required,
    )
