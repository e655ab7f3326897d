"""Why the data point at a fitted effect, in words, from the residual of the model without it."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from twotank_validation.diagnose.effects import THERMAL_STATES, EffectSpec, Nominal
from twotank_validation.diagnose.fit import BinData


def _ratio(
    nom: Nominal, data: BinData, ts_s: float, ch: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-bin measured/modelled ratio on output ``ch``: (omega rad/s, ratio, weight)."""
    g = nom.hold_response(data.theta, ts_s)
    yhat = np.einsum("kij,kj->ki", g, data.u)[:, ch]
    w = np.abs(yhat) ** 2 / data.scale[:, ch] ** 2
    ok = np.abs(yhat) > 0
    ratio = np.where(ok, data.y[:, ch] / np.where(ok, yhat, 1.0), 0.0)
    return data.theta / ts_s, ratio, w


def _phase_slope(omega: np.ndarray, ratio: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """Weighted LS slope of the unwrapped phase of ``ratio`` against omega (through 0), R^2."""
    order = np.argsort(omega)
    om, ph, ww = omega[order], np.unwrap(np.angle(ratio[order])), w[order]
    slope = float(np.sum(ww * om * ph) / max(np.sum(ww * om * om), 1e-300))
    resid = ph - slope * om
    tot = float(np.sum(ww * ph**2))
    return slope, 1.0 - float(np.sum(ww * resid**2)) / tot if tot > 0 else 0.0


def evidence(  # noqa: PLR0911, PLR0917 - one text per kind; the effect and where it was fitted
    spec: EffectSpec,
    values: np.ndarray,
    before: Nominal,
    data: BinData,
    ts_s: float,
    outputs: Sequence[str],
    reduction: float,
) -> str:
    """Why the data point at this effect, in words, from the residual of ``before``."""
    out = outputs[spec.channel]
    omega, ratio, w = _ratio(before, data, ts_s, spec.channel)
    f_lo, f_hi = float(np.min(omega)) / (2 * math.pi), float(np.max(omega)) / (2 * math.pi)
    band = f"{f_lo:.4f}-{f_hi:.4f} Hz"
    mag = float(np.sum(w * np.abs(ratio)) / max(np.sum(w), 1e-300))
    tail = f"; it removes {reduction:.0%} of the held-out error left without it"
    if spec.explain is not None:  # an effect that states its own evidence (effects.py)
        return spec.explain(values, before, data, ts_s, outputs) + tail
    if spec.kind == "delay":
        slope, r2 = _phase_slope(omega, ratio, w)
        return (
            f"the {out} residual phase relative to the model falls linearly with frequency over "
            f"{band} (slope {slope:.2f} rad per rad/s, R^2 {r2:.2f}): a delay of "
            f"{-slope:.1f} s; the measured/modelled magnitude stays near 1 ({mag:.2f}), "
            f"which rules out a lag; fitted delay {values[0]:.2f} s{tail}"
        )
    if spec.kind == "lag":
        lo, hi = np.argmin(omega), np.argmax(omega)
        return (
            f"the {out} measured/modelled magnitude falls from {abs(ratio[lo]):.2f} at "
            f"{omega[lo] / (2 * math.pi):.4f} Hz to {abs(ratio[hi]):.2f} at "
            f"{omega[hi] / (2 * math.pi):.4f} Hz with a phase lag, as 1/(1 + j w T): a lag of "
            f"T = {values[0]:.1f} s{tail}"
        )
    if spec.kind == "gain":
        ph = float(np.degrees(np.sum(w * np.angle(ratio)) / max(np.sum(w), 1e-300)))
        return (
            f"the {out} measured/modelled ratio is flat and nearly real over {band} (mean "
            f"magnitude {mag:.3f}, mean phase {ph:.1f} deg): a static gain error of "
            f"{values[0]:+.1%}{tail}"
        )
    if spec.kind == "coupling" and spec.source is not None:
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
            f"{out}'s own dynamics{tail}"
        )
    if spec.kind in ("leak", "heat_loss"):
        state = (
            "height"
            if spec.kind == "leak"
            else next(n for n in THERMAL_STATES if n in before.states)
        )
        i = before.states.index(state)
        after = spec.apply(before, values)
        low = int(np.argmin(omega))
        what = "extra outflow" if spec.kind == "leak" else "heat loss to ambient"
        return (
            f"at the lowest excited harmonic ({omega[low] / (2 * math.pi):.4f} Hz) the measured "
            f"{out} is {abs(ratio[low]):.2f} of the model's, with a phase lead of "
            f"{math.degrees(float(np.angle(ratio[low]))):.0f} deg: the {state} balance decays "
            f"faster than modelled, as with an {what}; the fitted rate {values[0]:.3g} 1/s "
            f"shortens the {state} time constant from {-1.0 / before.a[i, i]:.1f} s to "
            f"{-1.0 / after.a[i, i]:.1f} s{tail}"
        )
    return f"fitted {dict(zip(spec.names, values.tolist(), strict=True))}{tail}"
