"""The simulator for any LFT model (twotank_validation.sim.model_plant), against references.

References: the model's own frequency response (``LFTModel.response``), ``scipy.signal.dlsim``
of the closed loop, the validator (``make_datum`` + ``validate``), and each fault's closed
form (a bias adds b, a gain scales the input, a delay shifts the output).
"""

from __future__ import annotations

import dataclasses
import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import scipy.signal

from twotank_validation import make_datum, validate
from twotank_validation.core import lti
from twotank_validation.core.model import LFTModel, load_model
from twotank_validation.errors import ModelError, TwotankError, UnstableModelError
from twotank_validation.sim import model_plant as mp

DATA = Path(__file__).resolve().parents[1] / "data" / "models"
SHAPES = ("siso", "one_by_three", "three_by_two")
TS = 0.1
N = 256


@cache
def model(name: str) -> LFTModel:
    return load_model(DATA / f"{name}.yaml") if name != "B" else load_model("B")


def config(name: str, **kw) -> mp.ModelSimConfig:
    exc = {"period_samples": N, "rms": 0.2, "f_max_hz": 1.0, "seed": 3}
    exc |= kw.pop("excitation", {})
    kw.setdefault("ts_s", TS)
    return mp.ModelSimConfig(model=model(name), excitation=mp.ModelExcitation(**exc), **kw)


def beta(res: mp.ModelSimResult) -> float:
    u, y = res.recorded()
    datum = make_datum(u, y, ts_s=res.ts_s, period_samples=res.period_samples)
    return validate(datum, res.config.model).beta


def w_norm(res: mp.ModelSimResult) -> float:
    """||w|| of the recorded periods in the validator's power convention."""
    w = res.w[res.record_slice]
    return math.sqrt(float(np.mean(np.sum(w**2, axis=1))))


# ----------------------------------------------------------------- the discrete plant


@pytest.mark.parametrize("name", [*SHAPES, "B"])
def test_discrete_plant_is_the_models_generalised_plant(name: str) -> None:
    m = model(name)
    theta = np.linspace(1e-3, np.pi - 1e-3, 41)
    p = mp.discrete_plant(m, TS)
    assert p.shape == (m.blocks.nz + m.ny, m.blocks.nv + m.nw + m.nu)
    ref = m.response(theta, TS).p
    np.testing.assert_allclose(lti.frequency_response(p, theta), ref, rtol=0, atol=1e-12)


def test_whole_sample_model_delays_become_states_and_fractional_ones_are_refused() -> None:
    doc = {
        "name": "delayed",
        "inputs": ["u"],
        "outputs": ["y1", "y2"],
        "nominal": {
            "ss": {
                "A": [[-1.0]],
                "B": [[1.0]],
                "C": [[1.0], [2.0]],
                "D": [[0.0], [0.5]],
                "output_delays_s": [0.3, 0.0],
            },
        },
    }
    m = load_model(doc)
    theta = np.linspace(0.01, 3.0, 17)
    p = mp.discrete_plant(m, TS)
    np.testing.assert_allclose(
        lti.frequency_response(p, theta), m.response(theta, TS).p, rtol=0, atol=1e-12
    )
    with pytest.raises(mp.ModelSimError, match=r"whole number of samples"):
        mp.discrete_plant(m, 0.07)


def test_gain_member_closes_the_loop_as_the_upper_lft_bin_by_bin() -> None:
    m = model("three_by_two")
    member = mp.Member(kind="gains", gains=(0.7, -1.0, 0.4))
    cl = mp.close_loop(mp.discrete_plant(m, TS), mp.delta_system(m, member, TS), 4, 4)
    theta = np.linspace(0.01, 3.0, 13)
    resp = m.response(theta, TS)
    delta = np.zeros((4, 4))  # blocks (2x2, 1x1, 1x1): δ I each
    delta[0, 0] = delta[1, 1] = 0.7
    delta[2, 2], delta[3, 3] = -1.0, 0.4
    # F_u(P, Δ) = P22' + P21 Δ (I - P11 Δ)^-1 P12', with P' the [w; u] columns
    ref = resp.p[:, 4:, 4:] + resp.p21 @ delta @ np.linalg.solve(
        np.eye(4) - resp.p11 @ delta, resp.p[:, :4, 4:]
    )
    np.testing.assert_allclose(lti.frequency_response(cl, theta), ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_random_member_is_stable_and_inside_the_unit_ball(seed: int) -> None:
    m = model("three_by_two")
    d = mp.delta_system(m, mp.Member(kind="random", seed=seed, scale=0.9), TS)
    assert d.shape == (m.blocks.nv, m.blocks.nz)
    assert np.max(np.abs(np.linalg.eigvals(d.a))) < 1.0
    resp = lti.frequency_response(d, np.linspace(0.0, np.pi, 2001))
    for vs, zs in zip(m.blocks.v_slices, m.blocks.z_slices, strict=True):
        gains = np.linalg.norm(resp[:, vs, zs], ord=2, axis=(1, 2))
        assert gains.max() == pytest.approx(0.9, abs=1e-12)  # ||Δ_i||∞ = scale
    off_block = resp.copy()
    for vs, zs in zip(m.blocks.v_slices, m.blocks.z_slices, strict=True):
        off_block[:, vs, zs] = 0.0
    assert np.all(off_block == 0.0)  # block diagonal


# ----------------------------------------------------------------- the simulated record


@pytest.mark.parametrize("name", SHAPES)
def test_steady_state_dft_is_the_nominal_response_times_the_input(name: str) -> None:
    res = mp.simulate_model(config(name, noise_scale=0.0, periods=3))
    u, y = res.recorded()
    n = u.shape[0]
    assert n == 3 * N
    U, Y = np.fft.rfft(u, axis=0) / n, np.fft.rfft(y, axis=0) / n
    harmonics = mp.ModelExcitation(period_samples=N, f_max_hz=1.0).band(TS)
    k = np.arange(1, N // 2)
    k = k[(k / (N * TS) >= harmonics[0] - 1e-12) & (k / (N * TS) <= 1.0 + 1e-12)]
    bins = 3 * k  # whole periods: the excitation lives on every 3rd bin
    g = model(name).response(2 * np.pi * bins / n, TS).p23
    predicted = np.einsum("kij,kj->ki", g, U[bins])
    scale = np.max(np.abs(Y[bins]))
    np.testing.assert_allclose(Y[bins], predicted, rtol=0, atol=1e-9 * scale)
    others = np.setdiff1d(np.arange(1, n // 2), bins)
    assert np.max(np.abs(Y[others])) <= 1e-9 * scale  # periodic: nothing between harmonics
    y_op = [model(name).operating_point.get(o, 0.0) for o in model(name).output_names]
    np.testing.assert_allclose(Y[0].real, y_op, atol=1e-9)


@pytest.mark.parametrize("member", ["nominal", "gains=0.8,-0.5,1", "random,seed=2"])
def test_record_is_dlsim_of_the_closed_loop(member: str) -> None:
    cfg = config("three_by_two", member=member, periods=1, settle_periods=1)
    res = mp.simulate_model(cfg)
    sys = mp.closed_loop_system(cfg)
    q = np.hstack([res.w, res.u - np.asarray(cfg.offset)])
    _, y_ref, _ = scipy.signal.dlsim((sys.a, sys.b, sys.c, sys.d, TS), q)
    np.testing.assert_allclose(res.y - cfg.output_operating_point(), y_ref, rtol=0, atol=1e-12)


def test_start_at_rest_at_the_operating_point_and_commands_around_the_offsets() -> None:
    cfg = config("three_by_two", excitation={"offset": {"heater": 0.3}, "rms": [0.1, 0.0, 0.2]})
    res = mp.simulate_model(cfg)
    assert cfg.offset == (0.0, 0.0, 0.3)
    np.testing.assert_allclose(res.u.mean(axis=0), cfg.offset, atol=1e-12)
    np.testing.assert_allclose(res.u.std(axis=0), [0.1, 0.0, 0.2], rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(res.stamps_ns, np.arange(res.n_samples) * 100_000_000)
    # sample 0: state 0, y = y_op + D (u(0) - offset) + noise path (static noise on level)
    assert res.y[0, 0] == pytest.approx(0.4 + 0.01 * res.w[0, 0], abs=1e-15)
    assert res.settle_periods == mp.settling_periods(mp.closed_loop_system(cfg), N)
    assert res.n_samples == (res.settle_periods + cfg.periods) * N


def test_stepping_equals_the_batch_bit_for_bit() -> None:
    cfg = config(
        "three_by_two",
        member="random,seed=5,scale=0.7",
        faults=(
            "input_gain:feed_a=0.6@30",
            "stuck_input:heater@40-60",
            "sensor_bias:temp=0.05@35",
            "output_delay:level=1.25@20",
        ),
        settle_periods=1,
    )
    res = mp.simulate_model(cfg)
    plant = mp.ModelPlant(cfg)
    for k in range(res.n_samples):
        s = plant.step()
        assert s.stamp_ns == res.stamps_ns[k]
        assert np.array_equal(s.u, res.u[k])
        assert np.array_equal(s.y, res.y[k])
        assert np.array_equal(s.w, res.w[k])


# ----------------------------------------------------------------- the validator's verdict


@pytest.mark.parametrize("name", SHAPES)
def test_validator_does_not_invalidate_the_model_on_its_own_data(name: str) -> None:
    # 0.9: the realised ||w|| scatters ~1/sqrt(2 N nw) (about 2 %) around noise_scale
    res = mp.simulate_model(config(name, noise_scale=0.9, periods=4, noise_seed=11))
    assert beta(res) <= 1.0


@pytest.mark.parametrize("name", SHAPES)
@pytest.mark.parametrize("member", ["nominal", "gains=1", "gains=-0.6", "random,seed=4"])
def test_beta_is_at_most_the_realised_noise_for_any_member(name: str, member: str) -> None:
    """The true (Δ, w) explains the data, so the smallest ||w|| is at most ||w_true||."""
    res = mp.simulate_model(config(name, member=member, periods=4, noise_seed=5))
    b = beta(res)
    assert b <= w_norm(res) * (1.0 + 1e-3)  # slack: a dynamic noise weight's edge leakage
    assert b > 0.5  # and the noise is seen


FAULTS = {
    "input_gain": "input_gain:feed_a=0.5@0",
    "stuck_input": "stuck_input:feed_b@0",
    "sensor_bias": "sensor_bias:temp=0.2@{mid}",
    "output_delay": "output_delay:level=3@0",
}


@pytest.mark.parametrize("kind", sorted(FAULTS))
def test_each_fault_invalidates_the_model(kind: str) -> None:
    base = config("three_by_two", noise_scale=0.9, periods=4, settle_periods=3)
    mid = (3 + 2) * N * TS + 0.05  # the middle of the recorded periods
    faulty = dataclasses.replace(base, faults=(FAULTS[kind].format(mid=mid),))
    assert beta(mp.simulate_model(base)) <= 1.0
    assert beta(mp.simulate_model(faulty)) > 1.0


# ----------------------------------------------------------------- faults in closed form


def _pair(fault: str, name: str = "three_by_two", **kw):
    clean = config(name, settle_periods=0, periods=2, **kw)
    faulty = dataclasses.replace(clean, faults=(fault,))
    return mp.simulate_model(clean), mp.simulate_model(faulty), clean


def _fed(cfg: mp.ModelSimConfig, applied: np.ndarray) -> np.ndarray:
    """The fault-free plant fed with ``applied`` instead of its commands."""
    plant = mp.ModelPlant(cfg)
    return np.array([plant.step(row).y for row in applied])


def test_sensor_bias_adds_exactly_b_after_the_onset() -> None:
    clean, faulty, _ = _pair("sensor_bias:temp=0.25@12.34-30")
    k = np.arange(clean.n_samples)
    on = (k >= 124) & (k < 300)  # first sample with k ts >= 12.34 s; removed from 30 s
    np.testing.assert_allclose(faulty.y[:, 1] - clean.y[:, 1], 0.25 * on, rtol=0, atol=1e-14)
    assert np.array_equal(faulty.y[:, 0], clean.y[:, 0])
    assert np.array_equal(faulty.u, clean.u)


def test_input_gain_scales_exactly_that_input() -> None:
    clean, faulty, cfg = _pair("input_gain:heater=0.4@5", excitation={"offset": [0.0, 0.0, 0.5]})
    assert np.array_equal(faulty.u, clean.u)  # the commands are recorded, not the fault
    applied = clean.u.copy()
    applied[50:, 2] *= 0.4
    assert np.array_equal(faulty.y, _fed(cfg, applied))
    assert not np.allclose(faulty.y[60:], clean.y[60:])


def test_stuck_input_holds_the_value_before_the_onset() -> None:
    clean, faulty, cfg = _pair("stuck_input:feed_b@7.05")
    applied = clean.u.copy()
    applied[71:, 1] = clean.u[70, 1]  # onset at sample 71 (k ts >= 7.05 s)
    assert np.array_equal(faulty.y, _fed(cfg, applied))
    assert np.array_equal(faulty.u, clean.u)


def test_output_delay_is_the_shifted_output_at_multiples_of_ts() -> None:
    clean, faulty, _ = _pair("output_delay:level=2.5@10", noise_scale=0.5)
    assert np.array_equal(faulty.y[:100], clean.y[:100])
    np.testing.assert_array_equal(faulty.y[100:, 0], clean.y[75:-25, 0])
    assert np.array_equal(faulty.y[:, 1], clean.y[:, 1])


def test_fractional_output_delay_interpolates_linearly_and_rests_before_time_0() -> None:
    clean, faulty, cfg = _pair("output_delay:temp=0.25@0")
    y = clean.y[:, 1]
    past = np.concatenate([[cfg.output_operating_point()[1]] * 3, y])  # y(k) for k >= -3
    k = np.arange(clean.n_samples)
    ref = 0.5 * past[k + 3 - 2] + 0.5 * past[k + 3 - 3]  # y(k - 2.5)
    np.testing.assert_allclose(faulty.y[:, 1], ref, rtol=0, atol=1e-15)


# ----------------------------------------------------------------- text forms and errors


@pytest.mark.parametrize(
    ("spec", "fault"),
    [
        ("input_gain:u1=0.5@300", mp.ModelFault("input_gain", "u1", 0.5, 300.0)),
        ("stuck_input:u1@300", mp.ModelFault("stuck_input", "u1", 0.0, 300.0)),
        ("sensor_bias:y2=-0.1@300-400", mp.ModelFault("sensor_bias", "y2", -0.1, 300.0, 400.0)),
        ("output_delay:y1=2.5@0", mp.ModelFault("output_delay", "y1", 2.5, 0.0)),
    ],
)
def test_fault_text_round_trip(spec: str, fault: mp.ModelFault) -> None:
    assert mp.parse_model_fault(spec) == fault
    assert mp.parse_model_fault(mp.format_model_fault(fault)) == fault


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("input_gain=0.5@3", "KIND:CHANNEL"),
        ("leak:u1=0.5@3", "unknown"),
        ("stuck_input:u1=1@3", "takes no magnitude"),
        ("sensor_bias:y1@3", "needs =MAGNITUDE"),
        ("sensor_bias:y1=nan@3", "finite"),
        ("output_delay:y1=-1@3", ">= 0"),
        ("input_gain:u1=0.5@5-2", "later than"),
        ("input_gain:u1=x@5", "KIND:CHANNEL"),
    ],
)
def test_bad_fault_text_is_refused(spec: str, match: str) -> None:
    with pytest.raises(mp.ModelSimError, match=match):
        mp.parse_model_fault(spec)


@pytest.mark.parametrize("text", ["nominal", "gains=0.5", "gains=0.5,-1,0", "random,seed=3"])
def test_member_text_round_trip(text: str) -> None:
    member = mp.parse_member(text)
    assert mp.parse_member(mp.format_member(member)) == member


def test_unknown_channel_names_it_and_lists_the_models_channels() -> None:
    with pytest.raises(mp.ModelSimError) as err:
        config("three_by_two", faults=("sensor_bias:pressure=0.1@3",))
    text = str(err.value)
    assert "'pressure'" in text
    assert "['level', 'temp']" in text
    assert "['feed_a', 'feed_b', 'heater']" in text
    with pytest.raises(mp.ModelSimError, match=r"'heater' is an input"):
        config("three_by_two", faults=("sensor_bias:heater=0.1@3",))
    with pytest.raises(mp.ModelSimError, match=r"unknown channel\(s\) \['hot'\]"):
        config("three_by_two", excitation={"rms": {"hot": 0.1}})


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"ts_s": math.nan}, "ts_s=nan must be finite"),
        ({"ts_s": -0.1}, "ts_s=-0.1 must be > 0"),
        ({"noise_scale": math.nan}, "noise_scale"),
        ({"excitation": {"rms": [0.1, math.nan, 0.1]}}, r"rms\[1\]"),
        ({"excitation": {"rms": [0.1, 0.2]}}, "3 channels"),
        ({"excitation": {"period_samples": 2.5}}, "whole number of samples"),
        ({"excitation": {"period_samples": 0}}, "whole number of samples"),
        ({"excitation": {"f_max_hz": 100.0}}, "Nyquist"),
        ({"periods": 0}, "periods=0"),
        ({"member": "gains=0.5,0.5"}, "3 perturbation block"),
        ({"member": "gains=1.5"}, r"\[-1, 1\]"),
        ({"member": "random,scale=2"}, "<= 1"),
    ],
)
def test_bad_settings_raise_a_clear_error(kw: dict, match: str) -> None:
    with pytest.raises(mp.ModelSimError, match=match) as err:
        config("three_by_two", **kw)
    assert isinstance(err.value, TwotankError)
    assert isinstance(err.value, ModelError)


def test_unstable_models_and_members_are_refused() -> None:
    doc = {"name": "u", "inputs": ["u"], "outputs": ["y"], "nominal": {"tf": {"num": [1.0],
           "den": [1.0, -0.5]}}}  # fmt: skip
    with pytest.raises(UnstableModelError, match="not stable"):
        load_model(doc)
    # a generalised P with P11 = 1.5/(s+1): stable alone, unstable closed with δ = 1
    gp = {
        "name": "g",
        "inputs": ["u"],
        "outputs": ["y"],
        "generalized_plant": {
            "ss": {
                "A": [[-1.0]],
                "B": [[1.5, 0.0, 1.0]],
                "C": [[1.0], [1.0]],
                "D": [[0.0, 0.0, 0.0], [0.0, 0.1, 0.0]],
            },
            "blocks": [[1, 1]],
            "noise_inputs": 1,
        },
    }
    m = load_model(gp)
    base = mp.ModelSimConfig(
        model=m, ts_s=TS, excitation=mp.ModelExcitation(period_samples=N, f_max_hz=1.0)
    )
    assert mp.simulate_model(base).n_samples > 0  # the nominal is fine
    with pytest.raises(UnstableModelError, match="choose the nominal or smaller gains"):
        mp.simulate_model(dataclasses.replace(base, member=mp.parse_member("gains=1")))
    mp.simulate_model(dataclasses.replace(base, member=mp.parse_member("gains=0.5")))
