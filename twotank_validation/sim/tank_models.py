"""The paper's two candidate models, derived from the rig simulator by linearisation.

Model A (decoupled) and Model B (MIMO linearisation) share the uncertainty description of
Smith (1995, Sec. 3.4): an output-multiplicative scalar perturbation on each output and
weighted additive sensor noise. The nominal plants come from :mod:`twotank_validation.sim.rig`
(Jacobians of the same right-hand side the simulator integrates). The YAML files shipped in
``twotank_validation/models/`` are written by ``scripts/make_models.py`` from
:func:`model_document`; a test keeps them and this derivation consistent.

Weights (paper readings, see ``../shared/paper/NOTES.md``):

* ``W_Delta,h1 = 0.05 / (1 + 0.25 s)``: the OCR shows 0.5, but the text calls the weight
  "extremely small", "barely discernible" -- a leading 0 was lost.
* ``W_Delta,t1 = (0.1 + 16.5 s) / (1 + 20 s)``.
* ``W_n,h1 = 0.01``, ``W_n,t1 = 0.03`` (legible).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from twotank_validation.core.model import LFTModel, model_from_dict
from twotank_validation.errors import ModelError
from twotank_validation.sim import rig
from twotank_validation.sim.linearise import linearise_model_a, linearise_model_b

HEIGHT_PERTURBATION_WEIGHT = {"tf": {"num": [0.05], "den": [0.25, 1.0]}}
TEMPERATURE_PERTURBATION_WEIGHT = {"tf": {"num": [16.5, 0.1], "den": [20.0, 1.0]}}
HEIGHT_NOISE_WEIGHT = 0.01
TEMPERATURE_NOISE_WEIGHT = 0.03

_DESCRIPTIONS = {
    "A": (
        "Smith (1995) Model A: decoupled. Level 1.34/(1+122.5 s)(f_h+f_c), temperature "
        "1.25/(1+53.8 s) f_h (energy balance with the level held at its operating value); "
        "valve lags 1/(1+0.05 s). Output-multiplicative perturbation and sensor noise on "
        "each output."
    ),
    "B": (
        "Smith (1995) Model B: full MIMO Jacobian of the nonlinear tank model (mass and "
        "energy balances, outlet law, valve lags) at h1=0.47, t1=0.5; includes the "
        "level-to-temperature coupling. Same uncertainty as Model A."
    ),
}


def _round(m: np.ndarray) -> list[list[float]]:
    return [[float(f"{x:.12g}") for x in row] for row in np.atleast_2d(m)]


def model_document(which: str, params: rig.RigParams | None = None) -> dict[str, Any]:
    """YAML document of Model A or B, derived from the rig at the paper's operating point.

    Args:
        which: ``"A"`` or ``"B"``.
        params: rig parameters (default: the paper's).

    Raises:
        ModelError: unknown model name.
    """
    params = params or rig.RigParams()
    op = rig.operating_point(params)
    if which == "A":
        lin = linearise_model_a(params, op)
    elif which == "B":
        lin = linearise_model_b(params, op)
    else:
        raise ModelError(f"unknown tank model {which!r}: use 'A' or 'B'")
    return {
        "name": which,
        "description": _DESCRIPTIONS[which],
        "derivation": (
            f"linearise_model_{which.lower()}(RigParams(), operating_point(h1=0.47, t1=0.5)); "
            f"states {list(lin.state_names)}; written by scripts/make_models.py"
        ),
        "inputs": list(lin.input_names),
        "outputs": list(lin.output_names),
        "operating_point": {"height": op.height, "temperature": op.temperature},
        "nominal": {
            "ss": {
                "A": _round(lin.a),
                "B": _round(lin.b),
                "C": _round(lin.c),
                "D": _round(lin.d),
                "states": list(lin.state_names),
            }
        },
        "perturbations": [
            {
                "name": "height_multiplicative",
                "kind": "output_multiplicative",
                "outputs": ["height"],
                "weight": HEIGHT_PERTURBATION_WEIGHT,
            },
            {
                "name": "temperature_multiplicative",
                "kind": "output_multiplicative",
                "outputs": ["temperature"],
                "weight": TEMPERATURE_PERTURBATION_WEIGHT,
            },
        ],
        "noise": [
            {
                "name": "height_noise",
                "outputs": ["height"],
                "weight": {"gain": HEIGHT_NOISE_WEIGHT},
            },
            {
                "name": "temperature_noise",
                "outputs": ["temperature"],
                "weight": {"gain": TEMPERATURE_NOISE_WEIGHT},
            },
        ],
    }


def derived_model(which: str, params: rig.RigParams | None = None) -> LFTModel:
    """Model A or B built directly from the derivation (no YAML file involved)."""
    return model_from_dict(model_document(which, params), source=f"derived model {which}")
