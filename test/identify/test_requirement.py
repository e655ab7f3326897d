"""The report's per-line requirement, its figures and its JSON.

References: a plant ``H = (1 + a) G`` built from a known nominal and a known relative error
``a(f)`` per input (the requirement is ``max_i |a_i|`` in closed form), a brute-force search
over weights and perturbations for its lower end; a white noise (the noise requirement is the
flat weight at every line); and, on a simulated 1 x 3 plant, the identification's own arrays
and the model file it writes (read back through the model loader, evaluated at the lines).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_pipeline import N, _window

from twotank_validation.calibrate.calibration import CalibrationConfig, calibrate
from twotank_validation.core import lti
from twotank_validation.core.model import model_from_dict
from twotank_validation.identify.figures import FIGURES, write_identify_report
from twotank_validation.identify.pipeline import IdentifyConfig, identified_model, identify_windows
from twotank_validation.identify.requirement import (
    LEVEL,
    noise_requirement,
    output_noise_at_lines,
    perturbation_requirement,
    report_numbers,
    validation_requirement,
)
from twotank_validation.usecases.identify import identification_json

OUTPUTS = ["p_in", "p_out", "flow"]


def _plant(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A 2 x 2 nominal and its relative error ``a`` (L, 2, 2) per input, both known."""
    s = 2j * np.pi * f[:, None, None]
    g = np.array([[1.0, 0.5], [-0.3, 2.0]])[None] / (1.0 + s * np.array([[1.0], [0.2]])[None])
    a = np.empty_like(g)
    a[:, :, 0] = (0.05 + 0.3 * s[:, :, 0] / (s[:, :, 0] + 1.0)) * np.array([1.0, 0.5])
    a[:, :, 1] = 0.1 * np.exp(1j * f[:, None])  # flat, a phase that turns
    return g, a


def test_the_requirement_is_the_relative_error_in_closed_form():
    f = np.logspace(-2, 1, 40)
    g, a = _plant(f)
    measured = (1.0 + a) * g
    req = perturbation_requirement(measured, np.zeros(g.shape), g)
    np.testing.assert_allclose(req.entry, np.abs(a), rtol=1e-12)
    np.testing.assert_allclose(req.required, np.abs(a).max(axis=2), rtol=1e-12)
    np.testing.assert_array_equal(req.lo, req.required)
    # a disc of radius ρ about the measured response: the interval is |a| ∓ ρ/|G|
    rho = 0.04 * np.abs(g)
    req = perturbation_requirement(measured, rho, g)
    np.testing.assert_allclose(req.entry_hi, np.abs(a) + 0.04, rtol=1e-12)
    np.testing.assert_allclose(req.entry_lo, np.maximum(np.abs(a) - 0.04, 0.0), atol=1e-15)


def test_the_lower_end_is_the_smallest_weight_some_perturbation_explains_brute_force():
    """min |W| such that some |δ| <= 1 puts (1 + W δ) G inside the measured disc."""
    f = np.array([0.05, 0.3, 2.0])
    g, a = _plant(f)
    measured = (1.0 + a) * g
    rho = 0.03 * np.abs(g)
    req = perturbation_requirement(measured, rho, g)
    r, phi = np.meshgrid(np.linspace(0.0, 1.0, 41), np.linspace(0, 2 * np.pi, 1441))
    delta = (r * np.exp(1j * phi)).ravel()  # the unit disc, searched point by point
    for k in range(f.size):
        for c in range(2):
            for i in range(2):
                err, gk, rk = measured[k, c, i] - g[k, c, i], g[k, c, i], rho[k, c, i]

                def explains(
                    w: float, err: complex = err, gk: complex = gk, rk: float = rk
                ) -> bool:
                    return bool(np.min(np.abs(err - w * delta * gk)) <= rk)

                lo, hi = 0.0, 1.0  # bisection: more weight never explains less
                if explains(0.0):
                    hi = 0.0
                for _ in range(20):
                    mid = 0.5 * (lo + hi)
                    lo, hi = (lo, mid) if explains(mid) else (mid, hi)
                brute = hi
                assert brute == pytest.approx(req.entry_lo[k, c, i], abs=1e-5)


def test_a_white_noise_needs_the_flat_weight_at_every_line_and_a_coloured_one_follows_it():
    gains = np.array([0.02, 0.5])
    var = np.full((30, 2), 4.0)
    np.testing.assert_allclose(noise_requirement(var, gains), np.broadcast_to(gains, (30, 2)))
    shape = np.linspace(1.0, 3.0, 30)
    var = np.stack([shape**2, 7.0 * shape**2], axis=1)
    got = noise_requirement(var, gains)
    rms = np.sqrt(np.mean(shape**2))
    np.testing.assert_allclose(got, shape[:, None] / rms * gains[None], rtol=1e-12)


@pytest.fixture(scope="module")
def identified():
    windows = [_window(1), _window(2)]
    ident = identify_windows(windows, IdentifyConfig(orders=range(1, 6)))
    made = identified_model(ident, windows, "identified", ["pump"], OUTPUTS)
    lines = ident.response.lines
    nums = report_numbers(
        ident,
        made,
        OUTPUTS,
        output_noise_at_lines(ident, windows),
        validation_requirement(windows, made.document, lines, OUTPUTS),
    )
    return ident, made, nums


def test_the_written_weights_cover_the_requirement_where_the_scaling_says_so(identified):
    ident, made, nums = identified
    # the central requirement is the fit's relative error the weight shapes are fitted over
    np.testing.assert_allclose(nums.perturbation.required, ident.relative_error, rtol=1e-12)
    # the written weights, read back from the model file and evaluated as validate does
    model = model_from_dict(made.document)
    theta = 2 * np.pi * ident.response.lines / N
    written = np.zeros_like(nums.weight)
    for p in model.perturbations:
        (c,) = p.outputs
        written[:, c] = np.abs(lti.bin_response(p.weight, theta, 0.1, model.intersample)[:, 0, 0])
    np.testing.assert_allclose(nums.weight, written, rtol=1e-9)
    np.testing.assert_array_equal(nums.covered, written >= nums.perturbation.required * (1 - 1e-9))
    # the shapes cover the requirement; a factor of 1 or more on them keeps it covered
    factors = np.asarray(made.factors) * 1.2 if made.calibrated else np.full(len(OUTPUTS), 1.2)
    for c in range(len(OUTPUTS)):
        if factors[c] >= 1.0:
            assert nums.covered[:, c].all(), OUTPUTS[c]


def test_the_report_writes_its_figures_and_the_json_holds_their_numbers(identified, tmp_path):
    ident, made, nums = identified
    paths = write_identify_report(ident, made, nums, tmp_path, inputs=["pump"], outputs=OUTPUTS)
    assert sorted(Path(p).name for p in paths) == sorted(
        f"{s}.{e}" for s in FIGURES for e in ("pdf", "png")
    )
    for p in paths:
        head = Path(p).read_bytes()[:8]
        assert head.startswith(b"%PDF" if p.endswith(".pdf") else b"\x89PNG")
    doc = json.loads(json.dumps(identification_json(ident, made, None, nums)))["report"]
    fr = ident.response

    def cplx(x: list) -> np.ndarray:
        arr = np.asarray(x)
        return arr[..., 0] + 1j * arr[..., 1]

    np.testing.assert_array_equal(doc["freqs_hz"], fr.freqs_hz)
    np.testing.assert_array_equal(cplx(doc["measured"]), fr.g)
    np.testing.assert_allclose(doc["std_noise"], np.sqrt(ident.var_noise), rtol=1e-15)
    np.testing.assert_allclose(
        np.hypot(doc["std_noise"], doc["std_distortion"]), np.sqrt(fr.var), rtol=1e-12
    )
    np.testing.assert_allclose(doc["radius"], fr.radius(LEVEL), rtol=1e-15)
    np.testing.assert_array_equal(cplx(doc["nominal"]), ident.fit.response(fr.freqs_hz))
    pert = doc["perturbation"]
    np.testing.assert_allclose(pert["required"], ident.relative_error, rtol=1e-12)
    np.testing.assert_array_equal(pert["weight"], nums.weight)
    np.testing.assert_array_equal(pert["covered"], nums.covered)
    assert nums.validation_required is not None
    np.testing.assert_array_equal(pert["calibrate_required"], nums.validation_required)
    np.testing.assert_array_equal(pert["calibrate_covered"], nums.validation_covered)
    np.testing.assert_array_equal(doc["noise"]["weight"], made.noise.gains)
    assert np.asarray(doc["noise"]["required"]).shape == (fr.freqs_hz.size, len(OUTPUTS))


def test_calibrates_per_bin_requirement_is_reported_at_the_lines_and_marked_where_unmet():
    """An order-1 nominal of the 1 x 3 plant: its error needs the perturbation weights."""
    windows = [_window(1), _window(2)]
    ident = identify_windows(windows, IdentifyConfig(orders=range(1, 2)))
    made = identified_model(ident, windows, "identified", ["pump"], OUTPUTS)
    assert made.calibrated
    lines = ident.response.lines
    need = validation_requirement(windows, made.document, lines, OUTPUTS)
    nums = report_numbers(ident, made, OUTPUTS, None, need)
    assert need is not None
    assert nums.validation_covered is not None
    # calibrate's own requirement on the first block, through its public entry
    first = f"{OUTPUTS[0]}_multiplicative"
    cal = calibrate(windows, made.document, CalibrationConfig(together=False), blocks=[first])
    (block,) = cal.blocks
    # (calibrate judges every bin with input power; the response keeps the excited lines)
    mine = np.round(ident.response.freqs_hz * N * 0.1).astype(int)
    theirs = np.round(block.freqs_hz * N * 0.1).astype(int)
    common, at, there = np.intersect1d(mine, theirs, return_indices=True)
    assert common.size == mine.size
    np.testing.assert_allclose(need[at, 0], block.required[there], rtol=1e-9)
    assert np.any(need[:, 0] > 0.0)
    # the written weight (from the model file) against it, line by line
    model = model_from_dict(made.document)
    theta = 2 * np.pi * lines / N
    for p in model.perturbations:
        (c,) = p.outputs
        mag = np.abs(lti.bin_response(p.weight, theta, 0.1, model.intersample)[:, 0, 0])
        expect = mag >= np.nan_to_num(need[:, c], nan=0.0) * (1 - 1e-9)
        np.testing.assert_array_equal(nums.validation_covered[:, c], expect)
    # the fit windows stay valid, as calibrate's scaling promises
    assert np.all(made.beta[~made.held_out] <= 1.0 + 1e-9)
