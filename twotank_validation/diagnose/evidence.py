"""Why the data point at a fitted effect, in words, from the residual of the model without it."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from twotank_validation.diagnose.effects import (
    THERMAL_STATES,
    EffectSpec,
    Nominal,
    mode_shift_text,
)
from twotank_validation.diagnose.fit import BinData
from twotank_validation.diagnose.kinds import EffectKind


@dataclass(frozen=True)
class EvidencePoints:
    """What the evidence of one fitted effect rests on: every bin the fit used, on its channel.

    The evidence text and the evidence figure both take their numbers from here (one
    function, :func:`evidence_points`), so that the figure shows exactly the points, the
    curve and the R^2 the text quotes. Bins are sorted by frequency; several windows give
    several points at one frequency.

    Attributes:
        f_hz: (k,) float, frequency of each bin, Hz.
        measured: (k,) complex, measured / modelled output ratio ``Y / (G U)`` (the model
            without the effect).
        fitted: (k,) complex, the same ratio with the fitted effect, at the same bins.
        weight: (k,) float, ``|G U|^2 / scale^2``, the weight of the bin in the fit.
        noise: (k,) float, RMS of the measurement noise on ``measured`` (from the
            non-harmonic bins: ``sqrt(noise) scale / |G U|``).
        phase_measured_deg, phase_fitted_deg: (k,) float, unwrapped phases; the measured one
            is the fitted one plus the wrapped angle between them (so noise never jumps a
            point by 360 deg).
        phase_band_deg: (k,) float, ``arcsin(noise / |fitted|)``, the noise band in phase.
        dense_f_hz: (n,) float, a log-spaced grid over the fitted band.
        dense_fitted: (n, c) complex, the fitted ratio on that grid, one column per input
            (one column when the ratio does not depend on the input: output effects).
        dense_inputs: the input index of each column of ``dense_fitted`` (empty for one
            column that holds for every input).
        r2: the R^2 the text quotes (see ``r2_kind``).
        r2_kind: ``"phase line"`` (a delay: the weighted fit of a line through 0 to the
            measured phase against frequency) or ``"effect"`` (``1 - sum w |m - f|^2 /
            sum w |m - 1|^2``: the share of the measured departure from the model that the
            fitted effect reproduces).
        slope_s: weighted LS slope of the measured phase (rad) against omega (rad/s), s.
    """

    f_hz: np.ndarray
    measured: np.ndarray
    fitted: np.ndarray
    weight: np.ndarray
    noise: np.ndarray
    phase_measured_deg: np.ndarray
    phase_fitted_deg: np.ndarray
    phase_band_deg: np.ndarray
    dense_f_hz: np.ndarray
    dense_fitted: np.ndarray
    dense_inputs: tuple[int, ...]
    r2: float
    r2_kind: str
    slope_s: float


def evidence_points(
    spec: EffectSpec, values: np.ndarray, before: Nominal, data: BinData, ts_s: float
) -> EvidencePoints:
    """The points, curve, noise band and R^2 of one fitted effect (see :class:`EvidencePoints`).

    Args:
        spec: the effect.
        values: its fitted parameters.
        before: the model without this effect (with the other chosen effects).
        data: the bins the fit used (all fit windows' excited bins).
        ts_s: sample period, s.
    """
    ch = spec.channel
    after = spec.apply(before, values)
    order = np.argsort(data.theta, kind="stable")
    theta = data.theta[order]
    u = data.u[order]
    y0 = np.einsum("kij,kj->ki", before.hold_response(theta, ts_s), u)[:, ch]
    y1 = np.einsum("kij,kj->ki", after.hold_response(theta, ts_s), u)[:, ch]
    scale = data.scale[order, ch]
    ok = np.abs(y0) > 0
    safe = np.where(ok, y0, 1.0)
    measured = np.where(ok, data.y[order, ch] / safe, 0.0)
    fitted = np.where(ok, y1 / safe, 1.0)
    weight = np.abs(y0) ** 2 / scale**2
    noise = np.where(ok, np.sqrt(data.noise[order, ch]) * scale / np.abs(safe), np.inf)
    ph_fit = np.unwrap(np.angle(fitted))
    ph_meas = ph_fit + np.angle(np.where(fitted != 0, measured / fitted, 1.0))
    band = np.arcsin(np.minimum(noise / np.maximum(np.abs(fitted), 1e-300), 1.0))
    f_hz = theta / ts_s / (2 * math.pi)
    dense_f = np.geomspace(float(f_hz[0]), float(f_hz[-1]), 200) if f_hz.size else f_hz
    th_d = 2 * math.pi * dense_f * ts_s
    g0, g1 = before.hold_response(th_d, ts_s)[:, ch], after.hold_response(th_d, ts_s)[:, ch]
    live = np.any(np.abs(g0) > 0, axis=0)
    dense = np.where(
        np.abs(g0[:, live]) > 0, g1[:, live] / np.where(g0[:, live] == 0, 1, g0[:, live]), 1
    )
    dense_inputs = tuple(int(j) for j in np.flatnonzero(live))
    if dense.shape[1] > 1 and np.allclose(dense, dense[:, :1], rtol=1e-9, atol=1e-12):
        dense, dense_inputs = dense[:, :1], ()
    omega = 2 * math.pi * f_hz
    slope = float(np.sum(weight * omega * ph_meas) / max(np.sum(weight * omega**2), 1e-300))
    if spec.kind is EffectKind.DELAY:
        tot = float(np.sum(weight * ph_meas**2))
        r2 = 1.0 - float(np.sum(weight * (ph_meas - slope * omega) ** 2)) / tot if tot > 0 else 0.0
        kind = "phase line"
    else:
        tot = float(np.sum(weight * np.abs(measured - 1.0) ** 2))
        r2 = 1.0 - float(np.sum(weight * np.abs(measured - fitted) ** 2)) / tot if tot > 0 else 0.0
        kind = "effect"
    return EvidencePoints(
        f_hz=f_hz,
        measured=measured,
        fitted=fitted,
        weight=weight,
        noise=noise,
        phase_measured_deg=np.degrees(ph_meas),
        phase_fitted_deg=np.degrees(ph_fit),
        phase_band_deg=np.degrees(band),
        dense_f_hz=dense_f,
        dense_fitted=dense,
        dense_inputs=dense_inputs,
        r2=r2,
        r2_kind=kind,
        slope_s=slope,
    )


def evidence(  # noqa: PLR0911, PLR0917 - one text per kind; the effect and where it was fitted
    spec: EffectSpec,
    values: np.ndarray,
    before: Nominal,
    data: BinData,
    ts_s: float,
    outputs: Sequence[str],
    reduction: float,
    points: EvidencePoints | None = None,
) -> str:
    """Why the data point at this effect, in words, from the residual of ``before``.

    ``points`` (:func:`evidence_points` of the same arguments) are computed when not given;
    the evidence figure draws the same object.
    """
    out = outputs[spec.channel]
    pts = points if points is not None else evidence_points(spec, values, before, data, ts_s)
    ratio, w = pts.measured, pts.weight
    band = f"{pts.f_hz[0]:.4f}-{pts.f_hz[-1]:.4f} Hz"
    mag = float(np.sum(w * np.abs(ratio)) / max(np.sum(w), 1e-300))
    fit_r2 = (
        f"R^2 {pts.r2:.2f} of the fitted effect against the measured/modelled ratio at the "
        f"{pts.f_hz.size} bins the fit used"
    )
    tail = f"; it removes {reduction:.0%} of the held-out error left without it"
    if spec.explain is not None:  # an effect that states its own evidence (effects.py)
        return spec.explain(values, before, data, ts_s, outputs) + tail
    if spec.kind is EffectKind.DELAY:
        return (
            f"the {out} residual phase relative to the model falls linearly with frequency over "
            f"{band} (slope {pts.slope_s:.2f} rad per rad/s, R^2 {pts.r2:.2f} at the "
            f"{pts.f_hz.size} bins the fit used): a delay of {-pts.slope_s:.1f} s; the "
            f"measured/modelled magnitude stays near 1 ({mag:.2f}), which rules out a lag; "
            f"fitted delay {values[0]:.2f} s{tail}"
        )
    if spec.kind is EffectKind.LAG:
        lo, hi = 0, ratio.size - 1
        return (
            f"the {out} measured/modelled magnitude falls from {abs(ratio[lo]):.2f} at "
            f"{pts.f_hz[lo]:.4f} Hz to {abs(ratio[hi]):.2f} at {pts.f_hz[hi]:.4f} Hz with a "
            f"phase lag, as 1/(1 + j w T) ({fit_r2}): a lag of T = {values[0]:.1f} s{tail}"
        )
    if spec.kind is EffectKind.GAIN:
        ph = float(np.degrees(np.sum(w * np.angle(ratio)) / max(np.sum(w), 1e-300)))
        return (
            f"the {out} measured/modelled ratio is flat and nearly real over {band} (mean "
            f"magnitude {mag:.3f}, mean phase {ph:.1f} deg; {fit_r2}): a static gain error of "
            f"{values[0]:+.1%}{tail}"
        )
    if spec.kind is EffectKind.COUPLING and spec.source is not None:
        g = before.hold_response(data.theta, ts_s)
        yhat = np.einsum("kij,kj->ki", g, data.u)
        e = (data.y[:, spec.channel] - yhat[:, spec.channel]) / data.scale[:, spec.channel]
        s = yhat[:, spec.source] / data.scale[:, spec.channel]
        coh = float(abs(np.vdot(s, e)) ** 2 / max(np.vdot(s, s).real * np.vdot(e, e).real, 1e-300))
        src = outputs[spec.source]
        return (
            f"the {out} residual is coherent with the modelled {src} (squared coherence "
            f"{coh:.2f} over {band}): {src} drives {out} through K(s) = (k0 + k_inf T s)/(1 + T s) "
            f"with k0 = {values[0]:.3g}, k_inf = {values[1]:.3g} and T = "
            f"{spec.fixed.get('time_constant_s', float('nan')):.1f} s, the time constant of "
            f"{out}'s own dynamics ({fit_r2}){tail}"
        )
    if spec.kind in (EffectKind.LEAK, EffectKind.HEAT_LOSS):
        state = (
            "height"
            if spec.kind is EffectKind.LEAK
            else next(n for n in THERMAL_STATES if n in before.states)
        )
        i = before.states.index(state)
        after = spec.apply(before, values)
        low = 0
        what = "extra outflow" if spec.kind is EffectKind.LEAK else "heat loss to ambient"
        return (
            f"at the lowest excited harmonic ({pts.f_hz[low]:.4f} Hz) the measured "
            f"{out} is {abs(ratio[low]):.2f} of the model's, with a phase lead of "
            f"{math.degrees(float(np.angle(ratio[low]))):.0f} deg: the {state} balance decays "
            f"faster than modelled, as with an {what}; the fitted rate {values[0]:.3g} 1/s "
            f"shortens the {state} time constant from {-1.0 / before.a[i, i]:.1f} s to "
            f"{-1.0 / after.a[i, i]:.1f} s ({fit_r2}){tail}"
        )
    if spec.kind is EffectKind.MODE:
        return _mode_evidence(spec, values, pts, out, fit_r2) + tail
    return f"fitted {dict(zip(spec.names, values.tolist(), strict=True))} ({fit_r2}){tail}"


def _mode_evidence(
    spec: EffectSpec, values: np.ndarray, pts: EvidencePoints, out: str, fit_r2: str
) -> str:
    """A resonance that sits elsewhere: the ratio's swing around the mode, and the shift."""
    f0 = spec.fixed["nominal_frequency_hz"]
    lo_f, hi_f = sorted((f0, float(values[0])))
    near = (pts.f_hz >= lo_f / 1.1) & (pts.f_hz <= hi_f * 1.1)
    if not np.any(near):
        near = np.ones(pts.f_hz.size, dtype=bool)
    mag = np.abs(pts.measured[near])
    f = pts.f_hz[near]
    return (
        f"around mode {int(spec.fixed['mode'])} the {out} measured/modelled ratio swings from "
        f"{float(np.min(mag)):.2f} to {float(np.max(mag)):.2f} over {f[0]:.4g}-{f[-1]:.4g} Hz "
        f"(at {int(np.sum(near))} bins): a resonance that sits elsewhere than modelled, not a "
        f"flat gain or a phase line; {mode_shift_text(spec, values)}, its mode shape kept "
        f"({fit_r2})"
    )
