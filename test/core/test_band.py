"""The validation band (issue 28 items 1 and 6): β over chosen bins, lines outside, leakage flag."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from twotank_validation.core import solvers
from twotank_validation.core.band import Band, band_mask, excited_lines, parse_band
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import model_from_dict
from twotank_validation.core.validate import validate, validate_beta
from twotank_validation.errors import ModelError, ModelFileError

TS = 0.1
PERIOD = 128
N_PERIODS = 2
N = PERIOD * N_PERIODS
LINES = np.arange(3, 20)  # excited harmonics of the period (period-bin index)

# one input, two outputs, one input-multiplicative block: coupled, so the fast path runs
SIMO = {
    "name": "simo",
    "inputs": ["u"],
    "outputs": ["y1", "y2"],
    "nominal": {
        "ss": {"A": [[-0.3]], "B": [[0.6]], "C": [[1.0], [0.4]], "D": [[0.0], [0.1]]},
    },
    "perturbations": [{"kind": "input_multiplicative", "inputs": ["u"], "weight": 0.1}],
    "noise": [{"outputs": ["y1", "y2"], "weight": 0.02}],
}


def _command(seed: int) -> np.ndarray:
    """(N, 1) a multisine on LINES of the period, repeated N_PERIODS times."""
    rng = np.random.default_rng(seed)
    spec = np.zeros(PERIOD // 2 + 1, dtype=complex)
    spec[LINES] = np.exp(2j * np.pi * rng.random(LINES.size))
    one = np.fft.irfft(spec, n=PERIOD)
    return np.tile(one / np.std(one), N_PERIODS)[:, None]


def _output(model, u: np.ndarray, gain: float, seed: int) -> np.ndarray:
    """(N, ny) periodic steady-state response of ``gain`` x the nominal, plus white noise."""
    theta = 2 * np.pi * np.arange(N // 2 + 1) / N
    g = model.response(theta, TS).p23  # (bins, ny, nu)
    y_f = gain * np.einsum("kij,kj->ki", g, np.fft.rfft(u, axis=0))
    y = np.fft.irfft(y_f, n=N, axis=0)
    return y + np.random.default_rng(seed).normal(0.0, 0.01, y.shape)


def _line(freq_hz: float, amp: float) -> np.ndarray:
    k = np.arange(N)
    return amp * np.sin(2 * np.pi * freq_hz * k * TS)[:, None]


def test_band_beta_equals_problem_3_solved_by_hand_on_the_band_bins() -> None:
    """β with a band = sqrt(Σ weight·w_min²) of the per-bin SDP run on those bins alone."""
    band = Band(0.2, 1.0)
    model = model_from_dict({**SIMO, "band": {"min_hz": 0.2, "max_hz": 1.0}})
    assert model.band == band
    u = _command(0)
    y = _output(model, u, 1.3, 1)  # a 30 % gain error: beyond the 10 % block
    d = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    res = validate(d, model)
    assert res.method == "fast"
    keep = (d.freqs_hz >= 0.2) & (d.freqs_hz <= 1.0)
    assert 0 < keep.sum() < keep.size
    np.testing.assert_array_equal(res.band_mask, keep)
    # reference: the cvxpy SDP on the kept bins only, totalled by hand
    ref = solvers.solve_sdp(model.response(d.theta[keep], TS), d.u_bins[keep], d.y_bins[keep])
    beta_ref = math.sqrt(float(np.sum(d.bin_weights[keep] * ref.lower**2)))
    assert res.beta == pytest.approx(beta_ref, rel=1e-5)
    assert res.beta > 1.0  # the gain error invalidates over the band too
    # the rest is reported: the whole β² splits into the band's and the outside's
    whole = validate(d, dataclasses.replace(model, band=None))
    assert res.beta**2 + res.beta_outside**2 == pytest.approx(whole.beta**2, rel=1e-9)
    assert whole.beta_outside == 0.0
    assert whole.band_mask.all()
    assert "band" not in whole.summary()
    assert res.summary()["beta_outside"] == res.beta_outside


def test_a_mains_line_outside_the_band_moves_only_beta_outside() -> None:
    model = model_from_dict({**SIMO, "band": "excited:0:2"})
    u = _command(2)
    y = _output(model, u, 1.0, 3)
    mains = 3.125  # Hz: bin 80, a harmonic of the period, outside the band (excited: < 1.5 Hz)
    d_clean = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    d_mains = make_datum(u, y + _line(mains, 0.5), ts_s=TS, period_samples=PERIOD)
    clean, hum = validate(d_clean, model), validate(d_mains, model)
    assert hum.beta == pytest.approx(clean.beta, rel=1e-9, abs=1e-12)
    assert hum.beta < 1.0 < hum.beta_outside  # the line would invalidate over every bin
    assert hum.lines_outside[0][0] == pytest.approx(mains)
    # which lines outside carry power: the mains line repeats far above its noise
    assert hum.periodic_outside[0][0] == pytest.approx(mains)
    assert all(f != pytest.approx(mains) for f, _ in clean.periodic_outside)
    unbanded = validate(d_mains, dataclasses.replace(model, band=None))
    assert unbanded.beta > 1.0  # what the band takes off the verdict
    # the alarm's path (validate_beta) counts the same bins
    assert validate_beta(d_mains, model).beta == pytest.approx(hum.beta, rel=1e-9)


def test_excited_lines_ignore_a_line_the_command_does_not_carry() -> None:
    u = _command(4)
    mains_bin = 40 * N_PERIODS  # a harmonic of the period, not among LINES
    measured = u + _line(mains_bin / (N * TS), 0.05)  # the command plus pickup
    cmd_bins = np.fft.rfft(u, axis=0) / N
    meas_bins = np.fft.rfft(measured, axis=0) / N
    expected = np.zeros(N // 2 + 1, dtype=bool)
    expected[LINES * N_PERIODS] = True
    np.testing.assert_array_equal(excited_lines(cmd_bins, N_PERIODS), expected)
    assert excited_lines(meas_bins, N_PERIODS)[mains_bin]  # the measured signal carries it
    # validate with the measured input but the command's spectrum: the pickup is not counted
    model = model_from_dict({**SIMO, "band": "excited"})
    d = make_datum(measured, _output(model, measured, 1.0, 5), ts_s=TS, period_samples=PERIOD)
    res = validate(d, model, command_bins=cmd_bins)
    np.testing.assert_array_equal(res.band_mask, expected)
    assert validate(d, model).band_mask[mains_bin]  # without the command, the datum's input


def test_band_forms_and_bad_bands() -> None:
    assert parse_band(None) is None
    assert parse_band("all") is None
    assert parse_band("excited") == Band(excited=True)
    assert parse_band("0.001:0.02") == Band(0.001, 0.02)
    assert parse_band(":5") == Band(0.0, 5.0)
    assert parse_band({"min_hz": 1}) == Band(1.0, math.inf)
    freqs = np.linspace(0.0, 5.0, 11)
    assert band_mask(freqs, parse_band("1:2")).sum() == 3  # 1.0, 1.5, 2.0
    for bad in ("2:1", "fast", {"max": 3}, {"excited": "yes"}, 7):
        with pytest.raises(ModelError, match="band"):
            parse_band(bad)
    with pytest.raises(ModelFileError, match="band"):
        model_from_dict({**SIMO, "band": "5:1"})


def test_a_band_without_bins_is_said() -> None:
    model = model_from_dict({**SIMO, "band": "100:200"})  # above Nyquist (5 Hz)
    u = _command(6)
    d = make_datum(u, _output(model, u, 1.0, 7), ts_s=TS, period_samples=PERIOD)
    res = validate(d, model)
    assert res.beta == 0.0
    assert any("holds no bin" in w for w in res.warnings)


# --- item 6: the leakage bound flagged where it exceeds the data it bounds ---------------------


def _siso(time_constant_s: float) -> dict:
    return {
        "name": "siso",
        "inputs": ["u"],
        "outputs": ["y"],
        "nominal": {"tf": {"num": [1.0], "den": [time_constant_s, 1.0]}},
        "noise": [{"outputs": ["y"], "weight": 0.02}],
    }


def _moment_by_hand(tau_s: float) -> float:
    """sum_k k |p(k)| of the zero-order-hold discretisation of 1/(tau s + 1), closed form."""
    a = math.exp(-TS / tau_s)
    # p(k) = (1 - a) a^(k-1), k >= 1: sum_k k (1 - a) a^(k-1) = 1 / (1 - a)
    return 1.0 / (1.0 - a)


@pytest.mark.parametrize(("tau_s", "vacuous"), [(0.2, False), (200.0, True)])
def test_leakage_bound_flagged_only_where_it_exceeds_the_outputs_lines(
    tau_s: float, vacuous: bool
) -> None:
    """A fast plant: the bound is below the output's lines; a slow one: above all of them."""
    model = model_from_dict(_siso(tau_s))
    u = _command(8)
    y = _output(model, u, 1.0, 9)[:, :1]
    d = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    res = validate(d, model)
    bound = 2.0 / N * _moment_by_hand(tau_s) * float(np.max(np.abs(u - u.mean())))
    assert res.leakage[0] == pytest.approx(bound, rel=1e-6)
    largest_line = float(np.max(np.abs(np.fft.rfft(y - y.mean(), axis=0)))) / N
    assert (bound > largest_line) is vacuous  # the independent comparison
    assert bool(res.leakage_exceeds_data[0]) is vacuous
    summary = res.summary()
    assert (summary["leakage_bound"] == [None]) is vacuous  # left out of the report there
    assert ("leakage_note" in summary) is vacuous
    assert not any("leakage" in w for w in res.warnings)  # β does not use the bound


# --- the command line's / node's band: the monitor's setting ------------------------------------


def test_the_monitors_band_setting_replaces_the_models_and_reaches_the_window() -> None:
    """``--band`` (the node's ``band``) replaces each model's own; a window's β is validate()'s
    over that band, and ``beta_outside`` reports the rest."""
    from tools import streamfuzz  # noqa: PLC0415
    from twotank_validation import online  # noqa: PLC0415
    from twotank_validation.core.model import load_model  # noqa: PLC0415
    from twotank_validation.online import AlarmConfig  # noqa: PLC0415

    base = online.MonitorConfig(
        ts_s=0.8, period_samples=256, hop_samples=256, alarm=AlarmConfig(debounce="count")
    )
    banded_b = dataclasses.replace(load_model("B"), band=Band(0.0, 0.05))
    assert base.banded(banded_b) is banded_b  # no --band: the file's band
    assert online.MonitorConfig(band="all").banded(banded_b).band is None
    with pytest.raises(ValueError, match="band"):
        online.MonitorConfig(band="low")
    cfg = dataclasses.replace(base, band="0.01:0.2")
    stamps, u, y = streamfuzz.clean_record(6, 0)
    reports = [r for r in online.monitor_record(stamps, u, y, cfg, [load_model("B")]) if r.judged]
    assert reports
    last = reports[-1]
    n = cfg.window_samples
    datum = make_datum(u[-n:], y[-n:], ts_s=0.8, period_samples=256)
    ref = validate(datum, dataclasses.replace(load_model("B"), band=Band(0.01, 0.2)))
    assert last.beta == ref.beta
    assert last.beta_outside == ref.beta_outside
    assert last.beta_outside > 0.0
    assert last.lines_outside == ref.lines_outside
    assert last.lines_outside[0][1] == max(s for _, s in ref.lines_outside)
    from twotank_validation.replay.summary import window_entry  # noqa: PLC0415

    entry = window_entry(last, 0)
    assert entry["beta_outside"] == ref.beta_outside
    assert entry["lines_outside"] == [list(p) for p in ref.lines_outside]
    plain = online.monitor_record(stamps, u, y, base, [load_model("B")])
    assert all(math.isnan(r.beta_outside) for r in plain)  # no band: nothing outside
    assert "beta_outside" not in window_entry(plain[-1], 0)  # the JSON as without bands


@pytest.mark.parametrize("n_periods", [2, 8])
def test_noise_alone_is_listed_as_a_periodic_line_at_the_rate_derived(n_periods: int) -> None:
    """(1 + 25/(p-1))^-(p-1) per bin for Gaussian noise (docs/theory.md §12)."""
    from twotank_validation.core.band import periodic_lines  # noqa: PLC0415

    rng = np.random.default_rng(n_periods)
    period, records = 64, 200
    listed = 0
    for _ in range(records):
        u = np.tile(rng.normal(size=period), n_periods)
        d = make_datum(u, rng.normal(size=u.size), ts_s=1.0, period_samples=period)
        none = np.zeros(d.freqs_hz.size, dtype=bool)
        listed += len(periodic_lines(d.y_bins, d.noise_std, d.freqs_hz, none, top=10**6))
    bins = records * (period // 2)  # harmonic bins 1..L/2
    rate = (1 + 25 / (n_periods - 1)) ** -(n_periods - 1)
    assert listed / bins == pytest.approx(rate, abs=4 * math.sqrt(rate / bins) + 1e-4)


def test_band_option_replaces_the_files_band_in_the_model_and_its_document() -> None:
    """``calibrate``/``diagnose --band``: the model judged and the file written claim it."""
    from twotank_validation.usecases.reading import LoadedModel, banded  # noqa: PLC0415

    doc = {**SIMO, "band": "excited"}
    loaded = LoadedModel(model_from_dict(doc), doc, "test")
    assert banded(loaded, "") is loaded
    narrow = banded(loaded, "0.1:0.5")
    assert narrow.model.band == Band(0.1, 0.5)
    assert model_from_dict(narrow.document).band == Band(0.1, 0.5)  # the document round-trips
    everything = banded(loaded, "all")
    assert everything.model.band is None
    assert "band" not in everything.document
