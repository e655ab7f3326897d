"""The records and text forms of a model simulation's faults, and its setting checks.

:class:`ModelFault` is one fault of the simulated plant on a named channel of the model
(``input_gain``, ``stuck_input``, ``sensor_bias``, ``output_delay``); its text form
``KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S]`` is read by :func:`parse_model_fault` and written
by :func:`format_model_fault`. :class:`ModelSimError` is the error every part of the model
simulator raises for a bad setting; the checks of single settings (a finite real, an integer,
one number per channel) live here for the modules that build on it
(:mod:`twotank_validation.sim.model_members`, :mod:`twotank_validation.sim.model_plant`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from twotank_validation.core.model import LFTModel
from twotank_validation.errors import ModelError

__all__ = [
    "FAULT_TEXT_FORM",
    "MAX_DELAY_SAMPLES",
    "MODEL_FAULT_KINDS",
    "ModelFault",
    "ModelSimError",
    "format_model_fault",
    "parse_model_fault",
]

MODEL_FAULT_KINDS: Final = ("input_gain", "stuck_input", "sensor_bias", "output_delay")
"""Faults of :class:`ModelFault`: two on inputs, two on outputs."""

_INPUT_FAULTS: Final = ("input_gain", "stuck_input")

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
