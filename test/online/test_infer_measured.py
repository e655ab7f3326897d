"""Period inference on measured inputs (issue 28, item 2): repeating only within their noise.

References: the period the excitation was generated with, and the commanded inference's own
answer on the same inputs without noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from twotank_validation.core.datum import MEASURED_INPUT_RTOL
from twotank_validation.online.infer import infer_excitation_period
from twotank_validation.sim.excitation import ExcitationConfig, excitation_commands

NOISE = 1e-3


def _logged(period: int, kind: str, periods: int = 4, hold: int = 0, seed: int = 0):
    """(clean, logged): the commands and a sensor's reading of them (white noise added)."""
    cfg = ExcitationConfig(
        kind=kind, ts_s=0.1, period_samples=period, settle_periods=0, record_periods=periods
    )
    u = excitation_commands(cfg, np.array([0.4, 0.5]))
    u = np.vstack([np.tile([0.4, 0.5], (hold, 1)), u])
    rms = np.sqrt(np.mean((u[hold:] - u[hold:].mean(0)) ** 2, axis=0))
    noise = np.random.default_rng(seed).standard_normal(u.shape) * NOISE * rms
    return u, u + noise


@pytest.mark.parametrize(
    ("period", "kind", "hold"),
    [(2048, "filtered_noise", 0), (256, "multisine", 37), (64, "filtered_noise", 500)],
)
def test_measured_inputs_give_the_true_period(period: int, kind: str, hold: int) -> None:
    clean, logged = _logged(period, kind, hold=hold)
    assert infer_excitation_period(clean) == period  # the commanded reference
    both = np.array([True, True])
    # the held start is noisy too: the excitation starts where the reading first moves
    logged[:hold] = clean[:hold]
    assert infer_excitation_period(logged, measured=both) == period
    assert infer_excitation_period(logged) is None  # as commands, they do not repeat
    mixed = np.column_stack([clean[:, 0], logged[:, 1]])  # one commanded, one measured
    assert infer_excitation_period(mixed, measured=np.array([False, True])) == period


def test_measured_inputs_with_lost_samples() -> None:
    _, logged = _logged(256, "filtered_noise")
    logged[np.random.default_rng(3).random(len(logged)) < 0.02] = np.nan
    assert infer_excitation_period(logged, measured=np.array([True, True])) == 256


def test_a_measured_input_whose_excitation_changes_does_not_repeat() -> None:
    _, logged = _logged(256, "multisine")
    logged[600:] = logged[600:].mean(0) + (1.0 + 4 * MEASURED_INPUT_RTOL) * (
        logged[600:] - logged[600:].mean(0)
    )
    assert infer_excitation_period(logged, measured=np.array([True, True])) is None
    noise = np.random.default_rng(1).standard_normal((3000, 2))
    assert infer_excitation_period(noise, measured=np.array([True, True])) is None
