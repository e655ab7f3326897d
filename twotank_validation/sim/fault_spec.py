"""Text form of rig faults, for ROS parameters and command lines.

``KIND[:CHANNEL][=MAGNITUDE]@ONSET_S[-END_S]``, for example ``leak=0.02@1000``,
``sensor_bias:height=0.05@500``, ``valve_stuck:hot@300``, ``valve_weak:cold=0.7@300-900``,
``mixing_delay=25@0``. Magnitudes and channels mean what :class:`twotank_validation.sim.rig.Fault`
says.
"""

from __future__ import annotations

import math
import re

from twotank_validation.errors import ModelError
from twotank_validation.sim.rig import FAULT_KINDS, Fault

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
