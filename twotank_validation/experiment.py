"""The paper's experiment (Smith 1995, Sec. 4) reproduced on the simulated rig.

A periodic excitation drives both valves around h1 = 0.47, t1 = 0.5; after the settling
periods, whole periods of commands and measured outputs form the datum; each model is
validated and, side by side, the probabilistic residual tests of the paper's Section 2.1 run
on the same data.

Defaults (chosen so that the rig stays plausible and the paper's qualitative result shows;
see docs/demo.md): the rig's unmodeled mixing is a 15 s transport delay on
the measured temperature at h1 = 0.47, growing with level; sensor noise 0.003 (level) and
0.01 (temperature) RMS, below the noise weights 0.01 and 0.03; the excitation is periodic
low-pass (0.006 Hz) filtered noise of 0.05 RMS on the hot valve and 0.2 RMS on the cold valve
(the cold valve moves the level, which is what Model A ignores in the temperature).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from twotank_validation.core import stats
from twotank_validation.core.datum import Datum, NormConvention, make_datum
from twotank_validation.core.model import LFTModel, load_model, load_model_document
from twotank_validation.core.validate import ValidationResult, inverse_dft, validate
from twotank_validation.defaults import Method
from twotank_validation.diagnose import Diagnosis, Window, diagnose
from twotank_validation.sim import excitation, rig, simulator
from twotank_validation.sim.faults import Fault


def _default_rig() -> rig.RigParams:
    return rig.RigParams(mixing_delay_s=15.0, noise_std_height=0.003, noise_std_temperature=0.01)


def _default_excitation() -> excitation.ExcitationConfig:
    return excitation.ExcitationConfig(
        kind="filtered_noise", rms=(0.05, 0.2), cutoff_hz=0.006, seed=2
    )


@dataclass(frozen=True)
class ExperimentConfig:
    """Settings of the simulated experiment.

    Attributes:
        rig: rig parameters, including its unmodeled mixing delay and sensor noise.
        excitation: periodic excitation (period, settling and recorded periods, seed).
        height: operating level (model units).
        temperature: operating temperature (model units).
        convention: norm convention of ||w||.
        models: model names or YAML paths to validate.
        max_lag: lags of the probabilistic residual tests.
        alpha: level of the probabilistic residual tests.
        seed: sensor-noise seed of the simulator.
        faults: faults and undeclared effects switched on during the run (``faults.Fault``).
    """

    rig: rig.RigParams = field(default_factory=_default_rig)
    excitation: excitation.ExcitationConfig = field(default_factory=_default_excitation)
    height: float = 0.47
    temperature: float = 0.5
    convention: NormConvention = NormConvention.POWER
    models: tuple[str, ...] = ("A", "B")
    max_lag: int = 25
    alpha: float = 0.01
    seed: int = 0
    faults: tuple[Fault, ...] = ()


@dataclass(frozen=True)
class ModelOutcome:
    """One model against the datum.

    Attributes:
        validation: deterministic (worst-case) validation.
        sdp_check: the general SDP solver on the same datum, if it was run.
        residual: (n_samples, n_outputs) float, measured minus the nominal model's periodic
            steady-state output (model units).
        residual_tests: whiteness and input cross-correlation tests on ``residual``.
    """

    validation: ValidationResult
    sdp_check: ValidationResult | None
    residual: np.ndarray
    residual_tests: stats.ResidualTests

    @property
    def rms_error(self) -> np.ndarray:
        """(n_outputs,) float, RMS simulation error per output (model units)."""
        return np.sqrt(np.mean(self.residual**2, axis=0))


@dataclass(frozen=True)
class ExperimentResult:
    """The datum and every model's outcome.

    Attributes:
        config: the settings.
        time_s: (n_samples,) float, time of each recorded sample (s).
        u: (n_samples, 2) float, recorded valve commands (model units).
        y: (n_samples, 2) float, recorded level and temperature (model units).
        height_range: (min, max) level over the whole run, settling included.
        datum: the transformed datum.
        outcomes: per model name.
    """

    config: ExperimentConfig
    time_s: np.ndarray
    u: np.ndarray
    y: np.ndarray
    height_range: tuple[float, float]
    datum: Datum
    outcomes: Mapping[str, ModelOutcome]


def nominal_residual(result: ValidationResult) -> np.ndarray:
    """(n_samples, ny) time-domain output error of the nominal model, by inverse DFT of E(n)."""
    return inverse_dft(result.error, result.n_samples, result.convention)


def simulate_datum(
    config: ExperimentConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[float, float]]:
    """Run the rig through settling and recorded periods.

    Returns:
        ``(time_s, u, y, height_range)`` for the recorded periods: (n,), (n, 2), (n, 2).
    """
    op = rig.operating_point(config.rig, config.height, config.temperature)
    commands = excitation.excitation_commands(config.excitation, op.commands)
    sim = simulator.simulate(
        config.rig, commands, config.excitation.ts_s, op=op, seed=config.seed, faults=config.faults
    )
    rec = excitation.record_slice(config.excitation)
    levels = sim.states[:, 2]
    return (
        sim.time_s[rec],
        sim.commands[rec],
        sim.measured[rec],
        (float(levels.min()), float(levels.max())),
    )


def run_experiment(
    config: ExperimentConfig | None = None,
    *,
    sdp_check: bool = False,
    progress: Callable[[str, int], Callable[[int], None]] | None = None,
) -> ExperimentResult:
    """Simulate the rig, build the datum and validate every model.

    Args:
        config: settings (defaults: :class:`ExperimentConfig`).
        sdp_check: also run the general SDP solver on every bin, to compare.
        progress: factory ``(label, total) -> callback`` for per-bin progress of the SDP.
    """
    config = config or ExperimentConfig()
    time_s, u, y, h_range = simulate_datum(config)
    datum = make_datum(
        u,
        y,
        ts_s=config.excitation.ts_s,
        period_samples=config.excitation.period_samples,
        convention=config.convention,
    )
    outcomes: dict[str, ModelOutcome] = {}
    for name in config.models:
        model: LFTModel = load_model(name)
        resp = model.response(datum.theta, datum.ts_s)
        result = validate(datum, model, response=resp)
        check = None
        if sdp_check:
            cb = progress(f"SDP model {model.name}", datum.theta.size) if progress else None
            check = validate(datum, model, method=Method.SDP, response=resp, progress=cb)
        residual = nominal_residual(result)
        tests = stats.residual_tests(
            residual,
            u,
            output_names=list(model.output_names),
            input_names=list(model.input_names),
            max_lag=config.max_lag,
            alpha=config.alpha,
        )
        outcomes[model.name] = ModelOutcome(result, check, residual, tests)
    return ExperimentResult(config, time_s, u, y, h_range, datum, outcomes)


def diagnosis_windows(config: ExperimentConfig, n_windows: int = 4) -> list[Window]:
    """The experiment run for ``2 n_windows`` recorded periods, cut into two-period windows.

    The first window is the demo's datum (same seeds, same settling); the others continue
    the run, so the diagnosis can fit on some windows and judge on the rest.
    """
    exc = replace(config.excitation, record_periods=2 * n_windows)
    time_s, u, y, _ = simulate_datum(replace(config, excitation=exc))
    n = 2 * exc.period_samples
    return [
        Window(u[i * n : (i + 1) * n], y[i * n : (i + 1) * n], exc.ts_s, exc.period_samples,
               float(time_s[i * n]))
        for i in range(n_windows)
    ]  # fmt: skip


def run_diagnosis(
    config: ExperimentConfig | None = None, model: str = "B", n_windows: int = 4
) -> Diagnosis:
    """Diagnose ``model`` on the experiment: the demo finds the rig's mixing delay in B."""
    config = config or ExperimentConfig()
    doc, source = load_model_document(model)
    return diagnose(
        diagnosis_windows(config, n_windows), doc, source=source, convention=config.convention
    )
