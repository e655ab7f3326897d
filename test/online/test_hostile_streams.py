"""Hostile and broken input to the online validator (the node's and replay's one code path).

A short bounded version of ``bench/fuzz_streams.py``: random hostile stretches (random
stamps, NaN and inf, huge values, bursts, silences, clock jumps both ways, malformed values)
in clean rig data. The validator must not die, must not judge a window that overlaps the
hostile stretch, and must judge again (Model B back to OK) once good data return. The
reference is the injected stretch itself (``streamfuzz.check``).
"""

from __future__ import annotations

import math
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tools import streamfuzz
from twotank_validation.core.model import load_model
from twotank_validation.errors import DatumError
from twotank_validation.online import MonitorConfig, OnlineValidator

MODELS = [load_model("A"), load_model("B")]


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_hostile_stretches_never_kill_or_fool_the_validator(seed):
    result = streamfuzz.run(seed, MODELS)
    assert result.violations == [], (result.kinds, result.violations)


def _clean(core, t0_ns, n, ts_ns=800_000_000):
    reports = []
    for k in range(n):
        t = t0_ns + k * ts_ns
        reports += core.feed("flow_cmd", t, (0.4, 0.4))
        reports += core.feed("height", t, 0.47)
        reports += core.feed("temperature", t, 0.5)
    return reports


def test_far_future_stamp_is_a_clock_jump_not_a_billion_gaps():
    core = OnlineValidator(MonitorConfig(ts_s=0.8, period_samples=256), [MODELS[1]])
    # (the aligner fits its grid's phase to the first 64 stamps per output: clean stretches
    # here are longer than that, so the grid is set when the hostile stamp comes)
    _clean(core, 0, 100)
    start = time.perf_counter()
    core.feed("height", 2**62, 0.47)  # one bogus stamp, 146 years ahead
    core.feed("flow_cmd", 2**62, (0.4, 0.4))
    _clean(core, 100 * 800_000_000, 100)  # and the real clock again
    assert time.perf_counter() - start < 1.0
    assert core.counters().clock_resets >= 2
    assert core.counters().missing < 100


def test_far_future_command_does_not_block_later_commands():
    core = OnlineValidator(MonitorConfig(ts_s=0.8, period_samples=256), [MODELS[1]])
    _clean(core, 0, 100)
    core.feed("flow_cmd", 2**60, (0.4, 0.4))
    _clean(core, 100 * 800_000_000, 10)
    assert core._aligner.last_command_ns == 109 * 800_000_000  # white-box: the aligner inside


def test_malformed_values_are_clear_errors_and_the_validator_goes_on():
    core = OnlineValidator(MonitorConfig(ts_s=0.8, period_samples=256), [MODELS[1]])
    with pytest.raises(DatumError, match="not a number"):
        core.feed("height", 0, "0.47 m")
    with pytest.raises(DatumError, match="2 values"):
        core.feed("flow_cmd", 0, (1.0, 2.0, 3.0))
    with pytest.raises(DatumError, match="unknown topic 'pressure'"):
        core.feed("pressure", 0, 1.0)
    _clean(core, 0, 80)  # the first 64 per output fix the grid's phase, then all come out
    assert core.samples_seen >= 78


@pytest.mark.parametrize("value", [1e300, -1e12, math.inf, math.nan])
def test_implausible_values_are_flagged_not_judged(value):
    stamps, u, y = streamfuzz.clean_record(4, 0)
    strict = MonitorConfig(ts_s=0.8, period_samples=256, max_recovered_fraction=0.0)
    core = OnlineValidator(strict, [MODELS[1]])
    reports = []
    for k in range(stamps.size):
        t = int(stamps[k])
        reports += core.feed("flow_cmd", t, (float(u[k, 0]), float(u[k, 1])))
        reports += core.feed("height", t, value if k == 700 else float(y[k, 0]))
        reports += core.feed("temperature", t, float(y[k, 1]))
    assert reports
    assert not any(r.judged for r in reports if r.start_ns <= stamps[700] <= r.end_ns)
    assert core.counters().non_finite == 1
