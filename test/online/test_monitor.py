"""The online validator's core: alarm debouncing, sample alignment, windowing and gates."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tools import streamfuzz
from twotank_validation import online
from twotank_validation.core.model import load_model
from twotank_validation.online import Alarm, AlarmConfig, AlarmState, update_alarm

# ------------------------------------------------------------------ alarm


def run_alarm(verdicts, cfg=None):
    cfg = cfg or AlarmConfig(debounce="count")  # the count rule, by hand
    state, levels = AlarmState(), []
    for v in verdicts:
        if v is None:
            state = update_alarm(state, cfg, judged=False, invalidated=False, beta=math.nan)
        else:
            beta = 1.5 if v else 0.5
            state = update_alarm(state, cfg, judged=True, invalidated=v, beta=beta)
        levels.append(state.level)
    return levels


def test_alarm_sequence_by_hand() -> None:
    ok, w, e, s = Alarm.OK, Alarm.WARN, Alarm.ERROR, Alarm.STALE
    # invalid once -> WARN (beta 1.5 >= 0.8), twice -> ERROR, one valid -> still ERROR,
    # a stale window keeps counters, three valid in a row clear it; after an invalidating
    # window the level returns to OK only through the clear rule's valid windows (WARN until)
    seq = [False, True, True, False, None, False, False, True, False, None, False, False]
    assert run_alarm(seq) == [ok, w, e, e, s, e, ok, w, w, s, w, ok]


def test_latched_alarm_needs_reset() -> None:
    cfg = AlarmConfig(latch=True)
    state = AlarmState()
    for v in [True, True, False, False, False, False]:
        state = update_alarm(state, cfg, judged=True, invalidated=v, beta=1.5 if v else 0.1)
    assert state.level is Alarm.ERROR
    state = online.reset_alarm(state)
    state = update_alarm(state, cfg, judged=True, invalidated=False, beta=0.1)
    assert state.level is Alarm.OK


@given(
    st.lists(st.one_of(st.none(), st.booleans()), max_size=40), st.integers(1, 4), st.integers(1, 4)
)
def test_alarm_matches_reference_definition(verdicts, n_alarm, n_clear) -> None:
    """ERROR iff, looking back over judged windows, the last run of >= n_alarm invalidating
    windows is not followed by >= n_clear valid ones; WARN on an invalidating window, and on a
    valid one while the last invalidating window is not followed by >= n_clear valid ones."""
    cfg = AlarmConfig(alarm_windows=n_alarm, clear_windows=n_clear, debounce="count")
    levels = run_alarm(verdicts, cfg)
    for i, v in enumerate(verdicts):
        if v is None:
            assert levels[i] is Alarm.STALE
            continue
        judged = [x for x in verdicts[: i + 1] if x is not None]
        in_error = False
        run_bad = run_good = 0
        for x in judged:
            run_bad, run_good = (run_bad + 1, 0) if x else (0, run_good + 1)
            if run_bad >= n_alarm:
                in_error = True
            elif in_error and run_good >= n_clear:
                in_error = False
        unsettled = any(judged) and run_good < n_clear
        expected = Alarm.ERROR if in_error else (Alarm.WARN if v or unsettled else Alarm.OK)
        assert levels[i] is expected


# ------------------------------------------------------------------ aligner

TS_NS = 100_000_000


def make_aligner():
    # the grid starts at the first stamp (no phase fit), where these tests place it
    return online.SampleAligner(0.1, 2, ("height", "temperature"), phase_fit=0)


def test_aligner_zero_order_holds_commands_and_matches_grid() -> None:
    al = make_aligner()
    out = []
    out += al.push_command(0, [0.4, 0.4])
    out += al.push_measurement(0, 3_000_000, 0.47)  # 3 ms jitter
    out += al.push_measurement(1, 0, 0.5)
    out += al.push_measurement(0, TS_NS, 0.48)
    out += al.push_measurement(1, TS_NS, 0.51)
    out += al.push_command(TS_NS, [0.5, 0.3])
    assert [s.index for s in out] == [0, 1]
    np.testing.assert_array_equal(out[0].u, [0.4, 0.4])
    np.testing.assert_array_equal(out[1].u, [0.5, 0.3])
    np.testing.assert_array_equal(out[1].y, [0.48, 0.51])
    assert all(s.flag is None for s in out)


def test_aligner_flags_bad_input_without_losing_samples() -> None:
    al = make_aligner()
    out = []
    out += al.push_command(0, [0.4, 0.4])
    for k in range(6):
        t = k * TS_NS
        if k == 2:
            out += al.push_measurement(0, t, float("nan"))
        elif k != 3:  # k = 3: height never arrives (gap)
            out += al.push_measurement(0, t, 0.47)
        out += al.push_measurement(1, t, 0.5)
        out += al.push_measurement(1, t, 0.5)  # duplicate
        out += al.push_command(t, [0.4, 0.4])  # duplicate/old command
    out += al.push_measurement(0, 0, 0.47)  # out of order (already finalised)
    assert [s.index for s in out] == [0, 1, 2, 3, 4, 5]
    assert "non-finite height" in str(out[2].flag)
    assert "gap" in str(out[3].flag)
    assert "height" in str(out[3].flag)
    assert out[4].flag is None
    c = al.counters
    assert c.duplicates >= 6
    assert c.out_of_order >= 1
    assert c.non_finite == 1
    assert c.missing == 1


def test_aligner_restarts_on_clock_jump_backwards() -> None:
    al = make_aligner()
    al.push_command(0, [0.4, 0.4])
    for k in range(700):  # 70 s of data
        al.push_measurement(0, k * TS_NS, 0.47)
        al.push_measurement(1, k * TS_NS, 0.5)
    al.push_measurement(0, 200 * TS_NS, 0.47)  # 50 s late: a straggler, dropped
    assert al.counters.out_of_order == 1
    assert al.counters.clock_resets == 0
    al.push_measurement(0, 0, 0.47)  # 69.8 s back (> 60 s): the clock restarted
    assert al.counters.clock_resets == 1
    assert al.next_index == 0


# ------------------------------------------------------------------ monitor on the rig

# same 204.8 s period, 8x fewer samples; one window per period and the count rule, as these
# tests count windows by period
FAST = online.MonitorConfig(
    ts_s=0.8, period_samples=256, hop_samples=256, alarm=AlarmConfig(debounce="count")
)


def rig_record(n_periods: int = 6, seed: int = 0):
    """The nominal rig at ts 0.8 s, period 256 (``streamfuzz.clean_record``, cached there)."""
    return streamfuzz.clean_record(n_periods, seed)


def models():
    return [load_model("A"), load_model("B")]


def test_monitor_verdicts_on_the_rig() -> None:
    stamps, u, y = rig_record()
    reports = online.monitor_record(stamps, u, y, FAST, models())
    by_model = {m: [r for r in reports if r.model == m] for m in ("A", "B")}
    assert len(by_model["A"]) == 5  # windows end at periods 2..6
    assert not by_model["A"][0].judged
    assert "settling" in by_model["A"][0].data_quality
    assert by_model["A"][0].alarm is Alarm.STALE
    judged_a = [r for r in by_model["A"] if r.judged]
    judged_b = [r for r in by_model["B"] if r.judged]
    assert all(r.invalidated for r in judged_a)
    assert not any(r.invalidated for r in judged_b)
    assert by_model["A"][-1].alarm is Alarm.ERROR
    assert by_model["B"][-1].alarm is Alarm.OK


def test_monitor_equals_offline_validation_bit_for_bit() -> None:
    """A judged window's beta equals validate() on the same samples (one code path)."""
    from twotank_validation.core.datum import make_datum  # noqa: PLC0415
    from twotank_validation.core.validate import validate  # noqa: PLC0415

    stamps, u, y = rig_record()
    reports = online.monitor_record(stamps, u, y, FAST, models())
    last = [r for r in reports if r.model == "B"][-1]
    n = FAST.window_samples
    datum = make_datum(u[-n:], y[-n:], ts_s=0.8, period_samples=256)
    res = validate(datum, load_model("B"))
    assert last.beta == res.beta
    np.testing.assert_array_equal(last.w_min, res.w_min)


def test_monitor_with_the_fast_path_agrees_with_the_closed_form() -> None:
    """method="fast" in the monitor: the same verdicts, beta to 1e-9 of the closed form's,
    and the certified bounds reported (the closed form leaves them NaN)."""
    import dataclasses  # noqa: PLC0415

    stamps, u, y = rig_record()
    auto = online.monitor_record(stamps, u, y, FAST, models())
    fast_cfg = dataclasses.replace(FAST, method="fast")
    quick = online.monitor_record(stamps, u, y, fast_cfg, models())
    assert [(r.model, r.judged, r.invalidated) for r in quick] == [
        (r.model, r.judged, r.invalidated) for r in auto
    ]
    for a, f in zip(auto, quick, strict=True):
        if not a.judged:
            continue
        assert a.solver == "closed_form"
        assert f.solver == "fast"
        assert f.beta == pytest.approx(a.beta, rel=1e-9)
        assert math.isnan(a.beta_lower)
        assert f.beta_lower == f.beta
        assert f.beta_upper == pytest.approx(f.beta, rel=1e-9)


@settings(max_examples=5)
@given(seed=st.integers(0, 2**16))
def test_aligner_path_equals_direct_path_under_shuffled_arrival(seed: int) -> None:
    """Messages of the three streams arriving in any order within a sample, with jitter, give
    the same reports as feeding the aligned record directly."""
    stamps, u, y = rig_record()
    rng = np.random.default_rng(seed)
    al = online.SampleAligner(0.8, 2, ("height", "temperature"))
    mon = online.WindowMonitor(FAST, models())
    live = []
    for k in range(len(stamps)):
        jitter = rng.integers(-50_000_000, 50_000_000, size=3)
        events = [
            ("cmd", int(stamps[k] + abs(jitter[0])) if k else 0, u[k]),
            ("m0", int(stamps[k] + jitter[1]), y[k, 0]),
            ("m1", int(stamps[k] + jitter[2]), y[k, 1]),
        ]
        for i in rng.permutation(3):
            kind, t, val = events[i]
            if kind == "cmd":
                samples = al.push_command(t, val)
            else:
                samples = al.push_measurement(int(kind[1]), t, float(val))
            for s in samples:
                live.extend(mon.push(s))
    offline = online.monitor_record(stamps, u, y, FAST, models())
    # the aligner finalises the last sample only when the next one arrives
    offline = offline[: len(live)]
    assert len(live) == len(offline) >= 8
    for a, b in zip(live, offline, strict=True):
        assert (a.model, a.judged, a.data_quality, a.alarm) == (
            b.model,
            b.judged,
            b.data_quality,
            b.alarm,
        )
        if a.judged:
            assert a.beta == b.beta


def test_monitor_refuses_windows_unfit_to_judge() -> None:
    stamps, u, y = rig_record()
    y_nan = y.copy()
    y_nan[700, 1] = np.nan
    strict = dataclasses.replace(FAST, max_recovered_fraction=0.0)  # no recovery
    reports = online.monitor_record(stamps, u, y_nan, strict, models()[:1])
    affected = [r for r in reports if r.start_ns <= stamps[700] <= r.end_ns]
    assert affected
    assert all(not r.judged and "non-finite" in r.data_quality for r in affected)
    # input changed (excitation switched): not periodic
    u2 = u.copy()
    u2[800:] = u2[800:] * 0.5 + 0.2
    reports = online.monitor_record(stamps, u2, y, FAST, models()[:1])
    assert any("input not periodic" in r.data_quality for r in reports)
    # no excitation at all
    flat = np.tile(u[0], (len(u), 1))
    reports = online.monitor_record(stamps, flat, y, FAST, models()[:1])
    assert all(not r.judged for r in reports)
    assert "too little excitation" in reports[-1].data_quality


def test_monitor_config_rejects_bad_values() -> None:
    with pytest.raises(ValueError, match="period_samples"):
        online.MonitorConfig(period_samples=1)
    with pytest.raises(ValueError, match="alarm_windows"):
        AlarmConfig(alarm_windows=0)


# ------------------------------------------------------------------ batches through the monitor


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_push_block_equals_push_one_by_one(seed: int) -> None:
    """Blocks of any size (crossing period boundaries and the ring's end) give the reports and
    the window data of pushing the same samples one at a time."""
    stamps, u, y = rig_record()
    rng = np.random.default_rng(seed)
    y = y.copy()
    y[rng.integers(0, len(y), 3), 0] = np.nan  # some unusable samples
    flags = [None if np.isfinite(y[k]).all() else "non-finite value" for k in range(len(y))]
    one = online.WindowMonitor(FAST, models())
    many = online.WindowMonitor(FAST, models())
    want, want_windows = [], []
    for k in range(len(stamps)):
        reps = one.push(online.Sample(k, int(stamps[k]), u[k].copy(), y[k].copy(), flags[k]))
        want += reps
        want_windows += [one.last_window() for _ in reps]
    got, got_windows = [], []
    k = 0
    while k < len(stamps):
        m = int(rng.integers(1, 700))
        block = online.SampleBlock(
            k, stamps[k : k + m].copy(), u[k : k + m].copy(), y[k : k + m].copy(), flags[k : k + m]
        )
        got += many.push_block(block, lambda rep: got_windows.append(many.last_window()))
        k += m
    assert len(got) == len(want) >= 8
    for a, b in zip(got, want, strict=True):
        assert (a.model, a.start_ns, a.end_ns, a.judged, a.data_quality, a.alarm) == (
            b.model,
            b.start_ns,
            b.end_ns,
            b.judged,
            b.data_quality,
            b.alarm,
        )
        assert a.beta == b.beta or (math.isnan(a.beta) and math.isnan(b.beta))
    assert len(got_windows) == len(want_windows)
    for ga, wa in zip(got_windows, want_windows, strict=True):
        for x, z in zip(ga, wa, strict=True):
            np.testing.assert_array_equal(x, z)


def test_window_data_in_time_order_across_the_ring_end() -> None:
    """last_window() against the samples pushed, at every phase of the ring buffer."""
    cfg = online.MonitorConfig(ts_s=0.8, period_samples=8, periods_per_window=2, settle_periods=1)
    mon = online.WindowMonitor(cfg, models())
    rows = []
    for k in range(60):
        s = online.Sample(k, k * 800, np.array([k, -k], float), np.array([2 * k, 0.5]), None)
        mon.push(s)
        rows.append(s)
        stamps, u, y = mon.last_window()
        recent = rows[-cfg.window_samples :]
        np.testing.assert_array_equal(stamps, [r.stamp_ns for r in recent])
        np.testing.assert_array_equal(u, [r.u for r in recent])
        np.testing.assert_array_equal(y, [r.y for r in recent])


def test_model_constants_are_ready_before_the_first_window() -> None:
    """The pulse-response moment (leakage bound) is computed when the monitor is built where
    the reports need it (the fast path), so the first window's report does not wait for it;
    the closed form's reports (the tank models under "auto") never need it."""
    ms = [load_model("A"), load_model("B")]
    online.WindowMonitor(dataclasses.replace(FAST, method="fast"), ms)
    for m in ms:
        assert ("pulse_moment", FAST.ts_s) in m.cache
    ms = [load_model("A"), load_model("B")]
    online.WindowMonitor(FAST, ms)
    for m in ms:
        assert ("pulse_moment", FAST.ts_s) not in m.cache


def test_fast_path_kernel_is_loaded_before_the_first_window_and_only_then() -> None:
    """With method="fast" the monitor loads the compiled kernel when it is built (the first
    window does not wait for numba); with "auto" on the tank models (closed form) it never
    loads numba at all. In a fresh interpreter, so nothing else has loaded it."""
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    code = (
        "import sys\n"
        "from twotank_validation.online import window\n"
        "from twotank_validation.core.model import load_model\n"
        "ms = [load_model('A'), load_model('B')]\n"
        "cfg = window.MonitorConfig(ts_s=0.8, period_samples=256, method=sys.argv[1])\n"
        "window.WindowMonitor(cfg, ms)\n"
        "loaded = 'numba' in sys.modules\n"
        "ready = loaded and bool(sys.modules['twotank_validation.core.fast.kernel'].solve_bins"
        ".signatures)\n"
        "print(loaded, ready)\n"
    )
    for method, want in (("fast", "True True"), ("auto", "False False")):
        out = subprocess.run(
            [sys.executable, "-c", code, method], capture_output=True, text=True, check=True
        )
        assert out.stdout.strip() == want, (method, out.stdout, out.stderr[-2000:])


@pytest.mark.parametrize("method", ["auto", "fast", "sdp", "closed_form"])
def test_takes_fast_path_names_validates_route(method: str) -> None:
    """takes_fast_path says "fast" exactly where validate then reports method "fast": the
    tank models (closed form under auto) and a three-block model (fast under auto)."""
    from twotank_validation.core.datum import make_datum  # noqa: PLC0415
    from twotank_validation.core.model import BlockStructure, PlantResponse  # noqa: PLC0415
    from twotank_validation.core.validate import takes_fast_path, validate  # noqa: PLC0415

    rng = np.random.default_rng(2)
    u = rng.normal(size=(512, 2))
    y = rng.normal(size=(512, 2))
    datum = make_datum(u, y, ts_s=0.8, period_samples=256)
    for m in (load_model("A"), load_model("B")):
        resp = m.response(datum.theta, datum.ts_s)
        res = validate(datum, m, method=method, response=resp)
        assert takes_fast_path(resp, method) == (res.method == "fast"), (m.name, res.method)
    blocks = BlockStructure(((1, 1), (2, 1), (1, 1)))
    p = rng.normal(size=(4, blocks.nz + 2, blocks.nv + 4)) + 0j
    p[:, : blocks.nz, : blocks.nv + 2] = 0.0  # z = P13 U: structured, not decoupled
    resp3 = PlantResponse(p, blocks, 2, 2, 2)
    assert takes_fast_path(resp3, "auto")
    assert not takes_fast_path(resp3, "sdp")


def test_alarm_stays_warn_while_the_operating_point_is_unchecked() -> None:
    """By hand: valid windows whose operating point cannot be checked since the model was
    invalidated count towards clearing ERROR, but the level never returns to OK on them."""
    cfg = AlarmConfig(alarm_windows=2, clear_windows=2, debounce="count")
    state, levels = AlarmState(), []
    # (invalidated, unchecked): two invalidating, three valid unchecked, two valid checked
    for inv, unchecked in [(True, False), (True, True)] + [(False, True)] * 3 + [(False, False)]:
        state = update_alarm(
            state, cfg, judged=True, invalidated=inv, beta=1.5 if inv else 0.1, unchecked=unchecked
        )
        levels.append(state.level)
    ok, w, e = Alarm.OK, Alarm.WARN, Alarm.ERROR
    assert levels == [w, e, e, w, w, ok]


def test_a_new_alarm_config_judges_the_windows_after_it() -> None:
    """``set_alarm`` between two windows (a node's run-time parameter): the windows before are
    those of a monitor with the old settings, the ones after those of a monitor that had the
    new settings from the start (the betas untouched; here only WARN depends on it)."""
    stamps, u, y = rig_record()
    new = dataclasses.replace(FAST.alarm, warn_beta=1e-3)
    switched = online.WindowMonitor(FAST, models())
    old_ref = online.WindowMonitor(FAST, models())
    new_ref = online.WindowMonitor(dataclasses.replace(FAST, alarm=new), models())
    half = len(stamps) // 2
    b_alarms: list[tuple[bool, Alarm]] = []  # (after the switch, alarm) of model B
    for k in range(len(stamps)):
        if k == half:
            switched.set_alarm(new)
        s = online.Sample(k, int(stamps[k]), u[k].copy(), y[k].copy(), None)
        got = switched.push(s)
        want_old, want_new = old_ref.push(s), new_ref.push(s)
        want = want_old if k < half else want_new
        assert [(r.model, r.beta, r.alarm) for r in got] == [
            (r.model, r.beta, r.alarm) for r in want
        ]
        b_alarms += [(k >= half, r.alarm) for r in got if r.model == "B" and r.judged]
    # the switch mattered: model B's judged windows are OK before it and WARN after it
    assert {a for after, a in b_alarms if not after} == {Alarm.OK}
    assert {a for after, a in b_alarms if after} == {Alarm.WARN}
    assert switched.config.alarm.warn_beta == 1e-3
