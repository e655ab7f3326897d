"""The simulated rig's faults at twice their stated limits, one spec each.

The stated limits are the default alarm's (docs/detection.md, "Stated limits"); kinds
without a stated limit (sensor delays, mixing delay, heat loss, stuck and saturating valve,
hot supply) at the sizes of the detection matrix. Used by the isolation bench
(``bench/bench_isolation.py``) and by identify's grey-box tests, which must be invalidated by
each of them.
"""

from __future__ import annotations

TWICE_STATED_LIMITS = (
    "leak=0.06",
    "sensor_bias:height=0.05",
    "sensor_bias:temperature=0.16",
    "valve_weak:hot=0.86",
    "valve_weak:cold=0.86",
    "sensor_delay:height=10",
    "sensor_delay:temperature=30",
    "mixing_delay=35",
    "heat_loss=0.2",
    "valve_stuck:hot=0",
    "valve_saturation:hot=0.38",
    "hot_supply=-0.15",
)
