"""calibrate keeps its outputs when no weight can be changed, and says one quantity one way
(issue 27, item 8).

References: the blocks' notes and the failure are compared between what is printed, the JSON
and the report's calibration.md; the written factor of a uniformly scaled block is read back
from the model file it wrote (its weight against the stated model's).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

from twotank_validation import cli
from twotank_validation.core.model import load_model_document
from twotank_validation.errors import ExitCode


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The shipped leak and nominal scenarios, as the issue makes them."""
    root = tmp_path_factory.mktemp("cal_outputs")
    out = {}
    for name in ("leak", "nominal"):
        out[name] = root / f"{name}_bag"
        cmd = ["simulate", "--scenario", name, "--out", str(out[name]), "--quiet"]
        assert cli.main(cmd) == 0
    return out


def test_no_weight_changed_keeps_the_notes_json_and_report(bags, tmp_path, capsys) -> None:
    out_model, out_json, figs = tmp_path / "a.yaml", tmp_path / "c.json", tmp_path / "figs"
    code = cli.main(
        ["calibrate", str(bags["leak"]), "--model", "A", "--out-model", str(out_model),
         "--json", str(out_json), "--report", str(figs), "--quiet"]
    )  # fmt: skip
    out, err = capsys.readouterr()
    assert code == ExitCode.ERROR  # documented: docs/cli.md, exit code 2
    assert "no weight could be changed" in err
    assert "Traceback" not in err
    assert not out_model.exists()
    doc = json.loads(out_json.read_text())
    assert doc["failure"].startswith("no weight could be changed")
    assert doc["model_file"] is None
    notes = [b["note"] for b in doc["blocks"]]
    assert notes
    assert all(notes)  # every block says why it was left as it is
    for note in notes:  # each printed, and in the report
        assert note in out
        assert note in (figs / "calibration.md").read_text()
    assert (figs / "calibration_beta.png").stat().st_size > 0
    assert doc["failure"] in (figs / "calibration.md").read_text()


def _number(pattern: str, text: str) -> float:
    found = re.search(pattern, text)
    assert found, (pattern, text)
    return float(found.group(1))


def test_one_quantity_said_one_way(bags, tmp_path, capsys) -> None:
    """The factor on the stated weight: alone, and as written (after the blocks above)."""
    out_model, out_json = tmp_path / "a.yaml", tmp_path / "c.json"
    code = cli.main(
        ["calibrate", str(bags["nominal"]), "--model", "A", "--out-model", str(out_model),
         "--json", str(out_json), "--quiet"]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == ExitCode.OK
    assert "scaled uniformly" not in out  # the one quantity is the factor on the stated weight
    assert "demand" not in out
    doc = json.loads(out_json.read_text())
    stated, _ = load_model_document("A")
    written = yaml.safe_load(out_model.read_text())
    noise = {n["outputs"][0]: n for n in stated["noise"]}
    noise_after = {n["outputs"][0]: n for n in written["noise"]}
    block = next(b for b in doc["blocks"] if b["name"] == "temperature_noise")
    alone, need, factor = block["scaling"], block["fit_scaling"], block["written_factor"]
    assert alone > 1.0 > factor  # alone it needs more; after the blocks above, less
    assert factor == pytest.approx(need * 1.2, rel=1e-12)  # times the margin
    # the model file's weight is the stated one times the written factor
    gain = noise["temperature"]["weight"]["gain"]
    assert noise_after["temperature"]["weight"]["gain"] == pytest.approx(gain * factor, rel=1e-9)
    lines = out.splitlines()
    at = next(i for i, line in enumerate(lines) if "temperature_noise:" in line)
    head, written_line = lines[at], next(ln for ln in lines[at:] if "written:" in ln)
    assert _number(r"(\d+\.?\d*) × its stated weight", head) == pytest.approx(alone, rel=1e-2)
    assert "alone (the other blocks as stated)" in head
    assert _number(r"written: (\d+\.?\d*) × the stated weight", written_line) == pytest.approx(
        factor, rel=1e-3
    )
    assert _number(r"= (\d+\.?\d*) ", written_line) == pytest.approx(need, rel=1e-3)
    assert "the blocks above as calibrated" in written_line
