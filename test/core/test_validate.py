"""validate(): solver choice, dimension checks, and an input-multiplicative model end to end."""

from __future__ import annotations

import numpy as np
import pytest

from twotank_validation.core import lti
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model, model_from_dict
from twotank_validation.core.validate import validate
from twotank_validation.errors import DimensionError, ModelError

SISO_INPUT_MULT = {
    "name": "siso_im",
    "inputs": ["u"],
    "outputs": ["y"],
    "nominal": {"tf": {"num": [2.0], "den": [5.0, 1.0]}},
    "perturbations": [{"kind": "input_multiplicative", "inputs": ["u"], "weight": 0.2}],
    "noise": [{"outputs": ["y"], "weight": 0.05}],
}


def periodic_record(seed: int, n_periods: int = 2, period: int = 64):
    rng = np.random.default_rng(seed)
    u = np.tile(rng.normal(size=period), n_periods)
    return u, rng


def test_dimension_mismatch_is_named() -> None:
    u, rng = periodic_record(0)
    datum = make_datum(u, rng.normal(size=u.size), ts_s=0.1, period_samples=64)
    with pytest.raises(DimensionError, match="2 inputs"):
        validate(datum, load_model("A"))


SIMO_INPUT_MULT = {
    "name": "simo_im",
    "inputs": ["u"],
    "outputs": ["y1", "y2"],
    "nominal": {"ss": {"A": [[-0.2]], "B": [[1.0]], "C": [[1.0], [0.5]], "D": [[0.0], [0.0]]}},
    "perturbations": [{"kind": "input_multiplicative", "inputs": ["u"], "weight": 0.3}],
    "noise": [{"outputs": ["y1", "y2"], "weight": 0.05}],
}


def test_closed_form_refused_where_it_does_not_apply() -> None:
    u, rng = periodic_record(1)
    model = model_from_dict(SIMO_INPUT_MULT)
    datum = make_datum(u, rng.normal(size=(u.size, 2)), ts_s=0.1, period_samples=64)
    with pytest.raises(ModelError, match="closed form does not apply"):
        validate(datum, model, method="closed_form")
    with pytest.raises(ModelError, match="unknown method"):
        validate(datum, model, method="newton")


def test_coupled_structure_goes_to_fast_path_automatically() -> None:
    """Not decoupled, one block: auto takes the batched fast path, which equals the SDP path."""
    u, rng = periodic_record(3)
    model = model_from_dict(SIMO_INPUT_MULT)
    datum = make_datum(u, rng.normal(size=(u.size, 2)), ts_s=0.1, period_samples=64)
    res = validate(datum, model)
    assert res.method == "fast"
    assert "more than one output" in res.method_reason
    assert f"{res.fallback_bins} fell back" in res.method_reason
    assert res.summary()["fallback_bins"] == res.fallback_bins
    assert res.solution.certified.all()
    assert np.max(res.solution.gap) <= 1e-6 * np.max(res.w_upper)  # one block: bounds meet
    sdp = validate(datum, model, method="sdp")
    assert sdp.method == "sdp"
    assert sdp.method_reason == "SDP relaxation (requested)"
    floor = 1e-6 * float(np.max(sdp.w_upper))
    np.testing.assert_allclose(res.w_min, sdp.w_min, rtol=1e-6, atol=floor)
    np.testing.assert_allclose(res.w_upper, sdp.w_upper, rtol=1e-6, atol=floor)
    assert res.beta == pytest.approx(sdp.beta, rel=1e-6)


def test_fast_path_forced_on_a_decoupled_model_matches_closed_form() -> None:
    """method="fast" on Model A (which auto sends to the closed form): same bins, same beta."""
    rng = np.random.default_rng(4)
    period = 128
    u = np.tile(rng.normal(scale=0.05, size=(period, 2)), (2, 1))
    y = 0.3 * np.roll(u, 3, axis=0) @ np.array([[1.0, 0.5], [0.2, 1.0]])
    datum = make_datum(u, y + 0.01 * rng.normal(size=y.shape), ts_s=1.0, period_samples=period)
    model = load_model("A")
    auto = validate(datum, model)
    forced = validate(datum, model, method="fast")
    assert auto.method == "closed_form"
    assert forced.method == "fast"
    assert forced.method_reason.startswith("fast batched dual (requested)")
    assert forced.fallback_bins == 0
    floor = 1e-6 * float(np.max(auto.w_min))
    np.testing.assert_allclose(forced.w_min, auto.w_min, rtol=1e-6, atol=floor)
    np.testing.assert_allclose(forced.w_upper, auto.w_upper, rtol=1e-6, atol=floor)
    assert forced.beta == pytest.approx(auto.beta, rel=1e-9)
    np.testing.assert_allclose(forced.error, auto.error, rtol=1e-12, atol=1e-15)


FOUR_BLOCKS = {
    "name": "four_blocks",
    "inputs": ["u"],
    "outputs": ["y"],
    "nominal": {"tf": {"num": [2.0], "den": [5.0, 1.0]}},
    "perturbations": [
        {"kind": "output_multiplicative", "outputs": ["y"], "weight": 0.1},
        {"kind": "input_multiplicative", "inputs": ["u"], "weight": 0.1},
        {"kind": "additive", "inputs": ["u"], "outputs": ["y"], "weight": 0.05},
        {"kind": "additive", "inputs": ["u"], "outputs": ["y"], "weight": 0.02},
    ],
    "noise": [{"outputs": ["y"], "weight": 0.05}],
}


def test_structure_beyond_the_fast_path_goes_to_sdp() -> None:
    """Four blocks: auto falls through to the per-bin SDP and says why; "fast" is refused."""
    u, rng = periodic_record(5, period=16)
    model = model_from_dict(FOUR_BLOCKS)
    datum = make_datum(u, rng.normal(size=u.size), ts_s=0.1, period_samples=16)
    res = validate(datum, model)
    assert res.method == "sdp"
    assert "fast path not applicable (4 blocks" in res.method_reason
    with pytest.raises(ModelError, match="fast path does not cover"):
        validate(datum, model, method="fast")


def test_siso_input_multiplicative_matches_scalar_formula() -> None:
    """SISO input-multiplicative: y = G(u + W v) + W_n w, |v| <= |u|; per bin the reach of
    the perturbation is |G W U| around G U, so min |w| = max(0, |E| - |G W U|)/W_n."""
    u, rng = periodic_record(2)
    model = model_from_dict(SISO_INPUT_MULT)
    g = lti.frequency_response(model.nominal_discrete(0.1), 2 * np.pi * np.arange(65) / 128)[
        :, 0, 0
    ]
    y_bins = g * np.fft.rfft(u - u.mean()) * (1 + 0.3 * rng.normal(size=65))
    y = np.fft.irfft(y_bins, n=128) + 0.01 * rng.normal(size=128)
    datum = make_datum(u, y, ts_s=0.1, period_samples=64)
    res = validate(datum, model)
    assert res.method == "closed_form"  # one output, one scalar block: decoupled
    sdp = validate(datum, model, method="sdp")
    e = datum.y_bins[:, 0] - g * datum.u_bins[:, 0]
    expected = np.maximum(0.0, np.abs(e) - np.abs(g * 0.2 * datum.u_bins[:, 0])) / 0.05
    floor = 1e-9 * expected.max()
    np.testing.assert_allclose(res.w_min, expected, rtol=1e-6, atol=floor)
    np.testing.assert_allclose(sdp.w_min, expected, rtol=1e-6, atol=floor)
    np.testing.assert_allclose(sdp.w_upper, expected, rtol=1e-6, atol=floor)
    assert res.beta == pytest.approx(np.sqrt(np.sum(datum.bin_weights * expected**2)), rel=1e-6)


# --------------------------------------------------------------- warnings on the verdict


@pytest.fixture(scope="module")
def rig_record():
    """Seven periods of the nominal simulated rig (Ts 0.1 s, period 2048): u, y."""
    import dataclasses  # noqa: PLC0415

    from twotank_validation.sim.scenario import load_scenario, simulate_scenario  # noqa: PLC0415

    s = dataclasses.replace(load_scenario("nominal"), duration_s=7 * 204.8)
    _, u, y = simulate_scenario(s)
    return u, y


def _model_b_without(noise_names: set[str]):
    import copy  # noqa: PLC0415

    from twotank_validation.core.model import load_model_document, model_from_dict  # noqa: PLC0415

    doc, _ = load_model_document("B")
    doc = copy.deepcopy(doc)
    doc["noise"] = [ch for ch in doc["noise"] if ch["name"] not in noise_names]
    if not doc["noise"]:
        del doc["noise"]
    return model_from_dict(doc, "test")


def test_a_settled_record_has_no_warnings(rig_record) -> None:
    from twotank_validation import load_model, make_datum, validate  # noqa: PLC0415

    u, y = rig_record
    d = make_datum(u[-4096:], y[-4096:], ts_s=0.1, period_samples=2048)  # 5 periods settled
    assert validate(d, load_model("B")).warnings == ()


def test_a_start_up_transient_is_flagged(rig_record) -> None:
    from twotank_validation import load_model, make_datum, validate  # noqa: PLC0415

    u, y = rig_record
    d = make_datum(u[:4096], y[:4096], ts_s=0.1, period_samples=2048)  # from the excitation's start
    assert d.periodicity.transient_suspected  # the datum's own finding, independent of validate
    res = validate(d, load_model("B"))
    assert any("transient" in w for w in res.warnings)


def test_inputs_that_do_not_move_are_flagged() -> None:
    from twotank_validation import load_model, make_datum, validate  # noqa: PLC0415

    u = np.tile([0.4, 0.5], (4096, 1))
    noise = np.random.default_rng(0).normal(0.0, 0.003, (4096, 2))
    d = make_datum(u, 0.47 + noise, ts_s=0.1, period_samples=2048)
    res = validate(d, load_model("B"))
    assert any("inputs do not move" in w for w in res.warnings)
    moving = make_datum(
        u + np.tile(np.r_[np.ones(1024), -np.ones(1024)][:, None] * 0.01, (2, 1)),
        0.47 + noise,
        ts_s=0.1,
        period_samples=2048,
    )
    assert not any("do not move" in w for w in validate(moving, load_model("B")).warnings)


def test_a_model_without_noise_is_flagged_and_refused_by_the_monitor(rig_record) -> None:
    from twotank_validation import MonitorConfig, OnlineValidator, make_datum, validate  # noqa: PLC0415
    from twotank_validation.errors import ModelError  # noqa: PLC0415

    u, y = rig_record
    d = make_datum(u[-4096:], y[-4096:], ts_s=0.1, period_samples=2048)
    bare = _model_b_without({"height_noise", "temperature_noise"})
    res = validate(d, bare)
    assert not np.isfinite(res.beta)  # noisy data: no ||w|| explains them (independent fact)
    assert any("no noise channels" in w for w in res.warnings)
    with pytest.raises(ModelError, match="no noise channels"):
        OnlineValidator(MonitorConfig(), [bare])
    half = _model_b_without({"temperature_noise"})
    res = validate(d, half)
    assert not np.isfinite(res.beta)
    assert any("beta is infinite" in w for w in res.warnings)
