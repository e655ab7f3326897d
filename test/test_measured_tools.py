"""calibrate and diagnose on a measured input (issue 28, item 2): the datum validate builds.

The record is the nominal rig's (the plant sees the clean command); the logged inputs are the
commands plus white noise at 1e-3 of their RMS, marked ``kind=measured``. References: the
same windows as ``validate`` judges them (β bit for bit: one datum), and the noise-free
record's β, within the input noise's effect that ``validate`` reports for each window
(docs/theory.md, "Measured inputs").
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tools.streamfuzz import CONFIG, clean_record
from twotank_validation import cli

NOISE = 1e-3


@pytest.fixture(scope="module")
def tables(tmp_path_factory) -> dict[str, Path]:
    """The rig's record with clean and with noisy logged inputs (CSV)."""
    stamps, u, y = clean_record(8)
    rms = np.sqrt(np.mean((u - u.mean(0)) ** 2, axis=0))
    noise = np.random.default_rng(3).standard_normal(u.shape) * NOISE * rms
    out = {}
    folder = tmp_path_factory.mktemp("measured")
    for name, logged in (("clean", u), ("noisy", u + noise)):
        out[name] = folder / f"{name}.csv"
        pd.DataFrame(
            {"t": stamps / 1e9, "hot": logged[:, 0], "cold": logged[:, 1]}
            | {"h": y[:, 0], "T": y[:, 1]}
        ).to_csv(out[name], index=False)
    return out


def _run(command: str, table: Path, capsys) -> dict:
    args = [command, str(table), "--model", "B", "--time", "t", "--quiet"]
    args += ["--period", str(CONFIG.period_samples)]
    args += ["--input", "hot=column:hot,kind=measured", "--input", "cold=column:cold,kind=measured"]
    args += ["--output", "height=column:h", "--output", "temperature=column:T"]
    out = table.with_suffix(f".{command}.json")
    code = cli.main([*args, "--json", str(out)])
    err = capsys.readouterr().err
    assert code == cli.EXIT_OK, err  # judged, not refused
    return json.loads(out.read_text())


def _validated(doc: dict) -> dict[float, tuple[float, float]]:
    """validate's judged windows: start (s) -> (beta, input_noise_effect)."""
    return {
        round(w["start"], 1): (w["beta"], w["input_noise_effect"])
        for w in doc["models"]["B"]["windows"]
        if w["beta"] is not None
    }


def test_calibrate_and_diagnose_take_validates_datum_of_a_measured_input(tables, capsys) -> None:
    clean = _validated(_run("validate", tables["clean"], capsys))
    noisy = _validated(_run("validate", tables["noisy"], capsys))
    cal = _run("calibrate", tables["noisy"], capsys)
    diag = _run("diagnose", tables["noisy"], capsys)
    diag_clean = _run("diagnose", tables["clean"], capsys)
    judged = [(w["start_s"], w["beta"]) for w in cal["windows"]]
    judged += list(
        zip(diag["heldout_windows_start_s"], diag["before"]["beta_windows"], strict=True)
    )
    assert len(judged) == 4
    for start, beta in judged:
        ref, effect = noisy[round(start, 1)]
        assert beta == pytest.approx(ref, rel=1e-9)  # validate's datum: averaged inputs
        assert 0.0 < effect < 1e-3
        assert abs(beta - clean[round(start, 1)][0]) <= effect
    # the same answer as on the clean inputs (the rig's mixing delay, which Model B lacks),
    # its parameter moved by far less than its own standard error
    assert [(e["kind"], e["channel"]) for e in diag["effects"]] == [("delay", "temperature")]
    assert [(e["kind"], e["channel"]) for e in diag_clean["effects"]] == [("delay", "temperature")]
    got, ref = diag["effects"][0], diag_clean["effects"][0]
    stderr = ref["uncertainty"]["delay_s"]["stderr"]
    assert abs(got["parameters"]["delay_s"] - ref["parameters"]["delay_s"]) < 0.05 * stderr
