"""A sensor at an integer fraction of the command rate is validated at the rate it supports.

References: the clean record decimated by hand (every other sample of every signal) and
validated directly with ``make_datum`` + ``validate`` at twice the sample period; the
aligner's decimated samples are that record, bit for bit, and so are the judged β.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from tools import streamfuzz
from tools.events import arrival_order
from twotank_validation import bags, cli, online, replay
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model
from twotank_validation.core.validate import validate
from twotank_validation.online import COMMAND, MonitorConfig, OnlineValidator
from twotank_validation.online.infer import supported_rate
from twotank_validation.online.streams import RigUnits
from twotank_validation.sim import scenario as sc

NAMES = ("height", "temperature")
TS_NS = 800_000_000


def half_rate_events(stamps, u, y, rng, *, jitter_ns=0, every=2):
    """Commands and height every step, temperature every ``every``-th step; jittered stamps."""
    n = len(stamps)
    kinds, st_, vals = [], [], []
    for kind, values, keep in (
        (COMMAND, u, np.ones(n, bool)),
        (0, y[:, :1], np.ones(n, bool)),
        (1, y[:, 1:], np.arange(n) % every == 0),
    ):
        idx = np.flatnonzero(keep)
        kinds.append(np.full(len(idx), kind))
        st_.append(stamps[idx] + rng.integers(-jitter_ns, jitter_ns + 1, len(idx)))
        v = np.full((len(idx), 2), np.nan)
        v[:, : values.shape[1]] = values[idx]
        vals.append(v)
    return arrival_order(np.concatenate(kinds), np.concatenate(st_), np.concatenate(vals))


@pytest.mark.parametrize(("every", "jitter"), [(2, 0), (2, 0.1), (3, 0.1), (2, 0.3)])
def test_decimated_samples_are_every_other_sample_of_the_record(every, jitter) -> None:
    stamps, u, y = streamfuzz.clean_record(2, 1)
    rng = np.random.default_rng(every)
    k, s, v = half_rate_events(stamps, u, y, rng, jitter_ns=round(jitter * TS_NS), every=every)
    al = online.SampleAligner(
        every * 0.8, 2, NAMES, oversampling=(every, every, 1), jitter_fraction=0.45
    )
    got = []
    for p in al.push_events(k, s, v):
        got.extend(p.samples() if isinstance(p, online.SampleBlock) else [p])
    want_u, want_y = u[::every], y[::every]
    assert len(got) >= len(want_u) - 2
    assert all(g.flag is None for g in got)
    np.testing.assert_array_equal(np.array([g.u for g in got]), want_u[: len(got)])
    np.testing.assert_array_equal(np.array([g.y for g in got]), want_y[: len(got)])
    # the height messages between the emitted samples were dropped as in-between ticks
    assert (every - 1) * (len(got) - 1) <= al.counters.decimated <= (every - 1) * len(stamps)
    assert al.counters.off_grid == al.counters.missing == al.counters.duplicates == 0


def test_beta_at_the_supported_rate_equals_the_decimated_record() -> None:
    stamps, u, y = streamfuzz.clean_record(6, 2)
    cfg = MonitorConfig(ts_s=1.6, period_samples=128)
    model = load_model("B")
    core = OnlineValidator(cfg, [model], oversampling={"flow_cmd": 2, "height": 2})
    reports = core.feed_many(
        *half_rate_events(stamps, u, y, np.random.default_rng(0), jitter_ns=round(0.1 * TS_NS))
    )
    judged = [r for r in reports if r.judged]
    assert len(judged) >= 2
    ud, yd = u[::2], y[::2]
    n = cfg.window_samples
    for r in judged:
        # the window's first sample on the decimated record
        first = round((r.start_ns - stamps[0]) / (2 * TS_NS))
        datum = make_datum(
            ud[first : first + n], yd[first : first + n], ts_s=1.6, period_samples=128
        )
        assert r.beta == validate(datum, model, method=cfg.method).beta


def test_supported_rate_is_the_least_common_multiple() -> None:
    r = supported_rate(0.1, {"height": 0.1, "temperature": 0.2}, "flow_cmd")
    assert (r.factor, r.oversampling) == (2, {"flow_cmd": 2, "height": 2, "temperature": 1})
    r = supported_rate(0.1, {"height": 0.2, "temperature": 0.3}, "flow_cmd")
    assert (r.factor, r.oversampling) == (6, {"flow_cmd": 6, "height": 3, "temperature": 2})
    r = supported_rate(0.1, {"height": 0.05, "temperature": 0.137}, "flow_cmd")
    assert (r.factor, r.oversampling, r.odd) == (
        1,
        {"flow_cmd": 1, "height": 2},
        {"temperature": 0.137},
    )


def half_rate_bag(path, periods=6.0, metadata=False):
    scen = dataclasses.replace(
        sc.load_scenario("nominal"), ts_s=0.8, period_samples=256, duration_s=periods * 204.8
    )
    stamps, u, y = sc.simulate_scenario(scen)
    units = RigUnits()
    with bags.BagWriter(path, "mcap") as bag:
        for topic, msgtype in bags.expected_types().items():
            bag.add_topic(topic, msgtype[0])
        if metadata:
            bag.set_custom_data("ts_s", "0.8")
            bag.set_custom_data("period_samples", "256")
        for k, t in enumerate(stamps.tolist()):
            bag.write("flow_cmd", t, bags.flow_command(t, *u[k]))
            bag.write("height", t + 1, bags.fluid_pressure(t, y[k, 0], units))
            if k % 2 == 0:
                bag.write("temperature", t + 2, bags.temperature_msg(t, y[k, 1], units))
    return path, stamps, u, y


@pytest.mark.parametrize("metadata", [False, True])
def test_replay_infers_the_supported_rate_and_judges(tmp_path, metadata) -> None:
    path, *_ = half_rate_bag(tmp_path / "half", metadata=metadata)
    code = cli.main(["validate", str(path), "--json", str(tmp_path / "out.json"), "--model", "B"])
    out = json.loads((tmp_path / "out.json").read_text())
    assert code == 0
    timing = out["timing"]
    assert timing["ts_s"] == pytest.approx(1.6)
    assert timing["period_samples"] == 128
    assert timing["oversampling"] == {"flow_cmd": 2, "height": 2}
    model = out["models"]["B"]
    assert model["judged"] >= 2
    assert model["not_judged_reasons"] == {} or all(
        "settling" in why for why in model["not_judged_reasons"]
    )


def test_the_command_rate_given_by_option_is_contradicted(tmp_path, capsys) -> None:
    path, *_ = half_rate_bag(tmp_path / "half", periods=5)
    args = ["--json", str(tmp_path / "out.json"), "--ts", "0.8", "--period", "256"]
    code = cli.main(["validate", str(path), *args])
    captured = capsys.readouterr()
    assert "pass --ts 1.6" in captured.err
    assert "temperature every 1.6 s" in captured.err
    assert code == 4  # nothing judged: every other temperature sample is a gap
    timing = json.loads((tmp_path / "out.json").read_text())["timing"]
    assert any("pass --ts 1.6" in c for c in timing["conflicts"])


def test_replay_config_carries_the_decimation(tmp_path) -> None:
    path, stamps, u, y = half_rate_bag(tmp_path / "half")
    timing = replay.resolve_timing(path)
    cfg = replay.ReplayConfig(
        monitor=MonitorConfig(ts_s=timing.ts_s, period_samples=timing.period_samples),
        oversampling=timing.oversampling,
    )
    res = replay.replay_bag(path, [load_model("B")], cfg)
    judged = [r for r in res.reports if r.judged]
    assert len(judged) >= 2
    assert res.counters["decimated"] > 0
    assert res.counters["missing"] == res.counters["off_grid"] == 0
    # the judged β is the decimated record's, validated directly
    ud, yd = u[::2], y[::2]
    n = cfg.monitor.window_samples
    for r in judged:
        first = round((r.start_ns - stamps[0]) / 1.6e9)
        datum = make_datum(
            ud[first : first + n], yd[first : first + n], ts_s=1.6, period_samples=128
        )
        want = validate(datum, load_model("B"), method=cfg.monitor.method).beta
        assert r.beta == pytest.approx(want, rel=1e-12)  # the bag's units: an ulp or two
