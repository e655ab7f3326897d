"""Joint calibration: several blocks scaled together, against a brute-force grid.

The data: the simulated rig without its mixing delay (Model A lacks the level-to-temperature
coupling) and with a tank area of 60 instead of 91.4 (Model A's height dynamics are wrong
too), so the error lies on both outputs: neither output's multiplicative block explains every
window alone (the other as stated), both together do. The reference scales the weights in the
model *document* (a new model per grid point) and validates every window with the window
solver, independently of the calibration's plant-column scaling and search.
"""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest

from twotank_validation import experiment
from twotank_validation.calibrate import (
    CalibrationConfig,
    WindowProblem,
    calibrate,
    calibration_text,
    choose_blocks,
    window_scaling,
)
from twotank_validation.calibrate.joint import common_scaling, joint_scaling
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model_document, model_from_dict
from twotank_validation.core.validate import solve_bins, total_beta
from twotank_validation.sim.rig import RigParams

TS, PERIOD = 0.1, 2048
BLOCKS = ["height_multiplicative", "temperature_multiplicative"]
RIG = RigParams(area=60.0, mixing_delay_s=0.0, noise_std_height=0.003, noise_std_temperature=0.01)


@pytest.fixture(scope="module")
def case():
    ws = experiment.diagnosis_windows(experiment.ExperimentConfig(rig=RIG), 2)
    datums = [make_datum(w.u, w.y, ts_s=TS, period_samples=PERIOD) for w in ws]
    doc, source = load_model_document("A")
    model = model_from_dict(doc, source)
    problems = [WindowProblem.of(d, model) for d in datums]
    return doc, datums, problems, choose_blocks(model, BLOCKS)


def _feasible(doc: dict, datums, factors: tuple[float, float]) -> bool:
    """Every window valid with perturbation i's weight (a tf) times factors[i], from the file."""
    new = copy.deepcopy(doc)
    for i, f in enumerate(factors):
        tf = new["perturbations"][i]["weight"]["tf"]
        tf["num"] = [x * f for x in tf["num"]]
    model = model_from_dict(new)
    for d in datums:
        sol = solve_bins(model.response(d.theta, TS), d.u_bins, d.y_bins)
        if total_beta(sol.lower, d.bin_weights) > 1.0:
            return False
    return True


def test_each_block_alone_cannot_explain_the_windows(case):
    """The premise: one block at a time (the other as stated) finds no factor at all."""
    _, _, problems, blocks = case
    for b in blocks:
        assert math.isinf(max(window_scaling(p, b) for p in problems))


def test_common_factor_against_a_grid(case):
    """The common factor is the grid's smallest feasible common scale to 0.5 %, and
    feasibility along the grid flips once (beta is monotone in a common scale)."""
    doc, datums, problems, blocks = case
    common, _ = common_scaling(problems, blocks)
    grid = np.exp(np.arange(math.log(2.0), math.log(20.0), 0.005))
    flags = [_feasible(doc, datums, (float(c), float(c))) for c in grid[::20]]
    assert flags == sorted(flags)  # False ... False True ... True
    i = flags.index(True)
    fine = grid[max(0, 20 * i - 20) : 20 * i + 1]
    first = next(float(c) for c in fine if _feasible(doc, datums, (float(c), float(c))))
    assert first / 1.005 <= common <= first


def test_joint_factors_against_a_brute_force_grid(case):
    """On a 10 % grid of both factors: no feasible grid point has a smaller sum of squares
    than the joint answer; the answer is feasible, and 1 % below it is not (on the frontier);
    the grid's best feasible point is within a grid step of the answer's objective."""
    doc, datums, problems, blocks = case
    joint = joint_scaling(problems, blocks)
    s = joint.factors
    assert all(0.0 < f < math.inf for f in s)
    assert joint.objective <= 2.0 * joint.common**2  # no worse than the common factor
    assert _feasible(doc, datums, s)
    assert not _feasible(doc, datums, (0.99 * s[0], 0.99 * s[1]))
    grid = np.exp(np.arange(math.log(2.0), math.log(16.0), math.log(1.1)))
    best = math.inf
    for a in grid:
        for b in grid:
            obj = a * a + b * b
            if obj < joint.objective * 0.999 and _feasible(doc, datums, (a, b)):
                pytest.fail(
                    f"grid point ({a:.3g}, {b:.3g}) is feasible with {obj:.4g} < "
                    f"{joint.objective:.4g}"
                )
            if (
                obj < best
                and obj < 1.21 * 1.21 * joint.objective
                and _feasible(doc, datums, (a, b))
            ):
                best = obj
    assert best <= 1.21 * 1.21 * joint.objective


def test_calibrate_together_writes_the_joint_factors(case):
    """``calibrate`` with ``together``: the file's weights are the stated ones times the fit
    windows' joint factors times the margin (read back from the document), the held-out
    window is valid with them, and the text and JSON say so."""
    doc, datums, _, _ = case
    ws = experiment.diagnosis_windows(experiment.ExperimentConfig(rig=RIG), 2)
    cal = calibrate(ws, doc, CalibrationConfig(together=True), blocks=BLOCKS)
    assert cal.joint is not None
    assert cal.document is not None
    assert all(math.isinf(b.scaling) for b in cal.blocks)  # alone: no answer
    written = cal.joint.written
    assert written is not None
    for i, f in enumerate(written):
        got = cal.document["perturbations"][i]["weight"]["tf"]["num"]
        want = doc["perturbations"][i]["weight"]["tf"]["num"]
        assert np.allclose(np.asarray(got) / np.asarray(want), f, rtol=1e-12)
        assert f == pytest.approx(1.2 * cal.joint.fit.factors[i], rel=1e-12)
    assert _feasible(doc, datums[1:], written)  # the held-out window
    assert cal.judged.held_out.tolist() == [False, True]
    assert np.all(cal.judged.beta_after <= 1.0)
    assert np.all(cal.judged.beta > 1.0)
    out = json.loads(json.dumps(cal.to_json()))
    assert out["joint"]["written"] == dict(zip(BLOCKS, written, strict=True))
    text = calibration_text(cal)
    assert "the common factor" in text
    assert "joint factors" in text
