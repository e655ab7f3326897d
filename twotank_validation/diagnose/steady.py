"""Operating-point effects: a constant sensor offset, judged on the windows' means.

Each window's mean is removed before the DFT, so a constant output offset (a sensor bias) is
invisible to the dynamic fit. It shows in the means: per window ``w`` and output ``c`` the
steady-state deviation

    d_w = ȳ_w − y_ref − G(0) (ū_w − u_ref)

(the output means minus what the model's DC gain ``G(0)`` predicts from the input means,
around a reference operating point ``(u_ref, y_ref)``). The reference is the one passed in
(e.g. the stretch before a change), else the model file's ``operating_point`` (outputs only:
the recording's mean inputs are then taken as the inputs that hold it, i.e. the experiment is
assumed to run around the model's operating point).

The offset is fitted on the fit windows (the mean of ``d_w``), its uncertainty is the
standard error over all windows, and it is judged on the held-out windows like the dynamic
effects. It is reported when it is

* material: larger than the constant the model's own noise weight allows at zero frequency
  (the Problem 3 bound at the DC bin: a deviation within it needs no effect);
* consistent: of the same sign in every window and beyond ``t_{1-alpha/2, n-1}`` standard
  errors;
* explanatory: it removes at least ``min_reduction`` of the held-out windows' steady-state
  deviation (scaled by the noise weight, with the per-parameter penalty).

A bias cannot be written into an LTI model file: it is reported with a recommendation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.stats

from twotank_validation.core.oppoint import OperatingPoint
from twotank_validation.diagnose.effects import Nominal
from twotank_validation.diagnose.inputs import DiagnosisConfig, DiagnosisError, Window


@dataclass(frozen=True)
class Finding:
    """An effect reported outside the model file (an offset or an input saturation).

    Attributes:
        kind: ``offset`` or ``saturation``.
        target: the output (offset) or input (saturation) it acts on.
        parameters: fitted values (model units), with their uncertainty where known.
        evidence: why the data point at it, in words.
        recommendation: what to do about it.
        heldout_reduction: fraction of the held-out error it removes (steady-state deviation
            for an offset, scaled error at the excited bins for a saturation).
    """

    kind: str
    target: str
    parameters: Mapping[str, float]
    evidence: str
    recommendation: str
    heldout_reduction: float
    extra: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready entry."""
        return {
            "kind": self.kind,
            "channel": self.target,
            "parameters": {k: float(v) for k, v in self.parameters.items()},
            "evidence": self.evidence,
            "recommendation": self.recommendation,
            "heldout_reduction": float(self.heldout_reduction),
            **dict(self.extra),
        }


PLANT_CAUSES = {
    "temperature": (
        "; a changed supply temperature or heat loss moves the temperature the same way at "
        "steady state"
    ),
}
"""What else shifts each two-tank output at steady state, for the offset's recommendation.

(The level's other cause, a leak, is told apart from a sensor offset by the diagnosis:
:mod:`twotank_validation.diagnose.level`.)"""


def window_means(windows: Sequence[Window]) -> tuple[np.ndarray, np.ndarray]:
    """Input and output means per window: (n_windows, nu) and (n_windows, ny), model units."""
    return (
        np.array([w.u.mean(axis=0) for w in windows]),
        np.array([w.y.mean(axis=0) for w in windows]),
    )


def dc_gain(nom: Nominal) -> np.ndarray:
    """Steady-state gain of the nominal, (ny, nu): ``D - C A^-1 B`` (``D + C (I - A)^-1 B``).

    Raises:
        DiagnosisError: the nominal has an integrator (no steady state).
    """
    try:
        if nom.dt_s is not None:  # D + C (I - A)^-1 B at z = 1
            eye = np.eye(nom.a.shape[0])
            return np.asarray(nom.d + nom.c @ np.linalg.solve(eye - nom.a, nom.b))
        return np.asarray(nom.d - nom.c @ np.linalg.solve(nom.a, nom.b))
    except np.linalg.LinAlgError as err:
        raise DiagnosisError(
            "the model's nominal has an integrator: its steady state is undefined, so an "
            "output offset cannot be judged on the operating point"
        ) from err


def steady_deviation(
    windows: Sequence[Window],
    nom: Nominal,
    reference: OperatingPoint,
    u_effective: np.ndarray | None = None,
) -> np.ndarray:
    """``d_w = ȳ_w − y_ref − G(0)(ū_w − u_ref)`` per window: (n_windows, ny), model units.

    Args:
        windows: the windows.
        nom: the nominal plant (its DC gain predicts the outputs).
        reference: the reference operating point.
        u_effective: per window the input means to use instead of the measured ones (the
            means of the effective, e.g. clipped, inputs), (n_windows, nu).
    """
    u_bar, y_bar = window_means(windows)
    if u_effective is not None:
        u_bar = np.array(u_effective, dtype=float)
    g0 = dc_gain(nom)
    return np.asarray(y_bar - reference.y - (u_bar - reference.u) @ g0.T)


def resolve_reference(
    windows: Sequence[Window],
    outputs: Sequence[str],
    model_op: Mapping[str, float],
    reference: OperatingPoint | None,
) -> tuple[OperatingPoint | None, str]:
    """The reference operating point and how it was chosen (``None``: none available)."""
    if reference is not None:
        return reference, "relative to the given reference operating point"
    if not all(o in model_op for o in outputs):
        return None, ""
    u_bar, _ = window_means(windows)
    y_ref = np.array([float(model_op[o]) for o in outputs])
    where = ", ".join(f"{o} {model_op[o]:g}" for o in outputs)
    return (
        OperatingPoint(u=u_bar.mean(axis=0), y=y_ref),
        f"relative to the model's operating point ({where}), the recording's mean inputs "
        "taken as those that hold it",
    )


def fit_offsets(  # noqa: PLR0917 - the diagnosis context
    fit_w: Sequence[Window],
    held_w: Sequence[Window],
    nom: Nominal,
    outputs: Sequence[str],
    reference: OperatingPoint,
    noise_dc: np.ndarray,
    cfg: DiagnosisConfig,
    how: str,
    dynamics: str = "its dynamics are unchanged",
    u_effective: np.ndarray | None = None,
) -> tuple[list[Finding], list[tuple[str, float, str]]]:
    """Fit, judge and explain a constant offset on every output (see the module docstring).

    Args:
        fit_w: the fit windows.
        held_w: the held-out windows.
        nom: the nominal plant (with any dynamic effects already added).
        outputs: output names.
        reference: the reference operating point.
        noise_dc: (ny,) the model's noise amplitude at zero frequency (model units).
        cfg: settings (``alpha``, ``min_reduction``, ``param_penalty``).
        how: how the reference was chosen, for the evidence.
        dynamics: what the dynamic diagnosis found, for the evidence.
        u_effective: effective input means of the fit then held-out windows (see
            :func:`steady_deviation`).

    Returns:
        ``(findings, rejected)``: the offsets reported and, for the others, ``(label,
        held-out reduction, why not)``.
    """
    n_fit = len(fit_w)
    eff_fit = None if u_effective is None else u_effective[:n_fit]
    eff_held = None if u_effective is None else u_effective[n_fit:]
    d_fit = steady_deviation(fit_w, nom, reference, eff_fit)
    d_held = steady_deviation(held_w, nom, reference, eff_held)
    d_all = np.vstack([d_fit, d_held])
    n = d_all.shape[0]
    findings: list[Finding] = []
    rejected: list[tuple[str, float, str]] = []
    t_crit = float(scipy.stats.t.ppf(1.0 - cfg.alpha / 2.0, n - 1)) if n >= 2 else math.inf
    for c, out in enumerate(outputs):
        b = float(np.mean(d_fit[:, c]))
        se = float(np.std(d_all[:, c], ddof=1) / math.sqrt(n)) if n >= 2 else math.nan
        s = max(float(noise_dc[c]), 1e-12)
        j0 = float(np.sum((d_held[:, c] / s) ** 2))
        j1 = float(np.sum(((d_held[:, c] - b) / s) ** 2)) * (1.0 + cfg.param_penalty)
        red = 1.0 - j1 / j0 if j0 > 0 else 0.0
        mean_all = float(np.mean(d_all[:, c]))
        same_sign = int(np.sum(np.sign(d_all[:, c]) == np.sign(mean_all)))
        label = f"offset on {out}"
        if abs(mean_all) <= s:
            rejected.append((label, red, (
                f"not needed: the {out} mean is {mean_all:+.3g} from what the inputs predict "
                f"at steady state, within the {s:.3g} the model's noise allows there"
            )))  # fmt: skip
            continue
        if same_sign < n or not abs(mean_all) > t_crit * se:
            rejected.append((label, red, (
                f"not consistent: the {out} steady-state deviation {mean_all:+.3g} ± {se:.2g} "
                f"has the same sign in {same_sign} of {n} windows (all needed, and beyond "
                f"{t_crit:.3g} standard errors)"
            )))  # fmt: skip
            continue
        if red < cfg.min_reduction:
            rejected.append((label, red, (
                f"removes {max(red, 0.0):.0%} of the held-out steady-state deviation (at least "
                f"{cfg.min_reduction:.0%} needed): the deviation is not constant"
            )))  # fmt: skip
            continue
        side = "above" if b > 0 else "below"
        findings.append(
            Finding(
                kind="offset",
                target=out,
                parameters={"offset": b, "offset_std": se},
                evidence=(
                    f"the {out} reads {abs(b):.3g} ± {se:.1g} {side} what the inputs predict at "
                    f"steady state, in all {n} windows ({how}; the model's noise allows "
                    f"{s:.3g}); {dynamics}; the offset removes {red:.0%} of the held-out "
                    f"steady-state deviation"
                ),
                recommendation=(
                    f"recalibrate the {out} sensor (it reads {b:+.3g} off), or correct the "
                    "reference operating point if the plant itself moved"
                    + PLANT_CAUSES.get(out, "")
                ),
                heldout_reduction=red,
            )
        )
    return findings, rejected
