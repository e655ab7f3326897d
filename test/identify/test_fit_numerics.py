"""The rational fit's numerical pieces against independent references.

The refinement's analytic variable-projection Jacobian against central finite differences of
the residual at random points; the linear solve by normal equations against ``lstsq``; the
vector-fitting step from the normal equations' Cholesky factor against the one from a QR.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from twotank_validation.identify import fit as fit_mod

# a 1 x 2 plant: a real pole and a lightly damped pair (rad/s), two outputs
LINES = 80
FREQS = np.linspace(0.2, 6.0, LINES)


def _problem(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(s scaled, h (L, 2), w (L, 2), omega): noisy entries with a delay on output 1."""
    rng = np.random.default_rng(seed)
    s_hz = 2j * np.pi * FREQS
    g = np.stack(
        [2.0 / (1 + s_hz / 3.0), 5.0 / (s_hz**2 + 0.8 * s_hz + 40.0) * np.exp(-0.05 * s_hz)], 1
    )
    sigma = 0.02 * np.abs(g) + 1e-3
    h = g + sigma / math.sqrt(2) * (
        rng.standard_normal(g.shape) + 1j * rng.standard_normal(g.shape)
    )
    scale = 2 * math.pi * FREQS.max()
    return s_hz / scale, h, 1.0 / sigma, 2 * math.pi * FREQS


def _residual(s, h, w, omega, is_pair, n_tau):
    def res(x: np.ndarray) -> np.ndarray:
        taus = x[x.size - n_tau :] if n_tau else np.zeros(0)
        p = fit_mod._unpack(x[: x.size - n_tau], is_pair)
        return fit_mod._ri(
            fit_mod._linear(s, fit_mod._undelayed(h, omega, taus, 1), w, p)[1]
        ).ravel()

    return res


def _central(f, x: np.ndarray) -> np.ndarray:
    """Central differences, a step of 1e-6 of each parameter's size."""
    cols = []
    for k in range(x.size):
        step = 1e-6 * max(abs(x[k]), 1e-3)
        up, down = x.copy(), x.copy()
        up[k] += step
        down[k] -= step
        cols.append((f(up) - f(down)) / (2 * step))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("qr", [False, True], ids=["normal-equations", "qr"])
@pytest.mark.parametrize("n_tau", [0, 2], ids=["no-delay", "delays"])
def test_the_analytic_jacobian_matches_finite_differences_at_random_points(monkeypatch, qr, n_tau):
    if qr:  # every solve takes the ill-conditioned branch
        monkeypatch.setattr(fit_mod, "_GRAM_COND", 0.0)
    s, h, w, omega = _problem(1)
    rng = np.random.default_rng(7 + n_tau)
    for _ in range(3):
        poles = np.array(
            [-rng.uniform(0.02, 0.3), -rng.uniform(0.005, 0.05) + 1j * rng.uniform(0.05, 0.5)]
        )
        is_pair = poles.imag > 0
        taus = rng.uniform(0.0, 0.1, n_tau)
        x = np.concatenate([fit_mod._pack(poles), taus])
        h_und = fit_mod._undelayed(h, omega, taus, 1)
        phi = np.concatenate([fit_mod._basis(s, poles), np.ones((s.size, 1))], axis=1)
        jac = fit_mod._jacobian(
            s, h_und, w, poles, fit_mod._project(phi, h_und, w), omega=omega, n_tau=n_tau, n_u=1
        )
        ref = _central(_residual(s, h, w, omega, is_pair, n_tau), x)
        assert jac.shape == ref.shape == (2 * LINES * 2, x.size)
        for k in range(x.size):  # every column to 1e-6 of its own size
            np.testing.assert_allclose(jac[:, k], ref[:, k], atol=1e-6 * np.abs(ref[:, k]).max())


def test_the_linear_solve_matches_lstsq_per_entry():
    s, h, w, _ = _problem(2)
    poles = np.array([-0.1, -0.02 + 0.3j])
    coef, resid, phi = fit_mod._linear(s, h, w, poles)
    for e in range(h.shape[1]):
        a = w[:, e, None] * phi
        ref = np.linalg.lstsq(
            np.concatenate([a.real, a.imag]),
            np.concatenate([(w[:, e] * h[:, e]).real, (w[:, e] * h[:, e]).imag]),
            rcond=None,
        )[0]
        np.testing.assert_allclose(coef[:, e], ref, rtol=1e-9)
        np.testing.assert_allclose(resid[:, e], w[:, e] * (phi @ ref - h[:, e]), atol=1e-9)


def test_the_vector_fitting_step_from_cholesky_matches_the_one_from_a_qr(monkeypatch):
    s, h, w, _ = _problem(3)
    start = fit_mod._start_sets(3, float(np.min(np.abs(s))))[0]
    got = fit_mod._vf_step(s, h, w, start)
    monkeypatch.setattr(fit_mod, "_GRAM_COND", 0.0)  # the QR of the tall matrix
    ref = fit_mod._vf_step(s, h, w, start)
    np.testing.assert_allclose(got, ref, rtol=1e-8)
