"""Simulate any LFT model: its nominal plant, a member of its perturbation set, its noise, faults.

The two-tank rig (:mod:`twotank_validation.sim.rig`) is one plant; a user's plant is given as
an :class:`~twotank_validation.core.model.LFTModel` of any shape and channel names. This module
simulates such a model directly, the way the validator reads it:

* Every continuous part (nominal, each weight, a generalised P) is discretised at ``ts_s``
  on its own (:func:`twotank_validation.core.lti.discretise`) by the model's hold: zero-order
  hold, or first-order hold under ``intersample: foh`` and ``exact`` (a simulation needs a
  discrete system; ``exact`` is the response at the bins only), as
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

The simulator is three modules: :mod:`twotank_validation.sim.model_faults` (the fault records,
their text form, :class:`ModelSimError` and the setting checks),
:mod:`twotank_validation.sim.model_members` (the member Δ, the discrete state spaces, the
closed loop, the settling) and this one (the excitation, the configuration, the stepping and
the batch). Every public name of the other two is importable from here as well.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from twotank_validation.core.lti import StateSpace
from twotank_validation.core.model import LFTModel
from twotank_validation.defaults import NS_PER_S, PERIOD_SAMPLES, TS_S
from twotank_validation.errors import DatumError, ModelError
from twotank_validation.sim import excitation
from twotank_validation.sim.model_faults import (
    _ONSET_SLACK,
    FAULT_TEXT_FORM,
    MAX_DELAY_SAMPLES,
    MODEL_FAULT_KINDS,
    ModelFault,
    ModelSimError,
    _check_fault,
    _integer,
    _per_channel,
    _real,
    format_model_fault,
    parse_model_fault,
)
from twotank_validation.sim.model_members import (
    MAX_SETTLE_PERIODS,
    MEMBER_KINDS,
    SETTLE_TOL,
    Member,
    close_loop,
    delta_system,
    discrete_plant,
    format_member,
    parse_member,
    settling_periods,
    undelay,
)

__all__ = [
    "FAULT_TEXT_FORM",
    "MAX_DELAY_SAMPLES",
    "MAX_SETTLE_PERIODS",
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
        design: The whole design (:class:`~twotank_validation.sim.excitation.ExcitationDesign`:
            odd lines, detection lines, line grid, realisations, crest-factor minimisation).
            None: built of the fields above, which are the short form; given: those fields
            are set from it (a field given too must agree with it). The signal is drawn
            from :attr:`the_design`, this or the short form's.
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
    design: excitation.ExcitationDesign | None = None
    _design: excitation.ExcitationDesign = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.design is not None:
            excitation.take_design(self, self.design, ModelSimError)
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
        design = self.design
        if design is None:
            try:
                design = excitation.ExcitationDesign(
                    kind=self.kind,
                    period_samples=self.period_samples,
                    f_min_hz=self.f_min_hz or 0.0,
                    f_max_hz=self.f_max_hz or 0.0,
                    lines="odd" if self.odd_only else "all",
                    cutoff_hz=self.cutoff_hz or 0.0,
                    order=self.order,
                    seed=self.seed,
                )
            except DatumError as err:
                raise ModelSimError(f"excitation: {err}") from err
        object.__setattr__(self, "_design", design)

    @property
    def the_design(self) -> excitation.ExcitationDesign:
        """The design the signal is drawn from: ``design``, or the short form's."""
        return self._design

    def band(self, ts_s: float) -> tuple[float, float, float]:
        """``(f_min_hz, f_max_hz, cutoff_hz)`` with the defaults for sample period ``ts_s``."""
        f_min, f_max = self.the_design.band_hz(ts_s)
        return f_min, f_max, self.the_design.cutoff(ts_s)

    def deviations(self, ts_s: float, rms: Sequence[float]) -> FloatArray:
        """One cycle of the zero-mean deviations, one column per input.

        One period for a single realisation; with several, each realisation tiled over its
        ``realisation_periods`` periods, one after the other
        (:meth:`~twotank_validation.sim.excitation.ExcitationDesign.cycle`).

        Args:
            ts_s: Sample period, s.
            rms: (nu,) RMS per input, model units.

        Returns:
            (cycle_periods period_samples, nu) float, column i of RMS ``rms[i]``.

        Raises:
            ModelSimError: An empty or invalid band (the message names the fix).
        """
        try:
            return self.the_design.cycle(ts_s, np.asarray(list(rms), dtype=np.float64))
        except DatumError as err:
            raise ModelSimError(f"excitation: {err}") from err


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
        try:  # an empty band fails here, not later
            self.excitation.the_design.realisation_tables(self.ts_s, len(self.rms))
        except DatumError as err:
            raise ModelSimError(f"excitation: {err}") from err

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
        """(cycle, nu) absolute commands of one cycle; sample k uses row k mod its length.

        One period for a single realisation.
        """
        return np.asarray(self.offset) + self.excitation.deviations(self.ts_s, self.rms)


# --------------------------------------------------------------------------- the closed loop


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
        """The ``periods`` periods after settling (of the first realisation).

        :meth:`recorded_realisations` gives each realisation's.
        """
        start = self.settle_periods * self.period_samples
        return slice(start, start + self.periods * self.period_samples)

    def recorded(self) -> tuple[FloatArray, FloatArray]:
        """``(u, y)`` of the periods after settling (whole periods, for ``make_datum``)."""
        s = self.record_slice
        return self.u[s], self.y[s]

    @property
    def realisations(self) -> int:
        """Realisations in the run (each: settling periods, then the recorded ones)."""
        return self.config.excitation.the_design.realisations

    def recorded_realisations(self) -> list[tuple[FloatArray, FloatArray]]:
        """``(u, y)`` of each realisation's recorded periods (after its settling), in order."""
        block = (self.settle_periods + self.periods) * self.period_samples
        out = []
        for r in range(self.realisations):
            start = r * block + self.settle_periods * self.period_samples
            s = slice(start, start + self.periods * self.period_samples)
            out.append((self.u[s], self.y[s]))
        return out


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
    design = config.excitation.the_design.with_run(settle + config.periods)
    if design is not config.excitation.the_design:  # each realisation: settling, then recorded
        config = replace(config, excitation=replace(config.excitation, design=design))
    n = (settle + config.periods) * config.period_samples * design.realisations
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
