"""Noise weights from the data, and the noise's share of β (issue 28, item 4).

References:

* the noise helper's weights on held-out noise-only records of the exact nominal: the share
  of windows with β under the budget against the quantile asked for, within a binomial
  tolerance (the quantile is the chi-square approximation's, docs/theory.md §13);
* the noise-only β estimated from one record's period spread against a Monte-Carlo brute
  force (β of the nominal, whose error is the noise alone, over many records) and against
  the closed form ``E β² = noise_scale²`` of the simulator (its ``w`` has unit mean-square
  norm times ``noise_scale`` and enters through the model's own weights);
* the warning: weights equal to each output's noise RMS cost about ``√3`` on a 3-output model
  (each output a share of 1), the helper's do not warn.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.stats
import yaml

from twotank_validation import cli
from twotank_validation.calibrate import CalibrationError, noise_document, noise_from_data
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model, model_from_dict
from twotank_validation.core.noise_budget import NOISE_BETA_WARN, NOISE_WARN_CONFIDENCE
from twotank_validation.core.validate import noise_beta, noise_beta_bounds, validate
from twotank_validation.diagnose.inputs import Window
from twotank_validation.sim import model_plant as mp
from twotank_validation.sim.model_record import interface_map_path

MODELS = Path(__file__).parent.parent / "data" / "models"
TS_S = 0.5
PERIOD = 64
WINDOW = 2 * PERIOD


def _nominal_doc() -> dict:
    """one_by_three without its perturbation: β is then the noise's cost alone."""
    doc = yaml.safe_load((MODELS / "one_by_three.yaml").read_text())
    doc.pop("perturbations")
    return doc


def _record(doc: dict, seed: int, periods: int, noise_scale: float = 1.0) -> tuple:
    """(u, y) of ``periods`` settled periods of the nominal with noise only (no model error)."""
    run = mp.simulate_model(
        mp.ModelSimConfig(
            model=model_from_dict(doc, "sim"),
            ts_s=TS_S,
            excitation=mp.ModelExcitation(period_samples=PERIOD, seed=seed),
            periods=periods,
            settle_periods=3,
            noise_scale=noise_scale,
            noise_seed=seed,
        )
    )
    return run.recorded()


def _windows(u: np.ndarray, y: np.ndarray) -> list[Window]:
    return [
        Window(u[k : k + WINDOW], y[k : k + WINDOW], TS_S, PERIOD, start_s=k * TS_S)
        for k in range(0, u.shape[0], WINDOW)
    ]


def _beta(doc: dict, u: np.ndarray, y: np.ndarray) -> float:
    d = make_datum(u, y, ts_s=TS_S, period_samples=PERIOD)
    return float(validate(d, model_from_dict(doc, "m")).beta)


def test_helper_weights_hold_their_quantile_on_held_out_noise() -> None:
    doc = _nominal_doc()
    n_seeds = 60
    under_one, under_default, betas = 0, 0, []
    for seed in range(n_seeds):
        u, y = _record(doc, 100 + seed, 8)  # four windows of two periods to fit on
        wins = _windows(u, y)  # split_windows: the first two fit
        tight = noise_from_data(wins, doc, quantile=0.8, budget=1.0)
        default = noise_from_data(wins, doc)
        hu, hy = _record(doc, 5000 + seed, 2)  # held out: another seed
        b_tight = _beta(tight.document, hu, hy)
        b_default = _beta(default.document, hu, hy)
        under_one += b_tight <= 1.0
        under_default += b_default <= default.fit.budget
        betas.append(b_default)
    # the share under 1 is the quantile asked for (0.8), within a binomial 99.9 % interval
    lo, hi = scipy.stats.binom.interval(0.999, n_seeds, 0.8)
    assert lo <= under_one <= hi, under_one
    # the default (0.8 at 99 %): close to but under 1, and the 99 % quantile holds
    assert under_default >= scipy.stats.binom.ppf(0.001, n_seeds, 0.99)
    assert min(betas) > 0.5, min(betas)
    assert max(betas) < 1.0, max(betas)


def test_noise_beta_against_monte_carlo_and_closed_form() -> None:
    doc = yaml.safe_load((MODELS / "one_by_three.yaml").read_text())  # the stated weights
    nominal = _nominal_doc()
    scale = 0.6
    estimates, brute, lower = [], [], []
    for seed in range(40):
        u, y = _record(nominal, 300 + seed, 4, noise_scale=scale)
        d = make_datum(u, y, ts_s=TS_S, period_samples=PERIOD)
        estimates.append(validate(d, model_from_dict(nominal, "n")).noise_beta ** 2)
        brute.append(validate(d, model_from_dict(nominal, "n")).beta ** 2)
        lower.append(noise_beta_bounds(d, model_from_dict(nominal, "n"))[1])
    est, mc = np.array(estimates), np.array(brute)
    # the warning's lower bound (90 % confidence) is below the true value as often as it says
    covered = int(np.sum(np.array(lower) <= scale))
    assert covered >= scipy.stats.binom.ppf(0.001, est.size, NOISE_WARN_CONFIDENCE), covered
    se = math.hypot(est.std(ddof=1), mc.std(ddof=1)) / math.sqrt(est.size)
    assert abs(est.mean() - mc.mean()) < 4.0 * se, (est.mean(), mc.mean(), se)
    # the simulator's w has mean-square norm scale², all of it through the model's weights
    n = 4 * PERIOD
    assert abs(mc.mean() - scale**2 * (n - 1) / n) < 4.0 * mc.std(ddof=1) / math.sqrt(mc.size)
    # one record's estimate (its own spread, 3 complex dof per harmonic) is near the truth
    assert abs(math.sqrt(est[0]) - scale) < 0.15 * scale
    # the noise-only β does not depend on the perturbations: the full model's is its nominal's
    d = make_datum(u, y, ts_s=TS_S, period_samples=PERIOD)
    assert math.isclose(noise_beta(d, model_from_dict(doc, "full")), math.sqrt(estimates[-1]))


def test_warning_fires_for_raw_rms_weights_not_for_the_helpers() -> None:
    doc = _nominal_doc()
    u, y = _record(doc, 7, 8)
    cal = noise_from_data(_windows(u, y), doc)
    raw = noise_document(doc, cal.outputs, cal.fit.noise_rms)  # each weight its noise RMS
    hu, hy = _record(doc, 8, 2)
    d = make_datum(hu, hy, ts_s=TS_S, period_samples=PERIOD)
    res_raw = validate(d, model_from_dict(raw, "raw"))
    res_new = validate(d, model_from_dict(cal.document, "new"))
    assert abs(res_raw.noise_beta - math.sqrt(3.0)) < 0.15 * math.sqrt(3.0)
    assert abs(res_raw.beta - math.sqrt(3.0)) < 0.15 * math.sqrt(3.0)  # β is the noise's
    assert any("noise alone" in w and "--noise-from-data" in w for w in res_raw.warnings)
    assert res_new.noise_beta < NOISE_BETA_WARN
    assert not any("noise alone" in w for w in res_new.warnings)
    assert res_raw.summary()["noise_beta"] == pytest.approx(res_raw.noise_beta)


def test_one_period_windows_are_refused_with_the_fix() -> None:
    doc = _nominal_doc()
    u, y = _record(doc, 9, 2)
    one = [Window(u[k : k + PERIOD], y[k : k + PERIOD], TS_S, PERIOD) for k in (0, PERIOD)]
    with pytest.raises(CalibrationError, match="two or more periods"):
        noise_from_data(one, doc)


def test_cli_noise_from_data_round_trips_and_validate_reports_it(tmp_path: Path, capsys) -> None:
    model_file = tmp_path / "nominal.yaml"
    model_file.write_text(yaml.safe_dump(_nominal_doc()))
    rec = tmp_path / "run.csv"
    assert cli.main(
        ["simulate", "--model", str(model_file), "--format", "csv", "--out", str(rec),
         "--ts", str(TS_S), "--period", str(PERIOD), "--periods", "12", "--quiet"]
    ) == cli.EXIT_OK  # fmt: skip
    window = ["--map", str(interface_map_path(rec)), "--ts", str(TS_S), "--period", str(PERIOD),
              "--hop", str(PERIOD), "--quiet"]  # fmt: skip
    new, cal_json = tmp_path / "new.yaml", tmp_path / "cal.json"
    code = cli.main(
        ["calibrate", str(rec), "--model", str(model_file), *window, "--noise-from-data",
         "--out-model", str(new), "--json", str(cal_json)]
    )  # fmt: skip
    out, err = capsys.readouterr()
    assert code == cli.EXIT_OK, err
    assert "share one unit-norm w" in out
    written = json.loads(cal_json.read_text())
    gains = written["noise_from_data"]["gains"]
    model = load_model(new)  # round trip: the file loads, its weights are the JSON's gains
    theta = np.array([0.3])
    p22 = model.response(theta, TS_S).p22[0]
    assert np.allclose(np.abs(np.diag(p22)), [gains[n] for n in model.output_names])
    summary = tmp_path / "v.json"
    assert cli.main(["validate", str(rec), "--model", str(new), *window, "--no-diagnosis",
                     "--json", str(summary)]) == cli.EXIT_OK  # fmt: skip
    wins = json.loads(summary.read_text())["models"][model.name]["windows"]
    judged = [w for w in wins if w["beta"] is not None]
    assert judged
    assert all(w["noise_beta"] < NOISE_BETA_WARN for w in judged)
    assert not any("noise alone" in t for w in judged for t in w["warnings"])
    # usage: --noise-from-data with --block is refused in one line
    code = cli.main(["calibrate", str(rec), "--model", str(model_file), *window,
                     "--noise-from-data", "--block", "sensors"])  # fmt: skip
    err = capsys.readouterr().err
    assert code != cli.EXIT_OK
    assert "leave out --block" in err
    assert "Traceback" not in err
