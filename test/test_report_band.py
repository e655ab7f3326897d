"""validate's figures judge a window as its table does: the band (``--band``) and measured inputs.

The nominal rig's record with a strong line on the height above the band, its inputs logged
with noise at 1e-3 of their RMS and marked measured. Reference: the summary's largest β (the
window the figures are drawn for), which the replay judged with the band and the averaged
inputs; the figures' own validation of that window must give the same β.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tools.streamfuzz import CONFIG, clean_record
from twotank_validation import cli, report

LINE_HZ = 226 / (2 * CONFIG.period_samples * CONFIG.ts_s)  # above the band and every excited line


def test_the_figures_beta_is_the_judged_one(tmp_path, monkeypatch, capsys) -> None:
    stamps, u, y = clean_record(6)
    rms = np.sqrt(np.mean((u - u.mean(0)) ** 2, axis=0))
    logged = u + np.random.default_rng(3).standard_normal(u.shape) * 1e-3 * rms
    y = y.copy()
    y[:, 0] += 0.02 * np.sin(2 * np.pi * LINE_HZ * stamps / 1e9 + 0.3)
    table = tmp_path / "rig.csv"
    pd.DataFrame(
        {"t": stamps / 1e9, "hot": logged[:, 0], "cold": logged[:, 1], "h": y[:, 0], "T": y[:, 1]}
    ).to_csv(table, index=False)
    drawn: dict[str, float] = {}

    def per_bin(results, path, **_):
        drawn[path.stem] = next(iter(results.values())).beta

    monkeypatch.setattr(report, "plot_per_bin", per_bin)
    for name in ("plot_alarm_timeline", "plot_nyquist", "plot_time_signals"):
        monkeypatch.setattr(report, name, lambda *a, **k: None)
    args = ["validate", str(table), "--model", "B", "--time", "t", "--quiet", "--band", "0:0.3"]
    args += ["--period", str(CONFIG.period_samples)]
    args += ["--input", "hot=column:hot,kind=measured", "--input", "cold=column:cold,kind=measured"]
    args += ["--output", "height=column:h", "--output", "temperature=column:T"]
    args += ["--json", str(tmp_path / "v.json"), "--report", str(tmp_path / "figures")]
    assert cli.main(args) == cli.EXIT_OK, capsys.readouterr().err
    entry = json.loads((tmp_path / "v.json").read_text())["models"]["B"]
    assert entry["beta_outside_max"] > 1.0 > entry["beta_max"]  # the line lies outside
    assert drawn["per_bin_B_max_beta"] == pytest.approx(entry["beta_max"], rel=1e-9)
