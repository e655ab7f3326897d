"""Measured inputs in the interface map and the window monitor (issue 28, item 2).

The record is the nominal rig's (the plant sees the clean command, Model B explains it); the
logged inputs are the commands plus white noise at 1e-3 of their RMS. References: the same
windows judged on the clean commands (β moves by no more than the noise's effect), and the
commanded gate's own tolerance (1e-6 of the RMS), which the noise exceeds a thousandfold.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from tools.streamfuzz import clean_record
from twotank_validation.core.datum import MEASURED_INPUT_RTOL
from twotank_validation.core.model import load_model
from twotank_validation.errors import ModelError
from twotank_validation.online import AlarmConfig, MonitorConfig, monitor_record
from twotank_validation.online.interface_map import InputKind, InterfaceMap
from twotank_validation.online.interface_text import input_texts, interface_map_from_text
from twotank_validation.online.sources import InterfaceMapError
from twotank_validation.online.states import WindowState

CONFIG = MonitorConfig(
    ts_s=0.8, period_samples=256, hop_samples=256, alarm=AlarmConfig(debounce="count")
)
NOISE = 1e-3


def _noisy() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    stamps, u, y = clean_record(6)
    rms = np.sqrt(np.mean((u - u.mean(0)) ** 2, axis=0))
    noise = np.random.default_rng(3).standard_normal(u.shape) * NOISE * rms
    return stamps, u, u + noise, y


def test_measured_inputs_are_judged_and_commanded_ones_refused() -> None:
    stamps, u, logged, y = _noisy()
    model = load_model("B")
    clean = [r for r in monitor_record(stamps, u, y, CONFIG, [model]) if r.judged]
    measured = monitor_record(stamps, logged, y, CONFIG, [model], measured_inputs=("hot", "cold"))
    commanded = monitor_record(stamps, logged, y, CONFIG, [model])
    judged = [r for r in measured if r.judged]
    assert len(judged) == len(clean) == 4
    for rep, ref in zip(judged, clean, strict=True):
        # the noise estimate: 1e-3 of the RMS (within a few of its standard errors)
        assert rep.input_noise == pytest.approx(NOISE, rel=0.2)
        assert 0.0 < rep.input_noise_effect < abs(1.0 - rep.beta)  # no warning needed
        assert abs(rep.beta - ref.beta) <= rep.input_noise_effect
        assert rep.warnings == ref.warnings
        assert not rep.invalidated
    assert all(not r.judged for r in commanded)  # the gate stays strict for commands
    refused = [r for r in commanded if r.quality.state is WindowState.INPUT_NOT_PERIODIC]
    assert refused
    assert all(r.input_change > 100 * CONFIG.input_periodic_rtol for r in refused)
    assert all(r.input_noise == 0.0 for r in refused)


def test_a_measured_input_whose_excitation_changes_is_refused() -> None:
    stamps, u, logged, y = _noisy()
    logged = logged.copy()
    mid = 3 * CONFIG.period_samples
    logged[mid:] = u.mean(0) + 1.3 * (logged[mid:] - u.mean(0))
    reports = monitor_record(
        stamps, logged, y, CONFIG, [load_model("B")], measured_inputs=("hot", "cold")
    )
    spans = [r for r in reports if r.quality.state is WindowState.INPUT_NOT_PERIODIC]
    assert spans
    assert all(r.input_noise > MEASURED_INPUT_RTOL for r in spans)
    assert "measured input" in spans[0].data_quality


def test_an_unknown_measured_input_is_a_clear_error() -> None:
    with pytest.raises(ModelError, match=r"measured inputs \['flow'\] are not among the inputs"):
        monitor_record(*clean_record(6), CONFIG, [load_model("B")], measured_inputs=("flow",))


def _doc(kind: object = None, on: str = "inputs") -> dict[str, object]:
    hot = {"name": "hot", "column": "hot"}
    level = {"name": "height", "column": "h"}
    entry = {"inputs": hot, "outputs": level}[on] | ({} if kind is None else {"kind": kind})
    return {
        "inputs": [entry if on == "inputs" else hot],
        "outputs": [entry if on == "outputs" else level],
    }


def test_the_map_marks_an_input_measured() -> None:
    imap = InterfaceMap.from_dict(_doc("measured"), "rig.yaml")
    assert imap.kinds == (InputKind.MEASURED,)
    assert imap.measured_inputs == ("hot",)
    assert InterfaceMap.from_dict(imap.to_dict()) == imap  # the YAML form round-trips
    plain = InterfaceMap.from_dict(_doc(), "rig.yaml")
    assert plain.kinds == (InputKind.COMMANDED,)
    assert plain.measured_inputs == ()
    assert InterfaceMap.from_dict(_doc("commanded")) == plain  # the default, said
    assert "kind" not in plain.to_dict()["inputs"][0]
    text = interface_map_from_text(["hot=column:hot,kind=measured"], ["height=column:h"])
    assert text.measured_inputs == ("hot",)
    assert text.inputs == imap.inputs
    assert interface_map_from_text(input_texts(imap), ["height=column:h"]) == imap


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        (_doc("sensor"), "rig.yaml: inputs[0].kind: 'sensor' is not an input kind; use"),
        (_doc(3), "rig.yaml: inputs[0].kind: 3 is not an input kind"),
        (_doc("measured", "outputs"), "rig.yaml: outputs[0].kind: only an input has a kind"),
    ],
)
def test_a_bad_kind_is_a_clear_error(doc: dict[str, object], message: str) -> None:
    with pytest.raises(InterfaceMapError, match="^" + re.escape(message)) as err:
        InterfaceMap.from_dict(doc, "rig.yaml")
    assert "\n" not in str(err.value)
    assert "'measured'" in str(err.value)


@pytest.mark.parametrize(
    ("inputs", "outputs", "message"),
    [
        (["hot=column:hot,kind=noisy"], ["height=column:h"], r"inputs\[0\]: .*'noisy' is not"),
        (["hot=column:hot"], ["height=column:h,kind=measured"], r"outputs\[0\]: .*only an input"),
        (["hot=column:hot,kind=measured,kind=measured"], ["height=column:h"], "given twice"),
    ],
)
def test_a_bad_kind_in_text_is_a_clear_error(
    inputs: list[str], outputs: list[str], message: str
) -> None:
    with pytest.raises(InterfaceMapError, match=message):
        interface_map_from_text(inputs, outputs)


def test_input_noise_is_nan_where_the_gate_did_not_run() -> None:
    stamps, _, logged, y = _noisy()
    first = monitor_record(stamps, logged, y, CONFIG, [load_model("B")], measured_inputs=("hot",))[
        0
    ]
    assert first.quality.state is WindowState.SETTLING
    assert math.isnan(first.input_noise)
    assert math.isnan(first.input_noise_effect)


@pytest.mark.parametrize("kind", ["measured", "commanded"])
def test_validate_a_logged_table_without_period(kind: str, tmp_path, capsys) -> None:
    """The CLI on a CSV of noisy input readings: measured judges, commanded judges nothing."""
    import json  # noqa: PLC0415

    import pandas as pd  # noqa: PLC0415

    from twotank_validation import cli  # noqa: PLC0415

    stamps, _, logged, y = _noisy()
    table = tmp_path / "rig.csv"
    pd.DataFrame(
        {"t": stamps / 1e9, "hot": logged[:, 0], "cold": logged[:, 1], "h": y[:, 0], "T": y[:, 1]}
    ).to_csv(table, index=False)
    extra = f",kind={kind}"
    args = ["validate", str(table), "--model", "B", "--time", "t", "--quiet"]
    args += ["--input", f"hot=column:hot{extra}", "--input", f"cold=column:cold{extra}"]
    args += ["--output", "height=column:h", "--output", "temperature=column:T"]
    out = tmp_path / "v.json"
    code = cli.main([*args, "--json", str(out)])
    err = capsys.readouterr().err
    if kind == "commanded":
        assert code == cli.EXIT_NOT_JUDGED, err
        assert "the commands do not repeat" in err
        return
    assert code == cli.EXIT_OK, err
    doc = json.loads(out.read_text())
    assert doc["timing"]["period_samples"] == CONFIG.period_samples  # inferred, not given
    windows = [w for w in doc["models"]["B"]["windows"] if w["beta"] is not None]
    assert windows
    assert all(w["input_noise"] == pytest.approx(NOISE, rel=0.2) for w in windows)
    assert all(0.0 < w["input_noise_effect"] < 1.0 - w["beta"] for w in windows)
