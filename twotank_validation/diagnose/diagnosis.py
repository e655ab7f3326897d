"""The driver: the effect (or pair) a model lacks, judged on held-out windows.

Fits every effect of the catalogue, judges each on the held-out windows, keeps the best one
(or pair) and writes the changed model document.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.stats

from twotank_validation.core.datum import Datum, NormConvention
from twotank_validation.core.model import model_from_dict
from twotank_validation.core.oppoint import OperatingPoint
from twotank_validation.diagnose.distortion import finding_summary, reported_effects
from twotank_validation.diagnose.effects import (
    EffectSpec,
    Nominal,
    catalogue,
    channel_time_constants,
)
from twotank_validation.diagnose.evidence import EvidencePoints, evidence, evidence_points
from twotank_validation.diagnose.fit import (
    Assessment,
    BinData,
    Uncertainty,
    _apply_all,
    assess,
    bin_data,
    cost,
    fit_effects,
    fit_uncertainty,
    noise_floor,
    output_costs,
    output_noise_floors,
)
from twotank_validation.diagnose.inputs import (
    DiagnosisConfig,
    DiagnosisError,
    Window,
    split_windows,
)
from twotank_validation.diagnose.kinds import EffectKind
from twotank_validation.diagnose.level import (
    LEVEL,
    Course,
    DynamicsTest,
    LevelVerdict,
    Tank,
    decide,
    dynamics_test,
    leak_spec,
    level_moved,
)
from twotank_validation.diagnose.steady import Finding, dc_gain
from twotank_validation.errors import TwotankError


@dataclass(frozen=True)
class FittedEffect:
    """An effect with fitted parameters.

    Attributes:
        spec: the catalogue entry.
        values: fitted parameters, in ``spec.names`` order (SI units).
        fit_cost: scaled squared error on the fit windows with the effect.
        heldout_cost: the same on the held-out windows.
        reduction: fraction of the held-out error (penalised) removed, relative to the model
            it was added to.
        evidence: why the data point at it (or, for a rejected one, why not).
        uncertainty: standard errors and confidence intervals of ``values`` (chosen effects).
        points: the bins, curve and R^2 the evidence text quotes (chosen effects; the
            evidence figure draws exactly these).
    """

    spec: EffectSpec
    values: np.ndarray
    fit_cost: float
    heldout_cost: float
    reduction: float
    evidence: str = ""
    uncertainty: Uncertainty | None = None
    points: EvidencePoints | None = field(default=None, repr=False)

    def to_dict(self, outputs: Sequence[str]) -> dict[str, Any]:
        """The documented JSON entry of an effect."""
        out: dict[str, Any] = {
            "kind": self.spec.kind.value,
            "channel": self.spec.target(outputs),
            "parameters": {
                **{n: float(v) for n, v in zip(self.spec.names, self.values, strict=True)},
                **{n: float(v) for n, v in self.spec.fixed.items()},
            },
            "evidence": self.evidence,
            "heldout_reduction": self.reduction,
        }
        if self.uncertainty is not None:
            out["uncertainty"] = self.uncertainty.to_dict(self.spec.names)
        if self.spec.source is not None:
            out["source"] = outputs[self.spec.source]
        return out


@dataclass(frozen=True)
class RunnerUp:
    """A candidate (single effect or pair) that was not chosen, by its held-out score.

    Attributes:
        label: the effect, or the two effects joined by ``" + "``.
        n_params: fitted parameters.
        heldout_cost: penalised held-out cost (the selection score, lower is better).
        reduction: fraction of the model's held-out error it removes (penalised).
        close_call: its score is within ``DiagnosisConfig.parsimony`` of the chosen
            effects' (``None`` when nothing was chosen).
    """

    label: str
    n_params: int
    heldout_cost: float
    reduction: float
    close_call: bool | None

    def to_dict(self) -> dict[str, Any]:
        """JSON entry."""
        return {
            "candidate": self.label,
            "n_params": self.n_params,
            "heldout_reduction": self.reduction,
            "heldout_cost_penalised": self.heldout_cost,
            "close_call": self.close_call,
        }


@dataclass(frozen=True)
class Explained:
    """How much of the held-out error the chosen effects leave, and whether it is noise.

    Costs are the scaled squared error at the held-out excited bins (the fit criterion);
    the noise floor is the cost the measurement noise alone gives there (non-harmonic bins).

    Attributes:
        fraction: share of the error above the noise floor that the effects remove,
            ``1 - (J_after - F)+ / (J_before - F)``, in [0, 1] (0 when nothing was added);
            ``None`` when the model's error is not material (``J_before < material F``):
            nothing to explain.
        fraction_raw: ``1 - J_after / J_before`` (noise included).
        noise_ratio_after: ``J_after / F``.
        per_output: per output name, ``{"explained_fraction", "noise_ratio_before",
            "noise_ratio_after", "material_left"}``.
        white: per output, the residual after passes the whiteness test on most held-out
            windows (more than half).
        independent: per (output, input), the residual after passes the cross-correlation
            test on most held-out windows.
        unexplained: a material part is left on some output, or the residual after is
            correlated with an input.
        reasons: why ``unexplained``, in words.
    """

    fraction: float | None
    fraction_raw: float
    noise_ratio_after: float
    per_output: dict[str, dict[str, Any]]
    white: dict[str, bool]
    independent: dict[str, dict[str, bool]]
    unexplained: bool
    reasons: list[str]


@dataclass(frozen=True)
class Diagnosis:
    """Outcome of :func:`diagnose`.

    Attributes:
        model: name of the diagnosed model.
        before: the model judged on the held-out windows.
        after: the changed model judged on the same windows (``before`` when nothing added).
        effects: the effects added (0, 1 or 2), in the order they were added.
        rejected: every other candidate, as ``(label, held-out reduction, reason)``.
        not_applicable: catalogue entries that do not apply, with why.
        document: the changed model's YAML document (``None`` when nothing was added).
        outputs: output names.
        fit_windows, heldout_windows: start times (s) of the windows used for each role.
        adequate: no effect needed: the model explains this datum as well as any candidate.
        summary: one paragraph for the report.
        noise_ratio: held-out error of the model before, as a multiple of what the
            measurement noise alone would give (see ``DiagnosisConfig.material``).
        heldout: the held-out datums (for figures).
        fit_bins: the fit windows' excited bins (for figures).
        nominal_before, nominal_after: the nominal plants before and after.
        explained: how much of the held-out error is left, and whether it is noise.
        runners_up: the best candidates not chosen, by held-out score.
        inputs: input names.
        candidates: every single effect of the catalogue fitted alone, best held-out score
            first (``reduction`` is its penalised held-out reduction).
        level: what moved the level, where its mean moved: a leak, a sensor offset, or
            undecided (:class:`~twotank_validation.diagnose.level.LevelVerdict`); None where
            it did not move.
    """

    model: str
    before: Assessment
    after: Assessment
    effects: list[FittedEffect]
    rejected: list[tuple[str, float, str]]
    not_applicable: list[tuple[str, str]]
    document: dict[str, Any] | None
    outputs: tuple[str, ...]
    fit_windows: list[float]
    heldout_windows: list[float]
    adequate: bool
    summary: str
    noise_ratio: float = math.nan
    heldout: list[Datum] = field(default_factory=list, repr=False)
    fit_bins: BinData | None = field(default=None, repr=False)
    nominal_before: Nominal | None = field(default=None, repr=False)
    nominal_after: Nominal | None = field(default=None, repr=False)
    findings: list[Finding] = field(default_factory=list)
    distortion: dict[str, Any] = field(default_factory=dict)
    explained: Explained | None = None
    runners_up: list[RunnerUp] = field(default_factory=list)
    inputs: tuple[str, ...] = ()
    candidates: list[FittedEffect] = field(default_factory=list, repr=False)
    level: LevelVerdict | None = None

    @property
    def unexplained(self) -> bool:
        """A material part of the held-out error is left, or the residual is not independent."""
        return self.explained is not None and self.explained.unexplained

    def to_json(self, model_file: str | None = None) -> dict[str, Any]:
        """The documented JSON (docs/cli.md, "diagnose JSON")."""

        def side(a: Assessment) -> dict[str, Any]:
            return a.to_dict()

        ex = self.explained
        return {
            "model": self.model,
            "adequate": self.adequate,
            "unexplained": self.unexplained,
            "explained_fraction": ex.fraction if ex else None,
            "explained_fraction_raw": ex.fraction_raw if ex else None,
            "noise_ratio": self.noise_ratio,
            "remaining_noise_ratio": ex.noise_ratio_after if ex else None,
            "residual_white": all(ex.white.values()) if ex and ex.white else None,
            "residual_independent": (
                all(v for d in ex.independent.values() for v in d.values())
                if ex and ex.independent
                else None
            ),
            "unexplained_reasons": ex.reasons if ex else [],
            "per_output": ex.per_output if ex else {},
            "summary": self.summary,
            "before": side(self.before),
            "effects": [e.to_dict(self.outputs) for e in self.effects],
            "after": side(self.after),
            "model_file": model_file,
            "rejected": [
                {"candidate": lab, "heldout_reduction": red, "reason": why}
                for lab, red, why in self.rejected
            ],
            "not_applicable": [
                {"candidate": lab, "reason": why} for lab, why in self.not_applicable
            ],
            "runners_up": [r.to_dict() for r in self.runners_up],
            "findings": [f.to_dict() for f in self.findings],
            "level": None if self.level is None else self.level.to_dict(),
            "distortion": self.distortion,
            "fit_windows_start_s": self.fit_windows,
            "heldout_windows_start_s": self.heldout_windows,
        }


def changed_document(
    doc: Mapping[str, Any],
    nominal: Nominal,
    effects: Sequence[FittedEffect],
    outputs: Sequence[str],
) -> dict[str, Any]:
    """The model file with the effects added to its nominal (a new name and description)."""
    new = copy.deepcopy(dict(doc))
    new["nominal"] = nominal.to_node()
    labels = [e.spec.label(outputs) for e in effects]
    new["name"] = f"{doc.get('name', 'model')}_diagnosed"
    params = "; ".join(
        f"{e.spec.label(outputs)}: "
        + ", ".join(f"{n} = {v:.4g}" for n, v in zip(e.spec.names, e.values, strict=True))
        for e in effects
    )
    new["description"] = (
        f"{doc.get('description', '')} Diagnosed from data: added {', '.join(labels)} ({params})."
    ).strip()
    new["derivation"] = (
        f"{doc.get('derivation', doc.get('name', ''))}; then twotank-validation diagnose added "
        f"{', '.join(labels)}"
    )
    return new


def _datums(windows: Sequence[Window], convention: NormConvention) -> list[Datum]:
    return [w.datum(convention) for w in windows]


def diagnose(
    windows: Sequence[Window],
    doc: Mapping[str, Any],
    config: DiagnosisConfig | None = None,
    *,
    source: str = "model",
    convention: NormConvention = NormConvention.POWER,
    reference: OperatingPoint | None = None,
    course: Course | None = None,
) -> Diagnosis:
    """Trace the residual of ``doc``'s model on ``windows`` to the effect it lacks.

    A level whose steady mean moved (an offset on ``height``) is then told a leak or a
    sensor offset (:mod:`twotank_validation.diagnose.level`): by the time course at the
    change when ``course`` holds it, and by the dynamics of the thermal balance, which a
    leak changes (the tank holds less) and a sensor offset does not. A leak is added to the
    model (the nominal re-linearised at the lower level); when the data cannot tell the two
    apart both are named, with what would separate them, and no repair is advised.

    Args:
        windows: non-overlapping windows of whole periods (same ts and period).
        doc: the model document (as loaded from YAML).
        config: settings.
        source: label of the model in messages.
        convention: norm convention of the validations.
        reference: reference operating point of the offset check (default: the model's).
        course: the level's time course at the change that led into these windows
            (:func:`~twotank_validation.diagnose.level.level_course`); None: no change
            inside the recording (the fault, if any, was there from the start).

    Raises:
        DiagnosisError: too little data, no excitation, or a model that cannot be changed.
    """
    cfg = config or DiagnosisConfig()
    found = _diagnose(windows, doc, cfg, source=source, convention=convention, reference=reference)
    return _level_check(
        found,
        windows,
        doc,
        cfg,
        source=source,
        convention=convention,
        reference=reference,
        course=course,
    )


def _diagnose(
    windows: Sequence[Window],
    doc: Mapping[str, Any],
    cfg: DiagnosisConfig,
    *,
    source: str,
    convention: NormConvention,
    reference: OperatingPoint | None,
) -> Diagnosis:
    """:func:`diagnose` without the level check: the catalogue, the reported effects."""
    model = model_from_dict(doc, source)
    nominal = Nominal.from_document(doc, source)
    outputs = model.output_names
    fit_w, held_w = split_windows(windows)
    fit_d, held_d = _datums(fit_w, convention), _datums(held_w, convention)
    ts = fit_d[0].ts_s
    fit_data = bin_data(fit_d, model, cfg.excitation_floor)
    held_data = bin_data(held_d, model, cfg.excitation_floor)
    if fit_data.theta.size == 0 or held_data.theta.size == 0:
        raise DiagnosisError(
            "the windows carry no excitation at the harmonics of the period: a model error "
            "cannot be traced without excitation"
        )
    f_fit = fit_data.theta / (2.0 * math.pi * ts)  # the excited band, Hz
    specs, skipped = catalogue(
        nominal,
        outputs,
        period_s=fit_w[0].period_samples * ts,
        operating_point=model.operating_point,
        max_time_fraction=cfg.max_time_fraction,
        inputs=model.input_names,
        band_hz=(float(np.min(f_fit)), float(np.max(f_fit))),
    )
    before = assess(model, held_d, held_w, cfg)
    j0 = cost(nominal, held_data, ts)

    def judged(
        chosen: Sequence[EffectSpec], starts: Sequence[np.ndarray] | None
    ) -> tuple[np.ndarray, float, float]:
        values, fit_cost = fit_effects(nominal, chosen, fit_data, ts, starts)
        j = cost(_apply_all(nominal, chosen, values), held_data, ts)
        k = sum(s.n_params for s in chosen)
        return values, fit_cost, j * (1.0 + cfg.param_penalty * k)

    singles = []
    for s in specs:
        values, fit_cost, adj = judged([s], None)
        singles.append(FittedEffect(s, values, fit_cost, adj, 1.0 - adj / j0))
    singles.sort(key=lambda e: -e.reduction)
    singles = _prefer_parsimonious(singles, cfg.parsimony)
    chosen: list[FittedEffect] = []
    pairs: list[tuple[float, FittedEffect, FittedEffect]] = []
    best = singles[0] if singles else None
    floor = noise_floor(held_data)
    material = j0 >= cfg.material * floor
    if best is not None and material and cfg.max_effects >= 1:
        if best.reduction >= cfg.min_reduction:
            chosen.append(best)
        left = best.heldout_cost / (1.0 + cfg.param_penalty * best.spec.n_params)
        if cfg.max_effects >= 2 and left >= cfg.material * floor:
            # a pair when one effect alone does not explain the data: it must remove
            # min_reduction of the error, and min_second_reduction of what the best single
            # effect leaves
            pair, pairs = _best_pair(singles, specs, judged, cfg)
            if (
                pair is not None
                and pair[0] <= (1.0 - cfg.min_second_reduction) * best.heldout_cost
                and pair[0] <= (1.0 - cfg.min_reduction) * j0
            ):
                chosen = [pair[1], pair[2]]
    changed = nominal
    for e in chosen:
        changed = e.spec.apply(changed, e.values)
    # effects outside the state-space catalogue (input saturation, offset): distortion.py
    k_chosen = sum(e.spec.n_params for e in chosen)
    findings, replaces, reported_rejected, reported_extra = reported_effects(
        fit_w, held_w, model, nominal, changed,
        cost(changed, held_data, ts) * (1.0 + cfg.param_penalty * k_chosen) if chosen else j0,
        fit_data, held_data, cfg, reference,
        f"after adding {', '.join(e.spec.label(outputs) for e in chosen)}" if chosen
        else "its dynamics are unchanged",
        {e.spec.input: float(e.values[0]) for e in chosen
         if e.spec.kind is EffectKind.INPUT_GAIN and e.spec.input is not None},
        [e.spec.label(outputs) for e in chosen if e.spec.kind.record.moves_operating_point],
        _moved_outputs(chosen, len(outputs)),
    )  # fmt: skip
    if replaces:  # the linear fit of a clipped input is its describing function
        chosen, changed = [], nominal
    if chosen:  # how sure: jointly, on the bins the effects were fitted on
        sure = fit_uncertainty(
            nominal,
            [e.spec for e in chosen],
            fit_data,
            ts,
            np.concatenate([e.values for e in chosen]),
            cfg.confidence,
        )
        chosen = [
            replace(e, uncertainty=part)
            for e, part in zip(chosen, _split(sure, chosen), strict=True)
        ]
    runners = _runners_up(singles, pairs, chosen, j0, outputs, cfg)
    # evidence: each chosen effect against the model with the other chosen effects added, so
    # that its own signature shows; its reduction is what it removes on top of the others
    j_all = cost(changed, held_data, ts)
    with_evidence = []
    for i, e in enumerate(chosen):
        base = nominal
        for other in chosen[:i] + chosen[i + 1 :]:
            base = other.spec.apply(base, other.values)
        red = 1.0 - j_all / max(cost(base, held_data, ts), 1e-300)
        pts = evidence_points(e.spec, e.values, base, fit_data, ts)
        text = evidence(e.spec, e.values, base, fit_data, ts, outputs, red, pts)
        text += _interval_note(e.uncertainty)
        with_evidence.append(replace(e, reduction=red, evidence=text, points=pts))
    chosen = with_evidence
    chosen_specs = {id(e.spec) for e in chosen}
    rejected = []
    for e in singles:
        if id(e.spec) in chosen_specs:
            continue
        label = e.spec.label(outputs)
        if not material:
            why = (
                f"not needed: the model's held-out error is {j0 / max(floor, 1e-300):.1f} times "
                f"what the measurement noise alone gives (material from {cfg.material:g}); "
                f"it would remove {max(e.reduction, 0.0):.0%} of it"
            )
        elif chosen and e.reduction >= cfg.min_reduction:
            why = (
                f"removes {e.reduction:.0%} of the held-out error alone, but "
                f"{' with '.join(c.spec.label(outputs) for c in chosen)} explains the data better"
            )
        elif e.reduction < cfg.min_reduction:
            why = (
                f"removes {max(e.reduction, 0.0):.0%} of the held-out error with "
                f"{e.spec.n_params} parameter(s) (at least {cfg.min_reduction:.0%} needed)"
            )
        else:
            why = f"removes {e.reduction:.0%} of the held-out error"
        bounds = zip(e.spec.names, e.values, e.spec.lower, e.spec.upper, strict=True)
        at_bound = [n for n, v, lo, hi in bounds if np.isclose(v, lo) or np.isclose(v, hi)]
        if at_bound and e.reduction > 0:
            why += f"; fitted {', '.join(at_bound)} at the search bound"
        rejected.append((label, float(e.reduction), why))
    rejected += reported_rejected
    document = changed_document(doc, changed, chosen, outputs) if chosen else None
    if document is not None:
        after_model = model_from_dict(document, f"{source} (diagnosed)")
        after = assess(after_model, held_d, held_w, cfg)
    else:
        after = before
    explained = _explained(
        output_costs(nominal, held_data, ts),
        output_costs(changed, held_data, ts),
        output_noise_floors(held_data),
        after,
        outputs,
        cfg,
    )
    summary = _summary(model.name, before, after, chosen, outputs, explained, bool(findings))
    if findings:
        summary = finding_summary(model.name, findings, summary if chosen else "")
    return Diagnosis(
        model=model.name,
        before=before,
        after=after,
        effects=chosen,
        rejected=rejected,
        not_applicable=skipped,
        document=document,
        outputs=tuple(outputs),
        fit_windows=[w.start_s for w in fit_w],
        heldout_windows=[w.start_s for w in held_w],
        adequate=not chosen and not findings and not explained.unexplained,
        summary=summary,
        noise_ratio=j0 / floor if floor > 0 else math.inf,
        heldout=held_d,
        fit_bins=fit_data,
        nominal_before=nominal,
        nominal_after=changed,
        findings=findings,
        distortion=reported_extra["distortion"],
        explained=explained,
        runners_up=runners,
        inputs=tuple(model.input_names),
        candidates=list(singles),
    )


# --------------------------------------------------------------------------- the level


def _level_check(
    found: Diagnosis,
    windows: Sequence[Window],
    doc: Mapping[str, Any],
    cfg: DiagnosisConfig,
    *,
    source: str,
    convention: NormConvention,
    reference: OperatingPoint | None,
    course: Course | None,
) -> Diagnosis:
    """A level offset told a leak or a sensor offset (:func:`diagnose`); else ``found``."""
    off = next(
        (
            f
            for f in found.findings
            if f.kind == EffectKind.OFFSET and f.target == LEVEL and not f.extra
        ),
        None,
    )
    # (a leak only lowers the level: a level above what the inputs predict stays an offset)
    if (
        off is None
        or not float(off.parameters["offset"]) < 0.0
        or found.nominal_before is None
        or found.fit_bins is None
    ):
        return found
    model = model_from_dict(doc, source)
    nominal = found.nominal_before
    outputs = found.outputs
    h = outputs.index(LEVEL)
    ts = windows[0].ts_s
    change, change_std = float(off.parameters["offset"]), float(off.parameters["offset_std"])
    gain = float(np.mean(dc_gain(nominal)[h]))
    outflow = -change / gain if gain else math.nan
    taus = channel_time_constants(nominal, h, ts)
    tau_level = max(taus) if taus else math.nan
    tank = Tank.of(nominal, outputs, model.operating_point)
    if isinstance(tank, str):
        verdict = decide(change, change_std, outflow, (), course, tau_level, tank)
        if verdict.kind is EffectKind.LEAK:  # the time course says so; the model cannot hold it
            leak = Finding(
                kind=EffectKind.LEAK.value,
                target=LEVEL,
                parameters={"level_change": change, "outflow": outflow},
                evidence=verdict.evidence(),
                recommendation=_leak_advice(outflow),
                heldout_reduction=off.heldout_reduction,
                extra={"level": verdict.to_dict()},
            )
            findings = [leak if f is off else f for f in found.findings]
            return replace(
                found, findings=findings, level=verdict, summary=_resummary(found, findings)
            )
        return _offset_or_undecided(found, off, verdict)
    moved = copy.deepcopy(dict(doc))
    moved["nominal"] = level_moved(nominal, change, tank).to_node()
    moved["operating_point"] = {**dict(doc.get("operating_point") or {}), LEVEL: tank.h0 + change}
    moved_ref = None
    if reference is not None:
        y = np.array(reference.y, dtype=float)
        y[h] += change
        moved_ref = OperatingPoint(u=reference.u, y=y)
    try:
        leaky = _diagnose(
            windows,
            moved,
            cfg,
            source=f"{source} with the level {change:+.3g}",
            convention=convention,
            reference=moved_ref,
        )
    except TwotankError as err:  # the moved model cannot be judged: the dynamics not tested
        why = f"the model re-linearised at the moved level: {err}"
        verdict = decide(change, change_std, outflow, (), course, tau_level, why)
        return _offset_or_undecided(found, off, verdict)
    # the level fitted to the dynamics with the effects each explanation chose (Bonferroni
    # over the two): a stand-in for the other explanation only widens its own interval
    tests: list[DynamicsTest] = []
    for chosen in (found.effects, leaky.effects):
        effects = [(e.spec, e.values, e.spec.label(outputs)) for e in chosen]
        if any(t.with_effects == tuple(x[2] for x in effects) for t in tests):
            continue
        tests.append(
            dynamics_test(nominal, tank, change, effects, found.fit_bins, ts, cfg.alpha / 2)
        )
    verdict = decide(change, change_std, outflow, tests, course, tau_level)
    if verdict.kind is EffectKind.LEAK:
        return _as_leak(found, leaky, verdict, doc, tank, model, cfg, ts)
    return _offset_or_undecided(found, off, verdict)


def _leak_advice(outflow: float) -> str:
    return (
        f"find and stop the leak (about {outflow:.3g} model flow units lost besides the "
        "outlet); the height sensor reads right: do not recalibrate it"
    )


def _resummary(found: Diagnosis, findings: Sequence[Finding]) -> str:
    """The summary of ``found`` with other findings (as :func:`_diagnose` writes it)."""
    ex = found.explained
    assert ex is not None
    dynamic = (
        _summary(found.model, found.before, found.after, found.effects, found.outputs, ex, True)
        if found.effects
        else ""
    )
    return finding_summary(found.model, findings, dynamic)


def _offset_or_undecided(found: Diagnosis, off: Finding, verdict: LevelVerdict) -> Diagnosis:
    """The offset confirmed by the evidence, or both named (no repair) when it does not decide."""
    extra = {"level": verdict.to_dict()}
    if verdict.kind is EffectKind.OFFSET:
        sure = replace(
            off,
            evidence=f"{off.evidence}; not a leak: {verdict.evidence()}",
            extra=extra,
        )
        confirmed = [sure if f is off else f for f in found.findings]
        why = f"not a leak: {verdict.evidence()}"
        rejected = [*found.rejected, ("leak (a constant extra outflow)", 0.0, why)]
        return replace(
            found,
            findings=confirmed,
            rejected=rejected,
            level=verdict,
            summary=_resummary(found, confirmed),
        )
    side = "lower" if verdict.change < 0 else "higher"
    advice = (
        f"no repair yet: a {LEVEL} sensor offset of {verdict.change:+.3g} or a leak of about "
        f"{verdict.outflow:.3g} (a constant extra outflow, the level really "
        f"{abs(verdict.change):.3g} {side}) fit these data alike; {verdict.separating()}"
    )
    undecided = f"the data do not tell it from a leak: {verdict.evidence()}"
    both = replace(
        off,
        evidence=f"{off.evidence}; {undecided}",
        recommendation=advice,
        extra={**extra, "undecided_with": EffectKind.LEAK.value},
    )
    leak = Finding(
        kind=EffectKind.LEAK.value,
        target=LEVEL,
        parameters={"level_change": verdict.change, "outflow": verdict.outflow},
        evidence=(
            f"a constant extra outflow of {verdict.outflow:.3g} puts the level "
            f"{abs(verdict.change):.3g} {side}, as the {LEVEL} reads; the data do not tell it "
            f"from a sensor offset: {verdict.evidence()}"
        ),
        recommendation=advice,
        heldout_reduction=off.heldout_reduction,
        extra={**extra, "undecided_with": EffectKind.OFFSET.value},
    )
    findings: list[Finding] = []
    for f in found.findings:
        findings += [both, leak] if f is off else [f]
    return replace(found, findings=findings, level=verdict, summary=_resummary(found, findings))


def _as_leak(  # noqa: PLR0917 - both diagnoses and the tank
    found: Diagnosis,
    leaky: Diagnosis,
    verdict: LevelVerdict,
    doc: Mapping[str, Any],
    tank: Tank,
    model: Any,
    cfg: DiagnosisConfig,
    ts: float,
) -> Diagnosis:
    """The diagnosis with the leak added.

    The nominal re-linearised at the lower level, then the effects chosen against it.
    """
    outputs = found.outputs
    nominal = found.nominal_before
    assert nominal is not None
    assert found.fit_bins is not None
    change = verdict.change
    spec = leak_spec(nominal, tank, change)
    values = np.array([change])
    rest = list(leaky.effects)
    changed = leaky.nominal_after if leaky.nominal_after is not None else nominal
    held = bin_data(found.heldout, model, cfg.excitation_floor)
    without = nominal
    for e in rest:
        without = e.spec.apply(without, e.values)
    j_all = cost(changed, held, ts)
    red = 1.0 - j_all / max(cost(without, held, ts), 1e-300)
    pts = evidence_points(spec, values, without, found.fit_bins, ts)
    z = float(scipy.stats.norm.ppf(0.5 + cfg.confidence / 2.0))
    sd = verdict.change_std
    sure = Uncertainty(np.array([sd]), values - z * sd, values + z * sd, ("",), 1.0, cfg.confidence)
    text = (
        f"the level sits {abs(change):.3g} {'below' if change < 0 else 'above'} what the "
        f"inputs predict at steady state (from the means: ± {sd:.1g}), a constant extra "
        f"outflow of about {verdict.outflow:.3g}, and it is not a sensor offset: "
        f"{verdict.evidence()}; the lower level removes {red:.0%} of the held-out error left "
        "without it"
    )
    leak = FittedEffect(
        spec, values, cost(changed, found.fit_bins, ts), j_all, red, text, sure, pts
    )
    effects = [leak, *rest]
    document = changed_document(doc, changed, effects, outputs)
    document["operating_point"] = {
        **dict(document.get("operating_point") or {}),
        LEVEL: tank.h0 + change,
    }
    after = leaky.after
    explained = _explained(
        output_costs(nominal, held, ts),
        output_costs(changed, held, ts),
        output_noise_floors(held),
        after,
        outputs,
        cfg,
    )
    summary = _leak_summary(
        found.model, found.before, after, leak, rest, leaky.findings, explained, outputs, verdict
    )
    why = f"not a sensor offset: {verdict.evidence()}"
    return replace(
        leaky,
        model=found.model,
        before=found.before,
        after=after,
        effects=effects,
        rejected=[*leaky.rejected, (f"offset on {LEVEL}", 0.0, why)],
        not_applicable=found.not_applicable,
        document=document,
        adequate=False,
        summary=summary,
        noise_ratio=found.noise_ratio,
        nominal_before=nominal,
        nominal_after=changed,
        explained=explained,
        level=verdict,
    )


def _leak_summary(  # noqa: PLR0917 - everything the paragraph says
    name: str,
    before: Assessment,
    after: Assessment,
    leak: FittedEffect,
    rest: Sequence[FittedEffect],
    others: Sequence[Finding],
    explained: Explained,
    outputs: Sequence[str],
    verdict: LevelVerdict,
) -> str:
    """The paragraph of a diagnosis that found a leak: the leak and what to do first."""
    change = verdict.change
    head = (
        f"Model {name}: leak: the level sits {abs(change):.3g} "
        f"{'lower' if change < 0 else 'higher'} than the inputs hold it (a constant extra "
        f"outflow); {_leak_advice(verdict.outflow)}"
    )
    head += "".join(f"; {f.kind} on {f.target}: {f.recommendation}" for f in others) + "."
    if explained.unexplained:  # what the leak (and the rest) leave
        partial = (
            f"; the best partial fit adds {' and '.join(e.spec.label(outputs) for e in rest)}"
            if rest
            else ""
        )
        return (
            f"{head} Beside the leak, {'; '.join(explained.reasons)}: an effect outside the "
            f"catalogue{partial} (held-out beta {before.beta:.3f} -> {after.beta:.3f})."
        )
    added = " and ".join(f"{e.spec.label(outputs)} ({_values_text(e)})" for e in rest)
    rms = ", ".join(f"{o} {before.rms[o]:.4g} -> {after.rms[o]:.4g}" for o in outputs)
    frac = explained.fraction
    share = (
        f"; {frac:.0%} of the held-out error above the noise explained" if frac is not None else ""
    )
    return (
        f"{head} {f'Model {name} also lacks {added}. ' if rest else ''}On held-out data beta "
        f"{before.beta:.3f} -> {after.beta:.3f}; RMS simulation error {rms} (model units)"
        f"{share}."
    )


WIDE_INTERVAL = 2.0
"""An interval widened by at least this factor for model error says so in the evidence."""


def _interval_note(sure: Uncertainty | None) -> str:
    """Why the intervals are wide, when the model error the fit leaves widened them."""
    if sure is None or not sure.inflation >= WIDE_INTERVAL**2:
        return ""
    return (
        f"; its interval is {math.sqrt(sure.inflation):.1f} times as wide as the measurement "
        f"noise alone would make it: the fit leaves {sure.inflation:.0f} times the noise at its "
        "bins (model error: the plant's nonlinearity or an effect outside the catalogue), and "
        "what the parameter absorbs of it is not in that residual"
    )


def _moved_outputs(chosen: Sequence[FittedEffect], ny: int) -> list[int] | None:
    """The outputs whose operating point the chosen effects move by themselves (None: all).

    A thermal effect moves its own output (the temperature) alone.
    """
    moving = [e for e in chosen if e.spec.kind.record.moves_operating_point]
    if any(not e.spec.kind.record.thermal for e in moving):
        return None
    return sorted({e.spec.channel for e in moving if e.spec.channel < ny})


def _split(sure: Uncertainty, effects: Sequence[FittedEffect]) -> list[Uncertainty]:
    """The joint uncertainty of several effects, cut into one per effect."""
    out, i = [], 0
    for e in effects:
        k = e.spec.n_params
        out.append(
            replace(
                sure,
                stderr=sure.stderr[i : i + k],
                low=sure.low[i : i + k],
                high=sure.high[i : i + k],
                at_bound=sure.at_bound[i : i + k],
            )
        )
        i += k
    return out


def _runners_up(  # noqa: PLR0917 - every candidate and the choice
    singles: Sequence[FittedEffect],
    pairs: Sequence[tuple[float, FittedEffect, FittedEffect]],
    chosen: Sequence[FittedEffect],
    j0: float,
    outputs: Sequence[str],
    cfg: DiagnosisConfig,
) -> list[RunnerUp]:
    """The best candidates other than the chosen effects, by penalised held-out cost."""
    cands: list[tuple[float, tuple[str, ...], int]] = [
        (e.heldout_cost, (e.spec.label(outputs),), e.spec.n_params) for e in singles
    ]
    cands += [
        (adj, (a.spec.label(outputs), b.spec.label(outputs)), a.spec.n_params + b.spec.n_params)
        for adj, a, b in pairs
    ]
    mine = frozenset(e.spec.label(outputs) for e in chosen)
    scores = [c for c, labels, _ in cands if frozenset(labels) == mine]
    score = min(scores) if chosen and scores else None
    out: list[RunnerUp] = []
    for c, labels, n in sorted(cands, key=lambda t: t[0]):
        if len(out) >= cfg.runners_up:
            break
        if frozenset(labels) == mine:
            continue
        close = None if score is None else bool(c <= cfg.parsimony * score)
        out.append(
            RunnerUp(" + ".join(labels), n, float(c), float(1.0 - c / max(j0, 1e-300)), close)
        )
    return out


def _explained(  # noqa: PLR0917 - the costs and the tests
    before: np.ndarray,
    after: np.ndarray,
    floor: np.ndarray,
    tests_after: Assessment,
    outputs: Sequence[str],
    cfg: DiagnosisConfig,
) -> Explained:
    """How much of the held-out error is left, per output and in all, and whether it is noise.

    Args:
        before: (ny,) held-out cost per output of the model.
        after: (ny,) the same of the changed model.
        floor: (ny,) the cost the measurement noise alone gives, per output.
        tests_after: the changed model judged on the held-out windows (residual tests).
        outputs: output names.
        cfg: settings (``unexplained_factor``, ``unexplained_fraction``).
    """

    def fraction(jb: float, ja: float, f: float) -> float | None:
        if jb < cfg.material * f or jb <= f:  # nothing material to explain
            return None
        return float(np.clip(1.0 - max(ja - f, 0.0) / (jb - f), 0.0, 1.0))

    reasons: list[str] = []
    per: dict[str, dict[str, Any]] = {}
    for o, jb, ja, f in zip(outputs, before, after, floor, strict=True):
        frac = fraction(float(jb), float(ja), float(f))
        ratio_a = float(ja / f) if f > 0 else math.inf
        left = (
            ratio_a >= cfg.unexplained_factor
            and frac is not None
            and 1.0 - frac >= cfg.unexplained_fraction
        )
        per[o] = {
            "explained_fraction": frac,
            "noise_ratio_before": float(jb / f) if f > 0 else math.inf,
            "noise_ratio_after": ratio_a,
            "material_left": bool(left),
        }
        if left:
            reasons.append(
                f"{1.0 - (frac or 0.0):.0%} of the {o} error above the noise floor is left "
                f"({ratio_a:.1f} times the noise, material from {cfg.unexplained_factor:g})"
            )
    white: dict[str, bool] = {}
    independent: dict[str, dict[str, bool]] = {}
    tests = [t for t in tests_after.residual_tests_windows if isinstance(t, Mapping)]
    if tests:
        for o in outputs:
            fails = sum(not t["whiteness"][o]["passed"] for t in tests if o in t["whiteness"])
            white[o] = fails * 2 <= len(tests)
            cross = tests[0]["cross_correlation"].get(o, {})
            independent[o] = {}
            for i in cross:
                fails = sum(not t["cross_correlation"][o][i]["passed"] for t in tests)
                independent[o][i] = fails * 2 <= len(tests)
                if not independent[o][i]:
                    reasons.append(
                        f"the {o} residual is correlated with the input {i} "
                        f"({fails} of {len(tests)} held-out windows)"
                    )
    jb, ja, f = float(np.sum(before)), float(np.sum(after)), float(np.sum(floor))
    return Explained(
        fraction=fraction(jb, ja, f),
        fraction_raw=float(1.0 - ja / jb) if jb > 0 else 1.0,
        noise_ratio_after=ja / f if f > 0 else math.inf,
        per_output=per,
        white=white,
        independent=independent,
        unexplained=bool(reasons),
        reasons=reasons,
    )


def _best_pair(
    singles: Sequence[FittedEffect],
    specs: Sequence[EffectSpec],
    judged: Callable[
        [Sequence[EffectSpec], Sequence[np.ndarray] | None], tuple[np.ndarray, float, float]
    ],
    cfg: DiagnosisConfig,
) -> tuple[
    tuple[float, FittedEffect, FittedEffect] | None, list[tuple[float, FittedEffect, FittedEffect]]
]:
    """The best pair of effects, fitted jointly, each of the leading singles as the first.

    Not greedy: a first effect that fits best alone can be the wrong one when a second
    effect is present (a lag mimics part of a delay plus a leak), so every pair with one of
    the ``pair_candidates`` best singles is fitted and judged on the held-out windows.

    Returns:
        The best ``(penalised held-out cost, first, second)`` (or ``None``), and every pair
        tried, best first.
    """
    results: list[tuple[float, FittedEffect, FittedEffect]] = []
    seen: set[frozenset[int]] = set()
    firsts = [e for e in singles[: cfg.pair_candidates] if e.reduction > 0.0]  # best first
    for first in firsts:
        for s in specs:
            key = frozenset((id(first.spec), id(s)))
            # (two modes of one structure are two effects, though they show on one output)
            same = (s.kind, s.channel, s.input, s.fixed.get("mode")) == (
                first.spec.kind,
                first.spec.channel,
                first.spec.input,
                first.spec.fixed.get("mode"),
            )
            if same or key in seen:
                continue
            seen.add(key)
            values, fit_cost, adj = judged([first.spec, s], [first.values])
            n1 = first.spec.n_params
            second = FittedEffect(s, values[n1:], fit_cost, adj, 1.0 - adj / first.heldout_cost)
            results.append((adj, replace(first, values=values[:n1]), second))
    if not results:
        return None, results
    results.sort(key=lambda t: t[0])
    close = [t for t in results if t[0] <= cfg.parsimony * results[0][0]]
    return min(close, key=lambda t: (t[1].spec.n_params + t[2].spec.n_params, t[0])), results


def _prefer_parsimonious(ranked: list[FittedEffect], factor: float) -> list[FittedEffect]:
    """Move the most parsimonious of the near-best candidates to the front.

    Near-best: held-out error left within ``factor`` of the best one's; most parsimonious:
    fewest parameters, then least error. The rest keep their order.
    """
    if not ranked:
        return ranked
    left = [max(1.0 - e.reduction, 1e-12) for e in ranked]
    close = [i for i, v in enumerate(left) if v <= factor * left[0]]
    pick = min(close, key=lambda i: (ranked[i].spec.n_params, left[i]))
    return [ranked[pick], *ranked[:pick], *ranked[pick + 1 :]]


def _values_text(e: FittedEffect) -> str:
    """``delay_s 35.6 ± 2.6`` for each fitted parameter (± the standard error when known)."""
    parts = []
    for k, (n, v) in enumerate(zip(e.spec.names, e.values, strict=True)):
        se = None if e.uncertainty is None else e.uncertainty.stderr[k]
        pm = f" ± {se:.2g}" if se is not None and math.isfinite(se) else ""
        parts.append(f"{n} {v:.4g}{pm}")
    return ", ".join(parts)


def _summary(  # noqa: PLR0917 - everything the paragraph says
    name: str,
    before: Assessment,
    after: Assessment,
    chosen: Sequence[FittedEffect],
    outputs: Sequence[str],
    explained: Explained,
    steady_findings: bool = False,
) -> str:
    # the held-out beta is the dynamics'; a steady-state finding (an offset, a saturation)
    # means the operating point may invalidate the model although the dynamics do not
    if not steady_findings and math.isfinite(before.beta) and before.beta <= 1.0:
        # a model set that explains the data needs no repair: that first; what structure its
        # residual has inside the stated uncertainty is the detail, never the headline
        valid = f"not invalidated (held-out beta {before.beta:.3f} <= 1)"
        if not chosen and not explained.unexplained:
            return (
                f"Model {name} is adequate for this datum: {valid}, and no effect of the "
                "catalogue removes enough of the held-out error to be worth its parameters."
            )
        head = (
            f"Model {name} is {valid}: the data lie inside its model set and nothing needs "
            "fixing. Detail, inside the stated uncertainty: "
        )
        if explained.unexplained:
            detail = _invalid_summary(name, before, after, chosen, outputs, explained)
            return head + detail.removeprefix(f"Model {name}: ")
        added = " and ".join(f"{e.spec.label(outputs)} ({_values_text(e)})" for e in chosen)
        return (
            f"{head}adding {added} would take the held-out beta from {before.beta:.3f} to "
            f"{after.beta:.3f} (a tighter model, not a repair)."
        )
    return _invalid_summary(name, before, after, chosen, outputs, explained)


def _invalid_summary(  # noqa: PLR0917 - everything the paragraph says
    name: str,
    before: Assessment,
    after: Assessment,
    chosen: Sequence[FittedEffect],
    outputs: Sequence[str],
    explained: Explained,
) -> str:
    not_white = [o for o, ok in explained.white.items() if not ok]
    if explained.unexplained:
        worst = max(
            outputs,
            key=lambda o: (
                explained.per_output[o]["material_left"],
                1.0 - (explained.per_output[o]["explained_fraction"] or 0.0),
            ),
        )
        frac = explained.per_output[worst]["explained_fraction"] or 0.0
        left = (
            f"{1.0 - (explained.fraction or 0.0):.0%} of the held-out error above the noise "
            f"remains ({worst}: {1.0 - frac:.0%}, "
            f"{explained.per_output[worst]['noise_ratio_after']:.1f} times the noise)"
        )
        white = f", not white on {', '.join(not_white)}" if not_white else ""
        head = "partly explained" if chosen else "not explained"
        text = f"Model {name}: {head}; {left}{white}: an effect outside the catalogue"
        if not chosen:
            return (
                text + " (or a change inside the recording); no effect of the catalogue "
                f"removes enough of it (held-out beta {before.beta:.3f}). "
                + "; ".join(explained.reasons).capitalize()
                + "."
            )
        added = " and ".join(e.spec.label(outputs) for e in chosen)
        return (
            f"{text}. The best partial fit is {added}, not the answer: "
            + "; ".join(explained.reasons)
            + f". On held-out data beta {before.beta:.3f} -> {after.beta:.3f}."
        )
    if not chosen:
        return (
            f"Model {name} is adequate for this datum: no effect of the catalogue removes enough "
            f"of the held-out error to be worth its parameters (held-out beta {before.beta:.3f})."
        )
    added = " and ".join(f"{e.spec.label(outputs)} ({_values_text(e)})" for e in chosen)
    rms = ", ".join(f"{o} {before.rms[o]:.4g} -> {after.rms[o]:.4g}" for o in outputs)
    return (
        f"Model {name} lacks {added}. On held-out data beta {before.beta:.3f} -> "
        f"{after.beta:.3f}; RMS simulation error {rms} (model units); "
        f"{explained.fraction or 0.0:.0%} of the held-out error above the noise explained."
    )
