"""Per-bin data of a window and its homogenised quadratic forms, batched.

:func:`_classify` finds, per bin, the blocks forced to ``v_i = 0`` (:class:`_Window`);
:func:`_homogenise` eliminates the output equation -- through ``P22^-1`` where ``P22`` is
square and well conditioned, else orthonormally -- and builds each bin's forms ``A`` and
``Q_i`` (:class:`_Forms`), as :func:`solvers.homogenise_bin` does for one bin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twotank_validation.core.fast.linalg import (
    _chol_solve,
    _cholesky,
    _cols,
    _complement,
    _gram,
    _least_norm_size,
    _matmul,
    _matvec,
    _row_space,
    _sq,
)
from twotank_validation.core.fast.rules import NEGLIGIBLE_Z, NOISE_GAIN, TINY, UNEXCITED
from twotank_validation.core.model import BlockStructure

_CONSISTENCY_RTOL = 1e-8  # as solvers._CONSISTENCY_RTOL
TINY_WEIGHT = 1e-13
"""A block whose columns of ``P`` are below this times those of all the unknowns has a tiny
weight (forced where its effect is negligible too: :func:`_classify`)."""


@dataclass(frozen=True)
class _Window:
    """Per-bin data shared by every route (bin axis last).

    Attributes:
        zu: (nz, n) complex, ``P13 U``.
        r: (ny, n) complex, ``Y - P23 U``.
        active: (n_blocks, n) bool, False where the block is forced to ``v_i = 0``.
        drive: (n_blocks, n) float, ``||P13_i U||``.
        x_scale: (n,) float, the norm of the least-norm unknowns (0 where every block is
            unexcited, and it is not needed).
    """

    zu: np.ndarray
    r: np.ndarray
    active: np.ndarray
    drive: np.ndarray
    x_scale: np.ndarray


def _balancing(pt: np.ndarray, win: _Window, blocks: BlockStructure, nw: int) -> np.ndarray:
    """(nv + nw, n) float, the balancing of the unknowns for homogenised forms (0 if forced).

    Each block's ``v`` is scaled by ``min(1, z_size / ||x0||)``, ``z_size = ||P13_i U|| +
    ||[P11 P12]_i|| ||x0||`` (as :func:`solvers.homogenise_bin`).
    """
    nx = blocks.nv + nw
    col = np.ones((nx, pt.shape[-1]))
    x_scale = win.x_scale
    for i, (vs, zs) in enumerate(zip(blocks.v_slices, blocks.z_slices, strict=True)):
        dep = np.sqrt(_sq(pt[zs, :nx]).sum(axis=(0, 1)))
        z_size = win.drive[i] + dep * x_scale
        with np.errstate(invalid="ignore", divide="ignore"):  # x_scale 0: block forced
            bal = np.minimum(1.0, np.maximum(z_size / np.maximum(x_scale, TINY), 1e-150))
        col[vs] = np.where(win.active[i], bal, 0.0)
    return col


def _classify(
    pt: np.ndarray,
    ut: np.ndarray,
    yt: np.ndarray,
    blocks: BlockStructure,
    *,
    nw: int,
    u_scale: float,
    coupled: bool,
) -> _Window:
    """Forced blocks and balancing of every bin, by the rules of :func:`solvers.homogenise_bin`.

    A block whose input does not depend on ``v, w`` and is zero (unexcited: below 1e-12 of
    ``||P13|| u_scale``; or negligible: below 1e-10 of the bin's least-norm unknowns) is
    forced to ``v_i = 0``. (The balancing of the unknowns, needed by homogenised forms
    only, is :func:`_balancing`.)

    Args:
        pt: (nz + ny, nv + nw + nu, n) complex, P with the bin axis last.
        ut: (nu, n) complex.
        yt: (ny, n) complex.
        blocks: block structure.
        nw: noise dimension.
        u_scale: largest ||U(n)|| of the window.
        coupled: ``P11`` or ``P12`` is non-zero somewhere in the window.
    """
    nz, nv = blocks.nz, blocks.nv
    nx = nv + nw
    nb = pt.shape[-1]
    pu = _matvec(pt[:, nx:], ut)  # [P13 U; P23 U]
    zu = pu[:nz]
    r = yt - pu[nz:]
    starts = np.array([zs.start for zs in blocks.z_slices])
    drive = np.sqrt(np.add.reduceat(_sq(zu), starts, axis=0))  # ||z_i||, (m, n)
    p13 = np.sqrt(np.add.reduceat(_sq(pt[:nz, nx:]).sum(axis=1), starts, axis=0))
    unexcited = drive <= UNEXCITED * u_scale * p13
    # the scale of the unknowns matters only where some block may stay active
    x_scale = np.zeros(nb)
    need = np.flatnonzero(~np.all(unexcited, axis=0)) if not coupled else np.arange(nb)
    if need.size:
        x_scale[need] = _least_norm_size(_cols(pt[nz:, :nx], need), _cols(r, need))
    active = np.ones((blocks.n_blocks, nb), dtype=bool)
    negligible = drive <= NEGLIGIBLE_Z * x_scale
    if coupled:
        p_norm = np.sqrt(_sq(pt).sum(axis=(0, 1))) + TINY
        for i, zs in enumerate(blocks.z_slices):
            dep = np.sqrt(_sq(pt[zs, :nx]).sum(axis=(0, 1)))
            active[i] = ~((dep <= 1e-13 * p_norm) & (unexcited[i] | negligible[i]))
    else:  # z = P13 U everywhere: no dependence on v, w
        active = ~(unexcited | negligible)
    # A block whose v_i enters nothing (its columns of P are exactly zero: a zero weight, as
    # calibrate's probe at factor 0 makes) is forced too: v_i = 0 is then optimal. So is,
    # where z = P13 U, a block with a tiny weight: its columns below TINY_WEIGHT times those
    # of all the unknowns, and its largest effect on the outputs, ||P21_i||_F ||z_i||
    # (||v_i|| <= ||z_i||), below NEGLIGIBLE_Z times ||Y - P23 U||: v_i = 0 then changes what
    # w must explain by less than that fraction. Left active, such a block's dual optimum is
    # d_i = 0 with a (near) singular Hessian (the hard case), and the bin fell back to the
    # per-bin SDP.
    r_norm = np.sqrt(_sq(r).sum(axis=0))
    unknowns = np.sqrt(_sq(pt[:, :nx]).sum(axis=(0, 1)))
    for i, vs in enumerate(blocks.v_slices):
        active[i] &= np.any(pt[:, vs] != 0.0, axis=(0, 1))
        if not coupled:
            col = np.sqrt(_sq(pt[:, vs]).sum(axis=(0, 1)))
            effect = np.sqrt(_sq(pt[nz:, vs]).sum(axis=(0, 1))) * drive[i]
            active[i] &= ~((col <= TINY_WEIGHT * unknowns) & (effect <= NEGLIGIBLE_Z * r_norm))
    return _Window(zu=zu, r=r, active=active, drive=drive, x_scale=x_scale)


@dataclass(frozen=True)
class _Forms:
    """Bins with at least one constrained block, homogenised, in one padded batch.

    As :func:`solvers.homogenise_bin`: ``x = [v; w] = rho * m @ xh``, ``xh = [t; 1]``;
    ``||w||^2 = rho^2 a_scale xh^H a xh``; block constraints ``xh^H q_i xh >= 0`` with
    ``q_i = pz_i - pv_i`` (``pz_i``: the ``||z_i||^2`` form, ``pv_i``: the ``||v_i||^2``
    form, over the same norm). A forced block has ``q_i = 0``. Bins whose reduced dimension
    is below the batch's carry padded coordinates (zero columns of ``m``, identity in ``a``),
    so their padded ``t`` entries are 0 at every multiplier.

    Attributes:
        m: (nv + nw, K, g) complex.
        a: (K, K, g) complex Hermitian.
        q, pz, pv: (n_blocks, K, K, g) complex Hermitian.
        active: (n_blocks, g) bool.
        rho: (g,) float, variable scaling.
        a_scale: (g,) float, objective scaling.
        dscale: (n_blocks, g) float, ``||Q_i|| / ||A||`` before normalisation (0 if forced):
            multipliers ``c * dscale`` weigh every block alike in the objective's units.
        feasible: (g,) bool, the output equation has a solution.
        z_fixed: ``z = P13 U`` at every bin (``P11 = P12 = 0``): each ``pz_i`` is zero but
            for its homogenising entry.
    """

    m: np.ndarray
    a: np.ndarray
    q: np.ndarray
    pz: np.ndarray
    pv: np.ndarray
    active: np.ndarray
    rho: np.ndarray
    a_scale: np.ndarray
    dscale: np.ndarray
    feasible: np.ndarray
    z_fixed: bool = False


def _take_window(win: _Window, idx: np.ndarray) -> _Window:
    return _Window(*(_cols(getattr(win, f), idx) for f in _Window.__dataclass_fields__))


def _homogenise(
    pt: np.ndarray,
    yt: np.ndarray,
    win: _Window,
    blocks: BlockStructure,
    *,
    nw: int,
    inv: np.ndarray | None,
    good: np.ndarray,
    coupled: bool,
) -> _Forms:
    """Eliminate the output equation and build the quadratic forms of a batch of bins.

    Two eliminations, each bin taking the first that applies:

    * noise elimination -- ``P22`` square (up to 3x3) and well conditioned at the bin, and
      ``||P22^-1 P21 D||_F <= NOISE_GAIN`` (``D``: the balancing of ``v``):
      ``w = P22^-1 (Y - P23 U - P21 v)``, the unknowns are ``v`` (balanced);
    * orthonormal elimination -- any bin: see :func:`_forms_orthonormal`.

    Args:
        pt: (nz + ny, nv + nw + nu, g) complex.
        yt: (ny, g) complex.
        win: the same bins' :class:`_Window`.
        blocks: block structure.
        nw: noise dimension.
        inv: (nw, nw, g) complex, ``P22^-1`` where ``good`` (None: not square, or too large).
        good: (g,) bool, bins where ``inv`` is trustworthy (see :func:`linalg._inverse_small`).
        coupled: ``P11`` or ``P12`` is non-zero somewhere in the batch.
    """
    g = yt.shape[1]
    if inv is None or not np.any(good):
        return _forms_orthonormal(pt, yt, win, blocks, nw, coupled=coupled)
    nz, nv = blocks.nz, blocks.nv
    col = _balancing(pt, win, blocks, nw)
    f = _matmul(inv, pt[nz:, :nv]) * col[None, :nv]  # (nw, nv, g): P22^-1 P21 D
    good = good & (_sq(f).sum(axis=(0, 1)) <= NOISE_GAIN**2)
    if np.all(good):
        return _forms_noise(pt, win, blocks, inv, f, col_v=col[:nv], coupled=coupled)
    if not np.any(good):
        return _forms_orthonormal(pt, yt, win, blocks, nw, coupled=coupled)
    ig, ib = np.flatnonzero(good), np.flatnonzero(~good)
    fg = _forms_noise(
        _cols(pt, ig),
        _take_window(win, ig),
        blocks,
        _cols(inv, ig),
        _cols(f, ig),
        col_v=_cols(col[:nv], ig),
        coupled=coupled,
    )
    fb = _forms_orthonormal(
        _cols(pt, ib), _cols(yt, ib), _take_window(win, ib), blocks, nw, coupled=coupled
    )
    return _concat_forms([(ig, fg), (ib, fb)], g)


def _forms_noise(
    pt: np.ndarray,
    win: _Window,
    blocks: BlockStructure,
    inv: np.ndarray,
    f: np.ndarray,
    *,
    col_v: np.ndarray,
    coupled: bool,
) -> _Forms:
    """Homogenised forms with ``w`` eliminated through ``P22^-1`` (``t`` = balanced ``v``).

    ``x = [v; w] = [D t; w0 - F t]`` with ``D = diag(col)``, ``w0 = P22^-1 (Y - P23 U)``,
    ``F = P22^-1 P21 D``; the homogenising point is the least-norm solution in balanced
    coordinates (``min ||t||^2 + ||w||^2``, as :func:`solvers.homogenise_bin`), not ``t = 0``:
    the Schur complement then cancels no more digits than the orthonormal elimination's.
    Forced blocks (``col = 0``) become padded coordinates.

    Args:
        pt: (nz + ny, nv + nw + nu, g) complex.
        win: the same bins' :class:`_Window`.
        blocks: block structure.
        inv: (nw, nw, g) complex, ``P22^-1``.
        f: (nw, nv, g) complex, ``F``.
        col_v: (nv, g) float, ``diag D`` (0 on forced blocks).
        coupled: ``P11`` or ``P12`` is non-zero somewhere in the batch.
    """
    nv = blocks.nv
    nw = inv.shape[0]
    g = pt.shape[-1]
    w0 = _matvec(inv, win.r)
    gram = _gram(f, f)
    for j in range(nv):
        gram[j, j] += 1.0
    low, diag, _ = _cholesky(gram)  # I + F^H F: positive definite
    t0 = _chol_solve(low, diag, (f.conj() * w0[:, None]).sum(axis=0))
    x0v = col_v * t0
    x0w = w0 - _matvec(f, t0)
    rho = np.sqrt(_sq(x0v).sum(axis=0) + _sq(x0w).sum(axis=0))
    rho = np.maximum(np.maximum(rho, np.sqrt(_sq(win.zu).sum(axis=0))), TINY)
    m = np.zeros((nv + nw, nv + 1, g), dtype=complex)
    for j in range(nv):
        m[j, j] = col_v[j]
    m[nv:, :nv] = -f
    m[:nv, nv] = x0v / rho
    m[nv:, nv] = x0w / rho
    return _assemble_forms(
        pt,
        win,
        blocks,
        m,
        rho=rho,
        pad=col_v == 0.0,
        feasible=np.ones(g, dtype=bool),
        coupled=coupled,
    )


def _forms_orthonormal(
    pt: np.ndarray, yt: np.ndarray, win: _Window, blocks: BlockStructure, nw: int, *, coupled: bool
) -> _Forms:
    """Homogenised forms by orthonormal elimination (any bin, as solvers.homogenise_bin).

    The balanced output equation ``[P21 P22] diag(col) x_b = Y - P23 U`` is orthonormalised
    (pivoted Gram-Schmidt); its null space, together with the selector rows ``v_i = 0`` of
    forced blocks (their balancing column is 0, so these rows are orthogonal to the
    equation), gives ``x = col * (N t + x0)``, scaled by ``rho = max(||x0||, ||P13 U||)``.

    Args:
        pt: (nz + ny, nv + nw + nu, g) complex.
        yt: (ny, g) complex.
        win: the same bins' :class:`_Window`.
        blocks: block structure.
        nw: noise dimension.
        coupled: ``P11`` or ``P12`` is non-zero somewhere in the batch.
    """
    nz, nv = blocks.nz, blocks.nv
    nx = nv + nw
    nb = pt.shape[-1]
    col, active, zu, r = _balancing(pt, win, blocks, nw), win.active, win.zu, win.r
    rs = _row_space(pt[nz:, :nx] * col[None], r)
    feasible = rs.resid <= _CONSISTENCY_RTOL * (
        np.sqrt(_sq(r).sum(axis=0)) + np.sqrt(_sq(yt).sum(axis=0)) + TINY
    )
    sel = np.zeros((nv, nx, nb), dtype=complex)  # v_i = 0 rows of the forced blocks
    for i, vs in enumerate(blocks.v_slices):
        for j in range(vs.start, vs.stop):
            sel[j, j] = ~active[i]
    rank = rs.rank + (~active * np.array([r_ for r_, _ in blocks.shapes])[:, None]).sum(axis=0)
    k = nx - int(np.min(rank)) if nb else 0
    null, pad = _complement(np.concatenate([rs.q, sel]), k)
    x0 = rs.x0 * col
    rho = np.maximum(np.maximum(np.sqrt(_sq(x0).sum(axis=0)), np.sqrt(_sq(zu).sum(axis=0))), TINY)
    m = np.empty((nx, k + 1, nb), dtype=complex)
    m[:, :k] = null * col[:, None]
    m[:, k] = x0 / rho
    return _assemble_forms(pt, win, blocks, m, rho=rho, pad=pad, feasible=feasible, coupled=coupled)


def _assemble_forms(
    pt: np.ndarray,
    win: _Window,
    blocks: BlockStructure,
    m: np.ndarray,
    *,
    rho: np.ndarray,
    pad: np.ndarray,
    feasible: np.ndarray,
    coupled: bool,
) -> _Forms:
    """``A = M_w^H M_w`` and ``Q_i = G_i^H G_i - M_vi^H M_vi`` (``G = [P11 P12] M + P13 U``).

    Args:
        pt: (nz + ny, nv + nw + nu, g) complex.
        win: the same bins' :class:`_Window`.
        blocks: block structure.
        m: (nv + nw, K, g) complex, ``x = rho m xh``.
        rho: (g,) float.
        pad: (K - 1, g) bool, padded coordinates (zero columns of ``m``).
        feasible: (g,) bool.
        coupled: ``P11`` or ``P12`` is non-zero somewhere in the batch (else ``G_i`` has
            only its homogenising column).
    """
    nz, nv = blocks.nz, blocks.nv
    nx, kk, nb = m.shape
    k = kk - 1
    zu_r = win.zu / rho
    if coupled:
        gz = _matmul(pt[:nz, :nx], m)  # (nz, K, g)
        gz[:, k] += zu_r
    a = _gram(m[nv:], m[nv:])
    # forms are scaled by their trace (any positive scale does; this one is cheap)
    a_scale = a[0, 0].real.copy()
    for j in range(1, kk):
        a_scale += a[j, j].real
    a_scale = np.maximum(a_scale, TINY)
    a /= a_scale
    for j in range(k):
        a[j, j] += pad[j]  # padded coordinates: |t_j|^2 in the objective, in no constraint
    pz = np.zeros((blocks.n_blocks, kk, kk, nb), dtype=complex)
    pv = np.zeros_like(pz)
    dscale = np.zeros((blocks.n_blocks, nb))
    active = win.active
    for i, (vs, zs) in enumerate(zip(blocks.v_slices, blocks.z_slices, strict=True)):
        fv = _gram(m[vs], m[vs])
        tv = _sq(m[vs]).sum(axis=(0, 1))
        if coupled:
            fz = _gram(gz[zs], gz[zs])
            tz = _sq(gz[zs]).sum(axis=(0, 1))
        else:  # G_i = [0 .. 0, P13_i U / rho]: one entry
            tz = _sq(zu_r[zs]).sum(axis=0)
            fz = np.zeros_like(fv)
            fz[k, k] = tz
        nq = tz + tv  # trace of G^H G + M^H M >= ||Q_i||_F
        dscale[i] = np.where(active[i], nq, 0.0) / a_scale
        scale = np.where(active[i] & (nq > 0.0), 1.0 / np.where(nq > 0.0, nq, 1.0), 0.0)
        pz[i], pv[i] = fz * scale, fv * scale
    return _Forms(
        m=m,
        a=a,
        q=pz - pv,
        pz=pz,
        pv=pv,
        active=active,
        rho=rho,
        a_scale=a_scale,
        dscale=dscale,
        feasible=feasible,
        z_fixed=not coupled,
    )


def _concat_forms(parts: list[tuple[np.ndarray, _Forms]], g: int) -> _Forms:
    """One batch from forms of disjoint bin sets, padded to the largest dimension.

    Padding inserts coordinates before the homogenising one: zero columns of ``m``, zero rows
    and columns of the constraint forms, identity in ``a``.
    """
    kk = max(f.a.shape[0] for _, f in parts)
    nm, nx = parts[0][1].q.shape[0], parts[0][1].m.shape[0]
    out = {
        "m": np.zeros((nx, kk, g), dtype=complex),
        "a": np.zeros((kk, kk, g), dtype=complex),
        "q": np.zeros((nm, kk, kk, g), dtype=complex),
        "pz": np.zeros((nm, kk, kk, g), dtype=complex),
        "pv": np.zeros((nm, kk, kk, g), dtype=complex),
        "active": np.zeros((nm, g), dtype=bool),
        "rho": np.zeros(g),
        "a_scale": np.zeros(g),
        "dscale": np.zeros((nm, g)),
        "feasible": np.zeros(g, dtype=bool),
    }
    for idx, f in parts:
        k = f.a.shape[0] - 1
        pos = [*range(k), kk - 1]  # where this part's coordinates go
        for i, pi in enumerate(pos):
            out["m"][:, pi, idx] = f.m[:, i]
            for j, pj in enumerate(pos):
                out["a"][pi, pj, idx] = f.a[i, j]
                for name in ("q", "pz", "pv"):
                    out[name][:, pi, pj, idx] = getattr(f, name)[:, i, j]
        for j in range(k, kk - 1):
            out["a"][j, j, idx] = 1.0
        for name in ("active", "rho", "a_scale", "dscale", "feasible"):
            out[name][..., idx] = getattr(f, name)
    return _Forms(**out, z_fixed=all(f.z_fixed for _, f in parts))
