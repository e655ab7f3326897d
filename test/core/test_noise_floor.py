"""The per-bin noise floor: what a window's noise alone is expected to cost at each bin.

References:

* a Monte-Carlo brute force: the exact nominal (no perturbations) on noise-only records, whose
  per-bin minimum ``min ||W(n)||`` is then the noise's own cost at that bin; its mean square
  over many records is the floor's square there (the floor estimated from each record's
  own period-to-period spread), per group of bins;
* the total: ``noise_beta² = Σ_n b_n floor(n)²`` over the band's bins (``noise_beta`` sums
  the outputs' terms of another function, :func:`expected_noise_beta`), on the closed-form
  and the general route alike;
* one period (no spread): NaN at every bin, as ``noise_beta``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from twotank_validation.core.band import Band
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import model_from_dict
from twotank_validation.core.validate import noise_cost, validate, validate_beta
from twotank_validation.sim import model_plant as mp

MODELS = Path(__file__).parent.parent / "data" / "models"
TS_S = 0.5
PERIOD = 64


def _doc(perturbations: bool) -> dict:
    doc = yaml.safe_load((MODELS / "one_by_three.yaml").read_text())
    if not perturbations:
        doc.pop("perturbations")
    return doc


def _record(doc: dict, seed: int, periods: int) -> tuple[np.ndarray, np.ndarray]:
    run = mp.simulate_model(
        mp.ModelSimConfig(
            model=model_from_dict(doc, "sim"),
            ts_s=TS_S,
            excitation=mp.ModelExcitation(period_samples=PERIOD, seed=seed),
            periods=periods,
            settle_periods=3,
            noise_scale=0.5,
            noise_seed=seed,
        )
    )
    return run.recorded()


def test_the_floor_is_the_noise_s_mean_cost_per_bin_by_monte_carlo() -> None:
    nominal = model_from_dict(_doc(False), "n")
    floor2, cost2 = [], []
    for seed in range(40):
        u, y = _record(_doc(False), 700 + seed, 4)
        d = make_datum(u, y, ts_s=TS_S, period_samples=PERIOD)
        res = validate(d, nominal)
        floor2.append(res.noise_floor**2)
        cost2.append(res.w_min**2)  # the nominal's error is the noise: its cost, bin by bin
    f2, c2 = np.array(floor2)[:, 1:], np.array(cost2)[:, 1:]  # DC: the mean is removed
    # per group of 16 bins: the mean estimate against the mean brute force, within 4 SE
    for lo in range(0, f2.shape[1] - 15, 16):
        est, mc = f2[:, lo : lo + 16].mean(axis=1), c2[:, lo : lo + 16].mean(axis=1)
        se = math.hypot(est.std(ddof=1), mc.std(ddof=1)) / math.sqrt(est.size)
        assert abs(est.mean() - mc.mean()) < 4.0 * se, (lo, est.mean(), mc.mean(), se)
        assert 0.7 < est.mean() / mc.mean() < 1.4, (lo, est.mean(), mc.mean())


def test_noise_beta_totals_the_floor_over_the_band_on_every_route() -> None:
    u, y = _record(_doc(False), 11, 3)
    d = make_datum(u, y, ts_s=TS_S, period_samples=PERIOD)
    doc = _doc(True)
    for band in (None, Band(0.01, 0.3)):
        model = model_from_dict(doc | ({} if band is None else {"band": band.to_dict()}), "m")
        full = validate(d, model)  # the general route (perturbations on a 1x3 model)
        fast = validate_beta(d, model)
        mask = full.band_mask
        total = math.sqrt(float(np.sum(d.bin_weights[mask] * full.noise_floor[mask] ** 2)))
        assert math.isclose(full.noise_beta, total, rel_tol=1e-12)
        assert np.array_equal(fast.noise_floor, full.noise_floor)
        assert fast.noise_beta == full.noise_beta
        assert np.all(np.isfinite(full.noise_floor[1:]))
    # one period: no spread, nothing to say at any bin
    one = make_datum(u[:PERIOD], y[:PERIOD], ts_s=TS_S, period_samples=PERIOD)
    cost = noise_cost(one, model_from_dict(doc, "m"))
    assert math.isnan(cost.beta)
    assert cost.floor.shape == one.freqs_hz.shape
    assert np.all(np.isnan(cost.floor))
