"""The use cases: a job runs in process to the outcome the command line prints and exits with,
and a job pickles (a fleet ships it to Dask) and comes back equal."""

from __future__ import annotations

import dataclasses
import json
import pickle
from pathlib import Path

import pytest

from twotank_validation import cli, fleet
from twotank_validation.bags import write_scenario_bag
from twotank_validation.errors import ExitCode
from twotank_validation.online import MonitorConfig
from twotank_validation.sim import scenario as sc
from twotank_validation.usecases import (
    CalibrateJob,
    DiagnoseJob,
    Level,
    ReadSettings,
    Status,
    UsageError,
    ValidateJob,
)

FAST = ["--ts", "0.8", "--period", "256", "--quiet"]


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six periods of the nominal rig at ts 0.8 s, period 256 (its metadata say so)."""
    base = sc.load_scenario("nominal")
    short = dataclasses.replace(base, ts_s=0.8, period_samples=256, duration_s=6 * 0.8 * 256)
    path = tmp_path_factory.mktemp("usecases") / "good"
    write_scenario_bag(short, path, progress=False)
    return path


def _read() -> ReadSettings:
    return ReadSettings(
        monitor=MonitorConfig(ts_s=0.8, period_samples=256), ts_s=0.8, period_samples=256
    )


def test_validate_job_in_process_is_the_commands_outcome(bag, tmp_path, capsys) -> None:
    job = ValidateJob(str(bag), _read(), diagnosis=False)
    said = []
    outcome = job.run(say=said.append)
    assert outcome.code is ExitCode.OK
    assert outcome.status is Status.COMPLETE
    assert tuple(said) == outcome.messages
    assert all(m.level in (Level.NOTE, Level.WARNING) for m in said)
    out_json = tmp_path / "v.json"
    capsys.readouterr()
    code = cli.main(["validate", str(bag), *FAST, "--no-diagnosis", "--json", str(out_json)])
    out, err = capsys.readouterr()
    assert code == outcome.code
    assert out.splitlines() == list(outcome.text)
    assert json.loads(out_json.read_text()) == outcome.document
    printed = [line for line in err.splitlines() if line.split(":")[0] in ("note", "WARNING")]
    assert printed == [str(m) for m in (*outcome.messages, *outcome.closing) if m.level]


def test_the_cli_builds_the_job_of_its_arguments(bag) -> None:
    args = cli.build_parser().parse_args(["validate", str(bag), *FAST, "--model", "B"])
    job = cli._validate_job(args)
    assert job.recording == str(bag)
    assert job.models == ("B",)
    assert (job.read.ts_s, job.read.period_samples) == (0.8, 256)
    assert job.diagnosis


def test_a_diagnose_job_in_process_is_the_commands_outcome(bag, capsys) -> None:
    args = cli.build_parser().parse_args(["diagnose", str(bag), "--model", "A", *FAST])
    outcome = cli._diagnose_job(args).run()
    capsys.readouterr()
    code = cli.main(["diagnose", str(bag), "--model", "A", *FAST])
    out, err = capsys.readouterr()
    assert code == outcome.code
    assert out.splitlines() == "\n".join(outcome.text).splitlines()
    for m in outcome.closing:
        assert str(m) in err


@pytest.mark.parametrize(
    "job",
    [
        ValidateJob("x.mcap", models=("A", "B"), json_path="v.json"),
        DiagnoseJob("x.mcap", "B", start="10", end="2024-05-01T12:30:00", segment=True),
        CalibrateJob("x.mcap", "A", blocks=("delta_1",), margin=1.5),
    ],
    ids=lambda j: type(j).__name__,
)
def test_a_job_pickles_and_round_trips(job) -> None:
    back = pickle.loads(pickle.dumps(job))
    assert back == job
    assert type(back) is type(job)


def test_a_fleet_task_is_the_jobs_outcome_on_that_recording(bag) -> None:
    job = ValidateJob("elsewhere", _read(), diagnosis=False, json_path="never.json")
    task = fleet.run_task(pickle.loads(pickle.dumps(job)), str(bag))
    alone = job.at(str(bag)).run()
    assert task == fleet.RecordingOutcome.of(str(bag), alone)
    assert task.status == "complete"
    assert task.code == 0
    assert not Path("never.json").exists()


def test_an_unreadable_recording_is_an_error_outcome(tmp_path) -> None:
    missing = tmp_path / "none"
    outcome = ValidateJob(str(missing), _read()).run()
    assert outcome.code is ExitCode.ERROR
    assert outcome.status is Status.UNREADABLE
    assert [m.level for m in outcome.closing] == [Level.ERROR]


def test_settings_that_do_not_hold_are_a_usage_error() -> None:
    read = ReadSettings(monitor=MonitorConfig(ts_s=0.8, period_samples=256, hop_samples=64))
    with pytest.raises(UsageError, match="hop_samples"):
        read.replay_config(0.8, 100)


def test_the_recording_is_opened_once_for_timing_and_replay(bag, monkeypatch) -> None:
    import twotank_validation.bags as bags  # noqa: PLC0415

    opened = []
    real = bags.open_bag

    def counting(path):
        opened.append(path)
        return real(path)

    monkeypatch.setattr(bags, "open_bag", counting)
    read = ReadSettings(monitor=MonitorConfig(ts_s=0.8, period_samples=256))  # timing: metadata
    outcome = ValidateJob(str(bag), read, diagnosis=False).run()
    assert outcome.code is ExitCode.OK
    assert outcome.document is not None
    assert outcome.document["timing"]["ts_from"] == "bag metadata"
    assert opened == [str(bag)]


def test_a_model_without_its_document_is_an_error_not_left_out() -> None:
    from twotank_validation.core.model import load_model_document, model_from_dict  # noqa: PLC0415
    from twotank_validation.errors import ModelError  # noqa: PLC0415
    from twotank_validation.replay import model_documents  # noqa: PLC0415

    doc, _ = load_model_document("B")
    own = model_from_dict({**doc, "name": "B_tuned"}, "tuned.yaml")
    with pytest.raises(ModelError, match=r"model 'B_tuned'.*--model FILE"):
        model_documents([own])
    assert model_documents([own], {"B_tuned": doc}) == {"B_tuned": doc}


def test_timing_conflicts_are_typed_with_the_value_the_data_suggest(bag) -> None:
    from twotank_validation import replay  # noqa: PLC0415

    cfg = replay.ReplayConfig(monitor=MonitorConfig(ts_s=0.8, period_samples=256))
    timing = replay.resolve_timing(bag, cfg, ts_s=0.5, period_samples=256)
    (ts,) = [c for c in timing.findings if c.setting is replay.TimingSetting.TS]
    assert (ts.given_by, ts.value, ts.suggested) == (replay.GivenBy.OPTION, 0.5, 0.8)
    assert "pass --ts 0.8" in ts.text
    assert timing.conflicts == tuple(c.text for c in timing.findings)
    assert "findings" not in timing.to_json()


def test_a_model_without_a_judged_window_has_a_typed_reason(tmp_path) -> None:
    from twotank_validation import replay  # noqa: PLC0415
    from twotank_validation.core.model import load_model  # noqa: PLC0415
    from twotank_validation.online.states import WindowQuality  # noqa: PLC0415

    base = sc.load_scenario("nominal")
    short = dataclasses.replace(base, ts_s=0.8, period_samples=256, duration_s=2.5 * 0.8 * 256)
    path = tmp_path / "short"
    write_scenario_bag(short, path, progress=False)
    outcome = ValidateJob(str(path), _read(), models=("A",), diagnosis=False).run()
    assert outcome.code is ExitCode.NOT_JUDGED
    cfg = _read().replay_config(0.8, 256)
    result = replay.replay_recording(path, [load_model("A")], cfg)
    (why,) = replay.unjudged(result, ["A"], None, cfg)
    assert why.model == "A"
    assert isinstance(why.reason, WindowQuality) or why.no_window is not None
    errors = [str(m) for m in outcome.closing if m.level is Level.ERROR]
    assert errors[0] == f"ERROR: {why.text()}"
