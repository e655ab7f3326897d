"""Input saturation (a distortion test, a fitted clip level) and the effects outside the model.

:func:`reported_effects` runs the effects outside the state-space catalogue (saturation,
offset) in the diagnosis.

**Distortion test.** With a periodic input a linear plant's output has energy only at the
harmonic bins the input excites (plus noise at every bin). Inside the excited band, the
harmonic bins the input does not excite (*detection lines*, e.g. the even harmonics of an
odd-only multisine) therefore carry noise only, like the non-harmonic bins. Per output,

    F = mean |E|² at the detection lines / mean |Y|² at the non-harmonic bins of the band,

with ``E = Y − G U`` the nominal's residual, is F(2 k_d, 2 k_n)-distributed for a linear
plant with Gaussian noise (``scipy.stats.f``); a small p-value means a nonlinearity. A
filtered-noise excitation excites every harmonic inside its band: there are no detection
lines and the test is reported as not possible (the saturation fit still runs).

**Saturation fit.** Per input and side, the input is replaced by ``min(u_i, hi)`` (or
``max(u_i, lo)``) in the time domain before the DFT; the level is fitted by a scan over the
input's quantiles and ``scipy.optimize.minimize_scalar`` on the same scaled error as the
dynamic effects (fit windows), and judged on the held-out windows with the same penalty. It
is reported when the error is material, it removes ``min_reduction`` of the held-out error,
and it leaves less than the dynamic effects chosen; the distortion test is its supporting
evidence where the excitation allows it (it does not veto: with few detection lines it has
little power). It replaces those dynamic effects: the linear fit of a clipped input is its
describing function, not a property of the plant. A saturation cannot be written into an
LTI model file: it is reported with a recommendation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize
import scipy.stats

from twotank_validation.core.datum import NormConvention, scaled_dft
from twotank_validation.core.model import LFTModel
from twotank_validation.core.oppoint import OperatingPoint
from twotank_validation.diagnose.effects import Nominal
from twotank_validation.diagnose.fit import BinData, excited_bins, noise_floor, noise_scale
from twotank_validation.diagnose.inputs import DiagnosisConfig, Window
from twotank_validation.diagnose.steady import (
    Finding,
    fit_offsets,
    resolve_reference,
    window_means,
)

MIN_LINES = 4
"""Fewer detection lines than this (over all windows) leave the test without power."""

SIDES = ("upper", "lower")
"""``upper``: ``min(u, level)`` (a valve that opens no further); ``lower``: ``max(u, level)``."""


@dataclass(frozen=True)
class DistortionTest:
    """The harmonic-distortion F-test per output.

    Attributes:
        statistic: (ny,) F, NaN when not possible.
        p_value: (ny,) p-values.
        lines: detection lines used (summed over windows).
        noise_bins: non-harmonic bins used.
        note: why the test was not possible ("" when it was).
    """

    statistic: np.ndarray
    p_value: np.ndarray
    lines: int
    noise_bins: int
    note: str = ""

    @property
    def possible(self) -> bool:
        """The windows have detection lines and noise bins in the excited band."""
        return not self.note

    def significant(self, alpha: float) -> np.ndarray:
        """(ny,) bool: distortion at level ``alpha``."""
        return np.asarray(self.p_value < alpha) if self.possible else np.zeros(0, dtype=bool)

    def to_dict(self, outputs: Sequence[str]) -> dict[str, Any]:
        """JSON-ready summary."""
        if not self.possible:
            return {"possible": False, "note": self.note}
        return {
            "possible": True,
            "F": {o: float(f) for o, f in zip(outputs, self.statistic, strict=True)},
            "p_value": {o: float(p) for o, p in zip(outputs, self.p_value, strict=True)},
            "detection_lines": self.lines,
            "noise_bins": self.noise_bins,
        }


def distortion_test(
    windows: Sequence[Window], nom: Nominal, floor: float, ny: int
) -> DistortionTest:
    """The harmonic-distortion F-test of the windows (see the module docstring)."""
    det: list[np.ndarray] = []
    noise: list[np.ndarray] = []
    for w in windows:
        d = w.datum()
        p = d.n_samples // d.period_samples
        n = np.arange(d.theta.size)
        idx = excited_bins(d, floor)
        if idx.size == 0 or p < 2:
            continue
        band = (n >= idx.min()) & (n <= idx.max())
        harmonic = n % p == 0
        lines = np.flatnonzero(band & harmonic & ~np.isin(n, idx))
        if lines.size:
            g = nom.hold_response(d.theta[lines], d.ts_s)
            e = d.y_bins[lines] - np.einsum("kij,kj->ki", g, d.u_bins[lines])
            det.append(np.abs(e) ** 2)
        noise.append(np.abs(d.y_bins[band & ~harmonic]) ** 2)
    nan = np.full(ny, math.nan)
    if sum(x.shape[0] for x in det) < MIN_LINES or not noise:
        why = (
            f"fewer than {MIN_LINES} detection lines: the input excites (almost) every harmonic "
            "inside its band (an odd-only multisine leaves the even ones to test on)"
            if noise
            else "windows of one period have no non-harmonic bins to measure the noise"
        )
        return DistortionTest(nan, nan, 0, 0, why)
    num, den = np.concatenate(det), np.concatenate(noise)
    f = np.mean(num, axis=0) / np.maximum(np.mean(den, axis=0), 1e-300)
    p = scipy.stats.f.sf(f, 2 * num.shape[0], 2 * den.shape[0])
    return DistortionTest(f, np.asarray(p), int(num.shape[0]), int(den.shape[0]))


def _clipped_bins(
    windows: Sequence[Window], data: BinData, i: int, level: float, side: str
) -> tuple[np.ndarray, np.ndarray]:
    """Input DFT at ``data``'s bins with input ``i`` clipped, and per-window effective means."""
    u_bins = data.u.copy()
    means = []
    for k, w in enumerate(windows):
        u = w.u.copy()
        u[:, i] = np.minimum(u[:, i], level) if side == "upper" else np.maximum(u[:, i], level)
        means.append(u.mean(axis=0))
        rows = np.flatnonzero(data.window == k)
        n = u.shape[0]
        idx = np.rint(data.theta[rows] * n / (2 * np.pi)).astype(int)
        u_bins[rows] = scaled_dft(u - u.mean(axis=0), NormConvention.POWER)[idx]
    return u_bins, np.array(means)


def _cost(nom: Nominal, data: BinData, u_bins: np.ndarray, ts_s: float) -> float:
    g = nom.hold_response(data.theta, ts_s)
    e = (data.y - np.einsum("kij,kj->ki", g, u_bins)) / data.scale
    return float(np.sum(np.abs(e) ** 2))


@dataclass(frozen=True)
class SaturationFit:
    """One input and side with its fitted level.

    Attributes:
        input: input index.
        side: ``upper`` or ``lower``.
        level: fitted clip level (command, model units).
        fit_cost, heldout_cost: scaled squared error (held-out: with the parameter penalty).
        clipped: fraction of the held-out samples the level clips.
        constant_cost: held-out error with the input held constant (clipped at every sample:
            a valve that follows no command), no parameter to penalise.
    """

    input: int
    side: str
    level: float
    fit_cost: float
    heldout_cost: float
    clipped: float
    constant_cost: float = math.inf


def fit_saturation(  # noqa: PLR0917 - the diagnosis context
    fit_w: Sequence[Window],
    held_w: Sequence[Window],
    nom: Nominal,
    fit_data: BinData,
    held_data: BinData,
    ts_s: float,
    cfg: DiagnosisConfig,
) -> list[SaturationFit]:
    """Fit a clip level per input and side; best (least held-out error) first."""
    out = []
    for i in range(fit_data.u.shape[1]):
        u_fit = np.concatenate([w.u[:, i] for w in fit_w])
        for side in SIDES:
            qs = np.linspace(0.02, 0.98, 25) if side == "upper" else np.linspace(0.98, 0.02, 25)
            grid = np.quantile(u_fit, qs)

            def j_fit(level: float, i: int = i, side: str = side) -> float:
                return _cost(nom, fit_data, _clipped_bins(fit_w, fit_data, i, level, side)[0], ts_s)

            costs = [j_fit(float(x)) for x in grid]
            k = int(np.argmin(costs))
            lo, hi = sorted((float(grid[max(k - 1, 0)]), float(grid[min(k + 1, grid.size - 1)])))
            best, best_c = float(grid[k]), costs[k]
            if hi > lo:
                sol = scipy.optimize.minimize_scalar(j_fit, bounds=(lo, hi), method="bounded")
                if float(sol.fun) < best_c:
                    best, best_c = float(sol.x), float(sol.fun)
            u_held, _ = _clipped_bins(held_w, held_data, i, best, side)
            j_held = _cost(nom, held_data, u_held, ts_s) * (1.0 + cfg.param_penalty)
            u_all = np.concatenate([w.u[:, i] for w in held_w])
            frac = float(np.mean(u_all > best) if side == "upper" else np.mean(u_all < best))
            u_const = held_data.u.copy()
            u_const[:, i] = 0.0  # a constant input has no component at the excited bins
            j_const = _cost(nom, held_data, u_const, ts_s)
            out.append(SaturationFit(i, side, best, best_c, j_held, frac, j_const))
    out.sort(key=lambda s: s.heldout_cost)
    return out


def reported_effects(  # noqa: PLR0917 - the diagnosis context
    fit_w: Sequence[Window],
    held_w: Sequence[Window],
    model: LFTModel,
    nominal: Nominal,
    changed: Nominal,
    chosen_cost: float,
    fit_data: BinData,
    held_data: BinData,
    cfg: DiagnosisConfig,
    reference: OperatingPoint | None = None,
    dynamics: str = "its dynamics are unchanged",
    input_gains: Mapping[int, float] | None = None,
    moves_operating_point: Sequence[str] = (),
    moved_outputs: Sequence[int] | None = None,
) -> tuple[list[Finding], bool, list[tuple[str, float, str]], dict[str, Any]]:
    """Run the effects outside the state-space catalogue: input saturation, then offset.

    Args:
        fit_w: the fit windows.
        held_w: the held-out windows.
        model: the model (names, noise weights, operating point).
        nominal: its nominal plant.
        changed: the nominal with the chosen dynamic effects.
        chosen_cost: penalised held-out cost of ``changed`` (the nominal's when none).
        fit_data: the excited bins of the fit windows.
        held_data: the excited bins of the held-out windows.
        cfg: settings.
        reference: the reference operating point for the offset (default: the model's).
        dynamics: what the dynamic diagnosis found, for the offset's evidence.
        input_gains: the chosen input gains, ``{input index: g}``. An input gain scales the
            delivered input itself, so at steady state it also moves the outputs by
            ``G(0)[:, i] g u_ref_i`` beyond what the changed nominal gives for the deviation
            ``ū − u_ref``; that part is not an offset. (Assumes the input's model units are
            zero at no flow, as the shipped models' valve commands are.)
        moves_operating_point: labels of chosen effects that shift the equilibrium by
            themselves (a leak, a heat loss, a hot-supply change): beside them the offset is
            not judged, since the deviation model cannot say how far they move it.
        moved_outputs: the outputs whose operating point those effects move (None: all; a
            thermal effect moves the temperature alone, so the level's offset is still
            judged beside it).

    Returns:
        ``(findings, replaces, rejected, extra)``: the reported effects; whether a saturation
        replaces the chosen dynamic effects; candidates not reported, ``(label, held-out
        reduction, why)``; and JSON extras (the distortion test).
    """
    ts = fit_w[0].ts_s
    outputs, inputs = list(model.output_names), list(model.input_names)
    j0 = float(np.sum(np.abs(_residual(nominal, held_data, ts)) ** 2))
    floor = noise_floor(held_data)
    material = j0 >= cfg.material * floor
    test = distortion_test([*fit_w, *held_w], nominal, cfg.excitation_floor, len(outputs))
    extra = {"distortion": test.to_dict(outputs)}
    findings: list[Finding] = []
    rejected: list[tuple[str, float, str]] = []
    replaces = False
    u_eff = None
    sats = fit_saturation(fit_w, held_w, nominal, fit_data, held_data, ts, cfg)
    if sats:
        s = sats[0]
        red = 1.0 - s.heldout_cost / max(j0, 1e-300)
        label = f"saturation of {inputs[s.input]}"
        why = ""
        if not material:
            why = "not needed: the held-out error is at the measurement-noise level"
        elif red < cfg.min_reduction:
            why = f"removes {max(red, 0.0):.0%} of the held-out error (at least "
            why += f"{cfg.min_reduction:.0%} needed)"
        elif s.heldout_cost >= chosen_cost:
            why = f"removes {red:.0%} of the held-out error, but the dynamic effect(s) more"
        if why:
            rejected.append((label, red, why))
        else:
            replaces = True
            verb = "opens no further than" if s.side == "upper" else "closes no further than"
            above = "above" if s.side == "upper" else "below"
            dist = (
                "the distortion test: "
                + ", ".join(
                    f"{o} F {f:.3g} (p {p:.2g})"
                    for o, f, p in zip(outputs, test.statistic, test.p_value, strict=True)
                )
                + f" over {test.lines} detection lines"
                if test.possible
                else f"the distortion test is not possible ({test.note})"
            )
            findings.append(
                Finding(
                    kind="saturation",
                    target=inputs[s.input],
                    parameters={
                        "level": s.level,
                        "clipped_fraction": s.clipped,
                        "constant_cost_ratio": s.constant_cost / max(s.heldout_cost, 1e-300),
                    },
                    evidence=(
                        f"with the {inputs[s.input]} command clipped {above} {s.level:.3g} "
                        f"({s.clipped:.0%} of the samples) the nominal removes {red:.0%} of the "
                        f"held-out error, more than any dynamic effect; {dist}"
                    ),
                    recommendation=(
                        f"the {inputs[s.input]} valve {verb} command {s.level:.3g}: keep the "
                        "excitation inside it, or model the limit"
                    ),
                    heldout_reduction=red,
                    extra={"side": s.side},
                )
            )
            _, u_eff = _clipped_bins([*fit_w, *held_w], _stack(fit_data, held_data), s.input,
                                     s.level, s.side)  # fmt: skip
    ref, how = resolve_reference([*fit_w, *held_w], outputs, model.operating_point, reference)
    moved = set(range(len(outputs)) if moved_outputs is None else moved_outputs)
    unjudged = moved if moves_operating_point and not replaces else set()
    why_unjudged = (
        f"not judged: {' and '.join(moves_operating_point)} moves the operating point by "
        "itself, by an amount the linear model does not give, so a constant sensor offset "
        "cannot be told apart from it on the window means"
    )
    if ref is not None and unjudged == set(range(len(outputs))):
        rejected.append(("offset", 0.0, why_unjudged))
    elif ref is None:
        rejected.append(("offset", 0.0, (
            "not applicable: no reference operating point (the model file has no "
            "operating_point for every output, and none was given)"
        )))  # fmt: skip
    else:
        noise_dc = noise_scale(model, np.zeros(1), ts, np.ones(len(outputs)))[0]
        if input_gains and not replaces:
            # with the changed nominal's column (1 + g) G0_i, the means ū_i + g/(1+g) u_ref_i
            # give G0_i ((1 + g) ū_i − u_ref_i): the delivered input's deviation
            u_eff, _ = window_means([*fit_w, *held_w])
            for i, g in input_gains.items():
                u_eff[:, i] += g / (1.0 + g) * ref.u[i]
        off, why_not = fit_offsets(
            fit_w, held_w, nominal if replaces else changed, outputs, ref, noise_dc, cfg, how,
            "with the input clipped as found" if replaces else dynamics, u_eff,
        )  # fmt: skip
        # beside an effect that moves some outputs' operating point (a thermal one moves the
        # temperature alone), the others' offsets are still judged
        names = {outputs[c] for c in unjudged}
        findings += [f for f in off if f.target not in names]
        rejected += [r for r in why_not if r[0] not in {f"offset on {n}" for n in names}]
        rejected += [(f"offset on {n}", 0.0, why_unjudged) for n in sorted(names)]
    return findings, replaces, rejected, extra


def _residual(nom: Nominal, data: BinData, ts_s: float) -> np.ndarray:
    g = nom.hold_response(data.theta, ts_s)
    return (data.y - np.einsum("kij,kj->ki", g, data.u)) / data.scale


def _stack(a: BinData, b: BinData) -> BinData:
    """The bins of ``a`` then ``b``, windows renumbered (for the effective input means)."""
    return BinData(
        np.concatenate([a.theta, b.theta]),
        np.concatenate([a.u, b.u]),
        np.concatenate([a.y, b.y]),
        np.concatenate([a.scale, b.scale]),
        np.concatenate([a.window, b.window + a.n_windows]),
        a.n_windows + b.n_windows,
        np.concatenate([a.noise, b.noise]),
    )


def finding_summary(name: str, findings: Sequence[Finding], dynamic: str) -> str:
    """The summary with the reported effects first.

    Two findings the data cannot tell apart (``extra["undecided_with"]``: a level offset
    and a leak) are one part, ``offset on height or leak: ...``, with their one advice.
    """
    parts, paired = [], set()
    for f in findings:
        other = f.extra.get("undecided_with")
        if other is None:
            parts.append(f"{f.kind} on {f.target}: {f.recommendation}")
        elif (other, f.target) not in paired:  # the pair once, in the findings' order
            paired.add((f.kind, f.target))
            parts.append(f"{f.kind} on {f.target} or {other}: {f.recommendation}")
    head = f"Model {name}: " + "; ".join(parts) + "."
    return f"{head} {dynamic}".strip()
