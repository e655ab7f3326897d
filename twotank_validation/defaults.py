"""Defaults and names that more than one layer uses, each written once.

Every module that needs one of these imports it from here; nothing else restates them.
"""

from __future__ import annotations

import enum
from typing import Final

NS_PER_S: Final = 1_000_000_000
"""Nanoseconds per second: stamps are integer nanoseconds everywhere."""

TS_S: Final = 0.1
"""Default sample period of the two-tank rig (s)."""

PERIOD_SAMPLES: Final = 2048
"""Default excitation period (samples): 204.8 s at :data:`TS_S`."""

RIG_PI_KP: Final = (0.9, 0.7)
"""The rig's PI gains [level: total flow per unit of level, temperature: hot fraction per
unit of temperature] (``sim.control``: SIMC tuning); the closed-loop formulation's ``rig``
controller (docs/theory.md §21) reads the same."""

RIG_PI_TI_S: Final = (122.5, 53.8)
"""The rig's PI integral times [level, temperature] (s)."""

RIG_PI_FILTER_S: Final = 2.0
"""The rig's measurement filter time constant (s)."""

MAX_RECOVERED_FRACTION: Final = 0.02
"""Default largest fraction of a window per signal whose unusable samples are recovered from
the other periods. At 1 % of the messages lost per topic a window of N samples loses about
N/100 per signal (close to Poisson), so a cap of 2 % judges nearly every window there; the
recovered samples move β by a random amount well inside its window-to-window spread
(docs/theory.md §7)."""

JITTER_FRACTION: Final = 0.45
"""Default accepted distance of a stamp from its sample-grid point, as a fraction of the
sample period: each stamp goes to the nearest grid point, with a guard band of 5 % of a step
either side of the midpoint (stamps there are flagged off-grid, as they could belong to
either neighbour). The grid's phase is fit to the stamps, so jitter up to this fraction is
absorbed."""


class Method(enum.StrEnum):
    """The per-bin solver routes of :func:`twotank_validation.core.validate.validate`."""

    AUTO = "auto"
    """The closed form where it applies, else the fast path, else the SDP."""
    CLOSED_FORM = "closed_form"
    """The exact closed form for one full perturbation block (or none)."""
    FAST = "fast"
    """The compiled dual ascent with certified bounds (structured models)."""
    SDP = "sdp"
    """The per-bin cvxpy relaxation: the reference."""


METHODS: Final = tuple(m.value for m in Method)
"""The method names, in the order shown to users."""
