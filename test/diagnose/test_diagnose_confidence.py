"""How sure and how complete a diagnosis is: parameter uncertainty, what is left, the figure.

References are independent of the diagnosis code:

* the standard error of a gain fitted to synthetic linear data with complex Gaussian noise of
  known variance against the closed form ``sigma / sqrt(2 sum |G U|^2)``, and the interval's
  coverage of the injected gain over many noise draws;
* the confidence intervals on the simulated rig against the injected sensor delay / leak
  (true rate lambda / A1 from the physics), over seeds;
* the explained fraction against the costs recomputed here with the exact (ZOH) model
  through the validator;
* an effect outside the catalogue (a resonance filter applied to the measured temperature)
  that must be reported unexplained, never as the answer;
* the evidence figure's data against the evidence text's R^2 recomputed here from the points.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from test_diagnose import A1, NOISE, _spec, _specs, rig_windows, sensor_delay

from twotank_validation import report
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model_document, model_from_dict
from twotank_validation.core.validate import validate
from twotank_validation.diagnose import (
    BinData,
    Window,
    bin_data,
    diagnose,
    excited_bins,
    fit_effects,
    fit_uncertainty,
    noise_scale,
)
from twotank_validation.sim.rig import RigParams

# --------------------------------------------------------------------------- closed form


def _synthetic(nom, g_true: float, sigma: float, rng: np.random.Generator) -> BinData:
    """Bins of ``Y = (1 + g) G U + N`` on output 0, N complex Gaussian, E|N|^2 = sigma^2."""
    k = 40
    theta = 2 * np.pi * np.arange(1, k + 1) / 4096
    u = rng.normal(size=(k, 2)) + 1j * rng.normal(size=(k, 2))
    g = nom.hold_response(theta, 0.1)
    y = np.einsum("kij,kj->ki", g, u)
    y[:, 0] *= 1.0 + g_true
    noise = sigma / np.sqrt(2) * (rng.normal(size=y.shape) + 1j * rng.normal(size=y.shape))
    return BinData(
        theta, u, y + noise, np.ones(y.shape), np.zeros(k, int), 1, np.full(y.shape, sigma**2)
    )


def test_gain_stderr_is_the_closed_form_and_covers():
    nom, _, specs = _specs("B")
    spec = _spec(specs, "gain", 0)
    rng = np.random.default_rng(7)
    sigma, g_true = 0.05, 0.2
    hits, n, ratios = 0, 100, []
    for _ in range(n):
        data = _synthetic(nom, g_true, sigma, rng)
        x, _ = fit_effects(nom, [spec], data, 0.1)
        u = fit_uncertainty(nom, [spec], data, 0.1, x)
        a = np.einsum("kij,kj->ki", nom.hold_response(data.theta, 0.1), data.u)[:, 0]
        closed = sigma / np.sqrt(2 * np.sum(np.abs(a) ** 2))
        # the noise is all there is: never below the closed form; above it only by the
        # residual's own scatter (White's estimator) and the chi-square of the noise
        ratios.append(u.stderr[0] / closed)
        assert u.at_bound == ("",)
        hits += u.low[0] <= g_true <= u.high[0]
    assert min(ratios) >= 1 - 1e-6
    assert np.median(ratios) <= 1.2
    assert hits / n >= 0.92


def test_a_parameter_at_its_bound_gets_a_one_sided_interval():
    """No delay at all: the fitted delay sits at 0, the lower bound."""
    nom, _, specs = _specs("B")
    spec = _spec(specs, "delay", 1)
    data = _synthetic(nom, 0.0, 0.05, np.random.default_rng(3))
    x = np.array([0.0])
    u = fit_uncertainty(nom, [spec], data, 0.1, x)
    assert u.at_bound == ("lower",)
    assert u.low[0] == 0.0
    assert 0.0 < u.high[0] < spec.upper[0]
    assert u.to_dict(spec.names)["delay_s"]["at_bound"] == "lower"


# --------------------------------------------------------------------------- the rig

COVERAGE_SEEDS = range(100, 120)


def _fit_on_rig(case: str, seed: int, rms: float) -> tuple[float, float, float]:
    """(truth, low, high): the effect fitted as diagnose fits it, on one window of two periods."""
    nom, doc, specs = _specs("B")
    rng = np.random.default_rng(seed)
    if case == "delay":
        truth = float(rng.uniform(8.0, 25.0))
        ws = rig_windows(RigParams(**NOISE), [sensor_delay(truth)], seed, (rms, rms), 1)
        spec = _spec(specs, "delay", 1)
    else:
        lam = float(rng.uniform(0.3, 0.9))
        truth = lam / A1
        ws = rig_windows(RigParams(**NOISE, leak_per_level=lam), (), seed, (rms, rms), 1)
        spec = _spec(specs, "leak", 0)
    datum = make_datum(ws[0].u, ws[0].y, ts_s=0.1, period_samples=ws[0].period_samples)
    data = bin_data([datum], model_from_dict(doc), 1e-4)
    x, _ = fit_effects(nom, [spec], data, 0.1)
    u = fit_uncertainty(nom, [spec], data, 0.1, x)
    return truth, float(u.low[0]), float(u.high[0])


@pytest.mark.parametrize(("case", "rms"), [("delay", 0.03), ("leak", 0.1)])
def test_confidence_intervals_cover_the_injected_parameter(case, rms):
    """95 % intervals cover the injected parameter in >= 90 % of the seeds.

    The delay at 0.03 RMS: at the diagnosis experiments' 0.1 RMS the rig's nonlinearity
    shifts the fitted delay by more than the interval says (docs/diagnosis.md, "How sure").
    """
    runs = [_fit_on_rig(case, seed, rms) for seed in COVERAGE_SEEDS]
    hits = sum(lo <= t <= hi for t, lo, hi in runs)
    assert hits >= 0.9 * len(runs), runs


def test_diagnosis_reports_uncertainty_runners_up_and_what_is_left():
    doc, source = load_model_document("B")
    ws = rig_windows(RigParams(**NOISE), [sensor_delay(15.0)], seed=11)
    diag = diagnose(ws, doc, source=source)
    out = json.loads(json.dumps(diag.to_json()))
    (effect,) = out["effects"]
    ci = effect["uncertainty"]["delay_s"]
    assert ci["ci95"][0] < effect["parameters"]["delay_s"] < ci["ci95"][1]
    assert ci["stderr"] > 0
    text = report.diagnosis_text(diag)
    assert re.search(r"delay_s [\d.]+ ± [\d.e-]+ \(95 %: [\d.]+ – [\d.]+\)", text)
    # what is left, recomputed with the exact model through the validator
    model = model_from_dict(doc)
    new = model_from_dict(diag.document)
    held = [make_datum(w.u, w.y, ts_s=0.1, period_samples=w.period_samples) for w in ws[2:]]

    def costs(m):
        total = np.zeros(2)
        for d in held:
            idx = excited_bins(d, 1e-4)
            y_rms = np.sqrt(np.sum(d.bin_weights[:, None] * np.abs(d.y_bins) ** 2, axis=0))
            scale = noise_scale(model, d.theta[idx], 0.1, y_rms)
            total += np.sum(np.abs(validate(d, m).error[idx] / scale) ** 2, axis=0)
        return total

    floor = np.sum(bin_data(held, model, 1e-4).noise, axis=0)
    jb, ja = costs(model), costs(new)
    want = 1 - (ja.sum() - floor.sum()) / (jb.sum() - floor.sum())
    assert out["explained_fraction"] == pytest.approx(want, abs=0.01)
    t = out["per_output"]["temperature"]
    assert t["noise_ratio_after"] == pytest.approx(ja[1] / floor[1], rel=0.05)
    assert out["per_output"]["height"]["explained_fraction"] is None  # nothing to explain
    assert out["unexplained"] is False
    assert not diag.adequate
    # runners-up: other candidates, by score, the lag (which mimics a delay) among them
    ups = out["runners_up"]
    assert 1 <= len(ups) <= 3
    assert all(u["candidate"] != "delay on temperature" for u in ups)
    assert [u["heldout_cost_penalised"] for u in ups] == sorted(
        u["heldout_cost_penalised"] for u in ups
    )
    assert "lag on temperature" in [u["candidate"] for u in ups]
    assert "Runners-up" in text


# --------------------------------------------------------------------------- outside the catalogue


def _resonate(ws: list[Window], f0_hz: float, k: float, zeta: float) -> list[Window]:
    """Windows whose measured temperature went through ``1 + k 2 zeta w0 s / (s^2 + ...)``.

    A resonance of the sensor: no effect of the catalogue has this shape. Applied to the
    periodic windows in the frequency domain (whole periods).
    """
    out = []
    for w in ws:
        y = w.y.copy()
        n = y.shape[0]
        s = 2j * np.pi * np.fft.rfftfreq(n, w.ts_s)
        w0 = 2 * np.pi * f0_hz
        h = 1 + k * 2 * zeta * w0 * s / (s**2 + 2 * zeta * w0 * s + w0**2)
        mean = y[:, 1].mean()
        y[:, 1] = np.fft.irfft(h * np.fft.rfft(y[:, 1] - mean), n) + mean
        out.append(Window(w.u, y, w.ts_s, w.period_samples, w.start_s))
    return out


def test_an_effect_outside_the_catalogue_is_reported_unexplained():
    doc, source = load_model_document("B")
    ws = rig_windows(RigParams(**NOISE, leak_per_level=0.6), (), seed=4)
    diag = diagnose(_resonate(ws, 0.02, 3.0, 0.15), doc, source=source)
    out = diag.to_json()
    assert out["unexplained"] is True, diag.summary
    assert not diag.adequate
    if diag.before.beta <= 1.0:  # not invalidated: said first, the rest is the detail
        assert diag.summary.startswith("Model B is not invalidated (held-out beta")
        detail = diag.summary.split("Detail, inside the stated uncertainty: ", 1)[1]
    else:
        assert diag.summary.startswith("Model B: ")
        detail = diag.summary.removeprefix("Model B: ")
    assert "explained;" in detail.split(".")[0]
    assert "outside the catalogue" in diag.summary
    temp = out["per_output"]["temperature"]
    assert temp["material_left"]
    if diag.effects:  # a partial fit is said to be one
        assert "not the answer" in diag.summary
        assert "Partial fit" in report.diagnosis_text(diag)


# --------------------------------------------------------------------------- the figure


def test_evidence_figure_draws_the_points_and_r2_of_the_text(tmp_path):
    doc, source = load_model_document("B")
    ws = rig_windows(RigParams(**NOISE, leak_per_level=0.6), [sensor_delay(12.0)], seed=2)
    diag = diagnose(ws, doc, source=source)
    panels = report.diagnosis_effect_data(diag)
    assert [e.spec.kind for e, _ in panels] == [e.spec.kind for e in diag.effects]
    assert diag.fit_bins is not None
    for effect, pts in panels:
        # every bin the fit used, on a log-spaced dense grid over exactly their band
        assert pts.f_hz.size == diag.fit_bins.theta.size
        np.testing.assert_allclose(
            np.sort(pts.f_hz), np.sort(diag.fit_bins.theta / 0.1 / (2 * np.pi))
        )
        assert pts.dense_f_hz[0] == pytest.approx(pts.f_hz.min())
        assert pts.dense_f_hz[-1] == pytest.approx(pts.f_hz.max())
        # the R^2 the text quotes is the one recomputed here from the plotted points
        quoted = float(re.search(r"R\^2 (-?[\d.]+)", effect.evidence).group(1))
        w, om = pts.weight, 2 * np.pi * pts.f_hz
        if effect.spec.kind == "delay":
            ph = np.radians(pts.phase_measured_deg)
            slope = np.sum(w * om * ph) / np.sum(w * om**2)
            r2 = 1 - np.sum(w * (ph - slope * om) ** 2) / np.sum(w * ph**2)
            assert -slope == pytest.approx(effect.values[0], rel=0.05)
        else:
            m, f = pts.measured, pts.fitted
            r2 = 1 - np.sum(w * np.abs(m - f) ** 2) / np.sum(w * np.abs(m - 1) ** 2)
        assert quoted == pytest.approx(r2, abs=0.005)
        assert pts.r2 == pytest.approx(r2)
        # the measured phase sits within a turn of the fitted curve (no unwrapping jumps)
        assert np.all(np.abs(pts.phase_measured_deg - pts.phase_fitted_deg) <= 180.0)
    report.plot_diagnosis_effect(diag, tmp_path / "effect.png")
    assert (tmp_path / "effect.png").stat().st_size > 0
