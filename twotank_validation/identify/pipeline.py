"""From the windows of a periodic experiment to a response, a nominal and a model document.

The windows come from the replay (the same reading, gaps and periodicity gate as
``validate``); :func:`probe_model` is the model the replay is given to cut them: it names the
interface map's channels and claims nothing (a zero nominal with unit noise), so every window
the gate passes is kept whatever the plant.

:func:`identify_windows` picks the estimator from the data (docs/theory.md §16):

* whole periods in steady state, one input pattern per input or more:
  :func:`~twotank_validation.identify.nonparametric.frf_from_experiments`;
* one input and several random-phase realisations (input patterns):
  :func:`~twotank_validation.identify.nonparametric.best_linear_approximation`, whose spread
  over the realisations holds the nonlinear distortion;
* a single period per window, or a transient the gate flagged:
  :func:`~twotank_validation.identify.lpm.local_polynomial` on each window, combined by
  inverse-variance weighting.

then fits a nominal (:mod:`twotank_validation.identify.fit`) and says how far it is from the
response at each line. :func:`model_document` writes the result as a model file that
``validate`` reads.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from twotank_validation.calibrate.calibration import CalibrationConfig, calibrate, window_betas
from twotank_validation.calibrate.noise import fitted_noise_weights
from twotank_validation.calibrate.weightfit import FittedWeight, fit_weight
from twotank_validation.core import lti
from twotank_validation.core.band import Band, excited_lines
from twotank_validation.core.datum import assess_periodicity
from twotank_validation.core.lti import Intersample
from twotank_validation.core.model import LFTModel, model_from_dict
from twotank_validation.core.noise_budget import (
    NOISE_BUDGET,
    NOISE_QUANTILE,
    NoiseSpread,
    NoiseWeights,
    noise_weights,
)
from twotank_validation.core.validate import validation_band
from twotank_validation.diagnose.inputs import Window, split_windows
from twotank_validation.errors import DatumError, IdentificationError
from twotank_validation.identify.fit import RationalFit, select_order
from twotank_validation.identify.greybox import (
    GreyBoxConfig,
    GreyBoxFit,
    GreyBoxModel,
    ParameterStatus,
    fit_two_tank,
)
from twotank_validation.identify.lpm import local_polynomial
from twotank_validation.identify.nonparametric import (
    Distortion,
    FrequencyResponse,
    best_linear_approximation,
    bla_over_experiments,
    distortion_lines,
    frf_from_experiments,
    split_by_pattern,
)
from twotank_validation.sim.excitation import ExcitationLines
from twotank_validation.sim.rig import RigParams

__all__ = [
    "Estimator",
    "Identification",
    "IdentifiedModel",
    "IdentifyConfig",
    "identified_model",
    "identify_windows",
    "model_document",
    "probe_model",
]

PROBE_NAME = "identify_probe"


class Estimator(enum.StrEnum):
    """How the response was estimated."""

    PERIODIC = "periodic"
    """Averaged over whole periods in steady state (the period spread gives σ)."""
    BLA = "best linear approximation"
    """Over random-phase realisations (σ holds the noise and the nonlinear distortion)."""
    LPM = "local polynomial"
    """The transient removed by local polynomials (a single period or a settling record)."""


@dataclass(frozen=True)
class IdentifyConfig:
    """Settings of the identification.

    Attributes:
        orders: the orders (states per input) tried; the MDL picks one.
        band: the band (Hz) the response and the fit use; None: every excited line.
        lpm_degree: the local polynomials' degree.
        margin: the perturbation weight covers this times the fit's error (with 2 σ).
        max_weight_order: largest order of the perturbation weight.
        delays: fit a transport delay per output with the nominal (a process plant's dead
            time; written as the nominal's ``output_delays_s``).
        grey_box: also fit this first-principles model's physical parameters to the response
            and take its linearisation as the nominal (docs/theory.md §17); None: the
            black-box fit is the nominal.
        grey_box_prior: the grey box's start and the value of what the data leave
            undetermined (None: the paper's rig, ``RigParams()``).
        lines: the excitation design's lines (the design written beside the recording,
            :func:`~twotank_validation.sim.excitation.read_design`): the excited lines are
            these, not those the input shows, and the outputs' power at the detection and
            even lines is measured (:attr:`Identification.distortion`); None: no design.
    """

    orders: range = field(default_factory=lambda: range(1, 9))
    band: Band | None = None
    lpm_degree: int = 2
    margin: float = 1.2
    max_weight_order: int = 2
    delays: bool = False
    grey_box: GreyBoxModel | None = None
    grey_box_prior: RigParams | None = None
    lines: ExcitationLines | None = None


@dataclass(frozen=True)
class Identification:
    """What the identification found.

    Attributes:
        response: the measured response at the excited lines in the band.
        estimator: how it was estimated.
        var_noise: (L, n_y, n_u) the noise's share of ``response.var`` (equal to it but
            for the best linear approximation, where the rest is distortion).
        fit: the chosen nominal.
        fits: every order's fit.
        ts_s: sample period (s).
        period_samples: samples per period.
        n_windows: windows used.
        notes: what a user should know (the estimator's choice, a poor fit, dropped lines).
        grey_box: the two-tank rig's physical parameters fitted to the response
            (:mod:`twotank_validation.identify.greybox`); when set, its linearisation is the
            nominal the document and the weights use (``fit`` stays the black-box fit).
        distortion: the outputs' power at the design's detection (odd) and even lines, the
            mean over the windows of each window's (a realisation's) level; None without a
            design's odd lines.
    """

    response: FrequencyResponse
    estimator: Estimator
    var_noise: np.ndarray
    fit: RationalFit
    fits: tuple[RationalFit, ...]
    ts_s: float
    period_samples: int
    n_windows: int
    config: IdentifyConfig = field(default_factory=IdentifyConfig)
    notes: tuple[str, ...] = ()
    grey_box: GreyBoxFit | None = None

    @property
    def nominal(self) -> RationalFit | GreyBoxFit:
        """The nominal the model set is built on: the grey box when fitted, else ``fit``."""
        return self.fit if self.grey_box is None else self.grey_box

    @property
    def intersample(self) -> Intersample:
        """The nominal's intersample assumption.

        ``exact`` for a fit to the sampled response, ``zoh`` for the grey box (a continuous
        plant driven by held commands).
        """
        return Intersample.EXACT if self.grey_box is None else self.grey_box.intersample

    distortion: Distortion | None = None

    @cached_property
    def shapes(self) -> tuple[FittedWeight, ...]:
        """Per output, a weight over the fit's relative error: the shape calibrate scales.

        Output-multiplicative, over ``|H - G| / |G|`` (largest over the inputs).
        """
        return _weights(self, cover=False)

    @cached_property
    def covers(self) -> tuple[FittedWeight, ...]:
        """Per output, a weight over what the response alone demands.

        Over ``(|H - G| + 2 σ) / |G|`` times the margin: where nothing can be held out to
        calibrate on.
        """
        return _weights(self, cover=True)

    @property
    def relative_error(self) -> np.ndarray:
        """(L, n_y) the fit's largest relative error over the inputs at each line."""
        model = self.nominal.response(self.response.freqs_hz)
        err = np.abs(self.response.g - model)
        return np.max(err / np.maximum(np.abs(model), 1e-300), axis=2)


def probe_model(inputs: Sequence[str], outputs: Sequence[str]) -> LFTModel:
    """A model that names the channels and claims nothing: the replay cuts windows with it.

    A zero nominal and unit noise weights (``n_y x n_u``), so it is valid on any data.
    """
    return model_from_dict(
        {
            "name": PROBE_NAME,
            "inputs": list(inputs),
            "outputs": list(outputs),
            "nominal": {"gain": [[0.0] * len(inputs) for _ in outputs]},
            "noise": [{"name": "probe", "outputs": list(outputs), "weight": {"gain": 1.0}}],
        },
        source="identify probe",
    )


def _lines(
    windows: Sequence[Window], band: Band | None, design: ExcitationLines | None = None
) -> np.ndarray:
    """The excited lines (the design's, else the windows' mean input period's) in the band."""
    n = windows[0].period_samples
    if design is not None:
        lines = np.asarray(design.excited, dtype=int)
    else:
        periods = np.concatenate([w.u.reshape(-1, n, w.u.shape[1]) for w in windows])
        spec = np.fft.rfft(periods.mean(axis=0), axis=0) / n
        lines = np.flatnonzero(excited_lines(spec, 1))
    if band is not None:
        f = lines / (n * windows[0].ts_s)
        lines = lines[(f >= band.min_hz) & (f <= band.max_hz)]
    if lines.size == 0:
        where = "" if band is None else f" in {band.min_hz:g}..{band.max_hz:g} Hz"
        raise IdentificationError(
            f"no excited line{where}: the input carries no periodic excitation there; give a "
            "band where it does (--band) or a record with a periodic excitation"
        )
    return lines


def _periodic(
    windows: Sequence[Window], lines: np.ndarray
) -> tuple[FrequencyResponse, np.ndarray, Estimator]:
    n = windows[0].period_samples
    u = np.concatenate([w.u for w in windows])
    y = np.concatenate([w.y for w in windows])
    groups = split_by_pattern(u - u.mean(axis=0), y - y.mean(axis=0), n)
    n_u = u.shape[1]
    ts = windows[0].ts_s
    if n_u == 1 and len(groups) > 1:
        bla = best_linear_approximation([[g] for g in groups], n, lines, ts)
        return bla.response, bla.var_noise, Estimator.BLA
    if n_u > 1 and len(groups) > n_u:
        # more random-phase experiments than inputs: the spread about the fit shows the
        # nonlinear distortion beside the noise (an orthogonal multisine's n_u patterns give
        # no spread to see it with, and take frf_from_experiments below)
        bla = bla_over_experiments(groups, n, lines, ts)
        return bla.response, bla.var_noise, Estimator.BLA
    if len(groups) < n_u:
        # one input pattern for several inputs (every valve driven at once, as the rig's
        # excitation does): the mean period, and the inputs told apart over neighbouring lines
        # by the local polynomial method (their spectra differ from line to line)
        up = u.reshape(-1, n, n_u).mean(axis=0)
        yp = y.reshape(-1, n, y.shape[1]).mean(axis=0)
        try:
            fr = local_polynomial(up - up.mean(axis=0), yp - yp.mean(axis=0), lines, ts)
        except IdentificationError as err:
            raise IdentificationError(
                f"{n_u} inputs excited together in one pattern, and the local polynomial "
                f"method cannot tell them apart ({err}): record one experiment per input, or "
                "an orthogonal multisine, or excite every line of the band"
            ) from err
        return fr, fr.var, Estimator.LPM
    fr = frf_from_experiments(groups, n, lines, ts)
    return fr, fr.var, Estimator.PERIODIC


def _lpm(
    windows: Sequence[Window], lines: np.ndarray, degree: int
) -> tuple[FrequencyResponse, np.ndarray, Estimator]:
    fits = []
    for w in windows:
        p = w.n_periods
        fits.append(
            local_polynomial(
                w.u - w.u.mean(axis=0),
                w.y - w.y.mean(axis=0),
                lines * p,
                w.ts_s,
                degree=degree,
                n_periods=p,
            )
        )
    inv = np.sum([1.0 / f.var for f in fits], axis=0)
    g = np.sum([f.g / f.var for f in fits], axis=0) / inv
    var = 1.0 / inv
    noise_var = np.mean([f.noise_var for f in fits if f.noise_var is not None], axis=0)
    fr = FrequencyResponse(
        lines=lines,
        freqs_hz=lines / (windows[0].period_samples * windows[0].ts_s),
        g=g,
        var=var,
        n_periods=min(f.n_periods for f in fits),
        n_experiments=len(fits),
        noise_var=noise_var,
    )
    return fr, var, Estimator.LPM


def _distortion(windows: Sequence[Window], design: ExcitationLines) -> Distortion | None:
    """The outputs' power at the design's detection and even lines, over the windows.

    Per window (one realisation: the distortion's phases change with the realisation, so
    the periods are averaged within it only), then the mean level over the windows. None
    for a design without unexcited odd or even lines, or off a grid of every line.
    """
    if design.step != 1 or not (design.detection.size or design.even.size):
        return None
    each = [
        distortion_lines(
            w.y - w.y.mean(axis=0), w.period_samples, design.excited, (design.first, design.last)
        )
        for w in windows
    ]
    return Distortion(
        odd=np.mean([d.odd for d in each], axis=0),
        even=np.mean([d.even for d in each], axis=0),
        noise_odd=np.mean([d.noise_odd for d in each], axis=0),
        noise_even=np.mean([d.noise_even for d in each], axis=0),
        n_odd=each[0].n_odd,
        n_even=each[0].n_even,
    )


def _transient(windows: Sequence[Window]) -> bool:
    """Whether a window of three or more periods shows a transient still decaying.

    A drift or a shrinking period-to-period variation
    (:func:`~twotank_validation.core.datum.assess_periodicity`).
    """
    for w in windows:
        if w.n_periods >= 3:
            u, y = w.u - w.u.mean(axis=0), w.y - w.y.mean(axis=0)
            if assess_periodicity(u, y, w.period_samples).transient_suspected:
                return True
    return False


_POORLY_DETERMINED = 0.5
"""Median σ of an entry, over its output's largest |G|, above which identify says the data
hardly determine it."""


def _poorly_determined(fr: FrequencyResponse) -> list[str]:
    """A note per input-output entry whose response the data hardly determine.

    An entry is poorly determined when its median σ over the lines, relative to the largest
    entry of its output at each line, is above :data:`_POORLY_DETERMINED`; the note names
    the fix.
    """
    # relative to the output's largest entry at each line: an entry the plant does not have
    # (a zero response) is determined as zero, not poorly
    scale = np.max(np.abs(fr.g), axis=2, keepdims=True)  # (L, n_y, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.median(np.sqrt(fr.var) / scale, axis=0)  # (n_y, n_u)
    poor = [(c, i) for c, i in zip(*np.nonzero(~(rel <= _POORLY_DETERMINED)), strict=True)]
    if not poor:
        return []
    entries = ", ".join(f"output {c + 1} / input {i + 1} ({rel[c, i]:.2g})" for c, i in poor)
    fix = "record more periods or a larger excitation"
    if fr.g.shape[2] > 1 and fr.n_experiments == 1:
        fix = (
            "excite the inputs in separate experiments or with orthogonal multisines "
            "(the local polynomial method separates inputs on the same lines only where "
            "the response is smooth over its window), or " + fix
        )
    return [
        f"the data hardly determine the response (median σ over the output's largest |G|): "
        f"{entries}: {fix}"
    ]


def identify_windows(windows: Sequence[Window], config: IdentifyConfig) -> Identification:
    """The response, the nominal and the weights from the windows of one experiment.

    A single period per window, or a transient still decaying, takes the local polynomial
    method; else the periods are averaged.

    Args:
        windows: whole-period windows in model units (non-overlapping).
        config: the settings.

    Raises:
        IdentificationError: no window, no excitation in the band, too few experiments for
            the inputs, or no order the data can support.
    """
    if not windows:
        raise IdentificationError("no window to identify from")
    lines = _lines(windows, config.band, config.lines)
    one_period = all(w.n_periods == 1 for w in windows)
    transient = not one_period and _transient(windows)
    notes = []
    if one_period or transient:
        fr, var_noise, est = _lpm(windows, lines, config.lpm_degree)
        why = "a single period per window" if one_period else "a transient in the windows"
        notes.append(f"{est.value}: {why}, the transient removed by local polynomials")
    else:
        fr, var_noise, est = _periodic(windows, lines)
        notes.append(f"{est.value}: averaged over whole periods")
    notes.extend(_poorly_determined(fr))
    best, fits = select_order(fr, config.orders, delays=config.delays)
    if not best.supported:
        notes.append(
            f"no order in {config.orders.start}..{config.orders.stop - 1} has every pole "
            "determined by the data (a pole within a few σ of the origin is fitted noise); "
            f"order {best.order}, the lowest, is taken: try lower orders (--orders)"
        )
    if best.cost_ratio > 4.0:
        notes.append(
            f"the order-{best.order} fit leaves {best.cost_ratio:.1f} times the residual the "
            "response's σ explains: the plant is not linear over the band, or needs a higher "
            "order (--orders); the perturbation weight covers the difference"
        )
    top = float(np.max(fr.freqs_hz))
    if best.spurious(top):
        notes.append(f"the fit has resonances above the band: {best.spurious(top)}")
    n = windows[0].period_samples
    ts = windows[0].ts_s
    grey = None
    if config.grey_box is GreyBoxModel.TWO_TANK:
        # the operating point is measured: the outputs' mean over the windows
        y = np.concatenate([w.y for w in windows])
        prior = config.grey_box_prior or RigParams()
        grey = fit_two_tank(
            fr,
            ts,
            GreyBoxConfig(float(y[:, 0].mean()), float(y[:, 1].mean()), prior=prior),
        )
        undetermined = [e.name for e in grey.estimates if e.status is ParameterStatus.UNDETERMINED]
        notes.append(
            f"grey box two-tank: residual {grey.cost_ratio:.2f} x what σ explains"
            + (
                f"; not determined by the data, pinned at the prior: {undetermined}"
                if undetermined
                else ""
            )
        )
    return Identification(
        response=fr,
        estimator=est,
        var_noise=var_noise,
        fit=best,
        fits=tuple(fits),
        ts_s=ts,
        period_samples=n,
        n_windows=len(windows),
        config=config,
        notes=tuple(notes),
        grey_box=grey,
        distortion=None if config.lines is None else _distortion(windows, config.lines),
    )


def _weights(ident: Identification, *, cover: bool) -> tuple[FittedWeight, ...]:
    """Per output, a weight over the fit's relative error (largest over the inputs).

    ``cover``: over ``(|H - G| + 2 σ) / |G|`` times the margin (the response's uncertainty
    counted as error); else over ``|H - G| / |G|`` (a shape, margin 1).
    """
    fr, fit, config = ident.response, ident.nominal, ident.config
    ts_s, n = ident.ts_s, ident.period_samples
    model = fit.response(fr.freqs_hz)
    spread = 2.0 * np.sqrt(fr.var) if cover else 0.0
    need = (np.abs(fr.g - model) + spread) / np.maximum(np.abs(model), 1e-300)
    theta = 2 * math.pi * fr.lines / n
    margin = config.margin if cover else 1.0
    out = []
    for c in range(fr.g.shape[1]):
        required = np.max(need[:, c, :], axis=1)
        # the weight's corners are fitted on at most _WEIGHT_LINES lines (each group's
        # largest requirement), then its gain is raised until it covers every line
        keep = _envelope(required, _WEIGHT_LINES)
        fitted = fit_weight(
            theta[keep],
            required[keep],
            ts_s,
            margin=margin,
            max_order=config.max_weight_order,
            intersample=ident.intersample,
        )
        out.append(_covering(fitted, theta, required * margin, ts_s, ident.intersample))
    return tuple(out)


_WEIGHT_LINES = 60
"""Most lines a weight's corner frequencies are fitted on (the fit is Nelder-Mead over every
line given); the gain then covers every line."""


def _envelope(required: np.ndarray, most: int) -> np.ndarray:
    """(k,) int: the line of the largest requirement in each of ``most`` consecutive groups."""
    if required.size <= most:
        return np.arange(required.size)
    groups = np.array_split(np.arange(required.size), most)
    return np.array([g[int(np.argmax(required[g]))] for g in groups])


def _covering(
    fitted: FittedWeight,
    theta: np.ndarray,
    required: np.ndarray,
    ts_s: float,
    intersample: Intersample = Intersample.EXACT,
) -> FittedWeight:
    """``fitted`` with its gain raised (if need be) to cover ``required`` at every line."""
    sys = lti.from_transfer_function(fitted.num, fitted.den)
    mag = np.abs(lti.bin_response(sys, theta, ts_s, intersample)[:, 0, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        short = np.where(required > 0, required / mag, 0.0)
    factor = max(float(np.max(short, initial=0.0)), 1.0)
    if factor == 1.0 or not math.isfinite(factor):
        return dataclasses.replace(fitted, magnitude=mag)
    return dataclasses.replace(
        fitted,
        num=tuple(float(x) * factor for x in fitted.num),
        gain=fitted.gain * factor,
        magnitude=mag * factor,
    )


def _matrix(x: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.atleast_2d(x)]


def model_document(
    ident: Identification,
    name: str,
    inputs: Sequence[str],
    outputs: Sequence[str],
    *,
    noise_weights: Sequence[float],
    cover: bool = False,
    shape_margin: float = 1.0,
) -> dict[str, Any]:
    """The identified model set as a model-file document (``validate`` reads it as it is).

    The nominal is the fit's state space (continuous, s), evaluated exactly at the bins
    (``intersample: exact``): it was fitted to the sampled response as measured, so a hold
    applied again would count the sampling twice (docs/theory.md §14, §16). With a grey box
    (:attr:`Identification.grey_box`) the nominal is the rig's linearisation, a continuous
    plant driven by held commands (``intersample: zoh``, docs/theory.md §17). One
    output-multiplicative perturbation per output with its fitted weight; noise on every
    output with the flat weights ``noise_weights`` (model units, one per output); the band
    the identification used. ``cover``: the perturbation weights are the covers (what the
    response demands), else the shapes times ``shape_margin``.
    """
    ss = ident.nominal.state_space()
    freqs = ident.response.freqs_hz
    what = (
        f"order {ident.fit.order} per input"
        if ident.grey_box is None
        else f"grey box two-tank linearised at h1={ident.grey_box.op.height:.4g}, "
        f"t1={ident.grey_box.op.temperature:.4g}"
    )
    doc: dict[str, Any] = {
        "name": name,
        "description": (
            f"identified: {what}, {ident.estimator.value}, "
            f"{freqs.size} lines {freqs.min():.4g}..{freqs.max():.4g} Hz"
        ),
        "inputs": list(inputs),
        "outputs": list(outputs),
        "intersample": ident.intersample.value,
        "nominal": {
            "ss": {"A": _matrix(ss.a), "B": _matrix(ss.b), "C": _matrix(ss.c), "D": _matrix(ss.d)}
        },
        "band": f"{float(freqs.min()):.6g}:{float(freqs.max()):.6g}",
    }
    if ss.output_delays_s:
        doc["nominal"]["ss"]["output_delays_s"] = [float(t) for t in ss.output_delays_s]
    perturbations = []
    weights = ident.covers if cover else ident.shapes
    for c, (out, w) in enumerate(zip(outputs, weights, strict=True)):
        if w.gain <= 0.0:
            continue
        perturbations.append(
            {
                "name": f"{out}_multiplicative",
                "kind": "output_multiplicative",
                "outputs": [outputs[c]],
                "weight": {
                    "tf": {
                        "num": [float(x) * (1.0 if cover else shape_margin) for x in w.num],
                        "den": list(w.den),
                    }
                },
            }
        )
    if perturbations:
        doc["perturbations"] = perturbations
    doc["noise"] = [
        {"name": f"{out}_noise", "outputs": [out], "weight": {"gain": max(float(wn), 1e-12)}}
        for out, wn in zip(outputs, noise_weights, strict=True)
    ]
    return doc


@dataclass(frozen=True)
class IdentifiedModel:
    """The identified model set and how it did on the windows.

    Attributes:
        document: the model file (a mapping ``model_from_dict`` reads).
        noise: the noise weights set from the data (docs/theory.md §13).
        beta: (n_windows,) β of the model set on each window.
        held_out: (n_windows,) bool, the windows that took no part in setting the weights
            (all False where there was nothing to hold out).
        calibrated: the perturbation weights were scaled together on fit windows by
            ``calibrate`` (False: the response's covers were written, nothing held out).
        factors: the joint factors on the weight shapes (one per output; empty when not
            calibrated).
    """

    document: dict[str, Any]
    noise: NoiseWeights
    beta: np.ndarray
    held_out: np.ndarray
    calibrated: bool
    factors: tuple[float, ...] = ()

    def weights(self) -> list[tuple[str, list[float], list[float]]]:
        """Each perturbation block's name and weight (numerator, denominator in s)."""
        out = []
        for p in self.document.get("perturbations", []):
            tf = p["weight"]["tf"]
            out.append((p["name"], [float(x) for x in tf["num"]], [float(x) for x in tf["den"]]))
        return out


def _placeholder_gains(n_y: int) -> list[float]:
    """Noise gains that only make a document loadable before the noise is set."""
    return [1.0] * n_y


def _one_period_spread(fr: FrequencyResponse, n: int) -> NoiseSpread:
    """The output noise per bin of a one-period window, from the local polynomials' residual.

    Every bin takes its nearest line's estimate; the estimate at a line has the local fit's
    degrees of freedom.
    """
    if fr.noise_var is None:
        raise IdentificationError("the response carries no noise estimate")
    bins = np.arange(n // 2 + 1)
    nearest = np.abs(bins[:, None] - fr.lines[None, :]).argmin(axis=1)
    var = fr.noise_var[nearest].copy()
    var[0] = 0.0
    return NoiseSpread(var, nearest, fr.noise_var, float(max(fr.n_periods - 1, 1)), 1)


def _betas(windows: Sequence[Window], model: LFTModel) -> np.ndarray:
    """(n,) β of the model on each window, its datum built as ``validate`` builds it."""
    return window_betas([w.datum() for w in windows], model)


def _can_hold_out(windows: Sequence[Window]) -> bool:
    return len(windows) >= 2 or windows[0].n_periods >= 2


def identified_model(
    ident: Identification,
    windows: Sequence[Window],
    name: str,
    inputs: Sequence[str],
    outputs: Sequence[str],
    *,
    quantile: float = NOISE_QUANTILE,
    budget: float = NOISE_BUDGET,
    margin: float = 1.2,
) -> IdentifiedModel:
    """The model set: the nominal, noise weights from the data, then the perturbations.

    1. Noise weights: with two or more periods per window from the period-to-period spread
       of the fit windows (:func:`~twotank_validation.calibrate.noise.fitted_noise_weights`); with
       one period from the local polynomials' residual.
    2. Perturbation weights: where windows can be held out, the weight shapes (the fit's
       relative error) scaled together by ``calibrate`` on the fit windows, the smallest
       factors for which no fit window is invalidated, times ``margin``, and judged on the
       held-out windows; else the covers of the response's error with its 2 σ.

    Raises:
        IdentificationError: the noise cannot be estimated, or no scaling explains the fit
            windows.
    """
    draft = model_document(
        ident, name, inputs, outputs, noise_weights=_placeholder_gains(len(outputs))
    )
    n = windows[0].period_samples
    try:
        if all(w.n_periods >= 2 for w in windows):
            fitted = fitted_noise_weights(
                windows, model_from_dict(draft, name), quantile=quantile, budget=budget
            )
        else:
            first = windows[0].datum()
            fitted = noise_weights(
                _one_period_spread(ident.response, n),
                first.bin_weights,
                first.n_samples,
                mask=validation_band(first, model_from_dict(draft, name)),
                quantile=quantile,
                budget=budget,
            )
    except DatumError as err:  # CalibrationError is one
        raise IdentificationError(f"the noise weights cannot be set: {err}") from err
    gains = fitted.gains.tolist()
    if not _can_hold_out(windows):
        doc = model_document(ident, name, inputs, outputs, noise_weights=gains, cover=True)
        beta = _betas(windows, model_from_dict(doc, name))
        return IdentifiedModel(doc, fitted, beta, np.zeros(len(windows), bool), False)
    doc = model_document(ident, name, inputs, outputs, noise_weights=gains)
    blocks = [p["name"] for p in doc.get("perturbations", [])]
    if not blocks:
        beta = _betas(windows, model_from_dict(doc, name))
        return IdentifiedModel(doc, fitted, beta, np.zeros(len(windows), bool), False)
    try:
        cal = calibrate(
            windows,
            doc,
            CalibrationConfig(margin=margin, together=True),
            blocks=blocks,
            source=name,
        )
    except DatumError as err:
        raise IdentificationError(f"the perturbation weights cannot be calibrated: {err}") from err
    if cal.joint is not None and cal.joint.fit.common == 0.0:
        # the noise weights explain the fit windows without any perturbation: the fit's own
        # error at the lines (the shapes) times the margin is written, and judged
        final_doc = model_document(
            ident, name, inputs, outputs, noise_weights=gains, shape_margin=margin
        )
        fit_w, held_w = split_windows(windows)  # as calibrate split them
        beta = _betas([*fit_w, *held_w], model_from_dict(final_doc, name))
        held = np.array([False] * len(fit_w) + [True] * len(held_w))
        return IdentifiedModel(final_doc, fitted, beta, held, False)
    if cal.document is None or cal.joint is None:
        raise IdentificationError(
            "no scaling of the perturbation weights explains the fit windows: the plant is "
            "not linear over the band or changed during the record; identify on a steady "
            "stretch (--start/--end) or a narrower band (--band)"
        )
    result = dict(cal.document)
    result["name"] = name
    result["description"] = doc["description"]
    return IdentifiedModel(
        result,
        fitted,
        cal.judged.beta_after,
        cal.judged.held_out,
        True,
        tuple(float(x) for x in cal.joint.fit.factors),
    )
