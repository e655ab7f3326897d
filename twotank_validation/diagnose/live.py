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

Confidence (in [0, 1]):

* a dynamic effect: the explained fraction of the held-out error above the noise floor,
  halved when the best runner-up is a close call (its score within the parsimony factor);
* a saturation or stuck valve: the fraction of the held-out error the clip removes;
* an operating-point move: ``cos² best − cos² runner-up`` of the direction match, times, for
  an output alone, ``1 − RSS_chosen / RSS_other`` of the step-versus-settle fit;
* ``unexplained``: one minus the explained fraction of the best partial fit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from twotank_validation.core.datum import NormConvention
from twotank_validation.core.oppoint import OperatingPoint
from twotank_validation.diagnose.diagnosis import Diagnosis, diagnose
from twotank_validation.diagnose.effects import Nominal, channel_time_constants
from twotank_validation.diagnose.inputs import DiagnosisConfig, DiagnosisError, Window
from twotank_validation.diagnose.steady import dc_gain
from twotank_validation.errors import TwotankError
from twotank_validation.online.livediag import (
    STUCK,
    UNEXPLAINED,
    DiagnosisJob,
    LiveDiagnosis,
    WindowData,
)

STUCK_FRACTION = 0.9
"""A saturation that clips at least this fraction of the samples is a stuck valve."""

MATERIAL_MOVE = 0.01
"""An output's steady mean moved materially: by more than this (model units, five times the
operating-point check's default dead band)."""

THERMAL = ("heat_loss", "hot_supply")
"""Catalogue effects that move the temperature alone at steady state."""


def _windows(data: Sequence[WindowData], job: DiagnosisJob, t0_ns: int) -> list[Window]:
    return [
        Window(w.u, w.y, job.ts_s, job.period_samples, (w.start_ns - t0_ns) * 1e-9) for w in data
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
            return _answer(job, UNEXPLAINED, "", {}, 0.0, f"no model document for {job.model}")
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
            return _answer(job, UNEXPLAINED, "", {}, 0.0, f"not diagnosed: {err}")

    def name(
        self,
        job: DiagnosisJob,
        d: Diagnosis,
        nominal: Nominal,
        reference: OperatingPoint | None,
    ) -> LiveDiagnosis:
        """The most likely effect of a diagnosis (module docstring, step 3)."""
        sat = [f for f in d.findings if f.kind == "saturation"]
        if sat:
            f = sat[0]
            clipped = float(f.parameters.get("clipped_fraction", 0.0))
            kind = STUCK if clipped >= STUCK_FRACTION else "saturation"
            text = (
                f"the {f.target} valve follows no command (clips {clipped:.0%} of the samples)"
                if kind == STUCK
                else f"the {f.target} valve saturates: {f.evidence}"
            )
            conf = float(np.clip(f.heldout_reduction, 0.0, 1.0))
            return _answer(job, kind, f.target, dict(f.parameters), conf, text)
        if reference is not None:
            move = operating_point_move(job, d, nominal, reference)
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
        offsets = [f for f in d.findings if f.kind == "offset"]
        if offsets:
            f = max(offsets, key=lambda f: abs(f.parameters["offset"]))
            conf = float(np.clip(f.heldout_reduction, 0.0, 1.0))
            return _answer(job, "offset", f.target, dict(f.parameters), conf, f.evidence)
        ex = d.explained
        left = 1.0 - (ex.fraction or 0.0) if ex is not None else 1.0
        return _answer(job, UNEXPLAINED, "", {}, left, d.summary)


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
    kind: str,
    channel: str,
    parameters: Mapping[str, float],
    confidence: float,
    summary: str,
) -> LiveDiagnosis:
    return LiveDiagnosis(
        model=job.model,
        kind=kind,
        channel=channel,
        parameters={k: float(v) for k, v in parameters.items()},
        confidence=float(np.clip(confidence, 0.0, 1.0)) if math.isfinite(confidence) else 0.0,
        summary=summary,
        onset_ns=job.onset_ns,
        window_end_ns=job.trigger_end_ns,
        windows=len(job.post),
        update=job.update,
    )


def operating_point_move(
    job: DiagnosisJob, d: Diagnosis, nominal: Nominal, reference: OperatingPoint
) -> LiveDiagnosis | None:
    """The plant cause whose steady-state signature the move of the operating point matches.

    The move ``m = ȳ − y_ref − G(0)(ū − u_ref)`` (model units) is taken on the last period
    of the newest window. Candidate directions: each output alone, and each input's column
    of ``G(0)`` (one valve delivering a different flow: ``input_gain``). An output alone is
    a sensor ``offset`` when the move was a step (the per-hop means follow a step averaged
    over a period better than a first-order settle with the output's slowest time
    constant), else a plant effect (``leak`` for the level, a thermal effect for the
    temperature). None when no output moved by more than :data:`MATERIAL_MOVE`.
    """
    g0 = dc_gain(nominal)  # (ny, nu)
    outputs, inputs = d.outputs, d.inputs
    ny, nu = g0.shape
    dev = (job.means_y - reference.y) - (job.means_u - reference.u) @ g0.T  # (k, ny)
    move = dev[-1]
    if not np.any(np.abs(move) > MATERIAL_MOVE):
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
        return _answer(job, "input_gain", inputs[idx], params, conf, text)
    out = outputs[idx]
    step, settle = _step_or_settle(job, dev[:, idx], nominal, idx)
    chosen, other = (step, settle) if step <= settle else (settle, step)
    conf *= 1.0 - chosen / max(other, 1e-300)
    size = float(move[idx])
    if step <= settle:
        text = f"the {out} sensor reads {size:+.3g} off: its mean stepped at the onset"
        return _answer(job, "offset", out, {"offset": size}, conf, text)
    if out == "height":
        denom = float(np.sum(g0[idx]))
        flow = -2.0 * size / denom if denom else math.nan
        text = (
            f"the level settled {size:+.3g} lower through the tank's own time constant: a "
            f"constant extra outflow of about {flow:.3g}"
        )
        return _answer(job, "leak", out, {"level_change": size, "outflow": flow}, conf, text)
    thermal = [e for e in d.effects if e.spec.kind in THERMAL]
    kind = thermal[0].spec.kind if thermal else "heat_loss"
    channel = "hot" if kind == "hot_supply" else out
    text = f"the {out} settled {size:+.3g} off through the plant's thermal time constant"
    return _answer(job, kind, channel, {"temperature_change": size}, conf, text)


def _step_or_settle(
    job: DiagnosisJob, dev: np.ndarray, nominal: Nominal, channel: int
) -> tuple[float, float]:
    """Residual sums of squares of a step and of a first-order settle fitted to the move.

    ``dev`` (k,) is the output's steady deviation on each recent window's last period (a
    period-long mean ending at ``job.means_end_ns``). A step at ``t0`` gives, averaged over
    a period P, ``clip((t − t0)/P, 0, 1)``; a first-order settle with time constant T gives
    ``(F(t − t0) − F(t − P − t0)) / P`` with ``F(x) = x − T (1 − e^{−x/T})`` for x > 0. The
    onset ``t0`` is searched on a grid of a tenth of a period; baseline and size by least
    squares.
    """
    t = (job.means_end_ns - job.means_end_ns[0]) * 1e-9
    p_s = job.period_samples * job.ts_s
    taus = channel_time_constants(nominal, channel, job.ts_s)
    tau = max(taus) if taus else p_s / 10.0

    def ramp(x: np.ndarray) -> np.ndarray:
        return np.clip(x / p_s, 0.0, 1.0)

    def settle(x: np.ndarray) -> np.ndarray:
        def f(z: np.ndarray) -> np.ndarray:
            z = np.maximum(z, 0.0)
            return z - tau * (1.0 - np.exp(-z / tau))

        return (f(x) - f(x - p_s)) / p_s

    def rss(shape: Any) -> float:
        best = math.inf
        for t0 in np.arange(t[0] - p_s, t[-1], p_s / 10.0):
            a = np.column_stack([np.ones_like(t), shape(t - t0)])
            coef, *_ = np.linalg.lstsq(a, dev, rcond=None)
            best = min(best, float(np.sum((a @ coef - dev) ** 2)))
        return best

    return rss(ramp), rss(settle)
