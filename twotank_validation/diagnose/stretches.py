"""Changes inside a recording: where the plant changed, transients, each stretch diagnosed.

A recording may hold more than one plant: a fault that starts in the middle, a leak whose
level is still settling in the first windows. A diagnosis fitted across such a change blends
two plants into one wrong answer. Here the judged windows are

1. summarised, window by window, by a few *features* (:func:`window_features`): the
   validation beta of the model; per output the scaled residual energy at the excited bins
   (``log10 mean |E(n)/scale|^2``), the residual's group delay (the phase slope of
   ``Y_c / (G U)_c`` between neighbouring harmonics, s) and its mean log gain; and the
   operating point: each output's mean minus what the model's DC gain predicts from the
   input means (a sensor bias or a leak shows there even when the dynamics do not change);
2. checked for a transient (:attr:`WindowFeatures.transient`, :func:`find_stretches`): the
   validator's finding (the output mean drifts across the window, its period-to-period
   variation decays) and, after the
   segmentation, a window at the start of a stretch whose operating point has not yet
   reached the stretch's steady level. Those windows are *skipped*, and said so (the
   transient is not modelled);
3. segmented (:func:`segment`) by binary segmentation with a likelihood-ratio test for a
   shift of the feature means, each feature standardised by its window-to-window noise;
4. diagnosed stretch by stretch (:func:`diagnose_stretches`) with
   :func:`~twotank_validation.diagnose.diagnosis.diagnose`: relative to the model, and relative
   to the stretch before it (the model *with the effects found in the previous stretch*; when
   that stretch needed nothing, both answers are the same).

Why a hand-written test: no change-point library is installed in the project's environment
(``ruptures`` is not available), and the problem is small (tens of windows, ~10 features
whose noise is known from the data). The test is the textbook one for a mean shift of
independent Gaussian vectors with known variance (e.g. Basseville & Nikiforov, *Detection of
Abrupt Changes*, 1993, Sec. 2.2): for a split of ``m`` windows after ``k``, the statistic
``S_k = k (m - k) / m * sum_f ((mean_left_f - mean_right_f) / sigma_f)^2`` is chi-square with
``d`` (features) degrees of freedom when nothing changed; the largest over the ``m - 1``
splits is compared with the chi-square quantile at ``alpha / (m - 1)`` (Bonferroni), so that a
stationary recording raises a false change with probability at most ``alpha``. Each feature's
``sigma`` is the robust (median absolute deviation) estimate from the differences of
consecutive windows, which a few changes do not inflate, and never below a floor
(:class:`ChangeConfig`) that makes a change too small to matter invisible however quiet the
data. Binary segmentation applies the same test again on both sides of each change found.

Everything here is ROS-free and works on :class:`~twotank_validation.diagnose.inputs.Window`
arrays; :func:`twotank_validation.replay.windows_with_findings` gives the windows of a bag
with what the validator found in each.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.stats

from twotank_validation.core.datum import NormConvention
from twotank_validation.core.model import model_from_dict
from twotank_validation.core.oppoint import OperatingPoint
from twotank_validation.core.validate import validate
from twotank_validation.diagnose.diagnosis import Diagnosis, diagnose
from twotank_validation.diagnose.effects import Nominal
from twotank_validation.diagnose.fit import bin_data, scaled_error
from twotank_validation.diagnose.inputs import DiagnosisConfig, DiagnosisError, Window
from twotank_validation.diagnose.level import LEVEL, level_course

TRANSIENT_WORDS = ("transient", "drifts")
"""Words of the validator's findings (``WindowReport.warnings``) that mark a transient."""


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class ChangeConfig:
    """Settings of the change-point search and of the transient test.

    Attributes:
        alpha: probability of a false change in a stationary recording (Bonferroni over the
            splits of each segment), in (0, 1).
        beta_floor: smallest noise assumed for the window beta.
        energy_floor: the same for the log10 residual energy (0.1: a 26 % change of the
            residual power is noise).
        delay_floor_s: the same for the residual group delay (s).
        gain_floor: the same for the mean log gain of the residual ratio.
        level_floor: the same for the operating point (model units; the validator's drift
            allowance of the operating-point check).
        settle_sigmas: a window at the start of a stretch whose operating point differs from
            the stretch's steady level by more than this many noise units (and at least
            ``level_floor``) is still settling.
    """

    alpha: float = 1e-3
    beta_floor: float = 0.02
    energy_floor: float = 0.1
    delay_floor_s: float = 0.5
    gain_floor: float = 0.01
    level_floor: float = 0.002
    settle_sigmas: float = 5.0

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha < 1.0:
            raise DiagnosisError(f"alpha={self.alpha} must be in (0, 1)")
        floors = (
            self.beta_floor,
            self.energy_floor,
            self.delay_floor_s,
            self.gain_floor,
            self.level_floor,
        )
        if min(floors) <= 0.0 or self.settle_sigmas <= 0.0:
            raise DiagnosisError("the noise floors and settle_sigmas must be > 0")


# --------------------------------------------------------------------------- per window


@dataclass(frozen=True)
class WindowFindings:
    """What the validator found in a window (from its ``WindowReport``), handed along.

    Attributes:
        beta: the window's validation beta (NaN: not known, computed here).
        beta_op: the operating point's beta (NaN where not checked).
        data_quality: the validator's data-quality text (``"ok..."`` for a judged window).
        warnings: the validator's warnings (a transient still decaying, ...).
    """

    beta: float = math.nan
    beta_op: float = math.nan
    data_quality: str = "ok"
    warnings: tuple[str, ...] = ()

    @property
    def transient(self) -> str:
        """The validator's transient finding in its words, or ``""``."""
        hits = [w for w in self.warnings if any(k in w for k in TRANSIENT_WORDS)]
        return "; ".join(hits)


@dataclass(frozen=True)
class WindowFeatures:
    """The features of one window (see the module docstring).

    Attributes:
        start_s, end_s: window time span (s from the recording start).
        beta: validation beta of the model.
        beta_op: the operating point's beta from the validator (NaN: not known).
        energy: (ny,) log10 of the mean scaled residual power at the excited bins.
        delay_s: (ny,) group delay of the residual ratio ``Y_c / (G U)_c`` (s; 0 when the
            model's phase is right).
        log_gain: (ny,) weighted mean of ``log |Y_c / (G U)_c|``.
        level: (ny,) output means minus the model's DC gain times the input means (model
            units).
        transient: why the window carries a transient (the validator's finding or the
            periodicity test of its datum), or ``""``.
        drift: (ny,) output mean of the window's last period minus its first's (model
            units; 0 for a window of one period).
    """

    start_s: float
    end_s: float
    beta: float
    beta_op: float
    energy: np.ndarray
    delay_s: np.ndarray
    log_gain: np.ndarray
    level: np.ndarray
    transient: str = ""
    drift: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def vector(self) -> np.ndarray:
        """(1 + 4 ny,) float: beta, energy, delay, log gain, level (the segmented features)."""
        return np.concatenate([[self.beta], self.energy, self.delay_s, self.log_gain, self.level])


def feature_floors(ny: int, config: ChangeConfig) -> np.ndarray:
    """(1 + 4 ny,) float: the noise floor of each feature of :meth:`WindowFeatures.vector`."""
    c = config
    per = [c.energy_floor, c.delay_floor_s, c.gain_floor, c.level_floor]
    return np.array([c.beta_floor, *[f for f in per for _ in range(ny)]])


def feature_names(outputs: Sequence[str]) -> list[str]:
    """Names of the features of :meth:`WindowFeatures.vector`, for the evidence."""
    kinds = ("residual energy (log10)", "residual delay (s)", "residual log gain", "level")
    return ["beta", *[f"{o} {k}" for k in kinds for o in outputs]]


def window_features(
    windows: Sequence[Window],
    doc: Mapping[str, Any],
    findings: Sequence[WindowFindings] | None = None,
    *,
    source: str = "model",
    convention: NormConvention = NormConvention.POWER,
    excitation_floor: float = 1e-4,
) -> list[WindowFeatures]:
    """The features of each window (see the module docstring).

    Args:
        windows: judged windows in time order.
        doc: the model document.
        findings: what the validator found in each window (same order), or None: beta and
            the transient test are computed here from the window's datum.
        source: label of the model in messages.
        convention: norm convention of the validations.
        excitation_floor: as :attr:`DiagnosisConfig.excitation_floor`.

    Raises:
        DiagnosisError: findings of another length, or a window without excitation.
    """
    if findings is not None and len(findings) != len(windows):
        raise DiagnosisError(
            f"{len(findings)} findings for {len(windows)} windows: give one per window"
        )
    model = model_from_dict(doc, source)
    nominal = Nominal.from_document(doc, source)
    g0 = nominal.hold_response(np.zeros(1), 1.0)[0].real  # (ny, nu) DC gain
    out = []
    for i, w in enumerate(windows):
        datum = w.datum(convention)
        found = findings[i] if findings is not None else WindowFindings()
        beta = found.beta if math.isfinite(found.beta) else float(validate(datum, model).beta)
        if findings is not None:
            transient = found.transient
        else:
            transient = "; ".join(
                m for m in datum.periodicity.messages if any(k in m for k in TRANSIENT_WORDS)
            )
        data = bin_data([datum], model, excitation_floor)
        if data.theta.size < 2:
            raise DiagnosisError(
                f"the window at {w.start_s:.1f} s carries no excitation at the harmonics of the "
                "period: its residual cannot be compared with the other windows'"
            )
        e = scaled_error(nominal, data, w.ts_s)
        gu = np.einsum("kij,kj->ki", nominal.hold_response(data.theta, w.ts_s), data.u)
        weight = np.abs(gu) ** 2 / data.scale**2  # (k, ny)
        ok = np.abs(gu) > 0
        ratio = np.where(ok, data.y / np.where(ok, gu, 1.0), 1.0)
        # group delay: the phase step between neighbouring harmonics, weighted; no unwrapping
        # (a delay below half the period steps by less than pi per harmonic)
        step = 2.0 * math.pi / (w.period_samples * w.ts_s)  # rad/s between harmonics
        pair = np.isclose(np.diff(data.theta) / w.ts_s, step, rtol=1e-6)
        z = np.sum(
            (ratio[1:] * np.conj(ratio[:-1]) * np.sqrt(weight[1:] * weight[:-1]))[pair], axis=0
        )
        delay = -np.angle(z) / step
        log_gain = np.sum(weight * np.log(np.maximum(np.abs(ratio), 1e-12)), axis=0) / np.maximum(
            np.sum(weight, axis=0), 1e-300
        )
        level = w.y.mean(axis=0) - g0 @ w.u.mean(axis=0)
        out.append(
            WindowFeatures(
                start_s=w.start_s,
                end_s=w.start_s + w.u.shape[0] * w.ts_s,
                beta=beta,
                beta_op=found.beta_op,
                energy=np.log10(np.maximum(np.mean(np.abs(e) ** 2, axis=0), 1e-300)),
                delay_s=delay,
                log_gain=log_gain,
                level=level,
                transient=transient,
                drift=w.y[-w.period_samples :].mean(axis=0) - w.y[: w.period_samples].mean(axis=0),
            )
        )
    return out


# --------------------------------------------------------------------------- segmentation


def feature_noise(
    x: np.ndarray, floors: np.ndarray, adjacent: np.ndarray | None = None
) -> np.ndarray:
    """(d,) float: each feature's window-to-window noise, never below its floor.

    The median absolute deviation of the differences of consecutive windows, over
    ``0.6745 sqrt(2)`` (a Gaussian's standard deviation): a few changes among the
    differences do not inflate it. Fewer than two differences: the floors.

    Args:
        x: (n_windows, d) float, features in time order.
        floors: (d,) float.
        adjacent: (n_windows - 1,) bool, which consecutive windows follow each other
            directly; None: all. A difference across a transient window (skipped between
            two steady ones: the plant moved there) is not noise and is left out.
    """
    d = np.diff(x, axis=0)
    if adjacent is not None:
        d = d[np.asarray(adjacent, dtype=bool)]
    if d.shape[0] < 2:
        return floors.copy()
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0) / (0.6745 * math.sqrt(2.0))
    return np.maximum(mad, floors)


def split_statistic(x: np.ndarray, sigma: np.ndarray) -> tuple[int, float]:
    """The best split of a segment and its likelihood-ratio statistic.

    Args:
        x: (m, d) float, the segment's features; m >= 2.
        sigma: (d,) float, their noise.

    Returns:
        ``(k, S_k)``: the segment splits after its first ``k`` windows (1 <= k < m), where
        ``S_k = k (m - k) / m * sum_f ((mean(x[:k]) - mean(x[k:])) / sigma)^2`` is largest.
    """
    m = x.shape[0]
    z = x / sigma
    c = np.cumsum(z, axis=0)
    total = c[-1]
    k = np.arange(1, m)
    left = c[:-1] / k[:, None]
    right = (total[None, :] - c[:-1]) / (m - k)[:, None]
    s = k * (m - k) / m * np.sum((left - right) ** 2, axis=1)
    best = int(np.argmax(s))
    return best + 1, float(s[best])


def change_threshold(m: int, d: int, alpha: float) -> float:
    """The statistic above which a segment of ``m`` windows and ``d`` features has changed."""
    return float(scipy.stats.chi2.isf(alpha / max(m - 1, 1), d))


def segment(x: np.ndarray, sigma: np.ndarray, alpha: float) -> list[int]:
    """Binary segmentation: the indices where a new segment starts (sorted, without 0).

    Args:
        x: (n, d) float, features in time order.
        sigma: (d,) float, their noise (:func:`feature_noise`).
        alpha: false-change probability of each test.
    """
    cuts: list[int] = []
    todo = [(0, x.shape[0])]
    while todo:
        a, b = todo.pop()
        if b - a < 2:
            continue
        k, s = split_statistic(x[a:b], sigma)
        if s > change_threshold(b - a, x.shape[1], alpha):
            cuts.append(a + k)
            todo += [(a, a + k), (a + k, b)]
    return sorted(cuts)


def differs(x: np.ndarray, y: np.ndarray, sigma: np.ndarray, alpha: float) -> bool:
    """Whether two groups of windows' features differ (the test of :func:`segment`)."""
    both = np.vstack([x, y])
    m, k = both.shape[0], x.shape[0]
    s = k * (m - k) / m * float(np.sum(((x.mean(0) - y.mean(0)) / sigma) ** 2))
    return s > change_threshold(m, both.shape[1], alpha)


# --------------------------------------------------------------------------- stretches


@dataclass(frozen=True)
class Stretch:
    """A stationary stretch of the recording.

    Attributes:
        windows: indices (into the windows given) of the steady windows, diagnosed.
        skipped: ``(index, why)`` of windows in the stretch that are not diagnosed (a
            transient, the window holding the change).
        start_s, end_s: time span (s) from the first window (skipped or not) to the last.
        change_at_s: start (s) of the first window holding changed data (the change lies in
            that window, or at the latest at its end); None for the first stretch. A
            transient in the first windows is skipped but is not a change: the response to
            the excitation's own start looks the same as a plant that changed just before
            the recording (what such a plant does after it settled is the diagnosis's job).
        evidence: what changed, in words (empty for the first stretch).
    """

    windows: list[int]
    skipped: list[tuple[int, str]]
    start_s: float
    end_s: float
    change_at_s: float | None
    evidence: str = ""


def find_stretches(
    features: Sequence[WindowFeatures],
    outputs: Sequence[str],
    config: ChangeConfig | None = None,
    *,
    split: bool = True,
) -> list[Stretch]:
    """Split the windows into stationary stretches and mark the windows to skip.

    Windows with a transient (:attr:`WindowFeatures.transient`) are left out of the
    segmentation; each belongs to the stretch after it. A single window between two changes
    holds the change (its features lie between its neighbours'): it is skipped. The first
    windows of a stretch whose level has not settled to the stretch's steady level are
    skipped too.

    Args:
        features: per window, in time order.
        outputs: output names (for the evidence).
        config: thresholds.
        split: segment (False: one stretch, only the transient windows skipped).
    """
    cfg = config or ChangeConfig()
    n = len(features)
    if n == 0:
        return []
    ny = len(outputs)
    x = np.array([f.vector() for f in features])
    steady = [i for i, f in enumerate(features) if not f.transient]
    adjacent = np.diff(steady) == 1  # no transient window between them
    sigma = feature_noise(x[steady], feature_floors(ny, cfg), adjacent) if steady else None
    groups: list[list[int]] = [steady] if steady else []
    if split and sigma is not None and len(steady) >= 2:
        cuts = segment(x[steady], sigma, cfg.alpha)
        bounds = [0, *cuts, len(steady)]
        groups = [steady[a:b] for a, b in itertools.pairwise(bounds)]
        groups = _merge_middle_windows(groups, x, sigma, cfg.alpha)
    skipped: dict[int, str] = {
        i: f"transient: {f.transient}" for i, f in enumerate(features) if f.transient
    }
    # windows that hold a change (single windows between two stretches) come marked -i - 1
    for g in list(groups):
        for i in [i for i in g if i < 0]:
            g.remove(i)
            skipped[-i - 1] = (
                "holds the change: its features lie between those of the stretches around it"
            )
    groups = [g for g in groups if g]
    stretches = []
    prev_last = -1
    for k, g in enumerate(groups):
        last = g[-1] if k < len(groups) - 1 else n - 1
        members = list(range(prev_last + 1, last + 1))
        used = [i for i in members if i in g]
        used = _settled(used, x, sigma, ny=ny, cfg=cfg, skipped=skipped)
        skip = [(i, skipped[i]) for i in members if i in skipped]
        first = members[0]
        change_at = None
        evidence = ""
        if k > 0 and sigma is not None:
            change_at = features[first].start_s
            evidence = _evidence(x[groups[k - 1]], x[used or g], sigma, outputs)
        stretches.append(
            Stretch(
                windows=used,
                skipped=skip,
                start_s=features[first].start_s,
                end_s=features[members[-1]].end_s,
                change_at_s=change_at,
                evidence=evidence,
            )
        )
        prev_last = last
    if not groups:  # every window carries a transient
        stretches.append(
            Stretch(
                windows=[],
                skipped=sorted(skipped.items()),
                start_s=features[0].start_s,
                end_s=features[-1].end_s,
                change_at_s=features[0].start_s,
                evidence="every window carries a transient: the plant never settled",
            )
        )
    return stretches


def _merge_middle_windows(
    groups: list[list[int]], x: np.ndarray, sigma: np.ndarray, alpha: float
) -> list[list[int]]:
    """A one-window group between two others holds the change: mark it (``-i - 1``).

    The marked window is moved into the next group (skipped there); the groups around it
    are merged when they do not differ.
    """
    out = [list(g) for g in groups]
    k = 1
    while k < len(out) - 1:
        if len(out[k]) == 1 and out[k][0] >= 0:
            i = out[k][0]
            before, after = out[k - 1], out[k + 1]
            real_b = [j for j in before if j >= 0]
            real_a = [j for j in after if j >= 0]
            if differs(x[real_b], x[real_a], sigma, alpha):
                out[k + 1] = [-i - 1, *after]
                del out[k]
            else:
                out[k - 1] = [*before, -i - 1, *after]
                del out[k : k + 2]
            continue
        k += 1
    return [sorted(g, key=lambda j: j if j >= 0 else -j - 1) for g in out]


def _settled(
    used: list[int],
    x: np.ndarray,
    sigma: np.ndarray | None,
    *,
    ny: int,
    cfg: ChangeConfig,
    skipped: dict[int, str],
) -> list[int]:
    """Drop the leading windows whose level has not reached the stretch's steady level."""
    if sigma is None or len(used) < 3:
        return used
    lv = slice(1 + 3 * ny, 1 + 4 * ny)
    tol = np.maximum(cfg.settle_sigmas * sigma[lv], cfg.level_floor)
    ref = np.median(x[used[len(used) // 2 :], lv], axis=0)
    keep = list(used)
    while len(keep) > 2:
        off = np.abs(x[keep[0], lv] - ref)
        if not np.any(off > tol):
            break
        worst = int(np.argmax(off / tol))
        skipped[keep[0]] = (
            f"settling: output {worst} level {off[worst]:.4g} from the stretch's steady level "
            f"(tolerance {tol[worst]:.3g})"
        )
        keep.pop(0)
    return keep


def _evidence(
    before: np.ndarray, after: np.ndarray, sigma: np.ndarray, outputs: Sequence[str]
) -> str:
    """The features that moved most between two stretches (in noise units), in words."""
    names = feature_names(outputs)
    a, b = np.median(before, axis=0), np.median(after, axis=0)
    z = np.abs(b - a) / sigma
    top = np.argsort(-z)[:3]
    return "; ".join(
        f"{names[j]} {a[j]:.4g} -> {b[j]:.4g} ({z[j]:.0f} x its noise)" for j in top if z[j] > 1
    )


# --------------------------------------------------------------------------- diagnosis


@dataclass(frozen=True)
class StretchDiagnosis:
    """One stretch and its diagnoses.

    Attributes:
        stretch: the stretch.
        window_starts_s: start times (s) of its diagnosed windows.
        skipped: ``(start_s, why)`` of its skipped windows.
        relative_to_model: the diagnosis against the model (None: not diagnosed).
        relative_to_previous: against the model with the previous stretch's effects, its
            steady means the offset's reference (None for the first stretch, or when one of
            the two could not be diagnosed).
        not_diagnosed: why the stretch was not diagnosed, or ``""``.
    """

    stretch: Stretch
    window_starts_s: list[float]
    skipped: list[tuple[float, str]]
    relative_to_model: Diagnosis | None
    relative_to_previous: Diagnosis | None
    not_diagnosed: str = ""

    def to_json(self) -> dict[str, Any]:
        """The documented JSON entry of a stretch (docs/cli.md, "diagnose JSON")."""
        return {
            "start_s": self.stretch.start_s,
            "end_s": self.stretch.end_s,
            "change_at_s": self.stretch.change_at_s,
            "windows": self.window_starts_s,
            "skipped": [{"start_s": s, "reason": why} for s, why in self.skipped],
            "not_diagnosed": self.not_diagnosed or None,
            "relative_to_model": (
                self.relative_to_model.to_json() if self.relative_to_model else None
            ),
            "relative_to_previous": (
                self.relative_to_previous.to_json() if self.relative_to_previous else None
            ),
        }


@dataclass(frozen=True)
class RecordingDiagnosis:
    """Outcome of :func:`diagnose_stretches`.

    Attributes:
        stretches: per stationary stretch, in time order.
        features: per window.
        segmented: whether change points were searched.
    """

    stretches: list[StretchDiagnosis]
    features: list[WindowFeatures] = field(repr=False)
    segmented: bool = True

    @property
    def changes(self) -> list[tuple[float, str]]:
        """``(at_s, evidence)`` of each change found."""
        return [
            (s.stretch.change_at_s, s.stretch.evidence)
            for s in self.stretches
            if s.stretch.change_at_s is not None
        ]

    @property
    def current(self) -> StretchDiagnosis | None:
        """The last stretch that was diagnosed (the plant as it is now), or None."""
        done = [s for s in self.stretches if s.relative_to_model is not None]
        return done[-1] if done else None

    def to_json(self) -> dict[str, Any]:
        """``{"stretches": [...], "changes": [...]}`` (docs/cli.md, "diagnose JSON")."""
        return {
            "segmented": self.segmented,
            "stretches": [s.to_json() for s in self.stretches],
            "changes": [{"at_s": t, "evidence": why} for t, why in self.changes],
        }


def too_few(windows: Sequence[Window]) -> str:
    """Why these windows are too few to diagnose, or ``""``."""
    if not windows:
        return "no steady window"
    if len(windows) == 1 and windows[0].n_periods < 2:
        return "one window of one period: nothing left to judge the fit on"
    return ""


def diagnose_stretches(
    windows: Sequence[Window],
    doc: Mapping[str, Any],
    findings: Sequence[WindowFindings] | None = None,
    config: DiagnosisConfig | None = None,
    change_config: ChangeConfig | None = None,
    *,
    split: bool = True,
    source: str = "model",
    convention: NormConvention = NormConvention.POWER,
) -> RecordingDiagnosis:
    """Find the stationary stretches of a recording and diagnose each.

    Args:
        windows: judged, non-overlapping windows in time order.
        doc: the model document.
        findings: what the validator found in each window, or None (computed here).
        config: settings of each diagnosis.
        change_config: settings of the change search and the transient test.
        split: search for changes (False: the windows are one stretch; transient windows
            are still skipped).
        source: label of the model in messages.
        convention: norm convention.

    Raises:
        DiagnosisError: no window, or a window without excitation.
    """
    if not windows:
        raise DiagnosisError(
            "no judged window to diagnose: record at least two whole windows of steady, "
            "excited data (see the validator's data-quality reasons)"
        )
    cfg = config or DiagnosisConfig()
    model = model_from_dict(doc, source)
    feats = window_features(
        windows,
        doc,
        findings,
        source=source,
        convention=convention,
        excitation_floor=cfg.excitation_floor,
    )
    stretches = find_stretches(feats, model.output_names, change_config, split=split)
    nominal = Nominal.from_document(doc, source)
    out: list[StretchDiagnosis] = []
    prev: Diagnosis | None = None
    prev_windows: list[Window] = []
    prev_index: list[int] = []
    for st in stretches:
        ws = [windows[i] for i in st.windows]
        why = too_few(ws)
        rel_model = rel_prev = None
        # the level's time course across the change (a sensor steps, a leaking tank settles)
        course = None
        if st.change_at_s is not None and prev_index and st.windows and LEVEL in model.output_names:
            around = windows[prev_index[-2:][0] : st.windows[-1] + 1]
            course = level_course(around, nominal, model.output_names.index(LEVEL), cfg.alpha)
        if not why:
            try:
                rel_model = diagnose(
                    ws,
                    doc,
                    cfg,
                    source=source,
                    convention=convention,
                    # relative to the model, the change is the level's whole move only when
                    # the level matched the model before it
                    course=course if prev is not None and prev.level is None else None,
                )
            except DiagnosisError as err:
                why = str(err)
        if rel_model is not None and prev is not None:
            # "what changed": the model with the previous stretch's effects, and the previous
            # stretch's steady means as the reference operating point (a sensor bias or a
            # leak shows there, not in the de-biased dynamics)
            rel_prev = diagnose(
                ws,
                prev.document if prev.document is not None else doc,
                cfg,
                source=f"{source} with the previous stretch's effects",
                convention=convention,
                reference=steady_means(prev_windows),
                course=course,
            )
        out.append(
            StretchDiagnosis(
                stretch=st,
                window_starts_s=[w.start_s for w in ws],
                skipped=[(windows[i].start_s, r) for i, r in st.skipped],
                relative_to_model=rel_model,
                relative_to_previous=rel_prev,
                not_diagnosed=why,
            )
        )
        if rel_model is not None:
            prev, prev_windows, prev_index = rel_model, ws, list(st.windows)
    return RecordingDiagnosis(out, feats, split)


def steady_means(windows: Sequence[Window]) -> OperatingPoint:
    """The operating point of a stretch: its windows' input and output means (model units)."""
    return OperatingPoint(
        u=np.mean([w.u.mean(axis=0) for w in windows], axis=0),
        y=np.mean([w.y.mean(axis=0) for w in windows], axis=0),
    )
