"""Batched small-matrix algebra of the fast path: every kernel runs over all bins at once.

All arrays keep the bin axis last: a batch of (r, c) matrices is an (r, c, g) array. Each
kernel (Cholesky, triangular solves, pivoted Gram-Schmidt, Cramer's rule, least-norm
solutions, Gauss-Jordan inverse) loops in Python over the few matrix entries while every
numpy operation runs over all bins (why: see :mod:`twotank_validation.core.fast.dispatch`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twotank_validation.core.fast.rules import GRAM_COND, NOISE_COND, PIVOT_RTOL, TINY

_RANK_RTOL = 1e-10  # as solvers._RANK_RTOL


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


def _least_norm(lhs: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-norm solution of ``lhs w = rhs`` per bin, and its residual norm.

    Args:
        lhs: (ny, nw, g) complex.
        rhs: (ny, g) complex.
    """
    rs = _row_space(lhs, rhs)
    return rs.x0, rs.resid


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
