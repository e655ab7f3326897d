"""Tests of the catalogue's input, supply, offset and saturation effects.

References are independent of the diagnosis code:

* the input gain against the closed form (the input's column of the response scaled);
* the hot-supply change against the rig re-linearised with ``RigParams.hot_supply_temp``
  changed (``twotank_validation.sim.linearise``);
* each scenario against the change injected into the simulated rig: a weak valve (the rig's
  ``valve_weak`` fault, commands raised to hold the operating point), a changed hot supply
  (``RigParams``), a sensor bias (the rig's ``sensor_bias`` fault), a valve that saturates
  (commands clipped by hand with ``np.minimum`` before simulating, the recorded commands
  unclipped), an output gain (the measured level's deviation scaled by hand);
* the distortion test's null distribution against simulated linear periodic data with
  Gaussian noise (its rejection rate at alpha over seeds).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from twotank_validation.core.model import load_model_document, model_from_dict
from twotank_validation.core.oppoint import OperatingPoint
from twotank_validation.diagnose import Nominal, Window, catalogue, diagnose
from twotank_validation.diagnose.distortion import distortion_test
from twotank_validation.sim import excitation, rig, simulator
from twotank_validation.sim.faults import Fault
from twotank_validation.sim.linearise import linearise_model_a, linearise_model_b

NOISE = {"noise_std_height": 0.003, "noise_std_temperature": 0.01}
H0 = 0.47
SLOW = settings(
    max_examples=2,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
)


def sim_windows(
    params: rig.RigParams,
    seed: int = 0,
    *,
    hot_gain: float = 1.0,
    clip: float | None = None,
    faults: tuple[Fault, ...] = (),
    kind: str = "filtered_noise",
    n_windows: int = 4,
) -> list[Window]:
    """Rig data around h 0.47, t 0.5: windows of two periods after five of settling.

    ``hot_gain``: the hot valve delivers this fraction of its command (the rig's weak-valve
    fault) and its command is raised to hold the operating point; ``clip``: the hot valve
    opens no further than this command (clipped by hand; the recorded command is not).
    """
    exc = excitation.ExcitationConfig(
        kind=kind, rms=(0.1, 0.1), cutoff_hz=0.01, seed=seed + 2, record_periods=2 * n_windows,
        odd_only=kind == "multisine", f_max_hz=0.05,
    )  # fmt: skip
    op = rig.operating_point(params)
    offset = op.commands / np.array([hot_gain, 1.0])
    commands = excitation.excitation_commands(exc, offset)
    applied = commands.copy()
    if clip is not None:
        applied[:, 0] = np.minimum(applied[:, 0], clip)
    weak = (Fault("valve_weak", 0.0, hot_gain, "hot"),) if hot_gain != 1.0 else ()
    sim = simulator.simulate(params, applied, exc.ts_s, op=op, seed=seed, faults=weak + faults)
    rec = excitation.record_slice(exc)
    u, y, n = commands[rec], sim.measured[rec], 2 * exc.period_samples
    return [
        Window(u[i * n : (i + 1) * n], y[i * n : (i + 1) * n], exc.ts_s, exc.period_samples)
        for i in range(n_windows)
    ]


def run(windows: list[Window], model: str = "B", **kw):
    doc, source = load_model_document(model)
    return diagnose(windows, doc, source=source, **kw)


def specs(model: str):
    doc, _ = load_model_document(model)
    m = model_from_dict(doc)
    nom = Nominal.from_document(doc)
    found, skipped = catalogue(
        nom, m.output_names, period_s=204.8, operating_point=m.operating_point,
        inputs=m.input_names,
    )  # fmt: skip
    return nom, found, skipped


def _cont(nom: Nominal, omega: np.ndarray) -> np.ndarray:
    eye = np.eye(nom.a.shape[0])
    return np.array([nom.c @ np.linalg.solve(1j * w * eye - nom.a, nom.b) + nom.d for w in omega])


# --------------------------------------------------------------------------- the structure


@given(g=st.floats(-0.9, 1.0), i=st.integers(0, 1))
def test_input_gain_scales_one_inputs_column(g, i):
    nom, found, _ = specs("B")
    spec = next(s for s in found if s.kind == "input_gain" and s.input == i)
    omega = np.geomspace(1e-3, 1.0, 9)
    before, after = _cont(nom, omega), _cont(spec.apply(nom, np.array([g])), omega)
    np.testing.assert_allclose(after[:, :, i], (1 + g) * before[:, :, i], atol=1e-12)
    np.testing.assert_allclose(after[:, :, 1 - i], before[:, :, 1 - i], atol=1e-12)
    assert spec.target(("height", "temperature")) == ("hot", "cold")[i]


@given(delta=st.floats(-0.4, 0.4))
def test_hot_supply_change_is_the_rigs_relinearisation(delta):
    """B and A changed by delta equal the rig re-linearised with t_h = 1 + delta."""
    base, params = rig.RigParams(), rig.RigParams(hot_supply_temp=1.0 + delta)
    for model, linearise in (("B", linearise_model_b), ("A", linearise_model_a)):
        nom, found, _ = specs(model)
        out = next(s for s in found if s.kind == "hot_supply").apply(nom, np.array([delta]))
        want = linearise(params, rig.operating_point(params))
        have = linearise(base, rig.operating_point(base))
        np.testing.assert_allclose(out.a - nom.a, want.a - have.a, atol=1e-12)
        np.testing.assert_allclose(out.b - nom.b, want.b - have.b, atol=1e-12)


def test_hot_supply_needs_state_names_and_a_hot_input():
    doc, _ = load_model_document("B")
    ss = {k: v for k, v in doc["nominal"]["ss"].items() if k != "states"}
    nom = Nominal.from_document(dict(doc, nominal={"ss": ss}))
    found, skipped = catalogue(
        nom, ("height", "temperature"), period_s=204.8, operating_point={}, inputs=("hot", "cold")
    )
    assert "hot_supply" not in {s.kind for s in found}
    assert "states" in dict(skipped)["hot_supply"]
    nom = Nominal.from_document(doc)
    _, skipped = catalogue(
        nom, ("height", "temperature"), period_s=204.8, operating_point={}, inputs=("a", "b")
    )
    assert "'hot'" in dict(skipped)["hot_supply"]


# --------------------------------------------------------------------------- the rig


def _effects(diag) -> dict:
    return {(e.spec.kind, e.to_dict(diag.outputs)["channel"]): e.values for e in diag.effects}


@SLOW
@given(k=st.floats(0.6, 0.85), seed=st.integers(0, 10_000))
def test_weak_valve_is_an_input_gain(k, seed):
    """A hot valve delivering k of its command: an input gain k - 1 on hot, not an output gain.

    Tolerance 0.03 absolute: the fit's error over seeds is < 0.01 (the rig's valve is linear
    in its command; the rest is noise).
    """
    diag = run(sim_windows(rig.RigParams(**NOISE), seed, hot_gain=k))
    got = _effects(diag)
    assert set(got) == {("input_gain", "hot")}, diag.summary
    assert got["input_gain", "hot"][0] == pytest.approx(k - 1.0, abs=0.03)
    assert "not an output gain" in diag.effects[0].evidence
    assert diag.after.rms["height"] <= 0.5 * diag.before.rms["height"]
    assert diag.to_json()["effects"][0]["channel"] == "hot"


def test_an_output_gain_is_not_an_input_gain():
    """The level sensor's deviation scaled by 1.3 by hand: a gain on height, not on an input."""
    ws = sim_windows(rig.RigParams(**NOISE), 3)
    scaled = [Window(w.u, w.y * [1.3, 1.0] - [0.3 * H0, 0.0], w.ts_s, w.period_samples) for w in ws]
    got = _effects(run(scaled))
    assert set(got) == {("gain", "height")}
    assert got["gain", "height"][0] == pytest.approx(0.3, abs=0.03)


@SLOW
@given(delta=st.sampled_from([-0.2, -0.15, 0.15, 0.2]), seed=st.integers(0, 10_000))
def test_hot_supply_change_is_found(delta, seed):
    """The rig's hot supply at 1 + delta: the hot-supply change, delta within 0.04.

    The tolerance: the rig's own nonlinearity (t = E/h) biases the fitted delta by about
    0.015 (the nominal rig's fit), plus noise.
    """
    diag = run(sim_windows(rig.RigParams(**NOISE, hot_supply_temp=1.0 + delta), seed))
    got = _effects(diag)
    assert set(got) == {("hot_supply", "hot")}, diag.summary
    assert got["hot_supply", "hot"][0] == pytest.approx(delta, abs=0.04)
    assert "height's stays at" in diag.effects[0].evidence
    assert diag.document is not None


@SLOW
@given(
    channel=st.sampled_from(["height", "temperature"]),
    bias=st.sampled_from([-0.08, -0.04, 0.04, 0.08]),
    seed=st.integers(0, 10_000),
)
def test_sensor_bias_is_an_offset_on_the_operating_point(channel, bias, seed):
    """The rig's sensor bias: an offset on that output within 0.002 (noise / sqrt(N) is
    ~1e-4; the rest is the rig's nonlinear mean shift), no dynamic effect."""
    ws = sim_windows(
        rig.RigParams(**NOISE), seed, faults=(Fault("sensor_bias", 0.0, bias, channel),)
    )
    diag = run(ws)
    assert diag.effects == []
    assert diag.document is None
    assert [(f.kind, f.target) for f in diag.findings] == [("offset", channel)], diag.summary
    found = diag.findings[0]
    assert found.parameters["offset"] == pytest.approx(bias, abs=0.002)
    assert f"in all {len(ws)} windows" in found.evidence
    assert "dynamics are unchanged" in found.evidence
    assert not diag.adequate
    assert "recalibrate" in diag.summary
    # the same against a reference operating point: a stretch of the nominal rig
    ref_w = sim_windows(rig.RigParams(**NOISE), seed + 1, n_windows=2)
    ref = OperatingPoint(
        u=np.mean([w.u.mean(0) for w in ref_w], 0), y=np.mean([w.y.mean(0) for w in ref_w], 0)
    )
    again = run(ws, reference=ref)
    assert [(f.kind, f.target) for f in again.findings] == [("offset", channel)]
    assert again.findings[0].parameters["offset"] == pytest.approx(bias, abs=0.002)
    assert diag.to_json()["findings"][0]["channel"] == channel


@SLOW
@given(level=st.floats(0.43, 0.55), seed=st.integers(0, 10_000))
def test_a_saturating_valve_is_named_as_such(level, seed):
    """The hot valve opens no further than ``level`` (op 0.40, excitation 0.1 RMS): a
    saturation of hot at the level within 0.01, and no output effect in its place."""
    diag = run(sim_windows(rig.RigParams(**NOISE), seed, clip=level))
    assert diag.effects == [], diag.summary
    assert [(f.kind, f.target) for f in diag.findings] == [("saturation", "hot")], diag.summary
    found = diag.findings[0]
    assert found.parameters["level"] == pytest.approx(level, abs=0.01)
    u = np.concatenate([w.u[:, 0] for w in sim_windows(rig.RigParams(), seed, n_windows=2)])
    assert found.parameters["clipped_fraction"] == pytest.approx(np.mean(u > level), abs=0.05)
    assert diag.summary.startswith("Model B: saturation on hot")
    assert "opens no further than command" in found.recommendation


@pytest.mark.parametrize("seed", [0, 1])
def test_negative_control_adds_and_reports_nothing(seed):
    diag = run(sim_windows(rig.RigParams(**NOISE), seed))
    assert diag.effects == []
    assert diag.findings == []
    assert diag.adequate
    assert diag.to_json()["findings"] == []


# --------------------------------------------------------------------------- distortion test


def test_distortion_test_finds_a_clipped_valve_and_not_the_linear_level():
    """Odd-only multisine: the clipped hot valve distorts the level; the nominal rig's level
    (a linear mass balance) does not at alpha = 0.01 (its temperature, t = E/h, is
    genuinely nonlinear and is not asserted on)."""
    nom = Nominal.from_document(load_model_document("B")[0])
    for seed in (0, 1):
        clipped = distortion_test(
            sim_windows(rig.RigParams(**NOISE), seed, clip=0.5, kind="multisine"), nom, 1e-4, 2
        )
        assert clipped.possible
        assert clipped.p_value[0] < 0.01
        nominal = distortion_test(
            sim_windows(rig.RigParams(**NOISE), seed, kind="multisine"), nom, 1e-4, 2
        )
        assert nominal.p_value[0] > 0.01


def test_distortion_test_rejects_at_its_level_on_linear_data():
    """Linear periodic data with Gaussian noise: rejections at alpha = 0.1 over 300 seeds
    within the binomial 99.9 % band."""
    nom = Nominal.from_document(load_model_document("B")[0])
    n, p_len, alpha, runs = 4096, 2048, 0.1, 300
    exc = excitation.ExcitationConfig(kind="multisine", odd_only=True, f_max_hz=0.05, seed=4)
    u = np.tile(excitation.excitation_period(exc), (2, 1))
    theta = 2 * np.pi * np.arange(n // 2 + 1) / n
    y_lin = np.fft.irfft(
        np.einsum("kij,kj->ki", nom.response(theta, 0.1), np.fft.rfft(u, axis=0)), n, axis=0
    )
    rng = np.random.default_rng(0)
    rejected = 0
    for _ in range(runs):
        ws = [Window(u, y_lin + rng.normal(0.0, 0.01, (n, 2)), 0.1, p_len) for _ in range(2)]
        test = distortion_test(ws, nom, 1e-4, 2)
        assert test.possible
        rejected += int(test.p_value[0] < alpha)
    lo, hi = scipy.stats.binom.ppf([0.0005, 0.9995], runs, alpha)
    assert lo <= rejected <= hi, rejected


def test_windows_of_one_period_cannot_be_tested():
    nom = Nominal.from_document(load_model_document("B")[0])
    ws = sim_windows(rig.RigParams(**NOISE), 0, n_windows=2)
    test = distortion_test([Window(w.u, w.y, w.ts_s, w.u.shape[0]) for w in ws], nom, 1e-4, 2)
    assert not test.possible
    assert "one period" in test.note
