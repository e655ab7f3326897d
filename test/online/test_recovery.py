"""Unusable samples recovered from the other periods: the rules, and β against the clean record."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tools import streamfuzz
from twotank_validation.core.model import load_model
from twotank_validation.online import MonitorConfig, OnlineValidator
from twotank_validation.online import streams as itf
from twotank_validation.online.recovery import recover_span

P = 8
NAMES = ("hot", "cold", "height", "temperature")
OUT = ("height", "temperature")


def periodic(q: int = 3, seed: int = 0):
    rng = np.random.default_rng(seed)
    u = np.tile(rng.random((P, 2)), (q, 1))
    y = np.tile(rng.random((P, 2)), (q, 1)) + 0.01 * rng.standard_normal((q * P, 2))
    return u, y


def run(u, y, flags, frac=0.25):
    return recover_span(
        u, y, flags, period=P, window=2 * P, max_fraction=frac, names=NAMES, output_names=OUT
    )


def test_a_missing_output_is_the_mean_of_the_other_periods() -> None:
    u, y = periodic()
    y2 = y.copy()
    y2[P + 3, 1] = np.nan
    flags = [None] * (3 * P)
    flags[P + 3] = "gap: no temperature sample at t = 1.000 s"
    rec = run(u, y2, flags)
    assert rec.reason is None
    assert rec.y[P + 3, 1] == pytest.approx((y[3, 1] + y[2 * P + 3, 1]) / 2, abs=0)
    assert np.array_equal(np.delete(rec.y, P + 3, axis=0), np.delete(y, P + 3, axis=0))
    assert rec.recovered.tolist() == [0, 0, 0, 1]


def test_an_off_grid_output_is_replaced_and_outputs_before_the_window_are_left() -> None:
    u, y = periodic()
    flags = [None] * (3 * P)
    flags[2 * P + 1] = "height stamp 123 ns is off the sample grid by 300.0 ms"
    flags[2] = "gap: no height sample at t = 0.2 s"  # settling period: not needed
    y2 = y.copy()
    y2[2, 0] = np.nan
    rec = run(u, y2, flags)
    assert rec.reason is None
    assert rec.y[2 * P + 1, 0] == pytest.approx((y[1, 0] + y[P + 1, 0]) / 2, abs=0)
    assert np.isnan(rec.y[2, 0])
    assert rec.recovered.tolist() == [0, 0, 1, 0]


def test_a_held_command_is_recovered_exactly() -> None:
    u, y = periodic()
    u2 = u.copy()
    u2[P + 5, 0] = u2[P + 4, 0]  # the command of P+5 was lost: the valve held P+4's
    rec = run(u2, y, [None] * (3 * P))
    assert rec.reason is None
    assert np.array_equal(rec.u, u)
    assert rec.recovered.tolist() == [1, 0, 0, 0]
    # a changed excitation (every period differs) is not "held": nothing is touched
    u3 = u.copy()
    u3[2 * P :, 0] += 0.1
    assert run(u3, y, [None] * (3 * P)).recovered.sum() == 0


def test_the_cap_and_a_phase_missing_everywhere_leave_the_window_unjudged() -> None:
    u, y = periodic()
    flags = [None] * (3 * P)
    y2 = y.copy()
    for k in (P, P + 1, P + 2, P + 3, P + 4):
        y2[k, 0] = np.nan
        flags[k] = "gap: no height sample"
    rec = run(u, y2, flags, frac=0.25)  # cap: 4 of a 16-sample window
    assert rec.reason is not None
    assert "5 unusable height sample(s), more than the 4" in rec.reason
    y3 = y.copy()
    y3[[3, P + 3, 2 * P + 3], 1] = np.nan
    flags = [None] * (3 * P)
    for k in (3, P + 3, 2 * P + 3):
        flags[k] = "gap: no temperature sample"
    rec = run(u, y3, flags)
    assert rec.reason is not None
    assert "unusable in every period" in rec.reason
    assert run(u, y2, flags, frac=0.0).reason == "unusable samples (recovery off)"


# --------------------------------------------------------------- against the clean record

N_PERIODS = 30
CFG = MonitorConfig(ts_s=0.8, period_samples=256)  # windows of 512 samples: cap 5 per signal


def replay_with_losses(loss: float, cfg: MonitorConfig, seed: int = 1):
    stamps, u, y = streamfuzz.clean_record(N_PERIODS, 0)
    rng = np.random.default_rng(seed)
    keep = rng.random((len(stamps), 3)) >= loss
    core = OnlineValidator(cfg, [load_model("B")])
    reports = []
    for k in range(len(stamps)):
        t = int(stamps[k])
        if keep[k, 0]:
            reports += core.feed(itf.FLOW_CMD, t, (float(u[k, 0]), float(u[k, 1])))
        if keep[k, 1]:
            reports += core.feed(itf.HEIGHT, t, float(y[k, 0]))
        if keep[k, 2]:
            reports += core.feed(itf.TEMPERATURE, t, float(y[k, 1]))
    return reports


@pytest.fixture(scope="module")
def clean():
    return {r.start_ns: r for r in replay_with_losses(0.0, CFG) if r.judged}


@pytest.mark.parametrize(
    ("loss", "cap", "judged_min"),
    [(1e-3, 0.01, 0.99), (1e-2, 0.03, 0.95)],
)
def test_lost_messages_are_recovered_and_beta_stays_within_2_percent(clean, loss, cap, judged_min):
    reports = replay_with_losses(loss, dataclasses.replace(CFG, max_recovered_fraction=cap))
    comparable = [r for r in reports if r.start_ns in clean]
    judged = [r for r in comparable if r.judged]
    assert len(judged) >= judged_min * len(comparable)
    assert any("recovered" in r.data_quality for r in judged)
    for r in judged:
        assert r.beta == pytest.approx(clean[r.start_ns].beta, rel=0.02)
    assert not any(r.invalidated for r in judged)


def test_losses_beyond_the_cap_stay_unjudged_with_the_reason(clean) -> None:
    reports = replay_with_losses(0.05, CFG)  # 5 % lost: about 25 per 512 samples
    comparable = [r for r in reports if r.start_ns in clean]
    assert not any(r.judged for r in comparable)
    assert all("can be recovered per signal" in r.data_quality for r in comparable)
