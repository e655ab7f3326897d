"""What a diagnosis takes: windows of whole periods, their fit/held-out split, the settings.

And the error raised on data or a model that cannot be diagnosed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from twotank_validation.core.datum import Datum, NormConvention, make_datum
from twotank_validation.errors import DatumError


class DiagnosisError(DatumError):
    """The data or the model cannot be diagnosed (too few windows, unsupported model)."""


# --------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class DiagnosisConfig:
    """Settings of the diagnosis.

    Attributes:
        min_reduction: fraction of the held-out (penalised) error an effect must remove to be
            added, in (0, 1). The same fraction is required of a second effect, relative to
            the error left by the first.
        material: an error is worth explaining only if its held-out cost is at least this
            multiple of the cost the measurement noise alone would give (estimated from the
            non-harmonic bins next to the excited ones).
        min_second_reduction: a second effect is added only if the pair, fitted jointly,
            removes at least this fraction of the held-out error left by the best single
            effect (a stricter bar than the first: a residual near the noise floor always has
            some structure a spurious second effect can fit).
        parsimony: among candidates that leave at most this multiple of the best one's
            held-out error, the one with the fewest parameters is preferred.
        pair_candidates: pairs are formed with each of this many best single effects first
            (those that remove anything alone).
        param_penalty: relative penalty per fitted parameter on the held-out error (an
            effect with k parameters is judged on ``J (1 + k * param_penalty)``).
        max_effects: at most this many effects are combined (1 or 2).
        excitation_floor: harmonic bins whose input power is below this fraction of the
            largest are not used (they carry noise only), in (0, 1).
        max_time_fraction: delays and time constants are searched up to this fraction of
            the excitation period.
        alpha: level of the residual statistics.
        max_lag: lags of the residual statistics.
        unexplained_factor: after the chosen effects, an output's held-out error is a
            material part left unexplained when it is at least this multiple of what the
            measurement noise alone gives ...
        unexplained_fraction: ... and at least this fraction of its error above the noise
            floor is left, in (0, 1). The factor is above ``material``: a linear model
            of a nonlinear plant leaves an error above the measurement noise at the excited
            bins even when nothing is missing (docs/diagnosis.md, "How much is left").
        confidence: level of the confidence intervals of the fitted parameters, in (0, 1).
        runners_up: how many runner-up candidates (single effects or pairs) are reported.
    """

    min_reduction: float = 0.5
    material: float = 4.0
    min_second_reduction: float = 0.7
    parsimony: float = 1.5
    pair_candidates: int = 3
    param_penalty: float = 0.02
    max_effects: int = 2
    excitation_floor: float = 1e-4
    max_time_fraction: float = 0.25
    alpha: float = 0.01
    max_lag: int = 25
    unexplained_factor: float = 25.0
    unexplained_fraction: float = 0.2
    confidence: float = 0.95
    runners_up: int = 3

    def __post_init__(self) -> None:
        if not 0.0 < self.min_reduction < 1.0:
            raise DiagnosisError(f"min_reduction={self.min_reduction} must be in (0, 1)")
        if self.param_penalty < 0.0:
            raise DiagnosisError(f"param_penalty={self.param_penalty} must be >= 0")
        if self.max_effects not in (0, 1, 2):
            raise DiagnosisError(f"max_effects={self.max_effects} must be 0, 1 or 2")
        if not 0.0 < self.excitation_floor < 1.0:
            raise DiagnosisError(f"excitation_floor={self.excitation_floor} must be in (0, 1)")
        if not self.unexplained_factor > 0.0:
            raise DiagnosisError(f"unexplained_factor={self.unexplained_factor} must be > 0")
        if not 0.0 < self.unexplained_fraction < 1.0:
            raise DiagnosisError(
                f"unexplained_fraction={self.unexplained_fraction} must be in (0, 1)"
            )
        if not 0.0 < self.confidence < 1.0:
            raise DiagnosisError(f"confidence={self.confidence} must be in (0, 1)")
        if self.runners_up < 0:
            raise DiagnosisError(f"runners_up={self.runners_up} must be >= 0")


@dataclass(frozen=True)
class Window:
    """One window of data in model units, whole excitation periods.

    Attributes:
        u: (n_samples, n_inputs) float, inputs.
        y: (n_samples, n_outputs) float, outputs.
        ts_s: sample period, s.
        period_samples: samples per excitation period.
        start_s: time of the first sample (s), for the report.
        measured: (n_inputs,) bool, the inputs logged by a sensor (the interface map's
            ``kind: measured``); None: every input commanded.
    """

    u: np.ndarray
    y: np.ndarray
    ts_s: float
    period_samples: int
    start_s: float = 0.0
    measured: np.ndarray | None = None

    def datum(self, convention: NormConvention | str = NormConvention.POWER) -> Datum:
        """The window's datum, built as the validator builds it (``make_datum``).

        A measured input is averaged over the periods, its noise estimated and its gate
        tolerant of that noise (docs/theory.md, "Measured inputs").

        Raises:
            DatumError: as :func:`~twotank_validation.core.datum.make_datum`.
        """
        return make_datum(
            self.u,
            self.y,
            ts_s=self.ts_s,
            period_samples=self.period_samples,
            convention=convention,
            measured=self.measured,
        )

    @property
    def n_periods(self) -> int:
        """Whole periods in the window."""
        return int(self.u.shape[0] // self.period_samples)

    def periods(self, first: int, count: int) -> Window:
        """The sub-window of ``count`` periods starting at period ``first``."""
        a, b = first * self.period_samples, (first + count) * self.period_samples
        return Window(
            self.u[a:b],
            self.y[a:b],
            self.ts_s,
            self.period_samples,
            self.start_s + a * self.ts_s,
            self.measured,
        )


def split_windows(windows: Sequence[Window]) -> tuple[list[Window], list[Window]]:
    """Fit and held-out windows: the first half (rounded up) fits, the rest judges.

    A single window of P >= 2 periods is split by periods (the first half fits). Windows
    must not overlap (the caller keeps non-overlapping ones).

    Raises:
        DiagnosisError: no window, or a single window of one period (nothing to hold out).
    """
    if not windows:
        raise DiagnosisError(
            "no judged window to diagnose: record at least two whole windows of steady, "
            "excited data (see the validator's data-quality reasons)"
        )
    if len(windows) == 1:
        w = windows[0]
        if w.n_periods < 2:
            raise DiagnosisError(
                "one window of one period: nothing left to judge the fit on; record at least "
                "two periods"
            )
        k = (w.n_periods + 1) // 2
        return [w.periods(0, k)], [w.periods(k, w.n_periods - k)]
    k = (len(windows) + 1) // 2
    return list(windows[:k]), list(windows[k:])
