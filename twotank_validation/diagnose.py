"""Close the loop: from the residual of a validation to the effect the model lacks.

Given windows of periodic data (whole excitation periods, as the validator sees them) and a
structured model (nominal state space + perturbations + noise, the YAML of
:mod:`twotank_validation.core.model`), the diagnosis

1. computes the raw error ``E(n) = Y(n) - G(e^{j theta_n}) U(n)`` of the nominal on every
   output at the excited harmonic bins of the period (where the input carries energy),
   scaled per output by the model's own noise weight, so that the outputs are comparable;
2. fits every applicable effect of a catalogue (:data:`EFFECT_KINDS`) -- each a structured
   change of the nominal state space with a few physical parameters -- by nonlinear least
   squares on the scaled error of the *fit* windows;
3. judges each fitted effect on *held-out* windows (never used to fit), with a penalty per
   parameter, keeps the best one when it removes at least ``min_reduction`` of the held-out
   error, and tries a second effect on top when the first leaves enough unexplained;
4. reports, on the held-out windows, the validation beta, the RMS simulation error per output
   and the paper's Section 2.1 residual statistics before and after, with the evidence for
   the chosen effect(s) and why each rejected candidate was rejected; the changed model is a
   YAML document the validator accepts as it is.

Catalogue (parameters in SI units; rates in 1/s, times in s):

* ``delay`` on an output: ``y_c(t) -> y_c(t - tau)`` (``output_delays_s`` in the YAML).
* ``lag`` on an output: ``y_c -> y_c / (1 + T s)`` (an extra state).
* ``gain`` on an output: ``y_c -> (1 + g) y_c``.
* ``coupling`` from output a into output c: ``y_c += K(s) y_a`` with
  ``K(s) = (k0 + k_inf T s) / (1 + T s)`` (DC gain ``k0``, high-frequency gain ``k_inf``,
  time constant ``T``; an extra state). The paper's Model A lacks the level-to-temperature
  coupling of Model B, which is exactly this form with T the temperature time constant.
* ``leak``: an extra outflow proportional to the level; the mass (``height``) and the
  energy/temperature states both decay faster by the rate ``r`` (needs state names).
* ``heat_loss``: heat lost to ambient, ``q (t - t_amb)``; the energy/temperature state decays
  faster by ``c`` and, for an energy state E = h t, the level feeds it with ``+c t0``
  (needs state names and the operating temperature).
* ``offset``: a sensor drift, ``y_c += d (t - mean t)`` within each window. The mean is
  removed before the DFT, so a constant offset is invisible to the validation by design;
  a drift is not a property of an LTI model: it is reported (with its rate) but not added to
  the model file, and the engineer is told to recalibrate the sensor.

Everything here is ROS-free and works on numpy arrays. scipy.optimize.least_squares does the
fitting; the catalogue and the selection rule are this package's own (no library does
model-structure diagnosis of LFT models).
"""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import scipy.optimize

from twotank_validation.core import lti, stats
from twotank_validation.core.datum import Datum, NormConvention, make_datum
from twotank_validation.core.lti import StateSpace
from twotank_validation.core.model import LFTModel, model_from_dict
from twotank_validation.core.validate import ValidationResult, inverse_dft, validate
from twotank_validation.errors import DatumError, ModelError

EFFECT_KINDS = ("delay", "lag", "gain", "coupling", "offset", "leak", "heat_loss")
"""Kinds of effect in the catalogue, in the order they are tried."""

THERMAL_STATES = ("energy", "temperature")
"""State names that the leak and heat-loss effects recognise as the thermal state."""


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

    def __post_init__(self) -> None:
        if not 0.0 < self.min_reduction < 1.0:
            raise DiagnosisError(f"min_reduction={self.min_reduction} must be in (0, 1)")
        if self.param_penalty < 0.0:
            raise DiagnosisError(f"param_penalty={self.param_penalty} must be >= 0")
        if self.max_effects not in (0, 1, 2):
            raise DiagnosisError(f"max_effects={self.max_effects} must be 0, 1 or 2")
        if not 0.0 < self.excitation_floor < 1.0:
            raise DiagnosisError(f"excitation_floor={self.excitation_floor} must be in (0, 1)")


@dataclass(frozen=True)
class Window:
    """One window of data in model units, whole excitation periods.

    Attributes:
        u: (n_samples, n_inputs) float, inputs.
        y: (n_samples, n_outputs) float, outputs.
        ts_s: sample period, s.
        period_samples: samples per excitation period.
        start_s: time of the first sample (s), for the report.
    """

    u: np.ndarray
    y: np.ndarray
    ts_s: float
    period_samples: int
    start_s: float = 0.0

    @property
    def n_periods(self) -> int:
        """Whole periods in the window."""
        return int(self.u.shape[0] // self.period_samples)

    def periods(self, first: int, count: int) -> Window:
        """The sub-window of ``count`` periods starting at period ``first``."""
        a, b = first * self.period_samples, (first + count) * self.period_samples
        return Window(
            self.u[a:b], self.y[a:b], self.ts_s, self.period_samples, self.start_s + a * self.ts_s
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


# --------------------------------------------------------------------------- nominal plant


@dataclass(frozen=True)
class Nominal:
    """A continuous-time nominal plant as it appears in a model file.

    Attributes:
        a, b, c, d: state-space matrices (n, n), (n, nu), (ny, n), (ny, nu).
        delays_s: (ny,) float, output transport delays in s.
        states: one name per state (``""`` when unnamed).
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    delays_s: np.ndarray
    states: tuple[str, ...]

    @classmethod
    def from_document(cls, doc: Mapping[str, Any], source: str = "model") -> Nominal:
        """Read the nominal of a model document (``nominal: {ss: ...}`` or ``tf``/``gain``).

        Raises:
            DiagnosisError: a generalized-plant model or a discrete-time nominal.
        """
        if "generalized_plant" in doc or "nominal" not in doc:
            raise DiagnosisError(
                f"{source}: diagnosis needs a structured model (nominal, perturbations, noise); "
                "a generalized plant has no nominal channels to change"
            )
        sys = model_from_dict(doc, source).nominal
        assert sys is not None
        if sys.is_discrete:
            raise DiagnosisError(
                f"{source}: the nominal is discrete-time; diagnosis changes continuous-time "
                "plants (give the nominal in continuous time)"
            )
        node = doc["nominal"]
        names: list[str] = []
        if isinstance(node, Mapping) and isinstance(node.get("ss"), Mapping):
            names = [str(s) for s in node["ss"].get("states") or []]
        if len(names) != sys.n_states:
            names = [""] * sys.n_states
        ny = sys.shape[0]
        delays = np.array(sys.output_delays_s or (0.0,) * ny, dtype=float)
        return cls(sys.a, sys.b, sys.c, sys.d, delays, tuple(names))

    def state_space(self) -> StateSpace:
        """The continuous-time state space with its delays."""
        return StateSpace(self.a, self.b, self.c, self.d, None, tuple(self.delays_s.tolist()))

    def response(self, theta: np.ndarray, ts_s: float) -> np.ndarray:
        """ZOH-discretised response at ``exp(j theta)``: (n_bins, ny, nu) complex."""
        return lti.frequency_response(lti.discretise(self.state_space(), ts_s), theta)

    def hold_response(self, theta: np.ndarray, ts_s: float) -> np.ndarray:
        """Fast response for fitting: ``G(j w) (1 - e^{-j theta}) / (j theta)`` times delays.

        The continuous response times the zero-order hold's; it differs from the exact ZOH
        discretisation (:meth:`response`) only by aliasing, ``O(|G(j(w + 2 pi / ts))|)``,
        i.e. ~1e-4 relative at the excited bins of the tank models (< 0.1 Hz at 10 Hz
        sampling). One batched solve instead of a matrix exponential per evaluation: the
        fit evaluates thousands of candidate plants. Shape (n_bins, ny, nu).
        """
        omega = np.asarray(theta, dtype=float) / ts_s
        n = self.a.shape[0]
        jw = 1j * omega[:, None, None] * np.eye(n)[None]
        x = np.linalg.solve(jw - self.a[None], np.broadcast_to(self.b, (omega.size, *self.b.shape)))
        g = np.einsum("pn,knm->kpm", self.c, x) + self.d[None]
        th = np.where(theta == 0.0, 1.0, theta)
        hold = np.where(theta == 0.0, 1.0, (1.0 - np.exp(-1j * th)) / (1j * th))
        delay = np.exp(-1j * omega[:, None] * self.delays_s[None, :])
        return g * hold[:, None, None] * delay[:, :, None]

    def to_node(self) -> dict[str, Any]:
        """The ``nominal`` node of a model file."""

        def rows(m: np.ndarray) -> list[list[float]]:
            return [[float(f"{x:.12g}") for x in r] for r in np.atleast_2d(m)]

        ss: dict[str, Any] = {
            "A": rows(self.a),
            "B": rows(self.b),
            "C": rows(self.c),
            "D": rows(self.d),
        }
        if any(self.states):
            ss["states"] = list(self.states)
        if np.any(self.delays_s > 0):
            ss["output_delays_s"] = [float(f"{t:.12g}") for t in self.delays_s]
        return {"ss": ss}

    def with_state(
        self, a_row_extra: np.ndarray, a_new: float, b_new: np.ndarray, name: str
    ) -> Nominal:
        """Append one state ``x' = a_row_extra @ x + a_new x_new + b_new @ u``."""
        n = self.a.shape[0]
        a = np.zeros((n + 1, n + 1))
        a[:n, :n] = self.a
        a[n, :n] = a_row_extra
        a[n, n] = a_new
        b = np.vstack([self.b, b_new[None, :]])
        c = np.hstack([self.c, np.zeros((self.c.shape[0], 1))])
        return replace(self, a=a, b=b, c=c, states=(*self.states, name))


# --------------------------------------------------------------------------- the catalogue


@dataclass(frozen=True)
class EffectSpec:
    """One candidate effect: a structured change of the nominal with named parameters.

    Attributes:
        kind: one of :data:`EFFECT_KINDS`.
        channel: index of the output it changes.
        source: coupling source output index (``None`` otherwise).
        names: parameter names (SI units in the name suffix).
        lower, upper: bounds per parameter.
        grid: values of the first parameter tried before the local fit.
        defaults: starting values of the other parameters.
        apply: ``(nominal, values) -> nominal``.
        fixed: parameters taken from the model, not fitted (reported with the fitted ones).
    """

    kind: str
    channel: int
    source: int | None
    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    grid: tuple[float, ...]
    defaults: tuple[float, ...]
    apply: Callable[[Nominal, np.ndarray], Nominal] = field(repr=False, compare=False)
    fixed: Mapping[str, float] = field(default_factory=dict)

    @property
    def n_params(self) -> int:
        """Number of fitted parameters."""
        return len(self.names)

    def label(self, outputs: Sequence[str]) -> str:
        """Human-readable name, e.g. ``delay on temperature``."""
        if self.kind == "coupling" and self.source is not None:
            t = self.fixed.get("time_constant_s")
            via = f" (T {t:.4g} s)" if t is not None else ""
            return f"coupling {outputs[self.source]} -> {outputs[self.channel]}{via}"
        if self.kind in ("leak", "heat_loss"):
            return self.kind.replace("_", " ")
        return f"{self.kind} on {outputs[self.channel]}"


def _delay(ch: int) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        delays = nom.delays_s.copy()
        delays[ch] += p[0]
        return replace(nom, delays_s=delays)

    return apply


def _lag(ch: int, name: str) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        t = max(float(p[0]), 1e-9)
        out = nom.with_state(nom.c[ch] / t, -1.0 / t, nom.d[ch] / t, name)
        c, d = out.c.copy(), out.d.copy()
        c[ch] = 0.0
        c[ch, -1] = 1.0
        d[ch] = 0.0
        return replace(out, c=c, d=d)

    return apply


def _gain(ch: int) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        c, d = nom.c.copy(), nom.d.copy()
        c[ch] *= 1.0 + p[0]
        d[ch] *= 1.0 + p[0]
        return replace(nom, c=c, d=d)

    return apply


def _coupling(src: int, ch: int, name: str, t_s: float) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        k0, k_inf = float(p[0]), float(p[1])
        c_src, d_src = nom.c[src].copy(), nom.d[src].copy()
        out = nom.with_state(c_src / t_s, -1.0 / t_s, d_src / t_s, name)
        c, d = out.c.copy(), out.d.copy()
        c[ch, : c_src.size] += k_inf * c_src
        c[ch, -1] += k0 - k_inf
        d[ch] += k_inf * d_src
        return replace(out, c=c, d=d)

    return apply


def channel_time_constants(nom: Nominal, ch: int, min_s: float) -> list[float]:
    """Time constants (s) of the real modes that output ``ch`` sees and some input drives.

    A coupling into ``ch`` enters through the channel's own dynamics, so its time constant
    is one of these (the fit picks which).
    """
    lam, vec = np.linalg.eig(nom.a)
    left = np.linalg.inv(vec)
    seen = np.abs(nom.c[ch] @ vec) * np.linalg.norm(left @ nom.b, axis=1)
    scale = float(np.max(seen, initial=0.0))
    out = sorted(
        {
            float(f"{-1.0 / lam[i].real:.6g}")
            for i in range(lam.size)
            if abs(lam[i].imag) < 1e-9
            and lam[i].real < 0
            and seen[i] > 1e-6 * scale
            and -1.0 / lam[i].real >= min_s
        }
    )
    return out


def _state_rate(rows: Sequence[tuple[int, int, float]]) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        a = nom.a.copy()
        for i, j, scale in rows:
            a[i, j] += scale * p[0]
        return replace(nom, a=a)

    return apply


def catalogue(
    nominal: Nominal,
    outputs: Sequence[str],
    *,
    period_s: float,
    operating_point: Mapping[str, float],
    max_time_fraction: float = 0.25,
) -> tuple[list[EffectSpec], list[tuple[str, str]]]:
    """The candidate effects that apply to this model, and those that do not (with why).

    Args:
        nominal: the model's nominal plant.
        outputs: output names (``height``/``temperature`` for the tank models).
        period_s: excitation period (s): bounds delays and time constants.
        operating_point: operating output values (the heat loss needs the temperature).
        max_time_fraction: delays and time constants up to this fraction of the period.
    """
    t_max = max_time_fraction * period_s
    times = tuple(float(x) for x in np.geomspace(0.5, t_max, 16))
    specs: list[EffectSpec] = []
    skipped: list[tuple[str, str]] = []
    for ch, out in enumerate(outputs):
        specs.append(
            EffectSpec(
                "delay", ch, None, ("delay_s",), (0.0,), (t_max,), (0.0, *times), (), _delay(ch)
            )
        )
        specs.append(
            EffectSpec(
                "lag",
                ch,
                None,
                ("time_constant_s",),
                (0.0,),
                (t_max,),
                times,
                (),
                _lag(ch, f"lag_{out}"),
            )
        )
        specs.append(
            EffectSpec(
                "gain",
                ch,
                None,
                ("gain_error",),
                (-0.9,),
                (5.0,),
                (-0.5, -0.2, 0.0, 0.2, 0.5, 1.0),
                (),
                _gain(ch),
            )
        )
    for ch, out in enumerate(outputs):
        for t_c in channel_time_constants(nominal, ch, min_s=1.0):
            for src, src_name in enumerate(outputs):
                if src == ch:
                    continue
                specs.append(
                    EffectSpec(
                        "coupling",
                        ch,
                        src,
                        ("dc_gain", "hf_gain"),
                        (-50.0, -50.0),
                        (50.0, 50.0),
                        (0.0,),
                        (0.0,),
                        _coupling(src, ch, f"coupling_{src_name}_to_{out}", t_c),
                        fixed={"time_constant_s": t_c},
                    )
                )
    names = list(nominal.states)
    thermal = next((n for n in THERMAL_STATES if n in names), None)
    if "height" not in names or thermal is None:
        why = (
            "not applicable: the model's nominal has no states named 'height' and "
            "'energy'/'temperature' (the mass and energy balances a {} changes); "
            "add `states:` to the nominal `ss`"
        )
        skipped += [("leak", why.format("leak")), ("heat_loss", why.format("heat loss"))]
        return specs, skipped
    ih, it = names.index("height"), names.index(thermal)
    base = max(abs(nominal.a[ih, ih]), abs(nominal.a[it, it]), 1e-6)
    rates = tuple(float(x) for x in np.geomspace(base * 1e-2, base * 10.0, 16))
    h_ch = outputs.index("height") if "height" in outputs else 0
    specs.append(
        EffectSpec(
            "leak", h_ch, None, ("rate_per_s",), (0.0,), (20.0 * base,), rates, (),
            _state_rate([(ih, ih, -1.0), (it, it, -1.0)]),
        )
    )  # fmt: skip
    heat_rows = [(it, it, -1.0)]
    if thermal == "energy":
        t0 = operating_point.get("temperature")
        if t0 is None:
            skipped.append(("heat_loss", "not applicable: the model has no operating temperature"))
            return specs, skipped
        heat_rows.append((it, ih, float(t0)))
    t_ch = outputs.index("temperature") if "temperature" in outputs else ih
    specs.append(
        EffectSpec(
            "heat_loss", t_ch, None, ("rate_per_s",), (0.0,), (20.0 * base,), rates, (),
            _state_rate(heat_rows),
        )
    )  # fmt: skip
    return specs, skipped


# --------------------------------------------------------------------------- fit data


@dataclass(frozen=True)
class BinData:
    """Excited harmonic bins of a set of windows, stacked.

    Attributes:
        theta: (k,) float, rad/sample.
        u: (k, nu) complex, input DFT (power convention).
        y: (k, ny) complex, output DFT.
        scale: (k, ny) float, the model's noise amplitude per bin and output.
        window: (k,) int, index of the window each bin comes from.
        n_windows: number of windows stacked.
        noise: (k, ny) float, measurement-noise power of ``y`` at each bin, scaled like the
            error (``|Y|^2 / scale^2`` at the two neighbouring non-harmonic bins, which carry
            noise only); 0 where a window has one period (no such bins).
    """

    theta: np.ndarray
    u: np.ndarray
    y: np.ndarray
    scale: np.ndarray
    window: np.ndarray
    n_windows: int
    noise: np.ndarray


def excited_bins(datum: Datum, floor: float) -> np.ndarray:
    """Indices of the excited harmonic bins of a datum.

    Harmonic: n a multiple of the number of periods, 0 < n < N/2; excited: input power at
    least ``floor`` times the largest harmonic's.
    """
    n_per = datum.n_samples // datum.period_samples
    n = np.arange(datum.theta.size)
    harmonic = (n % n_per == 0) & (n > 0) & (n < datum.n_samples // 2)
    power = np.sum(np.abs(datum.u_bins) ** 2, axis=1)
    top = float(np.max(power[harmonic], initial=0.0))
    if top <= 0.0:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(harmonic & (power >= floor * top))


def noise_scale(model: LFTModel, theta: np.ndarray, ts_s: float, y_rms: np.ndarray) -> np.ndarray:
    """(k, ny) float: the model's noise amplitude on each output at each bin.

    ``sqrt(sum_j |P_{y_c w_j}|^2)``; an output without a noise channel falls back to 1e-3 of
    the output's RMS (so that its error still counts, on its own scale).
    """
    resp = model.response(theta, ts_s)
    p_w = resp.p22  # (k, ny, nw)
    scale = (
        np.sqrt(np.sum(np.abs(p_w) ** 2, axis=2))
        if p_w.shape[2]
        else np.zeros((theta.size, model.ny))
    )
    fallback = np.maximum(1e-3 * y_rms, 1e-12)[None, :]
    return np.where(scale > 0.0, scale, fallback)


def bin_data(datums: Sequence[Datum], model: LFTModel, floor: float) -> BinData:
    """Stack the excited bins of several datums."""
    parts = []
    for i, d in enumerate(datums):
        idx = excited_bins(d, floor)
        y_rms = np.sqrt(np.sum(d.bin_weights[:, None] * np.abs(d.y_bins) ** 2, axis=0))
        scale = noise_scale(model, d.theta[idx], d.ts_s, y_rms)
        if d.n_samples // d.period_samples >= 2:
            last = d.theta.size - 1
            around = np.abs(d.y_bins[np.clip(idx - 1, 0, last)]) ** 2
            around += np.abs(d.y_bins[np.clip(idx + 1, 0, last)]) ** 2
            noise = 0.5 * around / scale**2
        else:
            noise = np.zeros((idx.size, d.y_bins.shape[1]))
        parts.append(
            (d.theta[idx], d.u_bins[idx], d.y_bins[idx], scale, np.full(idx.size, i), noise)
        )
    theta, u, y, scale, win, noise = (np.concatenate([p[j] for p in parts]) for j in range(6))
    return BinData(theta, u, y, scale, win, len(datums), noise)


def scaled_error(nom: Nominal, data: BinData, ts_s: float) -> np.ndarray:
    """(k, ny) complex: ``(Y - G U) / scale`` at the stacked bins (fast hold response)."""
    g = nom.hold_response(data.theta, ts_s)
    return (data.y - np.einsum("kij,kj->ki", g, data.u)) / data.scale


def cost(nom: Nominal, data: BinData, ts_s: float) -> float:
    """Sum of squared scaled errors (the fit criterion)."""
    return float(np.sum(np.abs(scaled_error(nom, data, ts_s)) ** 2))


def noise_floor(data: BinData) -> float:
    """The cost measurement noise alone would give at these bins (same scaling as :func:`cost`)."""
    return float(np.sum(data.noise))


# --------------------------------------------------------------------------- fitting


def _apply_all(nom: Nominal, specs: Sequence[EffectSpec], x: np.ndarray) -> Nominal:
    i = 0
    for s in specs:
        nom = s.apply(nom, x[i : i + s.n_params])
        i += s.n_params
    return nom


def fit_effects(
    nominal: Nominal,
    specs: Sequence[EffectSpec],
    data: BinData,
    ts_s: float,
    starts: Sequence[np.ndarray] | None = None,
) -> tuple[np.ndarray, float]:
    """Fit the parameters of ``specs`` jointly by least squares on the scaled error.

    The first parameter of every spec is scanned over its grid (the leading specs' coarsely,
    and also from the given ``starts``), the others at their defaults; the two best points
    start a bounded trust-region fit.

    Returns:
        ``(values, cost)``: fitted parameters (concatenated in spec order) and the cost.
    """
    lower = np.concatenate([s.lower for s in specs]).astype(float)
    upper = np.concatenate([s.upper for s in specs]).astype(float)

    def residual(x: np.ndarray) -> np.ndarray:
        try:
            e = scaled_error(_apply_all(nominal, specs, x), data, ts_s)
        except ModelError:  # an unstable intermediate: a large, finite penalty
            return np.full(2 * data.y.size, 1e6)
        return np.concatenate([e.real.ravel(), e.imag.ravel()])

    last = specs[-1]
    offset = sum(s.n_params for s in specs[:-1])
    bases: list[np.ndarray] = []
    if starts:  # the given values of the leading specs (e.g. a single effect's fit)
        given = np.concatenate(list(starts))
        if given.size == offset:
            bases.append(given)
    # a coarse scan of the leading specs' first parameters too: a single effect's fit is
    # biased by the effect it misses (a delay fitted alone absorbs part of a heat loss)
    lead_grids = [
        [np.array([g, *s.defaults], dtype=float) for g in s.grid[:: 2 if len(s.grid) > 8 else 1]]
        for s in specs[:-1]
    ]
    for combo in itertools.product(*lead_grids):
        bases.append(np.concatenate(combo) if combo else np.zeros(0))
    scan = []
    for base in bases:
        for g in last.grid:
            x = np.concatenate([base, [g, *last.defaults]])
            r = residual(x)
            scan.append((float(r @ r), x))
    scan.sort(key=lambda t: t[0])
    best_x, best_c = scan[0][1], scan[0][0]
    for _, x0 in scan[:2]:
        sol = scipy.optimize.least_squares(
            residual, np.clip(x0, lower, upper), bounds=(lower, upper), x_scale="jac", max_nfev=200
        )
        c = float(sol.fun @ sol.fun)
        if c < best_c:
            best_x, best_c = sol.x, c
    return np.asarray(best_x, dtype=float), best_c


# --------------------------------------------------------------------------- judging


@dataclass(frozen=True)
class Assessment:
    """A model judged on the held-out windows.

    Attributes:
        beta: largest validation beta over the held-out windows.
        beta_windows: beta per held-out window.
        rms: per output, RMS over time of the model's periodic simulation error on the
            excited band (model units): what the model gets wrong, noise excluded.
        rms_raw: per output, RMS of the whole simulation error (noise included).
        cost: scaled squared error at the excited bins (the fit criterion).
        residual_tests: the paper's Sec. 2.1 statistics on the held-out window of largest
            beta (``stats.ResidualTests.to_dict()``), or an error string.
        results: the validations, one per held-out window.
    """

    beta: float
    beta_windows: list[float]
    rms: dict[str, float]
    rms_raw: dict[str, float]
    cost: float
    residual_tests: dict[str, Any] | str
    results: list[ValidationResult] = field(repr=False, default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "beta": self.beta,
            "beta_windows": self.beta_windows,
            "rms": self.rms,
            "rms_raw": self.rms_raw,
            "cost": self.cost,
            "residual_tests": self.residual_tests,
        }


def assess(
    model: LFTModel, datums: Sequence[Datum], windows: Sequence[Window], config: DiagnosisConfig
) -> Assessment:
    """Validate ``model`` on every held-out datum and measure its simulation error."""
    results = [validate(d, model) for d in datums]
    betas = [float(r.beta) for r in results]
    names = list(model.output_names)
    band = np.zeros(model.ny)
    raw = np.zeros(model.ny)
    for d, r in zip(datums, results, strict=True):
        idx = excited_bins(d, config.excitation_floor)
        e = r.error  # (n_bins, ny) raw error Y - G U
        band += np.sum(d.bin_weights[idx, None] * np.abs(e[idx]) ** 2, axis=0)
        raw += np.sum(d.bin_weights[1:, None] * np.abs(e[1:]) ** 2, axis=0)
    band, raw = np.sqrt(band / len(datums)), np.sqrt(raw / len(datums))
    worst = int(np.argmax(betas))
    tests: dict[str, Any] | str
    try:
        residual = inverse_dft(
            results[worst].error, datums[worst].n_samples, datums[worst].convention
        )
        tests = stats.residual_tests(
            residual,
            windows[worst].u,
            output_names=names,
            input_names=list(model.input_names),
            max_lag=config.max_lag,
            alpha=config.alpha,
        ).to_dict()
    except DatumError as err:
        tests = f"not computed: {err}"
    data = bin_data(datums, model, config.excitation_floor)
    nominal_cost = float(np.sum(np.abs(_model_scaled_error(model, data, datums[0].ts_s)) ** 2))
    return Assessment(
        beta=max(betas),
        beta_windows=betas,
        rms={n: float(v) for n, v in zip(names, band, strict=True)},
        rms_raw={n: float(v) for n, v in zip(names, raw, strict=True)},
        cost=nominal_cost,
        residual_tests=tests,
        results=results,
    )


def _model_scaled_error(model: LFTModel, data: BinData, ts_s: float) -> np.ndarray:
    g = model.response(data.theta, ts_s).p23
    return (data.y - np.einsum("kij,kj->ki", g, data.u)) / data.scale


# --------------------------------------------------------------------------- evidence


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


def evidence(  # noqa: PLR0917 - the fitted effect and where it was fitted
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


# --------------------------------------------------------------------------- the driver


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
    """

    spec: EffectSpec
    values: np.ndarray
    fit_cost: float
    heldout_cost: float
    reduction: float
    evidence: str = ""

    def to_dict(self, outputs: Sequence[str]) -> dict[str, Any]:
        """The documented JSON entry of an effect."""
        out: dict[str, Any] = {
            "kind": self.spec.kind,
            "channel": outputs[self.spec.channel],
            "parameters": {
                **{n: float(v) for n, v in zip(self.spec.names, self.values, strict=True)},
                **{n: float(v) for n, v in self.spec.fixed.items()},
            },
            "evidence": self.evidence,
            "heldout_reduction": self.reduction,
        }
        if self.spec.source is not None:
            out["source"] = outputs[self.spec.source]
        return out


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

    def to_json(self, model_file: str | None = None) -> dict[str, Any]:
        """The documented JSON (README "Diagnosis")."""

        def side(a: Assessment) -> dict[str, Any]:
            return a.to_dict()

        return {
            "model": self.model,
            "adequate": self.adequate,
            "noise_ratio": self.noise_ratio,
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
    return [
        make_datum(w.u, w.y, ts_s=w.ts_s, period_samples=w.period_samples, convention=convention)
        for w in windows
    ]


def diagnose(
    windows: Sequence[Window],
    doc: Mapping[str, Any],
    config: DiagnosisConfig | None = None,
    *,
    source: str = "model",
    convention: NormConvention = NormConvention.POWER,
) -> Diagnosis:
    """Trace the residual of ``doc``'s model on ``windows`` to the effect it lacks.

    Args:
        windows: non-overlapping windows of whole periods (same ts and period).
        doc: the model document (as loaded from YAML).
        config: settings.
        source: label of the model in messages.
        convention: norm convention of the validations.

    Raises:
        DiagnosisError: too little data, no excitation, or a model that cannot be changed.
    """
    cfg = config or DiagnosisConfig()
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
    specs, skipped = catalogue(
        nominal,
        outputs,
        period_s=fit_w[0].period_samples * ts,
        operating_point=model.operating_point,
        max_time_fraction=cfg.max_time_fraction,
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
            pair = _best_pair(singles, specs, judged, cfg)
            if (
                pair is not None
                and pair[0] <= (1.0 - cfg.min_second_reduction) * best.heldout_cost
                and pair[0] <= (1.0 - cfg.min_reduction) * j0
            ):
                chosen = [pair[1], pair[2]]
    changed = nominal
    for e in chosen:
        changed = e.spec.apply(changed, e.values)
    # evidence: each chosen effect against the model with the other chosen effects added, so
    # that its own signature shows; its reduction is what it removes on top of the others
    j_all = cost(changed, held_data, ts)
    with_evidence = []
    for i, e in enumerate(chosen):
        base = nominal
        for other in chosen[:i] + chosen[i + 1 :]:
            base = other.spec.apply(base, other.values)
        red = 1.0 - j_all / max(cost(base, held_data, ts), 1e-300)
        text = evidence(e.spec, e.values, base, fit_data, ts, outputs, red)
        with_evidence.append(replace(e, reduction=red, evidence=text))
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
    document = changed_document(doc, changed, chosen, outputs) if chosen else None
    if document is not None:
        after_model = model_from_dict(document, f"{source} (diagnosed)")
        after = assess(after_model, held_d, held_w, cfg)
    else:
        after = before
    summary = _summary(model.name, before, after, chosen, outputs)
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
        adequate=not chosen,
        summary=summary,
        noise_ratio=j0 / floor if floor > 0 else math.inf,
        heldout=held_d,
        fit_bins=fit_data,
        nominal_before=nominal,
        nominal_after=changed,
    )


def _best_pair(
    singles: Sequence[FittedEffect],
    specs: Sequence[EffectSpec],
    judged: Callable[
        [Sequence[EffectSpec], Sequence[np.ndarray] | None], tuple[np.ndarray, float, float]
    ],
    cfg: DiagnosisConfig,
) -> tuple[float, FittedEffect, FittedEffect] | None:
    """The best pair of effects, fitted jointly, each of the leading singles as the first.

    Not greedy: a first effect that fits best alone can be the wrong one when a second
    effect is present (a lag mimics part of a delay plus a leak), so every pair with one of
    the ``pair_candidates`` best singles is fitted and judged on the held-out windows.

    Returns:
        ``(penalised held-out cost, first, second)`` or ``None``.
    """
    results: list[tuple[float, FittedEffect, FittedEffect]] = []
    seen: set[frozenset[int]] = set()
    firsts = [e for e in singles[: cfg.pair_candidates] if e.reduction > 0.0]  # best first
    for first in firsts:
        for s in specs:
            key = frozenset((id(first.spec), id(s)))
            same = s.kind == first.spec.kind and s.channel == first.spec.channel
            if same or key in seen:
                continue
            seen.add(key)
            values, fit_cost, adj = judged([first.spec, s], [first.values])
            n1 = first.spec.n_params
            second = FittedEffect(s, values[n1:], fit_cost, adj, 1.0 - adj / first.heldout_cost)
            results.append((adj, replace(first, values=values[:n1]), second))
    if not results:
        return None
    results.sort(key=lambda t: t[0])
    close = [t for t in results if t[0] <= cfg.parsimony * results[0][0]]
    return min(close, key=lambda t: (t[1].spec.n_params + t[2].spec.n_params, t[0]))


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


def _summary(
    name: str,
    before: Assessment,
    after: Assessment,
    chosen: Sequence[FittedEffect],
    outputs: Sequence[str],
) -> str:
    if not chosen:
        return (
            f"Model {name} is adequate for this datum: no effect of the catalogue removes enough "
            f"of the held-out error to be worth its parameters (held-out beta {before.beta:.3f})."
        )
    added = " and ".join(e.spec.label(outputs) for e in chosen)
    rms = ", ".join(f"{o} {before.rms[o]:.4g} -> {after.rms[o]:.4g}" for o in outputs)
    return (
        f"Model {name} lacks {added}. On held-out data beta {before.beta:.3f} -> "
        f"{after.beta:.3f}; RMS simulation error {rms} (model units)."
    )


# --------------------------------------------------------------------------- bags


def windows_from_bag(
    path: str | Path, model: LFTModel, config: Any = None
) -> tuple[list[Window], Any]:
    """The judged, non-overlapping windows of a bag, read through the replay path.

    Args:
        path: rosbag2 directory or MCAP file.
        model: the model (the replay validates it on the way; its reports are returned).
        config: ``replay.ReplayConfig`` (topics, units, window settings).

    Returns:
        ``(windows, replay_result)``; windows are in time order, times in s from the bag
        start.

    Raises:
        BagError subclasses: the path is not a readable bag.
    """
    from twotank_validation import replay  # noqa: PLC0415 - bags only when reading a bag

    cfg = config or replay.ReplayConfig()
    kept: list[tuple[int, replay.WindowSnapshot]] = []

    def collect(rep: Any, snap: replay.WindowSnapshot) -> None:
        if kept and snap.stamps_ns[0] <= kept[-1][1].stamps_ns[-1]:
            return  # overlaps the last kept window
        kept.append((int(snap.stamps_ns[0]), snap))

    result = replay.replay_bag(path, [model], cfg, on_window=collect)
    t0 = result.bag_start_ns
    mon = cfg.monitor
    windows = [
        Window(snap.u, snap.y, mon.ts_s, mon.period_samples, (start - t0) * 1e-9)
        for start, snap in kept
    ]
    return windows, result
