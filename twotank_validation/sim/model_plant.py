"""Simulate any LFT model: its nominal plant, a member of its perturbation set, its noise, faults.

The two-tank rig (:mod:`twotank_validation.sim.rig`) is one plant; a user's plant is given as
an :class:`~twotank_validation.core.model.LFTModel` of any shape and channel names. This module
simulates such a model directly, the way the validator reads it:

* Every continuous part (nominal, each weight, a generalised P) is discretised by zero-order
  hold at ``ts_s`` on its own (:func:`twotank_validation.core.lti.discretise`), exactly as
  :meth:`LFTModel.response` does, and the parts are assembled into one discrete state space
  of the generalised plant ``P: [v; w; u] -> [z; y]`` (:func:`discrete_plant`). Transport
  delays of the model (``output_delays_s``) must be whole samples of ``ts_s``; they become
  shift-register states.
* The loop ``v = Δ z`` is closed with one member Δ of the perturbation set
  (:class:`Member`, :func:`delta_system`, :func:`close_loop`): ``nominal`` (Δ = 0),
  ``gains`` (a real scalar gain δ_i, |δ_i| <= 1, on each block: Δ_i = δ_i I) or ``random``
  (a random stable Δ_i(z) with ``||Δ_i||∞ = scale <= 1``, see :func:`delta_system`). The
  closed loop ``[w; u] -> y`` is LTI.
* The unknown input w is white Gaussian noise of unit norm in the validator's (power)
  sense, i.e. ``E[sum_i w_i(k)^2] = 1``: each of the nw channels has variance ``1 / nw``,
  all times ``noise_scale`` (default 1: the noise the model's weights admit, at its edge),
  entering through the noise weights as the model says.
* The excitation (:class:`ModelExcitation`) is one periodic signal per input: a random-phase
  multisine or circularly filtered noise of :mod:`twotank_validation.sim.excitation`, with an
  RMS and an operating-point offset per input.
* Faults (:class:`ModelFault`) name the model's channels: ``input_gain``, ``stuck_input``,
  ``sensor_bias``, ``output_delay`` (text form in :func:`parse_model_fault`).

Units and time: signals in model units, times in seconds, stamps in integer nanoseconds
``k ts_ns``. The model is linear about its operating point: the plant is at rest there for
all times before 0 (state 0, inputs at their offsets, outputs at the model's
``operating_point``, 0 for an output it does not name), and the excitation starts at
sample 0. The record is therefore periodic only once the transient has died out: the first
``settle_periods`` periods settle it (by default as many as the closed loop's slowest mode
needs to decay by :data:`SETTLE_TOL`), the last ``periods`` periods are the ones to validate
(:attr:`ModelSimResult.record_slice`). The whole run, settling included, is returned.

Sample k: the command ``u(k)`` (what is recorded) is computed, the faults turn it into the
input the plant gets, and ``y(k) = C x(k) + D [w(k); u_applied(k) - offset] + y_op`` is
measured (with direct feed-through when the model has it) before the state advances.
:class:`ModelPlant` steps one sample at a time (the ROS node); :func:`simulate_model` runs
the same steps for the whole record, so both are equal bit for bit.
"""

from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Final, NamedTuple

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from twotank_validation.core import lti
from twotank_validation.core.lti import StateSpace
from twotank_validation.core.model import LFTModel
from twotank_validation.defaults import NS_PER_S, PERIOD_SAMPLES, TS_S
from twotank_validation.errors import DatumError, ModelError, UnstableModelError
from twotank_validation.sim import excitation

__all__ = [
    "MAX_DELAY_SAMPLES",
    "MEMBER_KINDS",
    "MODEL_FAULT_KINDS",
    "SETTLE_TOL",
    "Member",
    "ModelExcitation",
    "ModelFault",
    "ModelPlant",
    "ModelSimConfig",
    "ModelSimError",
    "ModelSimResult",
    "PlantSample",
    "close_loop",
    "closed_loop_system",
    "delta_system",
    "discrete_plant",
    "format_member",
    "format_model_fault",
    "parse_member",
    "parse_model_fault",
    "settling_periods",
    "simulate_model",
    "undelay",
]

FloatArray = NDArray[np.float64]

MEMBER_KINDS: Final = ("nominal", "gains", "random")
"""Members of the perturbation set :class:`Member` offers."""

MODEL_FAULT_KINDS: Final = ("input_gain", "stuck_input", "sensor_bias", "output_delay")
"""Faults of :class:`ModelFault`: two on inputs, two on outputs."""

_INPUT_FAULTS: Final = ("input_gain", "stuck_input")

SETTLE_TOL: Final = 1e-9
"""Automatic settling: periods until ``||A_cl^(k)||_2`` of the closed loop is below this."""

MAX_SETTLE_PERIODS: Final = 1000
"""Automatic settling refuses a closed loop that needs more periods than this."""

MAX_DELAY_SAMPLES: Final = 1_000_000
"""Largest ``output_delay`` fault, in samples of ``ts_s``."""

_ONSET_SLACK: Final = 1e-9
"""A fault starts at the first sample k with ``k ts_s >= onset_s`` to this many samples."""


class ModelSimError(ModelError):
    """A model simulation is set up wrongly (the message names the setting and the fix)."""


# --------------------------------------------------------------------------- checks


def _real(where: str, value: object, *, lo: float | None = None, lo_open: bool = False) -> float:
    """A finite real (>= lo, or > lo with lo_open); ModelSimError naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ModelSimError(f"{where}={value!r} is not a number")
    x = float(value)
    if not math.isfinite(x):
        raise ModelSimError(f"{where}={value!r} must be finite (not NaN or inf)")
    if lo is not None and (x <= lo if lo_open else x < lo):
        raise ModelSimError(f"{where}={value!r} must be {'>' if lo_open else '>='} {lo:g}")
    return x


def _integer(where: str, value: object, *, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < lo:
        raise ModelSimError(f"{where}={value!r} must be an integer >= {lo}")
    return int(value)


def _per_channel(
    where: str, value: object, names: Sequence[str], default: float, *, lo: float | None = None
) -> tuple[float, ...]:
    """One finite number per channel from a number, a sequence or a mapping by name."""
    if isinstance(value, Mapping):
        unknown = sorted(str(k) for k in value if k not in names)
        if unknown:
            raise ModelSimError(
                f"{where}: unknown channel(s) {unknown}; the model's channels are {list(names)}"
            )
        return tuple(_real(f"{where}[{n!r}]", value.get(n, default), lo=lo) for n in names)
    if isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool):
        x = _real(where, value, lo=lo)
        return (x,) * len(names)
    if isinstance(value, str) or not isinstance(value, Sequence | np.ndarray):
        raise ModelSimError(
            f"{where}={value!r}: give a number, one number per channel {list(names)}, or a "
            "mapping of channel name to number"
        )
    items = list(value)
    if len(items) != len(names):
        raise ModelSimError(
            f"{where}={items!r} has {len(items)} entries but the model has {len(names)} "
            f"channels {list(names)}: give one per channel (or one number for all)"
        )
    return tuple(_real(f"{where}[{i}]", v, lo=lo) for i, v in enumerate(items))


# --------------------------------------------------------------------------- excitation


@dataclass(frozen=True, kw_only=True)
class ModelExcitation:
    """The periodic excitation: one signal per model input around an operating point.

    Each input gets its own realisation of the same design, drawn one input after the other
    from ``numpy.random.default_rng(seed)`` (as :func:`excitation.excitation_period` does for
    the two valves), scaled to its RMS and added to its offset.

    Attributes:
        kind: ``"multisine"`` (random-phase, flat spectrum, :func:`excitation.multisine_period`)
            or ``"filtered_noise"`` (:func:`excitation.filtered_noise_period`).
        period_samples: Samples per period, an integer >= 4.
        rms: RMS of each input's deviation (model units, >= 0): one number for all inputs,
            one per input (order of ``model.input_names``) or a mapping name -> RMS (inputs
            left out: 0.1). Resolved to one per input by :class:`ModelSimConfig`.
        offset: Operating point of each input (model units), same forms (default 0).
        f_min_hz: Multisine: lowest frequency, Hz; None: the period's first harmonic
            ``1 / (period_samples ts_s)``.
        f_max_hz: Multisine: highest frequency, Hz, below Nyquist; None: ``0.2 / ts_s``
            (40 % of Nyquist).
        odd_only: Multisine: odd harmonics only.
        cutoff_hz: Filtered noise: Butterworth -3 dB frequency, Hz; None: ``0.2 / ts_s``.
        order: Filtered noise: Butterworth order, >= 1.
        seed: Seed of the random phases or noise, >= 0.
    """

    kind: str = "multisine"
    period_samples: int = PERIOD_SAMPLES
    rms: float | Sequence[float] | Mapping[str, float] = 0.1
    offset: float | Sequence[float] | Mapping[str, float] = 0.0
    f_min_hz: float | None = None
    f_max_hz: float | None = None
    odd_only: bool = False
    cutoff_hz: float | None = None
    order: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        if self.kind not in excitation.EXCITATION_KINDS:
            raise ModelSimError(
                f"excitation kind={self.kind!r} is unknown; use one of "
                f"{excitation.EXCITATION_KINDS}"
            )
        if (
            isinstance(self.period_samples, bool)
            or not isinstance(self.period_samples, int | np.integer)
            or self.period_samples < 4
        ):
            raise ModelSimError(
                f"excitation period_samples={self.period_samples!r} must be a whole number of "
                "samples >= 4 (an integer, e.g. 2048)"
            )
        object.__setattr__(self, "period_samples", int(self.period_samples))
        for key in ("f_min_hz", "f_max_hz", "cutoff_hz"):
            if getattr(self, key) is not None:
                object.__setattr__(
                    self, key, _real(f"excitation {key}", getattr(self, key), lo=0.0, lo_open=True)
                )
        object.__setattr__(self, "order", _integer("excitation order", self.order, lo=1))
        object.__setattr__(self, "seed", _integer("excitation seed", self.seed, lo=0))
        if not isinstance(self.odd_only, bool):
            raise ModelSimError(f"excitation odd_only={self.odd_only!r} must be true or false")

    def band(self, ts_s: float) -> tuple[float, float, float]:
        """``(f_min_hz, f_max_hz, cutoff_hz)`` with the defaults for sample period ``ts_s``."""
        f_min = 1.0 / (self.period_samples * ts_s) if self.f_min_hz is None else self.f_min_hz
        f_max = 0.2 / ts_s if self.f_max_hz is None else self.f_max_hz
        cutoff = 0.2 / ts_s if self.cutoff_hz is None else self.cutoff_hz
        return f_min, f_max, cutoff

    def deviations(self, ts_s: float, rms: Sequence[float]) -> FloatArray:
        """One period of the zero-mean deviations, one column per input.

        Args:
            ts_s: Sample period, s.
            rms: (nu,) RMS per input, model units.

        Returns:
            (period_samples, nu) float, column i of RMS ``rms[i]``.

        Raises:
            ModelSimError: An empty or invalid band (the message names the fix).
        """
        f_min, f_max, cutoff = self.band(ts_s)
        rng = np.random.default_rng(self.seed)
        cols = []
        try:
            for r in rms:
                if self.kind == "multisine":
                    x = excitation.multisine_period(
                        self.period_samples, ts_s, f_min, f_max, self.odd_only, rng
                    )
                else:
                    x = excitation.filtered_noise_period(
                        self.period_samples, ts_s, cutoff, self.order, rng
                    )
                cols.append(r * x)
        except DatumError as err:
            raise ModelSimError(f"excitation: {err}") from err
        return np.column_stack(cols) if cols else np.zeros((self.period_samples, 0))


# --------------------------------------------------------------------------- members


@dataclass(frozen=True, kw_only=True)
class Member:
    """Which member Δ of the model's perturbation set the simulated plant is.

    Text form (:func:`parse_member`): ``nominal``, ``gains=G`` or ``gains=G1,G2,...`` (one
    per block), ``random`` with optional ``,seed=S`` and ``,scale=R``.

    Attributes:
        kind: ``"nominal"`` (Δ = 0: the nominal plant), ``"gains"`` (block i is the real
            gain ``gains[i]`` times the identity, ``Δ_i = δ_i I`` of the block's shape;
            a non-square block takes the rectangular identity), or ``"random"`` (each block a
            random stable discrete system, see :func:`delta_system`).
        gains: ``gains``: one δ_i per block, each in [-1, 1] (one value: the same for all).
        seed: ``random``: seed of the draw, >= 0.
        scale: ``random``: ``||Δ_i||∞`` of every block, in (0, 1].
    """

    kind: str = "nominal"
    gains: tuple[float, ...] = ()
    seed: int = 0
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in MEMBER_KINDS:
            raise ModelSimError(f"member kind={self.kind!r} is unknown; use one of {MEMBER_KINDS}")
        gains = tuple(self.gains) if isinstance(self.gains, Sequence) else (self.gains,)
        values = tuple(_real(f"member gains[{i}]", g) for i, g in enumerate(gains))
        if any(abs(g) > 1.0 for g in values):
            raise ModelSimError(
                f"member gains {list(values)} must lie in [-1, 1]: the model's set holds "
                "||Δ_i|| <= 1 only"
            )
        if self.kind == "gains" and not values:
            raise ModelSimError("member 'gains' needs at least one gain, e.g. gains=0.5")
        if self.kind != "gains" and values:
            raise ModelSimError(f"member {self.kind!r} takes no gains; use kind='gains'")
        object.__setattr__(self, "gains", values)
        object.__setattr__(self, "seed", _integer("member seed", self.seed, lo=0))
        scale = _real("member scale", self.scale, lo=0.0, lo_open=True)
        if scale > 1.0:
            raise ModelSimError(f"member scale={scale!r} must be <= 1 (||Δ||∞ <= 1)")
        object.__setattr__(self, "scale", scale)

    def block_gains(self, n_blocks: int) -> tuple[float, ...]:
        """The gain of each of ``n_blocks`` blocks (``gains`` member).

        Raises:
            ModelSimError: A count other than 1 or ``n_blocks``.
        """
        if len(self.gains) == 1:
            return self.gains * n_blocks
        if len(self.gains) != n_blocks:
            raise ModelSimError(
                f"member gains {list(self.gains)}: the model has {n_blocks} perturbation "
                "block(s); give one gain per block or one for all"
            )
        return self.gains


def parse_member(text: str) -> Member:
    """``"nominal"``, ``"gains=0.5,-1"``, ``"random"``, ``"random,seed=3,scale=0.8"`` -> Member.

    Raises:
        ModelSimError: Text of another form (the message shows the forms).
    """
    usage = (
        f"member {text!r}: write nominal, gains=G[,G...] (one per block, each in [-1, 1]) or "
        "random[,seed=S][,scale=R]"
    )
    if not isinstance(text, str):
        raise ModelSimError(usage)
    body = text.strip()
    if body == "nominal":
        return Member()
    try:
        if body.startswith("gains="):
            return Member(kind="gains", gains=tuple(float(g) for g in body[6:].split(",")))
        head, *options = body.split(",")
        if head != "random":
            raise ModelSimError(usage)
        kwargs: dict[str, float | int] = {}
        for opt in options:
            key, sep, value = opt.partition("=")
            if not sep or key.strip() not in ("seed", "scale") or key.strip() in kwargs:
                raise ModelSimError(usage)
            kwargs[key.strip()] = int(value) if key.strip() == "seed" else float(value)
        return Member(
            kind="random", seed=int(kwargs.get("seed", 0)), scale=float(kwargs.get("scale", 1.0))
        )
    except ValueError as err:
        raise ModelSimError(f"{usage} ({err})") from err


def format_member(member: Member) -> str:
    """Inverse of :func:`parse_member`."""
    if member.kind == "gains":
        return "gains=" + ",".join(_num(g) for g in member.gains)
    if member.kind == "random":
        return f"random,seed={member.seed},scale={_num(member.scale)}"
    return "nominal"


# --------------------------------------------------------------------------- faults


@dataclass(frozen=True)
class ModelFault:
    """A fault of the simulated plant on one named channel, active from ``onset_s`` to ``end_s``.

    A fault takes effect at the first sample k with ``k ts_s >= onset_s`` and is removed at
    the first sample with ``k ts_s >= end_s`` (to 1e-9 sample). The recorded inputs are the
    commands; input faults change what the plant gets, output faults what is measured.

    * ``input_gain``: the plant gets ``magnitude`` times the commanded input (its absolute
      value in model units, as a weak actuator delivers a fraction of its command; with a
      non-zero offset the input's mean moves too). Any finite factor.
    * ``stuck_input``: the input the plant gets holds the value it had at the sample before
      the onset (the offset if the onset is at 0); ``magnitude`` is unused.
    * ``sensor_bias``: ``magnitude`` (model units) is added to the measured output.
    * ``output_delay``: the measured output is the fault-free measured output ``magnitude``
      seconds earlier (0 <= magnitude <= :data:`MAX_DELAY_SAMPLES` samples), linearly
      interpolated between samples; before time 0 the output rests at its operating point.

    Faults combine: gains of one input multiply, a stuck input overrides its gain; biases and
    delays of one output add, the delay acting first (a bias is not delayed).

    Attributes:
        kind: One of :data:`MODEL_FAULT_KINDS`.
        channel: The model's input (input faults) or output (output faults) name.
        magnitude: Factor, bias (model units) or delay (s), see above.
        onset_s: Time it takes effect, s, finite, >= 0.
        end_s: Time it is removed, s, > onset_s; default never.
    """

    kind: str
    channel: str
    magnitude: float = 0.0
    onset_s: float = 0.0
    end_s: float = math.inf

    def __post_init__(self) -> None:
        if self.kind not in MODEL_FAULT_KINDS:
            raise ModelSimError(
                f"fault kind {self.kind!r} is unknown; use one of {MODEL_FAULT_KINDS}"
            )
        where = f"fault {self.kind}"
        if not isinstance(self.channel, str) or not self.channel:
            raise ModelSimError(f"{where}: channel={self.channel!r} must name a model channel")
        object.__setattr__(self, "magnitude", _real(f"{where} magnitude", self.magnitude))
        object.__setattr__(self, "onset_s", _real(f"{where} onset_s", self.onset_s, lo=0.0))
        end = self.end_s
        if isinstance(end, bool) or not isinstance(end, int | float) or math.isnan(end):
            raise ModelSimError(f"{where}: end_s={end!r} must be a time in s or inf")
        if end <= self.onset_s:
            raise ModelSimError(
                f"{where}: end_s={end!r} must be later than onset_s={self.onset_s!r}"
            )
        object.__setattr__(self, "end_s", float(end))
        if self.kind == "output_delay" and self.magnitude < 0.0:
            raise ModelSimError(f"{where}: the delay {self.magnitude!r} s must be >= 0")

    @property
    def on_input(self) -> bool:
        """The fault acts on an input (else on an output)."""
        return self.kind in _INPUT_FAULTS


_FAULT_TEXT: Final = re.compile(
    r"^\s*(?P<kind>[a-z_]+):(?P<channel>[^=@:\s]+)(?:=(?P<mag>[^@\s]+))?"
    r"@(?P<onset>[^-\s]+)(?:-(?P<end>\S+))?\s*$"
)
FAULT_TEXT_FORM: Final = "KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S]"
"""The grammar of :func:`parse_model_fault`."""


def parse_model_fault(spec: str) -> ModelFault:
    """Parse ``KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S]``.

    Examples: ``input_gain:u1=0.5@300``, ``stuck_input:u1@300``, ``sensor_bias:y2=0.1@300``,
    ``output_delay:y1=2.5@300``, ``input_gain:u2=0.8@100-400``. ``MAGNITUDE`` is a factor,
    a bias (model units) or a delay (s); ``stuck_input`` takes none. Times in s.

    Raises:
        ModelSimError: Malformed text or an invalid fault (the message shows the form).
    """
    m = _FAULT_TEXT.match(spec) if isinstance(spec, str) else None
    if m is None:
        raise ModelSimError(
            f"fault spec {spec!r} is not {FAULT_TEXT_FORM}, e.g. 'input_gain:u1=0.5@300' or "
            f"'stuck_input:u1@300'; kinds: {', '.join(MODEL_FAULT_KINDS)}"
        )
    kind = m["kind"]
    if kind == "stuck_input" and m["mag"] is not None:
        raise ModelSimError(f"fault spec {spec!r}: stuck_input takes no magnitude")
    if kind in MODEL_FAULT_KINDS and kind != "stuck_input" and m["mag"] is None:
        raise ModelSimError(f"fault spec {spec!r}: {kind} needs =MAGNITUDE")
    try:
        return ModelFault(
            kind=kind,
            channel=m["channel"],
            magnitude=float(m["mag"]) if m["mag"] is not None else 0.0,
            onset_s=float(m["onset"]),
            end_s=float(m["end"]) if m["end"] is not None else math.inf,
        )
    except ValueError as err:  # float() of bad text; ModelSimError is a ValueError too
        if isinstance(err, ModelSimError):
            raise ModelSimError(f"fault spec {spec!r}: {err}") from err
        raise ModelSimError(f"fault spec {spec!r} is not {FAULT_TEXT_FORM}: {err}") from err


def _num(x: float) -> str:
    """Shortest text that reads back to ``x`` (``300``, not ``300.0``)."""
    text = repr(float(x))
    return text[:-2] if text.endswith(".0") else text


def format_model_fault(fault: ModelFault) -> str:
    """Inverse of :func:`parse_model_fault` (the shortest numbers that read back the same)."""
    mag = "" if fault.kind == "stuck_input" else f"={_num(fault.magnitude)}"
    end = f"-{_num(fault.end_s)}" if math.isfinite(fault.end_s) else ""
    return f"{fault.kind}:{fault.channel}{mag}@{_num(fault.onset_s)}{end}"


def _check_fault(fault: ModelFault, model: LFTModel, ts_s: float) -> None:
    names = model.input_names if fault.on_input else model.output_names
    role = "input" if fault.on_input else "output"
    if fault.channel not in names:
        other = model.output_names if fault.on_input else model.input_names
        hint = f" ({fault.channel!r} is an {'output' if fault.on_input else 'input'})" * (
            fault.channel in other
        )
        raise ModelSimError(
            f"fault {format_model_fault(fault)}: model {model.name!r} has no {role} "
            f"{fault.channel!r}{hint}; its inputs are {list(model.input_names)}, its outputs "
            f"{list(model.output_names)}"
        )
    if fault.kind == "output_delay" and fault.magnitude / ts_s > MAX_DELAY_SAMPLES:
        raise ModelSimError(
            f"fault {format_model_fault(fault)}: a delay of {fault.magnitude:g} s is more than "
            f"{MAX_DELAY_SAMPLES} samples of ts_s={ts_s:g}"
        )


# --------------------------------------------------------------------------- the configuration


@dataclass(frozen=True, kw_only=True)
class ModelSimConfig:
    """Everything a simulated run of a model needs. Validated on construction.

    Attributes:
        model: The model set (structured or generalised).
        ts_s: Sample period, s, > 0, a whole number of nanoseconds.
        excitation: The periodic excitation; its ``rms`` and ``offset`` are resolved here to
            one float per input (``model.input_names`` order).
        periods: Periods to record after settling, >= 1.
        settle_periods: Periods run first to let the transient die out; None: automatic
            (:func:`settling_periods`).
        member: The member Δ of the perturbation set.
        noise_scale: w is ``noise_scale`` times white Gaussian noise of unit mean-square norm
            (each of the nw channels of variance ``1 / nw``), >= 0 (0: no noise). The
            realised ``||w||`` of a record scatters around ``noise_scale`` by about
            ``1 / sqrt(2 N nw)`` relative (N samples).
        noise_seed: Seed of w, >= 0.
        faults: Faults (:class:`ModelFault` or their text form), each naming a channel of
            the model.
    """

    model: LFTModel
    ts_s: float = TS_S
    excitation: ModelExcitation = field(default_factory=ModelExcitation)
    periods: int = 2
    settle_periods: int | None = None
    member: Member = field(default_factory=Member)
    noise_scale: float = 1.0
    noise_seed: int = 0
    faults: tuple[ModelFault, ...] = ()

    def __post_init__(self) -> None:
        put = object.__setattr__
        if not isinstance(self.model, LFTModel):
            raise ModelSimError(
                f"model must be an LFTModel (load_model(path)), got {type(self.model).__name__}"
            )
        put(self, "ts_s", _real("ts_s", self.ts_s, lo=0.0, lo_open=True))
        ts_ns = self.ts_s * NS_PER_S
        if ts_ns < 1.0 or abs(ts_ns - round(ts_ns)) > 1e-3:
            raise ModelSimError(
                f"ts_s={self.ts_s!r} must be a whole number of nanoseconds (>= 1 ns) so that "
                "sample k is stamped exactly k ts_s"
            )
        if not isinstance(self.excitation, ModelExcitation):
            raise ModelSimError(
                f"excitation must be a ModelExcitation, got {type(self.excitation).__name__}"
            )
        names = self.model.input_names
        put(
            self,
            "excitation",
            replace(
                self.excitation,
                rms=_per_channel("excitation rms", self.excitation.rms, names, 0.1, lo=0.0),
                offset=_per_channel("excitation offset", self.excitation.offset, names, 0.0),
            ),
        )
        put(self, "periods", _integer("periods", self.periods, lo=1))
        if self.settle_periods is not None:
            put(self, "settle_periods", _integer("settle_periods", self.settle_periods, lo=0))
        if isinstance(self.member, str):
            put(self, "member", parse_member(self.member))
        if not isinstance(self.member, Member):
            raise ModelSimError(f"member must be a Member, got {self.member!r}")
        if self.member.kind == "gains":
            self.member.block_gains(self.model.blocks.n_blocks)
        put(self, "noise_scale", _real("noise_scale", self.noise_scale, lo=0.0))
        put(self, "noise_seed", _integer("noise_seed", self.noise_seed, lo=0))
        faults: object = self.faults
        if isinstance(faults, str | ModelFault) or not isinstance(faults, Sequence):
            raise ModelSimError(
                f"faults={faults!r} must be a list of faults, e.g. ['input_gain:u1=0.5@300']"
            )
        parsed = tuple(f if isinstance(f, ModelFault) else parse_model_fault(f) for f in faults)
        for f in parsed:
            _check_fault(f, self.model, self.ts_s)
        put(self, "faults", parsed)
        self.excitation.deviations(self.ts_s, self.rms)  # an empty band fails here, not later

    @property
    def ts_ns(self) -> int:
        """Sample period, integer ns; sample k is stamped ``k ts_ns``."""
        return round(self.ts_s * NS_PER_S)

    @property
    def period_samples(self) -> int:
        """Samples per excitation period."""
        return self.excitation.period_samples

    @property
    def rms(self) -> tuple[float, ...]:
        """(nu,) RMS of each input's deviation."""
        return tuple(self.excitation.rms)  # type: ignore[arg-type]

    @property
    def offset(self) -> tuple[float, ...]:
        """(nu,) operating point of each input."""
        return tuple(self.excitation.offset)  # type: ignore[arg-type]

    def output_operating_point(self) -> FloatArray:
        """(ny,) the outputs at rest: the model's ``operating_point``, 0 where it names none."""
        op = self.model.operating_point
        return np.array([float(op.get(n, 0.0)) for n in self.model.output_names])

    def command_table(self) -> FloatArray:
        """(period_samples, nu) absolute commands of one period; sample k uses row k mod N."""
        return np.asarray(self.offset) + self.excitation.deviations(self.ts_s, self.rms)


# --------------------------------------------------------------------------- state spaces


def _stack(
    parts: Sequence[tuple[StateSpace, FloatArray, FloatArray]], n_in: int, n_out: int, dt_s: float
) -> StateSpace:
    """Sum of paths ``M_out S M_in``: states stacked, ``(S, M_in, M_out)`` each."""
    a = scipy.linalg.block_diag(*[s.a for s, _, _ in parts]) if parts else np.zeros((0, 0))
    n = a.shape[0]
    b = np.zeros((n, n_in))
    c = np.zeros((n_out, n))
    d = np.zeros((n_out, n_in))
    row = 0
    for s, m_in, m_out in parts:
        k = s.n_states
        b[row : row + k] = s.b @ m_in
        c[:, row : row + k] = m_out @ s.c
        d += m_out @ s.d @ m_in
        row += k
    return StateSpace(a if n else np.zeros((0, 0)), b, c, d, dt_s)


def _series(first: StateSpace, second: StateSpace) -> StateSpace:
    """``second`` after ``first`` (discrete, delay-free)."""
    n1 = first.n_states
    a = np.block(
        [
            [first.a, np.zeros((n1, second.n_states))],
            [second.b @ first.c, second.a],
        ]
    )
    b = np.vstack([first.b, second.b @ first.d])
    c = np.hstack([second.d @ first.c, second.c])
    return StateSpace(a if a.size else np.zeros((0, 0)), b, c, second.d @ first.d, first.dt_s)


def undelay(sys: StateSpace) -> StateSpace:
    """A discrete system with its output delays turned into shift-register states.

    Output i delayed by d_i samples (``output_delays_s[i] / dt_s``) gets d_i states
    ``s_1(k+1) = [C x + D u]_i(k)``, ``s_j(k+1) = s_{j-1}(k)``, ``y_i = s_{d_i}``.

    Raises:
        ModelSimError: A delay that is not a whole number of samples (the time domain cannot
            hold the band-limited fractional delay the validator's frequency response uses).
    """
    if not sys.output_delays_s:
        return sys
    assert sys.dt_s is not None
    shifts = []
    for i, tau in enumerate(sys.output_delays_s):
        samples = tau / sys.dt_s
        if abs(samples - round(samples)) > 1e-9 * max(1.0, samples):
            raise ModelSimError(
                f"output {i} has a transport delay of {tau:g} s, not a whole number of samples "
                f"of ts_s={sys.dt_s:g}: simulate at a ts_s that divides it, or round the delay "
                "in the model file"
            )
        shifts.append(round(samples))
    n0, (p, m) = sys.n_states, sys.shape
    total = n0 + sum(shifts)
    a = np.zeros((total, total))
    b = np.zeros((total, m))
    c = np.zeros((p, total))
    d = np.zeros((p, m))
    a[:n0, :n0], b[:n0] = sys.a, sys.b
    pos = n0
    for i, k in enumerate(shifts):
        if k == 0:
            c[i, :n0], d[i] = sys.c[i], sys.d[i]
            continue
        a[pos, :n0], b[pos] = sys.c[i], sys.d[i]  # s_1(k+1) = (C x + D u)_i
        for j in range(1, k):
            a[pos + j, pos + j - 1] = 1.0
        c[i, pos + k - 1] = 1.0
        pos += k
    return StateSpace(a, b, c, d, sys.dt_s)


def _select(rows: int, cols: int, pairs: Sequence[tuple[int, int]]) -> FloatArray:
    m = np.zeros((rows, cols))
    for r, c in pairs:
        m[r, c] = 1.0
    return m


def discrete_plant(model: LFTModel, ts_s: float) -> StateSpace:
    """The generalised plant ``P: [v; w; u] -> [z; y]`` as one discrete, delay-free state space.

    Each continuous part is discretised by ZOH at ``ts_s`` on its own (as
    :meth:`LFTModel.response`), so ``P(e^{jθ})`` equals ``model.response(θ, ts_s).p`` (for
    whole-sample delays). A structured model is the sum of its paths: the nominal G on u
    (into y and into the z of output-multiplicative blocks), per block its weight on v (into
    y, through G[:, S] for an input-multiplicative block) and its selection of u or G u
    into z, per noise channel its weight on w.

    Args:
        model: The model set.
        ts_s: Sample period, s.

    Returns:
        (nz + ny, nv + nw + nu) discrete state space with sample period ``ts_s``.

    Raises:
        ModelError: A discrete part with another sample period; a fractional delay.
    """
    nz, nv, nw, nu, ny = model.blocks.nz, model.blocks.nv, model.nw, model.nu, model.ny
    n_in, n_out = nv + nw + nu, nz + ny
    if model.generalized is not None:
        return undelay(lti.discretise(model.generalized, ts_s))
    assert model.nominal is not None
    g = undelay(lti.discretise(model.nominal, ts_s))
    u_cols = [nv + nw + j for j in range(nu)]
    y_rows = [nz + i for i in range(ny)]
    # the nominal on u, into y; output-multiplicative blocks read their z from this copy of G
    y_all = _select(n_out, ny, [(y_rows[i], i) for i in range(ny)])
    u_in = _select(nu, n_in, [(j, u_cols[j]) for j in range(nu)])
    g_out = y_all.copy()
    parts: list[tuple[StateSpace, FloatArray, FloatArray]] = []
    for pert, vs, zs in zip(
        model.perturbations, model.blocks.v_slices, model.blocks.z_slices, strict=True
    ):
        w = undelay(lti.discretise(pert.weight, ts_s))
        v_in = _select(w.shape[1], n_in, [(k, vs.start + k) for k in range(w.shape[1])])
        if pert.kind == "output_multiplicative":
            for k, o in enumerate(pert.outputs):
                g_out[zs.start + k, o] = 1.0  # z_i = E_S G u, from the nominal's copy of G
            y_sel = [(y_rows[o], k) for k, o in enumerate(pert.outputs)]
            parts.append((w, v_in, _select(n_out, w.shape[0], y_sel)))
            continue
        # z_i = E_in u: a static path
        z_sel = _select(n_out, nu, [(zs.start + k, j) for k, j in enumerate(pert.inputs)])
        parts.append((lti.static_gain(np.eye(nu), ts_s), u_in, z_sel))
        if pert.kind == "input_multiplicative":  # y += G E_S^T W v
            ins = list(pert.inputs)
            g_s = StateSpace(g.a, g.b[:, ins], g.c, g.d[:, ins], ts_s)
            parts.append((_series(w, g_s), v_in, y_all))
        else:  # additive: y[S_out] += W v
            y_sel = [(y_rows[o], k) for k, o in enumerate(pert.outputs)]
            parts.append((w, v_in, _select(n_out, w.shape[0], y_sel)))
    col = nv
    for ch in model.noise:
        w = undelay(lti.discretise(ch.weight, ts_s))
        k_in = w.shape[1]
        w_in = _select(k_in, n_in, [(k, col + k) for k in range(k_in)])
        y_sel = [(y_rows[o], k) for k, o in enumerate(ch.outputs)]
        parts.append((w, w_in, _select(n_out, w.shape[0], y_sel)))
        col += k_in
    return _stack([(g, u_in, g_out), *parts], n_in, n_out, ts_s)


def _random_allpass(rng: np.random.Generator, ts_s: float) -> StateSpace:
    """A stable first-order discrete all-pass ``(z^-1 - a) / (1 - a z^-1)``, |H(e^{jθ})| = 1."""
    a = float(rng.uniform(-0.9, 0.9))
    # H(z) = (1 - a z) / (z - a) = -a + (1 - a^2) / (z - a)
    return StateSpace(
        np.array([[a]]), np.array([[1.0]]), np.array([[1.0 - a * a]]), np.array([[-a]]), ts_s
    )


def delta_system(model: LFTModel, member: Member, ts_s: float) -> StateSpace:
    """The member Δ = diag(Δ_1 .. Δ_m) as one discrete state space ``z -> v`` (nv x nz).

    * ``nominal``: 0.
    * ``gains``: ``Δ_i = δ_i I`` (rectangular identity for a non-square block), static.
    * ``random``: ``Δ_i(z) = s Q_1 diag(g_k A_k(z)) Q_2`` with ``Q_1``, ``Q_2`` random
      orthogonal matrices (QR of a Gaussian matrix; a sign for 1 x 1), ``g_k`` uniform in
      [-1, 1] divided by the largest ``|g_k|``, ``A_k`` a random stable first-order all-pass
      (pole uniform in (-0.9, 0.9)). The singular values of ``Δ_i(e^{jθ})`` are ``s |g_k|``
      at every θ, so ``||Δ_i||∞ = s = scale`` exactly (no frequency grid) and Δ_i is
      stable. Drawn from ``default_rng(member.seed)``.

    Raises:
        ModelSimError: A ``gains`` member with the wrong number of gains.
    """
    shapes = model.blocks.shapes
    parts: list[tuple[StateSpace, FloatArray, FloatArray]] = []
    nv, nz = model.blocks.nv, model.blocks.nz
    if member.kind == "nominal" or not shapes:
        return lti.static_gain(np.zeros((nv, nz)), ts_s)
    rng = np.random.default_rng(member.seed)
    gains = member.block_gains(len(shapes)) if member.kind == "gains" else ()
    for i, ((rows, cols), vs, zs) in enumerate(
        zip(shapes, model.blocks.v_slices, model.blocks.z_slices, strict=True)
    ):
        m_in = _select(cols, nz, [(k, zs.start + k) for k in range(cols)])
        m_out = _select(nv, rows, [(vs.start + k, k) for k in range(rows)])
        if member.kind == "gains":
            parts.append((lti.static_gain(gains[i] * np.eye(rows, cols), ts_s), m_in, m_out))
            continue
        r = min(rows, cols)
        q1, q2 = _orthogonal(rng, rows), _orthogonal(rng, cols)
        g = rng.uniform(-1.0, 1.0, size=r)
        g /= np.max(np.abs(g))  # the largest |g_k| is 1: ||Δ_i||∞ = scale exactly
        for k in range(r):
            ap = _random_allpass(rng, ts_s)
            col_in = q2[k : k + 1, :]  # (1, cols): the k-th row of Q_2
            col_out = member.scale * g[k] * q1[:, k : k + 1]  # (rows, 1)
            parts.append((ap, col_in @ m_in, m_out @ col_out))
    return _stack(parts, nz, nv, ts_s)


def _orthogonal(rng: np.random.Generator, n: int) -> FloatArray:
    """A random n x n orthogonal matrix (QR of a Gaussian matrix, signs fixed: Haar)."""
    q, r = np.linalg.qr(rng.standard_normal((n, n)))
    return np.asarray(q * np.sign(np.diag(r))[None, :])


def close_loop(p: StateSpace, delta: StateSpace, nz: int, nv: int) -> StateSpace:
    """The upper LFT ``F_u(P, Δ)``: ``[w; u] -> y`` with ``v = Δ z``.

    Args:
        p: ``[v; w; u] -> [z; y]``, discrete, delay-free.
        delta: ``z -> v`` (nv x nz), discrete, delay-free, same sample period.
        nz: Rows of z in P's outputs (the first ones).
        nv: Columns of v in P's inputs (the first ones).

    Returns:
        The closed loop, states ``[x_P; x_Δ]``.

    Raises:
        ModelSimError: ``I - D11 D_Δ`` singular (the loop is not well posed).
        UnstableModelError: The closed loop is unstable for this member.
    """
    a, b, c, d = p.a, p.b, p.c, p.d
    b1, b2 = b[:, :nv], b[:, nv:]
    c1, c2 = c[:nz], c[nz:]
    d11, d12, d21, d22 = d[:nz, :nv], d[:nz, nv:], d[nz:, :nv], d[nz:, nv:]
    ad, bd, cd, dd = delta.a, delta.b, delta.c, delta.d
    np_, nd = p.n_states, delta.n_states
    loop = np.eye(nz) - d11 @ dd
    if nz and np.linalg.cond(loop) > 1e12:
        raise ModelSimError(
            "the loop v = Δ z is not well posed for this member (I - P11(∞) Δ(∞) is "
            "singular): choose smaller gains"
        )
    m = np.linalg.inv(loop) if nz else np.zeros((0, 0))
    # z = Zx [x_P; x_Δ] + Zq q,  v = Vx x + Vq q  (q = [w; u])
    zx = m @ np.hstack([c1, d11 @ cd])
    zq = m @ d12
    vx = np.hstack([np.zeros((nv, np_)), cd]) + dd @ zx
    vq = dd @ zq
    a_cl = np.vstack(
        [
            np.hstack([a, np.zeros((np_, nd))]) + b1 @ vx,
            np.hstack([np.zeros((nd, np_)), ad]) + bd @ zx,
        ]
    )
    b_cl = np.vstack([b2 + b1 @ vq, bd @ zq])
    c_cl = np.hstack([c2, np.zeros((c2.shape[0], nd))]) + d21 @ vx
    d_cl = d22 + d21 @ vq
    n = np_ + nd
    sys = StateSpace(a_cl if n else np.zeros((0, 0)), b_cl, c_cl, d_cl, p.dt_s)
    if n and np.max(np.abs(np.linalg.eigvals(sys.a))) >= 1.0 - 1e-9:
        raise UnstableModelError(
            "the simulated plant (the model closed with the chosen member Δ) is unstable: "
            "choose the nominal or smaller gains, or a model whose P11 has gain < 1"
        )
    return sys


def closed_loop_system(config: ModelSimConfig) -> StateSpace:
    """The simulated plant ``[w; u] -> y`` (deviations) of a configuration."""
    model = config.model
    try:
        p = discrete_plant(model, config.ts_s)
    except ModelSimError:
        raise
    except ModelError as err:
        raise ModelSimError(f"model {model.name!r} at ts_s={config.ts_s:g}: {err}") from err
    delta = delta_system(model, config.member, config.ts_s)
    return close_loop(p, delta, model.blocks.nz, model.blocks.nv)


def settling_periods(system: StateSpace, period_samples: int, tol: float = SETTLE_TOL) -> int:
    """Periods after which the transient from rest has decayed: ``||A^(p N)||_2 <= tol``.

    Args:
        system: The discrete closed loop.
        period_samples: N.
        tol: Relative size of the remaining transient.

    Returns:
        The smallest p >= 1 (0 for a static system).

    Raises:
        ModelSimError: More than :data:`MAX_SETTLE_PERIODS` periods would be needed (give
            ``settle_periods`` yourself, or lengthen the period).
    """
    if system.n_states == 0:
        return 0
    step = np.linalg.matrix_power(system.a, period_samples)
    power = step.copy()
    for p in range(1, MAX_SETTLE_PERIODS + 1):
        if np.linalg.norm(power, 2) <= tol:
            return p
        power = power @ step
    raise ModelSimError(
        f"the plant's transient needs more than {MAX_SETTLE_PERIODS} periods of "
        f"{period_samples} samples to decay by {tol:g}: lengthen the period or set "
        "settle_periods yourself"
    )


# --------------------------------------------------------------------------- stepping


class PlantSample(NamedTuple):
    """One sample of the simulated plant."""

    stamp_ns: int
    """``k ts_ns``."""
    u: FloatArray
    """(nu,) the commanded inputs (recorded), model units."""
    y: FloatArray
    """(ny,) the measured outputs, model units."""
    w: FloatArray
    """(nw,) the unknown input drawn for this sample (noise_scale included)."""


@dataclass(frozen=True)
class _Window:
    kind: str
    index: int
    magnitude: float
    first: int
    stop: int | None  # first sample without the fault, None: never

    def active(self, k: int) -> bool:
        return k >= self.first and (self.stop is None or k < self.stop)


def _first_sample(t_s: float, ts_s: float) -> int:
    return max(0, math.ceil(t_s / ts_s - _ONSET_SLACK))


class ModelPlant:
    """The simulated plant, one sample at a time (the ROS node's engine).

    :meth:`step` computes sample k (see the module docstring) and advances. Two plants of
    the same configuration give the same samples bit for bit; :func:`simulate_model` is
    :meth:`step` repeated.

    Args:
        config: The run.
        system: The closed loop, if already built (``closed_loop_system(config)``).
    """

    def __init__(self, config: ModelSimConfig, system: StateSpace | None = None) -> None:
        self.config = config
        self.system = closed_loop_system(config) if system is None else system
        self.table = config.command_table()
        self.offset = np.asarray(config.offset, dtype=float)
        self.y_op = config.output_operating_point()
        self.nw = config.model.nw
        # unit-norm w: the mean square summed over the nw channels is 1 (power convention)
        self._w_scale = config.noise_scale / math.sqrt(self.nw) if self.nw else 0.0
        self.k = 0
        self.x = np.zeros(self.system.n_states)
        self._rng = np.random.default_rng(config.noise_seed)
        model = config.model
        self._windows = tuple(
            _Window(
                f.kind,
                (model.input_names if f.on_input else model.output_names).index(f.channel),
                f.magnitude,
                _first_sample(f.onset_s, config.ts_s),
                None if math.isinf(f.end_s) else _first_sample(f.end_s, config.ts_s),
            )
            for f in config.faults
        )
        self._applied = self.offset.copy()  # the input the plant had before sample 0
        self._held: dict[int, float] = {}
        delays = [f.magnitude for f in config.faults if f.kind == "output_delay"]
        depth = 2 + math.ceil(sum(delays) / config.ts_s) if delays else 0
        self._history: deque[FloatArray] = deque(maxlen=max(depth, 1))

    @property
    def stamp_ns(self) -> int:
        """Stamp of the next sample."""
        return self.k * self.config.ts_ns

    def command(self, k: int) -> FloatArray:
        """(nu,) the excitation's command of sample k (model units)."""
        return np.array(self.table[k % len(self.table)])

    def _applied_input(self, k: int, u: FloatArray) -> FloatArray:
        """The input the plant gets: gains first, then stuck inputs hold their value."""
        applied = u.copy()
        for f in self._windows:
            if f.kind == "input_gain" and f.active(k):
                applied[f.index] *= f.magnitude
        for n, f in enumerate(self._windows):
            if f.kind != "stuck_input":
                continue
            if not f.active(k):
                self._held.pop(n, None)
                continue
            held = self._held.setdefault(n, float(self._applied[f.index]))
            applied[f.index] = held
        return applied

    def _measured(self, k: int, y_pre: FloatArray) -> FloatArray:
        self._history.appendleft(y_pre)  # history[j] = y_pre(k - j)
        y = y_pre.copy()
        delay = np.zeros(y.size)
        bias = np.zeros(y.size)
        for f in self._windows:
            if f.active(k):
                if f.kind == "output_delay":
                    delay[f.index] += f.magnitude / self.config.ts_s
                elif f.kind == "sensor_bias":
                    bias[f.index] += f.magnitude
        for i in np.flatnonzero(delay).tolist():
            tau = float(delay[i])
            whole = math.floor(tau + 1e-9)
            frac = tau - whole if tau - whole > 1e-9 else 0.0
            y[i] = self._past(whole, i)
            if frac:
                y[i] = (1.0 - frac) * y[i] + frac * self._past(whole + 1, i)
        return y + bias if bias.any() else y

    def _past(self, j: int, i: int) -> float:
        """y_pre_i(k - j); the operating point before sample 0."""
        if j < len(self._history):
            return float(self._history[j][i])
        return float(self.y_op[i])

    def step(self, command: FloatArray | None = None) -> PlantSample:
        """Measure sample k and advance one sample.

        Args:
            command: (nu,) the command to apply (model units); None: the excitation's.

        Returns:
            The sample: stamp, commanded u (what a recorder logs), measured y, drawn w.
        """
        k = self.k
        u = self.command(k) if command is None else np.asarray(command, dtype=float).copy()
        applied = self._applied_input(k, u)
        w = self._w_scale * self._rng.standard_normal(self.nw) if self.nw else np.zeros(0)
        q = np.concatenate([w, applied - self.offset])
        sys = self.system
        y_pre = sys.c @ self.x + sys.d @ q + self.y_op
        self.x = sys.a @ self.x + sys.b @ q
        y = self._measured(k, y_pre) if self._windows else y_pre
        self._applied = applied
        self.k = k + 1
        return PlantSample(k * self.config.ts_ns, u, y, w)


# --------------------------------------------------------------------------- batch


@dataclass(frozen=True)
class ModelSimResult:
    """A simulated run of a model.

    Attributes:
        stamps_ns: (n,) int64, ``k ts_ns``.
        u: (n, nu) float, the commanded inputs, model units (order of ``input_names``).
        y: (n, ny) float, the measured outputs, model units (order of ``output_names``).
        w: (n, nw) float, the unknown input drawn (noise_scale included).
        input_names: The model's input names.
        output_names: The model's output names.
        ts_s: Sample period, s.
        period_samples: Samples per excitation period.
        settle_periods: Periods of settling at the start.
        periods: Periods after settling.
        config: The configuration that made it.
    """

    stamps_ns: NDArray[np.int64]
    u: FloatArray
    y: FloatArray
    w: FloatArray
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    ts_s: float
    period_samples: int
    settle_periods: int
    periods: int
    config: ModelSimConfig = field(repr=False)

    @property
    def n_samples(self) -> int:
        """Samples in the run."""
        return int(self.stamps_ns.size)

    @property
    def record_slice(self) -> slice:
        """The samples of the ``periods`` periods after settling."""
        start = self.settle_periods * self.period_samples
        return slice(start, start + self.periods * self.period_samples)

    def recorded(self) -> tuple[FloatArray, FloatArray]:
        """``(u, y)`` of the periods after settling (whole periods, for ``make_datum``)."""
        s = self.record_slice
        return self.u[s], self.y[s]


def simulate_model(config: ModelSimConfig) -> ModelSimResult:
    """Simulate the configuration: settling periods, then the recorded periods.

    A hand loop over :meth:`ModelPlant.step` rather than ``scipy.signal.dlsim``: the faults
    switch per sample (a stuck input holds the value applied before its onset, a delayed
    output reads the past measurements) and the ROS node steps the same code one sample at
    a time, so the batch is that node's output bit for bit. (The tests check it against
    ``dlsim`` and against the model's frequency response.)

    Returns:
        The run, ``(settle_periods + periods) period_samples`` samples.

    Raises:
        ModelSimError: A setting the model cannot be simulated with.
        UnstableModelError: The chosen member makes the plant unstable.
    """
    system = closed_loop_system(config)
    settle = (
        settling_periods(system, config.period_samples)
        if config.settle_periods is None
        else config.settle_periods
    )
    n = (settle + config.periods) * config.period_samples
    plant = ModelPlant(config, system)
    model = config.model
    stamps = np.empty(n, dtype=np.int64)
    u = np.empty((n, model.nu))
    y = np.empty((n, model.ny))
    w = np.empty((n, model.nw))
    for k in range(n):
        s = plant.step()
        stamps[k], u[k], y[k], w[k] = s.stamp_ns, s.u, s.y, s.w
    return ModelSimResult(
        stamps_ns=stamps,
        u=u,
        y=y,
        w=w,
        input_names=model.input_names,
        output_names=model.output_names,
        ts_s=config.ts_s,
        period_samples=config.period_samples,
        settle_periods=settle,
        periods=config.periods,
        config=config,
    )
