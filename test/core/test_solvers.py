"""Problem 3 solvers against independent references: brute force and the closed form."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
from hypothesis import given, settings
from hypothesis import strategies as st

from twotank_validation.core import solvers
from twotank_validation.core.model import BlockStructure, PlantResponse


def random_problem(seed: int, shapes: tuple[tuple[int, int], ...], nw: int, ny: int, nu: int):
    """A random one-bin problem with a well-posed LFT (||P11|| = 0.5) and full-row-rank P22."""
    rng = np.random.default_rng(seed)
    blocks = BlockStructure(shapes)
    nz, nv = blocks.nz, blocks.nv

    def cplx(*shape):
        return rng.normal(size=shape) + 1j * rng.normal(size=shape)

    p = cplx(nz + ny, nv + nw + nu)
    p11 = p[:nz, :nv]
    p[:nz, :nv] = 0.5 * p11 / np.linalg.norm(p11, 2)
    p[nz:, nv : nv + nw] *= 0.2  # noise weights smaller than the rest, as in practice
    u = cplx(nu)
    y = cplx(ny)
    resp = PlantResponse(p[None], blocks, nw, nu, ny)
    return resp, u[None], y[None]


def lft_noise_norms(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, deltas: list[np.ndarray]
) -> np.ndarray:
    """Independent reference: min ||w|| for K fixed Deltas (each (K, r_i, c_i)) of one bin.

    Closes the loop explicitly, ``v = Delta (I - P11 Delta)^-1 (P12 w + P13 u)``, and solves
    the output equation for w by least squares (P22 has full row rank in these problems).
    """
    blocks = resp.blocks
    nv, nz = blocks.nv, blocks.nz
    k = deltas[0].shape[0]
    dmat = np.zeros((k, nv, nz), dtype=complex)
    for d, vs, zs in zip(deltas, blocks.v_slices, blocks.z_slices, strict=True):
        dmat[:, vs, zs] = d
    p = resp.p[0]
    p11, p12, p13 = p[:nz, :nv], p[:nz, nv : nv + resp.nw], p[:nz, nv + resp.nw :]
    p21, p22, p23 = p[nz:, :nv], p[nz:, nv : nv + resp.nw], p[nz:, nv + resp.nw :]
    closed = dmat @ np.linalg.inv(np.eye(nz)[None] - p11[None] @ dmat)
    lhs = p22[None] + p21[None] @ closed @ p12[None]
    rhs = (y[0] - p23 @ u[0])[None] - (p21[None] @ closed @ p13[None]) @ u[0]
    w = np.einsum("kij,kj->ki", np.linalg.pinv(lhs), rhs)
    return np.linalg.norm(w, axis=1)


def lft_noise_norm(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, deltas: list[np.ndarray]
) -> float:
    """One Delta (list of (r_i, c_i) blocks) of :func:`lft_noise_norms`."""
    return float(lft_noise_norms(resp, u, y, [d[None] for d in deltas])[0])


def brute_force_scalar_blocks(resp: PlantResponse, u: np.ndarray, y: np.ndarray) -> float:
    """Dense polar grid over each scalar Delta_i in the unit disc, then local refinement."""
    m = resp.blocks.n_blocks
    radii = np.linspace(0.0, 1.0, 11)
    angles = np.linspace(0.0, 2 * np.pi, 32, endpoint=False)
    disc = np.unique(np.round(np.outer(radii, np.exp(1j * angles)).ravel(), 12))
    grids = np.meshgrid(*([disc] * m), indexing="ij")
    points = np.stack([g.ravel() for g in grids], axis=1)
    values = lft_noise_norms(resp, u, y, [points[:, i, None, None] for i in range(m)])
    best = np.inf
    for idx in np.argsort(values)[:3]:
        start = points[idx]

        def obj(x: np.ndarray) -> float:
            c = x[:m] + 1j * x[m:]
            ds = c / np.maximum(1.0, np.abs(c))  # radial projection onto the unit disc
            return lft_noise_norm(resp, u, y, [np.array([[d]]) for d in ds]) ** 2  # smooth at 0

        x0 = np.concatenate([start.real, start.imag])
        bounds = [(-1.0, 1.0)] * (2 * m)
        res = scipy.optimize.minimize(
            obj, x0, method="L-BFGS-B", bounds=bounds, options={"ftol": 1e-15, "gtol": 1e-12}
        )
        # derivative-free polish: the radial projection makes the objective kinked on the circle
        res = scipy.optimize.minimize(
            obj,
            res.x,
            method="Nelder-Mead",
            options={"xatol": 1e-12, "fatol": 1e-16, "maxiter": 4000},
        )
        best = min(best, float(np.sqrt(res.fun)), float(values[idx]))
    return best


def check_witness(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, sol: solvers.BinSolutions
) -> None:
    """The witness is feasible: ||Delta_i|| <= 1 and it reproduces the datum with its w."""
    for d in sol.delta:
        assert np.linalg.norm(d[0], 2) <= 1.0 + 1e-9
    ref = lft_noise_norm(resp, u, y, [d[0] for d in sol.delta])
    assert ref == pytest.approx(sol.upper[0], rel=1e-8, abs=1e-12)
    assert np.linalg.norm(sol.w[0]) == pytest.approx(sol.upper[0], rel=1e-9, abs=1e-12)


@settings(max_examples=8)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_blocks=st.integers(1, 2),
    nw=st.integers(1, 2),
    nu=st.integers(1, 2),
)
def test_sdp_matches_brute_force_for_one_or_two_scalar_blocks(
    seed: int, n_blocks: int, nw: int, nu: int
) -> None:
    ny = min(nw, 2)
    resp, u, y = random_problem(seed, ((1, 1),) * n_blocks, nw, ny, nu)
    sol = solvers.solve_sdp(resp, u, y)
    brute = brute_force_scalar_blocks(resp, u, y)
    scale = lft_noise_norm(resp, u, y, [np.zeros((1, 1))] * n_blocks)  # Delta = 0
    # Soundness: the lower bound never exceeds a feasible value.
    assert sol.lower[0] <= brute + 1e-7 * scale
    # Tightness for <= 2 blocks (complex S-lemma / rank-one SDP solution): bounds meet.
    assert sol.upper[0] - sol.lower[0] <= 1e-6 * max(scale, 1e-12)
    # Brute force cannot beat the exact minimum, and with refinement reaches it.
    assert brute >= sol.upper[0] - 1e-6 * scale
    assert brute <= sol.upper[0] + 1e-3 * scale
    check_witness(resp, u, y, sol)


@given(seed=st.integers(0, 2**32 - 1))
def test_sdp_lower_bound_is_sound_for_general_blocks(seed: int) -> None:
    """Three blocks, one of them 2x1 (non-square): the lower bound stays below feasible points."""
    shapes = ((1, 1), (2, 1), (1, 1))
    resp, u, y = random_problem(seed, shapes, 2, 2, 2)
    sol = solvers.solve_sdp(resp, u, y)
    assert sol.lower[0] <= sol.upper[0] + 1e-9
    rng = np.random.default_rng(seed)
    for _ in range(200):  # random feasible Deltas are upper bounds on the minimum
        ds = []
        for r, c in shapes:
            d = rng.normal(size=(r, c)) + 1j * rng.normal(size=(r, c))
            ds.append(d * rng.uniform(0, 1) / np.linalg.norm(d, 2))
        assert sol.lower[0] <= lft_noise_norm(resp, u, y, ds) + 1e-9
    check_witness(resp, u, y, sol)


def decoupled_problem(seed: int, n_bins: int = 16):
    """Two outputs, each with its own scalar multiplicative block and noise (tank-model shape)."""
    rng = np.random.default_rng(seed)
    blocks = BlockStructure(((1, 1), (1, 1)))
    ny, nu, nw = 2, 2, 2
    g = rng.normal(size=(n_bins, ny, nu)) + 1j * rng.normal(size=(n_bins, ny, nu))
    wd = rng.uniform(0.05, 1.0, size=(n_bins, 2)) * np.exp(1j * rng.uniform(0, 6, size=(n_bins, 2)))
    wn = rng.uniform(0.01, 0.1, size=(n_bins, 2))
    p = np.zeros((n_bins, 4, 6), dtype=complex)
    p[:, 0:2, 4:6] = g  # z = G u
    p[:, 2, 0], p[:, 3, 1] = wd[:, 0], wd[:, 1]
    p[:, 2, 2], p[:, 3, 3] = wn[:, 0], wn[:, 1]
    p[:, 2:4, 4:6] = g
    u = rng.normal(size=(n_bins, nu)) + 1j * rng.normal(size=(n_bins, nu))
    y = np.einsum("kij,kj->ki", g, u) * (1 + rng.normal(scale=0.5, size=(n_bins, ny)))
    y[::4] = 0.0  # bins the model explains exactly
    u[1::5] = 0.0  # bins with no excitation (z = 0)
    return PlantResponse(p, blocks, nw, nu, ny), u, y


@settings(max_examples=4)
@given(seed=st.integers(0, 2**32 - 1))
def test_closed_form_matches_sdp_and_brute_force(seed: int) -> None:
    # 10 bins keep an exactly explained bin (0, 4, 8) and an unexcited one (1, 6)
    resp, u, y = decoupled_problem(seed, n_bins=10)
    structure, _ = solvers.decoupled_structure(resp)
    assert structure is not None
    cf = solvers.solve_closed_form(resp, u, y, structure)
    sdp = solvers.solve_sdp(resp, u, y)
    scale = np.linalg.norm(y - np.einsum("kij,kj->ki", resp.p23, u), axis=1) / 0.01 + 1e-300
    np.testing.assert_array_less(
        np.abs(sdp.lower - cf.lower), 1e-6 * np.maximum(cf.lower, 1e-3 * scale) + 1e-15
    )
    np.testing.assert_array_less(
        np.abs(sdp.upper - cf.lower), 1e-6 * np.maximum(cf.lower, 1e-3 * scale) + 1e-15
    )
    for n in (0, 3):  # an exactly explained bin and a general one (the brute force is slow)
        one = PlantResponse(resp.p[n : n + 1], resp.blocks, 2, 2, 2)
        brute = brute_force_scalar_blocks(one, u[n : n + 1], y[n : n + 1])
        unperturbed = lft_noise_norm(one, u[n : n + 1], y[n : n + 1], [np.zeros((1, 1))] * 2)
        assert brute == pytest.approx(cf.lower[n], rel=1e-6, abs=1e-6 * unperturbed)


def test_closed_form_scalar_case_by_hand() -> None:
    """|w| = max(0, |e| - |a| c)/|g| on a single output, checked by hand."""
    blocks = BlockStructure(((1, 1),))
    p = np.zeros((1, 2, 3), dtype=complex)
    p[0, 0, 2] = 2.0  # z = 2 u
    p[0, 1, 0] = 0.5j  # y += 0.5j v
    p[0, 1, 1] = 0.1  # y += 0.1 w
    p[0, 1, 2] = 2.0  # y += 2 u (nominal)
    resp = PlantResponse(p, blocks, 1, 1, 1)
    u = np.array([[1.0 + 0j]])
    y = np.array([[2.0 + 3.0j]])  # e = 3j, |a| c = 0.5 * 2 = 1 -> |w| = (3 - 1)/0.1 = 20
    structure, _ = solvers.decoupled_structure(resp)
    assert structure is not None
    sol = solvers.solve_closed_form(resp, u, y, structure)
    assert sol.lower[0] == pytest.approx(20.0)
    assert abs(sol.delta[0][0, 0, 0]) == pytest.approx(1.0)


def test_output_without_noise_is_infeasible_when_unexplained() -> None:
    blocks = BlockStructure(((1, 1),))
    p = np.zeros((1, 2, 3), dtype=complex)
    p[0, 0, 2] = 1.0
    p[0, 1, 0] = 0.1
    p[0, 1, 2] = 1.0
    resp = PlantResponse(p, blocks, 1, 1, 1)  # noise weight zero
    u = np.array([[1.0 + 0j]])
    structure, _ = solvers.decoupled_structure(resp)
    assert structure is not None
    assert np.isinf(solvers.solve_closed_form(resp, u, np.array([[2.0 + 0j]]), structure).lower[0])
    assert solvers.solve_closed_form(resp, u, np.array([[1.05 + 0j]]), structure).lower[0] == 0.0
    assert np.isinf(solvers.solve_sdp(resp, u, np.array([[2.0 + 0j]])).lower[0])


def test_decoupled_structure_rejects_coupled_models() -> None:
    resp, _, _ = decoupled_problem(0)
    p = resp.p.copy()
    p[:, 2, 1] = 0.1  # block 2 also acts on output 1
    structure, reason = solvers.decoupled_structure(PlantResponse(p, resp.blocks, 2, 2, 2))
    assert structure is None
    assert "more than one output" in reason
