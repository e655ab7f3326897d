"""validate/diagnose on recordings not made with the defaults: timing from metadata or data,
contradictions named with the value the data suggest, and never a silent pass."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from twotank_validation import cli

SLOW = {"name": "slow", "duration_s": 2100, "ts_s": 0.5, "period_samples": 512}


# the recordings give 6 whole windows a period apart; windows are judged every quarter period
# (the default hop), 4 per period: (6 - 1) * 4 + 1
JUDGED = (6 - 1) * 4 + 1


@pytest.fixture(scope="module")
def slow_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scenario bag at Ts 0.5 s, period 512 (256 s), with the scenario in its metadata."""
    root = tmp_path_factory.mktemp("slow")
    (root / "slow.yaml").write_text(yaml.safe_dump(SLOW))
    bag = root / "bag"
    assert cli.main(["simulate", "--scenario", str(root / "slow.yaml"), "--out", str(bag)]) == 0
    return bag


@pytest.fixture(scope="module")
def bare_bag(slow_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same recording without custom_data in metadata.yaml (as other recorders write)."""
    bag = tmp_path_factory.mktemp("bare") / "bag"
    bag.mkdir()
    for f in slow_bag.iterdir():
        (bag / f.name).write_bytes(f.read_bytes())
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    meta["rosbag2_bagfile_information"]["custom_data"] = None
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta))
    return bag


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = cli.main(args)
    out, err = capsys.readouterr()
    return code, out, err


def test_timing_from_the_bags_metadata(slow_bag: Path, tmp_path: Path, capsys) -> None:
    out_json = tmp_path / "v.json"
    code, _, err = run(["validate", str(slow_bag), "--quiet", "--json", str(out_json)], capsys)
    assert code == cli.EXIT_OK
    assert "sample period 0.5 s from the bag's metadata" in err
    doc = json.loads(out_json.read_text())
    assert doc["timing"]["ts_s"] == 0.5
    assert doc["timing"]["period_samples"] == 512
    assert (doc["timing"]["ts_from"], doc["timing"]["period_from"]) == ("bag metadata",) * 2
    for entry in doc["models"].values():
        # 2100 s = 8.2 periods: windows end at periods 2..8; the first is still settling
        assert entry["judged"] == JUDGED
        assert entry["not_judged_reasons"] == {"settling": 4}  # the first period's 4 windows
        assert entry["judged"] == sum(w["beta"] is not None for w in entry["windows"])


def test_timing_inferred_from_the_data(bare_bag: Path, tmp_path: Path, capsys) -> None:
    out_json = tmp_path / "v.json"
    code, _, err = run(["validate", str(bare_bag), "--quiet", "--json", str(out_json)], capsys)
    assert code == cli.EXIT_OK
    assert "sample period 0.5 s inferred from the command stamps" in err
    assert "excitation period 512 samples (256 s) inferred from the commands" in err
    doc = json.loads(out_json.read_text())
    assert (doc["timing"]["ts_from"], doc["timing"]["period_from"]) == (
        "command stamps",
        "commands",
    )
    assert all(e["judged"] == JUDGED for e in doc["models"].values())


def test_a_wrong_ts_is_named_and_nothing_judged_is_an_error(bare_bag: Path, capsys) -> None:
    code, _, err = run(["validate", str(bare_bag), "--quiet", "--ts", "0.1"], capsys)
    assert code == cli.EXIT_NOT_JUDGED
    assert "the command stamps lie on a 0.5 s grid: pass --ts 0.5" in err
    assert "ERROR: no window of model B could be judged: unusable samples (gap)" in err


def test_a_wrong_period_is_named(slow_bag: Path, capsys) -> None:
    code, _, err = run(["validate", str(slow_bag), "--quiet", "--period", "500"], capsys)
    assert code == cli.EXIT_NOT_JUDGED
    assert "the commands repeat every 256 s: pass --period 512" in err
    assert "input not periodic" in err
    # the right value on its own: no warning
    code, _, err = run(["validate", str(slow_bag), "--quiet", "--period", "512"], capsys)
    assert code == cli.EXIT_OK
    assert "WARNING" not in err


@pytest.mark.parametrize("remap", ["temperature=height", "flow_cmd=height"])
def test_two_streams_on_one_topic_is_a_usage_error(slow_bag: Path, remap: str, capsys) -> None:
    code, _, err = run(["validate", str(slow_bag), "--quiet", "--topic", remap], capsys)
    assert code == cli.EXIT_ERROR
    assert "each stream is read from a topic of its own type" in err
    assert "Traceback" not in err


def test_a_topic_of_the_wrong_type_judges_nothing_and_says_why(slow_bag: Path, capsys) -> None:
    args = ["--topic", "height=temperature", "--topic", "temperature=height"]
    code, _, err = run(["validate", str(slow_bag), "--quiet", *args], capsys)
    assert code == cli.EXIT_INCOMPLETE  # the recording does not fit: that is the cause
    assert "topic 'temperature' carries sensor_msgs/msg/Temperature" in err
    assert "no window of model A could be judged: no window was formed" in err


def test_diagnose_judging_nothing_exits_non_zero(bare_bag: Path, capsys) -> None:
    code, _, err = run(["diagnose", str(bare_bag), "--model", "B", "--ts", "0.1"], capsys)
    assert code == cli.EXIT_NOT_JUDGED
    assert "pass --ts 0.5" in err


def test_help_lists_exit_codes_and_defaults(capsys) -> None:
    with pytest.raises(SystemExit):
        cli.main(["validate", "--help"])
    out = capsys.readouterr().out
    assert f"{cli.EXIT_NOT_JUDGED} read completely, but no window of a model could be judged" in (
        " ".join(out.split())
    )
    assert "(default: 2)" in out  # --periods-per-window
    assert "(default: 9806.65)" in out


def test_a_closed_pipe_ends_quietly_and_the_json_is_written(slow_bag: Path, tmp_path: Path):
    out_json = tmp_path / "v.json"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    cmd = [sys.executable, "-m", "twotank_validation.cli", "validate", str(slow_bag), "--quiet"]
    proc = subprocess.Popen(
        [*cmd, "--json", str(out_json)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )
    assert proc.stdout is not None
    assert proc.stderr is not None
    proc.stdout.close()  # the reader is gone before the first line (as `| head -0`)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == cli.EXIT_OK
    assert "Traceback" not in err
    assert "BrokenPipe" not in err
    assert json.loads(out_json.read_text())["models"]["B"]["judged"] == JUDGED
