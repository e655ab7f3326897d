"""Tests of core.model: shipped YAML models, P(e^{j theta}) assembly, schema errors.

References: zero-order holds computed by the matrix exponential of the augmented matrix
(scipy.linalg.expm, not cont2discrete) or in closed form for first-order weights, plants
evaluated by a linear solve per frequency, the generalised plant written out entry by entry
from the interconnection equations, and the paper's legible numbers (Smith 1995, Sec. 3).
"""

from __future__ import annotations

import copy
import textwrap
from importlib import resources

import numpy as np
import pytest
import scipy.linalg
import yaml

from twotank_validation.core.model import (
    BlockStructure,
    LFTModel,
    PlantResponse,
    load_model,
    model_from_dict,
)
from twotank_validation.errors import (
    DimensionError,
    ModelError,
    ModelFileError,
    UnstableModelError,
)
from twotank_validation.sim import rig, tank_models

THETA = np.array([0.0, 0.003, 0.05, 0.4, 1.3, np.pi])


# --------------------------------------------------------------------------- references


def _zoh(a, b, dt):
    """ZOH by the exponential of [[A, B], [0, 0]] dt."""
    a, b = np.atleast_2d(a), np.atleast_2d(b)
    n, m = b.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = a
    big[:n, n:] = b
    e = scipy.linalg.expm(big * dt)
    return e[:n, :n], e[:n, n:]


def _ss_response(a, b, c, d, dt, theta):
    """ZOH-discretised C (zI - Ad)^-1 Bd + D at z = exp(j theta), (n_bins, p, m)."""
    ad, bd = _zoh(a, b, dt)
    eye = np.eye(ad.shape[0])
    return np.array(
        [np.atleast_2d(c) @ np.linalg.solve(zz * eye - ad, bd) + d for zz in np.exp(1j * theta)]
    )


def _lag(gain, tau, dt, theta):
    """ZOH of gain / (1 + tau s): gain (1 - e) / (z - e), e = exp(-dt/tau)."""
    e = np.exp(-dt / tau)
    return gain * (1 - e) / (np.exp(1j * theta) - e)


def _lead_lag(n1, n0, d1, d0, dt, theta):
    """ZOH of (n1 s + n0) / (d1 s + d0) = n1/d1 + (n0 - n1 d0/d1) / (d1 s + d0)."""
    direct = n1 / d1
    return direct + _lag((n0 - direct * d0) / d0, d1 / d0, dt, theta)


def _shipped_document(which: str) -> dict:
    name = {"A": "model_a.yaml", "B": "model_b.yaml"}[which]
    text = resources.files("twotank_validation").joinpath("models", name).read_text()
    return yaml.safe_load(text)


# --------------------------------------------------------------------------- shipped models


@pytest.mark.parametrize("which", ["A", "B"])
def test_shipped_yaml_equals_derivation(which):
    loaded = load_model(which)
    derived = tank_models.derived_model(which)
    assert loaded.name == derived.name == which
    assert loaded.input_names == derived.input_names == ("hot", "cold")
    assert loaded.output_names == derived.output_names == ("height", "temperature")
    assert dict(loaded.operating_point) == pytest.approx(dict(derived.operating_point))
    for attr in "abcd":
        got = getattr(loaded.nominal, attr)
        ref = getattr(derived.nominal, attr)
        assert got.shape == ref.shape
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12 * np.max(np.abs(ref)))
    assert loaded.nominal.dt_s is None
    assert loaded.blocks == derived.blocks == BlockStructure(((1, 1), (1, 1)))
    assert loaded.block_names == derived.block_names
    assert loaded.noise_names == derived.noise_names == ("height_noise", "temperature_noise")
    pairs = [
        *zip(loaded.perturbations, derived.perturbations, strict=True),
        *zip(loaded.noise, derived.noise, strict=True),
    ]
    assert len(pairs) == 4
    for got, ref in pairs:
        assert got.outputs == ref.outputs
        assert got.name == ref.name
        for attr in "abcd":
            np.testing.assert_array_equal(getattr(got.weight, attr), getattr(ref.weight, attr))
    assert [p.kind for p in loaded.perturbations] == ["output_multiplicative"] * 2


def test_shipped_weights_are_the_papers():
    # Section 3.4 readings, written out independently of tank_models' constants.
    for which in ("A", "B"):
        doc = _shipped_document(which)
        weights = {p["name"]: p["weight"] for p in doc["perturbations"]}
        assert weights["height_multiplicative"] == {"tf": {"num": [0.05], "den": [0.25, 1.0]}}
        assert weights["temperature_multiplicative"] == {
            "tf": {"num": [16.5, 0.1], "den": [20.0, 1.0]}
        }
        noise = {n["name"]: n["weight"] for n in doc["noise"]}
        assert noise == {"height_noise": {"gain": 0.01}, "temperature_noise": {"gain": 0.03}}


def _first_order_channels(model: LFTModel):
    """Slow poles (time constants, s) and the DC gain of the nominal."""
    g = model.nominal
    poles = np.sort(np.linalg.eigvals(g.a).real)
    dc = -g.c @ np.linalg.solve(g.a, g.b) + g.d
    return poles, dc


def test_model_a_paper_numbers():
    poles, dc = _first_order_channels(load_model("A"))
    # Valve lags 1/(1 + 0.05 s): two poles at -20.
    np.testing.assert_allclose(poles[:2], [-20.0, -20.0], rtol=1e-9)
    taus = sorted(-1.0 / poles[2:])
    # Paper: temperature 1.25/(1 + 53.8 s) f_h, level 1.34/(1 + 122.5 s)(f_h + f_c).
    assert round(taus[0], 1) == 53.8
    assert round(taus[1], 1) == 122.5
    assert round(dc[0, 0], 2) == 1.34
    assert round(dc[0, 1], 2) == 1.34
    assert round(dc[1, 0], 2) == 1.25
    assert abs(dc[1, 1]) < 1e-12
    # Hand derivation from the rig constants: f1 = (h1 + beta)/alpha = 1.07/1.34; level
    # tau = A1 alpha, gain alpha; temperature tau = A1 h1 / f1, gain t_h / f1 = 1.2523.
    f1 = (0.47 + 0.6) / 1.34
    assert dc[1, 0] == pytest.approx(1.0 / f1, rel=1e-9)
    assert 1.0 / f1 == pytest.approx(1.2523, abs=5e-5)
    assert taus[0] == pytest.approx(91.4 * 0.47 / f1, rel=1e-9)
    assert taus[1] == pytest.approx(91.4 * 1.34, rel=1e-9)
    assert dc[0, 0] == pytest.approx(1.34, rel=1e-9)


def test_model_b_level_channel_and_output_map():
    a_model, b_model = load_model("A"), load_model("B")
    _, dc_a = _first_order_channels(a_model)
    poles_b, dc_b = _first_order_channels(b_model)
    # The mass balance is the same in both models.
    np.testing.assert_allclose(dc_b[0], dc_a[0], rtol=1e-9)
    assert -1.0 / poles_b[-1] == pytest.approx(91.4 * 1.34, rel=1e-9)
    # Temperature t1 = E1 / h1 linearised at h1 = 0.47, t1 = 0.5: dt = dE/h1 - t1/h1 dh.
    np.testing.assert_allclose(
        b_model.nominal.c, [[0, 0, 1, 0], [0, 0, -0.5 / 0.47, 1 / 0.47]], rtol=1e-9
    )
    # At DC the coupled model still gives the energy-balance gains: t = f_h t_h / f1 ...
    f1 = (0.47 + 0.6) / 1.34
    op = rig.operating_point(rig.RigParams())
    assert dc_b[1, 0] == pytest.approx((1.0 - op.temperature) / f1, rel=1e-9)
    assert dc_b[1, 1] == pytest.approx((0.0 - op.temperature) / f1, rel=1e-9)


@pytest.mark.parametrize("dt", [1.0, 0.25])
def test_model_b_response_vs_independent_construction(dt):
    doc = _shipped_document("B")
    ss = doc["nominal"]["ss"]
    a, b, c, d = (np.array(ss[k], dtype=float) for k in "ABCD")
    g = _ss_response(a, b, c, d, dt, THETA)  # (nb, 2, 2)
    w_h = _lag(0.05, 0.25, dt, THETA)
    w_t = _lead_lag(16.5, 0.1, 20.0, 1.0, dt, THETA)
    nb = THETA.size
    ref = np.zeros((nb, 4, 6), dtype=complex)
    ref[:, 0, 4:] = g[:, 0, :]  # z_h = G_h u
    ref[:, 1, 4:] = g[:, 1, :]  # z_t = G_t u
    ref[:, 2, 0] = w_h  # y_h += W_h v_h
    ref[:, 3, 1] = w_t  # y_t += W_t v_t
    ref[:, 2, 2] = 0.01  # y_h += 0.01 w_h
    ref[:, 3, 3] = 0.03  # y_t += 0.03 w_t
    ref[:, 2:, 4:] = g

    resp = load_model("B").response(THETA, dt)
    assert isinstance(resp, PlantResponse)
    assert resp.p.shape == (nb, 4, 6)
    np.testing.assert_allclose(resp.p, ref, rtol=1e-9, atol=1e-12)
    # Partition accessors.
    assert resp.p11.shape == (nb, 2, 2)
    assert resp.p12.shape == (nb, 2, 2)
    assert np.all(resp.p11 == 0)
    assert np.all(resp.p12 == 0)
    np.testing.assert_allclose(resp.p13, g, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(
        resp.p21, np.stack([np.diag([x, y]) for x, y in zip(w_h, w_t, strict=True)])
    )
    np.testing.assert_allclose(resp.p22, np.broadcast_to(np.diag([0.01, 0.03]), (nb, 2, 2)))
    np.testing.assert_allclose(resp.p23, g, rtol=1e-9, atol=1e-12)
    # Weights at DC are the weights' static gains: 0.05 and 0.1.
    assert abs(resp.p21[0, 0, 0]) == pytest.approx(0.05, rel=1e-12)
    assert abs(resp.p21[0, 1, 1]) == pytest.approx(0.1, rel=1e-12)


def test_nominal_discrete_is_zoh():
    m = load_model("A")
    ad, bd = _zoh(m.nominal.a, m.nominal.b, 2.0)
    g = m.nominal_discrete(2.0)
    assert g.dt_s == 2.0
    np.testing.assert_allclose(g.a, ad, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(g.b, bd, rtol=1e-10, atol=1e-14)


# --------------------------------------------------------------------------- structured kinds


NOMINAL_3X2 = {
    "ss": {
        "A": [[-0.5, 0.2], [0.0, -2.0]],
        "B": [[1.0, 0.0, 0.5], [0.3, 1.0, -1.0]],
        "C": [[1.0, 0.0], [0.4, 1.0]],
        "D": [[0.0, 0.1, 0.0], [0.0, 0.0, 0.2]],
    }
}


def _nominal_3x2(dt, theta):
    ss = NOMINAL_3X2["ss"]
    return _ss_response(*(np.array(ss[k]) for k in "ABCD"), dt, theta)


def _doc(**extra):
    doc = {"name": "t", "inputs": ["u1", "u2", "u3"], "outputs": ["y1", "y2"]}
    doc["nominal"] = copy.deepcopy(NOMINAL_3X2)
    doc.update(extra)
    return doc


def test_input_multiplicative_single_input():
    dt = 0.5
    doc = _doc(
        perturbations=[
            {
                "kind": "input_multiplicative",
                "inputs": ["u2"],
                "weight": {"tf": {"num": [0.4], "den": [3.0, 1.0]}},
            }
        ]
    )
    m = model_from_dict(doc)
    assert m.blocks.shapes == ((1, 1),)
    assert m.nw == 0
    resp = m.response(THETA, dt)
    g = _nominal_3x2(dt, THETA)
    w = _lag(0.4, 3.0, dt, THETA)
    # y = G (u + E^T W v): P21 = G[:, u2] W; z = u2: P13 = [0, 1, 0].
    np.testing.assert_allclose(resp.p21[:, :, 0], g[:, :, 1] * w[:, None], rtol=1e-9)
    np.testing.assert_array_equal(resp.p13, np.broadcast_to([[0, 1, 0]], (THETA.size, 1, 3)))
    np.testing.assert_allclose(resp.p23, g, rtol=1e-9)
    assert np.all(resp.p11 == 0)


def test_input_multiplicative_full_matrix_weight():
    dt = 1.0
    wa, wb = [[-1.0, 0.5], [0.0, -0.3]], [[1.0, 0.0], [0.2, 1.0]]
    wc, wd = [[0.5, 0.0], [0.0, 0.7]], [[0.1, 0.05], [0.0, 0.2]]
    doc = _doc(
        perturbations=[
            {
                "kind": "input_multiplicative",
                "inputs": ["u3", "u1"],
                "weight": {"ss": {"A": wa, "B": wb, "C": wc, "D": wd}},
            }
        ]
    )
    resp = model_from_dict(doc).response(THETA, dt)
    g = _nominal_3x2(dt, THETA)
    w = _ss_response(np.array(wa), np.array(wb), np.array(wc), np.array(wd), dt, THETA)
    # E_S^T maps [v1; v2] to inputs [u3, u1]: P21 = G[:, [u3, u1]] W.
    ref21 = np.einsum("kij,kjl->kil", g[:, :, [2, 0]], w)
    np.testing.assert_allclose(resp.p21, ref21, rtol=1e-9, atol=1e-12)
    ref13 = np.array([[0, 0, 1], [1, 0, 0]])
    np.testing.assert_array_equal(resp.p13, np.broadcast_to(ref13, (THETA.size, 2, 3)))


def test_additive_non_square_block():
    dt = 0.5
    doc = _doc(
        perturbations=[
            {
                "name": "add",
                "kind": "additive",
                "inputs": ["u3", "u1"],
                "outputs": ["y2"],
                "weight": {"tf": {"num": [0.2], "den": [1.0, 1.0]}},
            }
        ]
    )
    m = model_from_dict(doc)
    # Delta maps z (2 inputs) to v (1 output): shape (len(outputs), len(inputs)).
    assert m.blocks.shapes == ((1, 2),)
    assert (m.blocks.nv, m.blocks.nz) == (1, 2)
    assert m.block_names == ("add",)
    resp = m.response(THETA, dt)
    assert resp.p.shape == (THETA.size, 2 + 2, 1 + 0 + 3)
    w = _lag(0.2, 1.0, dt, THETA)
    np.testing.assert_allclose(resp.p21[:, :, 0], np.stack([0 * w, w], axis=1), rtol=1e-12)
    np.testing.assert_array_equal(
        resp.p13, np.broadcast_to([[0, 0, 1], [1, 0, 0]], (THETA.size, 2, 3))
    )
    assert np.all(resp.p11 == 0)


def test_combined_structured_model_entry_by_entry():
    dt = 0.5
    w_in = {
        "ss": {"A": [[-2.0]], "B": [[1.0, 1.0]], "C": [[0.5], [0.0]], "D": [[0.1, 0], [0, 0.3]]}
    }
    doc = _doc(
        perturbations=[
            {
                "kind": "output_multiplicative",
                "outputs": ["y2"],
                "weight": {"tf": {"num": [0.5], "den": [2.0, 1.0]}},
            },
            {"kind": "additive", "inputs": ["u3", "u1"], "outputs": ["y1"], "weight": 0.3},
            {"kind": "input_multiplicative", "inputs": ["u2", "u1"], "weight": w_in},
        ],
        noise=[
            {
                "name": "n",
                "outputs": ["y2", "y1"],
                "weight": [0.1, {"tf": {"num": [1.0], "den": [10.0, 1.0]}}],
            },
            {"name": "m", "outputs": ["y1"], "weight": {"gain": 0.05}},
        ],
    )
    m = model_from_dict(doc)
    assert m.blocks.shapes == ((1, 1), (1, 2), (2, 2))
    assert m.noise_names == ("n[0]", "n[1]", "m")
    assert m.block_names == (
        "output_multiplicative:y2",
        "additive:y1",
        "input_multiplicative:u2,u1",
    )
    nb = THETA.size
    g = _nominal_3x2(dt, THETA)
    w0 = _lag(0.5, 2.0, dt, THETA)
    w2 = _ss_response(
        *(np.array(w_in["ss"][k], dtype=float) for k in "ABCD"), dt, THETA
    )  # (nb, 2, 2)
    wn1 = _lag(1.0, 10.0, dt, THETA)
    # Rows: z0 | z1 z2 | z3 z4 | y1 y2.  Cols: v0 | v1 | v2 v3 | w0 w1 w2 | u1 u2 u3.
    ref = np.zeros((nb, 7, 10), dtype=complex)
    u = slice(7, 10)
    ref[:, 0, u] = g[:, 1, :]  # z0 = G_y2 u
    ref[:, 1, 9] = 1.0  # z1 = u3
    ref[:, 2, 7] = 1.0  # z2 = u1
    ref[:, 3, 8] = 1.0  # z3 = u2
    ref[:, 4, 7] = 1.0  # z4 = u1
    ref[:, 5:, u] = g  # y = G u + ...
    ref[:, 6, 0] = w0  # y2 += W0 v0
    ref[:, 5, 1] = 0.3  # y1 += 0.3 v1
    ref[:, 5:, 2:4] = np.einsum("kij,kjl->kil", g[:, :, [1, 0]], w2)  # y += G E^T W2 [v2; v3]
    ref[:, 6, 4] = 0.1  # y2 += 0.1 w0
    ref[:, 5, 5] = wn1  # y1 += Wn1 w1
    ref[:, 5, 6] = 0.05  # y1 += 0.05 w2
    np.testing.assert_allclose(m.response(THETA, dt).p, ref, rtol=1e-9, atol=1e-12)


def test_discrete_parts_used_as_given_and_sample_period_checked():
    dt = 0.2
    doc = _doc(
        noise=[
            {
                "outputs": ["y1"],
                "weight": {
                    "ss": {"A": [[0.5]], "B": [[1.0]], "C": [[0.25]], "D": [[0.0]], "dt_s": dt}
                },
            }
        ]
    )
    m = model_from_dict(doc)
    resp = m.response(THETA, dt)
    np.testing.assert_allclose(resp.p22[:, 0, 0], 0.25 / (np.exp(1j * THETA) - 0.5), rtol=1e-12)
    assert np.all(resp.p22[:, 1, 0] == 0)
    with pytest.raises(ModelError, match=r"sample period 0\.2 s but the datum has 0\.1 s"):
        m.response(THETA, 0.1)


# --------------------------------------------------------------------------- generalized plant


def _gp_doc(ss, blocks=([1, 1], [2, 1]), noise_inputs=1):
    return {
        "name": "gp",
        "inputs": ["a", "b"],
        "outputs": ["p", "q"],
        "generalized_plant": {
            "ss": ss,
            "blocks": [list(b) for b in blocks],
            "noise_inputs": noise_inputs,
        },
    }


def test_generalized_static_plant_round_trip():
    # nz = 1 + 1 = 2, nv = 1 + 2 = 3, nw = 1, nu = 2, ny = 2: P is (4, 6).
    d = np.arange(24, dtype=float).reshape(4, 6) / 10.0
    ss = {"A": [], "B": [], "C": [], "D": d.tolist()}
    m = model_from_dict(_gp_doc(ss))
    assert m.blocks.shapes == ((1, 1), (2, 1))
    assert (m.blocks.nv, m.blocks.nz, m.nw, m.nu, m.ny) == (3, 2, 1, 2, 2)
    assert m.noise_names == ("w0",)
    assert m.block_names == ("block0", "block1")
    assert m.blocks.v_slices == (slice(0, 1), slice(1, 3))
    assert m.blocks.z_slices == (slice(0, 1), slice(1, 2))
    resp = m.response(THETA, 1.0)
    np.testing.assert_array_equal(resp.p, np.broadcast_to(d, (THETA.size, 4, 6)))
    for part, (r, c) in {
        "p11": (slice(0, 2), slice(0, 3)),
        "p12": (slice(0, 2), slice(3, 4)),
        "p13": (slice(0, 2), slice(4, 6)),
        "p21": (slice(2, 4), slice(0, 3)),
        "p22": (slice(2, 4), slice(3, 4)),
        "p23": (slice(2, 4), slice(4, 6)),
    }.items():
        np.testing.assert_array_equal(getattr(resp, part)[0], d[r, c], err_msg=part)
    np.testing.assert_array_equal(m.nominal_discrete(1.0).d, d[2:, 4:])


def test_generalized_dynamic_plant():
    rng = np.random.default_rng(8)
    a = np.array([[-0.3, 1.0], [-1.0, -0.3]])
    b, c, d = rng.normal(size=(2, 6)), rng.normal(size=(4, 2)), rng.normal(size=(4, 6))
    ss = {"A": a.tolist(), "B": b.tolist(), "C": c.tolist(), "D": d.tolist()}
    m = model_from_dict(_gp_doc(ss))
    dt = 0.7
    ref = _ss_response(a, b, c, d, dt, THETA)
    resp = m.response(THETA, dt)
    np.testing.assert_allclose(resp.p, ref, rtol=1e-9, atol=1e-12)
    nom = m.nominal_discrete(dt)
    np.testing.assert_allclose(
        _ss_response(a, b[:, 4:], c[2:], d[2:, 4:], dt, THETA), resp.p23, rtol=1e-9, atol=1e-12
    )
    assert nom.shape == (2, 2)


def test_generalized_plant_shape_mismatch():
    ss = {"A": [], "B": [], "C": [], "D": np.zeros((4, 5)).tolist()}
    with pytest.raises(DimensionError, match=r"generalized plant is \(4, 5\) .* need \(4, 6\)"):
        model_from_dict(_gp_doc(ss))


def test_generalized_plant_unstable():
    ss = {"A": [[0.1]], "B": [[1.0] * 6], "C": [[1.0]] * 4, "D": np.zeros((4, 6)).tolist()}
    with pytest.raises(UnstableModelError, match="generalized plant of model 'gp'"):
        model_from_dict(_gp_doc(ss))


def test_generalized_excludes_nominal():
    doc = _gp_doc({"A": [], "B": [], "C": [], "D": np.zeros((4, 6)).tolist()})
    doc["nominal"] = {"gain": 1.0}
    with pytest.raises(ModelFileError, match="generalized_plant excludes"):
        model_from_dict(doc)


@pytest.mark.parametrize(
    "gp", [{"ss": None, "blocks": [[1, 1]]}, {"ss": None, "blocks": [[1, 1, 1]], "noise_inputs": 0}]
)
def test_generalized_plant_missing_fields(gp):
    doc = _gp_doc(None)
    doc["generalized_plant"] = gp
    with pytest.raises(ModelFileError, match="needs blocks"):
        model_from_dict(doc)


def test_generalized_plant_negative_noise_inputs():
    ss = {"A": [], "B": [], "C": [], "D": np.zeros((4, 5)).tolist()}
    with pytest.raises(ModelFileError, match="noise_inputs"):
        model_from_dict(_gp_doc(ss, noise_inputs=-1))


def test_block_structure_rejects_empty_block():
    with pytest.raises(ModelError, match="positive"):
        BlockStructure(((1, 0),))


# --------------------------------------------------------------------------- YAML files


GOOD_YAML = """\
name: small
inputs: [hot, cold]
outputs: [height, temperature]
operating_point: {height: 0.47, temperature: 0.5}
nominal:
  ss:
    A: [[-0.1, 0.0], [0.0, -0.2]]
    B: [[1.0, 0.0], [0.0, 1.0]]
    C: [[1.0, 0.0], [0.0, 1.0]]
    D: [[0.0, 0.0], [0.0, 0.0]]
perturbations:
  - name: pert
    kind: output_multiplicative
    outputs: [height]
    weight: {tf: {num: [0.05], den: [0.25, 1.0]}}
noise:
  - name: noise
    outputs: [height, temperature]
    weight: [0.01, {gain: 0.03}]
"""


def _write(tmp_path, text):
    path = tmp_path / "model.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def test_good_yaml_file_loads(tmp_path):
    m = load_model(_write(tmp_path, GOOD_YAML))
    assert m.name == "small"
    assert m.operating_point == {"height": 0.47, "temperature": 0.5}
    assert m.noise_names == ("noise[0]", "noise[1]")
    np.testing.assert_array_equal(m.noise[0].weight.d, np.diag([0.01, 0.03]))
    resp = m.response(np.array([0.0]), 1.0)
    # DC: G = diag(10, 5); weights at DC 0.05, 0.01, 0.03.
    np.testing.assert_allclose(resp.p23[0], np.diag([10.0, 5.0]), rtol=1e-9)
    np.testing.assert_allclose(resp.p21[0, :, 0], [0.05, 0.0], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(resp.p22[0], np.diag([0.01, 0.03]))


BAD_FILES = {
    "syntax": (
        GOOD_YAML.replace("inputs: [hot, cold]", "inputs: [hot, cold"),
        ModelFileError,
        "not valid YAML",
    ),
    "unknown_top_level": (
        GOOD_YAML + "nominall: {gain: 1}\n",
        ModelFileError,
        r"top level: unknown keys \['nominall'\]",
    ),
    "unknown_channel": (
        GOOD_YAML.replace("outputs: [height]", "outputs: [heigth]"),
        ModelFileError,
        r"perturbations\[0\]\.outputs: unknown channel 'heigth'",
    ),
    "missing_weight": (
        GOOD_YAML.replace("    weight: {tf: {num: [0.05], den: [0.25, 1.0]}}\n", ""),
        ModelFileError,
        r"perturbations\[0\]: missing weight",
    ),
    "improper_tf": (
        GOOD_YAML.replace("num: [0.05], den: [0.25, 1.0]", "num: [1.0, 0.05], den: [2.0]"),
        ModelFileError,
        r"perturbations\[0\]\.weight\.tf: .*improper",
    ),
    "unknown_kind": (
        GOOD_YAML.replace("kind: output_multiplicative", "kind: multiplicative"),
        ModelFileError,
        r"perturbations\[0\]: kind must be one of .* found 'multiplicative'",
    ),
    "wrong_weight_size": (
        GOOD_YAML.replace(
            "weight: {tf: {num: [0.05], den: [0.25, 1.0]}}", "weight: {gain: [[1, 0], [0, 1]]}"
        ),
        ModelFileError,
        r"perturbations\[0\]\.weight: weight is \(2, 2\), expected scalar or \(1, 1\)",
    ),
    "wrong_list_length": (
        GOOD_YAML.replace("weight: [0.01, {gain: 0.03}]", "weight: [0.01, 0.02, 0.03]"),
        ModelFileError,
        r"noise\[0\]\.weight: a list of weights needs 2 entries, found 3",
    ),
    "duplicate_names": (
        GOOD_YAML.replace("inputs: [hot, cold]", "inputs: [hot, hot]"),
        ModelFileError,
        r"inputs: duplicate names in \['hot', 'hot'\]",
    ),
    "channel_twice": (
        GOOD_YAML.replace(
            "outputs: [height, temperature]\n    weight", "outputs: [height, height]\n    weight"
        ),
        ModelFileError,
        r"noise\[0\]\.outputs: channel listed twice",
    ),
    "unknown_lti_kind": (
        GOOD_YAML.replace("weight: {tf: {num: [0.05], den: [0.25, 1.0]}}", "weight: {zpk: [1]}"),
        ModelFileError,
        r"perturbations\[0\]\.weight: unknown LTI kind 'zpk'",
    ),
    "ss_missing_matrix": (
        GOOD_YAML.replace("    D: [[0.0, 0.0], [0.0, 0.0]]\n", ""),
        ModelFileError,
        r"nominal\.ss: missing \['D'\]",
    ),
    "ss_unknown_key": (
        GOOD_YAML.replace(
            "    D: [[0.0, 0.0], [0.0, 0.0]]\n", "    D: [[0.0, 0.0], [0.0, 0.0]]\n    E: 1\n"
        ),
        ModelFileError,
        r"nominal\.ss: unknown keys \['E'\]",
    ),
    "ss_not_numbers": (
        GOOD_YAML.replace("A: [[-0.1, 0.0], [0.0, -0.2]]", "A: [[-0.1, x], [0.0, -0.2]]"),
        ModelFileError,
        r"nominal\.ss\.A: expected a number or a list of lists",
    ),
    "delays_not_a_list": (
        GOOD_YAML.replace(
            "D: [[0.0, 0.0], [0.0, 0.0]]", "D: [[0.0, 0.0], [0.0, 0.0]]\n    output_delays_s: 3"
        ),
        ModelFileError,
        r"nominal\.ss\.output_delays_s: expected a list",
    ),
    "delays_wrong_count": (
        GOOD_YAML.replace(
            "D: [[0.0, 0.0], [0.0, 0.0]]", "D: [[0.0, 0.0], [0.0, 0.0]]\n    output_delays_s: [1.0]"
        ),
        ModelFileError,
        r"nominal\.ss: output_delays_s has 1 entries",
    ),
    "delays_negative": (
        GOOD_YAML.replace(
            "D: [[0.0, 0.0], [0.0, 0.0]]",
            "D: [[0.0, 0.0], [0.0, 0.0]]\n    output_delays_s: [1.0, -2.0]",
        ),
        ModelFileError,
        r">= 0 s",
    ),
    "states_wrong_count": (
        GOOD_YAML.replace(
            "D: [[0.0, 0.0], [0.0, 0.0]]", "D: [[0.0, 0.0], [0.0, 0.0]]\n    states: [x]"
        ),
        ModelFileError,
        r"nominal\.ss\.states: expected a list of names, one per state",
    ),
    "ss_inconsistent": (
        GOOD_YAML.replace("A: [[-0.1, 0.0], [0.0, -0.2]]", "A: [[-0.1]]"),
        ModelFileError,
        r"nominal\.ss: state-space shapes disagree",
    ),
    "wrong_channels_for_kind": (
        GOOD_YAML.replace("outputs: [height]\n", "outputs: [height]\n    inputs: [hot]\n"),
        ModelFileError,
        r"perturbations\[0\]: output_multiplicative needs outputs only",
    ),
    "missing_name": (
        GOOD_YAML.replace("name: small\n", ""),
        ModelFileError,
        "missing required key 'name'",
    ),
    "missing_nominal": (
        GOOD_YAML.split("nominal:", maxsplit=1)[0],
        ModelFileError,
        "missing 'nominal'",
    ),
    "top_level_list": ("- 1\n- 2\n", ModelFileError, "expected a mapping, found list"),
    "nominal_shape": (
        GOOD_YAML.replace("C: [[1.0, 0.0], [0.0, 1.0]]", "C: [[1.0, 0.0]]").replace(
            "D: [[0.0, 0.0], [0.0, 0.0]]", "D: [[0.0, 0.0]]"
        ),
        DimensionError,
        r"nominal plant is \(1, 2\) .* names 2 outputs and 2 inputs",
    ),
    "unstable_nominal": (
        GOOD_YAML.replace("A: [[-0.1, 0.0], [0.0, -0.2]]", "A: [[-0.1, 0.0], [0.0, 0.2]]"),
        UnstableModelError,
        r"nominal plant of model 'small' is not stable \(poles \[0\.2",
    ),
    "unstable_weight": (
        GOOD_YAML.replace("den: [0.25, 1.0]", "den: [-0.25, 1.0]"),
        UnstableModelError,
        "weight of perturbation 'pert' is not stable",
    ),
    "mixed_discrete_weight": (
        GOOD_YAML.replace(
            "weight: [0.01, {gain: 0.03}]",
            "weight: [0.01, {ss: {A: 0.5, B: 1, C: 1, D: 0, dt_s: 0.1}}]",
        ),
        ModelFileError,
        r"noise\[0\]\.weight: diagonal weight mixes sample periods",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_malformed_yaml_files(tmp_path, case):
    text, error, pattern = BAD_FILES[case]
    path = _write(tmp_path, text)
    with pytest.raises(error, match=pattern) as info:
        load_model(path)
    assert isinstance(info.value, ModelError)
    if error is ModelFileError:
        assert str(path) in str(info.value)


def test_missing_file(tmp_path):
    path = tmp_path / "nope.yaml"
    with pytest.raises(ModelFileError, match=r"nope\.yaml not found: .*\['A', 'B'\]"):
        load_model(path)


def test_builtin_name_is_not_a_path(tmp_path):
    with pytest.raises(ModelFileError, match="not found"):
        load_model("C")


# Schema violations that escape as builtin exceptions instead of ModelFileError.
ESCAPING = {
    "operating_point_not_a_number": (
        GOOD_YAML.replace("height: 0.47,", "height: high,"),
        "operating_point",
    ),
    "dt_s_not_a_number": (
        GOOD_YAML.replace(
            "    D: [[0.0, 0.0], [0.0, 0.0]]\n", "    D: [[0.0, 0.0], [0.0, 0.0]]\n    dt_s: fast\n"
        ),
        "dt_s",
    ),
    "perturbations_not_a_list": (
        GOOD_YAML.split("perturbations:", maxsplit=1)[0] + "perturbations: 5\n",
        "perturbations",
    ),
}


@pytest.mark.parametrize("case", sorted(ESCAPING))
def test_schema_violations_raise_model_file_error(tmp_path, case):
    text, key = ESCAPING[case]
    with pytest.raises(ModelFileError, match=key):
        load_model(_write(tmp_path, text))


def test_constant_tf_weight_is_accepted(tmp_path):
    text = GOOD_YAML.replace(
        "weight: [0.01, {gain: 0.03}]", "weight: {tf: {num: [0.01], den: [1.0]}}"
    )
    m = load_model(_write(tmp_path, text))
    np.testing.assert_allclose(m.response(np.array([0.0, 1.0]), 1.0).p22[:, 0, 0], 0.01)


def test_output_delays_in_a_model_file_delay_the_response(tmp_path):
    """A delayed output: exactly the undelayed response times exp(-j theta tau / ts)."""
    delayed = GOOD_YAML.replace(
        "D: [[0.0, 0.0], [0.0, 0.0]]",
        "D: [[0.0, 0.0], [0.0, 0.0]]\n    output_delays_s: [0.0, 2.5]\n    states: [h, t]",
    )
    m = load_model(_write(tmp_path, delayed))
    ref = load_model(_write(tmp_path, GOOD_YAML))
    theta = np.linspace(0.0, np.pi, 9)
    got, want = m.response(theta, 0.5).p23, ref.response(theta, 0.5).p23
    np.testing.assert_allclose(got[:, 0], want[:, 0])
    np.testing.assert_allclose(got[:, 1], want[:, 1] * np.exp(-1j * theta * 5.0)[:, None])
