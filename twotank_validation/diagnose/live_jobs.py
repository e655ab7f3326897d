"""The catalogue behind the live diagnosis: one job's windows in, the most likely effect out.

:func:`catalogue_diagnosis` is the function a
:class:`~twotank_validation.online.livediag.LiveDiagnoser` runs. For a job (windows before
and after an alarm's onset) it

1. diagnoses the windows *before* the onset against the model (what the model lacked
   already; cached per onset) and takes that model, with those effects, as the baseline;
2. diagnoses the windows *after* the onset against the baseline, with the windows before
   the onset as the reference operating point (:func:`~.diagnosis.diagnose` with
   ``reference=``), so that a bias or a leak shows;
3. names the most likely effect:

   * a *saturation* finding: the input clips; ``stuck`` when it clips
     ``STUCK_FRACTION`` or more of the samples (the valve follows no command);
   * else, when the outputs' steady means moved materially from the reference (the
     validator's operating-point check sees the same move, though it skips a window still
     settling, so the alarm may rise on the dynamics first): the *operating-point signature*
     (:func:`operating_point_move`): the direction of the move among those of the plant
     causes (an output alone; the steady-state response to one valve's flow), and, for an
     output alone, whether it moved as a step (a sensor: ``offset``) or through the plant's
     own time constant (``leak`` for the level; for the temperature the thermal effect the
     catalogue picked, ``heat_loss`` when it picked neither);
   * else the catalogue's dynamic effect that removes most of the held-out error;
   * else ``unexplained``.

Score (in [0, 1]; the diagnosis's own ranking, mapped to the answer's probability by
:func:`~.answer_probability.answer_probability`, fitted on the isolation bench):

* a dynamic effect: the explained fraction of the held-out error above the noise floor,
  halved when the best runner-up is a close call (its score within the parsimony factor);
* a saturation or stuck valve: the fraction of the held-out error the clip removes;
* an operating-point move: ``cos² best − cos² runner-up`` of the direction match, times, for
  an output alone, ``1 − RSS_chosen / RSS_other`` of the step-versus-settle fit;
* ``unexplained``: one minus the explained fraction of the best partial fit.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import scipy.signal

from twotank_validation.core.datum import NormConvention
from twotank_validation.core.oppoint import OperatingPoint
from twotank_validation.diagnose.answer_probability import answer_probability
from twotank_validation.diagnose.diagnosis import Diagnosis, diagnose
from twotank_validation.diagnose.effects import Nominal, channel_time_constants
from twotank_validation.diagnose.inputs import DiagnosisConfig, DiagnosisError, Window
from twotank_validation.diagnose.kinds import EffectKind
from twotank_validation.diagnose.level import shape_fit
from twotank_validation.diagnose.steady import dc_gain
from twotank_validation.errors import TwotankError
from twotank_validation.online.livediag import DiagnosisJob, LiveDiagnosis, WindowData

STUCK_FRACTION = 0.9
"""A saturation that clips at least this fraction of the samples is a stuck valve (so is one
whose input held constant explains the held-out windows as well as the clip, its level's
parameter counted: ``constant_cost_ratio`` ≤ 1)."""

MATERIAL_MOVE = 0.01
"""An output's steady mean moved materially: by more than this (model units, five times the
operating-point check's default dead band)."""


def _windows(data: Sequence[WindowData], job: DiagnosisJob, t0_ns: int) -> list[Window]:
    return [
        Window(w.u, w.y, job.ts_s, job.period_samples, (w.start_ns - t0_ns) * 1e-9, job.measured)
        for w in data
    ]


def _means(windows: Sequence[Window]) -> OperatingPoint:
    return OperatingPoint(
        u=np.mean([w.u.mean(axis=0) for w in windows], axis=0),
        y=np.mean([w.y.mean(axis=0) for w in windows], axis=0),
    )


class CatalogueDiagnosis:
    """The job runner of the live diagnosis (module docstring); callable on a job.

    Args:
        documents: model name -> its model document (as loaded from YAML).
        config: settings of each diagnosis.
        convention: norm convention of the validations.
    """

    def __init__(
        self,
        documents: Mapping[str, Mapping[str, Any]],
        config: DiagnosisConfig | None = None,
        *,
        convention: NormConvention = NormConvention.POWER,
    ) -> None:
        self.documents = dict(documents)
        self.config = config or DiagnosisConfig()
        self.convention = convention
        self._baseline: dict[str, tuple[int, Mapping[str, Any]]] = {}

    def baseline(self, job: DiagnosisJob, pre: Sequence[Window]) -> Mapping[str, Any]:
        """The model with the effects it lacked before the onset (cached per onset)."""
        cached = self._baseline.get(job.model)
        if cached is None or cached[0] != job.onset_ns:
            doc = self.documents[job.model]
            base = doc
            if pre and (len(pre) > 1 or pre[0].n_periods >= 2):
                try:
                    before = diagnose(pre, doc, self.config, convention=self.convention)
                    base = before.document if before.document is not None else doc
                except DiagnosisError:
                    base = doc
            cached = self._baseline[job.model] = (job.onset_ns, base)  # one onset per model
        return cached[1]

    def __call__(self, job: DiagnosisJob) -> LiveDiagnosis:
        """Diagnose one job (never raises: a job that cannot be diagnosed is unexplained)."""
        if job.model not in self.documents:
            return _answer(
                job, EffectKind.UNEXPLAINED, "", {}, 0.0, f"no model document for {job.model}"
            )
        job = dated(job, Nominal.from_document(self.documents[job.model]))
        t0 = job.pre[0].start_ns if job.pre else job.post[0].start_ns
        pre = _windows(job.pre, job, t0)
        post = _windows(job.post, job, t0)
        try:
            base = self.baseline(job, pre)
            reference = _means(pre) if pre else None
            d = diagnose(
                post,
                base,
                self.config,
                source=f"model {job.model} before the onset",
                convention=self.convention,
                reference=reference,
            )
            return self.name(job, d, Nominal.from_document(base), reference)
        except TwotankError as err:
            return _answer(job, EffectKind.UNEXPLAINED, "", {}, 0.0, f"not diagnosed: {err}")

    def name(
        self,
        job: DiagnosisJob,
        d: Diagnosis,
        nominal: Nominal,
        reference: OperatingPoint | None,
    ) -> LiveDiagnosis:
        """The most likely effect of a diagnosis (module docstring, step 3)."""
        sat = [f for f in d.findings if f.kind == EffectKind.SATURATION]
        if sat:
            f = sat[0]
            clipped = float(f.parameters.get("clipped_fraction", 0.0))
            constant = float(f.parameters.get("constant_cost_ratio", math.inf))
            stuck = clipped >= STUCK_FRACTION or constant <= 1.0
            kind = EffectKind.STUCK if stuck else EffectKind.SATURATION
            text = (
                f"the {f.target} valve follows no command (clips {clipped:.0%} of the samples)"
                if stuck
                else f"the {f.target} valve saturates: {f.evidence}"
            )
            conf = float(np.clip(f.heldout_reduction, 0.0, 1.0))
            return _answer(job, kind, f.target, dict(f.parameters), conf, text)
        if reference is not None:
            move = operating_point_move(job, d, nominal, reference, self.config)
            if move is not None:
                return move
        if d.effects:
            e = max(d.effects, key=lambda e: e.reduction)
            ex = d.explained
            conf = (ex.fraction or 0.0) if ex is not None else 0.0
            close = bool(d.runners_up and d.runners_up[0].close_call)
            if close:
                conf *= 0.5
            params = {n: float(v) for n, v in zip(e.spec.names, e.values, strict=True)}
            text = f"{e.spec.label(d.outputs)}; {d.summary}"
            return _answer(job, e.spec.kind, e.spec.target(d.outputs), params, conf, text)
        offsets = [f for f in d.findings if f.kind == EffectKind.OFFSET]
        if offsets:
            f = max(offsets, key=lambda f: abs(f.parameters["offset"]))
            conf = float(np.clip(f.heldout_reduction, 0.0, 1.0))
            return _answer(job, EffectKind.OFFSET, f.target, dict(f.parameters), conf, f.evidence)
        ex = d.explained
        left = 1.0 - (ex.fraction or 0.0) if ex is not None else 1.0
        return _answer(job, EffectKind.UNEXPLAINED, "", {}, left, d.summary)


def catalogue_diagnosis(
    documents: Mapping[str, Mapping[str, Any]],
    config: DiagnosisConfig | None = None,
    *,
    convention: NormConvention = NormConvention.POWER,
) -> CatalogueDiagnosis:
    """The job runner of the live diagnosis for these model documents (name -> document)."""
    return CatalogueDiagnosis(documents, config, convention=convention)


def _answer(  # noqa: PLR0917 - the fields of the answer
    job: DiagnosisJob,
    kind: EffectKind,
    channel: str,
    parameters: Mapping[str, float],
    score: float,
    summary: str,
) -> LiveDiagnosis:
    score = float(np.clip(score, 0.0, 1.0)) if math.isfinite(score) else 0.0
    return LiveDiagnosis(
        model=job.model,
        kind=kind.value,
        channel=channel,
        parameters={k: float(v) for k, v in parameters.items()},
        score=score,
        summary=summary,
        onset_ns=job.onset_ns,
        window_end_ns=job.trigger_end_ns,
        windows=len(job.post),
        update=job.update,
        probability=answer_probability(kind.value, score),
    )


def operating_point_move(
    job: DiagnosisJob,
    d: Diagnosis,
    nominal: Nominal,
    reference: OperatingPoint,
    config: DiagnosisConfig | None = None,
) -> LiveDiagnosis | None:
    """The plant cause whose steady-state signature the move of the operating point matches.

    The move ``m = ȳ − y_ref − G(0)(ū − u_ref)`` (model units) is taken on the last period
    of the newest window. Candidate directions: each output alone, and each input's column
    of ``G(0)`` (one valve delivering a different flow: ``input_gain``). The level alone is
    a sensor ``offset`` when the move was a step (the per-hop means follow a step averaged
    over a period better than a first-order settle with the output's slowest time
    constant), else a ``leak``. Any other output alone is judged by its dynamics
    (:func:`_thermal_or_offset`). None when no output moved by more than
    :data:`MATERIAL_MOVE`.
    """
    g0 = dc_gain(nominal)  # (ny, nu)
    outputs, inputs = d.outputs, d.inputs
    ny, nu = g0.shape
    dev = (job.means_y - reference.y) - (job.means_u - reference.u) @ g0.T  # (k, ny)
    move = dev[-1]
    if not np.any(np.abs(move) > MATERIAL_MOVE):
        return None
    if not job.raised_by.operating_point and not np.any(np.abs(move) > 2 * MATERIAL_MOVE):
        # a small move that did not itself invalidate the model (a delay inside a feedback
        # loop shifts the means of a nonlinear plant a little): the dynamics name the fault
        return None
    cands: list[tuple[str, int, np.ndarray]] = [("output", c, np.eye(ny)[c]) for c in range(ny)]
    cands += [("input", i, g0[:, i]) for i in range(nu)]
    norm = float(np.linalg.norm(move))
    cos = [abs(float(v @ move)) / max(float(np.linalg.norm(v)) * norm, 1e-300) for _, _, v in cands]
    order = np.argsort(cos)[::-1]
    best, second = int(order[0]), int(order[1])
    conf = max(cos[best] ** 2 - cos[second] ** 2, 0.0)
    what, idx, vec = cands[best]
    if what == "input":
        delta = float(vec @ move / max(float(vec @ vec), 1e-300))
        u_abs = abs(float(reference.u[idx]))
        params = {"flow_change": delta}
        if u_abs > 0:
            params["gain_error"] = delta / u_abs
        text = (
            f"the {inputs[idx]} valve delivers {delta:+.3g} (model units) at steady state: the "
            f"operating point moved by {np.array2string(move, precision=3)} along its "
            "steady-state response"
        )
        return _answer(job, EffectKind.INPUT_GAIN, inputs[idx], params, conf, text)
    out = outputs[idx]
    size = float(move[idx])
    step, settle = _step_or_settle(job, mean_deviations(job, nominal)[:, idx], nominal, idx)
    chosen, other = (step, settle) if step <= settle else (settle, step)
    conf *= 1.0 - chosen / max(other, 1e-300)
    if out != "height":
        # with the inputs held (open loop) a sensor offset leaves the plant where it was,
        # so the dynamics tell it from a plant effect; where the inputs moved (a feedback
        # loop compensating) the plant moved either way and the time course decides
        inputs_moved = bool(np.any(np.abs(job.means_u[-1] - reference.u) > MATERIAL_MOVE))
        cfg = config or DiagnosisConfig()
        stepped = inputs_moved and step <= settle
        return _thermal_or_offset(job, d, out, size, conf, cfg, stepped=stepped)
    if step <= settle:
        text = f"the {out} sensor reads {size:+.3g} off: its mean stepped at the onset"
        return _answer(job, EffectKind.OFFSET, out, {"offset": size}, conf, text)
    denom = float(np.sum(g0[idx]))
    flow = -2.0 * size / denom if denom else math.nan
    text = (
        f"the level settled {size:+.3g} lower through the tank's own time constant: a "
        f"constant extra outflow of about {flow:.3g}"
    )
    return _answer(job, EffectKind.LEAK, out, {"level_change": size, "outflow": flow}, conf, text)


def _thermal_or_offset(  # noqa: PLR0917 - the move and how it was matched
    job: DiagnosisJob,
    d: Diagnosis,
    out: str,
    size: float,
    conf: float,
    cfg: DiagnosisConfig,
    *,
    stepped: bool,
) -> LiveDiagnosis:
    """A temperature that moved alone: a sensor offset, a heat loss or a hot-supply change.

    The three move the temperature alone at steady state. A sensor offset changes no
    response where the inputs stay put (open loop: the true temperature does not move), so
    that the windows after the onset need no effect (the held-out error is not material, or
    no candidate removes ``min_reduction`` of it). Where the inputs moved (a feedback loop
    holds the measured temperature, so a sensor offset moves the true one and the responses
    with it) it is told by its time course: a step in the period means (``stepped``: a step
    fits them better than a settle through the thermal time constant,
    :func:`_step_or_settle` on :func:`mean_deviations`). For a mixing tank a
    supply-temperature change scales both valves' temperature responses by one factor ``1 +
    Δt/(t − t_cold)`` with the time constant unchanged, an output ``gain`` on the
    temperature of the move's sign; a heat loss also makes the temperature settle faster,
    which the catalogue's ``heat_loss`` fits. (The catalogue's own ``hot_supply`` is
    linearised at the temperature before the move and misses the share of the cold valve, so
    it is not used to decide here.)
    Confidence: the direction match and the step-or-settle contrast, times the gap between
    the two candidates' held-out reductions for a plant cause.
    """
    reds: dict[EffectKind, tuple[float, float]] = {}  # kind -> (held-out reduction, first value)
    for e in d.candidates:
        wanted = e.spec.kind is EffectKind.HEAT_LOSS or (
            e.spec.kind is EffectKind.GAIN and e.spec.target(d.outputs) == out
        )
        if wanted and (e.spec.kind not in reds or e.reduction > reds[e.spec.kind][0]):
            reds[e.spec.kind] = (float(e.reduction), float(e.values[0]))
    none = (-math.inf, 0.0)
    gain, loss = reds.get(EffectKind.GAIN, none), reds.get(EffectKind.HEAT_LOSS, none)
    material = d.noise_ratio >= cfg.material
    if stepped or not material or max(gain[0], loss[0]) < cfg.min_reduction:
        text = (
            f"the {out} sensor reads {size:+.3g} off: its mean stepped at the onset"
            if stepped
            else f"the {out} sensor reads {size:+.3g} off: its mean moved while the responses "
            "stayed as before"
        )
        return _answer(job, EffectKind.OFFSET, out, {"offset": size}, conf, text)
    if gain[0] >= loss[0] and gain[1] * size > 0:
        g = gain[1]
        text = (
            f"the {out} settled {size:+.3g} off and both valves' {out} responses are "
            f"scaled by {1.0 + g:.3f} with the time constant unchanged: the hot supply "
            f"temperature changed (about {size / g:+.3g} from the cold supply)"
        )
        params = {"temperature_change": size, "response_gain": g}
        return _answer(
            job, EffectKind.HOT_SUPPLY, "hot", params, conf * (gain[0] - max(loss[0], 0.0)), text
        )
    text = (
        f"the {out} settled {size:+.3g} off and settles faster than modelled: heat is lost "
        f"at a rate of about {loss[1]:.3g} /s"
    )
    params = {"temperature_change": size, "rate_per_s": loss[1]}
    return _answer(
        job, EffectKind.HEAT_LOSS, out, params, conf * (loss[0] - max(gain[0], 0.0)), text
    )


def _shape_fit(
    job: DiagnosisJob, dev: np.ndarray, nominal: Nominal, channel: int, shape: str
) -> tuple[float, float, float]:
    """A step or a first-order settle fitted to an output's steady deviations.

    ``dev`` (k,) is the output's steady deviation on each recent window's last period (a
    period-long mean ending at ``job.means_end_ns``). A step at ``t0`` gives, averaged over
    a period P, ``clip((t − t0)/P, 0, 1)``; a first-order settle (``shape="settle"``) with the
    output's slowest time constant T gives ``(F(t − t0) − F(t − P − t0)) / P`` with
    ``F(x) = x − T (1 − e^{−x/T})`` for x > 0. The onset ``t0`` is searched on a grid of a
    tenth of a period; baseline and size by least squares.

    Returns:
        ``(rss, t0_s, size)``: residual sum of squares (model units²), the fitted onset (s
        after ``job.means_end_ns[0]``) and the size of the change (model units).
    """
    t = (job.means_end_ns - job.means_end_ns[0]) * 1e-9
    p_s = job.period_samples * job.ts_s
    taus = channel_time_constants(nominal, channel, job.ts_s)
    tau = max(taus) if taus else p_s / 10.0
    return shape_fit(t, dev, p_s, tau, shape)


def _step_or_settle(
    job: DiagnosisJob, dev: np.ndarray, nominal: Nominal, channel: int
) -> tuple[float, float]:
    """Residual sums of squares of a step and of a first-order settle (:func:`_shape_fit`)."""
    return (
        _shape_fit(job, dev, nominal, channel, "step")[0],
        _shape_fit(job, dev, nominal, channel, "settle")[0],
    )


def change_onset(job: DiagnosisJob, nominal: Nominal) -> int | None:
    """When the operating point started to move, from the per-hop means (ns), or None.

    The steady deviation ``ȳ − G(0) ū`` of each output (model units; constant while the
    plant is the model, whatever the inputs do, so it also sees a fault a feedback loop
    hides in the inputs) is fitted a step and a settle (:func:`_shape_fit`); the output
    that moved most, by more than :data:`MATERIAL_MOVE`, dates the change by its better
    fit. None when no output moved materially or the change is not inside the means kept.
    """
    if len(job.means_end_ns) < 3:
        return None
    dev = mean_deviations(job, nominal)
    best: tuple[float, float] | None = None  # (|size|, t0)
    for c in range(dev.shape[1]):
        fits = [_shape_fit(job, dev[:, c], nominal, c, s) for s in ("step", "settle")]
        _rss, t0, size = min(fits)
        if abs(size) > MATERIAL_MOVE and (best is None or abs(size) > best[0]):
            best = (abs(size), t0)
    if best is None or best[1] <= 0.0:
        return None
    return int(job.means_end_ns[0] + round(best[1] * 1e9))


def mean_deviations(job: DiagnosisJob, nominal: Nominal) -> np.ndarray:
    """Each output's period mean less the nominal's response to the input means: (k, ny).

    ``d_k = ȳ_k − ȳ_0 − (P ∗ (ū − ū_0))(t_k)``, model units, at the end stamps
    ``job.means_end_ns``. A period mean is a moving average, which commutes with the plant,
    so the output means are the plant's response to the input means: simulated here
    (scipy.signal.lsim, the input means interpolated linearly between hops, from rest at
    the first), so that what the inputs did, a feedback loop's compensation or a setpoint
    change included, leaves the deviation in its settling as at steady state. Constant
    while the plant is the nominal; a fault shows in it with its own time course. With
    input means that never moved, stamps not evenly spaced (a gap in the judged
    windows) or a discrete-time nominal, the steady-state version ``ȳ − ȳ_0 − G(0)(ū − ū_0)``.
    """
    du = job.means_u - job.means_u[0]
    dy = job.means_y - job.means_y[0]
    t = (job.means_end_ns - job.means_end_ns[0]) * 1e-9
    steps = np.diff(t)
    even = steps.size > 0 and np.allclose(steps, steps[0], rtol=1e-6) and steps[0] > 0
    if not even or not np.any(du) or nominal.dt_s is not None:  # discrete: steady state
        return np.asarray(dy - du @ dc_gain(nominal).T)
    sys = scipy.signal.StateSpace(nominal.a, nominal.b, nominal.c, nominal.d)
    _, ysim, _ = scipy.signal.lsim(sys, du, t, interp=True)
    return np.asarray(dy - np.reshape(ysim, dy.shape))


def dated(job: DiagnosisJob, nominal: Nominal) -> DiagnosisJob:
    """The job with its reference windows ending before the change (:func:`change_onset`).

    A slow fault (a heat loss, a changed supply) can leave windows valid after it started,
    so the validator's onset (the end of the last valid window) comes late and its windows
    before the onset already hold part of the move. When the means date the change earlier,
    the newest non-overlapping windows ending at or before it (from ``pre`` and ``earlier``)
    become the reference, and the onset is that date; else the job is returned unchanged.
    """
    t0 = change_onset(job, nominal)
    if t0 is None or t0 >= job.onset_ns:
        return job
    n_pre = len(job.pre)
    before = [w for w in (*job.earlier, *job.pre) if w.end_ns <= t0]
    if n_pre == 0 or not before:
        return job
    pre = tuple(before[-n_pre:])
    earlier = tuple(before[:-n_pre])
    return dataclasses.replace(job, onset_ns=t0, pre=pre, earlier=earlier)
