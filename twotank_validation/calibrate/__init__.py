"""How much uncertainty the data demand of a model set, handed on to robust-control design.

:func:`calibrate` takes the judged windows of a recording and a model document and says, for
each chosen perturbation or noise block, the smallest factor on its stated weight for which
no window is invalidated (the block alone, the others as stated), the smallest weight
magnitude each excited bin requires, and a fitted low-order weight covering that requirement
with a margin, written into a new model file judged on held-out windows (docs/calibrate.md).

Modules (each imports only those above it):

* :mod:`~twotank_validation.calibrate.scaling`: the blocks of a model, the uniform scaling
  per window and the per-bin requirement, with the window solver; :class:`CalibrationError`.
* :mod:`~twotank_validation.calibrate.joint`: several blocks scaled together (a common factor,
  and the smallest set of per-block factors that explains every window).
* :mod:`~twotank_validation.calibrate.weightfit`: the stable, minimum-phase weight fit.
* :mod:`~twotank_validation.calibrate.calibration`: :func:`calibrate` and its result.
* :mod:`~twotank_validation.calibrate.noise`: :func:`noise_from_data`, the noise weights set
  from the period-to-period spread, the output channels sharing the one unit-norm ``w``.
* :mod:`~twotank_validation.calibrate.recording`: :func:`calibrate_recording` (a bag or table
  read through the replay path) and the report (text and figures).
"""

from __future__ import annotations

from twotank_validation.calibrate.calibration import (
    NO_WEIGHT_CHANGED,
    BlockCalibration,
    Calibration,
    CalibrationConfig,
    Judged,
    calibrate,
    model_of,
)
from twotank_validation.calibrate.joint import JointScaling, common_scaling, joint_scaling
from twotank_validation.calibrate.noise import (
    NoiseCalibration,
    noise_document,
    noise_from_data,
    noise_model_of,
)
from twotank_validation.calibrate.recording import (
    calibrate_recording,
    calibration_text,
    write_calibration_report,
)
from twotank_validation.calibrate.scaling import (
    BinRequirement,
    Block,
    CalibrationError,
    WindowProblem,
    bin_requirement,
    choose_blocks,
    model_blocks,
    window_scaling,
)
from twotank_validation.calibrate.weightfit import FittedWeight, fit_weight

__all__ = [
    "NO_WEIGHT_CHANGED",
    "BinRequirement",
    "Block",
    "BlockCalibration",
    "Calibration",
    "CalibrationConfig",
    "CalibrationError",
    "FittedWeight",
    "JointScaling",
    "Judged",
    "NoiseCalibration",
    "WindowProblem",
    "bin_requirement",
    "calibrate",
    "calibrate_recording",
    "calibration_text",
    "choose_blocks",
    "common_scaling",
    "fit_weight",
    "joint_scaling",
    "model_blocks",
    "model_of",
    "noise_document",
    "noise_from_data",
    "noise_model_of",
    "window_scaling",
    "write_calibration_report",
]
