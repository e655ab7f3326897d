"""Sample and excitation periods inferred from data, against brute force and the generator."""

from __future__ import annotations

import numpy as np
import pytest

from twotank_validation.defaults import NS_PER_S
from twotank_validation.online.infer import (
    grid_samples,
    infer_excitation_period,
    infer_sample_period,
)
from twotank_validation.sim.excitation import ExcitationConfig, excitation_commands


def commands(period: int, kind: str = "filtered_noise", periods: int = 3, hold: int = 0):
    cfg = ExcitationConfig(
        kind=kind, ts_s=0.1, period_samples=period, settle_periods=0, record_periods=periods
    )
    u = excitation_commands(cfg, np.array([0.4, 0.5]))
    return np.vstack([np.tile([0.4, 0.5], (hold, 1)), u])


def brute_period(u: np.ndarray, rtol: float = 1e-6) -> int | None:
    """Reference: the smallest shift p >= 4 with every aligned pair within rtol * RMS."""
    moved = np.any(u != u[0], axis=1)
    z = u[int(np.argmax(moved)) :]
    rms = np.sqrt(np.mean((z - z.mean(axis=0)) ** 2, axis=0))
    for p in range(4, len(z) // 2 + 1):
        if np.all(np.abs(z[p:] - z[:-p]) <= rtol * rms):
            return p
    return None


@pytest.mark.parametrize("ts", [0.1, 0.5, 1 / 30, 0.02])
def test_sample_period_on_a_grid_with_losses_and_jitter(ts: float) -> None:
    rng = np.random.default_rng(1)
    n = 5000
    ts_ns = round(ts * NS_PER_S)
    keep = rng.random(n) > 0.01
    jitter = rng.uniform(-0.15, 0.15, n) * ts_ns
    stamps = 1_700_000_000 * NS_PER_S + np.arange(n) * ts_ns + jitter.astype(np.int64)
    found = infer_sample_period(stamps[keep])
    assert found is not None
    # first and last stamps jitter by 15 % of a step at most: the step is known to 2 * 0.15 / n
    assert found.ts_s == pytest.approx(ts, rel=0.3 / n + 1e-9)
    missing = int(np.count_nonzero(~keep[1:-1]))  # interior drops (the ends set the span)
    assert abs(found.steps_missing - missing) <= 2
    assert found.on_grid > 0.95


def test_sample_period_needs_three_stamps() -> None:
    assert infer_sample_period(np.array([0, 100])) is None
    assert infer_sample_period(np.array([0, 100, 100, 100])) is None


def test_grid_samples_places_values_and_leaves_gaps() -> None:
    stamps = np.array([0, 100, 300, 300, 400]) * 1_000_000  # 0.1 s grid, 0.2 s lost
    vals = np.arange(5.0)[:, None]
    g = grid_samples(stamps, vals, 0.1)
    assert g.shape == (5, 1)
    assert np.isnan(g[2, 0])
    assert g[3, 0] == 3.0  # a repeated step keeps its last value


@pytest.mark.parametrize(
    ("period", "kind", "hold"),
    [(2048, "filtered_noise", 0), (256, "multisine", 37), (64, "filtered_noise", 500)],
)
def test_excitation_period_of_generated_commands(period: int, kind: str, hold: int) -> None:
    u = commands(period, kind, hold=hold)
    assert infer_excitation_period(u) == period
    if period <= 256:
        assert brute_period(u) == period


def test_excitation_period_with_lost_samples() -> None:
    u = commands(256, periods=4)
    rng = np.random.default_rng(3)
    u[rng.random(len(u)) < 0.02] = np.nan
    assert infer_excitation_period(u) == 256


def test_two_periods_at_least_are_needed_and_noise_does_not_repeat() -> None:
    u = commands(256, periods=3)
    assert infer_excitation_period(u[: 2 * 256 - 10]) is None  # less than two periods
    rng = np.random.default_rng(0)
    assert infer_excitation_period(rng.standard_normal((3000, 2))) is None
    assert infer_excitation_period(np.tile([0.4, 0.5], (3000, 1))) is None
    assert infer_excitation_period(np.full((100, 2), np.nan)) is None


def test_a_changed_excitation_breaks_the_repetition() -> None:
    u = commands(256, periods=4)
    u[700:, 0] += 1e-3  # the hot valve's offset moves after 2.7 periods
    assert infer_excitation_period(u) is None
