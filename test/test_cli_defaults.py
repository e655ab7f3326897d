"""Defaults that do not cry wolf (issue 27, item 11): the models judged are the ones named,
or the defaults said as such (stderr and JSON); ``--fail-on-alarm`` exits non-zero when an
alarm rose, for a pipeline; a fleet counts its alarms per model.

References: each recording's JSON (its models' ``first_alarm``) for the exit code, and the
validator's settings tree for the default models (the node's ``models`` parameter).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from twotank_validation import cli
from twotank_validation.bags import write_scenario_bag
from twotank_validation.errors import ExitCode
from twotank_validation.online.validator_settings import ValidatorSettings
from twotank_validation.sim import scenario as sc

FAST = ["--ts", "0.8", "--period", "256", "--quiet", "--no-diagnosis"]


def _scenario(name: str, **changes) -> sc.Scenario:
    base = sc.load_scenario(name)
    return dataclasses.replace(base, ts_s=0.8, period_samples=256, **changes)


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two nominal recordings and a leak after the operating point is commissioned."""
    root = tmp_path_factory.mktemp("defaults")
    out = {}
    for name in ("nominal_1", "nominal_2"):
        out[name] = root / "nominal" / name
        write_scenario_bag(_scenario("nominal", duration_s=6 * 204.8), out[name], progress=False)
    out["leak"] = root / "leak"
    leak = _scenario("leak", duration_s=10 * 204.8, faults=("leak=0.04@900",))
    write_scenario_bag(leak, out["leak"], progress=False)
    return out


def _validate(args: list[str], capsys) -> tuple[int, str, str]:
    capsys.readouterr()
    code = cli.main(["validate", *args, *FAST])
    out, err = capsys.readouterr()
    return code, out, err


def test_the_default_models_are_said(bags, tmp_path, capsys) -> None:
    out_json = tmp_path / "v.json"
    code, _, err = _validate([str(bags["nominal_1"]), "--json", str(out_json)], capsys)
    assert code == ExitCode.OK
    defaults = list(ValidatorSettings.models)  # the node's models parameter: one default
    said = [line for line in err.splitlines() if "default models" in line]
    assert len(said) == 1
    named = " and ".join(defaults)
    assert said[0].startswith(f"note: no --model given: judging the default models {named}")
    doc = json.loads(out_json.read_text())
    assert doc["models_from"] == "default"
    assert list(doc["models"]) == defaults


def test_only_the_models_named_are_judged(bags, tmp_path, capsys) -> None:
    out_json = tmp_path / "v.json"
    args = [str(bags["nominal_1"]), "--model", "B", "--json", str(out_json)]
    code, out, err = _validate(args, capsys)
    assert code == ExitCode.OK
    assert "default models" not in err
    doc = json.loads(out_json.read_text())
    assert doc["models_from"] == "named"
    assert list(doc["models"]) == ["B"]
    assert "model A" not in out


@pytest.mark.parametrize(
    ("recording", "model"), [("nominal_1", "B"), ("nominal_1", "A"), ("leak", "B")]
)
def test_fail_on_alarm_exits_non_zero_when_an_alarm_rose(
    bags, recording, model, tmp_path, capsys
) -> None:
    out_json = tmp_path / "v.json"
    args = [str(bags[recording]), "--model", model, "--json", str(out_json)]
    code, _, err = _validate([*args, "--fail-on-alarm"], capsys)
    alarm = json.loads(out_json.read_text())["models"][model]["first_alarm"]
    assert code == (ExitCode.ALARM if alarm is not None else ExitCode.OK)
    if alarm is not None:
        assert f"alarm of model {model} rose at {alarm:.1f} s" in err
    # without the option the same run exits 0: the alarm alone is no failure
    assert _validate(args, capsys)[0] == ExitCode.OK


def test_the_cases_above_cover_both_answers(bags, tmp_path) -> None:
    """Model A on nominal data alarms by design, Model B does not; the leak raises B's."""
    from twotank_validation.usecases import ReadSettings, ValidateJob  # noqa: PLC0415

    read = ReadSettings(ts_s=0.8, period_samples=256)
    first = {
        (rec, m): ValidateJob(str(bags[rec]), read, (m,), diagnosis=False)
        .run()
        .summary["models"][m]["first_alarm"]
        for rec, m in [("nominal_1", "B"), ("nominal_1", "A"), ("leak", "B")]
    }
    assert first[("nominal_1", "B")] is None
    assert first[("nominal_1", "A")] is not None
    assert first[("leak", "B")] is not None


def test_fail_on_alarm_needs_the_models_named(bags, capsys) -> None:
    code, _, err = _validate([str(bags["nominal_1"]), "--fail-on-alarm"], capsys)
    assert code == ExitCode.ERROR
    assert "--fail-on-alarm" in err
    assert "--model" in err


def test_a_fleet_counts_alarms_per_model(bags, tmp_path, capsys) -> None:
    nominal = str(bags["nominal_1"].parent)
    code, out, err = _validate([nominal, "--serial", "--out", str(tmp_path / "all")], capsys)
    assert code == ExitCode.OK
    assert sum("default models" in line for line in err.splitlines()) == 1  # once, not per bag
    assert "2 recording(s): 2 complete; alarms: model A on 2, model B on 0" in out
    named = ["--serial", "--model", "B", "--fail-on-alarm"]
    code, out, _ = _validate([nominal, *named, "--out", str(tmp_path / "b")], capsys)
    assert code == ExitCode.OK
    assert "alarms: model B on 0" in out
    both = [nominal, str(bags["leak"]), *named, "--out", str(tmp_path / "c")]
    code, out, _ = _validate(both, capsys)
    assert code == ExitCode.ALARM
    assert "alarms: model B on 1" in out
