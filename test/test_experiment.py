"""The paper's experiment in simulation (Smith 1995, Sec. 4) and the demo command."""

from __future__ import annotations

import dataclasses
import json
from functools import cache

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from twotank_validation import cli, experiment
from twotank_validation.core import solvers
from twotank_validation.core.datum import NormConvention
from twotank_validation.core.model import PlantResponse, load_model
from twotank_validation.sim.rig import MODEL_HEIGHT_RANGE


@cache
def default_run() -> experiment.ExperimentResult:
    return experiment.run_experiment()


def test_model_a_invalidated_model_b_not_default_run() -> None:
    """Paper: beta_A = 1.32 (invalidated), beta_B = 0.53 (not invalidated)."""
    res = default_run()
    beta_a = res.outcomes["A"].validation.beta
    beta_b = res.outcomes["B"].validation.beta
    assert beta_a > 1.0
    assert beta_b < 1.0
    # Same side and the same order of magnitude as the paper's figures.
    assert 1.0 < beta_a < 2.0
    assert 0.3 < beta_b < 0.8
    lo, hi = res.height_range
    assert MODEL_HEIGHT_RANGE[0] <= lo
    assert hi <= MODEL_HEIGHT_RANGE[1]


@settings(max_examples=4)
@given(seed=st.sampled_from([0, 1, 3, 4, 5]))
def test_verdicts_hold_across_excitation_and_noise_seeds(seed: int) -> None:
    base = experiment.ExperimentConfig()
    cfg = dataclasses.replace(
        base, excitation=dataclasses.replace(base.excitation, seed=seed), seed=seed
    )
    res = experiment.run_experiment(cfg)
    assert res.outcomes["A"].validation.invalidated
    assert not res.outcomes["B"].validation.invalidated


def test_power_convention_is_energy_divided_by_sqrt_n() -> None:
    """||w||_power = ||w||_energy / sqrt(N): the two readings of the paper's DFT prefactor."""
    res = default_run()
    cfg = dataclasses.replace(res.config, convention=NormConvention.ENERGY)
    energy = experiment.run_experiment(cfg)
    n = res.datum.n_samples
    for name in ("A", "B"):
        p, e = res.outcomes[name].validation, energy.outcomes[name].validation
        assert p.convention is NormConvention.POWER
        assert e.convention is NormConvention.ENERGY
        assert p.beta == pytest.approx(e.beta / np.sqrt(n), rel=1e-12)


def test_minimum_norm_w_is_rms_of_time_signal() -> None:
    """Power convention: beta equals the RMS of the inverse-DFT minimising w(k) (Parseval)."""
    res = default_run()
    for name in ("A", "B"):
        v = res.outcomes[name].validation
        w = v.time_domain_noise()
        assert v.beta == pytest.approx(float(np.sqrt(np.mean(np.sum(w**2, axis=1)))), rel=1e-9)


def test_model_a_temperature_noise_is_near_sinusoid_at_input_period() -> None:
    """Paper Fig. 8: Model A's minimum-norm w on t1 is nearly a sinusoid at the input period."""
    res = default_run()
    v = res.outcomes["A"].validation
    w_t = v.solution.w[:, 1]
    power = v.bin_weights * np.abs(w_t) ** 2
    fundamental = res.datum.n_periods  # bin of the period's fundamental
    assert np.argmax(power) == fundamental
    assert power[fundamental] / power.sum() > 0.3


def test_general_solver_agrees_with_closed_form_on_tank_models() -> None:
    res = default_run()
    d = res.datum
    rng = np.random.default_rng(0)
    harmonic = np.flatnonzero(d.harmonic_bins)
    bins = np.unique(np.concatenate([harmonic[:120], rng.choice(d.theta.size, 80, replace=False)]))
    for name in ("A", "B"):
        model = load_model(name)
        resp = model.response(d.theta, d.ts_s)
        sub = PlantResponse(resp.p[bins], resp.blocks, resp.nw, resp.nu, resp.ny)
        sdp = solvers.solve_sdp(sub, d.u_bins[bins], d.y_bins[bins])
        exact = res.outcomes[name].validation.w_min[bins]
        assert sdp.certified.all()
        floor = 1e-9 * float(exact.max())  # DC bin holds round-off of the bias removal only
        np.testing.assert_allclose(sdp.lower, exact, rtol=1e-6, atol=floor)
        np.testing.assert_allclose(sdp.upper, exact, rtol=1e-6, atol=floor)


def test_leakage_bound_matches_independent_pulse_sum() -> None:
    """Ljung's bound 2 c_N sum_j max|u_j| sum_k k|p_ij(k)|, pulses from scipy.signal.dimpulse."""
    res = default_run()
    d = res.datum
    for name in ("A", "B"):
        model = load_model(name)
        sys_d = model.nominal_discrete(d.ts_s)
        n_coeffs = 60_000  # slowest pole 122.5 s at 0.1 s: decayed below 1e-20
        moment = np.zeros((2, 2))
        for j in range(2):
            _, (yout,) = scipy.signal.dimpulse(
                (sys_d.a, sys_d.b[:, [j]], sys_d.c, sys_d.d[:, [j]], d.ts_s), n=n_coeffs
            )
            moment[:, j] = np.sum(np.arange(n_coeffs)[:, None] * np.abs(yout), axis=0)
        expected = 2.0 / d.n_samples * moment @ d.u_max
        np.testing.assert_allclose(res.outcomes[name].validation.leakage, expected, rtol=1e-6)


def test_probabilistic_tests_side_by_side() -> None:
    """Section 2.1 tests run on the same datum; the mixing delay colours the t1 residual of both
    models, so whiteness rejects both although only Model A is invalidated."""
    res = default_run()
    for name in ("A", "B"):
        tests = res.outcomes[name].residual_tests
        assert set(tests.whiteness) == {"height", "temperature"}
        assert tests.whiteness["temperature"].p_value < 0.01
    rms_a = res.outcomes["A"].rms_error
    rms_b = res.outcomes["B"].rms_error
    assert rms_b[1] < rms_a[1]  # Model B's temperature error is smaller


def test_demo_writes_report(tmp_path) -> None:
    out = tmp_path / "rep"
    assert cli.main(["demo", "--out", str(out), "--no-sdp", "--quiet"]) == 0
    for f in (
        "summary.md",
        "results.json",
        "per_bin.png",
        "time_signals.png",
        "nyquist_A.png",
        "nyquist_B.png",
    ):
        assert (out / f).is_file(), f
    numbers = json.loads((out / "results.json").read_text())
    assert numbers["norm_convention"] == "power"
    assert numbers["models"]["A"]["invalidated"] is True
    assert numbers["models"]["B"]["invalidated"] is False
    assert numbers["models"]["A"]["beta"] == pytest.approx(
        default_run().outcomes["A"].validation.beta
    )
    assert "power" in (out / "summary.md").read_text()


def test_cli_reports_errors_without_traceback(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    from twotank_validation.core.model import load_model as load  # noqa: PLC0415

    with pytest.raises(Exception, match="not valid YAML"):
        load(bad)
    with pytest.raises(SystemExit):
        cli.main(["demo", "--norm", "bogus"])
    assert "invalid choice" in capsys.readouterr().err
