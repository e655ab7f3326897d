"""Tests of twotank_validation.diagnose.stretches: changes inside a recording, transients.

References are the simulated rig's injected faults, independent of the diagnosis code: the
fault's onset (the change time must lie within one window of it), its kind and magnitude
(the sensor delay the rig adds; the leak rate lambda / A1 of a level-proportional leak, as
in test_diagnose), and the rig's 15 s mixing delay (which Model B lacks) before the fault.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from twotank_validation import cli
from twotank_validation.bags import write_scenario_bag
from twotank_validation.core.model import load_model_document
from twotank_validation.diagnose import Window
from twotank_validation.diagnose.stretches import (
    ChangeConfig,
    WindowFindings,
    diagnose_stretches,
    find_stretches,
    split_statistic,
    window_features,
)
from twotank_validation.sim import scenario as sc

A1 = 91.4
TS, P = 0.1, 2048
WINDOW_S = 2 * P * TS  # two periods per window, as the validator's default
OUTPUTS = ("height", "temperature")
DOC, SOURCE = load_model_document("B")
# each stretch's effect is judged with the tolerance of test_diagnose's checks (15 %): the
# fitted parameters land within a few per cent on these records; 15 % leaves room for the
# noise of the 2-3 held-out windows of a stretch of a 40-minute recording


def sim_windows(
    faults: tuple[str, ...] = (),
    *,
    n: int = 10,
    periods: int = 2,
    seed: int = 0,
    mixing_delay_s: float = 15.0,
    leak_per_level: float = 0.0,
) -> list[Window]:
    """Simulated rig data cut into ``n`` windows of ``periods`` periods after one of settling.

    The validator's defaults: one settling period, then windows of whole periods.
    """
    scen = sc.Scenario(
        name="stretch",
        duration_s=P * TS * (1 + periods * n),
        rms_hot=0.1,
        rms_cold=0.1,
        cutoff_hz=0.01,
        mixing_delay_s=mixing_delay_s,
        leak_per_level=leak_per_level,
        faults=faults,
        seed=seed,
        excitation_seed=seed + 2,
    )
    _, u, y = sc.simulate_scenario(scen)
    m = periods * P
    return [
        Window(u[P + i * m : P + (i + 1) * m], y[P + i * m : P + (i + 1) * m], TS, P,
               (P + i * m) * TS)
        for i in range(n)
    ]  # fmt: skip


def stretches_of(windows: list[Window]) -> list:
    return find_stretches(window_features(windows, DOC, source=SOURCE), OUTPUTS)


def delay_of(diag) -> float:
    (effect,) = diag.effects
    assert (effect.spec.kind, diag.outputs[effect.spec.channel]) == ("delay", "temperature")
    return float(effect.values[0])


# --------------------------------------------------------------------------- change times


@pytest.mark.parametrize(
    ("fault", "onset"),
    [
        ("sensor_delay:temperature=20@1500", 1500.0),
        ("leak=0.04@2100", 2100.0),
        ("valve_weak:hot=0.7@1300", 1300.0),
        ("sensor_bias:height=0.02@1800", 1800.0),
    ],
)
def test_a_fault_mid_recording_is_one_change_within_a_window_of_its_onset(fault, onset):
    ws = sim_windows((fault,))
    found = stretches_of(ws)
    changes = [s.change_at_s for s in found if s.change_at_s is not None]
    assert len(changes) == 1, [(s.change_at_s, s.evidence) for s in found]
    assert abs(changes[0] - onset) <= WINDOW_S, changes
    # the first stretch is wholly before the onset, the second's diagnosed windows after it
    before, after = found
    assert before.change_at_s is None
    assert not before.skipped
    assert all(ws[i].start_s + WINDOW_S <= onset for i in before.windows)
    assert all(ws[i].start_s >= onset for i in after.windows)
    assert after.evidence


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nominal_data_has_no_change(seed):
    """The rig without a fault: one stretch; at most the excitation's start-up is skipped.

    After one settling period the response to the excitation's start can still drift a
    little in the first window (the datum's transient finding): skipped, but no change.
    """
    (only,) = stretches_of(sim_windows(seed=seed))
    assert only.change_at_s is None
    assert only.windows == list(range(len(only.skipped), 10))
    assert all(why.startswith("transient") for _, why in only.skipped)
    assert len(only.skipped) <= 1


def test_split_statistic_is_the_brute_force_likelihood_ratio():
    """Against the two-segment Gaussian log-likelihood ratio computed split by split."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=(9, 3))
    x[6:] += [0.0, 2.0, -1.0]
    sigma = np.array([1.0, 0.5, 2.0])
    k, s = split_statistic(x, sigma)

    def rss(seg: np.ndarray) -> float:
        return float(np.sum(((seg - seg.mean(0)) / sigma) ** 2))

    lr = [rss(x) - rss(x[:j]) - rss(x[j:]) for j in range(1, 9)]
    assert k == 1 + int(np.argmax(lr))
    assert s == pytest.approx(max(lr))


# --------------------------------------------------------------------------- effects


def test_sensor_delay_mid_recording_each_stretch_has_its_own_delay():
    """The issue's case: 15 s (the rig's mixing delay) before, 35 s after, 20 s the change."""
    rec = diagnose_stretches(sim_windows(("sensor_delay:temperature=20@1500",)), DOC, source=SOURCE)
    first, second = rec.stretches
    assert first.relative_to_previous is None
    assert delay_of(first.relative_to_model) == pytest.approx(15.0, rel=0.15)
    assert delay_of(second.relative_to_model) == pytest.approx(35.0, rel=0.15)
    assert delay_of(second.relative_to_previous) == pytest.approx(20.0, rel=0.15)
    assert abs(second.stretch.change_at_s - 1500.0) <= WINDOW_S
    doc = rec.to_json()
    assert [c["at_s"] for c in doc["changes"]] == [second.stretch.change_at_s]
    entry = doc["stretches"][1]
    assert entry["relative_to_previous"]["effects"][0]["kind"] == "delay"
    assert {s["start_s"] for s in entry["skipped"]}.isdisjoint(entry["windows"])


def test_leak_mid_recording_is_found_after_the_change_only():
    """A level-proportional leak (the catalogue's leak) that appears between two windows.

    The rig's ``leak`` fault is a constant outflow: it moves the operating point but not the
    level dynamics. The level-proportional leak is a rig parameter, so the recording is the
    rig without it for four windows and with it (inflows retuned to hold the level) after,
    the same excitation going on; the mixing delay is 0 so that Model B is right before.
    """
    lam = 0.6
    ws = (
        sim_windows(mixing_delay_s=0.0)[:4]
        + sim_windows(mixing_delay_s=0.0, leak_per_level=lam)[4:]
    )
    rec = diagnose_stretches(ws, DOC, source=SOURCE)
    first, second = rec.stretches
    assert second.stretch.change_at_s == pytest.approx(ws[4].start_s)
    assert first.relative_to_model.adequate
    (leak,) = second.relative_to_model.effects
    assert leak.spec.kind == "leak"
    assert leak.values[0] == pytest.approx(lam / A1, rel=0.15)
    # the stretch before needed nothing: both answers name the same leak, and the leak's own
    # shift of the operating point is not taken for a sensor offset
    changed = second.relative_to_previous
    assert [e.spec.kind for e in changed.effects] == ["leak"]
    assert changed.effects[0].values[0] == pytest.approx(leak.values[0], rel=1e-9)
    assert not changed.findings


def test_valve_loss_mid_recording_is_an_input_gain_relative_to_the_stretch_before():
    """``valve_weak:hot=0.9``: the hot valve delivers 90 % of its flow after the onset.

    Relative to the stretch before (the rig's 15 s mixing delay already in it), what changed
    is the hot input's gain, g = 0.9 - 1 = -0.1, and nothing else: the level falls by 0.05
    at the same commands, which the input gain explains at steady state (no offset). The
    tolerance, 0.02, allows for the linear model read 0.05 away from its operating point
    (measured -0.087).
    """
    rec = diagnose_stretches(sim_windows(("valve_weak:hot=0.9@1300",)), DOC, source=SOURCE)
    first, second = rec.stretches
    assert abs(second.stretch.change_at_s - 1300.0) <= WINDOW_S
    changed = second.relative_to_previous
    (gain,) = changed.effects
    assert (gain.spec.kind, gain.to_dict(changed.outputs)["channel"]) == ("input_gain", "hot")
    assert gain.values[0] == pytest.approx(-0.1, abs=0.02)
    assert not changed.findings  # the level's fall is the valve's, not a sensor offset
    assert not any(e.spec.kind == "input_gain" for e in first.relative_to_model.effects)


def test_sensor_bias_mid_recording_is_an_offset_relative_to_the_stretch_before():
    """``sensor_bias:height=0.02``: the level reads 0.02 high after the onset.

    A constant offset leaves the de-biased dynamics as they were; relative to the stretch
    before (its steady means as the reference operating point) it is an output offset of
    0.02 on the level (tolerance 0.002, test_diagnose_catalogue's).
    """
    rec = diagnose_stretches(sim_windows(("sensor_bias:height=0.02@1800",)), DOC, source=SOURCE)
    first, second = rec.stretches
    changed = second.relative_to_previous
    offsets = [f for f in changed.findings if f.kind == "offset"]
    assert [f.target for f in offsets] == ["height"], changed.summary
    assert offsets[0].parameters["offset"] == pytest.approx(0.02, abs=0.002)
    assert not changed.effects  # the dynamics did not change
    assert not [f for f in first.relative_to_model.findings if f.kind == "offset"]


def test_leak_from_the_first_window_skips_its_transient_and_is_not_adequate():
    """A leak from t = 0: the level still settles in the first window, which is skipped.

    The settled windows are diagnosed; the leak lowers the level, so the temperature
    responds more strongly (1/h) and Model B is not adequate for them.
    """
    ws = sim_windows(("leak=0.1@0",), n=6, mixing_delay_s=0.0)
    rec = diagnose_stretches(ws, DOC, source=SOURCE)
    (only,) = rec.stretches
    assert only.skipped[0][0] == pytest.approx(ws[0].start_s)
    assert "transient" in only.skipped[0][1]
    assert ws[0].start_s not in only.window_starts_s
    assert not only.relative_to_model.adequate
    assert rec.changes == []


def test_the_validators_transient_finding_is_used_and_a_short_stretch_is_listed():
    """Findings handed along mark windows to skip; a stretch too short says why."""
    ws = sim_windows(("sensor_bias:height=0.05@2400",), n=12, periods=1)
    flagged = 2
    findings = [
        WindowFindings(warnings=("output mean drifts by up to 0.3 of its RMS",))
        if i == flagged
        else WindowFindings()
        for i in range(len(ws))
    ]
    rec = diagnose_stretches(ws, DOC, findings, source=SOURCE)
    first = rec.stretches[0]
    assert (ws[flagged].start_s, "transient: output mean drifts by up to 0.3 of its RMS") in (
        first.skipped
    )
    last = rec.stretches[-1]
    assert abs(last.stretch.change_at_s - 2400.0) <= P * TS
    assert last.relative_to_model is None
    assert "one period" in last.not_diagnosed
    assert rec.current is first


def test_change_config_refuses_nonsense():
    with pytest.raises(ValueError, match="alpha"):
        ChangeConfig(alpha=1.5)


# --------------------------------------------------------------------------- the command


@pytest.fixture(scope="module")
def delay_bag(tmp_path_factory) -> Path:
    scen = sc.Scenario(
        name="mid",
        duration_s=P * TS * 13,
        rms_hot=0.1,
        rms_cold=0.1,
        cutoff_hz=0.01,
        faults=("sensor_delay:temperature=20@1100",),
    )
    bag = tmp_path_factory.mktemp("bags") / "mid"
    write_scenario_bag(scen, bag)
    return bag


def test_diagnose_command_lists_the_stretches(delay_bag: Path, tmp_path: Path, capsys):
    out = tmp_path / "d.json"
    assert cli.main(["diagnose", str(delay_bag), "--model", "B", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert len(doc["changes"]) == 1
    assert abs(doc["changes"][0]["at_s"] - 1100.0) <= WINDOW_S
    assert len(doc["stretches"]) == 2
    # the top-level diagnosis is the last stretch's, relative to the model
    assert doc["stretch"] == 1
    assert doc["effects"][0]["parameters"]["delay_s"] == pytest.approx(35.0, rel=0.15)
    assert doc["stretches"][1]["relative_to_model"]["summary"] == doc["summary"]
    text = capsys.readouterr().out
    assert "stretch 2:" in text
    assert "changed at" in text


def test_diagnose_command_start_end_select_a_stretch(delay_bag: Path, tmp_path: Path, capsys):
    out = tmp_path / "d.json"
    # ISO form of 1400 s after the bag's start (its log times start at the epoch)
    args = ["diagnose", str(delay_bag), "--model", "B", "--json", str(out)]
    assert cli.main([*args, "--start", "1970-01-01T00:23:20Z"]) == 0
    doc = json.loads(out.read_text())
    assert doc["segmented"] is False
    assert doc["changes"] == []
    (only,) = doc["stretches"]
    assert min(only["windows"]) >= 1400.0
    assert doc["effects"][0]["parameters"]["delay_s"] == pytest.approx(35.0, rel=0.15)
    assert cli.main([*args, "--end", "1100"]) == 0
    doc = json.loads(out.read_text())
    assert doc["effects"][0]["parameters"]["delay_s"] == pytest.approx(15.0, rel=0.15)
    capsys.readouterr()
    for bad, words in (
        (["--start", "900", "--end", "800"], "before it starts"),
        (["--start", "9000"], "outside the recording"),
        (["--start", "1500", "--end", "1700"], "no whole judged window"),
        (["--start", "yesterday"], "ISO 8601"),
    ):
        assert cli.main([*args, *bad]) == cli.EXIT_ERROR, bad
        assert words in capsys.readouterr().err, bad
