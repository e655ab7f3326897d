"""Detection delay in closed loop beside open loop, faults at twice the default alarm's limits.

Each run is the default scenario (Model B, the default alarm: a window every quarter period,
the sequential debounce, the operating-point check), one fault from ``8 P + phase P``, open
loop (the excitation's commands to the valves) or closed loop (the PI loops of
``twotank_validation.sim.control``, the excitation added to their output, the validator's
periodicity gate at ``CLOSED_LOOP_INPUT_PERIODIC_RTOL``). Delay: onset to the end of the
first window whose alarm is ERROR, within 6 periods; "-" when none. Prints one row per fault
with the medians over seeds and phases (measured, not asserted)::

    scripts/run bench bench_closed_loop.py [--seeds 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

from tools.events import record_events
from twotank_validation.core.model import load_model
from twotank_validation.online import Alarm, MonitorConfig, OnlineValidator
from twotank_validation.sim.control import CLOSED_LOOP_INPUT_PERIODIC_RTOL
from twotank_validation.sim.scenario import ClosedLoop, Scenario, simulate_scenario

PERIOD, TS = 2048, 0.1
PERIOD_S = PERIOD * TS
# twice the stated limits of the default alarm (docs/detection.md "Stated limits")
FAULTS = {
    "leak": "leak=0.06",
    "sensor_bias:height": "sensor_bias:height=0.05",
    "sensor_bias:temperature": "sensor_bias:temperature=0.16",
    "valve_weak:hot (14 % loss)": "valve_weak:hot=0.86",
    "valve_weak:cold (14 % loss)": "valve_weak:cold=0.86",
}
PHASES = (0.2, 0.45, 0.7, 0.95)
HORIZON_P = 6
ONSET_P = 8  # onsets in period 8: the closed loop's start-up is over and its reference commissioned


def delay_s(spec: str, phase: float, seed: int, closed: bool) -> float | None:
    onset = round((ONSET_P + phase) * PERIOD) * TS
    scenario = Scenario(
        name="bench",
        duration_s=(ONSET_P + HORIZON_P + 1) * PERIOD_S,
        seed=seed,
        faults=(f"{spec}@{onset:g}",),
        closed_loop=ClosedLoop() if closed else None,
    )
    stamps, u, y = simulate_scenario(scenario)
    config = MonitorConfig(input_periodic_rtol=CLOSED_LOOP_INPUT_PERIODIC_RTOL if closed else 1e-6)
    reports = OnlineValidator(config, [load_model("B")]).feed_many(*record_events(stamps, u, y))
    for r in reports:
        t = r.end_ns / 1e9
        if r.alarm is Alarm.ERROR:
            if t < onset:
                return -1.0  # a false alarm before the onset
            return t - onset if t - onset <= HORIZON_P * PERIOD_S else None
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    start = time.monotonic()
    print(
        "| fault | open loop: detected | median delay (s) | closed loop: detected | "
        "median delay (s) |"
    )
    print("|---|---|---|---|---|")
    for name, spec in FAULTS.items():
        row = [name]
        for closed in (False, True):
            delays = [
                delay_s(spec, phase, seed, closed) for seed in range(args.seeds) for phase in PHASES
            ]
            found = [d for d in delays if d is not None and d >= 0]
            row.append(f"{len(found)}/{len(delays)}")
            row.append(f"{statistics.median(found):.0f}" if found else "-")
        print("| " + " | ".join(row) + " |", flush=True)
    print(f"({time.monotonic() - start:.0f} s wall)")


if __name__ == "__main__":
    main()
