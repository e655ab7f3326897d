"""Faults and unmodelled effects of the simulated rig, and their text form.

A :class:`Fault` switches on at a given simulated time: a leak, heat loss to ambient, a stuck,
weak or saturating valve, a sensor bias or delay, a changed mixing delay, a changed hot-supply
temperature (:class:`FaultKind`, each kind's properties one :class:`FaultKindRecord`).
:class:`FaultEffects` sums the active faults into what the simulator's balances need.

Text form, for ROS parameters and command lines:
``KIND[:CHANNEL][=MAGNITUDE]@ONSET_S[-END_S]``, for example ``leak=0.02@1000``,
``sensor_bias:height=0.05@500``, ``valve_stuck:hot@300``, ``valve_weak:cold=0.7@300-900``,
``mixing_delay=25@0``, ``valve_saturation:hot=0.45@1500``, ``hot_supply=-0.1@1500``
(:func:`parse_fault`, :func:`format_fault`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType
from typing import NamedTuple, cast

from twotank_validation.errors import ModelError


class FaultKind(StrEnum):
    """A kind of :class:`Fault` that TankSimulator implements; its text is its value.

    Its properties are one record each (:attr:`record`, :data:`FAULT_RECORDS`).
    """

    LEAK = "leak"
    SENSOR_BIAS = "sensor_bias"
    VALVE_STUCK = "valve_stuck"
    VALVE_WEAK = "valve_weak"
    SENSOR_DELAY = "sensor_delay"
    MIXING_DELAY = "mixing_delay"
    HEAT_LOSS = "heat_loss"
    VALVE_SATURATION = "valve_saturation"
    HOT_SUPPLY = "hot_supply"

    def __repr__(self) -> str:
        """The text's repr (``'leak'``): a Fault prints as it did when kinds were strings."""
        return repr(self.value)

    @property
    def record(self) -> FaultKindRecord:
        """This kind's properties."""
        return FAULT_RECORDS[self]


VALVE_CHANNELS: tuple[str, ...] = ("hot", "cold")
SENSOR_CHANNELS: tuple[str, ...] = ("height", "temperature")

MAX_FAULT_DELAY_S = 600.0
"""Largest ``sensor_delay`` or ``mixing_delay`` magnitude accepted, seconds."""

MAX_HOT_SUPPLY_SHIFT = 0.5
"""Largest size of a ``hot_supply`` change accepted (model temperature units; the nominal
supplies are 1 and 0)."""


@dataclass(frozen=True)
class MagnitudeRange:
    """The range of a fault's ``magnitude``: ``(low, high]`` or ``[low, high]``, and its unit.

    Attributes:
        low, high: the bounds.
        low_inclusive: whether ``low`` itself is accepted (``high`` always is).
        unit: what the magnitude is, in words with its unit.
    """

    low: float
    high: float
    low_inclusive: bool
    unit: str

    def contains(self, value: float) -> bool:
        """Whether ``value`` lies in the range."""
        above_low = value >= self.low if self.low_inclusive else value > self.low
        return above_low and value <= self.high

    @property
    def text(self) -> str:
        """``"[0, 1]"`` or ``"(0, 1]"``."""
        return f"{'[' if self.low_inclusive else '('}{self.low:g}, {self.high:g}]"


@dataclass(frozen=True)
class FaultKindRecord:
    """Everything about one kind of fault, in one place.

    Attributes:
        kind: the kind.
        magnitude: the range and unit of its ``magnitude``; None: the magnitude is ignored
            (any finite value).
        channels: the channels it acts on, one per fault (``()``: the whole tank, no channel).
        moves_operating_point: a constant change that moves the steady means by itself.
        thermal: acts on the energy balance (the heat the tank gains or loses).
        stuck: a valve that stops following (part of) its command: stuck or clipping.
        effect: the effect kind of the diagnosis that names it
            (``twotank_validation.diagnose.kinds.EffectKind``, by its text; this layer does
            not import the diagnosis).
        effect_channel: the channel that effect names; None: the fault's own channel.
    """

    kind: FaultKind
    magnitude: MagnitudeRange | None
    channels: tuple[str, ...]
    moves_operating_point: bool
    thermal: bool
    stuck: bool
    effect: str
    effect_channel: str | None


def _record(
    kind: FaultKind,
    magnitude: MagnitudeRange | None,
    channels: tuple[str, ...],
    effect: tuple[str, str | None],
    *,
    moves: bool = False,
    thermal: bool = False,
    stuck: bool = False,
) -> tuple[FaultKind, FaultKindRecord]:
    return kind, FaultKindRecord(kind, magnitude, channels, moves, thermal, stuck, *effect)


FAULT_RECORDS: Mapping[FaultKind, FaultKindRecord] = MappingProxyType(
    dict(
        [
            _record(
                FaultKind.LEAK,
                MagnitudeRange(
                    0.0, 1.0, True, "extra outflow, model flow units (nominal outflow 0.8)"
                ),
                (),
                ("leak", "height"),
                moves=True,
            ),
            _record(
                FaultKind.SENSOR_BIAS,
                MagnitudeRange(-1.0, 1.0, True, "additive offset, model units"),
                SENSOR_CHANNELS,
                ("offset", None),
                moves=True,
            ),
            _record(FaultKind.VALVE_STUCK, None, VALVE_CHANNELS, ("stuck", None), stuck=True),
            _record(
                FaultKind.VALVE_WEAK,
                MagnitudeRange(0.0, 1.0, False, "fraction of the commanded flow delivered"),
                VALVE_CHANNELS,
                ("input_gain", None),
                moves=True,
            ),
            _record(
                FaultKind.SENSOR_DELAY,
                MagnitudeRange(0.0, MAX_FAULT_DELAY_S, True, "extra transport delay, seconds"),
                SENSOR_CHANNELS,
                ("delay", None),
            ),
            _record(
                FaultKind.MIXING_DELAY,
                MagnitudeRange(
                    0.0, MAX_FAULT_DELAY_S, True, "mixing delay at mixing_ref_level, seconds"
                ),
                (),
                ("delay", "temperature"),
            ),
            _record(
                FaultKind.HEAT_LOSS,
                MagnitudeRange(0.0, 1.0, True, "heat-loss coefficient, model flow units"),
                (),
                ("heat_loss", "temperature"),
                moves=True,
                thermal=True,
            ),
            _record(
                FaultKind.VALVE_SATURATION,
                MagnitudeRange(0.0, 1.0, False, "largest command the valve follows, model units"),
                VALVE_CHANNELS,
                ("saturation", None),
                stuck=True,
            ),
            _record(
                FaultKind.HOT_SUPPLY,
                MagnitudeRange(
                    -MAX_HOT_SUPPLY_SHIFT,
                    MAX_HOT_SUPPLY_SHIFT,
                    True,
                    "change of the hot supply temperature, model temperature units",
                ),
                (),
                ("hot_supply", "hot"),
                moves=True,
                thermal=True,
            ),
        ]
    )
)
"""Each :class:`FaultKind`'s record (the one table a new kind is added to)."""

FAULT_KINDS: tuple[str, ...] = tuple(k.value for k in FaultKind)
"""The texts of the kinds of :class:`Fault` that TankSimulator implements."""


@dataclass(frozen=True)
class Fault:
    """A fault or unmodelled effect of the rig, active from ``onset_s`` until ``end_s``.

    Before ``onset_s`` and from ``end_s`` on the rig is nominal. In a TankSimulator a fault
    takes effect at the first sample instant k ts_s >= onset_s and is removed at the first
    sample instant >= end_s (both to a rounding tolerance of 1e-9 sample), so it is at most one
    sample late. Meaning of ``magnitude`` by ``kind`` (model units, seconds):

    * ``leak``: extra outflow in [0, 1] (model flow units; 0.02 is 2.5 % of the nominal
      outflow 0.8), leaving at the tank temperature: ``A1 dh1/dt = f_h + f_c - f1 - leak``.
    * ``sensor_bias``: additive offset in [-1, 1] on the measured ``channel``
      (``"height"`` or ``"temperature"``).
    * ``valve_stuck``: the ``channel`` valve (``"hot"`` or ``"cold"``) freezes at its actual
      flow when the fault takes effect and ignores its command; ``magnitude`` is ignored (any
      finite value, e.g. 0).
    * ``valve_weak``: the ``channel`` valve delivers ``magnitude`` in (0, 1] times its
      (saturated) command; 0.7 is a 30 % loss. The valve lag still applies.
    * ``sensor_delay``: extra transport delay of ``magnitude`` in [0, 600] s on the measured
      ``channel``: from onset the measurement is the fault-free measurement ``magnitude`` s
      earlier (linear interpolation between substeps).
    * ``mixing_delay``: the measured-temperature transport delay at ``mixing_ref_level``
      becomes ``magnitude`` in [0, 600] s, replacing ``RigParams.mixing_delay_s`` (still
      proportional to the level).
    * ``heat_loss``: heat lost to ambient, ``q (t1 - ambient_temperature)`` in the energy
      balance with q = ``magnitude`` in [0, 1] (model flow units, e.g. 0.05).
    * ``valve_saturation``: the ``channel`` valve follows its command only up to
      ``magnitude`` in (0, 1] (model units): it is driven by ``min(command, magnitude)``, so
      commands above the limit are clipped (e.g. 0.45 on a valve operated at 0.4 clips the
      peaks of the excitation around its operating point). Clipping is from above only; a
      dead zone near closed is not modelled. The valve lag still applies.
    * ``hot_supply``: the hot supply temperature becomes ``RigParams.hot_supply_temp +
      magnitude``, ``magnitude`` in [-0.5, 0.5] (model temperature units; -0.1 is a supply
      0.1 cooler). The rig acts exactly as with that ``hot_supply_temp``; the changed supply
      must stay above ``cold_supply_temp`` (checked when the fault is added to a simulator).

    Several faults combine: leaks, heat losses, hot-supply changes, biases and sensor delays of
    the same channel add; weak-valve factors multiply; of several saturations of one valve the
    lowest limit applies (the command is clipped before a weak valve scales it); a stuck valve
    overrides a weak or saturating one; of several active ``mixing_delay`` faults the one
    registered last applies.

    Attributes:
        kind: The kind (a :class:`FaultKind`; its text, e.g. ``"leak"``, is accepted and
            converted).
        onset_s: Simulated time (seconds, finite, >= 0) at which the fault takes effect.
        magnitude: Size of the fault, finite, in the range given above for its kind.
        channel: ``"hot"``/``"cold"`` for valve faults, ``"height"``/``"temperature"`` for
            sensor faults, ``""`` for the others.
        end_s: Time (seconds) from which the fault is removed, > ``onset_s``; default never.

    Raises:
        ModelError: If a field is invalid (unknown kind, missing or wrong channel, magnitude out
            of range, non-finite or negative onset, end not after onset).
    """

    kind: FaultKind
    onset_s: float
    magnitude: float
    channel: str = ""
    end_s: float = math.inf

    def __post_init__(self) -> None:
        if not isinstance(self.kind, str) or self.kind not in FAULT_KINDS:
            raise ModelError(
                f"Fault.kind={self.kind!r} is not a known fault kind; use one of {FAULT_KINDS}"
            )
        object.__setattr__(self, "kind", FaultKind(self.kind))
        record = self.kind.record
        where = f"Fault(kind={self.kind.value!r})"
        for name in ("onset_s", "magnitude", "end_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ModelError(f"{where}.{name}={value!r} is not a real number; pass a float")
            object.__setattr__(self, name, float(value))
        if not (math.isfinite(self.onset_s) and self.onset_s >= 0.0):
            raise ModelError(
                f"{where}.onset_s={self.onset_s!r} must be a finite simulated time >= 0 s"
            )
        if math.isnan(self.end_s) or self.end_s <= self.onset_s:
            raise ModelError(
                f"{where}.end_s={self.end_s!r} must be later than onset_s={self.onset_s!r} "
                "(math.inf: never removed)"
            )
        if not math.isfinite(self.magnitude):
            raise ModelError(f"{where}.magnitude={self.magnitude!r} is not finite")
        rng = record.magnitude
        if rng is not None and not rng.contains(self.magnitude):
            raise ModelError(
                f"{where}.magnitude={self.magnitude!r} is outside {rng.text} "
                f"({rng.unit}); pass a magnitude inside that range"
            )
        allowed = record.channels
        if not isinstance(self.channel, str):
            raise ModelError(f"{where}.channel={self.channel!r} is not a string")
        if allowed and self.channel not in allowed:
            raise ModelError(
                f"{where}.channel={self.channel!r} is invalid; a {self.kind} fault needs "
                f"channel in {allowed}"
            )
        if not allowed and self.channel:
            raise ModelError(
                f"{where}.channel={self.channel!r} is invalid; a {self.kind} fault acts on the "
                'whole tank: leave channel=""'
            )


class FaultEffects(NamedTuple):
    """Combined effect of the faults active during one sample (identity: the nominal rig)."""

    leak: float = 0.0
    heat_loss: float = 0.0
    valve_gain: tuple[float, float] = (1.0, 1.0)
    stuck: tuple[bool, bool] = (False, False)
    bias: tuple[float, float] = (0.0, 0.0)
    sensor_delay_s: tuple[float, float] = (0.0, 0.0)
    mixing_delay_s: float | None = None
    valve_limit: tuple[float, float] = (1.0, 1.0)
    hot_supply_shift: float = 0.0

    @property
    def changes_dynamics(self) -> bool:
        """Whether the state equations (or the valve inputs) differ from the nominal ones."""
        return (
            self.leak != 0.0
            or self.heat_loss != 0.0
            or self.valve_gain != (1.0, 1.0)
            or self.stuck != (False, False)
            or self.valve_limit != (1.0, 1.0)
            or self.hot_supply_shift != 0.0
        )

    @classmethod
    def of(cls, faults: Sequence[Fault]) -> FaultEffects:
        """Sum the effects of the active ``faults``."""
        leak = heat_loss = hot_supply = 0.0
        gain = [1.0, 1.0]
        limit = [1.0, 1.0]
        stuck = [False, False]
        bias = [0.0, 0.0]
        delay = [0.0, 0.0]
        mixing: float | None = None
        for f in faults:
            if f.kind is FaultKind.LEAK:
                leak += f.magnitude
            elif f.kind is FaultKind.HEAT_LOSS:
                heat_loss += f.magnitude
            elif f.kind is FaultKind.VALVE_WEAK:
                gain[VALVE_CHANNELS.index(f.channel)] *= f.magnitude
            elif f.kind is FaultKind.VALVE_SATURATION:
                i = VALVE_CHANNELS.index(f.channel)
                limit[i] = min(limit[i], f.magnitude)
            elif f.kind is FaultKind.HOT_SUPPLY:
                hot_supply += f.magnitude
            elif f.kind is FaultKind.VALVE_STUCK:
                stuck[VALVE_CHANNELS.index(f.channel)] = True
            elif f.kind is FaultKind.SENSOR_BIAS:
                bias[SENSOR_CHANNELS.index(f.channel)] += f.magnitude
            elif f.kind is FaultKind.SENSOR_DELAY:
                delay[SENSOR_CHANNELS.index(f.channel)] += f.magnitude
            else:  # mixing_delay: the last one registered wins
                mixing = f.magnitude
        return cls(
            leak=leak,
            heat_loss=heat_loss,
            valve_gain=(gain[0], gain[1]),
            stuck=(stuck[0], stuck[1]),
            bias=(bias[0], bias[1]),
            sensor_delay_s=(delay[0], delay[1]),
            mixing_delay_s=mixing,
            valve_limit=(limit[0], limit[1]),
            hot_supply_shift=hot_supply,
        )


# --- text form --------------------------------------------------------------------------------

_SPEC = re.compile(
    r"^\s*(?P<kind>[a-z_]+)(?::(?P<channel>[a-z_]+))?(?:=(?P<mag>[-+0-9.eE]+))?"
    r"@(?P<onset>[0-9.]+(?:[eE][-+]?[0-9]+)?)(?:-(?P<end>[0-9.]+(?:[eE][-+]?[0-9]+)?|inf))?\s*$"
)


def parse_fault(spec: str) -> Fault:
    """Parse one fault spec.

    Raises:
        ModelError: malformed text or invalid fault (the message shows the expected form).
    """
    m = _SPEC.match(spec)
    if m is None:
        raise ModelError(
            f"fault spec {spec!r} is not KIND[:CHANNEL][=MAGNITUDE]@ONSET_S[-END_S], "
            f"e.g. 'leak=0.02@1000'; kinds: {', '.join(FAULT_KINDS)}"
        )
    try:
        return Fault(
            kind=cast("FaultKind", m["kind"]),  # Fault checks and converts the text
            onset_s=float(m["onset"]),
            magnitude=float(m["mag"]) if m["mag"] is not None else 0.0,
            channel=m["channel"] or "",
            end_s=float(m["end"]) if m["end"] is not None else math.inf,
        )
    except ValueError as err:
        raise ModelError(f"fault spec {spec!r}: {err}") from err


def format_fault(fault: Fault) -> str:
    """Inverse of :func:`parse_fault`."""
    chan = f":{fault.channel}" if fault.channel else ""
    end = f"-{fault.end_s:g}" if math.isfinite(fault.end_s) else ""
    return f"{fault.kind}{chan}={fault.magnitude:g}@{fault.onset_s:g}{end}"
