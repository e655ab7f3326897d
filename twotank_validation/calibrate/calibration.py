"""Calibrate a model set's uncertainty on judged windows: scalings, per-bin picture, new weights.

:func:`calibrate` takes the judged windows of a recording (whole periods, as the validator
saw them) and a model document, and for each chosen block

1. finds the smallest uniform factor on its stated weight for which no window is
   invalidated, with the other blocks as stated (:func:`~.scaling.window_scaling`, per
   window; the largest is the answer): above 1 the data demand more uncertainty than stated,
   below 1 they use only that fraction of it;
2. computes, on the fit windows, the smallest weight magnitude each active bin requires
   (:func:`~.scaling.bin_requirement`, with the blocks calibrated before it as fitted and
   the rest as stated);
3. fits a low-order stable, minimum-phase weight over that requirement with a margin
   (:func:`~.weightfit.fit_weight`) and puts it into the model document.

The calibrated model is then judged on the held-out windows (the fit/held-out split of the
diagnosis, :func:`~twotank_validation.diagnose.split_windows`). Nothing is said outside the
excited band: the weight there is an extrapolation, flagged as one.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from twotank_validation.calibrate.joint import JointScaling, joint_scaling
from twotank_validation.calibrate.scaling import (
    Block,
    CalibrationError,
    WindowProblem,
    active_bins,
    bin_requirement,
    choose_blocks,
    weight_gain,
    window_scaling,
)
from twotank_validation.calibrate.weightfit import FittedWeight, fit_weight
from twotank_validation.core import lti
from twotank_validation.core.datum import Datum, NormConvention
from twotank_validation.core.model import LFTModel, PlantResponse, model_from_dict
from twotank_validation.core.validate import validate_beta
from twotank_validation.defaults import METHODS
from twotank_validation.diagnose.inputs import DiagnosisError, Window, split_windows


@dataclass(frozen=True)
class CalibrationConfig:
    """Settings of the calibration.

    Attributes:
        margin: the fitted weight covers this multiple of the per-bin requirement, >= 1.
        max_order: largest number of pole-zero pairs of a fitted weight, >= 0.
        order_tolerance_db: the lowest order whose mean excess over the requirement is
            within this many dB of the best order's is taken, >= 0.
        excitation_floor: harmonic bins with input power below this fraction of the largest
            are not excited (as the diagnosis), in (0, 1).
        method: the window solver's route (``"auto"``, ``"closed_form"``, ``"fast"``,
            ``"sdp"``), as :func:`~twotank_validation.core.validate.validate`.
        together: scale the chosen blocks together (:mod:`~.joint`): the common factor and
            the joint factors, each weight written as the stated one times its joint factor
            on the fit windows times the margin (no shape is fitted); False: one block after
            the other, as :func:`calibrate` describes.
    """

    margin: float = 1.2
    max_order: int = 2
    order_tolerance_db: float = 1.0
    excitation_floor: float = 1e-4
    method: str = "auto"
    together: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.margin) and self.margin >= 1.0):
            raise CalibrationError(f"margin={self.margin} must be >= 1")
        if self.max_order < 0:
            raise CalibrationError(f"max_order={self.max_order} must be >= 0")
        if not self.order_tolerance_db >= 0.0:
            raise CalibrationError(f"order_tolerance_db={self.order_tolerance_db} must be >= 0")
        if not 0.0 < self.excitation_floor < 1.0:
            raise CalibrationError(f"excitation_floor={self.excitation_floor} must be in (0, 1)")
        if self.method not in METHODS:
            raise CalibrationError(f"method={self.method!r}: use one of {METHODS}")


@dataclass(frozen=True)
class BlockCalibration:
    """What the data demand of one block.

    Attributes:
        name: the block's name.
        kind: ``"perturbation"`` or ``"noise"``.
        scaling: the smallest uniform factor on the stated weight for which no window is
            invalidated (others as stated); 0: the data need none of it; inf: no factor
            explains every window (the block alone cannot).
        window_scaling: (n_windows,) the same per window (every judged window).
        freqs_hz: (k,) frequencies of the bins judged one by one (fit windows).
        theta: (k,) the same in rad/sample.
        required: (k,) the smallest weight magnitude each bin requires (the largest over
            the fit windows; inf where no weight explains the bin within its share).
        stated: (k,) the stated weight's magnitude at those bins.
        fitted: the fitted weight, or None (``note`` says why).
        note: how the written weight was made, or why none was written; empty for a fit.
        fit_scaling: for a uniformly scaled block (noise, non-scalar weights), the smallest
            factor on the fit windows with the blocks before it calibrated; else None.
        margin: the calibration's margin (the written factor is ``fit_scaling`` times it).

    The one quantity is the *factor* on the block's stated weight (the weight in the model
    file is the stated one times it). ``scaling`` is the factor every window needs with the
    block *alone* (the other blocks as stated); ``fit_scaling`` the factor the fit windows
    need *after* the blocks calibrated before it (which may explain part of the error, so it
    can be smaller); ``written_factor`` what is written, ``fit_scaling`` times the margin.
    """

    name: str
    kind: str
    scaling: float
    window_scaling: tuple[float, ...]
    freqs_hz: np.ndarray
    theta: np.ndarray
    required: np.ndarray
    stated: np.ndarray
    fitted: FittedWeight | None
    note: str = ""
    fit_scaling: float | None = None
    margin: float = 1.0

    @property
    def written_factor(self) -> float | None:
        """The factor on the stated weight written for a uniformly scaled block.

        ``fit_scaling`` times the margin; None where the block was fitted or left as stated.
        """
        if self.fit_scaling is None or not math.isfinite(self.fit_scaling):
            return None
        return self.margin * self.fit_scaling

    def used_text(self) -> str:
        """The factor alone (``scaling``), in words: how much of the stated weight is used."""
        head = f"{self.name}: alone (the other blocks as stated),"
        if math.isinf(self.scaling):
            return (
                f"{head} no factor up to 1e6 × its stated weight explains every window (the "
                "error is on another channel)"
            )
        if self.scaling <= 1.0:
            return (
                f"{head} every window is explained with {self.scaling:.3g} × its stated "
                f"weight: the data use {self.scaling:.0%} of it ({1.0 - self.scaling:.0%} of "
                "it is not needed by any window)"
            )
        return (
            f"{head} every window needs {self.scaling:.3g} × its stated weight "
            f"({self.scaling - 1.0:.0%} more than stated)"
        )


@dataclass(frozen=True)
class JointCalibration:
    """The chosen blocks scaled together (``CalibrationConfig.together``).

    Attributes:
        every: on every judged window: the common factor and the joint factors.
        fit: the same on the fit windows (what is written, times the margin).
        margin: the calibration's margin.
    """

    every: JointScaling
    fit: JointScaling
    margin: float

    @property
    def written(self) -> tuple[float, ...] | None:
        """The factors written (fit joint factors times the margin), None if not finite."""
        if not all(math.isfinite(f) for f in self.fit.factors):
            return None
        return tuple(self.margin * f for f in self.fit.factors)

    def text(self) -> list[str]:
        """The joint answer in words (a few lines)."""
        e = self.every
        names = ", ".join(e.names)
        if math.isinf(e.common):
            return [
                f"together ({names}): no factor up to 1e6 on all of them explains every "
                "window (the error is on a block not chosen)"
            ]
        pairs = ", ".join(f"{n} {f:.4g}" for n, f in zip(e.names, e.factors, strict=True))
        lines = [
            f"together ({names}): every window is explained with {e.common:.4g} × every "
            "stated weight (the common factor)",
            f"  joint factors (the smallest sum of squares that explains every window): {pairs}",
        ]
        if (w := self.written) is not None:
            lines.append(
                "  written: "
                + ", ".join(f"{n} {f:.4g}" for n, f in zip(e.names, w, strict=True))
                + f" × the stated weight (the fit windows' joint factors × the margin "
                f"{self.margin:g})"
            )
        return lines

    def to_json(self) -> dict[str, Any]:
        """JSON-serialisable numbers (``inf`` as None)."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        def one(j: JointScaling) -> dict[str, Any]:
            return {
                "common": num(j.common),
                "window_common": [num(x) for x in j.window_common],
                "factors": dict(zip(j.names, (num(f) for f in j.factors), strict=True)),
                "sum_of_squares": num(j.objective),
            }

        w = self.written
        return {
            "blocks": list(self.every.names),
            "every_window": one(self.every),
            "fit_windows": one(self.fit),
            "margin": self.margin,
            "written": None if w is None else dict(zip(self.every.names, w, strict=True)),
            "text": self.text(),
        }


@dataclass(frozen=True)
class Judged:
    """A model judged on windows.

    Attributes:
        start_s: (n,) window start times (s).
        held_out: (n,) bool, the window was not used to fit.
        beta: (n,) beta of the stated model.
        beta_after: (n,) beta of the calibrated model (the stated one where nothing was fitted).
    """

    start_s: np.ndarray
    held_out: np.ndarray
    beta: np.ndarray
    beta_after: np.ndarray


@dataclass(frozen=True)
class Calibration:
    """The calibration of a model on the judged windows of a recording.

    Attributes:
        model: the model's name.
        convention: the norm convention of beta.
        blocks: one entry per chosen block, in the order calibrated.
        window_starts_s: (n,) the judged windows' start times (the uniform scalings).
        window_beta: (n,) the stated model's beta on them.
        judged: the stated and calibrated models on the fit and held-out windows.
        band_hz: the excited band of the data (lowest and highest excited harmonic, Hz).
        document: the calibrated model file (dict), or None when no weight was fitted.
        source: the model's label.
    """

    model: str
    convention: NormConvention
    blocks: list[BlockCalibration]
    window_starts_s: np.ndarray
    window_beta: np.ndarray
    judged: Judged
    band_hz: tuple[float, float]
    document: dict[str, Any] | None
    source: str = "model"
    extrapolated: dict[str, dict[str, float]] = field(default_factory=dict)
    joint: JointCalibration | None = None

    def to_json(self, model_file: str | None = None) -> dict[str, Any]:
        """JSON-serialisable numbers (``inf`` as None)."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "model": self.model,
            "norm_convention": self.convention.value,
            "band_hz": list(self.band_hz),
            "windows": [
                {"start_s": float(t), "beta": num(b)}
                for t, b in zip(self.window_starts_s, self.window_beta, strict=True)
            ],
            "blocks": [
                {
                    "name": b.name,
                    "kind": b.kind,
                    "scaling": num(b.scaling),
                    "used": b.used_text(),
                    "window_scaling": [num(s) for s in b.window_scaling],
                    "freqs_hz": b.freqs_hz.tolist(),
                    "required": [num(x) for x in b.required],
                    "stated": b.stated.tolist(),
                    "fitted": None
                    if b.fitted is None
                    else {
                        "weight": b.fitted.to_node(),
                        "order": b.fitted.order,
                        "margin": b.fitted.margin,
                        "mean_excess_db": b.fitted.mean_excess_db,
                        "magnitude": b.fitted.magnitude.tolist(),
                        "extrapolated": self.extrapolated.get(b.name, {}),
                    },
                    "note": b.note,
                    "fit_scaling": None if b.fit_scaling is None else num(b.fit_scaling),
                    "written_factor": b.written_factor,
                }
                for b in self.blocks
            ],
            "judged": [
                {
                    "start_s": float(t),
                    "held_out": bool(h),
                    "beta": num(b0),
                    "beta_after": num(b1),
                }
                for t, h, b0, b1 in zip(
                    self.judged.start_s,
                    self.judged.held_out,
                    self.judged.beta,
                    self.judged.beta_after,
                    strict=True,
                )
            ],
            "joint": None if self.joint is None else self.joint.to_json(),
            "model_file": model_file,
            "failure": None,
        }


def _datums(windows: Sequence[Window], convention: NormConvention) -> list[Datum]:
    return [w.datum(convention) for w in windows]


def _weight_node(doc: Mapping[str, Any], block: Block) -> Any:
    key = "noise" if block.is_noise else "perturbations"
    return doc[key][block.index]


def calibrate(
    windows: Sequence[Window],
    doc: Mapping[str, Any],
    config: CalibrationConfig | None = None,
    *,
    blocks: Sequence[str] | None = None,
    source: str = "model",
    convention: NormConvention = NormConvention.POWER,
) -> Calibration:
    """The smallest uncertainty the windows demand of each chosen block, and a fitted model.

    Args:
        windows: the judged, non-overlapping windows of a recording (whole periods, same
            sample and excitation period).
        doc: the model document (as loaded from YAML).
        config: settings.
        blocks: names of the perturbation and noise blocks to calibrate, in order; None or
            empty: every block of the model (perturbations, then noise).
        source: the model's label in messages.
        convention: the norm convention of beta.

    Raises:
        CalibrationError: no window, a block name the model does not have, windows of
            different lengths.
    """
    cfg = config or CalibrationConfig()
    if not windows:
        raise CalibrationError(
            "no judged window to calibrate on: the recording must hold at least one whole "
            "window of steady, excited data (see the validator's reasons for each window)"
        )
    model = model_from_dict(doc, source)
    chosen = choose_blocks(model, blocks)
    if len({(w.u.shape[0], w.period_samples, w.ts_s) for w in windows}) != 1:
        raise CalibrationError(
            "the windows differ in length, period or sample period: calibrate windows cut "
            "with one window setting"
        )
    try:
        fit_w, held_w = split_windows(windows)
    except DiagnosisError as err:
        raise CalibrationError(str(err)) from err
    all_d = _datums(windows, convention)
    fit_d, held_d = _datums(fit_w, convention), _datums(held_w, convention)
    ts = all_d[0].ts_s
    problems = [WindowProblem.of(d, model, cfg.method) for d in all_d]
    window_beta = np.array([p.beta(chosen[0], 1.0) for p in problems])
    scalings = {b.name: _scalings(problems, b) for b in chosen}
    current = copy.deepcopy(dict(doc))
    current_model = model
    results: list[BlockCalibration] = []
    band: list[float] = []
    extrapolated: dict[str, dict[str, float]] = {}
    joint = None
    if cfg.together:
        fit_p = (
            problems[: len(fit_d)]
            if len(windows) > 1
            else [WindowProblem.of(d, model, cfg.method) for d in fit_d]
        )
        joint = JointCalibration(joint_scaling(problems, chosen), joint_scaling(fit_p, chosen),
                                 cfg.margin)  # fmt: skip
        results, changed = _write_joint(joint, chosen, current, scalings, source)
        current_model = changed or model
        band = _band(fit_p, chosen, cfg.excitation_floor)
    for block in chosen if not cfg.together else ():
        fit_p = [WindowProblem.of(d, current_model, cfg.method) for d in fit_d]
        block_now = next(b for b in choose_blocks(current_model, [block.name]))
        theta, required = _requirement(fit_p, block_now, cfg.excitation_floor)
        if not block.is_noise:
            band += [float(theta.min()), float(theta.max())] if theta.size else []
        stated = weight_gain(block, theta, ts)
        current_gain = weight_gain(block_now, theta, ts)
        required_mag = required * current_gain
        fitted, note, fit_scaling = None, "", None
        if theta.size == 0:
            note = "no excited bin: the data say nothing about this block"
        elif block.weight is None:
            note = "a block of a generalised plant has no weight to replace: scale its columns"
        elif block.is_noise or block.weight.shape != (1, 1):
            # a noise weight's per-bin requirement is the periodogram of one noise draw (a
            # weight covering its scatter would be several times the noise's RMS), and only
            # scalar weights are fitted: these blocks are scaled uniformly
            if current_model is model and len(windows) > 1:  # the fit windows lead `windows`
                fit_scaling = max(scalings[block.name][: len(fit_w)])
            else:
                fit_scaling = max(window_scaling(p, block_now) for p in fit_p)
            if math.isfinite(fit_scaling):
                factor = fit_scaling * cfg.margin
                node = _weight_node(current, block)
                node["weight"] = scaled_node(node["weight"], factor)
                current_model = model_from_dict(current, f"{source} (calibrated)")
                others = "the blocks above as calibrated" if results else "the others as stated"
                note = (
                    f"written: {factor:.4g} × the stated weight = {fit_scaling:.4g} (the factor "
                    f"the fit windows need, {others}) × the margin {cfg.margin:g}"
                )
            else:
                note = "no factor explains the fit windows: the weight is left as it is"
        elif not np.all(np.isfinite(required_mag)):
            note = (
                "some bins cannot be explained by this block within their share of beta^2 "
                "(the error there is on another channel, or the noise alone exceeds the "
                "share): the weight is left as it is"
            )
        else:
            fitted = fit_weight(
                theta,
                required_mag,
                ts,
                margin=cfg.margin,
                max_order=cfg.max_order,
                order_tolerance_db=cfg.order_tolerance_db,
                intersample=model.intersample,
            )
            _weight_node(current, block)["weight"] = fitted.to_node()
            current_model = model_from_dict(current, f"{source} (calibrated)")
        freqs = theta / (2.0 * np.pi * ts)
        results.append(
            BlockCalibration(
                block.name,
                block.kind,
                max(scalings[block.name]),
                scalings[block.name],
                freqs,
                theta,
                required_mag,
                stated,
                fitted,
                note,
                fit_scaling,
                cfg.margin,
            )
        )
    fitted_any = current_model is not model
    band_theta = (min(band), max(band)) if band else (0.0, 0.0)
    band_hz = (band_theta[0] / (2 * np.pi * ts), band_theta[1] / (2 * np.pi * ts))
    for r in results:
        if r.fitted is not None:
            extrapolated[r.name] = _extrapolation(r.fitted, band_hz, ts, model.intersample)
    document = _calibrated_document(doc, current, results) if fitted_any else None
    judged_d = fit_d + held_d
    after_model = current_model if fitted_any else model
    # several windows: the judged ones are `windows` in order, whose beta is known
    before = window_beta.copy() if len(windows) > 1 else window_betas(judged_d, model, cfg.method)
    judged = Judged(
        start_s=np.array([w.start_s for w in (*fit_w, *held_w)]),
        held_out=np.array([False] * len(fit_d) + [True] * len(held_d)),
        beta=before,
        # one window and nothing fitted: the stated model's β, just computed
        beta_after=before.copy()
        if after_model is model and len(windows) == 1
        else window_betas(judged_d, after_model, cfg.method),
    )
    return Calibration(
        model=model.name,
        convention=convention,
        blocks=results,
        window_starts_s=np.array([w.start_s for w in windows]),
        window_beta=window_beta,
        judged=judged,
        band_hz=band_hz,
        document=document,
        source=source,
        extrapolated=extrapolated,
        joint=joint,
    )


def window_betas(datums: Sequence[Datum], model: LFTModel, method: str = "auto") -> np.ndarray:
    """(n,) β of the model on each datum, as ``validate`` finds it.

    By :func:`~twotank_validation.core.validate.validate_beta` (the same β, no witness); datums
    with the same bins share the model's response at them (evaluated once).
    """
    responses: dict[tuple[float, bytes], PlantResponse] = {}
    out = []
    for d in datums:
        key = (d.ts_s, d.theta.tobytes())
        if key not in responses:
            responses[key] = model.response(d.theta, d.ts_s)
        out.append(
            validate_beta(d, model, method=method, response=responses[key], caveats=False).beta
        )
    return np.array(out, dtype=float)


def _scalings(problems: Sequence[WindowProblem], block: Block) -> tuple[float, ...]:
    """The block's factor alone on each window (each window's search starts at the last's)."""
    out: list[float] = []
    for p in problems:
        out.append(window_scaling(p, block, out[-1] if out else None))
    return tuple(out)


def _band(problems: Sequence[WindowProblem], chosen: Sequence[Block], floor: float) -> list[float]:
    """The lowest and highest active bin (theta) of the chosen perturbations (empty: none)."""
    theta = [
        p.datum.theta[active_bins(p, b, floor)] for p in problems for b in chosen if not b.is_noise
    ]
    both = np.concatenate(theta) if theta else np.zeros(0)
    return [float(both.min()), float(both.max())] if both.size else []


def _write_joint(
    joint: JointCalibration,
    chosen: Sequence[Block],
    current: dict[str, Any],
    scalings: Mapping[str, tuple[float, ...]],
    source: str,
) -> tuple[list[BlockCalibration], LFTModel | None]:
    """Each chosen weight times its written joint factor in ``current`` (edited in place).

    Returns:
        The blocks' entries (the factor alone, the joint factor as ``fit_scaling``, no per-bin
        picture) and the calibrated model (None when nothing could be written).
    """
    written = joint.written
    results = []
    empty = np.zeros(0)
    for block, fit_f in zip(chosen, joint.fit.factors, strict=True):
        if written is None:
            note = "scaled together: no joint factors explain the fit windows; left as it is"
        elif block.weight is None:
            note = "scaled together: a block of a generalised plant has no weight to replace"
        else:
            factor = fit_f * joint.margin
            node = _weight_node(current, block)
            node["weight"] = scaled_node(node["weight"], factor)
            note = (
                f"written: {factor:.4g} × the stated weight = {fit_f:.4g} (its joint factor on "
                f"the fit windows, the chosen blocks scaled together) × the margin "
                f"{joint.margin:g}"
            )
        results.append(
            BlockCalibration(
                block.name,
                block.kind,
                max(scalings[block.name]),
                scalings[block.name],
                empty,
                empty,
                empty,
                empty,
                None,
                note,
                fit_f if written is not None else None,
                joint.margin,
            )
        )
    changed = written is not None and any(b.weight is not None for b in chosen)
    return results, (model_from_dict(current, f"{source} (calibrated)") if changed else None)


def _requirement(
    problems: Sequence[WindowProblem], block: Block, floor: float
) -> tuple[np.ndarray, np.ndarray]:
    """The active bins of all windows (theta) and the largest factor each requires."""
    reqs = [bin_requirement(p, block, floor) for p in problems]
    bins = np.unique(np.concatenate([r.bins for r in reqs])) if reqs else np.zeros(0, int)
    factor = np.zeros(bins.size)
    for r in reqs:
        pos = np.searchsorted(bins, r.bins)
        factor[pos] = np.maximum(factor[pos], r.factor)
    theta = problems[0].datum.theta[bins] if problems else np.zeros(0)
    return theta, factor


def _extrapolation(
    fitted: FittedWeight, band_hz: tuple[float, float], ts_s: float, how: lti.Intersample
) -> dict[str, float]:
    """The fitted weight's magnitude outside the excited band (DC, a decade below, Nyquist)."""
    points = {"dc": 0.0, "decade_below_band": band_hz[0] / 10.0, "nyquist": 0.5 / ts_s}
    theta = np.array([2 * np.pi * f * ts_s for f in points.values()])
    mag = np.abs(lti.bin_response(fitted.system(), theta, ts_s, how)[:, 0, 0])
    return {k: float(m) for k, m in zip(points, mag, strict=True)}


def scaled_node(node: Any, factor: float) -> Any:
    """A model-file weight node times ``factor`` (a number, gain, tf, ss or a diagonal list)."""
    if isinstance(node, list):
        return [scaled_node(n, factor) for n in node]
    if isinstance(node, int | float) and not isinstance(node, bool):
        return float(node) * factor
    ((key, body),) = node.items()
    if key == "gain":
        return {"gain": (np.asarray(body, dtype=float) * factor).tolist()}
    if key == "tf":
        return {"tf": {"num": [float(x) * factor for x in body["num"]], "den": body["den"]}}
    new = dict(body)
    new["C"] = (np.asarray(body["C"], dtype=float) * factor).tolist()
    new["D"] = (np.asarray(body["D"], dtype=float) * factor).tolist()
    return {"ss": new}


def _calibrated_document(
    doc: Mapping[str, Any], current: dict[str, Any], results: Sequence[BlockCalibration]
) -> dict[str, Any]:
    """The model file with the fitted weights (a new name, description and derivation)."""
    new = copy.deepcopy(current)
    done = [r for r in results if r.fitted is not None or r.written_factor is not None]
    new["name"] = f"{doc.get('name', 'model')}_calibrated"
    what = "; ".join(
        f"{r.name} weight of order {r.fitted.order} (margin {r.fitted.margin:g})"
        if r.fitted is not None
        else f"{r.name} {r.note}"
        for r in done
    )
    new["description"] = (
        f"{doc.get('description', '')} Uncertainty calibrated from data: {what}."
    ).strip()
    new["derivation"] = (
        f"{doc.get('derivation', doc.get('name', ''))}; then twotank-validation calibrate fitted "
        f"{', '.join(r.name for r in done)}"
    )
    return new


NO_WEIGHT_CHANGED = "no weight could be changed (see each block's note): no model file written"
"""What a calibration that changed no weight says (an error with ``--out-model``)."""


def model_of(calibration: Calibration) -> LFTModel | None:
    """The calibrated model (None when no weight was fitted)."""
    if calibration.document is None:
        return None
    return model_from_dict(calibration.document, f"{calibration.source} (calibrated)")


__all__ = [
    "NO_WEIGHT_CHANGED",
    "BlockCalibration",
    "Calibration",
    "CalibrationConfig",
    "Judged",
    "active_bins",
    "calibrate",
    "model_of",
]
