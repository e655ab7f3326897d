"""The simulated 1x3 structure (``sim.structure``): a chain of masses with a cubic spring.

References: the fixed-free uniform chain's natural frequencies in closed form; the linear
chain's response to a held force from ``scipy.signal.cont2discrete`` (zero-order hold) of the
state space the test builds from the mass and stiffness matrices itself, at the excited
lines, against the simulator at ``k_c = 0``; the model file against the same matrices. Then
the recordings ``simulate --structure`` writes, judged by ``validate --band``: the nominal is
not invalidated in the band at a low level and is at a high one, β grows with the level, and
over every bin a middle level is already invalid where the band is not (the cubic spring's
intermodulation lines fall outside the band too, the largest just below 2 Hz).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.signal

from twotank_validation import cli
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model
from twotank_validation.core.validate import validate
from twotank_validation.errors import ModelError
from twotank_validation.sim import structure as st
from twotank_validation.sim.model_record import interface_map_path

MODEL_FILE = Path(__file__).parents[1] / "data" / "models" / "structure_1x3.yaml"
BAND = {"min_hz": 2.0, "max_hz": 15.0}
K, M, DAMPING = 1800.0, 1.0, 1e-3  # the defaults, restated: the reference builds its own


def _reference_ss() -> tuple[np.ndarray, ...]:
    """The uniform chain (spring 1 to the ground, force on mass 3), built here by hand."""
    stiff = K * np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    a = np.block([[np.zeros((3, 3)), np.eye(3)], [-stiff / M, -DAMPING * stiff / M]])
    b = np.array([[0.0], [0.0], [0.0], [0.0], [0.0], [1.0 / M]])
    c = np.hstack([1000.0 * np.eye(3), np.zeros((3, 3))])  # mm
    return a, b, c, np.zeros((3, 1))


def _held_response(ts_s: float, theta: np.ndarray) -> np.ndarray:
    """(n, 3) ``Cd (z I - Ad)^-1 Bd`` at ``z = e^{j theta}``: scipy's zero-order hold."""
    ad, bd, cd, _, _ = scipy.signal.cont2discrete(_reference_ss(), ts_s, method="zoh")
    eye = np.eye(len(ad))
    return np.array([(cd @ np.linalg.solve(np.exp(1j * t) * eye - ad, bd))[:, 0] for t in theta])


def test_modes_are_the_uniform_chains_closed_form() -> None:
    f, zeta = st.StructureParams().modes()
    j = np.arange(1, 4)
    wn = 2.0 * np.sqrt(K / M) * np.sin((2 * j - 1) * np.pi / 14)  # fixed-free, 3 masses
    np.testing.assert_allclose(f, wn / (2 * np.pi), rtol=1e-9)
    np.testing.assert_allclose(zeta, DAMPING * wn / 2, rtol=1e-9)
    assert np.all((f > 2.0) & (f < 15.0))  # several modes in the band


def test_linear_simulation_is_the_held_force_response_at_the_excited_lines() -> None:
    cfg = st.StructureConfig(
        params=st.StructureParams(cubic_n_per_m3=0.0),
        ts_s=0.005,
        period_samples=512,
        periods=1,
        displacement_noise_mm=0.0,
        force_noise=0.0,
    )
    run = st.simulate_structure(cfg)
    assert np.array_equal(run.force_measured, run.force)
    lines = st.excited_bins(cfg)
    y = np.fft.fft(run.y_clean, axis=0)[lines]
    u = np.fft.fft(run.force)[lines]
    measured = y / u[:, None]
    ref = _held_response(cfg.ts_s, 2 * np.pi * lines / cfg.period_samples)
    # RK4 at 4 substeps and the transient left after settling (1e-6): 1e-4 relative
    np.testing.assert_allclose(measured, ref, rtol=1e-4)
    # and the module's own closed form agrees with scipy's discretisation
    f_hz = lines / (cfg.period_samples * cfg.ts_s)
    np.testing.assert_allclose(st.zoh_response(cfg.params, cfg.ts_s, f_hz), ref, rtol=1e-9)


def test_model_file_is_the_chain_and_the_writer_s_model() -> None:
    from_file = load_model(MODEL_FILE)
    written = load_model(st.structure_model(st.StructureParams()))
    ts = 0.0025
    theta = np.linspace(0.005, 0.3, 40)
    ref = _held_response(ts, theta)
    for model in (from_file, written):
        np.testing.assert_allclose(model.response(theta, ts).p23[:, :, 0], ref, rtol=1e-8)
    assert from_file.output_names == written.output_names == ("x1", "x2", "x3")


def _band_beta(level: float) -> tuple[float, float]:
    """(β in the band, β over every bin) of one window of 2 periods at ``level`` N RMS."""
    cfg = st.StructureConfig(force_rms_n=level, periods=2)
    run = st.simulate_structure(cfg)
    datum = make_datum(
        run.force_measured[:, None], run.y, ts_s=cfg.ts_s, period_samples=cfg.period_samples,
        measured=[True],
    )  # fmt: skip
    res = validate(datum, load_model({**st.structure_model(cfg.params), "band": BAND}))
    return res.beta, float(np.hypot(res.beta, res.beta_outside))


def test_beta_grows_with_the_level_and_the_band_keeps_the_distortion_out() -> None:
    betas = [_band_beta(level) for level in (0.5, 2.0, 3.0)]
    band = [b for b, _ in betas]
    assert band[0] < band[1] < 1.0 < band[2]
    assert band[1] > 2 * band[0]  # beyond the noise's scatter: the stiffened mode
    # at 2 N the cubic spring's intermodulation lines outside the band (the largest at 1.95,
    # 1.56 and 0.78 Hz) invalidate every bin's β
    assert betas[1][1] > 1.0


def _simulate_and_validate(tmp: Path, level: float) -> list[dict]:
    out = tmp / f"level_{level:g}.csv"
    code = cli.main(["simulate", "--structure", str(level), "--periods", "4", "--out", str(out)])
    assert code == cli.EXIT_OK
    summary = tmp / f"level_{level:g}.json"
    code = cli.main(
        [
            "validate", str(out), "--map", str(interface_map_path(out)),
            "--model", str(out.with_name(out.stem + st.MODEL_SUFFIX)), "--ts", "0.0025",
            "--period", "1024", "--settle-periods", "0", "--band", "2:15", "--quiet",
            "--no-diagnosis", "--json", str(summary),
        ]
    )  # fmt: skip
    assert code == cli.EXIT_OK
    windows = json.loads(summary.read_text())["models"]["structure_1x3"]["windows"]
    assert len(windows) == 9  # (4 - 2) periods of hops of a quarter period, + 1
    assert all(w["beta"] is not None for w in windows), windows  # the measured force passes
    return windows


def test_recordings_judged_with_the_band_low_level_valid_high_level_invalid(tmp_path: Path) -> None:
    low = _simulate_and_validate(tmp_path, 0.5)
    high = _simulate_and_validate(tmp_path, 3.0)
    assert all(w["beta"] < 1.0 for w in low), low
    assert all(w["beta"] > 1.0 for w in high), high
    assert all(w["input_noise"] == pytest.approx(3e-3, rel=0.1) for w in low + high)


def test_bad_settings_and_overwrites_are_clear_errors(tmp_path: Path, capsys) -> None:
    with pytest.raises(ModelError, match="force_rms_n"):
        st.StructureConfig(force_rms_n=0.0)
    with pytest.raises(ModelError, match="Nyquist"):
        st.StructureConfig(f_max_hz=300.0)
    with pytest.raises(ModelError, match="one spring per mass"):
        st.StructureParams(stiffness_n_per_m=(1.0, 2.0))
    out = tmp_path / "run.csv"
    out.write_text("taken")
    code = cli.main(["simulate", "--structure", "1", "--periods", "1", "--out", str(out)])
    assert code == cli.EXIT_ERROR
    assert "exists already" in capsys.readouterr().err
    assert out.read_text() == "taken"
    code = cli.main(
        ["simulate", "--structure", "1", "--fault", "x", "--out", str(tmp_path / "b.csv")]
    )
    assert code != cli.EXIT_OK
    assert "not for --structure" in capsys.readouterr().err
    assert not (tmp_path / "b.csv").exists()
