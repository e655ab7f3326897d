"""Tests of twotank_validation.calibrate: how much uncertainty the data demand of a model set.

References are independent of the calibration's own search:

* the uniform scaling against a brute-force grid: the model file's weight scaled by each grid
  value (a new model built from the document) and validated by ``validate`` on every window;
* the per-bin requirement bin by bin: ``validate`` of the model with the weight scaled to the
  requirement (and 0.1 % below it) against the bin's share of beta, the share recomputed from
  the model without the block;
* the fitted weight's coverage from the written model file's own weight (discretised and
  evaluated here);
* the data: the simulated rig without its mixing delay, where Model A lacks exactly the
  level-to-temperature coupling (beta about 1.33) and Model B lacks nothing material.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from twotank_validation import cli, experiment
from twotank_validation.bags import write_scenario_bag
from twotank_validation.calibrate import (
    CalibrationConfig,
    CalibrationError,
    WindowProblem,
    bin_requirement,
    calibrate,
    calibrate_recording,
    calibration_text,
    choose_blocks,
    fit_weight,
)
from twotank_validation.core import lti
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model, load_model_document, model_from_dict
from twotank_validation.core.validate import solve_bins, total_beta, validate
from twotank_validation.diagnose import split_windows
from twotank_validation.sim import scenario as sc
from twotank_validation.sim.rig import RigParams

TS, PERIOD = 0.1, 2048
TEMP = "temperature_multiplicative"
RIG = RigParams(mixing_delay_s=0.0, noise_std_height=0.003, noise_std_temperature=0.01)


@pytest.fixture(scope="module")
def windows():
    """Six two-period windows of the rig without its mixing delay (the coupling is real)."""
    return experiment.diagnosis_windows(experiment.ExperimentConfig(rig=RIG), 6)


def _datums(ws):
    return [make_datum(w.u, w.y, ts_s=TS, period_samples=PERIOD) for w in ws]


def _scaled_doc(doc: dict, factor: float, index: int = 1) -> dict:
    """The model file with perturbation ``index``'s weight times ``factor`` (its numerator)."""
    new = copy.deepcopy(doc)
    tf = new["perturbations"][index]["weight"]["tf"]
    tf["num"] = [x * factor for x in tf["num"]]
    return new


def _beta(datum, model) -> float:
    """beta of ``model`` on ``datum``: validate's solver and total, without its leakage bound
    (the pulse response of every new model would dominate the brute force's time)."""
    sol = solve_bins(model.response(datum.theta, TS), datum.u_bins, datum.y_bins)
    return total_beta(sol.lower, datum.bin_weights)


def _brute_force(doc: dict, datums, grid: np.ndarray) -> tuple[float, list[float]]:
    """Smallest grid factor with no window invalidated, and the same per window."""
    per_window = [math.inf] * len(datums)
    for s in grid:
        model = model_from_dict(_scaled_doc(doc, float(s)))
        for k, d in enumerate(datums):
            if math.isinf(per_window[k]) and _beta(d, model) <= 1.0:
                per_window[k] = float(s)
        if all(math.isfinite(p) for p in per_window):
            break
    return max(per_window), per_window


@pytest.fixture(scope="module")
def model_a_calibration(windows):
    doc, source = load_model_document("A")
    return doc, calibrate(windows, doc, blocks=[TEMP], source=source)


def test_model_a_scaling_is_the_brute_force_minimum(windows, model_a_calibration):
    """The temperature weight Model A needs: within a 0.5 % grid step of brute force."""
    doc, cal = model_a_calibration
    (block,) = cal.blocks
    assert block.name == TEMP
    grid = np.exp(np.arange(0.0, math.log(4.0), 0.005))  # 1 .. 4 in 0.5 % steps
    s_bf, per_window_bf = _brute_force(doc, _datums(windows), grid)
    assert 1.0 < s_bf < 4.0
    assert s_bf / 1.005 <= block.scaling <= s_bf  # the issue asks for <= 1.1 s_bf
    for got, want in zip(block.window_scaling, per_window_bf, strict=True):
        assert want / 1.005 <= got <= want
    assert "alone (the other blocks as stated), every window needs" in block.used_text()
    assert f"{block.scaling:.3g} × its stated weight" in block.used_text()


def test_model_a_calibrated_model_holds_on_held_out_windows(windows, model_a_calibration, tmp_path):
    """The written model is accepted as it is and no held-out window invalidates it."""
    _, cal = model_a_calibration
    assert cal.document is not None
    path = tmp_path / "a_cal.yaml"
    path.write_text(yaml.safe_dump(cal.document, sort_keys=False))
    model = load_model(path)
    _, held = split_windows(windows)
    betas = [validate(d, model).beta for d in _datums(held)]
    stated = [validate(d, load_model("A")).beta for d in _datums(held)]
    assert all(b > 1.0 for b in stated)
    assert all(b <= 1.0 for b in betas), betas
    np.testing.assert_allclose(cal.judged.beta_after[cal.judged.held_out], betas, rtol=1e-9)


def test_fitted_weight_covers_the_requirement_at_every_excited_bin(model_a_calibration):
    """From the written file's weight: |W(e^{j theta})| >= margin x requirement, bin by bin."""
    _, cal = model_a_calibration
    (block,) = cal.blocks
    fitted = block.fitted
    assert fitted is not None
    assert block.required.size > 0
    model = model_from_dict(cal.document)
    w = lti.discretise(model.perturbations[1].weight, TS)
    mag = np.abs(lti.frequency_response(w, block.theta)[:, 0, 0])
    assert np.all(mag >= fitted.margin * block.required * (1 - 1e-9))
    assert np.any(block.required > 0)
    # stable and minimum phase
    assert np.all(np.roots(fitted.den).real < 0)
    assert np.all(np.roots(fitted.num).real < 0)
    # outside the excited band the weight is flagged as an extrapolation
    lo, hi = cal.band_hz
    assert lo == pytest.approx(block.freqs_hz.min())
    assert hi == pytest.approx(block.freqs_hz.max())
    assert set(cal.extrapolated[TEMP]) == {"dc", "decade_below_band", "nyquist"}
    assert "extrapolated" in calibration_text(cal)


def test_per_bin_requirement_bin_by_bin(windows):
    """Each bin's factor is the smallest that brings its w_min within its share of beta^2."""
    doc, _ = load_model_document("A")
    model = load_model("A")
    datum = _datums(windows[:1])[0]
    (block,) = choose_blocks(model, [TEMP])
    req = bin_requirement(WindowProblem.of(datum, model), block, 1e-4)
    # the share, from the model without the block (weight 0) at the other bins
    no_block = copy.deepcopy(doc)
    no_block["perturbations"][1]["weight"] = {"gain": 0.0}
    without = validate(datum, model_from_dict(no_block)).w_min
    others = np.setdiff1d(np.arange(datum.theta.size), req.bins)
    fixed = float(np.sum(datum.bin_weights[others] * without[others] ** 2))
    share = (1.0 - fixed) / float(np.sum(datum.bin_weights[req.bins]))
    assert req.share == pytest.approx(share, rel=1e-9)
    b = math.sqrt(share)
    assert np.any(req.factor > 0)
    for n, f in zip(req.bins, req.factor, strict=True):
        if f == 0.0:
            assert without[n] <= b
            continue
        at = validate(datum, model_from_dict(_scaled_doc(doc, f * 1.0001))).w_min[n]
        below = validate(datum, model_from_dict(_scaled_doc(doc, f * 0.999))).w_min[n]
        assert at <= b < below, (n, f)


def test_model_b_uses_less_than_its_stated_weight():
    """On the default rig Model B is far from invalidated: say how much of its weight is used."""
    ws = experiment.diagnosis_windows(experiment.ExperimentConfig(), 4)
    doc, source = load_model_document("B")
    cal = calibrate(ws, doc, CalibrationConfig(max_order=1), blocks=[TEMP], source=source)
    (block,) = cal.blocks
    assert 0.0 < block.scaling < 1.0
    datums = _datums(ws)
    above = model_from_dict(_scaled_doc(doc, block.scaling * 1.01))
    below = model_from_dict(_scaled_doc(doc, block.scaling * 0.99))
    assert all(validate(d, above).beta <= 1.0 for d in datums)
    assert any(validate(d, below).beta > 1.0 for d in datums)
    text = calibration_text(cal)
    assert f"{block.scaling:.3g} × its stated weight: the data use {block.scaling:.0%}" in text
    assert f"{1 - block.scaling:.0%} of it is not needed" in text
    assert all(b <= 1.0 for b in cal.judged.beta_after)


def test_weight_fit_recovers_a_first_order_shape():
    """A requirement shaped like a known first-order weight: order <= 1, tight, covering."""
    theta = 2 * np.pi * np.arange(2, 60, 2) / 4096
    w = lti.discretise(lti.from_transfer_function([16.5, 0.1], [20.0, 1.0]), TS)
    known = np.abs(lti.frequency_response(w, theta)[:, 0, 0])
    required = known * np.random.default_rng(1).uniform(0.8, 1.0, theta.size)
    fitted = fit_weight(theta, required, TS, margin=1.1)
    assert fitted.order <= 1
    assert np.all(fitted.magnitude >= 1.1 * required * (1 - 1e-9))
    assert fitted.mean_excess_db < 20 * math.log10(1.1 / 0.8) + 1.0
    zero = fit_weight(theta, np.zeros(theta.size), TS)
    assert zero.order == 0
    assert zero.gain == 0.0
    with pytest.raises(Exception, match="finite and >= 0"):
        fit_weight(theta, np.full(theta.size, np.inf), TS)


def test_errors_name_the_fix(windows):
    doc, _ = load_model_document("A")
    with pytest.raises(CalibrationError, match="no judged window"):
        calibrate([], doc)
    with pytest.raises(CalibrationError, match=r"no block 'nonsense'.*height_multiplicative"):
        calibrate(windows, doc, blocks=["nonsense"])
    with pytest.raises(CalibrationError, match="margin"):
        CalibrationConfig(margin=0.5)


# --------------------------------------------------------------------------- recordings


def test_calibrate_command_on_a_bag(tmp_path: Path, capsys):
    """The documented command: text, JSON, figures and a model file the validator accepts."""
    scen = sc.Scenario(name="cal", duration_s=204.8 * 9, mixing_delay_s=0.0)
    bag = tmp_path / "bag"
    write_scenario_bag(scen, bag)
    out_json, out_model, report = tmp_path / "c.json", tmp_path / "a_cal.yaml", tmp_path / "rep"
    code = cli.main(
        ["calibrate", str(bag), "--model", "A", "--block", TEMP, "--json", str(out_json),
         "--report", str(report), "--out-model", str(out_model), "--quiet"]
    )  # fmt: skip
    assert code == cli.EXIT_OK
    out = json.loads(out_json.read_text())
    (block,) = out["blocks"]
    assert block["name"] == TEMP
    assert block["scaling"] > 1.0
    assert out["model_file"] == str(out_model)
    held = [j for j in out["judged"] if j["held_out"]]
    assert held
    assert all(j["beta"] > 1.0 and j["beta_after"] <= 1.0 for j in held)
    for name in ("calibration.md", "calibration_beta.png", "calibration_weights.png"):
        assert (report / name).stat().st_size > 0
    model = load_model(out_model)
    assert model.name == "A_calibrated"
    assert f"{block['scaling']:.3g} × its stated weight" in capsys.readouterr().out
    # the same through the core API
    doc, source = load_model_document("A")
    cal, _ = calibrate_recording(bag, doc, blocks=[TEMP], source=source)
    assert cal.blocks[0].scaling == pytest.approx(block["scaling"], rel=1e-9)
    # --together: both output blocks scaled as one problem; text, JSON, figures, model file
    joint_json, joint_model = tmp_path / "j.json", tmp_path / "a_joint.yaml"
    code = cli.main(
        ["calibrate", str(bag), "--model", "A", "--together", "--block", "height_multiplicative",
         "--block", TEMP, "--json", str(joint_json), "--report", str(tmp_path / "jrep"),
         "--out-model", str(joint_model), "--quiet"]
    )  # fmt: skip
    assert code == cli.EXIT_OK
    joint = json.loads(joint_json.read_text())["joint"]
    assert joint["blocks"] == ["height_multiplicative", TEMP]
    written = joint["written"]
    new = load_model_document(str(joint_model))[0]
    for i, name in enumerate(joint["blocks"]):
        num = new["perturbations"][i]["weight"]["tf"]["num"]
        stated = doc["perturbations"][i]["weight"]["tf"]["num"]
        assert np.allclose(np.asarray(num) / np.asarray(stated), written[name], rtol=1e-9)
    assert (tmp_path / "jrep" / "calibration_weights.png").stat().st_size > 0
    assert "the common factor" in capsys.readouterr().out


def test_calibrate_command_reports_problems(tmp_path: Path, capsys):
    scen = sc.Scenario(name="short", duration_s=204.8 * 2, mixing_delay_s=0.0)
    bag = tmp_path / "short"
    write_scenario_bag(scen, bag)
    assert cli.main(["calibrate", str(bag), "--model", "A", "--quiet"]) == cli.EXIT_NOT_JUDGED
    assert "no window of model A could be judged" in capsys.readouterr().err
    doc, _ = load_model_document("A")
    with pytest.raises(CalibrationError, match="no window of model A could be judged"):
        calibrate_recording(bag, doc)
    code = cli.main(["calibrate", str(bag), "--model", "A", "--block", "nonsense", "--quiet"])
    assert code == cli.EXIT_ERROR
    assert "no block 'nonsense'" in capsys.readouterr().err
