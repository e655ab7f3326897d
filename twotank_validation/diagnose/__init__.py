"""Close the loop: from the residual of a validation to the effect the model lacks.

Given windows of periodic data (whole excitation periods, as the validator sees them) and a
structured model (nominal state space + perturbations + noise, the YAML of
:mod:`twotank_validation.core.model`), the diagnosis

1. computes the raw error ``E(n) = Y(n) - G(e^{j theta_n}) U(n)`` of the nominal on every
   output at the excited harmonic bins of the period (where the input carries energy),
   scaled per output by the model's own noise weight, so that the outputs are comparable;
2. fits every applicable effect of a catalogue (:data:`EFFECT_KINDS`) -- each a structured
   change of the nominal state space with a few physical parameters -- by nonlinear least
   squares on the scaled error of the *fit* windows;
3. judges each fitted effect on *held-out* windows (never used to fit), with a penalty per
   parameter, keeps the best one when it removes at least ``min_reduction`` of the held-out
   error, and tries a second effect on top when the first leaves enough unexplained;
4. reports, on the held-out windows, the validation beta, the RMS simulation error per output
   and the paper's Section 2.1 residual statistics before and after, with the evidence for
   the chosen effect(s) and why each rejected candidate was rejected; the changed model is a
   YAML document the validator accepts as it is.

The catalogue of effects, with each effect's form and parameters, is described in
:mod:`twotank_validation.diagnose.effects`.

Modules (each imports only those above it):

* :mod:`~twotank_validation.diagnose.inputs`: what a diagnosis takes: :class:`Window` (whole
  periods in model units), :func:`split_windows` (fit / held-out), :class:`DiagnosisConfig`,
  and :class:`DiagnosisError`.
* :mod:`~twotank_validation.diagnose.kinds`: every kind of effect named (:class:`EffectKind`),
  each with one :class:`EffectRecord` (family, parameters, what it needs of the model, what it
  moves, its words); :func:`expected_effect`, the answer that names a simulated rig fault.
* :mod:`~twotank_validation.diagnose.effects`: :class:`Nominal` (the nominal plant of a model
  file), :class:`EffectSpec` and :func:`catalogue` (the candidate effects of a model).
* :mod:`~twotank_validation.diagnose.fit`: :class:`BinData` (the excited bins, step 1), the
  scaled error and :func:`cost`, :func:`fit_effects` (step 2), :func:`fit_uncertainty` (how
  sure the fitted parameters are), :class:`Assessment` and :func:`assess` (a model judged on
  held-out windows).
* :mod:`~twotank_validation.diagnose.evidence`: why the data point at a fitted effect, in words,
  and :func:`evidence_points`, the points, curve and R^2 that the text and figure share.
* :mod:`~twotank_validation.diagnose.steady`: the sensor offset judged on the window means
  against a reference operating point (:class:`Finding`: an effect outside the model file).
* :mod:`~twotank_validation.diagnose.level`: a level that moved at steady state, a leak or a
  sensor offset, told apart by the dynamics of the thermal balance and the time course at
  the change (:class:`~twotank_validation.diagnose.level.LevelVerdict`).
* :mod:`~twotank_validation.diagnose.distortion`: the harmonic-distortion test
  (:func:`distortion_test`) and the input saturation fit, run beside the catalogue.
* :mod:`~twotank_validation.diagnose.diagnosis`: :func:`diagnose` (steps 2-4: selection,
  evidence, the changed document) and its outcome :class:`Diagnosis`.
* :mod:`~twotank_validation.diagnose.stretches`: changes inside a recording: the stationary
  stretches (:func:`find_stretches`), transient windows skipped, and each stretch diagnosed
  against the model and against the stretch before (:func:`diagnose_stretches`).
* :mod:`~twotank_validation.diagnose.live_jobs`: the catalogue behind the live diagnosis
  (:func:`~twotank_validation.diagnose.live_jobs.catalogue_diagnosis`): the windows after an
  alarm's onset against those before it, and the most likely effect named.

Bags are not read here: :func:`twotank_validation.replay.windows_from_bag` gives the judged
windows of a recorded bag.

Everything here is ROS-free and works on numpy arrays. scipy.optimize.least_squares does the
fitting; the catalogue and the selection rule are this package's own (no library does
model-structure diagnosis of LFT models).
"""

from twotank_validation.diagnose.diagnosis import (
    Diagnosis,
    Explained,
    FittedEffect,
    RunnerUp,
    changed_document,
    diagnose,
)
from twotank_validation.diagnose.distortion import DistortionTest, distortion_test
from twotank_validation.diagnose.effects import (
    THERMAL_STATES,
    EffectSpec,
    Nominal,
    catalogue,
    channel_time_constants,
)
from twotank_validation.diagnose.evidence import EvidencePoints, evidence_points
from twotank_validation.diagnose.fit import (
    Assessment,
    BinData,
    Uncertainty,
    assess,
    bin_data,
    cost,
    excited_bins,
    fit_effects,
    fit_uncertainty,
    noise_floor,
    noise_scale,
    output_costs,
    output_noise_floors,
    scaled_error,
)
from twotank_validation.diagnose.inputs import (
    DiagnosisConfig,
    DiagnosisError,
    Window,
    split_windows,
)
from twotank_validation.diagnose.kinds import (
    EFFECT_KINDS,
    EFFECT_RECORDS,
    REPORTED_KINDS,
    ActsOn,
    EffectFamily,
    EffectKind,
    EffectRecord,
    ModelNeed,
    expected_effect,
    named,
)
from twotank_validation.diagnose.level import LevelVerdict
from twotank_validation.diagnose.steady import Finding
from twotank_validation.diagnose.stretches import (
    ChangeConfig,
    RecordingDiagnosis,
    Stretch,
    StretchDiagnosis,
    WindowFindings,
    diagnose_stretches,
    find_stretches,
)

__all__ = [
    "EFFECT_KINDS",
    "EFFECT_RECORDS",
    "REPORTED_KINDS",
    "THERMAL_STATES",
    "ActsOn",
    "Assessment",
    "BinData",
    "ChangeConfig",
    "Diagnosis",
    "DiagnosisConfig",
    "DiagnosisError",
    "DistortionTest",
    "EffectFamily",
    "EffectKind",
    "EffectRecord",
    "EffectSpec",
    "EvidencePoints",
    "Explained",
    "Finding",
    "FittedEffect",
    "LevelVerdict",
    "ModelNeed",
    "Nominal",
    "RecordingDiagnosis",
    "RunnerUp",
    "Stretch",
    "StretchDiagnosis",
    "Uncertainty",
    "Window",
    "WindowFindings",
    "assess",
    "bin_data",
    "catalogue",
    "changed_document",
    "channel_time_constants",
    "cost",
    "diagnose",
    "diagnose_stretches",
    "distortion_test",
    "evidence_points",
    "excited_bins",
    "expected_effect",
    "find_stretches",
    "fit_effects",
    "fit_uncertainty",
    "named",
    "noise_floor",
    "noise_scale",
    "output_costs",
    "output_noise_floors",
    "scaled_error",
    "split_windows",
]
