"""Hostile records give a flagged result or a clear error, never a verdict without a reason.

Issue 15, item 6: a model without a noise section, a record without excitation and a record
with a start-up transient. The online path (``OnlineValidator`` -> ``WindowMonitor``) must
carry the core's ``ValidationResult.warnings`` into its window reports (``warnings`` and the
judged window's ``data_quality``), the CLI's JSON and text, and replay's summary; a window not
judged must say why. The reference for the warnings is the core itself: ``make_datum`` and
``validate`` called here on the very samples of each window (``OnlineValidator.last_window``).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import yaml

from tools import streamfuzz
from tools.streamfuzz import transient_record
from twotank_validation import cli, experiment, replay
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import LFTModel, load_model, load_model_document, model_from_dict
from twotank_validation.core.validate import validate
from twotank_validation.errors import ModelError
from twotank_validation.online import MonitorConfig, OnlineValidator, WindowReport
from twotank_validation.online.streams import MEASUREMENTS, STREAM_KINDS
from twotank_validation.online.window import with_warnings
from twotank_validation.sim import rig, simulator

FAST = MonitorConfig(
    ts_s=0.8, period_samples=256, hop_samples=256
)  # the 204.8 s period, 8x fewer samples
MODELS = [load_model("A"), load_model("B")]


def assert_every_verdict_has_a_reason(reports: list[WindowReport]) -> None:
    """No window without a reason: the invariants of item 6, on any stream."""
    for r in reports:
        assert r.data_quality.strip(), r
        if r.judged:
            assert r.data_quality.startswith("ok"), r.data_quality
            for w in r.warnings:
                assert w.strip()
                assert f"; warning: {w}" in r.data_quality
        else:
            assert not r.invalidated
            assert math.isnan(r.beta)
            assert r.warnings == ()
            assert not r.data_quality.startswith("ok"), r.data_quality
        if r.judged and not math.isfinite(r.beta):
            assert r.warnings, f"judged window of {r.model} with beta {r.beta} and no warning"


def run_stream(
    stamps: np.ndarray, u: np.ndarray, y: np.ndarray, config: MonitorConfig, models: list[LFTModel]
) -> list[tuple[WindowReport, np.ndarray, np.ndarray]]:
    """Feed a record as stream events; each report with its window's ``(u, y)`` samples."""
    n = len(stamps)
    kinds = np.tile([STREAM_KINDS["flow_cmd"], *(STREAM_KINDS[s] for s in MEASUREMENTS)], n)
    ts = np.repeat(np.asarray(stamps, dtype=np.int64), 3)
    values = np.zeros((3 * n, 2))
    values[0::3] = u
    values[1::3, 0] = y[:, 0]
    values[2::3, 0] = y[:, 1]
    core = OnlineValidator(config, models)
    out: list[tuple[WindowReport, np.ndarray, np.ndarray]] = []

    def keep(rep: WindowReport) -> None:
        _, wu, wy = core.last_window()
        out.append((rep, wu, wy))

    core.feed_many(kinds, ts, values, on_report=keep)
    return out


def assert_warnings_match_the_core(
    runs: list[tuple[WindowReport, np.ndarray, np.ndarray]],
    config: MonitorConfig,
    models: list[LFTModel],
) -> list[WindowReport]:
    """Every judged window's warnings (and beta) equal ``validate`` on its samples."""
    by_name = {m.name: m for m in models}
    reports = [rep for rep, _, _ in runs]
    assert_every_verdict_has_a_reason(reports)
    for rep, wu, wy in runs:
        if not rep.judged:
            continue
        assert "recovered" not in rep.data_quality  # the samples here are the ones validated
        datum = make_datum(
            wu,
            wy,
            ts_s=config.ts_s,
            period_samples=config.period_samples,
            convention=config.convention,
        )
        res = validate(datum, by_name[rep.model], method=config.method)
        assert rep.warnings == res.warnings
        assert rep.data_quality == with_warnings("ok", res.warnings)
        assert rep.beta == res.beta or (math.isinf(rep.beta) and math.isinf(res.beta))
    return reports


@cache
def still_record(n_periods: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rig at its operating point with the excitation off: the inputs never move."""
    cfg = experiment.ExperimentConfig()
    n = n_periods * FAST.period_samples
    u = np.tile(rig.operating_point(cfg.rig).commands, (n, 1))
    sim = simulator.simulate(cfg.rig, u, FAST.ts_s, seed=0, substeps=16)
    stamps = np.arange(n, dtype=np.int64) * round(FAST.ts_s * 1e9)
    return stamps, sim.commands, sim.measured


def model_b_without(noise_names: set[str]) -> LFTModel:
    doc, _ = load_model_document("B")
    doc = copy.deepcopy(doc)
    doc["noise"] = [ch for ch in doc["noise"] if ch["name"] not in noise_names]
    if not doc["noise"]:
        del doc["noise"]
    return model_from_dict(doc, "test")


# ------------------------------------------------------------------ clean data: nothing moves


def test_clean_rig_windows_have_no_warnings_and_plain_ok() -> None:
    stamps, u, y = streamfuzz.clean_record(6, 0)
    reports = assert_warnings_match_the_core(run_stream(stamps, u, y, FAST, MODELS), FAST, MODELS)
    judged = [r for r in reports if r.judged]
    assert len(judged) == 8  # windows end at periods 2..6, the first settling
    assert all(r.warnings == () and r.data_quality == "ok" for r in judged)


# ------------------------------------------------------------------ start-up transient


@pytest.mark.parametrize("settle_periods", [0, 1])
def test_a_start_up_transient_is_flagged_in_the_judged_windows(settle_periods: int) -> None:
    cfg = dataclasses.replace(FAST, settle_periods=settle_periods)
    stamps, u, y = transient_record(6)
    reports = assert_warnings_match_the_core(run_stream(stamps, u, y, cfg, MODELS), cfg, MODELS)
    first = [r for r in reports if r.judged][:2]  # the first judged window, both models
    assert {r.model for r in first} == {"A", "B"}
    for r in first:
        assert any("transient" in w for w in r.warnings), r.warnings
        assert r.data_quality.startswith("ok; warning: output mean drifts")
    assert [r.warnings for r in reports[-2:]] == [(), ()]  # settled by the end
    if settle_periods == 0:
        # judged from the first sample: the transient invalidates Model B, and says so
        b0 = next(r for r in reports if r.model == "B")
        assert b0.judged
        assert b0.invalidated
        assert b0.warnings


# ------------------------------------------------------------------ no excitation


def test_no_excitation_is_not_judged_and_says_why() -> None:
    stamps, u, y = still_record(4)
    reports = assert_warnings_match_the_core(run_stream(stamps, u, y, FAST, MODELS), FAST, MODELS)
    assert not any(r.judged for r in reports)
    after_settling = [r for r in reports if "settling" not in r.data_quality]
    assert after_settling
    assert all("too little excitation" in r.data_quality for r in after_settling)


def test_no_excitation_judged_anyway_carries_the_cores_warning() -> None:
    """With the excitation gate off (min_excitation_rms = 0) the windows are judged, and
    each says that the inputs do not move, as validate() does on the same samples."""
    cfg = dataclasses.replace(FAST, min_excitation_rms=0.0)
    stamps, u, y = still_record(4)
    reports = assert_warnings_match_the_core(run_stream(stamps, u, y, cfg, MODELS), cfg, MODELS)
    judged = [r for r in reports if r.judged]
    assert len(judged) == 4
    assert all(any("inputs do not move" in w for w in r.warnings) for r in judged)


# ------------------------------------------------------------------ models without noise


def test_a_model_without_noise_is_refused_naming_the_fix() -> None:
    bare = model_b_without({"height_noise", "temperature_noise"})
    assert bare.nw == 0
    with pytest.raises(ModelError) as err:
        OnlineValidator(FAST, [load_model("A"), bare])
    text = str(err.value)
    assert "no noise channels" in text
    assert "add a noise section" in text
    assert bare.name in text


def test_an_output_without_noise_invalidates_with_a_warning_not_silently() -> None:
    """One noise channel left: accepted at start, but β is infinite in every window; the
    invalidated verdict carries the reason (it said only "ok" before)."""
    half = model_b_without({"temperature_noise"})
    stamps, u, y = streamfuzz.clean_record(4, 0)
    reports = assert_warnings_match_the_core(run_stream(stamps, u, y, FAST, [half]), FAST, [half])
    judged = [r for r in reports if r.judged]
    assert len(judged) == 2
    for r in judged:
        assert r.invalidated
        assert math.isinf(r.beta)
        assert any("beta is infinite" in w for w in r.warnings)


# ------------------------------------------------------------------ hostile streams


@pytest.mark.parametrize("seed", [3, 11, 29])
def test_hostile_streams_never_leave_a_verdict_without_a_reason(seed: int) -> None:
    result = streamfuzz.run(seed, MODELS)
    assert result.violations == [], (result.kinds, result.violations)
    assert any(not r.judged for r in result.reports)
    assert_every_verdict_has_a_reason(result.reports)


# ------------------------------------------------------------------ CLI and replay output


def _report(warnings: tuple[str, ...]) -> WindowReport:
    stamps, u, y = transient_record(4)
    cfg = dataclasses.replace(FAST, settle_periods=0)
    rep = next(r for r, _, _ in run_stream(stamps, u, y, cfg, [MODELS[1]]))
    return dataclasses.replace(rep, warnings=warnings)


def test_live_json_lists_the_warnings() -> None:
    rep = _report(("a transient may still be decaying",))
    doc = cli.report_dict(rep)
    assert doc["warnings"] == ["a transient may still be decaying"]
    assert doc["reason"] is None
    json.dumps(doc)
    assert cli.report_dict(_report(()))["warnings"] == []


def test_summary_json_counts_windows_with_warnings() -> None:
    stamps, u, y = transient_record(5)
    cfg = dataclasses.replace(FAST, settle_periods=0)
    reports = [r for r, _, _ in run_stream(stamps, u, y, cfg, MODELS)]
    result = replay.ReplayResult(path=Path("x"), reports=reports, bag_start_ns=0)
    doc = replay.summary_json(result, ["A", "B"])
    for name, entry in doc["models"].items():
        mine = [r for r in reports if r.model == name]
        warned = [r for r in mine if r.warnings]
        assert warned  # the transient
        assert entry["with_warnings"] == len(warned)
        assert [w["warnings"] for w in entry["windows"]] == [list(r.warnings) for r in mine]
        kinds = {replay.warning_kind(t) for r in warned for t in r.warnings}
        assert set(entry["warnings"]) == kinds
        assert all(any(t.startswith(k) for r in warned for t in r.warnings) for k in kinds)
        assert sum(entry["warnings"].values()) == sum(len(r.warnings) for r in warned)
    json.dumps(doc)


def test_validate_cli_json_and_table_carry_the_warnings(tmp_path: Path, capsys) -> None:
    """End to end: a scenario bag with a step of the level sensor's bias in the middle (the
    windows over the step see the output mean drift); the clean windows stay plain."""
    scenario = {
        "name": "bias",
        "duration_s": 8 * 204.8,
        "ts_s": 0.8,
        "period_samples": 256,
        "faults": ["sensor_bias:height=0.05@700"],
    }
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(scenario))
    bag = tmp_path / "bag"
    assert cli.main(["simulate", "--scenario", str(tmp_path / "s.yaml"), "--out", str(bag)]) == 0
    capsys.readouterr()
    out_json = tmp_path / "v.json"
    code = cli.main(["validate", str(bag), "--quiet", "--model", "B", "--json", str(out_json)])
    out, _ = capsys.readouterr()
    assert code == cli.EXIT_OK
    entry = json.loads(out_json.read_text())["models"]["B"]
    warned = [w for w in entry["windows"] if w["warnings"]]
    assert warned
    assert entry["with_warnings"] == len(warned)
    assert all(w["beta"] is not None for w in warned)  # judged windows only
    assert all(w["warnings"] == [] for w in entry["windows"] if w["end"] < 690)
    assert out.count("(warning: ") == sum(len(w["warnings"]) for w in warned)


def test_live_json_is_the_validate_window_entry_and_strict_json() -> None:
    """One serialisation: live's line is validate's window entry plus the model and judged;
    an infinite β (no w explains the datum) is null, so the line is strict JSON."""
    from twotank_validation.replay.summary import window_entry  # noqa: PLC0415

    rep = dataclasses.replace(_report(()), beta=math.inf)
    doc = cli.report_dict(rep)
    assert doc == {"model": rep.model, "judged": rep.judged} | window_entry(rep, 0)
    assert doc["beta"] is None
    json.dumps(doc, allow_nan=False)
