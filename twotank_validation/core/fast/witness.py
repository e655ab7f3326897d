"""Witness and consistency check of the batched fast path.

:func:`_witness` turns candidate unknowns into an exactly feasible rank-one ``Delta`` and its
least-norm ``w`` (the upper bound); :func:`_lagrangian_agrees` checks the certified dual value
against the Lagrangian evaluated in original units.
"""

from __future__ import annotations

import numpy as np

from twotank_validation.core.fast.dual import _DualResult
from twotank_validation.core.fast.forms import _Forms, _Window
from twotank_validation.core.fast.linalg import _inverse, _least_norm, _matmul, _matvec, _sq
from twotank_validation.core.fast.rules import TINY
from twotank_validation.core.model import BlockStructure


def _witness(
    pt: np.ndarray,
    ut: np.ndarray,
    yt: np.ndarray,
    x: np.ndarray,
    blocks: BlockStructure,
    *,
    nw: int,
    inv: np.ndarray | None,
    good: np.ndarray,
    coupled: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exactly feasible witness from candidate unknowns, as :func:`solvers.witness_from_delta`.

    ``Delta_i = v_i z_i^H / ||z_i||^2`` clipped to norm 1 (rank one), then the least-norm
    ``w`` of the closed loop ``(P22 + P21 Delta S P12) w = Y - P23 U - P21 Delta S P13 U``,
    ``S = (I - P11 Delta)^-1``.

    Args:
        pt: (nz + ny, nv + nw + nu, g) complex.
        ut: (nu, g) complex.
        yt: (ny, g) complex.
        x: (nv + nw, g) complex candidate ``[v; w]``.
        blocks: block structure.
        nw: noise dimension.
        inv: (nw, nw, g) complex, ``P22^-1`` where ``good`` (or None), used when ``z`` does
            not depend on the unknowns (then the closed loop is ``P22 w = ...``).
        good: (g,) bool.
        coupled: ``P11`` or ``P12`` is non-zero somewhere in the batch.

    Returns:
        ``(upper, w, v, z, dmat)``: (g,) float (``inf`` where the closed loop cannot explain
        the bin), (nw, g), (nv, g), (nz, g) complex, (nv, nz, g) complex block-diagonal Delta.
    """
    nz, nv = blocks.nz, blocks.nv
    nx = nv + nw
    g = x.shape[-1]
    p11, p12, p13 = pt[:nz, :nv], pt[:nz, nv:nx], pt[:nz, nx:]
    p21, p22, p23 = pt[nz:, :nv], pt[nz:, nv:nx], pt[nz:, nx:]
    zu = _matvec(p13, ut)
    r = yt - _matvec(p23, ut)
    v_c = x[:nv]
    z_c = _matvec(p11, v_c) + _matvec(p12, x[nv:]) + zu if coupled else zu
    dmat = np.zeros((nv, nz, g), dtype=complex)
    for vs, zs in zip(blocks.v_slices, blocks.z_slices, strict=True):
        vi, zi = v_c[vs], z_c[zs]
        zn2 = _sq(zi).sum(axis=0)
        safe = zn2 > TINY
        zn2 = np.where(safe, zn2, 1.0)
        ratio = np.sqrt(_sq(vi).sum(axis=0) / zn2)
        shrink = np.where(ratio > 1.0, 1.0 / np.maximum(ratio, TINY), 1.0)
        dmat[vs, zs] = vi[:, None] * zi.conj()[None, :] * np.where(safe, shrink / zn2, 0.0)
    if coupled:
        eye = np.eye(nz)[:, :, None]
        s = _inverse(eye - _matmul(p11, dmat))
        t = _matmul(_matmul(p21, dmat), s)  # P21 Delta S
        lhs = p22 + _matmul(t, p12)
        rhs = r - _matvec(t, zu)
    else:
        lhs = p22
        rhs = r - _matvec(p21, _matvec(dmat, zu))
    if not coupled and inv is not None and np.all(good):
        w, resid = _matvec(inv, rhs), np.zeros(g)  # P22 invertible: any rhs is reached
    else:
        w, resid = _least_norm(lhs, rhs)
    z = _matvec(s, _matvec(p12, w) + zu) if coupled else zu
    v = _matvec(dmat, z)
    scale = np.sqrt(_sq(rhs).sum(axis=0)) + np.sqrt(_sq(yt).sum(axis=0)) + TINY
    upper = np.where(resid <= 1e-7 * scale, np.sqrt(_sq(w).sum(axis=0)), np.inf)
    return upper, w, v, z, dmat


def _lagrangian_agrees(
    pt: np.ndarray,
    win: _Window,
    blocks: BlockStructure,
    *,
    x: np.ndarray,
    res: _DualResult,
    forms: _Forms,
    coupled: bool,
) -> np.ndarray:
    """Whether the certified value agrees with the Lagrangian evaluated in original units.

    The dual value comes from a Schur complement of the scaled forms; here the Lagrangian
    ``||w||^2 - sum_i mu_i (||z_i||^2 - ||v_i||^2)``, ``mu_i = d_i / dscale_i``, is evaluated
    at the minimiser ``x = [v; w]`` itself. Both are the dual function (clipped at 0, like the
    bound); they differ by more than round-off (1e-9 of the terms, 1e-12 of the forms' unit)
    only where the forms lost digits to cancellation (an ill-conditioned bin), which is then
    left to the fallback rather than trusted.

    Args:
        pt: (nz + ny, nv + nw + nu, g) complex.
        win: the same bins' :class:`forms._Window`.
        blocks: block structure.
        x: (nv + nw, g) complex, the Lagrangian minimiser ``rho m xh``.
        res: the dual ascent's result.
        forms: the homogenised bins.
        coupled: ``P11`` or ``P12`` is non-zero somewhere in the batch.

    Returns:
        (g,) bool.
    """
    nz, nv = blocks.nz, blocks.nv
    nx = x.shape[0]
    v, w = x[:nv], x[nv:]
    z = win.zu + _matvec(pt[:nz, :nx], x) if coupled else win.zu
    mu = np.where(res.d > 0.0, res.d / np.where(forms.dscale > 0.0, forms.dscale, 1.0), 0.0)
    w2 = _sq(w).sum(axis=0)
    lag = w2.copy()
    size = w2.copy()
    for i, (vs, zs) in enumerate(zip(blocks.v_slices, blocks.z_slices, strict=True)):
        z2, v2 = _sq(z[zs]).sum(axis=0), _sq(v[vs]).sum(axis=0)
        lag -= mu[i] * (z2 - v2)
        size += mu[i] * (z2 + v2)
    unit = forms.a_scale * forms.rho**2  # the forms' unit in original units
    schur = np.maximum(res.phi, 0.0) * unit
    agree: np.ndarray = np.abs(np.maximum(lag, 0.0) - schur) <= 1e-9 * size + 1e-12 * unit
    return agree
