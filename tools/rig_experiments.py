"""An identification experiment on the simulated two-tank rig: two orthogonal experiments.

Both valves carry a random-phase multisine on the lines 1/204.8 .. 0.03 Hz (ts 0.8 s, 256
samples a period), RMS 0.08 (hot) and 0.12 (cold) around the operating point h1 = 0.47,
t1 = 0.5; the second experiment flips the cold valve's sign (a 2 x 2 Hadamard pattern), so
the two valves' responses separate exactly (``frf_from_experiments``). Each experiment starts
at the operating point and settles for two periods before the recorded ones. The rig is the
demo's (``ExperimentConfig().rig``: a 15 s mixing delay, sensor noise 0.003 and 0.01).

Used by ``test/identify/test_greybox.py``, ``test/identify/test_pipeline.py`` and to write
the CSV of the docs' example (``python -m tools.rig_experiments OUT.csv``).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from functools import cache

import numpy as np

from twotank_validation.diagnose.inputs import Window
from twotank_validation.experiment import ExperimentConfig
from twotank_validation.sim import excitation, rig, simulator
from twotank_validation.sim.faults import Fault

TS_S = 0.8
PERIOD = 256
SETTLE = 2
RIG = ExperimentConfig().rig
"""The simulated rig's parameters (the reference the grey box is judged against)."""


def _commands(sign: float, periods: int, seed: int) -> np.ndarray:
    exc = excitation.ExcitationConfig(
        kind="multisine",
        f_max_hz=0.03,
        rms=(0.08, 0.12),
        ts_s=TS_S,
        period_samples=PERIOD,
        settle_periods=SETTLE,
        record_periods=periods,
        seed=seed,
    )
    op = rig.operating_point(RIG)
    u = excitation.excitation_commands(exc, op.commands)
    u[:, 1] = op.commands[1] + sign * (u[:, 1] - op.commands[1])
    return u


def experiment(
    sign: float, periods: int = 3, seed: int = 0, faults: Sequence[Fault] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """``(u, y)`` of one experiment, settling included: (n, 2), (n, 2), model units.

    ``sign``: +1 or -1 on the cold valve's excitation; ``seed``: the sensor noise's (the
    multisine's phases are the same for every seed); ``faults``: onsets in seconds from the
    start (the recorded periods start at ``SETTLE * PERIOD * TS_S``).
    """
    u = _commands(sign, periods, 0)
    sim = simulator.simulate(
        RIG, u, TS_S, op=rig.operating_point(RIG), seed=seed, substeps=16, faults=faults
    )
    return sim.commands, sim.measured


@cache
def windows(periods: int = 3, seed: int = 0) -> tuple[Window, Window]:
    """The recorded periods of the two experiments, one window each.

    Their sensor noise seeds are ``2 seed`` and ``2 seed + 1``.
    """
    out = []
    for k, sign in enumerate((1.0, -1.0)):
        u, y = experiment(sign, periods, 2 * seed + k)
        keep = slice(SETTLE * PERIOD, None)
        out.append(Window(u[keep], y[keep], TS_S, PERIOD))
    return out[0], out[1]


def write_csv(path: str, periods: int = 3, seed: int = 0) -> None:
    """Both experiments one after the other, settling included, as a table for ``--map``.

    Columns ``t`` (s), ``hot``, ``cold``, ``height``, ``temperature``.
    """
    parts = [experiment(sign, periods, 2 * seed + k) for k, sign in enumerate((1.0, -1.0))]
    u = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[1] for p in parts])
    t = np.arange(u.shape[0]) * TS_S
    table = np.column_stack([t, u, y])
    np.savetxt(path, table, delimiter=",", header="t,hot,cold,height,temperature", comments="")


if __name__ == "__main__":
    write_csv(sys.argv[1])
