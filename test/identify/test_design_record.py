"""A simulated record with realisations identified without repeating its design.

``simulate`` writes the excitation design beside the recording; ``identify`` reads the
periods, the realisations' boundaries and settling, and the excited and detection lines from
it. Reference: the design itself (its lines, its realisations), computed apart.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from twotank_validation.bags.model_bag import simulate_model_command
from twotank_validation.online.interface import load_interface_map
from twotank_validation.sim.excitation import ExcitationDesign, read_design
from twotank_validation.usecases import IdentifyJob, ReadSettings

MODEL = "test/data/models/one_by_three.yaml"


def test_identify_reads_the_design_beside_a_simulated_record(tmp_path: Path) -> None:
    design = ExcitationDesign(
        kind="multisine", period_samples=256, f_min_hz=0.0, f_max_hz=1.5, lines="odd",
        detection="1/3", realisations=4, seed=3,
    )  # fmt: skip
    out = simulate_model_command(
        MODEL, tmp_path / "run.csv", "csv", ts_s=0.1, periods=2, settle_periods=3, rms=0.5,
        noise_scale=0.3, design=design,
    )  # fmt: skip
    rec = read_design(out)
    assert rec is not None
    assert rec.design == ExcitationDesign(**{**design.__dict__, "realisation_periods": 5})
    np.testing.assert_array_equal(rec.lines.excited, design.excitation_lines(0.1).excited)  # type: ignore[union-attr]
    imap = load_interface_map(tmp_path / "run.map.yaml")
    outcome = IdentifyJob(str(out), ReadSettings(interface=imap), orders="1..4").run()
    doc = outcome.document
    assert doc is not None, outcome.errors
    # one window per realisation (after its 3 settling periods), so the best linear
    # approximation over the 4 realisations, at the design's excited lines
    assert doc["windows"] == 4
    assert doc["estimator"] == "best linear approximation"
    lines = design.excitation_lines(0.1)
    np.testing.assert_allclose(doc["response"]["freqs_hz"], lines.excited / 25.6)
    dist = doc["distortion"]
    assert (dist["n_odd"], dist["n_even"]) == (lines.detection.size, lines.even.size)
    # a linear plant: the unexcited lines hold the noise only (within a factor 4 of it)
    for kind in ("odd", "even"):
        assert np.all(np.array(dist[kind]) < 4 * np.array(dist[f"noise_{kind}"]))
