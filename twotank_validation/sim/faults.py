"""Faults and unmodelled effects of the simulated rig, and their text form.

A :class:`Fault` switches on at a given simulated time: a leak, heat loss to ambient, a stuck,
weak or saturating valve, a sensor bias or delay, a changed mixing delay, a changed hot-supply
temperature (kinds in ``FAULT_KINDS``).
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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from twotank_validation.errors import ModelError

FAULT_KINDS: tuple[str, ...] = (
    "leak",
    "sensor_bias",
    "valve_stuck",
    "valve_weak",
    "sensor_delay",
    "mixing_delay",
    "heat_loss",
    "valve_saturation",
    "hot_supply",
)
"""Kinds of :class:`Fault` that TankSimulator implements."""

VALVE_CHANNELS: tuple[str, ...] = ("hot", "cold")
SENSOR_CHANNELS: tuple[str, ...] = ("height", "temperature")
_CHANNELS: dict[str, tuple[str, ...]] = {
    "leak": (),
    "sensor_bias": SENSOR_CHANNELS,
    "valve_stuck": VALVE_CHANNELS,
    "valve_weak": VALVE_CHANNELS,
    "sensor_delay": SENSOR_CHANNELS,
    "mixing_delay": (),
    "heat_loss": (),
    "valve_saturation": VALVE_CHANNELS,
    "hot_supply": (),
}

MAX_FAULT_DELAY_S = 600.0
"""Largest ``sensor_delay`` or ``mixing_delay`` magnitude accepted, seconds."""

MAX_HOT_SUPPLY_SHIFT = 0.5
"""Largest size of a ``hot_supply`` change accepted (model temperature units; the nominal
supplies are 1 and 0)."""

# (low, high, low_inclusive, unit) of the magnitude of each kind; valve_stuck: any finite value.
_MAGNITUDE_RANGES: dict[str, tuple[float, float, bool, str]] = {
    "leak": (0.0, 1.0, True, "extra outflow, model flow units (nominal outflow 0.8)"),
    "sensor_bias": (-1.0, 1.0, True, "additive offset, model units"),
    "valve_weak": (0.0, 1.0, False, "fraction of the commanded flow delivered"),
    "sensor_delay": (0.0, MAX_FAULT_DELAY_S, True, "extra transport delay, seconds"),
    "mixing_delay": (0.0, MAX_FAULT_DELAY_S, True, "mixing delay at mixing_ref_level, seconds"),
    "heat_loss": (0.0, 1.0, True, "heat-loss coefficient, model flow units"),
    "valve_saturation": (0.0, 1.0, False, "largest command the valve follows, model units"),
    "hot_supply": (
        -MAX_HOT_SUPPLY_SHIFT,
        MAX_HOT_SUPPLY_SHIFT,
        True,
        "change of the hot supply temperature, model temperature units",
    ),
}


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
        kind: One of ``FAULT_KINDS``.
        onset_s: Simulated time (seconds, finite, >= 0) at which the fault takes effect.
        magnitude: Size of the fault, finite, in the range given above for its kind.
        channel: ``"hot"``/``"cold"`` for valve faults, ``"height"``/``"temperature"`` for
            sensor faults, ``""`` for the others.
        end_s: Time (seconds) from which the fault is removed, > ``onset_s``; default never.

    Raises:
        ModelError: If a field is invalid (unknown kind, missing or wrong channel, magnitude out
            of range, non-finite or negative onset, end not after onset).
    """

    kind: str
    onset_s: float
    magnitude: float
    channel: str = ""
    end_s: float = math.inf

    def __post_init__(self) -> None:
        if not isinstance(self.kind, str) or self.kind not in FAULT_KINDS:
            raise ModelError(
                f"Fault.kind={self.kind!r} is not a known fault kind; use one of {FAULT_KINDS}"
            )
        where = f"Fault(kind={self.kind!r})"
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
        if self.kind in _MAGNITUDE_RANGES:
            lo, hi, lo_inclusive, unit = _MAGNITUDE_RANGES[self.kind]
            above_lo = self.magnitude >= lo if lo_inclusive else self.magnitude > lo
            if not (above_lo and self.magnitude <= hi):
                bracket = "[" if lo_inclusive else "("
                raise ModelError(
                    f"{where}.magnitude={self.magnitude!r} is outside {bracket}{lo:g}, {hi:g}] "
                    f"({unit}); pass a magnitude inside that range"
                )
        allowed = _CHANNELS[self.kind]
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
            if f.kind == "leak":
                leak += f.magnitude
            elif f.kind == "heat_loss":
                heat_loss += f.magnitude
            elif f.kind == "valve_weak":
                gain[VALVE_CHANNELS.index(f.channel)] *= f.magnitude
            elif f.kind == "valve_saturation":
                i = VALVE_CHANNELS.index(f.channel)
                limit[i] = min(limit[i], f.magnitude)
            elif f.kind == "hot_supply":
                hot_supply += f.magnitude
            elif f.kind == "valve_stuck":
                stuck[VALVE_CHANNELS.index(f.channel)] = True
            elif f.kind == "sensor_bias":
                bias[SENSOR_CHANNELS.index(f.channel)] += f.magnitude
            elif f.kind == "sensor_delay":
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
            kind=m["kind"],
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
