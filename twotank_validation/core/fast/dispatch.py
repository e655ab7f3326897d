"""Batched fast path for Problem 3: every bin of a window solved together with numpy.

The per-bin reference (:func:`twotank_validation.core.solvers.solve_sdp`) builds one cvxpy SDP per
DFT bin, a few milliseconds each. Here every bin's problem is solved on its Lagrangian dual

    phi(d) = min_x ||w||^2 - sum_i d_i (||z_i||^2 - ||v_i||^2),     d >= 0 (one per block),

a concave function of at most three variables, maximised for all bins at once (a secular
Newton step, then projected Newton ascent with safeguards; see :func:`_dual_ascent`). At the
maximiser, with the Lagrangian's Hessian positive definite, its minimiser is primal optimal
(complementary slackness): the dual value is a certified lower bound and the rank-one
``Delta`` built from the minimiser an exactly feasible witness, so the bounds meet. Two
parametrisations of the unknowns:

* bins where ``z = P13 U`` (``P11 = P12 = 0``: every structured model) and ``P22`` is
  square and well conditioned: ``w = P22^-1 (Y - P23 U - P21 v)``, the dual in ``v``
  itself (:class:`_VKernel`);
* any other bin: the equality constraints eliminated and the problem homogenised as in
  :func:`solvers.homogenise_bin` (``min xh^H A xh`` s.t. ``xh^H Q_i xh >= 0``), the dual on
  those forms (:class:`_Kernel`). See docs/theory.md, Sec. 4 and 6.

Why this is hand-written: no library solves thousands of tiny concave duals batched. Batched
``numpy.linalg`` calls on ``(n_bins, k, k)`` stacks loop over LAPACK once per matrix
(a (2049, 2, 4) SVD costs about 13 ms, a (2049, 3, 3) matmul about 1 ms), and SDP/QCQP
solvers take one problem at a time. So the small matrices are stored "structure of arrays"
-- shape ``(rows, cols, n_bins)``, the bin axis last -- and every kernel (Cholesky,
triangular solves, pivoted Gram-Schmidt, Cramer's rule) loops in Python over the few matrix
entries while each numpy operation runs over all bins.

Bins the batched iteration cannot settle -- a dual optimum with singular Hessian (the "hard
case": a zero minimum with many minimisers, or a relaxation gap with three blocks), no
convergence, or a witness that does not meet the lower bound -- are handed to the per-bin
reference code, and counted (:attr:`FastStats.n_fallback`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from twotank_validation.core import solvers
from twotank_validation.core.fast.rules import (  # the rules the compiled kernel shares
    BACKTRACKS,
    FLAT_ITERATIONS,
    GRAM_COND,
    NEGLIGIBLE_Z,
    NOISE_COND,
    NOISE_GAIN,
    PHI_RUNAWAY,
    PIVOT_RTOL,
    STARTS_NATURAL,
    STARTS_SCALED,
    TINY,
    UNEXCITED,
    kernel_applies,
)
from twotank_validation.core.model import BlockStructure, PlantResponse
from twotank_validation.defaults import Method

MAX_BLOCKS = 3
"""Most blocks the fast path takes (the dual is exact for one or two, a bound for three)."""
MAX_UNKNOWNS = 16
"""Most unknowns ``nv + nw`` per bin (the kernels loop in Python over matrix entries)."""

_RANK_RTOL = 1e-10  # as solvers._RANK_RTOL
_CONSISTENCY_RTOL = 1e-8  # as solvers._CONSISTENCY_RTOL


@dataclass(frozen=True)
class FastStats:
    """How the bins of one call were solved.

    Attributes:
        n_bins: bins in the window.
        n_direct: bins solved without the dual: every block unexcited (least-norm w), the
            nominal alone explaining the bin (minimum 0 at x = 0), or an output equation
            with no solution (infeasible).
        n_dual: bins settled by the batched dual ascent.
        n_fallback: bins left unsettled by the batch (see the module doc): handed to the
            per-bin reference (cvxpy SDP) unless ``fallback=False``. The three add up to
            ``n_bins``.
        n_infeasible: bins reported infeasible (``inf``: no ``(w, Delta)`` explains them),
            whichever route found it.
        iterations: Newton iterations of the slowest batched bin.
        n_compiled: bins (direct or dual) answered by the compiled per-bin kernel
            (:mod:`twotank_validation.core.fast.kernel`); the rest of ``n_direct + n_dual`` by the
            batched numpy code.
        kernel_sized: the compiled kernel ran in its version compiled for these dimensions
            (:data:`fastkernel.SIZED`), not the general one.
    """

    n_bins: int
    n_direct: int
    n_dual: int
    n_fallback: int
    n_infeasible: int
    iterations: int
    n_compiled: int = 0
    kernel_sized: bool = False


@dataclass(frozen=True)
class FastSolutions:
    """Result of :func:`solve_fast`: the per-bin solutions and how they were obtained.

    Attributes:
        solutions: as :func:`solvers.solve_sdp` returns them (``method = "fast"``).
        stats: bins per route.
        fell_back: (n_bins,) bool, bins the batch left unsettled (answered by the per-bin
            reference when ``fallback=True``).
        error: (n_bins, ny) complex, ``Y - P23 U`` (computed on the way; saves callers it).
    """

    solutions: solvers.BinSolutions
    stats: FastStats
    fell_back: np.ndarray
    error: np.ndarray


def coverage(blocks: BlockStructure, nw: int) -> tuple[bool, str]:
    """Whether the fast path takes this structure, and why (not).

    Returns:
        ``(covered, reason)``.
    """
    if blocks.n_blocks > MAX_BLOCKS:
        return False, f"{blocks.n_blocks} blocks (the fast path takes at most {MAX_BLOCKS})"
    if blocks.nv + nw > MAX_UNKNOWNS:
        return False, f"{blocks.nv + nw} unknowns per bin (fast path: at most {MAX_UNKNOWNS})"
    exact = "exact" if blocks.n_blocks <= 2 else "a lower bound, gap reported"
    return True, f"{blocks.n_blocks} full complex block(s), dual {exact}"


# ------------------------------------------------------------------ batched small-matrix kernels
# All arrays keep the bin axis last: a batch of (r, c) matrices is an (r, c, g) array.


def _cols(x: np.ndarray, sel: np.ndarray) -> np.ndarray:
    """The bins ``sel`` (int indices or bool mask) of a batch, C-contiguous.

    ``x[..., sel]`` would do, but numpy lays such a result out with the bin axis strided,
    which makes every later elementwise operation several times slower.
    """
    if sel.dtype == bool:
        out: np.ndarray = np.compress(sel, x, axis=-1)
        return out
    return np.take(x, sel, axis=-1)


def _max_row_norm(x: np.ndarray) -> float:
    """Largest row 2-norm of an (n, k) complex array (0 for n = 0)."""
    if not x.shape[0]:
        return 0.0
    f = np.ascontiguousarray(x, dtype=complex).view(np.float64)  # (n, 2k): re, im
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", f, f))))


def _sq(x: np.ndarray) -> np.ndarray:
    """``|x|^2`` elementwise (real), without the square root of ``abs``."""
    out: np.ndarray = x.real * x.real + x.imag * x.imag
    return out


def _cholesky(
    h: np.ndarray, scale: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cholesky factors of a batch of Hermitian matrices.

    Args:
        h: (n, n, g) complex Hermitian (only the lower triangle is read).
        scale: (n, g) float, size of the terms each diagonal entry of ``h`` was summed from
            (default: its magnitude); pivot ``j`` below ``PIVOT_RTOL * scale[j]`` is
            round-off.

    Returns:
        ``(low, diag, ok)``: (n, n, g) complex strictly lower factor, (n, g) float positive
        diagonal, (g,) bool -- False where a pivot is round-off or negative (not numerically
        positive definite; the factors there are garbage).
    """
    n, g = h.shape[0], h.shape[-1]
    if scale is None:
        scale = np.abs(np.diagonal(h).real).T
    if n <= 2:  # explicit: the common sizes, a third of the numpy calls
        return _cholesky_small(h, scale)
    work = h.copy()
    low = np.zeros_like(h)
    diag = np.ones((n, g))
    ok = np.ones(g, dtype=bool)
    for j in range(n):
        piv = work[j, j].real
        good = piv > PIVOT_RTOL * scale[j]
        ok &= good
        dj = np.sqrt(np.where(good, piv, 1.0))
        diag[j] = dj
        if j + 1 < n:
            col = work[j + 1 :, j] / dj
            low[j + 1 :, j] = col
            work[j + 1 :, j + 1 :] -= col[:, None] * col.conj()[None, :]
    return low, diag, ok


def _cholesky_small(h: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_cholesky` for 1x1 and 2x2 batches, written out."""
    piv = h[0, 0].real
    ok = piv > PIVOT_RTOL * scale[0]
    d0 = np.sqrt(np.where(ok, piv, 1.0))
    low = np.zeros_like(h)
    if h.shape[0] == 1:
        return low, d0[None], ok
    l10 = h[1, 0] / d0
    low[1, 0] = l10
    piv = h[1, 1].real - _sq(l10)
    ok1 = piv > PIVOT_RTOL * scale[1]
    return low, np.stack([d0, np.sqrt(np.where(ok1, piv, 1.0))]), ok & ok1


def _chol_solve(low: np.ndarray, diag: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``L L^H x = b`` for a batch; ``b`` is (n, ..., g) (extra axes: several right sides)."""
    n = diag.shape[0]
    if n == 1:
        one: np.ndarray = b / (diag[0] * diag[0])
        return one
    if n == 2:
        l10 = low[1, 0]
        y0 = b[0] / diag[0]
        x1 = (b[1] - l10 * y0) / (diag[1] * diag[1])
        return np.stack([(y0 - l10.conj() * x1) / diag[0], x1])
    y = np.empty_like(b, dtype=complex)
    for i in range(n):
        acc = b[i].astype(complex, copy=True)
        for j in range(i):
            acc -= low[i, j] * y[j]
        y[i] = acc / diag[i]
    x = np.empty_like(y)
    for i in range(n - 1, -1, -1):
        acc = y[i].copy()
        for j in range(i + 1, n):
            acc -= low[j, i].conj() * x[j]
        x[i] = acc / diag[i]
    return x


@dataclass(frozen=True)
class _RowSpace:
    """Orthonormal basis of the row space of ``E x = f`` and its least-norm solution.

    Attributes:
        q: (p, n, g) complex; ``q[j]`` with ``j < rank`` are orthonormal, ``E x = f`` is
            ``q[j]^H x = s[j]``; rows beyond each bin's rank are zero.
        rank: (g,) int.
        x0: (n, g) complex, least-norm solution (least squares where inconsistent).
        resid: (g,) float, ``||E x0 - f||``.
    """

    q: np.ndarray
    rank: np.ndarray
    x0: np.ndarray
    resid: np.ndarray


def _row_space(e: np.ndarray, f: np.ndarray) -> _RowSpace:
    """Pivoted modified Gram-Schmidt (with one re-orthogonalisation) on the rows of ``E``.

    Rank-revealing: at each step the remaining row with the largest residual is taken; a row
    whose residual is below ``_RANK_RTOL * max(p, n)`` of the largest row norm ends the basis.

    Args:
        e: (p, n, g) complex, ``E`` per bin.
        f: (p, g) complex.
    """
    p, n, g = e.shape
    w = e.conj()  # equation j reads w[j]^H x = f[j]
    rhs = f.astype(complex, copy=True)
    q = np.zeros((p, n, g), dtype=complex)
    s = np.zeros((p, g), dtype=complex)
    rank = np.zeros(g, dtype=int)
    norms = _sq(w).sum(axis=1)  # (p, g)
    tol = _RANK_RTOL * max(p, n) * np.sqrt(np.max(norms, axis=0)) if p else np.zeros(g)
    for j in range(p):
        if j + 1 < p:  # pivot: bring the row with the largest residual to position j
            piv = np.argmax(_sq(w[j:]).sum(axis=1), axis=0)
            if np.any(piv):
                wj = np.take_along_axis(w[j:], piv[None, None, :], axis=0)[0]
                rj = np.take_along_axis(rhs[j:], piv[None, :], axis=0)[0]
                for k in range(1, p - j):
                    w[j + k] = np.where(piv == k, w[j], w[j + k])
                    rhs[j + k] = np.where(piv == k, rhs[j], rhs[j + k])
                w[j], rhs[j] = wj, rj
        wj, rj = w[j], rhs[j]
        if j:  # re-orthogonalise against the basis so far ("twice is enough")
            c = (q[:j].conj() * wj[None]).sum(axis=1)  # (j, g)
            wj = wj - (q[:j] * c[:, None]).sum(axis=0)
            rj = rj - (c.conj() * s[:j]).sum(axis=0)
        nj = np.sqrt(_sq(wj).sum(axis=0))
        ok = (nj > tol) & (rank == j)
        inv = np.where(ok, 1.0 / np.where(ok, nj, 1.0), 0.0)
        q[j] = wj * inv
        s[j] = rj * inv
        rank += ok
        if j + 1 < p:
            c = (q[j].conj()[None] * w[j + 1 :]).sum(axis=1)  # (p - j - 1, g)
            w[j + 1 :] -= q[j][None] * c[:, None]
            rhs[j + 1 :] -= c.conj() * s[j]
    x0 = (q * s[:, None]).sum(axis=0)
    resid = np.sqrt(_sq((e * x0[None]).sum(axis=1) - f).sum(axis=0))
    return _RowSpace(q=q, rank=rank, x0=x0, resid=resid)


def _complement(q: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``count`` orthonormal vectors orthogonal to the orthonormal rows ``q``.

    Gram-Schmidt on the unit vectors ``e_i``, each time the one with the largest residual
    (squared length at least ``1 / n`` while a direction is left, so the basis is well
    conditioned), re-orthogonalised once. Bins whose complement has fewer than ``count``
    dimensions get zero vectors, flagged as padding.

    Args:
        q: (r, n, g) complex orthonormal rows (zero rows are ignored).
        count: vectors wanted (the largest complement dimension of the batch).

    Returns:
        ``(basis, pad)``: (n, count, g) complex, the vectors as columns; (count, g) bool.
    """
    r, n, g = q.shape
    basis = np.zeros((r + count, n, g), dtype=complex)
    basis[:r] = q
    pad = np.zeros((count, g), dtype=bool)
    covered = _sq(q).sum(axis=0)  # (n, g): squared length of each e_i's projection
    cols = np.arange(g)
    for j in range(count):
        left = 1.0 - covered
        piv = np.argmax(left, axis=0)
        cur = basis[: r + j]
        c = cur[:, piv, cols].conj()  # (r + j, g): b^H e_piv
        vec = -(cur * c[:, None]).sum(axis=0)
        vec[piv, cols] += 1.0
        c2 = (cur.conj() * vec[None]).sum(axis=1)
        vec -= (cur * c2[:, None]).sum(axis=0)
        none = left[piv, cols] < 0.5 / n
        pad[j] = none
        vec *= np.where(none, 0.0, 1.0 / np.sqrt(np.maximum(_sq(vec).sum(axis=0), TINY)))
        basis[r + j] = vec
        covered += _sq(vec)
    return basis[r:].transpose(1, 0, 2), pad


def _gram(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``X^H Y`` for batches (r, a, g) and (r, b, g) -> (a, b, g)."""
    if x.shape[0] == 1:  # an outer product: no reduction
        outer: np.ndarray = x[0].conj()[:, None, :] * y[0][None, :, :]
        return outer
    out: np.ndarray = (x.conj()[:, :, None, :] * y[:, None, :, :]).sum(axis=0)
    return out


def _matmul(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``X Y`` for batches (a, r, g) and (r, b, g) -> (a, b, g)."""
    out: np.ndarray = (x[:, :, None, :] * y[None, :, :, :]).sum(axis=1)
    return out


def _matvec(x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``X v`` for batches (a, r, g) and (r, g) -> (a, g)."""
    out: np.ndarray = (x * v[None]).sum(axis=1)
    return out


def _adjugate(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Adjugate and determinant of a batch of 1x1, 2x2 or 3x3 matrices (real or complex).

    Args:
        h: (m, m, g), m <= 3.

    Returns:
        ``(adj, det)``: (m, m, g) and (g,), with ``h adj = det I``.
    """
    m = h.shape[0]
    if m == 1:
        return np.ones_like(h), h[0, 0]
    if m == 2:
        adj = np.empty_like(h)
        adj[0, 0], adj[1, 1] = h[1, 1], h[0, 0]
        np.negative(h[0, 1], out=adj[0, 1])
        np.negative(h[1, 0], out=adj[1, 0])
        return adj, h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0]
    adj = np.empty_like(h)
    for i in range(3):
        for j in range(3):
            r0, r1 = [k for k in range(3) if k != j]
            c0, c1 = [k for k in range(3) if k != i]
            minor = h[r0, c0] * h[r1, c1] - h[r0, c1] * h[r1, c0]
            adj[i, j] = -minor if (i + j) % 2 else minor
    return adj, h[0, 0] * adj[0, 0] + h[0, 1] * adj[1, 0] + h[0, 2] * adj[2, 0]


def _solve_small(h: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``h x = b`` for a batch of real 1x1, 2x2 or 3x3 systems by Cramer's rule.

    Args:
        h: (m, m, g) float, m <= 3.
        b: (m, g) float.

    Returns:
        (m, g) float; ``nan``/``inf`` where ``h`` is singular (callers check).
    """
    adj, det = _adjugate(h)
    with np.errstate(divide="ignore", invalid="ignore"):
        x: np.ndarray = (adj * b[None]).sum(axis=1) / det
    return x


def _inverse_small(a: np.ndarray, max_cond: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of a batch of complex 1x1, 2x2 or 3x3 matrices, and where it is trustworthy.

    Args:
        a: (n, n, g) complex, n <= 3.
        max_cond: largest condition number accepted (default ``NOISE_COND``).

    Returns:
        ``(inv, good)``: (n, n, g) complex; (g,) bool, Frobenius condition number
        ``||a||_F ||a^-1||_F`` (at most n times the 2-norm one) below ``max_cond``.
    """
    adj, det = _adjugate(a)
    norm2 = _sq(a).sum(axis=(0, 1))
    # a 2x2 adjugate has the entries of a, so the same norm
    size = norm2 if a.shape[0] == 2 else np.sqrt(norm2 * _sq(adj).sum(axis=(0, 1)))
    good = size < (max_cond or NOISE_COND) * np.abs(det)
    inv: np.ndarray = adj / np.where(good, det, 1.0)
    return inv, good


# ------------------------------------------------------------------ homogenisation, batched


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


def _least_norm_size(b: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``||x0||`` of the least-norm solution of ``B x = r`` per bin (a scale, not a solution).

    ``||x0||^2 = r^H (B B^H)^-1 r`` by Cramer's rule where the Gram matrix is small (up to
    3x3) and well conditioned; otherwise by the pivoted Gram-Schmidt of :func:`_row_space`.

    Args:
        b: (p, n, g) complex.
        r: (p, g) complex.

    Returns:
        (g,) float.
    """
    p = b.shape[0]
    if p > 3:
        exact: np.ndarray = np.sqrt(_sq(_row_space(b, r).x0).sum(axis=0))
        return exact
    if p <= 2:  # written out: Gram entries and Cramer's rule
        g00 = _sq(b[0]).sum(axis=0)
        if p == 1:
            ok1 = g00 > 0.0
            one: np.ndarray = np.sqrt(_sq(r[0]) / np.where(ok1, g00, 1.0))
            if not np.all(ok1):
                bad = np.flatnonzero(~ok1)
                one[bad] = np.sqrt(_sq(_row_space(_cols(b, bad), _cols(r, bad)).x0).sum(axis=0))
            return one
        g11 = _sq(b[1]).sum(axis=0)
        g01 = (b[0] * b[1].conj()).sum(axis=0)
        det = g00 * g11 - _sq(g01)
        ok2 = det > 1e-8 * g00 * g11  # condition number below ~1e8
        quad = g11 * _sq(r[0]) + g00 * _sq(r[1]) - 2.0 * (r[0].conj() * g01 * r[1]).real
        two: np.ndarray = np.sqrt(np.abs(quad) / np.where(ok2, det, 1.0))
        if not np.all(ok2):
            bad = np.flatnonzero(~ok2)
            two[bad] = np.sqrt(_sq(_row_space(_cols(b, bad), _cols(r, bad)).x0).sum(axis=0))
        return two
    gram = (b[:, None] * b.conj()[None, :]).sum(axis=2)  # B B^H, (p, p, g)
    inv, good = _inverse_small(gram, max_cond=GRAM_COND)
    size: np.ndarray = np.sqrt(np.abs((r.conj() * _matvec(inv, r)).sum(axis=0).real))
    if not np.all(good):
        bad = np.flatnonzero(~good)
        size[bad] = np.sqrt(_sq(_row_space(_cols(b, bad), _cols(r, bad)).x0).sum(axis=0))
    return size


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
        good: (g,) bool, bins where ``inv`` is trustworthy (see :func:`_inverse_small`).
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


# ------------------------------------------------------------------ batched dual ascent


@dataclass(frozen=True)
class _Point:
    """The dual function at multipliers ``d`` for a batch of bins.

    Attributes:
        ok: (g,) bool, ``H_tt`` numerically positive definite (else the rest is garbage).
        xh: (K, g) complex, Lagrangian minimiser ``[t; 1]``.
        phi: (g,) float, dual value ``xh^H H xh`` (a certified lower bound where ``ok``).
        px: (2m, K, g) complex, ``pz_i xh`` then ``pv_i xh``.
        n2: (2m, g) float, ``xh^H pz_i xh`` (``||z_i||^2`` in the units of ``q_i``) then
            ``xh^H pv_i xh`` (``||v_i||^2``).
        low, diag: Cholesky factors of ``H_tt``.
    """

    ok: np.ndarray
    xh: np.ndarray
    phi: np.ndarray
    px: np.ndarray
    n2: np.ndarray
    low: np.ndarray
    diag: np.ndarray

    @property
    def slack(self) -> np.ndarray:
        """(m, g) float, ``xh^H Q_i xh = ||z_i||^2 - ||v_i||^2`` (minus the gradient)."""
        m = self.n2.shape[0] // 2
        out: np.ndarray = self.n2[:m] - self.n2[m:]
        return out


@dataclass(frozen=True)
class _Kernel:
    """The forms of the bins being iterated, laid out for :func:`_evaluate`.

    Attributes:
        a: (K, K, g) complex.
        q: (m, K, K, g) complex, ``pz_i - pv_i``.
        pzv: (2m, K, K, g) complex, ``pz_i`` then ``pv_i``; only ``pv_i`` ((m, K, K, g))
            where ``zx`` is given.
        a_diag: (K - 1, g) float, ``|diag A_tt|``.
        q_diag: (m, K - 1, g) float, ``|diag Q_i,tt|`` (with ``a_diag``, the size of the
            terms each diagonal entry of ``H_tt`` is summed from).
        zx: (m, K, g) complex or None: ``pz_i xh``, the same at every ``xh`` when ``z`` does
            not depend on the unknowns (``pz_i`` lives in the homogenising entry).
    """

    a: np.ndarray
    q: np.ndarray
    pzv: np.ndarray
    a_diag: np.ndarray
    q_diag: np.ndarray
    zx: np.ndarray | None

    @property
    def unit(self) -> np.ndarray:
        """(g,) float, the objective's unit (the forms are normalised: 1)."""
        return np.ones(self.a.shape[-1])

    @property
    def size(self) -> int:
        """K, the homogenised dimension."""
        return int(self.a.shape[0])

    def evaluate(self, d: np.ndarray, *, at_zero: bool = False) -> _Point:
        """See :func:`_evaluate`."""
        return _evaluate_dense(self, d, at_zero=at_zero)

    @staticmethod
    def of(forms: _Forms) -> _Kernel:
        k = forms.a.shape[0] - 1
        diag_q = np.diagonal(forms.q[:, :k, :k], axis1=1, axis2=2)  # (m, g, k)
        fixed = forms.z_fixed
        return _Kernel(
            a=forms.a,
            q=forms.q,
            pzv=forms.pv if fixed else np.concatenate([forms.pz, forms.pv]),
            a_diag=np.ascontiguousarray(np.abs(np.diagonal(forms.a[:k, :k]).real).T),
            q_diag=np.ascontiguousarray(np.abs(diag_q.real).transpose(0, 2, 1)),
            zx=np.ascontiguousarray(forms.pz[:, :, k]) if fixed else None,
        )

    def take(self, sel: np.ndarray) -> _Kernel:
        return _Kernel(
            a=_cols(self.a, sel),
            q=_cols(self.q, sel),
            pzv=_cols(self.pzv, sel),
            a_diag=_cols(self.a_diag, sel),
            q_diag=_cols(self.q_diag, sel),
            zx=None if self.zx is None else _cols(self.zx, sel),
        )


@dataclass(frozen=True)
class _VKernel:
    """The dual in ``v`` itself, for bins where ``z = P13 U`` and ``P22`` is invertible.

    ``w = w0 - P v`` (``P = P22^-1 P21``, ``w0 = P22^-1 (Y - P23 U)``), so the bin is
    ``min ||w0 - P v||^2`` s.t. ``||v_i||^2 <= c_i = ||P13_i U||^2``: ``t = v``, ``H_tt =
    P^H P + sum_i d_i E_i^T E_i`` (``E_i`` selects block ``i``), ``H_ts = -P^H w0``. The
    multipliers ``d`` are in the objective's own units, and the dual value is evaluated as
    the Lagrangian at its minimiser, ``||w0 - P t||^2 + sum_i d_i (||t_i||^2 - c_i)``
    (no Schur complement, so no cancellation when ``||w0||`` dwarfs the minimum). Forced
    blocks' coordinates are pinned to 0 (identity rows in ``H_tt``).

    Attributes:
        gram: (k, k, g) complex, ``P^H P`` (identity on pinned coordinates).
        b: (k, g) complex, ``P^H w0`` (0 on pinned coordinates).
        p: (nw, k, g) complex, ``P``.
        w0: (nw, g) complex.
        c: (m, g) float.
        g_diag: (k, g) float, ``|diag gram|`` (pivot scales).
        zx: (m, K, g) complex, ``pz_i xh = c_i e_K`` (constant).
        unit: (g,) float, the objective's unit: ``||w0||^2`` (``||w||^2`` at ``v = 0``).
        blocks: block structure (the coordinates of each block).
    """

    gram: np.ndarray
    b: np.ndarray
    p: np.ndarray
    w0: np.ndarray
    c: np.ndarray
    g_diag: np.ndarray
    zx: np.ndarray
    unit: np.ndarray
    blocks: BlockStructure

    @property
    def size(self) -> int:
        """K = nv + 1."""
        return int(self.gram.shape[0]) + 1

    def take(self, sel: np.ndarray) -> _VKernel:
        return _VKernel(
            gram=_cols(self.gram, sel),
            b=_cols(self.b, sel),
            p=_cols(self.p, sel),
            w0=_cols(self.w0, sel),
            c=_cols(self.c, sel),
            g_diag=_cols(self.g_diag, sel),
            zx=_cols(self.zx, sel),
            unit=_cols(self.unit, sel),
            blocks=self.blocks,
        )

    def evaluate(self, d: np.ndarray, *, at_zero: bool = False) -> _Point:
        """See :func:`_evaluate`."""
        k, g = self.b.shape
        h = self.gram
        scale = self.g_diag
        if not at_zero:
            h = h.copy()
            scale = scale.copy()
            for i, vs in enumerate(self.blocks.v_slices):
                for j in range(vs.start, vs.stop):
                    h[j, j] += d[i]
                    scale[j] += d[i]
        low, diag, ok = _cholesky(h, scale)
        t = _chol_solve(low, diag, self.b)
        xh = np.concatenate([t, np.ones((1, g), dtype=complex)])
        nm = self.c.shape[0]
        pvx = np.zeros((nm, k + 1, g), dtype=complex)
        for i, vs in enumerate(self.blocks.v_slices):
            pvx[i, vs] = t[vs]
        v_starts = [vs.start for vs in self.blocks.v_slices]
        nv2 = np.add.reduceat(_sq(t), v_starts, axis=0)  # ||v_i||^2
        w = self.w0 - _matvec(self.p, t)
        phi = _sq(w).sum(axis=0) - (d * (self.c - nv2)).sum(axis=0)
        return _Point(
            ok=ok & np.isfinite(phi),
            xh=xh,
            phi=phi,
            px=np.concatenate([self.zx, pvx]),
            n2=np.concatenate([self.c, nv2]),
            low=low,
            diag=diag,
        )


@dataclass(frozen=True)
class _Batch:
    """The bins still iterating: their forms, block activity, multipliers, current point."""

    kern: _Kernel | _VKernel
    active: np.ndarray
    d: np.ndarray
    pt: _Point


def _evaluate(kern: _Kernel | _VKernel, d: np.ndarray, *, at_zero: bool = False) -> _Point:
    """Dual function, Lagrangian minimiser and constraint values at ``d`` ((m, g) float).

    ``at_zero``: the caller knows ``d = 0`` (``H = A``).
    """
    return kern.evaluate(d, at_zero=at_zero)


def _evaluate_dense(kern: _Kernel, d: np.ndarray, *, at_zero: bool = False) -> _Point:
    """:func:`_evaluate` on homogenised forms (phi by Schur complement)."""
    a = kern.a
    k = a.shape[0] - 1
    if at_zero:
        h, scale = a, kern.a_diag
    else:
        h = a - (kern.q * d[:, None, None, :]).sum(axis=0)
        scale = kern.a_diag + (kern.q_diag * d[:, None, :]).sum(axis=0)
    # pivots are compared with the terms H_tt is summed from (A_tt is a Gram matrix, PSD)
    low, diag, ok = _cholesky(h[:k, :k], scale)
    t = -_chol_solve(low, diag, h[:k, k])
    xh = np.concatenate([t, np.ones((1, a.shape[-1]), dtype=complex)])
    phi = h[k, k].real + (h[k, :k] * t).sum(axis=0).real
    px = (kern.pzv * xh[None, None, :, :]).sum(axis=2)
    if kern.zx is not None:  # pz_i xh does not depend on xh (its last entry is 1)
        px = np.concatenate([kern.zx, px])
        n2 = np.concatenate(
            [kern.zx[:, k].real, (xh.conj()[None] * px[kern.zx.shape[0] :]).sum(axis=1).real]
        )
    else:
        n2 = (xh.conj()[None] * px).sum(axis=1).real
    return _Point(ok=ok & np.isfinite(phi), xh=xh, phi=phi, px=px, n2=n2, low=low, diag=diag)


def _take(pt: _Point, sel: np.ndarray) -> _Point:
    return _Point(*(_cols(getattr(pt, f), sel) for f in _Point.__dataclass_fields__))


def _merge(pt: _Point, trial: _Point, at: np.ndarray) -> _Point:
    """``pt`` with the bins ``at`` replaced by ``trial``."""
    out = []
    for f in _Point.__dataclass_fields__:
        arr = getattr(pt, f).copy()
        arr[..., at] = getattr(trial, f)
        out.append(arr)
    return _Point(*out)


def _take_batch(b: _Batch, sel: np.ndarray) -> _Batch:
    return _Batch(
        kern=b.kern.take(sel), active=_cols(b.active, sel), d=_cols(b.d, sel), pt=_take(b.pt, sel)
    )


@dataclass(frozen=True)
class _DualResult:
    """Per bin: multipliers, Lagrangian minimiser, dual value, success; iteration count.

    ``cond``: the pivot ratio of ``H_tt`` at the final point (see :func:`_pivot_ratio`).
    """

    d: np.ndarray
    xh: np.ndarray
    phi: np.ndarray
    ok: np.ndarray
    iterations: int
    cond: np.ndarray


def _dual_ascent(
    kern: _Kernel | _VKernel, active: np.ndarray, dscale: np.ndarray, max_iter: int = 60
) -> _DualResult:
    """Maximise the concave dual of every bin at once.

    Each iteration tries, per bin, a Newton step on the secular form of the complementarity
    conditions, ``F_i(d) = 1/||v_i(d)|| - 1/||z_i(d)|| = 0`` on the free blocks (Moré and
    Sorensen's trick for the trust-region secular equation: when ``z`` does not depend on the
    unknowns, ``1/||v_i(d)||`` is close to linear in ``d``, so one step lands near the optimum
    even when the multipliers span many decades). The step is kept when it raises the dual;
    otherwise the projected Newton ascent of :func:`solvers.polish_dual` (free set
    ``d_i > 0 or slack_i < 0``, ``-Hessian = 2 Re(R^H H_tt^-1 R)``) with backtracking takes
    over. Bins leave the batch once settled (:func:`_settled`) or when no ascent is left at
    round-off level; bins without a positive definite ``H_tt`` at every start, or out of
    iterations, come back with ``ok = False``.

    Args:
        kern: the bins' forms (:class:`_Kernel`) or their dual in ``v`` (:class:`_VKernel`).
        active: (m, g) bool, blocks not forced to ``v_i = 0``.
        dscale: (m, g) float, multipliers that weigh every block alike in the objective's
            units (see :func:`_starts`).
        max_iter: Newton iterations at most.
    """
    kk, g = kern.size, active.shape[-1]
    nm = active.shape[0]
    d_out = np.zeros((nm, g))
    xh_out = np.zeros((kk, g), dtype=complex)
    xh_out[-1] = 1.0
    phi_out = np.zeros(g)
    ok_out = np.zeros(g, dtype=bool)
    cond_out = np.zeros(g)
    if kk == 1 and isinstance(kern, _Kernel):  # nothing to minimise: xh = [1] (as solve_bin_sdp)
        ones = np.ones(g)
        return _DualResult(d_out, xh_out, kern.a[0, 0].real.copy(), ones > 0, 0, ones)
    d = np.zeros((nm, g))
    pt = _evaluate(kern, d, at_zero=True)
    for start in _starts(dscale, active) if not np.all(pt.ok) else ():  # H_tt PD
        bad = np.flatnonzero(~pt.ok & np.any(active, axis=0))
        if bad.size == 0:
            break
        d[:, bad] = _cols(start, bad)
        pt = _merge(pt, _evaluate(kern.take(bad), _cols(d, bad)), bad)
    live = np.arange(g)
    bt = _Batch(kern, active, d, pt)
    if not np.all(pt.ok):
        live = np.flatnonzero(pt.ok)
        bt = _take_batch(bt, live)
    flat = np.zeros(live.size, dtype=int)  # consecutive iterations without ascent
    iterations = 0
    for it in range(max_iter + 1):
        free = _free_set(bt)
        # a dual growing without bound: no (w, Delta) may explain the bin (left to fallback)
        runaway = bt.pt.phi > PHI_RUNAWAY * bt.kern.unit
        done = _settled(bt, free) | (flat >= FLAT_ITERATIONS) | runaway
        all_done = bool(np.all(done))
        if all_done and live.size == g:  # the whole batch at once: no indexing
            d_out, xh_out, phi_out = bt.d, bt.pt.xh, bt.pt.phi
            ok_out, cond_out = ~runaway, _pivot_ratio(bt.pt)
            break
        if np.any(done):
            fin = live[done]
            d_out[:, fin], xh_out[:, fin] = _cols(bt.d, done), _cols(bt.pt.xh, done)
            phi_out[fin] = bt.pt.phi[done]
            ok_out[fin] = ~runaway[done]
            cond_out[fin] = _cols(_pivot_ratio(bt.pt), done)
        if all_done or it == max_iter:
            break
        if 4 * np.sum(done) >= done.size:  # drop settled bins once it pays
            keep = np.flatnonzero(~done)
            live, bt, flat = live[keep], _take_batch(bt, keep), flat[keep]
            free = _cols(free, keep)
            done = np.zeros(keep.size, dtype=bool)
        # else settled bins ride along, frozen (no move), and are recorded again unchanged
        iterations = it + 1
        secular, newton = _steps(bt, free & ~done)
        secular[:, done] = 0.0
        phi_before = bt.pt.phi
        bt, stalled = _advance(bt, secular, newton, compare=it > 0)
        gain = bt.pt.phi - phi_before
        flat = np.where(gain <= 1e-14 * (bt.kern.unit + np.abs(phi_before)), flat + 1, 0)
        stalled &= ~done
        if np.any(stalled):  # no ascent left: settled where H_tt is PD (the witness judges)
            fin = live[stalled]
            d_out[:, fin], xh_out[:, fin] = _cols(bt.d, stalled), _cols(bt.pt.xh, stalled)
            phi_out[fin] = bt.pt.phi[stalled]
            ok_out[fin] = bt.pt.ok[stalled]
            cond_out[fin] = _cols(_pivot_ratio(bt.pt), stalled)
            keep = np.flatnonzero(~stalled)
            if keep.size == 0:
                break
            live, bt, flat = live[keep], _take_batch(bt, keep), flat[keep]
    return _DualResult(d_out, xh_out, phi_out, ok_out, iterations, cond_out)


def _pivot_ratio(pt: _Point) -> np.ndarray:
    """(g,) float, smallest over largest squared Cholesky pivot of ``H_tt`` (conditioning)."""
    piv = pt.diag * pt.diag
    out: np.ndarray = np.min(piv, axis=0) / np.maximum(np.max(piv, axis=0), TINY)
    return out


def _starts(dscale: np.ndarray, active: np.ndarray) -> Iterator[np.ndarray]:
    """Starting multipliers tried, in order, where ``d = 0`` leaves ``H_tt`` singular.

    First the same multiplier ``c`` for every block in the units of the objective
    (``d_i = c ||Q_i|| / ||A||``: with a well-posed LFT, ``-sum_i Q_i`` is positive definite
    on the directions ``A`` leaves free, so a small uniform ``c`` works), then the same with
    one or two blocks left at 0 (a block whose ``Q_i`` curves the wrong way), then uniform
    in the normalised units.

    Yields:
        (m, g) float.
    """
    nm = active.shape[0]
    subsets = [np.ones(nm, dtype=bool)]
    subsets += [np.arange(nm) == i for i in range(nm)] if nm > 1 else []
    subsets += [np.arange(nm) != i for i in range(nm)] if nm > 2 else []
    for sub in subsets:
        for c in STARTS_NATURAL:
            yield c * dscale * sub[:, None]
    for c in STARTS_SCALED:
        yield c * active


def _free_set(bt: _Batch) -> np.ndarray:
    """(m, g) bool, multipliers Newton moves: positive, or at 0 with a violated constraint."""
    out: np.ndarray = bt.active & ((bt.d > 0.0) | (bt.pt.slack < 0.0))
    return out


def _settled(bt: _Batch, free: np.ndarray) -> np.ndarray:
    """Bins at a KKT point to round-off: the Lagrangian minimiser is then optimal.

    Primal feasibility ``||v_i||^2 <= ||z_i||^2`` within 1e-12 of their size, and duality
    gap ``sum_i d_i xh^H Q_i xh`` (what the objective at ``xh`` exceeds the dual value by)
    below 1e-12 of the dual value plus 1e-15 of the objective's unit.
    """
    pt = bt.pt
    if not np.any(bt.active):
        return np.ones(pt.phi.shape, dtype=bool)
    nm = bt.d.shape[0]
    size = pt.n2[:nm] + pt.n2[nm:]
    slack = pt.slack
    feasible = np.all((slack >= -1e-12 * size) | ~bt.active, axis=0)
    gap = (bt.d * np.abs(slack)).sum(axis=0)
    tol = 1e-12 * np.abs(pt.phi) + 1e-15 * bt.kern.unit
    out: np.ndarray = (feasible & (gap <= tol)) | ~np.any(free, axis=0)
    return out


@dataclass(frozen=True)
class _NewtonSystem:
    """Projected Newton step on the free multipliers, solved only where it is needed.

    The quadratic model of the dual around ``d`` is ``phi + g.D - D.H D / 2`` with gradient
    ``g = -slack`` and ``H = 2 Re(R^H H_tt^-1 R)`` (minus the Hessian).

    Attributes:
        dslack: (m, m, g) float, ``H``.
        slack: (m, g) float, minus the gradient.
        free: (m, g) bool, multipliers Newton moves.
        d: (m, g) float, the current multipliers.
    """

    dslack: np.ndarray
    slack: np.ndarray
    free: np.ndarray
    d: np.ndarray

    def step(self, sel: np.ndarray, *, bound: np.ndarray | None = None) -> np.ndarray:
        """(m, len(sel)) float, the step at the bins ``sel``.

        ``bound``: (m, len(sel)) bool, multipliers sent to 0 (the step is then the maximiser
        of the model over the other free ones, the bounded ones held at 0).
        """
        free = _cols(self.free, sel)
        d = _cols(self.d, sel)
        h = _cols(self.dslack, sel)
        nm = free.shape[0]
        to_zero = np.zeros_like(d)
        rhs = -_cols(self.slack, sel)
        if bound is not None:
            free = free & ~bound
            to_zero = np.where(bound, -d, 0.0)
            rhs = rhs - (h * to_zero[None, :, :]).sum(axis=1)  # g_F - H_FB D_B
        both = free[:, None] & free[None, :]
        step = _solve_small(np.where(both, h, np.eye(nm)[:, :, None]), np.where(free, rhs, 0.0))
        bad = ~np.all(np.isfinite(step), axis=0)
        out: np.ndarray = np.where(free & ~bad[None], step, to_zero)
        return out

    def cauchy(self, sel: np.ndarray) -> np.ndarray:
        """(m, len(sel)) float, the model's maximiser along the gradient on the free ones."""
        free = _cols(self.free, sel)
        grad = np.where(free, -_cols(self.slack, sel), 0.0)
        h = _cols(self.dslack, sel)
        curv = (grad[:, None] * h * grad[None, :]).sum(axis=(0, 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            length = np.where(curv > 0.0, (grad * grad).sum(axis=0) / curv, 0.0)
        out: np.ndarray = length * grad
        return out


def _steps(bt: _Batch, free: np.ndarray) -> tuple[np.ndarray, _NewtonSystem]:
    """The two candidate moves on the free multipliers.

    * Newton on the secular form ``F_i = 1/||v_i(d)|| - 1/||z_i(d)||`` with
      ``d t / d d_j = H_tt^-1 R_j``, ``R = [(Q_i xh)_t]``; ``nan`` where it does not apply
      (a free block with ``v_i`` or ``z_i`` at zero, a singular Jacobian, or no ascent
      direction).
    * Projected Newton ascent on ``phi`` (gradient ``-slack``, ``-Hessian = 2 Re(R^H H_tt^-1
      R)``), as a system solved later for the bins that need it.

    Returns:
        ``(secular, newton)``: (m, g) float; the Newton system.
    """
    pt = bt.pt
    k = pt.xh.shape[0] - 1
    nm = bt.d.shape[0]
    slack = pt.slack
    pxt = pt.px[:, :k]  # (2m, k, g): (pz_i xh)_t, (pv_i xh)_t
    nz2, nv2 = pt.n2[:nm], pt.n2[nm:]
    with np.errstate(divide="ignore", invalid="ignore"):  # v_i or z_i at 0: not usable
        iv = 1.0 / np.sqrt(nv2)
        iz = 1.0 / np.sqrt(nz2)
        if bt.kern.zx is not None:  # (pz_i xh)_t = 0: R = -(pv_i xh)_t
            pv_t = pxt[nm:]
            y = _chol_solve(pt.low, pt.diag, pv_t.transpose(1, 0, 2))  # -(d t / d d_j)
            dnv2 = -2.0 * (pv_t.conj()[:, :, None, :] * y[None]).sum(axis=1).real
            dslack = -dnv2
            jac = -0.5 * (iv * iv * iv)[:, None] * dnv2
        else:
            r = pxt[:nm] - pxt[nm:]  # (Q_i xh)_t
            y = _chol_solve(pt.low, pt.diag, r.transpose(1, 0, 2))  # (k, m, g): d t / d d_j
            dn2 = 2.0 * (pxt.conj()[:, :, None, :] * y[None]).sum(axis=1).real  # (2m, m, g)
            dnz2, dnv2 = dn2[:nm], dn2[nm:]
            dslack = dnz2 - dnv2  # = 2 Re(R^H H_tt^-1 R)
            jac = 0.5 * (iz * iz * iz)[:, None] * dnz2 - 0.5 * (iv * iv * iv)[:, None] * dnv2
    newton = _NewtonSystem(dslack=dslack, slack=slack, free=free, d=bt.d)
    both = free[:, None] & free[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        sec = _solve_small(
            np.where(both, jac, np.eye(nm)[:, :, None]), np.where(free, iz - iv, 0.0)
        )
    usable = (nv2 > 1e-200) & (nz2 > 1e-200)
    sec_ok = np.all(usable | ~free, axis=0) & np.all(np.isfinite(sec), axis=0)
    secular = np.where(free & sec_ok[None], sec, 0.0)
    # only an ascent direction of phi (gradient -slack) after projection onto d >= 0; when z
    # depends on the unknowns the secular Jacobian can point the wrong way
    moved = np.maximum(bt.d + secular, 0.0) - bt.d
    sec_ok &= (-slack * moved).sum(axis=0) > 0.0
    secular = np.where(sec_ok[None], secular, np.nan)
    return secular, newton


def _advance(
    bt: _Batch, secular: np.ndarray, newton: _NewtonSystem, *, compare: bool = False
) -> tuple[_Batch, np.ndarray]:
    """One ascent move per bin; ``phi`` never decreases and ``H_tt`` stays PD.

    First try: the secular step (a whole-batch evaluation; where it is accepted, that is the
    move -- the common case). Where it is refused or unusable, or with ``compare`` (after
    the first iteration: the secular step is a heuristic, and can creep towards the edge of
    the positive definite region when blocks interact), the candidates are evaluated and
    the best accepted one kept: the secular step, the full projected Newton step
    ``max(d + step, 0)``, the Cauchy point (the maximiser of the Newton model along the
    projected gradient: slower, but it follows a narrow ridge of the dual where Newton's
    model points the wrong way) and, with ``compare``, the full step with no multiplier
    falling below 1e-4 of its value (a zero minimum is approached as ``d -> 0``, where
    ``H_tt`` becomes singular: this gets there in a few iterations).

    Where none is accepted: the reduced Newton step (the
    multipliers the full one sends below 0 held at 0, the model maximised over the others:
    Bertsekas' active set); the full step with no multiplier falling below 1e-4 of its value
    (a zero minimum is approached as ``d -> 0``, where ``H_tt`` becomes singular); the step
    shortened so that no multiplier loses more than 90 % of its value; then halvings.

    Returns:
        ``(batch, stalled)``; ``stalled`` (g,) marks bins where nothing was accepted (``d``
        kept).
    """
    g = bt.d.shape[-1]
    floor = bt.pt.phi - 1e-15 * (bt.kern.unit + np.abs(bt.pt.phi))
    usable = np.all(np.isfinite(secular), axis=0)
    if np.all(usable) and not compare:  # the common case: one evaluation of the whole batch
        cand = np.maximum(bt.d + secular, 0.0)
        trial = _evaluate(bt.kern, cand)
        accept = trial.ok & (trial.phi >= floor)
        if np.all(accept):
            return dataclasses.replace(bt, d=cand, pt=trial), np.zeros(g, dtype=bool)
    best_phi = np.full(g, -np.inf)
    d_new = bt.d.copy()
    out = bt.pt

    def offer(sel: np.ndarray, cand: np.ndarray) -> None:
        """Evaluate candidates ``cand`` ((m, len(sel))) at bins ``sel``; keep improvements."""
        nonlocal out
        trial = _evaluate(bt.kern.take(sel), cand)
        better = trial.ok & (trial.phi >= floor[sel]) & (trial.phi > best_phi[sel])
        if np.any(better):
            at = sel[better]
            best_phi[at] = trial.phi[better]
            d_new[:, at] = _cols(cand, better)
            out = _merge(out, _take(trial, better), at)

    if np.any(usable):
        sel = np.flatnonzero(usable)
        offer(sel, np.maximum(_cols(bt.d, sel) + _cols(secular, sel), 0.0))
    pending = np.arange(g) if compare else np.flatnonzero(~np.isfinite(best_phi))
    if pending.size == 0:
        return dataclasses.replace(bt, d=d_new, pt=out), np.zeros(g, dtype=bool)
    d_p = _cols(bt.d, pending)
    step_p = newton.step(pending)
    offer(pending, np.maximum(d_p + step_p, 0.0))
    offer(pending, np.maximum(d_p + newton.cauchy(pending), 0.0))
    if compare:
        offer(pending, np.maximum(d_p + step_p, 1e-4 * d_p))
    left = ~np.isfinite(best_phi[pending])
    pending, d_p, step_p = pending[left], _cols(d_p, left), _cols(step_p, left)
    shrinking = step_p < 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(
            shrinking & (d_p > 0.0), 0.9 * d_p / np.where(shrinking, -step_p, 1.0), 2.0
        )
    alpha = np.minimum(1.0, np.min(ratio, axis=0))
    for trial_no in range(BACKTRACKS):
        if pending.size == 0:
            break
        if trial_no == 0:  # reduced step: what the full one sends below 0 held at 0
            hit = (d_p + step_p < 0.0) & (d_p > 0.0)
            cand = np.maximum(d_p + newton.step(pending, bound=hit), 0.0)
        elif trial_no == 1:  # the full step, no multiplier below 1e-4 of its value
            cand = np.maximum(d_p + step_p, 1e-4 * d_p)
        else:  # ratio test, then halvings
            cand = np.maximum(d_p + alpha * step_p, 0.0)
            alpha = 0.5 * alpha
        offer(pending, cand)
        left = ~np.isfinite(best_phi[pending])
        pending, d_p, step_p, alpha = (
            pending[left],
            _cols(d_p, left),
            _cols(step_p, left),
            alpha[left],
        )
    stalled = np.zeros(g, dtype=bool)
    stalled[pending] = True
    return dataclasses.replace(bt, d=d_new, pt=out), stalled


# ------------------------------------------------------------------ witness


def _least_norm(lhs: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-norm solution of ``lhs w = rhs`` per bin, and its residual norm.

    Args:
        lhs: (ny, nw, g) complex.
        rhs: (ny, g) complex.
    """
    rs = _row_space(lhs, rhs)
    return rs.x0, rs.resid


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
        win: the same bins' :class:`_Window`.
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


def _inverse(a: np.ndarray) -> np.ndarray:
    """Inverse of a batch (n, n, g) by Gauss-Jordan without pivoting.

    Used for ``I - P11 Delta`` with ``||P11 Delta|| < 1`` (well-posed LFT), whose leading
    principal submatrices are all invertible, so no pivoting is needed.
    """
    n = a.shape[0]
    work = np.concatenate([a.astype(complex), np.broadcast_to(np.eye(n)[:, :, None], a.shape)], 1)
    for j in range(n):
        work[j] = work[j] / work[j, j]
        for i in range(n):
            if i != j:
                work[i] = work[i] - work[i, j] * work[j]
    return work[:, n:]


# ------------------------------------------------------------------ driver


@dataclass(frozen=True)
class _Part:
    """Solutions of a subset of bins (bin axis last), before the fallback.

    Attributes:
        lower, upper: (g,) float bounds on ``min ||W(n)||``.
        w, v, z: (nw, g), (nv, g), (nz, g) complex, the witness.
        dmat: (nv, nz, g) complex, block-diagonal Delta of the witness.
        feasible: (g,) bool, the output equation has a solution.
        settled: (g,) bool, certified and tight (else: fallback).
        iterations: Newton iterations of the slowest bin.
    """

    lower: np.ndarray
    upper: np.ndarray
    w: np.ndarray
    v: np.ndarray
    z: np.ndarray
    dmat: np.ndarray
    feasible: np.ndarray
    settled: np.ndarray
    iterations: int


def _tight(upper: np.ndarray, lower: np.ndarray, win: _Window, unknowns: np.ndarray) -> np.ndarray:
    """Bounds that meet: as solve_sdp's tightness test, plus 1e-10 of the bin's unknowns.

    (The extra term is round-off on a bin the nominal explains to a few ulps, where
    ``||Y - P23 U||`` is itself round-off.) A bin without a witness (``inf``) is not tight.
    """
    scale = np.sqrt(_sq(win.r).sum(axis=0))
    with np.errstate(invalid="ignore"):
        out: np.ndarray = np.isfinite(upper) & (
            upper - lower <= 1e-9 * (upper + scale) + 1e-10 * unknowns
        )
    return out


def _solve_on_forms(
    pt: np.ndarray,
    ut: np.ndarray,
    yt: np.ndarray,
    win: _Window,
    blocks: BlockStructure,
    *,
    nw: int,
    inv: np.ndarray | None,
    good: np.ndarray,
    coupled: bool,
    max_iter: int,
) -> _Part:
    """Bins solved on their homogenised forms (any structure): dual, witness, checks."""
    forms = _homogenise(pt, yt, win, blocks, nw=nw, inv=inv, good=good, coupled=coupled)
    res = _dual_ascent(_Kernel.of(forms), forms.active, forms.dscale, max_iter)
    x_cand = forms.rho * _matvec(forms.m, res.xh)
    lower = np.sqrt(np.maximum(res.phi, 0.0) * forms.a_scale) * forms.rho
    upper, w, v, z, dmat = _witness(
        pt, ut, yt, x_cand, blocks, nw=nw, inv=inv, good=good, coupled=coupled
    )
    tight = _tight(upper, lower, win, forms.rho)
    consistent = _lagrangian_agrees(
        pt, win, blocks, x=x_cand, res=res, forms=forms, coupled=coupled
    )
    return _Part(
        lower=lower,
        upper=upper,
        w=w,
        v=v,
        z=z,
        dmat=dmat,
        feasible=forms.feasible,
        settled=res.ok & tight & consistent,
        iterations=res.iterations,
    )


def _solve_in_v(
    win: _Window, blocks: BlockStructure, *, inv: np.ndarray, pmat: np.ndarray, max_iter: int
) -> _Part:
    """Bins solved by :class:`_VKernel` (``z = P13 U``, ``P22`` invertible): dual, witness.

    The witness is exact without a further solve: ``v'_i = Delta_i z_i`` (the clipped
    ``v_i``) and ``w = w0 - P v'``. The dual value is the Lagrangian evaluated at its
    minimiser; where ``H_tt`` is ill conditioned at the end (pivot ratio below 1e-12) the
    minimiser is not trusted and the bin falls back.

    Args:
        win: the bins' :class:`_Window`.
        blocks: block structure.
        inv: (nw, nw, g) complex, ``P22^-1``.
        pmat: (nw, nv, g) complex, ``P = P22^-1 P21``.
        max_iter: Newton iterations at most.
    """
    nz, nv = blocks.nz, blocks.nv
    g = inv.shape[-1]
    w0 = _matvec(inv, win.r)
    gram = _gram(pmat, pmat)
    b = (pmat.conj() * w0[:, None]).sum(axis=0)
    c = np.empty((blocks.n_blocks, g))
    for i, (vs, zs) in enumerate(zip(blocks.v_slices, blocks.z_slices, strict=True)):
        c[i] = _sq(win.zu[zs]).sum(axis=0)
        pin = ~win.active[i]  # forced block: v_i = 0
        if np.any(pin):
            gram[vs, :, pin] = 0.0
            gram[:, vs, pin] = 0.0
            for j in range(vs.start, vs.stop):
                gram[j, j, pin] = 1.0
            b[vs, pin] = 0.0
    zx = np.zeros((blocks.n_blocks, nv + 1, g), dtype=complex)
    zx[:, nv] = c
    kern = _VKernel(
        gram=gram,
        b=b,
        p=pmat,
        w0=w0,
        c=c,
        g_diag=np.ascontiguousarray(np.abs(np.diagonal(gram).real).T),
        zx=zx,
        unit=np.maximum(_sq(w0).sum(axis=0), TINY),
        blocks=blocks,
    )
    dscale = np.where(win.active, np.mean(kern.g_diag, axis=0), 0.0)
    res = _dual_ascent(kern, win.active, dscale, max_iter)
    v_c = res.xh[:nv]
    dmat = np.zeros((nv, nz, g), dtype=complex)
    v = np.empty_like(v_c)
    for i, (vs, zs) in enumerate(zip(blocks.v_slices, blocks.z_slices, strict=True)):
        vi, zi = v_c[vs], win.zu[zs]
        safe = c[i] > TINY  # ||z_i||^2
        zn2 = np.where(safe, c[i], 1.0)
        ratio = np.sqrt(_sq(vi).sum(axis=0) / zn2)
        shrink = np.where(safe, np.where(ratio > 1.0, 1.0 / np.maximum(ratio, TINY), 1.0), 0.0)
        dmat[vs, zs] = vi[:, None] * zi.conj()[None, :] * (shrink / zn2)
        v[vs] = vi * shrink  # Delta_i z_i
    w = w0 - _matvec(pmat, v)
    upper = np.sqrt(_sq(w).sum(axis=0))
    lower = np.sqrt(np.maximum(res.phi, 0.0))
    tight = _tight(upper, lower, win, np.sqrt(_sq(v_c).sum(axis=0) + _sq(w0).sum(axis=0)))
    return _Part(
        lower=lower,
        upper=upper,
        w=w,
        v=v,
        z=win.zu.copy(),
        dmat=dmat,
        feasible=np.ones(g, dtype=bool),
        # a positive bound needs a trustworthy minimiser; a bound of 0 holds regardless
        settled=res.ok & tight & ((res.cond >= 1e-12) | (res.phi <= 0.0)),
        iterations=res.iterations,
    )


def solve_fast(
    resp: PlantResponse,
    u: np.ndarray,
    y: np.ndarray,
    *,
    max_iter: int = 60,
    fallback: bool = True,
    compiled: bool = True,
    threads: int | None = None,
) -> FastSolutions:
    """Problem 3 at every bin of a window, batched (same outputs as :func:`solvers.solve_sdp`).

    Where the model's perturbation inputs do not depend on the unknowns (``z = P13 U``) and
    ``P22`` is square, every bin goes first through the compiled per-bin kernel
    (:mod:`twotank_validation.core.fast.kernel`), which answers the bins whose bounds meet; the
    rest, and every bin of other structures, go through the batched numpy dual, and what
    that leaves unsettled to the per-bin cvxpy reference.

    Args:
        resp: plant response, n_bins bins, at most :data:`MAX_BLOCKS` blocks.
        u: (n_bins, nu) complex.
        y: (n_bins, ny) complex.
        max_iter: Newton iterations at most for the batched dual ascent.
        fallback: hand unsettled bins to :func:`solvers.solve_sdp` (else they keep the
            batched answer, marked uncertified).
        compiled: use the compiled kernel where it applies (``False``: numpy only).
        threads: threads the kernel shares the bins among (default
            :data:`fastkernel.THREADS`; the result does not depend on it).

    Returns:
        Solutions (``method = "fast"``) and statistics (bins per route, fallbacks).
    """
    blocks = resp.blocks
    covered, why = coverage(blocks, resp.nw)
    if not covered:
        raise ValueError(f"fast path does not cover this structure: {why}")
    nb = u.shape[0]
    u_scale = _max_row_norm(u)
    coupled = resp.coupled
    if compiled and nb and kernel_applies(blocks, resp.nw, resp.ny, coupled=coupled):
        return _solve_compiled(
            resp, u, y, u_scale=u_scale, max_iter=max_iter, fallback=fallback, threads=threads
        )
    return _solve_batched(
        resp, u, y, u_scale=u_scale, coupled=coupled, max_iter=max_iter, fallback=fallback
    )


def warm_up(resp: PlantResponse) -> bool:
    """Load the compiled kernel for this structure now (compile it if this checkout never has).

    A live validator calls this at start-up, so that its first window does not wait for
    numba's cache (a fraction of a second) or a first compile (~30 s). Runs the kernel on
    one made-up bin of ``resp``; does nothing (and raises nothing) where the fast path does
    not cover the structure or the kernel does not take it.

    Returns:
        Whether the kernel applies to ``resp`` (and is now loaded).
    """
    applies = kernel_applies(resp.blocks, resp.nw, resp.ny, coupled=resp.coupled)
    if not resp.p.shape[0] or not applies or not coverage(resp.blocks, resp.nw)[0]:
        return False
    one = PlantResponse(resp.p[:1], resp.blocks, resp.nw, resp.nu, resp.ny)
    u = np.ones((1, resp.nu), dtype=complex)
    solve_fast(one, u, np.ones((1, resp.ny), dtype=complex), fallback=False)
    return True


def _solve_compiled(
    resp: PlantResponse,
    u: np.ndarray,
    y: np.ndarray,
    *,
    u_scale: float,
    max_iter: int,
    fallback: bool,
    threads: int | None,
) -> FastSolutions:
    """The compiled kernel on every bin, the batched numpy path on the bins it defers."""
    # imported here: numba is loaded only by a process that uses the kernel
    from twotank_validation.core.fast.kernel import DONE, KIND_DUAL, solve_window  # noqa: PLC0415

    blocks = resp.blocks
    nb = u.shape[0]
    out = solve_window(
        resp.p,
        u,
        y,
        u_scale=u_scale,
        blocks=blocks,
        nw=resp.nw,
        max_iter=max_iter,
        threads=threads,
    )
    done = out.status == DONE
    lower, upper, w, v, z = out.lower, out.upper, out.w, out.v, out.z
    delta = tuple(
        np.ascontiguousarray(out.dmat[:, vs, zs])
        for vs, zs in zip(blocks.v_slices, blocks.z_slices, strict=True)
    )
    certified = done.copy()
    fell_back = np.zeros(nb, dtype=bool)
    n_compiled = int(np.count_nonzero(done))
    n_direct = int(np.count_nonzero(done & (out.kind != KIND_DUAL)))
    n_dual = n_compiled - n_direct
    n_fallback = 0
    iterations = out.iterations
    deferred = np.flatnonzero(~done)
    if deferred.size:
        sub = PlantResponse(resp.p[deferred], blocks, resp.nw, resp.nu, resp.ny)
        rest = _solve_batched(
            sub,
            u[deferred],
            y[deferred],
            u_scale=u_scale,
            coupled=False,
            max_iter=max_iter,
            fallback=fallback,
        )
        rs = rest.solutions
        lower[deferred], upper[deferred] = rs.lower, rs.upper
        w[deferred], v[deferred], z[deferred] = rs.w, rs.v, rs.z
        for dst, src in zip(delta, rs.delta, strict=True):
            dst[deferred] = src
        certified[deferred] = rs.certified
        fell_back[deferred] = rest.fell_back
        n_direct += rest.stats.n_direct
        n_dual += rest.stats.n_dual
        n_fallback = rest.stats.n_fallback
        iterations = max(iterations, rest.stats.iterations)
    sol = solvers.BinSolutions(
        lower=lower,
        upper=upper,
        w=w,
        v=v,
        z=z,
        delta=delta,
        certified=certified,
        method=Method.FAST.value,
    )
    stats = FastStats(
        n_bins=nb,
        n_direct=n_direct,
        n_dual=n_dual,
        n_fallback=n_fallback,
        n_infeasible=int(np.count_nonzero(np.isinf(lower))),
        iterations=iterations,
        n_compiled=n_compiled,
        kernel_sized=out.sized,
    )
    return FastSolutions(solutions=sol, stats=stats, fell_back=fell_back, error=out.r)


def _solve_batched(
    resp: PlantResponse,
    u: np.ndarray,
    y: np.ndarray,
    *,
    u_scale: float,
    coupled: bool,
    max_iter: int,
    fallback: bool,
) -> FastSolutions:
    """Every bin on the batched numpy dual (``u_scale``: the window's largest ``||U||``)."""
    blocks = resp.blocks
    nb = u.shape[0]
    nz, nv, nw = blocks.nz, blocks.nv, resp.nw
    nx = nv + nw
    pt = np.ascontiguousarray(resp.p.transpose(1, 2, 0))
    ut, yt = np.ascontiguousarray(u.T), np.ascontiguousarray(y.T)
    win = _classify(pt, ut, yt, blocks, nw=nw, u_scale=u_scale, coupled=coupled)
    ny = resp.ny
    inv22: np.ndarray | None = None
    good22 = np.zeros(nb, dtype=bool)
    if nw == ny <= 3:
        inv22, good22 = _inverse_small(pt[nz:, nv:nx])
    lower = np.zeros(nb)
    upper = np.zeros(nb)
    settled = np.zeros(nb, dtype=bool)
    feasible = np.ones(nb, dtype=bool)
    w = np.zeros((nw, nb), dtype=complex)
    v = np.zeros((nv, nb), dtype=complex)
    z = win.zu.copy()
    dmat = np.zeros((nv, nz, nb), dtype=complex)
    # Bins where every block is forced (no excitation): v = 0, z = P13 U, Delta = 0 and w is
    # the least-norm solution of P22 w = Y - P23 U; exact, no dual needed. Bins the nominal
    # explains exactly (Y = P23 U) have the feasible point x = 0: minimum 0, no dual either.
    explained = ~np.any(win.r != 0.0, axis=0)
    unexcited = ~np.any(win.active, axis=0) & ~explained
    if inv22 is not None:
        easy = np.flatnonzero(unexcited & good22)
        w[:, easy] = _matvec(_cols(inv22, easy), _cols(win.r, easy))
        unexcited[easy] = False
        settled[easy] = True
    direct = np.flatnonzero(unexcited)
    if direct.size:
        r_dir = _cols(win.r, direct)
        rs = _row_space(_cols(pt[nz:, nv:nx], direct), r_dir)
        scale = np.sqrt(_sq(r_dir).sum(axis=0)) + np.sqrt(_sq(_cols(yt, direct)).sum(axis=0))
        feasible[direct] = rs.resid <= _CONSISTENCY_RTOL * (scale + TINY)
        w[:, direct] = rs.x0
        settled[direct] = True
    lower[settled] = upper[settled] = np.sqrt(_sq(_cols(w, settled)).sum(axis=0))
    settled[explained] = True  # lower = upper = 0, w = v = 0, Delta = 0, z = P13 U
    dual = np.flatnonzero(~settled)
    iterations = 0
    # bins solved in v itself (z fixed, P22 invertible and well conditioned), the others on
    # the homogenised forms
    v_route = np.zeros(nb, dtype=bool)
    pmat = None
    if dual.size and inv22 is not None and not coupled:
        cand = dual[good22[dual]]
        pmat = _matmul(_cols(inv22, cand), _cols(pt[nz:, :nv], cand))  # P22^-1 P21
        small = _sq(pmat).sum(axis=(0, 1)) <= NOISE_GAIN**2
        v_route[cand[small]] = True
        pmat = _cols(pmat, np.flatnonzero(small))
    for idx, route in (
        (np.flatnonzero(v_route), "v"),
        (np.flatnonzero(~settled & ~v_route), "forms"),
    ):
        if not idx.size:
            continue
        sub = _take_window(win, idx)
        inv_d = None if inv22 is None else _cols(inv22, idx)
        if route == "v":
            assert inv_d is not None
            assert pmat is not None
            part = _solve_in_v(sub, blocks, inv=inv_d, pmat=pmat, max_iter=max_iter)
        else:
            p_d, u_d, y_d = _cols(pt, idx), _cols(ut, idx), _cols(yt, idx)
            part = _solve_on_forms(
                p_d,
                u_d,
                y_d,
                sub,
                blocks,
                nw=nw,
                inv=inv_d,
                good=good22[idx],
                coupled=coupled,
                max_iter=max_iter,
            )
        iterations = max(iterations, part.iterations)
        lower[idx], upper[idx], feasible[idx], settled[idx] = (
            part.lower,
            part.upper,
            part.feasible,
            part.settled,
        )
        w[:, idx], v[:, idx], z[:, idx], dmat[..., idx] = part.w, part.v, part.z, part.dmat
    infeasible = ~feasible
    lower[infeasible] = upper[infeasible] = np.inf
    settled |= infeasible
    certified = settled.copy()
    lower = np.minimum(lower, upper)
    out_w, out_v, out_z = w.T.copy(), v.T.copy(), z.T.copy()
    delta = tuple(
        np.ascontiguousarray(dmat[vs, zs].transpose(2, 0, 1))
        for vs, zs in zip(blocks.v_slices, blocks.z_slices, strict=True)
    )
    back = np.flatnonzero(~settled)
    if back.size and fallback:
        one = PlantResponse(resp.p[back], blocks, nw, resp.nu, resp.ny)
        ref = solvers.solve_sdp(one, u[back], y[back], u_scale=u_scale)
        lower[back], upper[back] = ref.lower, ref.upper
        out_w[back], out_v[back], out_z[back] = ref.w, ref.v, ref.z
        for dst, src in zip(delta, ref.delta, strict=True):
            dst[back] = src
        certified[back] = ref.certified
    sol = solvers.BinSolutions(
        lower=lower,
        upper=upper,
        w=out_w,
        v=out_v,
        z=out_z,
        delta=delta,
        certified=certified,
        method=Method.FAST.value,
    )
    n_dual = int(np.sum(settled[dual] & feasible[dual]))
    stats = FastStats(
        n_bins=nb,
        n_direct=nb - n_dual - int(back.size),
        n_dual=n_dual,
        n_fallback=int(back.size),
        n_infeasible=int(np.count_nonzero(np.isinf(lower))),
        iterations=iterations,
    )
    return FastSolutions(solutions=sol, stats=stats, fell_back=~settled, error=win.r.T.copy())
