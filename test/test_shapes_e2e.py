"""Plants of any shape end to end: simulated, recorded (CSV, bag) or live, judged by name.

For a 1x1, a 1x3 and a 3x2 plant (``test/data/models``), one run each of the model simulator
with an input fault (a weak actuator, ``input_gain`` 0.3, at 128 s) is

* written by ``twotank-validation simulate --model`` as a CSV table and as an MCAP bag, each
  with its interface map, and judged by ``twotank-validation validate --map`` (the CLI's
  JSON);
* run live: the model plant node and the validator node on a simulated clock
  (``ros.live_model``), the validator stamping the plant's headerless ``Float64`` topics by
  their receive time.

References: every judged window's beta equals ``validate()`` on the same samples of the
simulator's own arrays (``simulate_model``, the pure batch; the live run's aligned samples are
checked equal to them bit for bit and on the ``k ts`` grid); the alarm is never ERROR in a
window that ends before the fault's onset and is ERROR once the fault is in the windows.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from twotank_validation import cli
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import LFTModel, load_model
from twotank_validation.core.validate import validate
from twotank_validation.sim import model_plant as mp
from twotank_validation.sim.model_record import interface_map_path

MODELS = Path(__file__).parent / "data" / "models"
TS_S = 0.5
PERIOD = 64
PERIODS = 8  # 512 samples: the live run is a few hundred samples
ONSET_S = 128.0  # sample 256: four periods without the fault, four with it
NOISE_SCALE = 0.7  # inside the noise the model admits: beta < 1 without the fault
WINDOW = 2 * PERIOD  # periods_per_window 2 (the default)
SHAPES = {
    "1x1": ("siso.yaml", "input_gain:valve=0.3@128"),
    "1x3": ("one_by_three.yaml", "input_gain:pump=0.3@128"),
    "3x2": ("three_by_two.yaml", "input_gain:feed_a=0.3@128"),
}
WINDOW_OPTIONS = ["--ts", str(TS_S), "--period", str(PERIOD), "--hop", str(PERIOD)]


def _reference(model_file: str, fault: str) -> mp.ModelSimResult:
    """The run as the pure simulator computes it (the plant node's and the CLI's defaults)."""
    return mp.simulate_model(
        mp.ModelSimConfig(
            model=load_model(MODELS / model_file),
            ts_s=TS_S,
            excitation=mp.ModelExcitation(period_samples=PERIOD),
            periods=PERIODS,
            settle_periods=0,
            noise_scale=NOISE_SCALE,
            faults=(mp.parse_model_fault(fault),),
        )
    )


def _validate_beta(run: mp.ModelSimResult, model: LFTModel, start_s: float) -> float:
    """``validate()`` on the simulator's samples of the window that starts at ``start_s``."""
    k0 = round(start_s / TS_S)
    assert k0 * TS_S == pytest.approx(start_s, abs=1e-9)
    w = slice(k0, k0 + WINDOW)
    assert w.stop <= run.n_samples
    datum = make_datum(run.u[w], run.y[w], ts_s=TS_S, period_samples=PERIOD)
    return validate(datum, model).beta


def _check_windows(windows: list[dict[str, Any]], run: mp.ModelSimResult, model: LFTModel) -> None:
    """Betas equal ``validate()``'s; no ERROR before the onset, ERROR after it."""
    judged = [w for w in windows if w["beta"] is not None]
    assert len(judged) >= 4, windows
    for w in judged:
        assert w["beta"] == pytest.approx(_validate_beta(run, model, w["start"]), rel=1e-9)
    before = [w for w in judged if w["end"] < ONSET_S]
    after = [w for w in judged if w["start"] >= ONSET_S]
    assert len(before) >= 2, windows
    assert after, windows
    assert all(w["beta"] < 1.0 and w["alarm"] != "ERROR" for w in before), before
    assert all(w["beta"] > 1.0 for w in after), after
    assert windows[-1]["alarm"] == "ERROR", windows[-1]


@pytest.fixture(scope="module", params=sorted(SHAPES))
def shape(request: pytest.FixtureRequest) -> tuple[str, str, mp.ModelSimResult]:
    model_file, fault = SHAPES[request.param]
    return model_file, fault, _reference(model_file, fault)


def _simulate_cli(tmp: Path, model_file: str, fault: str, fmt: str, out: str) -> Path:
    path = tmp / out
    code = cli.main(
        [
            "simulate", "--model", str(MODELS / model_file), "--format", fmt, "--out", str(path),
            "--ts", str(TS_S), "--period", str(PERIOD), "--periods", str(PERIODS),
            "--settle-periods", "0", "--noise-scale", str(NOISE_SCALE), "--fault", fault,
        ]
    )  # fmt: skip
    assert code == cli.EXIT_OK
    assert interface_map_path(path).is_file()
    return path


@pytest.mark.parametrize("fmt", ["csv", "mcap"])
def test_a_recording_judged_by_the_cli_gives_validates_beta_and_the_alarm(
    shape: tuple[str, str, mp.ModelSimResult], fmt: str, tmp_path: Path, capsys
) -> None:
    model_file, fault, run = shape
    out = _simulate_cli(tmp_path, model_file, fault, fmt, "run.csv" if fmt == "csv" else "run")
    capsys.readouterr()
    summary = tmp_path / "summary.json"
    code = cli.main(
        [
            "validate", str(out), "--map", str(interface_map_path(out)),
            "--model", str(MODELS / model_file), *WINDOW_OPTIONS,
            "--quiet", "--no-diagnosis", "--json", str(summary),
        ]
    )  # fmt: skip
    assert code == cli.EXIT_OK, capsys.readouterr().err
    model = load_model(MODELS / model_file)
    windows = json.loads(summary.read_text())["models"][model.name]["windows"]
    _check_windows(windows, run, model)


def test_live_gives_validates_beta_and_the_alarm(shape: tuple[str, str, mp.ModelSimResult]) -> None:
    from twotank_validation.ros.live_model import ModelLiveConfig, run_model_live  # noqa: PLC0415

    model_file, fault, run = shape
    cfg = ModelLiveConfig(
        plant_model=str(MODELS / model_file),
        n_steps=run.n_samples,
        ts_s=TS_S,
        period_samples=PERIOD,
        faults=(fault,),
        noise_scale=NOISE_SCALE,
        validator={"hop_samples": PERIOD},
    )
    res = run_model_live(cfg)
    # the validator's samples are the simulator's, bit for bit, stamped k ts (receive time)
    stamps = np.array([s.stamp_ns for s in res.samples])
    assert np.array_equal(stamps, run.stamps_ns)
    assert np.array_equal(np.array([s.u for s in res.samples]), run.u)
    assert np.array_equal(np.array([s.y for s in res.samples]), run.y)
    assert all(s.flag is None for s in res.samples)
    windows = [cli.report_dict(r) for r in res.reports]
    _check_windows(windows, run, load_model(MODELS / model_file))


def test_live_with_a_model_of_other_channels_is_exit_2_without_a_traceback() -> None:
    """Checked before any node starts: a subprocess that must end, quickly, with exit 2."""
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    proc = subprocess.run(
        [
            sys.executable, "-m", "twotank_validation.cli", "live",
            "--plant-model", str(MODELS / "one_by_three.yaml"),
            "--model", str(MODELS / "siso.yaml"), "--duration", "10",
        ],
        capture_output=True, text=True, timeout=120, env=env, check=False,
    )  # fmt: skip
    assert proc.returncode == cli.EXIT_ERROR, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "model siso names input 'valve', which the plant 'one_by_three'" in proc.stderr
    assert "inputs [pump] and outputs [p_in, p_out, flow]" in proc.stderr  # the plant's side
    assert "inputs [valve] and outputs [flow]" in proc.stderr  # the model's side
    assert "--plant-model FILE" in proc.stderr
    assert proc.stdout == ""


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--scenario", "nominal", "--model", "X"], "exactly one of --scenario"),
        ([], "exactly one of --scenario NAME (the two-tank rig), --model FILE (any model) and"),
        (["--structure", "1", "--model", "X"], "found --model and --structure"),
        (["--scenario", "nominal", "--format", "csv"], "--format, --ts and --period are for"),
        (["--scenario", "nominal", "--ts", "0.5"], "--format, --ts and --period are for"),
        (["--model", str(MODELS / "siso.yaml"), "--storage", "sqlite3"], "with --model give"),
        (
            ["--model", str(MODELS / "siso.yaml"), "--fault", "sensor_bias:level=1@2"],
            "model 'siso' has no output 'level'; its inputs are ['valve'], its outputs ['flow']",
        ),
    ],
)
def test_simulate_usage_errors_are_exit_2(tmp_path: Path, capsys, args, message) -> None:
    out = tmp_path / "out"
    assert cli.main(["simulate", *args, "--out", str(out)]) == cli.EXIT_ERROR
    err = capsys.readouterr().err
    assert message in err
    assert "Traceback" not in err
    assert not out.exists()
    assert not interface_map_path(out).exists()


def test_live_usage_errors_are_exit_2(capsys) -> None:
    plant = str(MODELS / "siso.yaml")
    for args, message in (
        (["--plant-model", plant, "--closed-loop"], "a --plant-model runs open loop"),
        (["--member", "random"], "--member and --noise-scale are for --plant-model"),
        (["--plant-model", plant, "--fault", "leak=0.02@100"], "is not KIND:CHANNEL"),
        (["--plant-model", plant, "--ts", "0"], "give a sample period > 0"),
    ):
        assert cli.main(["live", *args]) == cli.EXIT_ERROR
        assert message in capsys.readouterr().err


def test_simulate_model_writes_a_table_when_out_ends_in_csv(tmp_path: Path, capsys) -> None:
    """--out x.csv without --format is a CSV table (read back by pandas), not a bag folder
    named x.csv; a bag format with a .csv name is refused."""
    import pandas as pd  # noqa: PLC0415

    model = str(Path(__file__).parent / "data" / "models" / "one_by_three.yaml")
    out = tmp_path / "run.csv"
    args = ["simulate", "--model", model, "--ts", "0.5", "--period", "16", "--periods", "2"]
    args += ["--settle-periods", "1"]
    assert cli.main([*args, "--out", str(out)]) == cli.EXIT_OK, capsys.readouterr().err
    assert out.is_file()
    frame = pd.read_csv(out)
    assert len(frame) == (1 + 2) * 16  # the settling period and the two recorded
    code = cli.main([*args, "--out", str(tmp_path / "b.csv"), "--format", "mcap"])
    assert code == cli.EXIT_ERROR
    assert "names a CSV table" in capsys.readouterr().err
