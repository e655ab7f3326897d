"""The simulated rig's faults at their stated limits and at twice them, one spec each.

The stated limits are the default alarm's (docs/detection.md, "Stated limits"); kinds
without a stated limit (sensor delays, mixing delay, heat loss, stuck and saturating valve,
hot supply) at the sizes of the detection matrix. Used by the isolation bench
(``bench/bench_isolation.py``), the closed-loop bench (``bench/bench_closed_loop.py``) and
identify's grey-box tests, which must be invalidated by each of them.
"""

from __future__ import annotations

STATED_LIMITS = {
    "leak": 0.03,
    "sensor_bias:height": 0.025,
    "sensor_bias:temperature": 0.08,
    "valve_weak:hot": 0.93,
    "valve_weak:cold": 0.93,
}
"""The default alarm's stated limits (docs/detection.md): the fault's size at the limit."""


def scaled(kind: str, factor: float) -> str:
    """The spec of ``kind`` at ``factor`` times its stated limit.

    A weak valve's size is the gain it keeps, so its loss (``1 - size``) is what scales:
    twice the limit 0.93 (7 % loss) is 0.86.
    """
    size = STATED_LIMITS[kind]
    size = 1.0 - factor * (1.0 - size) if kind.startswith("valve_weak") else factor * size
    return f"{kind}={round(size, 6):g}"


WITHOUT_STATED_LIMIT = (
    "sensor_delay:height=10",
    "sensor_delay:temperature=30",
    "mixing_delay=35",
    "heat_loss=0.2",
    "valve_stuck:hot=0",
    "valve_saturation:hot=0.38",
    "hot_supply=-0.15",
)
"""The kinds without a stated limit, at the sizes of the detection matrix."""

TWICE_STATED_LIMITS = tuple(scaled(kind, 2.0) for kind in STATED_LIMITS) + WITHOUT_STATED_LIMIT
