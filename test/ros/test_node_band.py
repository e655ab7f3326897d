"""The band and the measured inputs in the ValidationReport message (issue 28, items 1 and 2).

The nominal rig's record with a strong periodic line on the height above the band (a harmonic
of the period the command does not carry), through the validator node's subscription
callbacks with the band set as a node parameter. Reference: ``validate`` (the use case, through
the command line) on the same samples as a table with ``--band``: each window's
``beta_outside`` and ``lines_outside`` in its JSON.

Node tests start DDS participants: run them in a private network namespace with only
loopback up, like test_ros_nodes.py (`scripts/run test` does).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from node_feed import feed_rig_record, validator_node

from tools.streamfuzz import CONFIG, clean_record
from twotank_validation import cli
from twotank_validation.online import WindowReport
from twotank_validation.ros import messages

BAND = "0:0.3"
LINE_HZ = 226 / (2 * CONFIG.period_samples * CONFIG.ts_s)  # above the band and every excited line


def _record() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    stamps, u, y = clean_record(6)
    y = y.copy()
    y[:, 0] += 0.02 * np.sin(2 * np.pi * LINE_HZ * stamps / 1e9 + 0.3)
    return stamps, u, y


def _node_reports(stamps, u, y) -> list[tuple[WindowReport, object]]:
    out: list[tuple[WindowReport, object]] = []
    params = {"ts_s": CONFIG.ts_s, "period_samples": CONFIG.period_samples}
    with validator_node(params | {"models": ["B"], "band": BAND}) as node:
        _, report_cls = messages.message_classes()
        node.report_listeners.append(
            lambda rep: out.append((rep, messages.report_message(rep, report_cls)))
        )
        feed_rig_record(node, stamps, u, y)
    return out


def test_node_band_parameter_fills_the_message_as_validate_reports(tmp_path, capsys) -> None:
    stamps, u, y = _record()
    table = tmp_path / "rig.csv"
    pd.DataFrame(
        {"t": stamps / 1e9, "hot": u[:, 0], "cold": u[:, 1], "h": y[:, 0], "T": y[:, 1]}
    ).to_csv(table, index=False)
    args = ["validate", str(table), "--model", "B", "--time", "t", "--quiet", "--band", BAND]
    args += ["--period", str(CONFIG.period_samples), "--input", "hot=column:hot"]
    args += ["--input", "cold=column:cold", "--output", "height=column:h"]
    args += ["--output", "temperature=column:T", "--json", str(tmp_path / "v.json")]
    assert cli.main(args) == cli.EXIT_OK, capsys.readouterr().err
    doc = json.loads((tmp_path / "v.json").read_text())
    ref = {round(w["start"], 1): w for w in doc["models"]["B"]["windows"]}
    pairs = _node_reports(stamps, u, y)
    judged = [(rep, msg) for rep, msg in pairs if rep.judged]
    assert len(judged) >= 3
    for rep, msg in judged:
        w = ref[round((rep.start_ns - int(stamps[0])) / 1e9, 1)]
        assert msg.beta == pytest.approx(w["beta"], rel=1e-9)
        assert msg.beta_outside == pytest.approx(w["beta_outside"], rel=1e-9)
        assert msg.beta_outside > 1.0 > msg.beta  # the line outside the band, not in β
        pairs_msg = np.reshape(msg.lines_outside, (-1, 2))
        np.testing.assert_allclose(pairs_msg, np.array(w["lines_outside"]), rtol=1e-9)
        assert pairs_msg[0, 0] == pytest.approx(LINE_HZ)
        assert msg.input_noise == 0.0  # commanded inputs: no noise to report
        assert msg.input_noise_effect == 0.0
    for rep, msg in pairs:  # a window not judged: NaN and empty
        if not rep.judged:
            assert math.isnan(msg.beta_outside)
            assert math.isnan(msg.input_noise_effect)
            assert len(msg.lines_outside) == 0
