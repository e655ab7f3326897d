"""Measured data of a real rig: the Cascaded Tanks benchmark through ``validate`` (the CLI).

``test/data/cascaded_tanks/dataBenchmark.csv`` (Schoukens et al., DOI 10.4121/12960104,
CC BY-SA 4.0; README there) holds two experiments of one multisine period each, side by side
in columns and without a time column; a map per experiment reads it (rows stamped 4 s apart,
``time: {step_s: 4}``). Reference: the beta the CLI reports for the one window of each
experiment equals ``validate()`` on the file's samples read with numpy (not the table reader).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from twotank_validation import cli
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model
from twotank_validation.core.validate import validate
from twotank_validation.online.interface import InterfaceMapError, load_interface_map

DATA = Path(__file__).parent / "data" / "cascaded_tanks"
CSV = DATA / "dataBenchmark.csv"
MODEL = Path(__file__).parent / "data" / "models" / "cascaded_tanks.yaml"
SHA256 = "ef2388ed822f3aef4aa80d6b0f2b466dd80b361786b3eafc7a2957c31ea323a7"
OPTIONS = ["--ts", "4", "--period", "1024", "--periods-per-window", "1", "--settle-periods", "0"]


def test_the_copy_is_the_published_file_with_its_attribution() -> None:
    assert hashlib.sha256(CSV.read_bytes()).hexdigest() == SHA256
    readme = (DATA / "README.md").read_text()
    for needed in ("Schoukens", "10.4121/12960104", "CC BY-SA 4.0"):
        assert needed in readme


@pytest.mark.parametrize(("experiment", "u_col", "y_col"), [("estimation", 0, 2), ("test", 1, 3)])
def test_validate_reports_validates_beta_on_the_measured_samples(
    experiment: str, u_col: int, y_col: int, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "summary.json"
    code = cli.main(
        [
            "validate", str(CSV), "--map", str(DATA / f"{experiment}.map.yaml"),
            "--model", str(MODEL), *OPTIONS, "--quiet", "--json", str(out),
        ]
    )  # fmt: skip
    captured = capsys.readouterr()
    # one window judged (exit 0); the model is invalidated by the measured data
    assert code == cli.EXIT_OK, captured.err
    windows = json.loads(out.read_text())["models"]["cascaded_tanks"]["windows"]
    assert len(windows) == 1
    (w,) = windows
    assert (w["start"], w["end"]) == (0.0, 4092.0)
    assert w["reason"] is None
    assert any("one period only" in text for text in w["warnings"])
    raw = np.genfromtxt(CSV, delimiter=",", skip_header=1)
    datum = make_datum(raw[:, [u_col]], raw[:, [y_col]], ts_s=4.0, period_samples=1024)
    want = validate(datum, load_model(MODEL)).beta
    assert w["beta"] == pytest.approx(want, rel=1e-9)
    assert w["beta"] > 1.0
    assert w["invalidated"]
    assert "INVALIDATED" in captured.out


def test_without_a_time_column_or_step_the_table_is_refused_with_the_fix(tmp_path, capsys) -> None:
    bare = tmp_path / "bare.map.yaml"
    bare.write_text(
        "inputs: [{name: pump, column: uEst}]\noutputs: [{name: level, column: yEst}]\n"
    )
    code = cli.main(["validate", str(CSV), "--map", str(bare), "--model", str(MODEL), *OPTIONS])
    err = capsys.readouterr().err
    assert code == cli.EXIT_ERROR
    assert "no time column" in err
    assert "time: {step_s: SECONDS}" in err
    assert "Traceback" not in err


def test_step_s_is_a_positive_spacing_and_excludes_a_time_column(tmp_path) -> None:
    for time, message in (
        ("{step_s: 0}", "is not a sample spacing"),
        ("{step_s: 4, column: Ts}", "not both"),
        ("{step_s: four}", "is not a sample spacing"),
    ):
        path = tmp_path / "m.yaml"
        path.write_text(
            "inputs: [{name: pump, column: uEst}]\noutputs: [{name: level, column: yEst}]\n"
            f"time: {time}\n"
        )
        with pytest.raises(InterfaceMapError, match=message):
            load_interface_map(path)
    imap = load_interface_map(DATA / "estimation.map.yaml")
    assert imap.time is not None
    assert imap.time.step_s == 4.0
    assert imap.to_dict()["time"] == {"step_s": 4.0}
