"""calibrate over a validation band (issue 28, item 1): only the band's bins are counted.

The record is the nominal rig's with a strong periodic line added to the height outside the
band and outside the excitation (mains-like: a harmonic of the period the command does not
carry). Reference: a bisection on the height noise's factor written here, with beta over the
band's bins totalled from the per-bin minima of ``core.validate``'s solver on a model built
from the scaled document; the band's bins chosen here by frequency (not by ``core.band``).
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from tools.streamfuzz import CONFIG, clean_record
from twotank_validation.calibrate import WindowProblem, calibrate, choose_blocks
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model_document, model_from_dict
from twotank_validation.core.validate import lower_bins, validate
from twotank_validation.diagnose import Window

L, TS = CONFIG.period_samples, CONFIG.ts_s
BAND_HZ = 0.3
"""The band's top: the rig's command excites lines up to 0.45 Hz."""
LINE_HZ = 226 / (2 * L * TS)
"""0.552 Hz: a harmonic of the period above every excited line (a two-period window's bin 226)."""
BLOCK = "height_noise"


@pytest.fixture(scope="module")
def windows() -> list[Window]:
    """Two two-period windows of the settled rig, the height carrying a line at LINE_HZ."""
    _, u, y = clean_record(6)
    t = np.arange(u.shape[0]) * TS
    y = y.copy()
    y[:, 0] += 0.02 * np.sin(2 * np.pi * LINE_HZ * t + 0.3)
    return [
        Window(u[k * L : (k + 2) * L], y[k * L : (k + 2) * L], TS, L, k * L * TS) for k in (2, 4)
    ]


def _doc(factor: float, band: bool) -> dict:
    doc, _ = load_model_document("B")
    new = copy.deepcopy(doc)
    new["noise"][0]["weight"]["gain"] *= factor
    if band:
        new["band"] = {"min_hz": 0.0, "max_hz": BAND_HZ}
    return new


def _beta(datum, factor: float, mask: np.ndarray) -> float:
    """beta over the bins of ``mask`` with the height noise's weight times ``factor``."""
    model = model_from_dict(_doc(factor, band=False))
    lower = lower_bins(model.response(datum.theta, TS), datum.u_bins, datum.y_bins)
    return math.sqrt(float(np.sum(datum.bin_weights[mask] * lower[mask] ** 2)))


def _bisect(datum, mask: np.ndarray) -> float:
    """The smallest factor with beta <= 1 (bisection in log scale to 1e-7 relative)."""
    lo, hi = 1e-3, 1e3
    assert _beta(datum, lo, mask) > 1.0 >= _beta(datum, hi, mask)
    while hi / lo > 1.0 + 1e-7:
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if _beta(datum, mid, mask) <= 1.0 else (mid, hi)
    return hi


def test_calibrate_counts_only_the_band(windows) -> None:
    datums = [make_datum(w.u, w.y, ts_s=TS, period_samples=L) for w in windows]
    band = datums[0].freqs_hz <= BAND_HZ
    every = np.ones_like(band)
    in_band = max(_bisect(d, band) for d in datums)
    all_bins = max(_bisect(d, every) for d in datums)
    assert all_bins > 3.0 * in_band  # the line outside the band would dominate
    cal = calibrate(windows, _doc(1.0, band=True), blocks=[BLOCK])
    (block,) = cal.blocks
    assert block.scaling == pytest.approx(in_band, rel=1e-5)
    # the calibrated model (it keeps the band) holds on every window, counted over the band
    assert cal.document is not None
    assert cal.document["band"]["max_hz"] == BAND_HZ
    after = model_from_dict(cal.document)
    assert all(validate(d, after).beta <= 1.0 for d in datums)
    # the joint search's beta is validate's over the band
    model = model_from_dict(_doc(1.0, band=True))
    p = WindowProblem.of(datums[0], model)
    blocks = choose_blocks(model, [BLOCK, "temperature_noise"])
    assert p.beta_joint(blocks, [1.0, 1.0]) == pytest.approx(validate(datums[0], model).beta)
    assert p.beta(blocks[0], 1.0) == pytest.approx(_beta(datums[0], 1.0, band), rel=1e-12)
