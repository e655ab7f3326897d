"""The excitation design (issue 29, item 4): its lines, crest factor, realisations, its odd
distortion lines, and the validator's periodicity gate over several realisations.

Independent references: the band's lines counted by hand from ``k / (N ts)``; the crest
factor of the random-phase multisine of the same lines and draw; a static cubic's output
spectrum by triple convolution of the input's line spectrum (no FFT of the cubed signal);
the window ends that lie within one realisation, counted by hand.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from twotank_validation.core.model import load_model
from twotank_validation.errors import DatumError
from twotank_validation.identify.nonparametric import distortion_lines
from twotank_validation.online.states import WindowState
from twotank_validation.online.window import MonitorConfig, monitor_record
from twotank_validation.settings import SettingError, from_flat
from twotank_validation.sim import excitation as ex
from twotank_validation.sim import model_plant as mp

N, TS = 256, 1.0
F1, F2 = 0.01, 0.3


def _band_bins(step: int = 1) -> list[int]:
    """The grid lines of the band, by hand: bins k = step j with F1 <= k / (N TS) <= F2."""
    return [k for k in range(1, N // 2) if k % step == 0 and F1 <= k / (N * TS) <= F2]


def _design(**kw: object) -> ex.ExcitationDesign:
    base = {"kind": "multisine", "period_samples": N, "f_min_hz": F1, "f_max_hz": F2, "seed": 5}
    return ex.ExcitationDesign(**(base | kw))  # type: ignore[arg-type]


def _nonzero_bins(x: np.ndarray) -> np.ndarray:
    spec = np.abs(np.fft.rfft(x))
    return np.flatnonzero(spec > 1e-9 * spec.max())


def test_odd_design_with_detection_lines_has_exactly_the_designed_lines() -> None:
    d = _design(lines="odd", detection="1/3")
    lines = d.excitation_lines(TS)
    odd = [k for k in _band_bins() if k % 2 == 1]
    even = [k for k in _band_bins() if k % 2 == 0]
    np.testing.assert_array_equal(np.sort(np.r_[lines.excited, lines.detection]), odd)
    np.testing.assert_array_equal(lines.even, even)
    # one detection line in each whole group of three consecutive odd lines
    groups = np.searchsorted(odd, lines.detection) // 3
    np.testing.assert_array_equal(groups, np.arange(len(odd) // 3))
    tables = d.realisation_tables(TS, 2)
    for col in range(2):  # by DFT: the excited lines, nothing at detection or even lines
        np.testing.assert_array_equal(_nonzero_bins(tables[0, :, col]), lines.excited)
        amp = np.abs(np.fft.rfft(tables[0, :, col]))[lines.excited]
        np.testing.assert_allclose(amp, amp[0], rtol=1e-9)  # flat


def test_odd_odd_and_a_coarser_grid() -> None:
    oo = _design(lines="odd_odd").excitation_lines(TS)
    np.testing.assert_array_equal(oo.excited, [k for k in _band_bins() if k % 4 == 1])
    np.testing.assert_array_equal(oo.detection, [k for k in _band_bins() if k % 4 == 3])
    d = _design(lines="odd", line_step=3)
    grid = d.excitation_lines(TS)
    np.testing.assert_array_equal(grid.excited, [k for k in _band_bins(3) if (k // 3) % 2])
    np.testing.assert_array_equal(_nonzero_bins(d.realisation_tables(TS, 1)[0, :, 0]), grid.excited)


def test_a_single_plain_realisation_is_the_short_forms_multisine() -> None:
    """The design draws what multisine_period draws (the samples of every existing run)."""
    rng = np.random.default_rng(5)
    ref = [ex.multisine_period(N, TS, F1, F2, True, rng) for _ in range(2)]
    np.testing.assert_array_equal(_design(lines="odd").realisation_tables(TS, 2)[0].T, ref)


def test_crest_minimisation_beats_the_random_phases_it_started_from() -> None:
    d = _design(crest_min=True, realisations=2, realisation_periods=3)
    before, after = d.crest_factors(TS, 2)
    # reference: the random-phase multisine of the same lines and draw, computed apart
    plain = _design(realisations=2, realisation_periods=3).realisation_tables(TS, 2)
    random = np.array([[ex.crest_factor(plain[r, :, i]) for i in range(2)] for r in range(2)])
    np.testing.assert_allclose(before, random, rtol=1e-9)
    assert np.all(after < 0.75 * random)
    tables = d.realisation_tables(TS, 2)
    np.testing.assert_array_equal(_nonzero_bins(tables[1, :, 0]), d.excitation_lines(TS).excited)
    summary = d.summary(TS, 2)["crest_factor"]
    assert summary == {"random_phase": before.tolist(), "applied": after.tolist()}  # type: ignore[comparator-overlap]


def test_realisations_differ_in_phase_and_repeat_within() -> None:
    d = _design(lines="odd", realisations=3, realisation_periods=2)
    cycle = d.cycle(TS, np.array([0.1]))[:, 0]
    assert cycle.size == 3 * 2 * N
    periods = cycle.reshape(6, N)
    lines = d.excitation_lines(TS).excited
    for r in range(3):
        np.testing.assert_array_equal(periods[2 * r], periods[2 * r + 1])  # repeats within
    spectra = np.fft.rfft(periods[::2], axis=1)[:, lines]
    flat = np.abs(spectra)
    np.testing.assert_allclose(flat, np.broadcast_to(flat[0, 0], flat.shape), rtol=1e-9)
    for a, b in ((0, 1), (1, 2), (0, 2)):  # new phases: the phase differences are not constant
        dphi = np.angle(spectra[a] / spectra[b])
        assert np.std(np.exp(1j * dphi)) > 0.5
    with pytest.raises(DatumError, match="realisation_periods >= 1"):
        _design(realisations=3).cycle(TS, np.array([0.1]))


def test_bad_designs_name_the_setting() -> None:
    with pytest.raises(DatumError, match="detection='1/3' leaves odd lines out"):
        _design(detection="1/3")
    with pytest.raises(DatumError, match="lines shape a multisine"):
        ex.ExcitationDesign(lines="odd")
    with pytest.raises(DatumError, match="write M/G"):
        _design(lines="odd", detection="3/3")
    with pytest.raises(SettingError, match="lines"):
        from_flat(ex.ExcitationDesign, {"lines": "even"})
    with pytest.raises(DatumError, match="no odd_odd line"):
        _design(lines="odd_odd", f_min_hz=2.5 / N, f_max_hz=2.6 / N).excitation_lines(TS)


def _cubic_at(x_lines: np.ndarray, lines: np.ndarray, a: float, at: np.ndarray) -> np.ndarray:
    """DFT/N of ``a x^3`` at bins ``at``, x real with one-sided line spectrum ``x_lines``
    (DFT/N at ``lines``): triple sum over the two-sided lines, no FFT of x^3."""
    two = {int(k): c for k, c in zip(lines, x_lines, strict=True)}
    two |= {N - int(k): np.conj(c) for k, c in zip(lines, x_lines, strict=True)}
    keys = np.array(list(two))
    vals = np.array([two[int(k)] for k in keys])
    out = np.zeros(at.size, complex)
    for i, k in enumerate(at):
        s = 0j
        for k1, c1 in zip(keys, vals, strict=True):
            rest = (k - k1 - keys) % N
            hit = np.isin(rest, keys)
            idx = np.searchsorted(np.sort(keys), rest[hit])
            c3 = vals[np.argsort(keys)][idx]
            s += c1 * np.sum(vals[hit] * c3)
        out[i] = a * s
    return out


def test_a_cubic_shows_at_the_detection_lines_and_leaves_the_even_lines_clean() -> None:
    d = _design(lines="odd", detection="1/3", realisations=2, realisation_periods=2, seed=3)
    lines = d.excitation_lines(TS)
    x = d.cycle(TS, np.array([1.0]))[:, 0]
    a = 0.2
    y = (x + a * x**3)[:, None]  # a static odd nonlinearity on the simulated input
    for r in range(2):
        block = y[r * 2 * N : (r + 1) * 2 * N]
        dist = distortion_lines(block, N, lines.excited, (lines.first, lines.last))
        assert dist.n_odd == lines.detection.size
        assert dist.n_even == lines.even.size
        # reference: the cubic's spectrum at the detection lines by triple convolution
        xl = np.fft.rfft(x[r * 2 * N : r * 2 * N + N])[lines.excited] / N
        want = _cubic_at(xl, lines.excited, a, lines.detection)
        assert dist.odd[0] == pytest.approx(float(np.mean(np.abs(want) ** 2)), rel=1e-9)
        assert dist.odd[0] > 1e-6
        assert dist.even[0] < 1e-25  # an odd nonlinearity puts nothing at the even lines


@pytest.fixture(scope="module")
def realisation_record() -> tuple[mp.ModelSimResult, int]:
    """Model B driven by 3 realisations of 5 periods (2 settling, 3 recorded), 64 samples."""
    design = ex.ExcitationDesign(
        kind="multisine", period_samples=64, f_min_hz=0.0, f_max_hz=0.2, lines="odd",
        realisations=3, seed=1,
    )  # fmt: skip
    cfg = mp.ModelSimConfig(
        model=load_model("B"),
        ts_s=1.0,
        excitation=mp.ModelExcitation(design=design, rms=0.05, offset=0.4),
        periods=3,
        settle_periods=2,
        noise_scale=0.2,
    )
    return mp.simulate_model(cfg), 5


def test_the_gate_passes_the_windows_inside_each_realisation(
    realisation_record: tuple[mp.ModelSimResult, int],
) -> None:
    res, per = realisation_record
    n = 64
    cfg = MonitorConfig(
        ts_s=1.0, period_samples=n, periods_per_window=2, settle_periods=1, hop_samples=n,
        realisation_periods=per,
    )  # fmt: skip
    reports = monitor_record(res.stamps_ns, res.u, res.y, cfg, [load_model("B")])
    ends = [round(r.end_ns / 1e9) + 1 for r in reports]  # samples seen at each report
    judged = {e for e, r in zip(ends, reports, strict=True) if r.judged}
    # by hand: a window (2 periods) and its settling (1) inside one realisation of 5 periods
    want = {e for e in ends if (e - 1) % (per * n) + 1 >= 3 * n}
    assert judged == want
    assert len(judged) == 3 * 3
    states = {r.quality.state for r in reports if not r.judged}
    assert states == {WindowState.SETTLING}  # never INPUT_NOT_PERIODIC
    # without the design the changes of realisation are non-periodic input
    plain = monitor_record(
        res.stamps_ns, res.u, res.y, MonitorConfig(**{**cfg.__dict__, "realisation_periods": 0}),
        [load_model("B")],
    )  # fmt: skip
    assert WindowState.INPUT_NOT_PERIODIC in {r.quality.state for r in plain}


def test_the_gate_still_flags_an_input_that_does_not_repeat(
    realisation_record: tuple[mp.ModelSimResult, int],
) -> None:
    res, per = realisation_record
    n = 64
    u = res.u.copy()
    u[7 * n + 10, 0] += 0.02  # one sample of the second realisation's third period moved
    cfg = MonitorConfig(
        ts_s=1.0, period_samples=n, periods_per_window=2, settle_periods=1, hop_samples=n,
        realisation_periods=per,
    )  # fmt: skip
    reports = monitor_record(res.stamps_ns, u, res.y, cfg, [load_model("B")])
    flagged = [r for r in reports if r.quality.state is WindowState.INPUT_NOT_PERIODIC]
    assert flagged
    assert all("input not periodic" in r.data_quality for r in flagged)
    assert not any(math.isfinite(r.beta) for r in flagged)


def test_a_realisation_shorter_than_a_window_is_refused() -> None:
    with pytest.raises(ValueError, match="shorter than a window and its settling"):
        MonitorConfig(periods_per_window=2, settle_periods=1, realisation_periods=2)


def test_a_scenario_takes_the_design_in_its_excitation_mapping() -> None:
    from twotank_validation.sim.scenario import Scenario, ScenarioError  # noqa: PLC0415

    s = Scenario(
        name="r", duration_s=1000.0, period_samples=128, excitation_kind="multisine",
        rms_hot=0.02, rms_cold=0.05, f_max_hz=2.0,
        excitation={"lines": "odd", "detection": "1/3", "realisations": 2,
                    "realisation_periods": 3},
    )  # fmt: skip
    design = s.design()
    assert (design.kind, design.lines, design.realisations, design.seed) == (
        "multisine", "odd", 2, s.excitation_seed,
    )  # fmt: skip
    table = s.command_table() - s.operating_point().commands
    np.testing.assert_allclose(table, design.cycle(s.ts_s, np.array([0.02, 0.05])), atol=1e-15)
    assert s.with_design({"realisations": 3}).design().realisations == 3
    with pytest.raises(ScenarioError, match="unknown key"):
        Scenario(name="r", duration_s=10.0, excitation={"kind": "multisine"})
