"""β per window by the shared-response helper against ``validate`` on each window alone."""

from __future__ import annotations

import numpy as np

from twotank_validation.calibrate.calibration import window_betas
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model
from twotank_validation.core.validate import validate, validate_beta


def test_window_betas_are_validate_s_bit_for_bit_and_caveats_off_keeps_beta():
    model = load_model("B")
    rng = np.random.default_rng(5)
    datums = []
    for n_periods, period in ((2, 256), (2, 256), (3, 128)):  # two share their bins
        u_one = rng.standard_normal((period, len(model.input_names)))
        u = np.tile(u_one, (n_periods, 1))
        y = 0.05 * rng.standard_normal((n_periods * period, len(model.output_names)))
        datums.append(make_datum(u, y, ts_s=0.1, period_samples=period))
    got = window_betas(datums, model)
    ref = np.array([validate(d, model).beta for d in datums])
    np.testing.assert_array_equal(got, ref)
    for d in datums:
        full = validate_beta(d, model)
        bare = validate_beta(d, model, caveats=False)
        np.testing.assert_array_equal(bare.w_min, full.w_min)
        assert bare.beta == full.beta
        assert bare.warnings == ()
        assert np.isnan(bare.noise_beta)
