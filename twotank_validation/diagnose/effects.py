"""The nominal plant as a model file states it, and the catalogue of effects that change it.

Catalogue (parameters in SI units; rates in 1/s, times in s):

* ``delay`` on an output: ``y_c(t) -> y_c(t - tau)`` (``output_delays_s`` in the YAML).
* ``lag`` on an output: ``y_c -> y_c / (1 + T s)`` (an extra state).
* ``gain`` on an output: ``y_c -> (1 + g) y_c``: one output's response to every input.
* ``input_gain`` on an input (a weak or partly blocked valve): ``u_i -> (1 + g) u_i``, the
  nominal's ``B[:, i]`` and ``D[:, i]`` scaled: every output's response to that one input.
  With two inputs both excited it differs from an output gain, which scales one output's
  response to both inputs.
* ``coupling`` from output a into output c: ``y_c += K(s) y_a`` with
  ``K(s) = (k0 + k_inf T s) / (1 + T s)`` (DC gain ``k0``, high-frequency gain ``k_inf``,
  time constant ``T``; an extra state). The paper's Model A lacks the level-to-temperature
  coupling of Model B, which is exactly this form with T the temperature time constant.
* ``leak``: an extra outflow proportional to the level; the mass (``height``) and the
  energy/temperature states both decay faster by the rate ``r`` (needs state names).
* ``heat_loss``: heat lost to ambient, ``q (t - t_amb)``; the energy/temperature state decays
  faster by ``c`` and, for an energy state E = h t, the level feeds it with ``+c t0``
  (needs state names and the operating temperature).
* ``hot_supply``: the hot supply temperature changed by ``delta`` (model temperature units):
  only the hot input's entry into the thermal balance changes. For an energy state
  ``E = h t`` the hot flow brings ``f_h t_h`` and the level balance ``f_h``, so the entry of
  the hot input into ``E`` gains ``delta`` times its entry into ``height``; for a temperature
  state (level held at ``h0``) ``delta / h0`` times. "Entry" is the hot input's column of
  ``B`` and the columns of its valve-lag states (states driven by that input alone, with
  no other dynamics). Needs state names, an input named ``hot`` and, for a temperature
  state, the operating height.
* ``mode``: one lightly damped pole pair of the nominal (a resonance of a structure) moved
  to a new natural frequency ``frequency_hz`` (Hz) and damping ratio ``damping_ratio``,
  its mode shape kept (:func:`shift_mode`; the other modes unchanged). One candidate per
  pair with a damping ratio below :data:`MODE_MAX_DAMPING` inside the excited band
  (:func:`mode_specs`); a discrete nominal's poles map through ``z = exp(s T)``.

Outside the state-space catalogue (they cannot be written into an LTI model file; reported
with a recommendation, :data:`REPORTED_KINDS`; every kind's properties are one record,
:data:`twotank_validation.diagnose.kinds.EFFECT_RECORDS`):

* ``offset``: a constant sensor bias ``y_c += b``. The mean is removed before the DFT, so it
  is invisible to the dynamic fit; it is judged on the windows' means against a reference
  operating point (:mod:`twotank_validation.diagnose.steady`).
* ``saturation``: an input clipped, ``u_i -> min(u_i, hi)`` or ``max(u_i, lo)``, judged with a
  harmonic-distortion test and a fit of the level (:mod:`twotank_validation.diagnose.distortion`).

A ``drift`` (a slowly moving sensor reading, ``y_c += d t``) is not diagnosed: it is not a
property of an LTI model, and the datum's transient check flags the windows it spoils.

A discrete-time nominal (``ss`` with ``dt_s``, e.g. a fit from measured data) takes the
effects that act on its channels (docs/theory.md §14): ``gain`` and ``input_gain`` scale its
``C``/``D`` rows or ``B``/``D`` columns as in continuous time; ``delay`` is
``exp(-j theta tau / dt)`` at the bins (whole samples exactly, a fractional part as the
band-limited delay of a periodic signal); ``lag`` and ``coupling`` append their first-order
filter discretised by the model's ``intersample`` hold (first-order hold under ``exact``);
``mode`` moves a pole pair of its own ``A`` through ``z = exp(s T)``. The tank effects
need named continuous states and do not apply.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from twotank_validation.core import lti
from twotank_validation.core.lti import Intersample, StateSpace
from twotank_validation.core.model import model_from_dict
from twotank_validation.diagnose.inputs import DiagnosisError
from twotank_validation.diagnose.kinds import (
    EFFECT_KINDS,
    REPORTED_KINDS,
    EffectKind,
    ModelNeed,
)

__all__ = [  # the kinds' tuples are views of their records (diagnose.kinds)
    "EFFECT_KINDS",
    "MODE_MAX_DAMPING",
    "REPORTED_KINDS",
    "THERMAL_STATES",
    "Bins",
    "EffectSpec",
    "Mode",
    "Nominal",
    "catalogue",
    "channel_time_constants",
    "input_lag_states",
    "input_shares",
    "modal_coordinates",
    "mode_coefficients",
    "mode_of_pole",
    "mode_shift_text",
    "mode_specs",
    "modes",
    "s_from_z",
    "shift_mode",
    "z_from_s",
]


class Bins(Protocol):
    """What an effect's evidence reads of the fit's bins (:class:`~.fit.BinData` has it)."""

    @property
    def theta(self) -> np.ndarray:
        """(k,) rad/sample."""
        ...

    @property
    def u(self) -> np.ndarray:
        """(k, nu) complex input DFT."""
        ...

    @property
    def y(self) -> np.ndarray:
        """(k, ny) complex output DFT."""
        ...

    @property
    def scale(self) -> np.ndarray:
        """(k, ny) the model's noise amplitude."""
        ...


THERMAL_STATES = ("energy", "temperature")
"""State names that the leak and heat-loss effects recognise as the thermal state."""


# --------------------------------------------------------------------------- nominal plant


@dataclass(frozen=True)
class Nominal:
    """A nominal plant as it appears in a model file (continuous, or discrete with ``dt_s``).

    Attributes:
        a, b, c, d: state-space matrices (n, n), (n, nu), (ny, n), (ny, nu).
        delays_s: (ny,) float, output transport delays in s.
        states: one name per state (``""`` when unnamed).
        dt_s: sample period (s) of a discrete-time nominal; ``None``: continuous.
        intersample: the model's intersample assumption (how a continuous nominal meets the
            bins, how an effect's filter is discretised on a discrete one).
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    delays_s: np.ndarray
    states: tuple[str, ...]
    dt_s: float | None = None
    intersample: Intersample = Intersample.ZOH

    @classmethod
    def from_document(cls, doc: Mapping[str, Any], source: str = "model") -> Nominal:
        """Read the nominal of a model document (``nominal: {ss: ...}`` or ``tf``/``gain``).

        Raises:
            DiagnosisError: a generalized-plant model.
        """
        if "generalized_plant" in doc or "nominal" not in doc:
            raise DiagnosisError(
                f"{source}: diagnosis needs a structured model (nominal, perturbations, noise); "
                "a generalized plant has no nominal channels to change"
            )
        model = model_from_dict(doc, source)
        sys = model.nominal
        assert sys is not None
        node = doc["nominal"]
        names: list[str] = []
        if isinstance(node, Mapping) and isinstance(node.get("ss"), Mapping):
            names = [str(s) for s in node["ss"].get("states") or []]
        if len(names) != sys.n_states:
            names = [""] * sys.n_states
        ny = sys.shape[0]
        delays = np.array(sys.output_delays_s or (0.0,) * ny, dtype=float)
        return cls(sys.a, sys.b, sys.c, sys.d, delays, tuple(names), sys.dt_s, model.intersample)

    def state_space(self) -> StateSpace:
        """The state space (continuous, or discrete at ``dt_s``) with its delays."""
        delays = tuple(self.delays_s.tolist())
        return StateSpace(self.a, self.b, self.c, self.d, self.dt_s, delays)

    def response(self, theta: np.ndarray, ts_s: float) -> np.ndarray:
        """The response at the bins as the validator has it (:func:`lti.bin_response`).

        Shape (n_bins, ny, nu) complex.
        """
        return lti.bin_response(self.state_space(), theta, ts_s, self.intersample)

    def hold_response(self, theta: np.ndarray, ts_s: float) -> np.ndarray:
        """Fast response for fitting: ``G(j w) H(theta)`` times delays.

        ``H`` is the hold of the model's ``intersample``: ``(1 - e^{-j theta}) / (j theta)``
        (zero-order), ``sinc(theta / 2)^2`` (first-order, the triangle hold) or 1 (exact).
        It differs from the discretisation (:meth:`response`) only by aliasing,
        ``O(|G(j(w + 2 pi / ts))|)``, i.e. ~1e-4 relative at the excited bins of the tank
        models (< 0.1 Hz at 10 Hz sampling). One batched solve instead of a matrix
        exponential per evaluation: the fit evaluates thousands of candidate plants. A
        discrete nominal is evaluated at ``exp(j theta)`` as it is. Shape (n_bins, ny, nu).
        """
        if self.dt_s is not None:
            return lti.frequency_response(self.state_space(), np.asarray(theta, dtype=float))
        omega = np.asarray(theta, dtype=float) / ts_s
        n = self.a.shape[0]
        jw = 1j * omega[:, None, None] * np.eye(n)[None]
        x = np.linalg.solve(jw - self.a[None], np.broadcast_to(self.b, (omega.size, *self.b.shape)))
        g = np.einsum("pn,knm->kpm", self.c, x) + self.d[None]
        hold = _hold_factor(np.asarray(theta, dtype=float), self.intersample)
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
        if self.dt_s is not None:
            ss["dt_s"] = self.dt_s
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


def _hold_factor(theta: np.ndarray, how: Intersample) -> np.ndarray:
    """(n_bins,) complex: the hold's response relative to ``G(j w)`` (aliasing left out)."""
    th = np.where(theta == 0.0, 1.0, theta)
    if how is Intersample.EXACT:
        return np.ones(theta.size, dtype=complex)
    if how is Intersample.FOH:
        return np.where(theta == 0.0, 1.0, (np.sin(th / 2.0) / (th / 2.0)) ** 2).astype(complex)
    return np.where(theta == 0.0, 1.0, (1.0 - np.exp(-1j * th)) / (1j * th))


def _lag_filter(nom: Nominal, t_s: float) -> tuple[float, float, float, float]:
    """``1 / (1 + T s)`` as ``(a, b, c, d)`` scalars in the nominal's time domain.

    Continuous: ``(-1/T, 1/T, 1, 0)``; on a discrete nominal the filter discretised at its
    ``dt_s`` by the model's hold (first-order hold under ``exact``).
    """
    a, b, c, d = (np.array([[x]]) for x in (-1.0 / t_s, 1.0 / t_s, 1.0, 0.0))
    lag = StateSpace(a, b, c, d)
    if nom.dt_s is not None:
        lag = lti.discretise(lag, nom.dt_s, nom.intersample)
    return float(lag.a[0, 0]), float(lag.b[0, 0]), float(lag.c[0, 0]), float(lag.d[0, 0])


# --------------------------------------------------------------------------- the catalogue


@dataclass(frozen=True)
class EffectSpec:
    """One candidate effect: a structured change of the nominal with named parameters.

    Attributes:
        kind: one of :data:`EFFECT_KINDS` (its properties: ``kind.record``).
        channel: index of the output it changes.
        source: coupling source output index (``None`` otherwise).
        names: parameter names (SI units in the name suffix).
        lower, upper: bounds per parameter.
        grid: values of the first parameter tried before the local fit.
        defaults: starting values of the other parameters.
        apply: ``(nominal, values) -> nominal``.
        fixed: parameters taken from the model, not fitted (reported with the fitted ones).
        input: index of the input an input effect changes (``None`` for output effects;
            ``channel`` is then the output that carries most of the change, for figures).
        input_name: that input's name.
        explain: the effect's own evidence in words, ``(values, before, data, ts_s,
            outputs) -> str`` (``None``: the generic evidence of
            :mod:`twotank_validation.diagnose.evidence`).
        acts_on: index of the output the effect acts on when that is not the one its
            evidence shows (``channel``): a constant leak moves the level, and its response
            shows on the temperature. ``None``: ``channel``.
    """

    kind: EffectKind
    channel: int
    source: int | None
    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    grid: tuple[float, ...]
    defaults: tuple[float, ...]
    apply: Callable[[Nominal, np.ndarray], Nominal] = field(repr=False, compare=False)
    fixed: Mapping[str, float] = field(default_factory=dict)
    input: int | None = None
    input_name: str = ""
    explain: Callable[[np.ndarray, Nominal, Bins, float, Sequence[str]], str] | None = field(
        default=None, repr=False, compare=False
    )
    acts_on: int | None = None

    def target(self, outputs: Sequence[str]) -> str:
        """What the effect acts on: the input's name for an input effect, else the output's."""
        if self.input is not None:
            return self.input_name
        return outputs[self.channel if self.acts_on is None else self.acts_on]

    @property
    def n_params(self) -> int:
        """Number of fitted parameters."""
        return len(self.names)

    def label(self, outputs: Sequence[str]) -> str:
        """Human-readable name, e.g. ``delay on temperature`` (the kind's ``record.label``)."""
        t = self.fixed.get("time_constant_s")
        f0 = self.fixed.get("nominal_frequency_hz")
        return self.kind.record.label.format(
            output=outputs[self.channel],
            input=self.input_name,
            source=outputs[self.source] if self.source is not None else "",
            via=f" (T {t:.4g} s)" if t is not None else "",
            mode=f"{int(self.fixed.get('mode', 0))} at {f0:.4g} Hz" if f0 is not None else "",
        )


def _delay(ch: int) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        delays = nom.delays_s.copy()
        delays[ch] += p[0]
        return replace(nom, delays_s=delays)

    return apply


def _lag(ch: int, name: str) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        fa, fb, fc, fd = _lag_filter(nom, max(float(p[0]), 1e-9))
        out = nom.with_state(fb * nom.c[ch], fa, fb * nom.d[ch], name)
        c, d = out.c.copy(), out.d.copy()
        c[ch] *= fd
        c[ch, -1] = fc
        d[ch] *= fd
        return replace(out, c=c, d=d)

    return apply


def _gain(ch: int) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        c, d = nom.c.copy(), nom.d.copy()
        c[ch] *= 1.0 + p[0]
        d[ch] *= 1.0 + p[0]
        return replace(nom, c=c, d=d)

    return apply


def _input_gain(i: int) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        b, d = nom.b.copy(), nom.d.copy()
        b[:, i] *= 1.0 + p[0]
        d[:, i] *= 1.0 + p[0]
        return replace(nom, b=b, d=d)

    return apply


def _hot_supply(
    thermal: int, height: int, hot: int, lags: Sequence[int], factor: float
) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        a, b = nom.a.copy(), nom.b.copy()
        for j in lags:
            a[thermal, j] += factor * p[0] * nom.a[height, j]
        b[thermal, hot] += factor * p[0] * nom.b[height, hot]
        return replace(nom, a=a, b=b)

    return apply


def input_lag_states(nom: Nominal, i: int) -> list[int]:
    """States that are a pure lag of input ``i`` (a valve): driven by it alone, no coupling."""
    out = []
    for j in range(nom.a.shape[0]):
        others = np.delete(nom.b[j], i)
        row = np.delete(nom.a[j], j)
        if nom.b[j, i] != 0.0 and not np.any(others) and not np.any(row):
            out.append(j)
    return out


def input_shares(nom: Nominal, data: Bins, ts_s: float, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Measured/modelled factor of input ``i``'s share of each output, and its scatter.

    Per output c the least-squares factor ``r_c`` with ``Y_c - sum_{j != i} G_cj U_j ~ r_c
    G_ci U_i`` over the bins (scaled by the noise weight), and the scatter: the RMS of what
    ``r_c`` leaves, relative to the share. Shapes (ny,) complex and (ny,) float.
    """
    g = nom.hold_response(data.theta, ts_s)
    parts = g * data.u[:, None, :]  # (k, ny, nu): each input's share of each output
    share = parts[:, :, i] / data.scale
    rest = (data.y - (np.sum(parts, axis=2) - parts[:, :, i])) / data.scale
    den = np.maximum(np.sum(np.abs(share) ** 2, axis=0), 1e-300)
    r = np.sum(np.conj(share) * rest, axis=0) / den
    scatter = np.sqrt(np.sum(np.abs(rest - r * share) ** 2, axis=0) / den)
    return r, scatter


def _factors(r: np.ndarray, outputs: Sequence[str]) -> str:
    return ", ".join(
        f"{o} {abs(x):.3f} ({np.degrees(np.angle(x)):+.1f} deg)"
        for o, x in zip(outputs, r, strict=True)
    )


def _explain_input_gain(i: int, names: Sequence[str]) -> Callable[..., str]:
    def explain(
        values: np.ndarray, before: Nominal, data: Bins, ts_s: float, outputs: Sequence[str]
    ) -> str:
        r, scatter = input_shares(before, data, ts_s, i)
        after = _input_gain(i)(before, values)
        others = [
            f"the {names[j]} input's stays at "
            + _factors(input_shares(after, data, ts_s, j)[0], outputs)
            for j in range(len(names))
            if j != i
        ]
        return (
            f"the {names[i]} input's share of every output is scaled by one nearly real "
            f"factor at every excited bin ({_factors(r, outputs)}; scatter per bin "
            f"{float(np.max(scatter)):.2f}){'; ' if others else ''}{'; '.join(others)}: the "
            f"{names[i]} path is weaker or stronger than modelled, not an output gain (which "
            f"scales one output's response to every input); fitted gain error {values[0]:+.1%}"
        )

    return explain


def _explain_hot_supply(hot: int, thermal_out: int, height_out: int) -> Callable[..., str]:
    def explain(
        values: np.ndarray, before: Nominal, data: Bins, ts_s: float, outputs: Sequence[str]
    ) -> str:
        r, _ = input_shares(before, data, ts_s, hot)
        t, h = r[thermal_out], r[height_out]
        return (
            f"the {outputs[thermal_out]}'s share of the hot input is {abs(t):.3f} of the "
            f"model's ({np.degrees(np.angle(t)):+.1f} deg) while the {outputs[height_out]}'s "
            f"stays at {abs(h):.3f}: the hot flow is right but brings a different heat, as "
            f"with the hot supply temperature changed by {values[0]:+.3g} (model units)"
        )

    return explain


def _coupling(src: int, ch: int, name: str, t_s: float) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        k0, k_inf = float(p[0]), float(p[1])
        fa, fb, fc, fd = _lag_filter(nom, t_s)  # K = k_inf + (k0 - k_inf) / (1 + T s)
        c_src, d_src = nom.c[src].copy(), nom.d[src].copy()
        out = nom.with_state(fb * c_src, fa, fb * d_src, name)
        c, d = out.c.copy(), out.d.copy()
        through = k_inf + (k0 - k_inf) * fd
        c[ch, : c_src.size] += through * c_src
        c[ch, -1] += (k0 - k_inf) * fc
        d[ch] += through * d_src
        return replace(out, c=c, d=d)

    return apply


def channel_time_constants(nom: Nominal, ch: int, min_s: float) -> list[float]:
    """Time constants (s) of the real modes that output ``ch`` sees and some input drives.

    A coupling into ``ch`` enters through the channel's own dynamics, so its time constant
    is one of these (the fit picks which).
    """
    lam, vec = np.linalg.eig(nom.a)
    if nom.dt_s is not None:  # the continuous rate of a discrete pole: log(z) / dt
        z = lam.astype(complex)  # a pole at 0 (a pure delay): rate -inf, no time constant
        lam = np.where(z == 0, -np.inf, np.log(np.where(z == 0, 1.0, z)) / nom.dt_s)
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
    inputs: Sequence[str] = (),
    band_hz: tuple[float, float] | None = None,
) -> tuple[list[EffectSpec], list[tuple[str, str]]]:
    """The candidate effects that apply to this model, and those that do not (with why).

    Args:
        nominal: the model's nominal plant.
        outputs: output names (``height``/``temperature`` for the tank models).
        period_s: excitation period (s): bounds delays and time constants.
        operating_point: operating output values (the heat loss needs the temperature).
        max_time_fraction: delays and time constants up to this fraction of the period.
        inputs: input names (``hot``/``cold``; the hot-supply change needs ``hot``);
            default ``input 0``, ``input 1``, ...
        band_hz: the excited band ``(lowest, highest)``, Hz: a mode shift is a candidate
            for the nominal's lightly damped modes inside it (:func:`mode_specs`).
    """
    t_max = max_time_fraction * period_s
    times = tuple(float(x) for x in np.geomspace(0.5, t_max, 16))
    specs: list[EffectSpec] = []
    skipped: list[tuple[str, str]] = []
    for ch, out in enumerate(outputs):
        specs.append(
            EffectSpec(
                EffectKind.DELAY,
                ch,
                None,
                EffectKind.DELAY.record.parameters,
                (0.0,),
                (t_max,),
                (0.0, *times),
                (),
                _delay(ch),
            )
        )
        specs.append(
            EffectSpec(
                EffectKind.LAG,
                ch,
                None,
                EffectKind.LAG.record.parameters,
                (0.0,),
                (t_max,),
                times,
                (),
                _lag(ch, f"lag_{out}"),
            )
        )
        specs.append(
            EffectSpec(
                EffectKind.GAIN,
                ch,
                None,
                EffectKind.GAIN.record.parameters,
                (-0.9,),
                (5.0,),
                (-0.5, -0.2, 0.0, 0.2, 0.5, 1.0),
                (),
                _gain(ch),
            )
        )
    nu = nominal.b.shape[1]
    in_names = list(inputs) if len(inputs) == nu else [f"input {i}" for i in range(nu)]
    w0 = 2.0 * np.pi / period_s  # the first harmonic: which output carries most of an input
    eye = np.eye(nominal.a.shape[0])
    at = 1j * w0 if nominal.dt_s is None else np.exp(1j * w0 * nominal.dt_s)
    g0 = np.abs(nominal.c @ np.linalg.solve(at * eye - nominal.a, nominal.b) + nominal.d)
    share = g0 / np.maximum(np.sum(g0, axis=1, keepdims=True), 1e-300)
    for i, name in enumerate(in_names):
        specs.append(
            EffectSpec(
                EffectKind.INPUT_GAIN, int(np.argmax(share[:, i])), None,
                EffectKind.INPUT_GAIN.record.parameters, (-0.9,), (1.0,),
                (-0.5, -0.2, 0.0, 0.2, 0.5), (), _input_gain(i), input=i, input_name=name,
                explain=_explain_input_gain(i, in_names),
            )
        )  # fmt: skip
    for ch, out in enumerate(outputs):
        for t_c in channel_time_constants(nominal, ch, min_s=1.0):
            for src, src_name in enumerate(outputs):
                if src == ch:
                    continue
                specs.append(
                    EffectSpec(
                        EffectKind.COUPLING,
                        ch,
                        src,
                        EffectKind.COUPLING.record.parameters,
                        (-50.0, -50.0),
                        (50.0, 50.0),
                        (0.0,),
                        (0.0,),
                        _coupling(src, ch, f"coupling_{src_name}_to_{out}", t_c),
                        fixed={"time_constant_s": t_c},
                    )
                )
    specs_mode, skipped_mode = mode_specs(nominal, band_hz, nominal.dt_s)
    specs += specs_mode
    skipped += skipped_mode
    if nominal.dt_s is not None:
        skipped += _discrete_skips()
        return specs, skipped
    names = list(nominal.states)
    thermal = next((n for n in THERMAL_STATES if n in names), None)
    if "height" not in names or thermal is None:
        why = (
            f"not applicable: the model's nominal has no {ModelNeed.TANK_STATES} "
            "(the mass and energy balances a {} changes); add `states:` to the nominal `ss`"
        )
        skipped += [
            (str(k), why.format(k.record.text))
            for k in EFFECT_KINDS
            if ModelNeed.TANK_STATES in k.record.needs
        ]
        return specs, skipped
    ih, it = names.index("height"), names.index(thermal)
    base = max(abs(nominal.a[ih, ih]), abs(nominal.a[it, it]), 1e-6)
    rates = tuple(float(x) for x in np.geomspace(base * 1e-2, base * 10.0, 16))
    h_ch = outputs.index("height") if "height" in outputs else 0
    specs.append(
        EffectSpec(
            EffectKind.LEAK, h_ch, None, EffectKind.LEAK.record.parameters, (0.0,),
            (20.0 * base,), rates, (),
            _state_rate([(ih, ih, -1.0), (it, it, -1.0)]),
        )
    )  # fmt: skip
    specs_hot, why_hot = _hot_supply_spec(nominal, outputs, in_names, operating_point, ih, it)
    specs += specs_hot
    skipped += [(EffectKind.HOT_SUPPLY.value, why_hot)] if why_hot else []
    heat_rows = [(it, it, -1.0)]
    if thermal == "energy":
        t0 = operating_point.get("temperature")
        if t0 is None:
            why_heat = "not applicable: the model has no operating temperature"
            skipped.append((EffectKind.HEAT_LOSS.value, why_heat))
            return specs, skipped
        heat_rows.append((it, ih, float(t0)))
    t_ch = outputs.index("temperature") if "temperature" in outputs else ih
    specs.append(
        EffectSpec(
            EffectKind.HEAT_LOSS, t_ch, None, EffectKind.HEAT_LOSS.record.parameters, (0.0,),
            (20.0 * base,), rates, (),
            _state_rate(heat_rows),
        )
    )  # fmt: skip
    return specs, skipped


def _discrete_skips() -> list[tuple[str, str]]:
    """The effects on named continuous states, each with why a discrete nominal has none."""
    why = (
        "not applicable: the nominal is discrete-time; a {} acts on the rates of named "
        "continuous states (the mass and energy balances), which a discrete nominal's "
        "matrices (exp(A Ts)) do not keep apart; give the nominal in continuous time with "
        "`states:`"
    )
    return [
        (str(k), why.format(k.record.text))
        for k in EFFECT_KINDS
        if ModelNeed.TANK_STATES in k.record.needs
    ]


def _hot_supply_spec(  # noqa: PLR0917 - the catalogue's context
    nominal: Nominal,
    outputs: Sequence[str],
    inputs: Sequence[str],
    operating_point: Mapping[str, float],
    ih: int,
    it: int,
) -> tuple[list[EffectSpec], str]:
    """The hot-supply change of a model with height and thermal states, or why it does not apply."""
    if "hot" not in inputs:
        return [], "not applicable: the model has no input named 'hot'"
    hot = list(inputs).index("hot")
    factor = 1.0
    if nominal.states[it] == "temperature":
        h0 = operating_point.get("height")
        if h0 is None or h0 <= 0:
            return [], "not applicable: a temperature state needs the model's operating height"
        factor = 1.0 / float(h0)
    lags = input_lag_states(nominal, hot)
    t_ch = outputs.index("temperature") if "temperature" in outputs else it
    h_ch = outputs.index("height") if "height" in outputs else 0
    spec = EffectSpec(
        EffectKind.HOT_SUPPLY, t_ch, None, EffectKind.HOT_SUPPLY.record.parameters, (-1.0,), (1.0,),
        (-0.3, -0.1, 0.0, 0.1, 0.3), (), _hot_supply(it, ih, hot, lags, factor),
        input=hot, input_name="hot", explain=_explain_hot_supply(hot, t_ch, h_ch),
    )  # fmt: skip
    return [spec], ""


# --------------------------------------------------------------------------- resonant modes

MODE_MAX_DAMPING = 0.3
"""A complex pole pair with a damping ratio below this is a candidate for a mode shift."""

MODE_MAX_RATIO = 1.5
"""A mode's frequency is searched within this factor of the nominal's (and never past the
geometric mean with a neighbouring mode's, so that two modes cannot trade places)."""

_MODE_STEPS = (-0.2, -0.12, -0.08, -0.05, -0.03, -0.015, 0.0, 0.015, 0.03, 0.05, 0.08, 0.12, 0.2)
"""Relative frequency changes scanned before the local fit (a lightly damped resonance is
a narrow dip of the cost: steps of a few per cent, finer than its half-power width)."""


@dataclass(frozen=True)
class Mode:
    """One complex pole pair of a nominal.

    Attributes:
        index: its number, 1 for the lowest natural frequency (among all complex pairs).
        f_hz: natural (undamped) frequency ``|s| / (2 pi)``, Hz.
        zeta: damping ratio ``-Re(s) / |s|``.
        pole: the pole with positive imaginary part in the nominal's own domain: ``s``
            (rad/s) for a continuous nominal, ``z = exp(s T)`` for a discrete one.
    """

    index: int
    f_hz: float
    zeta: float
    pole: complex


def z_from_s(s: complex, ts_s: float) -> complex:
    """The discrete pole of a continuous one sampled every ``ts_s`` s: ``z = exp(s T)``."""
    return complex(np.exp(s * ts_s))


def s_from_z(z: complex, ts_s: float) -> complex:
    """The continuous pole of a discrete one (principal branch): ``s = log(z) / T``, rad/s."""
    return complex(np.log(complex(z)) / ts_s)


def mode_of_pole(s: complex) -> tuple[float, float]:
    """``(f_hz, zeta)`` of a continuous pole ``s`` (rad/s): ``|s| / (2 pi)``, ``-Re(s) / |s|``."""
    w = abs(s)
    return w / (2.0 * np.pi), (-s.real / w if w > 0 else 1.0)


def mode_coefficients(f_hz: float, zeta: float, ts_s: float | None = None) -> tuple[float, float]:
    """``(a0, a1)`` of the pair's characteristic polynomial ``x^2 + a1 x + a0``.

    ``s = w (-zeta + j sqrt(1 - zeta^2))`` with ``w = 2 pi f_hz`` (``0 <= zeta < 1``); in
    continuous time ``x = s``: ``(w^2, 2 zeta w)``; for a discrete nominal (``ts_s`` given)
    the pole maps through ``z = exp(s T)``: ``(|z|^2, -2 Re z)``.
    """
    w = 2.0 * np.pi * f_hz
    s = complex(-zeta * w, w * np.sqrt(max(1.0 - zeta * zeta, 0.0)))
    x = s if ts_s is None else z_from_s(s, ts_s)
    return abs(x) ** 2, -2.0 * x.real


def modes(a: np.ndarray, ts_s: float | None = None) -> list[Mode]:
    """The complex pole pairs of ``a`` (n, n), by natural frequency (``ts_s``: a discrete ``a``)."""
    lam = np.linalg.eigvals(a)
    tol = 1e-9 * max(float(np.max(np.abs(lam), initial=0.0)), 1.0)
    up = [complex(x) for x in lam if x.imag > tol]
    cont = [x if ts_s is None else s_from_z(x, ts_s) for x in up]
    order = sorted(range(len(up)), key=lambda i: abs(cont[i]))
    return [Mode(k + 1, *mode_of_pole(cont[i]), up[i]) for k, i in enumerate(order)]


def modal_coordinates(
    a: np.ndarray, b: np.ndarray, pole: complex
) -> tuple[np.ndarray, np.ndarray, complex]:
    """The real companion coordinates of the pole pair of ``a`` nearest ``pole``.

    With ``v``, ``w`` the right and left eigenvectors of the pole (``w v = 1``), the real
    basis ``V = [Re v, Im v]`` (n, 2) and ``W = [2 Re w; -2 Im w]`` (2, n) span the pair's
    invariant subspace (``W V = I``, ``V W`` the projector onto it along the other modes).
    In it the mode is ``zeta' = A0 zeta + B0 u`` with ``A0 = W A V``, ``B0 = W B``. The
    coordinate ``eta = p^T zeta`` with ``p`` the direction least driven by the inputs (the
    left singular vector of ``B0`` of its smallest singular value: ``p^T B0 = 0`` for one
    input) and its rate ``eta' = p^T A0 zeta`` are the companion coordinates: the mode's
    block is ``[[0, 1], [-a0, -a1]]`` and the inputs drive the rate alone, as forces drive
    a modal coordinate's acceleration in a structure.

    Args:
        a: (n, n) the state matrix.
        b: (n, nu) the input matrix.
        pole: the pole sought (the one with positive imaginary part).

    Returns:
        ``(P, Q, lam)``: P (n, 2), Q (2, n) real with ``Q P = I``, ``A P = P Ac``,
        ``Q A = Ac Q`` (``Ac`` the companion block), and the pole found.
    """
    lam, vec = np.linalg.eig(a)
    i = int(np.argmin(np.abs(lam - pole)))
    v, w = vec[:, i], np.linalg.inv(vec)[i]
    basis = np.column_stack([v.real, v.imag])
    coords = np.vstack([2.0 * w.real, -2.0 * w.imag])
    a0, b0 = coords @ a @ basis, coords @ b
    p = np.linalg.svd(b0)[0][:, -1]
    s_inv = np.vstack([p, p @ a0])
    return basis @ np.linalg.inv(s_inv), s_inv @ coords, complex(lam[i])


def shift_mode(
    a: np.ndarray, b: np.ndarray, pole: complex, a0_new: float, a1_new: float
) -> np.ndarray:
    """``a`` with the pole pair nearest ``pole`` moved to the roots of ``x^2 + a1 x + a0``.

    The mode's companion block (:func:`modal_coordinates`) takes the new coefficients; the
    input and output maps of its coordinates (the mode shape) and every other mode stay:
    ``A' = A - P[:, 1] (da0 Q[0] + da1 Q[1])``. Its contribution to the response,
    ``C P [1; s] (Q B)_2 / (s^2 + a1 s + a0)``, keeps its numerator: a stiffer spring
    raises ``a0 = w^2`` and the mode's static gain falls as ``1 / w^2``, as a structure's
    does when the mode shape is unchanged (a residue kept instead would leave the
    resonance peak's height unchanged and raise the static gain with w). Shape (n, n).
    """
    p_, q_, lam = modal_coordinates(a, b, pole)
    a0, a1 = abs(lam) ** 2, -2.0 * lam.real
    return np.asarray(a - np.outer(p_[:, 1], (a0_new - a0) * q_[0] + (a1_new - a1) * q_[1]))


def _mode(pole: complex, ts_s: float | None) -> Callable[[Nominal, np.ndarray], Nominal]:
    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        a0, a1 = mode_coefficients(float(p[0]), float(p[1]), ts_s)
        return replace(nom, a=shift_mode(nom.a, nom.b, pole, a0, a1))

    return apply


def _mode_channel(nom: Nominal, mode: Mode, ts_s: float | None) -> tuple[int, float]:
    """The output the mode shows on most, and how much it is driven and seen at all.

    Most: the largest share of the mode in the output's response at the mode's own
    frequency; at all: ``|C P| |Q B|`` over ``|C| |B|``.
    """
    p_, q_, _ = modal_coordinates(nom.a, nom.b, mode.pole)
    w = 2.0 * np.pi * mode.f_hz
    x = 1j * w if ts_s is None else np.exp(1j * w * ts_s)
    n = nom.a.shape[0]
    full = nom.c @ np.linalg.solve(x * np.eye(n) - nom.a, nom.b) + nom.d
    ac = q_ @ nom.a @ p_
    part = nom.c @ p_ @ np.linalg.solve(x * np.eye(2) - ac, q_ @ nom.b)
    share = np.linalg.norm(part, axis=1) / np.maximum(np.linalg.norm(full - part, axis=1), 1e-300)
    seen = float(np.linalg.norm(nom.c @ p_) * np.linalg.norm(q_ @ nom.b))
    scale = max(float(np.linalg.norm(nom.c) * np.linalg.norm(nom.b)), 1e-300)
    return int(np.argmax(share)), seen / scale


def _mode_bounds(found: Sequence[Mode], k: int, ts_s: float | None) -> tuple[float, float]:
    """The search bounds of mode ``k``'s new frequency, Hz (:data:`MODE_MAX_RATIO`)."""
    f = found[k].f_hz
    lo, hi = f / MODE_MAX_RATIO, f * MODE_MAX_RATIO
    if k > 0:
        lo = max(lo, float(np.sqrt(found[k - 1].f_hz * f)))
    if k + 1 < len(found):
        hi = min(hi, float(np.sqrt(found[k + 1].f_hz * f)))
    if ts_s is not None:
        hi = min(hi, 0.5 / ts_s * (1.0 - 1e-6))
    return lo, hi


def _mode_not_applicable(
    m: Mode, band_hz: tuple[float, float] | None, seen: float, lo: float, hi: float
) -> str:
    """Why a pole pair is no candidate (``""``: it is one)."""
    if m.zeta >= MODE_MAX_DAMPING:
        return f"is not lightly damped (below {MODE_MAX_DAMPING:g})"
    if band_hz is not None and not band_hz[0] <= m.f_hz <= band_hz[1]:
        return f"lies outside the excited band {band_hz[0]:.4g}-{band_hz[1]:.4g} Hz"
    if seen < 1e-9:
        return "is not driven by the inputs or not seen on the outputs"
    if not (lo < m.f_hz * (1.0 - 1e-6) and m.f_hz * (1.0 + 1e-6) < hi):
        return "coincides with another pair (a repeated frequency): which moved is not defined"
    return ""


def mode_specs(
    nominal: Nominal,
    band_hz: tuple[float, float] | None = None,
    ts_s: float | None = None,
) -> tuple[list[EffectSpec], list[tuple[str, str]]]:
    """A mode shift per lightly damped pole pair of the nominal in the band, and the others.

    Each pair with a damping ratio below :data:`MODE_MAX_DAMPING`, a natural frequency
    inside ``band_hz`` (the excited band; ``None``: any) and some input driving it and
    some output seeing it is a candidate: parameters its new natural frequency (Hz) and
    damping ratio, fixed its number and nominal values. A nominal without a complex pair
    has nothing to shift (no entry); a pair that does not qualify is listed with why.

    Args:
        nominal: the nominal plant.
        band_hz: ``(lowest, highest)`` excited frequency, Hz.
        ts_s: the sample period of a discrete nominal (poles map through ``z = exp(s T)``);
            ``None`` for a continuous one.
    """
    specs: list[EffectSpec] = []
    skipped: list[tuple[str, str]] = []
    found = modes(nominal.a, ts_s)
    kind = EffectKind.MODE
    for k, m in enumerate(found):
        lo, hi = _mode_bounds(found, k, ts_s)
        channel, seen = _mode_channel(nominal, m, ts_s)
        why = _mode_not_applicable(m, band_hz, seen, lo, hi)
        if why:
            what = f"mode {m.index} at {m.f_hz:.4g} Hz (damping {m.zeta:.3g})"
            skipped.append((kind.value, f"not applicable: {what} {why}"))
            continue
        grid = tuple(sorted({float(np.clip(m.f_hz * (1.0 + r), lo, hi)) for r in _MODE_STEPS}))
        specs.append(
            EffectSpec(
                kind, channel, None, kind.record.parameters, (lo, 1e-4), (hi, 0.9), grid,
                (m.zeta,), _mode(m.pole, ts_s),
                fixed={"mode": float(m.index), "nominal_frequency_hz": m.f_hz,
                       "nominal_damping_ratio": m.zeta},
            )
        )  # fmt: skip
    return specs, skipped


def mode_shift_text(
    spec: EffectSpec,
    values: np.ndarray,
    low: np.ndarray | None = None,
    high: np.ndarray | None = None,
) -> str:
    """``mode 1 at 1.655 Hz moved to 1.75807 Hz (1.75798-1.75817) (+6.2%), damping ...``.

    ``low``, ``high``: the parameters' confidence interval (omitted when ``None``); each
    value is printed with the digits that tell its interval's ends apart.
    """
    f0 = spec.fixed["nominal_frequency_hz"]
    z0 = spec.fixed["nominal_damping_ratio"]

    def show(i: int, unit: str = "") -> str:
        v = float(values[i])
        if low is None or high is None:
            return f"{v:.4g}{unit}"
        width = float(high[i] - low[i])
        rel = width / abs(v) if v and np.isfinite(width) and width > 0 else 1.0
        digits = min(max(4, int(np.ceil(-np.log10(rel))) + 2), 12)
        return f"{v:.{digits}g}{unit} ({low[i]:.{digits}g}-{high[i]:.{digits}g})"

    return (
        f"mode {int(spec.fixed['mode'])} at {f0:.4g} Hz moved to {show(0, ' Hz')} "
        f"({values[0] / f0 - 1.0:+.1%}), damping {z0:.3g} -> {show(1)}"
    )
