"""Tests of the mode-shift effect: a resonance of a structure that moved.

References are independent of the effect's code:

* the test structure's model file against its matrices built from the masses and springs
  (:func:`tools.mode_structure.structure`), its modes against the eigenvalues of that
  physical model;
* the shift itself against the structure with the *modal* stiffness of one mode raised,
  ``K' = K + d M phi phi^T M`` (phi mass-normalised, damping matrix unchanged): the mode's
  frequency moves, its shape and every other mode stay, so its frequency response is the
  effect's exactly (the choice "mode shape kept");
* the discrete pole map against the matrix exponential of that physical model;
* the diagnosis against data simulated with ``simulate_model``
  (:func:`tools.mode_structure.windows`) from the structure with a *physical* spring stiffened
  (the support spring of the third mass, 100 -> 130 N/m): the true new frequency and
  damping are the eigenvalues of that physical model (the stiffening also moves the mode
  shape by about 1 %, which the effect does not carry: the test shows the effect's
  intervals still hold the truth); and the same structure with an output gain injected by
  hand (the measured deviation scaled), where the mode shift must not be named.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import yaml

from tools.mode_structure import MASSES, MODEL, PERIOD, TS_S, structure, windows
from twotank_validation.core.model import load_model_document
from twotank_validation.diagnose import Nominal, catalogue, diagnose
from twotank_validation.diagnose.effects import (
    mode_coefficients,
    mode_of_pole,
    modes,
    s_from_z,
    shift_mode,
    z_from_s,
)
from twotank_validation.diagnose.kinds import EffectKind
from twotank_validation.report import diagnosis_text


def response(a: np.ndarray, b: np.ndarray, c: np.ndarray, f_hz: np.ndarray) -> np.ndarray:
    """(k, ny, nu) the continuous frequency response at ``f_hz``."""
    eye = np.eye(a.shape[0])
    return np.array([c @ np.linalg.solve(2j * np.pi * f * eye - a, b) for f in f_hz])


def pair_eigs(a: np.ndarray) -> np.ndarray:
    lam = np.linalg.eigvals(a)
    return np.sort_complex(lam[lam.imag > 0])


def nominal() -> Nominal:
    doc, _ = load_model_document(str(MODEL))
    return Nominal.from_document(doc)


def test_the_model_file_is_the_structure_of_masses_and_springs() -> None:
    nom = nominal()
    np.testing.assert_allclose(nom.a, structure(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(nom.b[:, 0], [0, 0, 0, 0, 0, 1.0 / MASSES[2]])
    lam = pair_eigs(structure())
    lam = lam[np.argsort(np.abs(lam))]
    got = modes(nom.a)
    assert [m.index for m in got] == [1, 2, 3]
    for m, x in zip(got, lam, strict=True):
        assert m.f_hz == pytest.approx(abs(x) / (2 * np.pi), rel=1e-12)
        assert m.zeta == pytest.approx(-x.real / abs(x), rel=1e-9)
    assert [round(m.f_hz, 3) for m in got] == [1.655, 6.946, 11.736]


@pytest.mark.parametrize("index", [0, 1, 2])
def test_the_shift_is_the_modal_stiffness_raised_with_the_mode_shape_kept(index: int) -> None:
    """The effect equals the physical structure with one mode's modal stiffness raised."""
    nom = nominal()
    m_mat = np.diag(MASSES)
    k_mat = -nom.a[3:, :3] * MASSES[:, None]
    w2, phi = scipy.linalg.eigh(k_mat, m_mat)  # mass-normalised: phi^T M phi = I
    # Rayleigh damping is modal: mode r's coordinate has damping 0.5 + 0.001 w_r^2 (1/s)
    d = 0.15 * w2[index]  # the modal stiffness raised by 15 %
    p = m_mat @ phi[:, index]
    changed = structure(k_extra=d * np.outer(p, p))
    w_new = np.sqrt(w2[index] + d)
    zeta_new = (0.5 + 0.001 * w2[index]) / (2 * w_new)
    mode = modes(nom.a)[index]
    a0, a1 = mode_coefficients(w_new / (2 * np.pi), zeta_new)
    shifted = shift_mode(nom.a, nom.b, mode.pole, a0, a1)
    f = np.geomspace(0.3, 30.0, 41)
    np.testing.assert_allclose(
        response(shifted, nom.b, nom.c, f), response(changed, nom.b, nom.c, f), rtol=1e-9
    )
    # the other modes stay, the shifted one is where it was asked to go
    before, after = modes(nom.a), modes(shifted)
    for i, (m0, m1) in enumerate(zip(before, after, strict=True)):
        if i == index:
            assert m1.f_hz == pytest.approx(w_new / (2 * np.pi), rel=1e-10)
            assert m1.zeta == pytest.approx(zeta_new, rel=1e-9)
        else:
            assert m1.pole == pytest.approx(m0.pole, rel=1e-10)
    # the mode's static gain falls as 1 / w^2 (its numerator kept), not as 1 / w (residue kept)
    static = -nom.c @ np.linalg.solve(shifted, nom.b) + nom.c @ np.linalg.solve(nom.a, nom.b)
    want = -nom.c @ np.linalg.solve(changed, nom.b) + nom.c @ np.linalg.solve(nom.a, nom.b)
    np.testing.assert_allclose(static, want, rtol=1e-8, atol=1e-12)


def test_a_discrete_nominal_maps_its_poles_through_exp_s_t() -> None:
    nom = nominal()
    ts = 0.01
    a_d = scipy.linalg.expm(nom.a * ts)
    b_d = np.linalg.solve(nom.a, (a_d - np.eye(6)) @ nom.b)  # zero-order hold
    for m_c, m_d in zip(modes(nom.a), modes(a_d, ts), strict=True):
        assert m_d.f_hz == pytest.approx(m_c.f_hz, rel=1e-10)
        assert m_d.zeta == pytest.approx(m_c.zeta, rel=1e-8)
        assert m_d.pole == pytest.approx(np.exp(m_c.pole * ts), rel=1e-12)
        assert s_from_z(z_from_s(m_c.pole, ts), ts) == pytest.approx(m_c.pole, rel=1e-12)
        assert mode_of_pole(m_c.pole) == pytest.approx((m_c.f_hz, m_c.zeta))
    target = modes(a_d, ts)[1]
    f_new, zeta_new = 1.06 * target.f_hz, 0.03
    shifted = shift_mode(a_d, b_d, target.pole, *mode_coefficients(f_new, zeta_new, ts))
    w = 2 * np.pi * f_new
    s_new = complex(-zeta_new * w, w * np.sqrt(1 - zeta_new**2))
    want = np.sort_complex(
        np.array([np.exp(s_new * ts), *(m.pole for m in modes(a_d, ts) if m.index != 2)])
    )
    np.testing.assert_allclose(pair_eigs(shifted), want, rtol=1e-10)


def test_a_repeated_frequency_is_named_not_fitted() -> None:
    """Two equal oscillators: the bounds of either would be empty (no fit, no traceback)."""
    osc = np.array([[0.0, 1.0], [-400.0, -1.0]])
    a = scipy.linalg.block_diag(osc, osc, np.array([[-50.0]]))
    doc = {
        "name": "twins", "inputs": ["f"], "outputs": ["y1", "y2"],
        "nominal": {"ss": {"A": a.tolist(), "B": [[0], [1], [0], [1], [1]],
                           "C": [[1, 0, 0, 0, 0], [0, 0, 1, 0, 1]], "D": [[0], [0]]}},
    }  # fmt: skip
    specs, skipped = catalogue(
        Nominal.from_document(doc), ("y1", "y2"), period_s=10.0, operating_point={}
    )
    assert not [s for s in specs if s.kind is EffectKind.MODE]
    why = [w for k, w in skipped if k == "mode"]
    assert len(why) == 2
    assert all("repeated frequency" in w for w in why)


def test_every_lightly_damped_mode_in_band_is_a_candidate() -> None:
    nom = nominal()
    outputs = ("x1", "x2", "x3")
    specs, skipped = catalogue(nom, outputs, period_s=PERIOD * TS_S, operating_point={})
    found = [s for s in specs if s.kind is EffectKind.MODE]
    assert [s.label(outputs) for s in found] == [
        "mode 1 at 1.655 Hz",
        "mode 2 at 6.946 Hz",
        "mode 3 at 11.74 Hz",
    ]
    for s in found:
        assert s.names == ("frequency_hz", "damping_ratio")
        f0 = s.fixed["nominal_frequency_hz"]
        assert s.lower[0] < f0 < s.upper[0]
        assert min(s.grid) < f0 < max(s.grid)
    # the neighbours bound the search: two modes never trade places
    assert found[0].upper[0] <= found[1].lower[0] <= found[1].upper[0] <= found[2].lower[0]
    assert not [k for k, _ in skipped if k == "mode"]
    specs, skipped = catalogue(
        nom, outputs, period_s=PERIOD * TS_S, operating_point={}, band_hz=(1.0, 8.0)
    )
    assert len([s for s in specs if s.kind is EffectKind.MODE]) == 2
    why = [w for k, w in skipped if k == "mode"]
    assert len(why) == 1
    assert "mode 3 at 11.74 Hz" in why[0]
    assert "outside the excited band" in why[0]


@pytest.mark.parametrize("seed", [3, 11])
def test_a_stiffened_support_spring_is_named_a_mode_shift_within_its_interval(
    seed: int, tmp_path: Path
) -> None:
    truth = modes(structure(130.0))[0]  # the physical structure's first mode, stiffened
    assert truth.f_hz / modes(structure())[0].f_hz - 1 == pytest.approx(0.062, abs=0.001)
    doc, source = load_model_document(str(MODEL))
    d = diagnose(windows(130.0, seed), doc, source=source)
    assert [(e.spec.kind, e.spec.fixed["mode"]) for e in d.effects] == [(EffectKind.MODE, 1.0)]
    assert not d.unexplained
    e = d.effects[0]
    assert e.uncertainty is not None
    low, high = e.uncertainty.low, e.uncertainty.high
    assert low[0] <= truth.f_hz <= high[0]
    assert low[1] <= truth.zeta <= high[1]
    assert high[0] - low[0] < 0.01 * truth.f_hz  # an interval that says something
    text = diagnosis_text(d)
    line = next(t.strip() for t in text.splitlines() if "moved to" in t)
    # the digits that tell the interval's ends apart, the values as fitted
    want = (
        f"mode 1 at 1.655 Hz moved to {e.values[0]:.6g} Hz ({low[0]:.6g}-{high[0]:.6g}) "
        f"(+6.2%), damping 0.0292 -> {e.values[1]:.5g} ({low[1]:.5g}-{high[1]:.5g})"
    )
    assert line == want
    # the changed model file holds the moved mode and the others as they were
    path = tmp_path / "changed.yaml"
    assert d.document is not None
    path.write_text(yaml.safe_dump(d.document))
    changed, _ = load_model_document(str(path))
    got = modes(Nominal.from_document(changed).a)
    assert got[0].f_hz == pytest.approx(e.values[0], rel=1e-9)
    assert got[0].zeta == pytest.approx(e.values[1], rel=1e-7)
    for m0, m1 in zip(modes(nominal().a)[1:], got[1:], strict=True):
        assert m1.pole == pytest.approx(m0.pole, rel=1e-9)


def test_an_output_gain_is_not_taken_for_a_mode_shift() -> None:
    doc, source = load_model_document(str(MODEL))
    d = diagnose(windows(100.0, 5, gain_x2=0.1), doc, source=source)
    assert [(e.spec.kind, d.outputs[e.spec.channel]) for e in d.effects] == [
        (EffectKind.GAIN, "x2")
    ]
    assert d.effects[0].values[0] == pytest.approx(0.1, abs=0.003)
    modes_tried = [e for e in d.candidates if e.spec.kind is EffectKind.MODE]
    assert len(modes_tried) == 3
    assert all(e.reduction < 0.5 for e in modes_tried)


def test_a_discrete_nominal_names_the_same_mode_shift() -> None:
    """The model file's nominal sampled (ZOH at the data's 0.01 s, ``dt_s``): the same answer.

    The simulator holds the force over each sample, so the sampled nominal is exact; the
    poles move as ``z = exp(s T)`` of the fitted frequency and damping.
    """
    doc, _ = load_model_document(str(MODEL))
    nom = Nominal.from_document(doc)
    a_d = scipy.linalg.expm(nom.a * TS_S)
    b_d = np.linalg.solve(nom.a, (a_d - np.eye(6)) @ nom.b)
    disc = {**doc, "nominal": {"ss": {**doc["nominal"]["ss"], "A": a_d.tolist(),
                                      "B": b_d.tolist(), "dt_s": TS_S}}}  # fmt: skip
    truth = modes(structure(130.0))[0]
    d = diagnose(windows(130.0, 12), disc, source="sampled")
    assert [(e.spec.kind, e.spec.fixed["mode"]) for e in d.effects] == [(EffectKind.MODE, 1.0)]
    e = d.effects[0]
    assert e.uncertainty is not None
    assert e.uncertainty.low[0] <= truth.f_hz <= e.uncertainty.high[0]
    assert e.uncertainty.low[1] <= truth.zeta <= e.uncertainty.high[1]
    assert d.document is not None
    changed = Nominal.from_document(d.document)
    assert changed.dt_s == TS_S
    got = modes(changed.a, TS_S)[0]
    assert (got.f_hz, got.zeta) == pytest.approx(tuple(e.values), rel=1e-7)
