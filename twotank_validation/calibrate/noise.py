"""Noise weights from the data: each output's weight set from its period-to-period spread.

:func:`noise_from_data` estimates every output's noise from the fit windows' spread
(:func:`~twotank_validation.core.noise_budget.noise_spread`), sets flat noise weights whose
noise-only β is at most ``budget`` with probability ``quantile`` on a window like them, the
output channels sharing the one unit-norm ``w`` (:func:`~twotank_validation.core.
noise_budget.noise_weights`, docs/theory.md §13), writes them into the model document and
judges the stated and the new model on the held-out windows.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from twotank_validation.calibrate.calibration import Judged
from twotank_validation.calibrate.scaling import CalibrationError
from twotank_validation.core.datum import Datum, NormConvention, make_datum
from twotank_validation.core.model import LFTModel, model_from_dict
from twotank_validation.core.noise_budget import (
    NOISE_BUDGET,
    NOISE_QUANTILE,
    NoiseWeights,
    noise_beta_quantile,
    noise_spread,
    noise_weights,
)
from twotank_validation.core.validate import noise_beta, validate, validation_band
from twotank_validation.diagnose.inputs import DiagnosisError, Window, split_windows
from twotank_validation.errors import TwotankError


@dataclass(frozen=True)
class NoiseCalibration:
    """Noise weights set from the period-to-period spread of a recording's windows.

    Attributes:
        model: the model's name.
        convention: the norm convention of β.
        outputs: the output names, in the model's order.
        fit: the fitted weights (gains per output, the noise each shows, the quantile, ...).
        stated_noise_beta: (n_fit,) the noise-only β the fit windows' spread costs under the
            stated weights (:func:`~twotank_validation.core.validate.noise_beta`).
        judged: β of the stated and the new model on the fit and held-out windows.
        noise_beta_after: (n_judged,) the noise-only β of each judged window under the new
            weights (same order as ``judged``).
        document: the model file with the new noise weights.
        source: the model's label.
    """

    model: str
    convention: NormConvention
    outputs: tuple[str, ...]
    fit: NoiseWeights
    stated_noise_beta: np.ndarray
    judged: Judged
    noise_beta_after: np.ndarray
    document: dict[str, Any]
    source: str = "model"

    def text(self, model_file: str | None = None) -> str:
        """What was set and how it judges, in a few lines."""
        f = self.fit
        gains = ", ".join(
            f"{n} {g:.4g} (noise {r:.3g})"
            for n, g, r in zip(self.outputs, f.gains, f.noise_rms, strict=True)
        )
        held = self.judged.held_out
        lines = [
            f"noise weights of model {self.model} from the period-to-period spread of "
            f"{int(np.sum(~held))} fit window(s) ({self.convention.value} norm):",
            f"  flat weights: {gains}",
            f"  the {f.n_outputs} output(s) share one unit-norm w: each weight is about "
            f"sqrt({f.n_outputs}) / {f.budget:g} × its noise, so that the noise alone costs "
            f"beta <= {f.budget:g} on {f.quantile:.0%} of windows like these (expected "
            f"{f.expected_beta:.3g}, 50 % at {noise_beta_quantile(f, 0.5):.3g})",
            "  noise alone under the stated weights on the fit windows: beta "
            + ", ".join(f"{b:.3g}" for b in self.stated_noise_beta),
        ]
        if np.any(held):
            lines.append(
                "  held-out windows: beta stated "
                + ", ".join(f"{b:.3g}" for b in self.judged.beta[held])
                + " -> new "
                + ", ".join(f"{b:.3g}" for b in self.judged.beta_after[held])
            )
        if model_file:
            lines.append(f"  written to {model_file}")
        return "\n".join(lines)

    def to_json(self, model_file: str | None = None) -> dict[str, Any]:
        """JSON-serialisable numbers (``inf``/NaN as None)."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        f = self.fit
        return {
            "model": self.model,
            "norm_convention": self.convention.value,
            "noise_from_data": {
                "outputs": list(self.outputs),
                "gains": dict(zip(self.outputs, map(float, f.gains), strict=True)),
                "noise_rms": dict(zip(self.outputs, map(float, f.noise_rms), strict=True)),
                "quantile": f.quantile,
                "budget": f.budget,
                "expected_noise_beta": f.expected_beta,
                "noise_beta_spread": f.spread,
                "dof": [float(d) for d in f.dof],
                "stated_noise_beta": [num(b) for b in self.stated_noise_beta],
            },
            "judged": [
                {
                    "start_s": float(t),
                    "held_out": bool(h),
                    "beta": num(b0),
                    "beta_after": num(b1),
                    "noise_beta_after": num(nb),
                }
                for t, h, b0, b1, nb in zip(
                    self.judged.start_s,
                    self.judged.held_out,
                    self.judged.beta,
                    self.judged.beta_after,
                    self.noise_beta_after,
                    strict=True,
                )
            ],
            "model_file": model_file,
            "failure": None,
        }


def noise_document(
    doc: Mapping[str, Any], outputs: Sequence[str], gains: np.ndarray
) -> dict[str, Any]:
    """The model file with flat noise weights ``gains`` (one per output, model order).

    Each noise block keeps its name and outputs, its weight becomes one gain per output; an
    output in ``k`` blocks gets ``gain / sqrt(k)`` in each (the least ``||w||`` that explains
    its noise is then the same); an output in none gets a block of its own,
    ``<output>_noise``.
    """
    new = copy.deepcopy(dict(doc))
    blocks = list(new.get("noise") or [])
    count = {o: sum(o in b.get("outputs", ()) for b in blocks) for o in outputs}
    gain = dict(zip(outputs, map(float, gains), strict=True))
    for b in blocks:
        outs = list(b["outputs"])
        nodes = [{"gain": gain[o] / math.sqrt(count[o])} for o in outs]
        b["weight"] = nodes if len(nodes) > 1 else nodes[0]
    for o in outputs:
        if count[o] == 0:
            blocks.append({"name": f"{o}_noise", "outputs": [o], "weight": {"gain": gain[o]}})
    new["noise"] = blocks
    new["name"] = f"{doc.get('name', 'model')}_noise"
    new["description"] = (
        f"{doc.get('description', '')} Noise weights set from the data's period-to-period spread."
    ).strip()
    new["derivation"] = (
        f"{doc.get('derivation', doc.get('name', ''))}; then twotank-validation calibrate "
        "--noise-from-data set the noise weights"
    )
    return new


def _datums(windows: Sequence[Window], convention: NormConvention) -> list[Datum]:
    return [
        make_datum(w.u, w.y, ts_s=w.ts_s, period_samples=w.period_samples, convention=convention)
        for w in windows
    ]


def _fit(
    windows: Sequence[Window],
    model: LFTModel,
    quantile: float,
    budget: float,
    convention: NormConvention,
) -> tuple[list[Window], list[Window], list[Datum], list[Datum], NoiseWeights]:
    """The fit and held-out windows, their datums and the weights set on the fit ones."""
    if model.generalized is not None:
        raise CalibrationError(
            f"model {model.name} is a generalised plant: its noise enters through its own "
            "P; --noise-from-data sets the noise section of a structured model"
        )
    try:
        fit_w, held_w = split_windows(windows)
        fit_d, held_d = _datums(fit_w, convention), _datums(held_w, convention)
        first = fit_d[0]
        spread = noise_spread([d.y_centred for d in fit_d], first.period_samples, convention)
        fitted = noise_weights(
            spread,
            first.bin_weights,
            first.n_samples,
            mask=validation_band(first, model),
            quantile=quantile,
            budget=budget,
        )
    except (DiagnosisError, TwotankError) as err:
        raise CalibrationError(str(err)) from err
    return list(fit_w), list(held_w), fit_d, held_d, fitted


def fitted_noise_weights(
    windows: Sequence[Window],
    model: LFTModel,
    *,
    quantile: float = NOISE_QUANTILE,
    budget: float = NOISE_BUDGET,
    convention: NormConvention = NormConvention.POWER,
) -> NoiseWeights:
    """The weights :func:`noise_from_data` sets, without judging them on the windows.

    Same arguments (a loaded model) and errors.
    """
    if not windows:
        raise CalibrationError(
            "no judged window to set the noise weights from: record at least one whole window "
            "of two or more periods"
        )
    return _fit(windows, model, quantile, budget, convention)[4]


def noise_from_data(
    windows: Sequence[Window],
    doc: Mapping[str, Any],
    *,
    quantile: float = NOISE_QUANTILE,
    budget: float = NOISE_BUDGET,
    method: str = "auto",
    source: str = "model",
    convention: NormConvention = NormConvention.POWER,
) -> NoiseCalibration:
    """Flat noise weights from the windows' period-to-period spread, judged on held-out ones.

    Args:
        windows: the judged, non-overlapping windows of a recording (whole periods, the same
            length; the fit ones need two or more periods each).
        doc: the model document (a structured model: nominal, perturbations, noise).
        quantile: probability that a window like the fit ones costs the noise alone at most
            ``budget``.
        budget: the noise-only β allowed at ``quantile``.
        method: the solver route for the judged windows' β.
        source: the model's label.
        convention: the norm convention of β.

    Raises:
        CalibrationError: no window, a generalised-plant model, windows of one period, too
            little data to estimate the noise, a bad quantile or budget.
    """
    if not windows:
        raise CalibrationError(
            "no judged window to set the noise weights from: record at least one whole window "
            "of two or more periods"
        )
    model = model_from_dict(doc, source)
    fit_w, held_w, fit_d, held_d, fitted = _fit(windows, model, quantile, budget, convention)
    try:
        document = noise_document(doc, model.output_names, fitted.gains)
        new_model = model_from_dict(document, f"{source} (noise from data)")
    except TwotankError as err:
        raise CalibrationError(str(err)) from err
    judged_d = fit_d + held_d
    before = [validate(d, model, method=method) for d in judged_d]
    after = [validate(d, new_model, method=method) for d in judged_d]
    return NoiseCalibration(
        model=model.name,
        convention=convention,
        outputs=model.output_names,
        fit=fitted,
        stated_noise_beta=np.array(
            [noise_beta(d, model, mask=validation_band(d, model)) for d in fit_d]
        ),
        judged=Judged(
            start_s=np.array([w.start_s for w in (*fit_w, *held_w)]),
            held_out=np.array([False] * len(fit_d) + [True] * len(held_d)),
            beta=np.array([r.beta for r in before]),
            beta_after=np.array([r.beta for r in after]),
        ),
        noise_beta_after=np.array([r.noise_beta for r in after]),
        document=document,
        source=source,
    )


def noise_model_of(calibration: NoiseCalibration) -> LFTModel:
    """The model with the new noise weights."""
    return model_from_dict(calibration.document, f"{calibration.source} (noise from data)")


__all__ = ["NoiseCalibration", "noise_document", "noise_from_data", "noise_model_of"]
