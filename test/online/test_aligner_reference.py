"""The sample aligner against its original, per-event numpy implementation (kept here verbatim).

The aligner was rewritten for speed (plain Python state, no per-event arrays). Its behaviour
must not change: these tests drive the rewritten aligner and the original one, copied below
from the commit before the rewrite, with the same streams of events (jitter, off-grid stamps,
NaN/inf, duplicates, out-of-order stamps, gaps, clock jumps backwards, non-finite commands) and
require identical samples (index, stamp, u, y, flag), counters and state after every event.

Rules added to the aligner later for hostile input (far-future stamps are clock jumps, bogus
future command stamps are dropped, magnitudes above 1e6 are flagged, the grid re-anchors after
a long run of off-grid stamps) are outside what the original did; the streams compared with it
stay clear of them, and the last tests hold the batch path to the current per-event rules.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twotank_validation import online
from twotank_validation.defaults import NS_PER_S
from twotank_validation.errors import DatumError

# ------------------------------------------------------------ the original (reference) aligner


@dataclass
class _Pending:
    y: np.ndarray
    seen: np.ndarray
    flag: str | None = None


class ReferenceAligner:
    """Put stamped commands and per-channel measurements on the sample grid.

    Args:
        ts_s: sample period (s).
        n_inputs: number of command entries.
        output_names: measurement channel names (order of ``y``).
        jitter_fraction: accepted distance of a measurement stamp from its grid point, as a
            fraction of the sample period.
        reset_after_s: a measurement stamped this much before the last finalised sample is
            taken for a clock jump backwards (a restarted recording or simulation) and the
            aligner starts over; later-than-that stragglers are dropped as out of order. A
            live node also resets on a backward jump of its ROS clock.
    """

    def __init__(
        self,
        ts_s: float,
        n_inputs: int,
        output_names: Sequence[str],
        *,
        jitter_fraction: float = 0.25,
        reset_after_s: float = 60.0,
    ) -> None:
        if not (math.isfinite(ts_s) and ts_s > 0):
            raise DatumError(f"sample period must be positive, found {ts_s}")
        self.ts_ns = round(ts_s * NS_PER_S)
        self.n_inputs = n_inputs
        self.output_names = tuple(output_names)
        self.tol_ns = round(jitter_fraction * self.ts_ns)
        self.reset_ns = round(reset_after_s * NS_PER_S)
        self.counters = online.AlignerCounters()
        self._clear()

    def _clear(self) -> None:
        self.t0_ns: int | None = None
        self.next_index = 0
        self._pending: dict[int, _Pending] = {}
        self._commands: deque[tuple[int, np.ndarray]] = deque()
        self._held = np.full(self.n_inputs, np.nan)
        self.last_command_ns: int | None = None

    def reset(self) -> None:
        """Start over (new grid origin); counters are kept."""
        self._clear()

    def grid_time(self, index: int) -> int:
        """Stamp (ns) of grid index ``index``."""
        assert self.t0_ns is not None
        return self.t0_ns + index * self.ts_ns

    def push_command(self, stamp_ns: int, values: Sequence[float]) -> list[online.Sample]:
        """Add a command (held from ``stamp_ns`` on). Returns samples it completes."""
        u = np.asarray(values, dtype=float)
        if u.shape != (self.n_inputs,):
            raise DatumError(f"command needs {self.n_inputs} values, found shape {u.shape}")
        if self.last_command_ns is not None and stamp_ns <= self.last_command_ns:
            if stamp_ns == self.last_command_ns:
                self.counters.duplicates += 1
            else:
                self.counters.out_of_order += 1
            return []
        if not np.all(np.isfinite(u)):
            self.counters.non_finite += 1
        self._commands.append((stamp_ns, u))
        self.last_command_ns = stamp_ns
        return self._finalise()

    def push_measurement(self, channel: int, stamp_ns: int, value: float) -> list[online.Sample]:
        """Add one measurement of output ``channel``. Returns the samples now complete."""
        if self.t0_ns is None:
            self.t0_ns = stamp_ns
        offset = stamp_ns - self.t0_ns
        k = (offset + self.ts_ns // 2) // self.ts_ns
        if k < self.next_index:
            if stamp_ns < self.grid_time(self.next_index) - self.reset_ns:
                self.counters.clock_resets += 1
                self._clear()
                return self.push_measurement(channel, stamp_ns, value)
            self.counters.out_of_order += 1
            return []
        pend = self._pending.get(k)
        if pend is None:
            pend = _Pending(
                np.full(len(self.output_names), np.nan), np.zeros(len(self.output_names), bool)
            )
            self._pending[k] = pend
        if pend.seen[channel]:
            self.counters.duplicates += 1
            return []
        pend.seen[channel] = True
        if abs(offset - k * self.ts_ns) > self.tol_ns:
            self.counters.off_grid += 1
            pend.flag = pend.flag or (
                f"{self.output_names[channel]} stamp {stamp_ns} ns is off the sample grid by "
                f"{(offset - k * self.ts_ns) / 1e6:.1f} ms"
            )
        if math.isfinite(value):
            pend.y[channel] = value
        else:
            self.counters.non_finite += 1
            pend.flag = pend.flag or f"non-finite {self.output_names[channel]} ({value})"
        return self._finalise()

    def _held_at(self, t_ns: int) -> np.ndarray:
        while self._commands and self._commands[0][0] <= t_ns + self.tol_ns:
            self._held = self._commands.popleft()[1]
        return self._held.copy()

    def _finalise(self) -> list[online.Sample]:
        out: list[online.Sample] = []
        while self._pending:
            k = self.next_index
            newest = max(self._pending)
            pend = self._pending.get(k)
            t_k = self.grid_time(k)
            cmd_known = (
                self.last_command_ns is not None and self.last_command_ns >= t_k - self.tol_ns
            )
            if pend is not None and pend.seen.all() and (cmd_known or newest > k + 1):
                flag = pend.flag
                y = pend.y
            elif newest > k + 1 and (pend is None or not pend.seen.all()):
                # later samples are complete or arriving: this one will not be completed
                self.counters.missing += 1
                missing = [
                    n
                    for n, s in zip(self.output_names, pend.seen if pend else [], strict=False)
                    if not s
                ]
                names = ", ".join(missing) if pend else ", ".join(self.output_names)
                flag = f"gap: no {names} sample at t = {t_k / NS_PER_S:.3f} s"
                y = pend.y if pend else np.full(len(self.output_names), np.nan)
            else:
                break
            u = self._held_at(t_k)
            if flag is None and not np.all(np.isfinite(u)):
                flag = (
                    "no valid valve command yet"
                    if self.last_command_ns is None
                    else "non-finite valve command"
                )
            self._pending.pop(k, None)
            self.next_index += 1
            out.append(online.Sample(k, t_k, u, y, flag))
        return out


# ------------------------------------------------------------------------------- comparison

TS_NS = 100_000_000
NAMES = ("height", "temperature")


def same_samples(got: list[online.Sample], want: list[online.Sample]) -> None:
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        assert (a.index, a.stamp_ns, a.flag) == (b.index, b.stamp_ns, b.flag)
        assert a.u.dtype == b.u.dtype == np.float64
        assert a.y.dtype == b.y.dtype == np.float64
        np.testing.assert_array_equal(a.u, b.u)  # NaN == NaN here
        np.testing.assert_array_equal(a.y, b.y)


def run_both(events, *, ts_s: float = 0.1, reset_after_s: float = 60.0) -> int:
    """Feed ``events`` (("cmd", t, (hot, cold)) | (channel, t, value)) to both aligners."""
    new = online.SampleAligner(
        ts_s, 2, NAMES, reset_after_s=reset_after_s, phase_fit=0, jitter_fraction=0.25
    )
    ref = ReferenceAligner(ts_s, 2, NAMES, reset_after_s=reset_after_s)
    n = 0
    for kind, t, value in events:
        if kind == "cmd":
            got, want = new.push_command(t, value), ref.push_command(t, value)
        else:
            got, want = new.push_measurement(kind, t, value), ref.push_measurement(kind, t, value)
        same_samples(got, want)
        assert new.counters == ref.counters
        assert (new.next_index, new.t0_ns, new.last_command_ns) == (
            ref.next_index,
            ref.t0_ns,
            ref.last_command_ns,
        )
        n += len(got)
    return n


def random_events(rng: np.random.Generator, n_samples: int) -> list:
    """A stream with every kind of bad input, at rates that make each of them common."""
    events: list = []
    k = 0
    for _ in range(n_samples):
        r = rng.random()
        if r < 0.03:
            k += int(rng.integers(2, 6))  # gap
        elif r < 0.05:
            k -= int(rng.integers(1, 4))  # stragglers / out of order
        elif r < 0.055:
            k -= int(rng.integers(590, 800))  # clock jumped back (about 60 s and more)
        else:
            k += 1
        base = k * TS_NS
        for kind in rng.permutation(3):
            if rng.random() < 0.03:
                continue  # this message is lost
            jit = rng.choice(
                [0, int(rng.integers(-20_000_000, 20_000_000)), 25_000_000, -25_000_001, 40_000_000]
            )
            t = int(base + jit)
            if kind == 2:
                val = rng.choice([0.4, math.nan, math.inf]) if rng.random() < 0.05 else 0.4
                u = (float(rng.random()), float(val))
                events.append(("cmd", max(t, 0) if rng.random() < 0.9 else t - TS_NS, u))
            else:
                v = float(rng.normal())
                if rng.random() < 0.04:
                    v = float(rng.choice([math.nan, math.inf, -math.inf]))
                events.append((int(kind), t, v))
            if rng.random() < 0.04:
                events.append(events[-1])  # duplicate
    return events


@pytest.mark.parametrize("seed", range(8))
def test_rewritten_aligner_equals_the_original_on_messy_streams(seed: int) -> None:
    rng = np.random.default_rng(seed)
    assert run_both(random_events(rng, 1500)) > 500


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["cmd", 0, 1]),
            st.integers(-3, 40),  # grid index
            st.sampled_from([0, 1, -1, 24_999_999, 25_000_000, 25_000_001, -30_000_000]),
            st.sampled_from([0.5, -1.25, math.nan, math.inf]),
        ),
        max_size=80,
    )
)
def test_rewritten_aligner_equals_the_original_on_arbitrary_events(events) -> None:
    stream = [
        (kind, k * TS_NS + jit, (v, 0.25) if kind == "cmd" else v) for kind, k, jit, v in events
    ]
    run_both(stream, reset_after_s=1.0)


def test_command_value_types_convert_as_before() -> None:
    """Lists, tuples, numpy rows, numpy scalars, ints: the same held values; bad shapes raise."""
    for value in ([0.5, 0.25], (1, 2), np.array([0.5, 0.25]), (np.float32(0.1), 0.2), [True, 0.0]):
        events = [("cmd", 0, value), (0, 0, 1.0), (1, 0, 2.0), (0, TS_NS, 1.0), (1, TS_NS, 2.0)]
        events.append(("cmd", TS_NS, value))
        assert run_both(events) == 2
    for bad in ([0.5], [[0.5, 0.25]], 0.5):
        with pytest.raises(DatumError):
            online.SampleAligner(0.1, 2, NAMES).push_command(0, bad)


# ---------------------------------------------------------------------- batches (push_events)

KIND = {"cmd": online.COMMAND, 0: 0, 1: 1}


def expand(pieces) -> list[online.Sample]:
    out: list[online.Sample] = []
    for p in pieces:
        out.extend(p.samples() if isinstance(p, online.SampleBlock) else [p])
    return out


def as_arrays(events):
    kinds = np.array([KIND[e[0]] for e in events], dtype=np.int8)
    stamps = np.array([e[1] for e in events], dtype=np.int64)
    values = np.full((len(events), 2), np.nan)
    for i, (kind, _, v) in enumerate(events):
        values[i] = v if kind == "cmd" else (v, np.nan)
    return kinds, stamps, values


def run_batched(events, rng: np.random.Generator, *, ts_s: float = 0.1, jitter=0.25) -> int:
    """push_events on random splits of ``events`` == the reference aligner event by event."""
    new = online.SampleAligner(ts_s, 2, NAMES, jitter_fraction=jitter, phase_fit=0)
    ref = ReferenceAligner(ts_s, 2, NAMES, jitter_fraction=jitter)
    kinds, stamps, values = as_arrays(events)
    cuts = np.sort(
        rng.choice(np.arange(1, len(events)), size=min(6, len(events) - 1), replace=False)
    )
    got: list[online.Sample] = []
    blocks = 0
    for a, b in zip([0, *cuts.tolist()], [*cuts.tolist(), len(events)], strict=True):
        pieces = new.push_events(kinds[a:b], stamps[a:b], values[a:b])
        blocks += sum(isinstance(p, online.SampleBlock) for p in pieces)
        got.extend(expand(pieces))
    want: list[online.Sample] = []
    for kind, t, v in events:
        want.extend(ref.push_command(t, v) if kind == "cmd" else ref.push_measurement(kind, t, v))
    same_samples(got, want)
    assert new.counters == ref.counters
    assert (new.next_index, new.t0_ns, new.last_command_ns) == (
        ref.next_index,
        ref.t0_ns,
        ref.last_command_ns,
    )
    # the state left behind matters: one more sample event by event must agree too
    t_next = (max(e[1] for e in events) // TS_NS + 3) * TS_NS
    tail = [("cmd", t_next, (0.1, 0.2)), (0, t_next, 1.0), (1, t_next, 2.0)]
    tail += [
        ("cmd", t_next + TS_NS, (0.3, 0.4)),
        (0, t_next + TS_NS, 1.0),
        (1, t_next + TS_NS, 2.0),
    ]
    for kind, t, v in tail:
        if kind == "cmd":
            same_samples(new.push_command(t, v), ref.push_command(t, v))
        else:
            same_samples(new.push_measurement(kind, t, v), ref.push_measurement(kind, t, v))
    assert new.counters == ref.counters
    return blocks


def regular_events(rng: np.random.Generator, n_samples: int, *, messy: float) -> list:
    """Long regular stretches (group order, command offset and jitter fixed or varying per
    stretch, at and around the tolerance), with bad events sprinkled in at rate ``messy``."""
    tol = 25_000_000
    cmd_offsets = [0, 3_000_000, -tol, -tol - 1, tol, tol + 1, -10_000_000, 60_000_000, 75_000_001]
    k = int(rng.integers(0, 3))
    events: list = [(0, k * TS_NS, 0.0)]  # the first measurement sets the grid origin
    order = list(rng.permutation(np.array(["cmd", 0, 1], dtype=object)))
    off = 0
    for _ in range(n_samples):
        if rng.random() < 0.02:
            order = list(rng.permutation(np.array(["cmd", 0, 1], dtype=object)))
            off = int(rng.choice(cmd_offsets))
        t = k * TS_NS
        for entry in order:
            kind = entry if entry == "cmd" else int(entry)
            if kind == "cmd":
                v = (float(rng.random()), 0.5)
                if rng.random() < messy:
                    v = (math.nan, 0.5)
                events.append(("cmd", t + off, v))
            else:
                jit = int(rng.choice([0, 1_000_000, -tol, tol, -4_000_000]))
                if rng.random() < messy:
                    jit = int(rng.choice([tol + 1, -tol - 1, 49_000_000]))
                v = float(rng.normal()) if rng.random() >= messy else math.nan
                events.append((kind, t + jit, v))
            if rng.random() < messy:
                events.append(events[-1])  # duplicate
            if rng.random() < messy / 2:
                events.pop()  # lost
        k += 1 if rng.random() >= messy else int(rng.choice([-2, 2, 3, -700]))
    return events


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("messy", [0.0, 0.002, 0.02])
def test_push_events_equals_the_original_event_by_event(seed: int, messy: float) -> None:
    rng = np.random.default_rng(seed)
    blocks = run_batched(regular_events(rng, 1200, messy=messy), rng)
    if messy == 0.0:
        assert blocks >= 1  # the batch path was taken


@pytest.mark.parametrize("seed", range(4))
def test_push_events_on_messy_streams(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    run_batched(random_events(rng, 1500), rng)


def test_push_events_command_late_and_missing_at_start() -> None:
    """Commands stamped after their grid point (held from the next sample on), the first
    samples without any command yet: flags and held values as event by event."""
    rng = np.random.default_rng(7)
    for off in (26_000_000, 74_000_000, 75_000_000, 99_000_000):
        events = []
        for k in range(60):
            t = k * TS_NS
            events += [(0, t, 1.0), (1, t, 2.0), ("cmd", t + off, (k / 10, 0.5))]
        run_batched(events, rng)
    events = [(0, 0, 1.0), (1, 0, 2.0)]  # no command at all for the first sample
    for k in range(1, 60):
        t = k * TS_NS
        events += [("cmd", t, (math.nan, 0.5) if k < 5 else (0.1, 0.5)), (0, t, 1.0), (1, t, 2.0)]
    run_batched(events, rng)


# ------------------------------------------- batches against the current per-event rules


def test_push_events_follows_the_hostile_input_rules() -> None:
    """Later rules of the per-event path (far-future stamps are clock jumps, bogus future
    command stamps are dropped, implausible magnitudes are flagged, the grid re-anchors after
    a run of off-grid stamps) apply in batches too: push_events on random splits gives the
    samples, counters and state of the same events pushed one by one."""
    rng = np.random.default_rng(3)
    events: list = [(0, 0, 0.0)]
    k = 0
    for stretch in range(40):
        kind = stretch % 5
        for _ in range(int(rng.integers(30, 90))):
            k += 1
            t = k * TS_NS
            off = 40_000_000 if kind == 1 else 0  # a long run off the grid: re-anchor
            big = 1e7 if kind == 2 and rng.random() < 0.3 else 0.5  # implausible values
            events += [("cmd", t, (0.3, big)), (0, t + off, big), (1, t + off, 0.25)]
        if kind == 3:
            events.append((0, (k + 50_000) * TS_NS, 0.5))  # far future: a clock jump
        if kind == 4:
            events.append(("cmd", (k + 50_000) * TS_NS, (0.1, 0.1)))  # bogus future command
    assert any(abs(e[2] if e[0] != "cmd" else e[2][1]) > 1e6 for e in events)
    new = online.SampleAligner(0.1, 2, NAMES, jitter_fraction=0.25)
    one = online.SampleAligner(0.1, 2, NAMES, jitter_fraction=0.25)
    kinds, stamps, values = as_arrays(events)
    cuts = np.sort(rng.choice(np.arange(1, len(events)), size=8, replace=False)).tolist()
    got: list[online.Sample] = []
    blocks = 0
    for a, b in zip([0, *cuts], [*cuts, len(events)], strict=True):
        pieces = new.push_events(kinds[a:b], stamps[a:b], values[a:b])
        blocks += sum(isinstance(p, online.SampleBlock) for p in pieces)
        got.extend(expand(pieces))
    want: list[online.Sample] = []
    for kind, t, v in events:
        want.extend(one.push_command(t, v) if kind == "cmd" else one.push_measurement(kind, t, v))
    same_samples(got, want)
    assert new.counters == one.counters
    assert (new.next_index, new.t0_ns, new.last_command_ns) == (
        one.next_index,
        one.t0_ns,
        one.last_command_ns,
    )
    assert blocks >= 10
    assert one.counters.clock_resets >= 8  # the jumps and re-anchors happened
    assert any(s.flag and "implausible" in s.flag for s in want)


@pytest.mark.parametrize("seed", range(6))
def test_feed_many_equals_feed_on_hostile_streams(seed: int) -> None:
    """streamfuzz's hostile stretches (NaN, inf, huge values, random and backward stamps,
    clock resets, bursts, duplicates, silences) in clean rig data: feed_many on random
    batches reports exactly what feed reports event by event."""
    from tools import streamfuzz  # noqa: PLC0415
    from twotank_validation.core.model import load_model  # noqa: PLC0415

    rng = np.random.default_rng(seed)
    stamps, u, y = streamfuzz.clean_record(9, seed % 4)
    period_ns = streamfuzz.CONFIG.period_samples * round(streamfuzz.CONFIG.ts_s * 1e9)
    lo = 3 * period_ns + int(rng.integers(0, period_ns))
    events, _ = streamfuzz.hostile_events(
        rng, streamfuzz._events(stamps, u, y), (lo, lo + period_ns)
    )
    events = [e for e in events if not isinstance(e[2], str) and len(np.atleast_1d(e[2])) <= 2]
    models = [load_model("B")]
    one = online.OnlineValidator(streamfuzz.CONFIG, models)
    many = online.OnlineValidator(streamfuzz.CONFIG, models)
    want = [rep for s, t, v in events for rep in one.feed(s, t, v)]
    kinds = np.array([online.STREAM_KINDS[s] for s, _, _ in events], dtype=np.int8)
    stamps_ = np.array([t for _, t, _ in events], dtype=np.int64)
    values = np.array([v if s == "flow_cmd" else (v, np.nan) for s, _, v in events], float)
    cuts = np.sort(rng.choice(np.arange(1, len(events)), size=10, replace=False)).tolist()
    got = []
    for a, b in zip([0, *cuts], [*cuts, len(events)], strict=True):
        got += many.feed_many(kinds[a:b], stamps_[a:b], values[a:b])
    assert len(got) == len(want) >= 6
    for x, z in zip(got, want, strict=True):
        assert (x.model, x.start_ns, x.end_ns, x.judged, x.data_quality, x.alarm) == (
            z.model,
            z.start_ns,
            z.end_ns,
            z.judged,
            z.data_quality,
            z.alarm,
        )
        assert x.beta == z.beta or (math.isnan(x.beta) and math.isnan(z.beta))
    assert many.counters() == one.counters()
