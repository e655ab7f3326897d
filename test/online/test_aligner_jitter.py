"""Stamp jitter: the aligner fits the sender's grid to the stamps and recovers the record.

Reference: the clean record itself. A sender that samples on its tick and stamps the message
with jitter (a receive or log time) delivers the exact values; aligned to the fitted grid they
must be the clean record, bit for bit, whatever the first stamp's own jitter, for jitter up to
about 0.35 of a step (the default tolerance is 0.45; the phase is a mean of 64 stamps per
output, whose error takes the rest of the margin). Grid stamps differ from the sender's ticks
by that error alone.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tools import streamfuzz
from tools.events import arrival_order
from twotank_validation import online
from twotank_validation.core.model import load_model
from twotank_validation.online import COMMAND, MonitorConfig, OnlineValidator

NAMES = ("height", "temperature")
TS_NS = 800_000_000  # streamfuzz's record: Ts 0.8 s


def jittered_events(stamps, u, y, rng, jitter_ns, *, first_jitter=None, phase_ns=0):
    """Arrival-ordered (kinds, stamps, values): each topic's stamps jittered independently."""
    n = len(stamps)
    kinds, st_, vals = [], [], []
    for kind, values in ((COMMAND, u), (0, y[:, :1]), (1, y[:, 1:])):
        jit = rng.integers(-jitter_ns, jitter_ns + 1, n)
        if first_jitter is not None:
            jit[0] = first_jitter
        kinds.append(np.full(n, kind))
        st_.append(stamps + phase_ns + jit)
        v = np.full((n, 2), np.nan)
        v[:, : values.shape[1]] = values
        vals.append(v)
    return arrival_order(np.concatenate(kinds), np.concatenate(st_), np.concatenate(vals))


def expand(pieces):
    out = []
    for p in pieces:
        out.extend(p.samples() if isinstance(p, online.SampleBlock) else [p])
    return out


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    frac=st.sampled_from([0.1, 0.2, 0.3, 0.35]),
    first=st.sampled_from([None, -1.0, 1.0]),
    phase=st.integers(-TS_NS // 2 + 1, TS_NS // 2 - 1),
)
def test_jittered_stamps_give_the_clean_record(seed, frac, first, phase) -> None:
    stamps, u, y = streamfuzz.clean_record(2, seed % 7)
    rng = np.random.default_rng(seed)
    jitter = round(frac * TS_NS)
    first_jitter = None if first is None else round(first * jitter)  # the worst first stamp
    k, s, v = jittered_events(stamps, u, y, rng, jitter, first_jitter=first_jitter, phase_ns=phase)
    al = online.SampleAligner(0.8, 2, NAMES)
    got = expand(al.push_events(k, s, v))
    assert len(got) >= len(stamps) - 2  # the last sample or two wait for later messages
    assert all(g.flag is None for g in got)
    idx = np.array([g.index for g in got])
    np.testing.assert_array_equal(idx, np.arange(len(got)))
    np.testing.assert_array_equal(np.array([g.u for g in got]), u[: len(got)])
    np.testing.assert_array_equal(np.array([g.y for g in got]), y[: len(got)])
    # the fitted grid is the sender's, up to the error of a mean of 2 x 64 uniform stamps
    err = np.array([g.stamp_ns for g in got]) - (stamps[: len(got)] + phase)
    assert np.ptp(err) == 0
    assert abs(int(err[0])) < 5 * jitter / np.sqrt(3 * 128) + 1
    assert al.counters.off_grid == al.counters.duplicates == al.counters.missing == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_batch_path_equals_event_by_event_under_jitter(seed) -> None:
    stamps, u, y = streamfuzz.clean_record(2, seed)
    rng = np.random.default_rng(seed)
    k, s, v = jittered_events(stamps, u, y, rng, round(0.3 * TS_NS))
    # some lost and duplicated messages as well
    keep = rng.random(len(k)) > 0.01
    k, s, v = k[keep], s[keep], v[keep]
    batch = online.SampleAligner(0.8, 2, NAMES)
    one = online.SampleAligner(0.8, 2, NAMES)
    got = expand(batch.push_events(k, s, v))
    want = []
    for kind, t, row in zip(k.tolist(), s.tolist(), v.tolist(), strict=True):
        if kind == COMMAND:
            want += one.push_command(t, row[:2])
        else:
            want += one.push_measurement(kind, t, row[0])
    assert len(got) == len(want) > 0
    for g, w in zip(got, want, strict=True):
        assert (g.index, g.stamp_ns, g.flag) == (w.index, w.stamp_ns, w.flag)
        np.testing.assert_array_equal(g.u, w.u)
        np.testing.assert_array_equal(g.y, w.y)
    assert batch.counters == one.counters


def test_without_phase_fit_a_late_first_stamp_flags_the_early_ones() -> None:
    """The rule the phase fit replaces: the grid at the first stamp (phase_fit=0)."""
    stamps, u, y = streamfuzz.clean_record(1, 0)
    rng = np.random.default_rng(0)
    jitter = round(0.2 * TS_NS)
    k, s, v = jittered_events(stamps, u, y, rng, jitter, first_jitter=jitter)
    old = online.SampleAligner(0.8, 2, NAMES, jitter_fraction=0.25, phase_fit=0)
    new = online.SampleAligner(0.8, 2, NAMES, jitter_fraction=0.25)
    old.push_events(k, s, v)
    new.push_events(k, s, v)
    assert old.counters.off_grid > 0
    assert new.counters.off_grid == 0


def test_online_beta_under_jitter_equals_the_clean_beta() -> None:
    stamps, u, y = streamfuzz.clean_record(5, 3)
    cfg = MonitorConfig(ts_s=0.8, period_samples=256)
    model = load_model("B")

    def judged(k, s, v):
        core = OnlineValidator(cfg, [model])
        return [r for r in core.feed_many(k, s, v) if r.judged]

    clean = judged(*jittered_events(stamps, u, y, np.random.default_rng(0), 0))
    noisy = judged(*jittered_events(stamps, u, y, np.random.default_rng(1), round(0.35 * TS_NS)))
    assert len(clean) == len(noisy) >= 2
    assert [r.beta for r in noisy] == [r.beta for r in clean]
