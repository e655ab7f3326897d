"""Compiled per-bin kernel of the fast path, for structured models (``z = P13 U``).

:func:`~twotank_validation.core.fast.dispatch.solve_fast` hands every bin of a window here
first when the model's perturbation inputs do not depend on the unknowns (``P11 = P12 = 0``: every
structured model, the tank models among them) and ``P22`` is square (``nw = ny``). Per bin,
in one compiled loop over the bins, this does what the batched numpy code does for the same
bins (the same rules and tolerances, see :mod:`twotank_validation.core.fast.dispatch`):

1. ``z = P13 U`` and ``r = Y - P23 U``; blocks with no excitation (``||P13_i U|| <= 1e-12
   ||P13_i||_F u_scale``) or a negligible one (below 1e-10 of the least-norm unknowns) are
   forced to ``v_i = 0``;
2. a bin the nominal explains exactly (``r = 0``) has minimum 0; a bin with every block
   forced has ``w = P22^-1 r`` (exact);
3. otherwise ``w = w0 - P v`` (``P = P22^-1 P21``, ``w0 = P22^-1 r``) and the bin is
   ``min ||w0 - P v||^2`` s.t. ``||v_i||^2 <= ||z_i||^2``; its Lagrangian dual (at most
   three multipliers) is maximised by the same ascent as :func:`dual._dual_ascent` (secular
   Newton step, then the best of secular, projected Newton, Cauchy and a floored step, then
   Bertsekas' reduced step and halvings), and the rank-one witness ``Delta_i = v_i z_i^H /
   ||z_i||^2`` (clipped to norm 1) with ``w = w0 - P Delta z`` is exactly feasible.

The dual value is a lower bound for any multipliers and the witness an upper bound, so a
bin is answered here only where the two meet (:func:`dispatch._tight`'s test) at a well
conditioned Lagrangian minimiser. Every other bin -- ``P22`` ill conditioned, a large
``P22^-1 P21``, an ill-conditioned output Gram matrix, no positive definite start, no
convergence, bounds that do not meet, non-finite data -- comes back with status
:data:`DEFER` and goes through the batched numpy path (and its per-bin cvxpy fallback).

Why compiled (numba) and hand-written: the batched numpy path spends its time on the
temporaries of a few hundred array operations over ``(rows, cols, n_bins)`` stacks; no
library solves thousands of tiny concave duals at once, and a loop over the bins in
Python costs more than the whole window. Here each bin's few-by-few matrices stay in
registers and small work buffers allocated once per call.

One source, two kinds of compiled kernel: the general one reads the dimensions from the
arrays; for the structures in :data:`SIZED` (the shipped tank models') the kernel is
compiled with the dimensions as constants (:func:`size_token`), which lets LLVM unroll the
few-by-few loops: ~30 % faster, bit-identical results. Each costs a compile of about half
a minute, once per checkout (numba's on-disk cache).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, TypeVar, cast

import numba
import numba.extending
import numpy as np

from twotank_validation.core.fast.rules import (
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
)
from twotank_validation.core.model import BlockStructure

F = TypeVar("F", bound=Callable[..., Any])


def _jit(fn: F) -> F:
    """``numba.njit`` with an on-disk cache (typed for mypy)."""
    return cast(F, numba.njit(cache=True, nogil=True, error_model="numpy")(fn))


def _inline(fn: F) -> F:
    """A helper of the kernel, inlined into its callers in numba's IR.

    LLVM does not inline these across numba's per-function modules: a call passing the
    work buffers cost more than the few-by-few arithmetic inside it.
    """
    return cast(F, numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(fn))


DONE = 0
"""Status: the bin is answered (bounds met)."""
DEFER = 1
"""Status: left to the batched numpy path."""

KIND_EXPLAINED = 0
"""The nominal explains the bin exactly (minimum 0)."""
KIND_DIRECT = 1
"""Every block forced: ``w = P22^-1 r``."""
KIND_DUAL = 2
"""Solved on the dual."""

_STARTS = np.array(STARTS_NATURAL + STARTS_SCALED)
_N_NATURAL = len(STARTS_NATURAL)


@_inline
def _abs2(x: complex) -> float:
    return x.real * x.real + x.imag * x.imag


@_inline
def _scale(x: complex, f: float) -> complex:
    """``x * f`` for a real ``f`` (numba would multiply, or divide, as complex numbers)."""
    return complex(x.real * f, x.imag * f)


@_inline
def _cholesky(h: Any, scale: Any, low: Any, diag: Any) -> bool:
    """``h = L L^H`` (lower triangle of ``h`` read); False where a pivot is round-off.

    ``low`` gets the strictly lower factor, ``diag`` the positive diagonal; a pivot below
    ``PIVOT_RTOL * scale[j]`` counts as singular (as ``linalg._cholesky``).
    """
    k = h.shape[0]
    for j in range(k):
        s = h[j, j].real
        for p in range(j):
            s -= _abs2(low[j, p])
        if not s > PIVOT_RTOL * scale[j]:
            return False
        dj = math.sqrt(s)
        diag[j] = dj
        for i in range(j + 1, k):
            acc = h[i, j]
            for p in range(j):
                acc -= low[i, p] * low[j, p].conjugate()
            low[i, j] = _scale(acc, 1.0 / dj)
    return True


@_inline
def _chol_solve(low: Any, diag: Any, b: Any, x: Any) -> None:
    """Solve ``L L^H x = b`` (``x`` and ``b`` may not alias)."""
    k = diag.shape[0]
    for i in range(k):
        acc = b[i]
        for j in range(i):
            acc -= low[i, j] * x[j]
        x[i] = _scale(acc, 1.0 / diag[i])
    for i in range(k - 1, -1, -1):
        acc = x[i]
        for j in range(i + 1, k):
            acc -= low[j, i].conjugate() * x[j]
        x[i] = _scale(acc, 1.0 / diag[i])


@_inline
def _inverse(a: Any, inv: Any, work: Any) -> bool:
    """Complex inverse by Gauss-Jordan with partial pivoting; False if singular."""
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            work[i, j] = a[i, j]
            inv[i, j] = 1.0 if i == j else 0.0
    for col in range(n):
        piv = col
        best = _abs2(work[col, col])
        for i in range(col + 1, n):
            m = _abs2(work[i, col])
            if m > best:
                best, piv = m, i
        if not best > 0.0:
            return False
        if piv != col:
            for j in range(n):
                work[col, j], work[piv, j] = work[piv, j], work[col, j]
                inv[col, j], inv[piv, j] = inv[piv, j], inv[col, j]
        f = 1.0 / work[col, col]
        for j in range(n):
            work[col, j] *= f
            inv[col, j] *= f
        for i in range(n):
            if i != col:
                e = work[i, col]
                if e != 0.0:
                    for j in range(n):
                        work[i, j] -= e * work[col, j]
                        inv[i, j] -= e * inv[col, j]
    return True


@_inline
def _frobenius_cond(a: Any, inv: Any) -> float:
    sa = 0.0
    si = 0.0
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            sa += _abs2(a[i, j])
            si += _abs2(inv[i, j])
    return math.sqrt(sa * si)


@_inline
def _solve_real(a: Any, b: Any, free: Any, x: Any, work: Any, idx: Any) -> bool:
    """``a[F, F] x[F] = b[F]`` on the free indices (``x = 0`` elsewhere); False if singular.

    Gaussian elimination with partial pivoting on the (at most 3 x 3) free part; ``work``
    (m, m + 1) float and ``idx`` (m,) int are scratch.
    """
    m = a.shape[0]
    f = 0
    for i in range(m):
        x[i] = 0.0
        if free[i]:
            idx[f] = i
            f += 1
    if f == 0:
        return True
    for r in range(f):
        for c in range(f):
            work[r, c] = a[idx[r], idx[c]]
        work[r, f] = b[idx[r]]
    for col in range(f):
        piv = col
        best = abs(work[col, col])
        for r in range(col + 1, f):
            if abs(work[r, col]) > best:
                best, piv = abs(work[r, col]), r
        if not best > 0.0:
            return False
        if piv != col:
            for c in range(f + 1):
                work[col, c], work[piv, c] = work[piv, c], work[col, c]
        for r in range(col + 1, f):
            e = work[r, col] / work[col, col]
            for c in range(col, f + 1):
                work[r, c] -= e * work[col, c]
    for r in range(f - 1, -1, -1):
        acc = work[r, f]
        for c in range(r + 1, f):
            acc -= work[r, c] * x[idx[c]]
        x[idx[r]] = acc / work[r, r]
    for r in range(f):  # noqa: SIM110 (no generator expressions in the kernel)
        if not math.isfinite(x[idx[r]]):
            return False
    return True


@_inline
def _newton_step(
    dnv2: Any, slack: Any, free: Any, newton: Any, amat: Any, rhs: Any, work: Any, idx: Any
) -> None:
    """The projected Newton step on the free multipliers (0 where it is singular).

    ``-H_FF step_F = g_F`` with ``H = dnv2`` (``d ||t_i||^2 / d d_j``) and gradient
    ``g = -slack``; ``rhs``, ``amat``, ``work`` and ``idx`` are scratch.
    """
    m = slack.shape[0]
    for i in range(m):
        rhs[i] = -slack[i]
        for j in range(m):
            amat[i, j] = -dnv2[i, j]
    if not _solve_real(amat, rhs, free, newton, work, idx):
        for i in range(m):
            newton[i] = 0.0


@_inline
def _evaluate(
    d: Any,
    gram: Any,
    gdiag: Any,
    b: Any,
    pm: Any,
    w0: Any,
    c: Any,
    vst: Any,
    vsp: Any,
    h: Any,
    sc: Any,
    low: Any,
    diag: Any,
    t: Any,
    nv2: Any,
) -> tuple[bool, float]:
    """The dual at ``d``: Lagrangian minimiser ``t``, ``||t_i||^2`` and the dual value.

    ``H = P^H P + sum_i d_i E_i^T E_i``, ``t = H^-1 P^H w0``, value ``||w0 - P t||^2 + sum_i
    d_i (||t_i||^2 - c_i)`` (the Lagrangian at its minimiser, as ``dual._VKernel``).
    Returns ``(ok, phi)``; ``ok`` is False where ``H`` is not numerically positive definite.
    """
    k = gram.shape[0]
    for i in range(k):
        sc[i] = gdiag[i]
        for j in range(i + 1):
            h[i, j] = gram[i, j]
    for blk in range(c.shape[0]):
        for p in range(vst[blk], vsp[blk]):
            h[p, p] += d[blk]
            sc[p] += d[blk]
    if not _cholesky(h, sc, low, diag):
        return False, 0.0
    _chol_solve(low, diag, b, t)
    phi = 0.0
    for r in range(pm.shape[0]):
        acc = w0[r]
        for p in range(k):
            acc -= pm[r, p] * t[p]
        phi += _abs2(acc)
    for blk in range(c.shape[0]):
        s = 0.0
        for p in range(vst[blk], vsp[blk]):
            s += _abs2(t[p])
        nv2[blk] = s
        phi -= d[blk] * (c[blk] - s)
    return math.isfinite(phi), phi


# Called, not inlined: the same helpers for the sites a bin rarely reaches (another start,
# backtracking, a 3 x 3 inverse). Every inlined copy grows the kernel numba must analyse,
# and its compile time grows faster than its size; the arithmetic, and so every bit of the
# answer, is the same either way.


@_jit
def _inverse_call(a: Any, inv: Any, work: Any) -> bool:
    """:func:`_inverse`, called."""
    return _inverse(a, inv, work)


@_jit
def _solve_real_call(a: Any, b: Any, free: Any, x: Any, work: Any, idx: Any) -> bool:
    """:func:`_solve_real`, called."""
    return _solve_real(a, b, free, x, work, idx)


@_jit
def _newton_step_call(
    dnv2: Any, slack: Any, free: Any, newton: Any, amat: Any, rhs: Any, work: Any, idx: Any
) -> None:
    """:func:`_newton_step`, called."""
    _newton_step(dnv2, slack, free, newton, amat, rhs, work, idx)


@_jit
def _evaluate_call(
    d: Any,
    gram: Any,
    gdiag: Any,
    b: Any,
    pm: Any,
    w0: Any,
    c: Any,
    vst: Any,
    vsp: Any,
    h: Any,
    sc: Any,
    low: Any,
    diag: Any,
    t: Any,
    nv2: Any,
) -> tuple[bool, float]:
    """:func:`_evaluate`, called."""
    return _evaluate(d, gram, gdiag, b, pm, w0, c, vst, vsp, h, sc, low, diag, t, nv2)


@_inline
def _noise_inverse(p: Any, n: int, nz: int, nv: int, p22: Any, inv22: Any, work22: Any) -> bool:
    """``inv22 = P22^-1`` at bin ``n``; False where ``P22`` is too ill-conditioned to eliminate."""
    nw = p22.shape[0]
    for i in range(nw):
        for j in range(nw):
            p22[i, j] = p[n, nz + i, nv + j]
    if nw == 2:  # written out (the common case): adjugate over determinant
        det = p22[0, 0] * p22[1, 1] - p22[0, 1] * p22[1, 0]
        size = _abs2(p22[0, 0]) + _abs2(p22[0, 1]) + _abs2(p22[1, 0]) + _abs2(p22[1, 1])
        # ||a||_F ||a^-1||_F = ||a||_F^2 / |det| for a 2 x 2 matrix
        if not size < NOISE_COND * math.sqrt(_abs2(det)):
            return False
        idet = 1.0 / det
        inv22[0, 0] = p22[1, 1] * idet
        inv22[0, 1] = -p22[0, 1] * idet
        inv22[1, 0] = -p22[1, 0] * idet
        inv22[1, 1] = p22[0, 0] * idet
        return True
    if not _inverse_call(p22, inv22, work22):
        return False
    return _frobenius_cond(p22, inv22) < NOISE_COND


@_inline
def _least_noise(inv22: Any, r: Any, w0: Any) -> float:
    """``w0 = P22^-1 r``; returns ``||w0||^2``."""
    nw = w0.shape[0]
    wn2 = 0.0
    for i in range(nw):
        acc = 0j
        for j in range(nw):
            acc += inv22[i, j] * r[j]
        w0[i] = acc
        wn2 += _abs2(acc)
    return wn2


def _dim(x: Any) -> int:
    """A dimension given as an int, or as a tuple whose length it is (see :func:`size_token`)."""
    return x if isinstance(x, int) else len(x)


@numba.extending.overload(_dim, inline="always")
def _dim_compiled(x: Any) -> Callable[[Any], int]:
    if isinstance(x, numba.types.Integer):

        def given(x: Any) -> Any:
            return x

        return given

    def length(x: Any) -> int:
        return len(x)  # a constant: the tuple's length is in its type

    return length


# The dual ascent of one bin (the rules of dual._dual_ascent) is written out inside
# solve_bins' loop: a call passing its ~40 work buffers cost more than the ascent itself.


@_jit
def solve_bins(
    p: Any,
    u: Any,
    y: Any,
    u_scale: float,
    sizes: Any,
    vst: Any,
    vsp: Any,
    zst: Any,
    zsp: Any,
    max_iter: int,
    lower: Any,
    upper: Any,
    w_out: Any,
    v_out: Any,
    dmat_out: Any,
    z_out: Any,
    r_out: Any,
    status: Any,
    kind: Any,
) -> int:
    """Every bin of a window (see the module doc); writes the outputs, returns iterations.

    Args:
        p: (n, nz + ny, nv + nw + nu) complex, P at the bins (``P11 = P12 = 0``, ny = nw).
        u: (n, nu) complex. y: (n, ny) complex.
        u_scale: largest ``||U(n)||`` of the window.
        sizes: ``(nz, nv, nw, nu, m)`` (m: number of blocks), as five ints or as
            :func:`size_token` (the kernel is then compiled for those dimensions).
        vst, vsp, zst, zsp: (m,) int, block slices of v and z.
        max_iter: Newton iterations at most.
        lower, upper: (n,) float out. w_out: (n, nw), v_out: (n, nv), dmat_out: (n, nv, nz),
            z_out: (n, nz), r_out: (n, ny) complex out (``r = Y - P23 U``).
        status: (n,) int8 out, :data:`DONE` or :data:`DEFER`. kind: (n,) int8 out.

    Returns:
        Newton iterations of the slowest bin answered on the dual.
    """
    nz = _dim(sizes[0])
    nv = _dim(sizes[1])
    nw = _dim(sizes[2])
    nu = _dim(sizes[3])
    m = _dim(sizes[4])
    nb = p.shape[0]
    ny = nw
    nx = nv + nw
    k = nv
    zu = np.empty(nz, dtype=np.complex128)
    r = np.empty(ny, dtype=np.complex128)
    drive = np.empty(m)
    active = np.zeros(m, dtype=np.bool_)
    gram_o = np.empty((ny, ny), dtype=np.complex128)
    inv_o = np.empty((ny, ny), dtype=np.complex128)
    work_o = np.empty((ny, ny), dtype=np.complex128)
    p22 = np.empty((nw, nw), dtype=np.complex128)
    inv22 = np.empty((nw, nw), dtype=np.complex128)
    pm = np.empty((nw, k), dtype=np.complex128)
    w0 = np.empty(nw, dtype=np.complex128)
    gram = np.empty((k, k), dtype=np.complex128)
    gdiag = np.empty(k)
    b = np.empty(k, dtype=np.complex128)
    c = np.empty(m)
    dscale = np.empty(m)
    d = np.empty(m)
    t = np.empty(k, dtype=np.complex128)
    nv2 = np.empty(m)
    h = np.zeros((k, k), dtype=np.complex128)
    sc = np.empty(k)
    low = np.zeros((k, k), dtype=np.complex128)
    diag = np.empty(k)
    tn = np.empty(k, dtype=np.complex128)
    nv2n = np.empty(m)
    lown = np.zeros((k, k), dtype=np.complex128)
    diagn = np.empty(k)
    cand = np.empty(m)
    best_d = np.empty(m)
    rhs = np.empty(k, dtype=np.complex128)
    ys = np.empty((m, k), dtype=np.complex128)
    dnv2 = np.empty((m, m))
    amat = np.empty((m, m))
    real_work = np.empty((m, m + 1))
    idx = np.empty(m, dtype=np.int64)
    free = np.zeros(m, dtype=np.bool_)
    red = np.zeros(m, dtype=np.bool_)
    slack = np.empty(m)
    sec = np.empty(m)
    newton = np.empty(m)
    step = np.empty(m)
    unexcited = np.empty(m, dtype=np.bool_)
    work22 = np.empty((nw, nw), dtype=np.complex128)
    vv = np.empty(k, dtype=np.complex128)
    worst = 0
    # Pass 1, a short loop over every bin: z and r, then the bins the nominal explains and
    # the bins with no block excited (w = P22^-1 r) are answered; the rest are listed for
    # pass 2. (One loop doing both ran each unexcited bin ~3x slower.)
    rest = np.empty(nb, dtype=np.int64)
    drives = np.empty((nb, m))
    unexcited_all = np.empty((nb, m), dtype=np.bool_)
    n_rest = 0
    for n in range(nb):
        status[n] = DEFER
        kind[n] = KIND_DUAL
        explained = True
        for i in range(nz):
            acc = 0j
            for j in range(nu):
                acc += p[n, i, nx + j] * u[n, j]
            z_out[n, i] = acc
        for i in range(ny):
            acc = y[n, i]
            for j in range(nu):
                acc -= p[n, nz + i, nx + j] * u[n, j]
            r_out[n, i] = acc
            if acc != 0.0:
                explained = False
        for i in range(nw):
            w_out[n, i] = 0.0
        for i in range(nv):
            v_out[n, i] = 0.0
            for j in range(nz):
                dmat_out[n, i, j] = 0.0
        if explained:
            lower[n] = upper[n] = 0.0
            status[n] = DONE
            kind[n] = KIND_EXPLAINED
            continue
        any_excited = False
        for blk in range(m):
            s = 0.0
            p13 = 0.0
            for i in range(zst[blk], zsp[blk]):
                s += _abs2(z_out[n, i])
                for j in range(nu):
                    p13 += _abs2(p[n, i, nx + j])
            drives[n, blk] = math.sqrt(s)
            unexcited_all[n, blk] = drives[n, blk] <= UNEXCITED * u_scale * math.sqrt(p13)
            any_excited = any_excited or not unexcited_all[n, blk]
        if any_excited:
            rest[n_rest] = n
            n_rest += 1
            continue
        # every block unexcited, hence forced: w = P22^-1 r, exact
        if not _noise_inverse(p, n, nz, nv, p22, inv22, work22):
            continue
        for i in range(ny):
            r[i] = r_out[n, i]
        wn2 = _least_noise(inv22, r, w0)
        for i in range(nw):
            w_out[n, i] = w0[i]
        lower[n] = upper[n] = math.sqrt(wn2)
        status[n] = DONE if math.isfinite(wn2) else DEFER
        kind[n] = KIND_DIRECT
    # Pass 2: the bins with an excited block
    for q_rest in range(n_rest):
        n = rest[q_rest]
        for i in range(nz):
            zu[i] = z_out[n, i]
        for i in range(ny):
            r[i] = r_out[n, i]
        for blk in range(m):
            drive[blk] = drives[n, blk]
            unexcited[blk] = unexcited_all[n, blk]
        x_scale = 0.0
        # ||x0||^2 = r^H (B B^H)^-1 r, B = [P21 P22] (some block is excited)
        for i in range(ny):
            for j in range(ny):
                acc = 0j
                for q in range(nx):
                    acc += p[n, nz + i, q] * p[n, nz + j, q].conjugate()
                gram_o[i, j] = acc
        if ny == 1:
            if not gram_o[0, 0].real > 0.0:
                continue
            x_scale = math.sqrt(_abs2(r[0]) / gram_o[0, 0].real)
        elif ny == 2:
            g00, g11, g01 = gram_o[0, 0].real, gram_o[1, 1].real, gram_o[0, 1]
            det = g00 * g11 - _abs2(g01)
            if not det > 1e-8 * g00 * g11:
                continue
            quad = (
                g11 * _abs2(r[0]) + g00 * _abs2(r[1]) - 2.0 * (r[0].conjugate() * g01 * r[1]).real
            )
            x_scale = math.sqrt(abs(quad) / det)
        else:
            if not _inverse_call(gram_o, inv_o, work_o):
                continue
            if not _frobenius_cond(gram_o, inv_o) < GRAM_COND:
                continue
            acc = 0j
            for i in range(ny):
                for j in range(ny):
                    acc += r[i].conjugate() * inv_o[i, j] * r[j]
            x_scale = math.sqrt(abs(acc.real))
        any_active = False
        for blk in range(m):
            active[blk] = not (unexcited[blk] or drive[blk] <= NEGLIGIBLE_Z * x_scale)
            any_active = any_active or active[blk]
        if not _noise_inverse(p, n, nz, nv, p22, inv22, work22):
            continue
        wn2 = _least_noise(inv22, r, w0)
        if not any_active:  # every block forced: w = P22^-1 r, exact
            for i in range(nw):
                w_out[n, i] = w0[i]
            lower[n] = upper[n] = math.sqrt(wn2)
            status[n] = DONE if math.isfinite(wn2) else DEFER
            kind[n] = KIND_DIRECT
            continue
        pn2 = 0.0
        for i in range(nw):
            for j in range(k):
                acc = 0j
                for q in range(nw):
                    acc += inv22[i, q] * p[n, nz + q, j]
                pm[i, j] = acc
                pn2 += _abs2(acc)
        if not pn2 <= NOISE_GAIN * NOISE_GAIN:
            continue
        for i in range(k):
            acc = 0j
            for q in range(nw):
                acc += pm[q, i].conjugate() * w0[q]
            b[i] = acc
            for j in range(k):
                acc = 0j
                for q in range(nw):
                    acc += pm[q, i].conjugate() * pm[q, j]
                gram[i, j] = acc
        for blk in range(m):
            s = 0.0
            for i in range(zst[blk], zsp[blk]):
                s += _abs2(zu[i])
            c[blk] = s
            if not active[blk]:  # forced block: v_i = 0
                for i in range(vst[blk], vsp[blk]):
                    b[i] = 0.0
                    for j in range(k):
                        gram[i, j] = 0.0
                        gram[j, i] = 0.0
                    gram[i, i] = 1.0
        mean_g = 0.0
        for i in range(k):
            gdiag[i] = abs(gram[i, i].real)
            mean_g += gdiag[i]
        mean_g /= k
        for blk in range(m):
            dscale[blk] = mean_g if active[blk] else 0.0
        unit = max(wn2, TINY)
        # ---- dual ascent (as dual._dual_ascent): on exit d, t, nv2, low, diag hold the
        # final point, ok_a says whether it is usable, its the Newton iterations
        ok_a = False
        phi = 0.0
        its = 0
        cond = 0.0
        for _once in range(1):
            for i in range(m):
                d[i] = 0.0
            ok, phi = _evaluate(d, gram, gdiag, b, pm, w0, c, vst, vsp, h, sc, low, diag, t, nv2)
            found = ok
            if not found:  # starts, as dual._starts: uniform, one block, all but one; then scaled
                n_sub = 1 + (m if m > 1 else 0) + (m if m > 2 else 0)
                for sub in range(n_sub + 1):
                    lo_s, hi_s = (0, _N_NATURAL) if sub < n_sub else (_N_NATURAL, _STARTS.size)
                    for si in range(lo_s, hi_s):
                        cs = _STARTS[si]
                        for i in range(m):
                            if sub == n_sub:
                                on = active[i]
                                d[i] = cs if on else 0.0
                                continue
                            if sub == 0:
                                on = True
                            elif sub <= m:
                                on = i == sub - 1
                            else:
                                on = i != sub - 1 - m
                            d[i] = cs * dscale[i] if on else 0.0
                        ok, phi = _evaluate_call(
                            d, gram, gdiag, b, pm, w0, c, vst, vsp, h, sc, low, diag, t, nv2
                        )
                        if ok:
                            found = True
                            break
                    if found:
                        break
            if not found:
                ok_a, phi, its, cond = False, 0.0, 0, 0.0
                break
            flat = 0
            iterations = 0
            done_ok = False
            for it in range(max_iter + 1):
                any_free = False
                feasible = True
                gap = 0.0
                for i in range(m):
                    slack[i] = c[i] - nv2[i]
                    free[i] = active[i] and (d[i] > 0.0 or slack[i] < 0.0)
                    any_free = any_free or free[i]
                    if active[i] and slack[i] < -1e-12 * (c[i] + nv2[i]):
                        feasible = False
                    gap += d[i] * abs(slack[i])
                runaway = phi > PHI_RUNAWAY * unit
                settled = (feasible and gap <= 1e-12 * abs(phi) + 1e-15 * unit) or not any_free
                if settled or flat >= FLAT_ITERATIONS or runaway:
                    done_ok = not runaway
                    break
                if it == max_iter:
                    break
                iterations = it + 1
                # derivatives: y_j = H^-1 (t restricted to block j) = -d t / d d_j
                for j in range(m):
                    if not free[j]:
                        continue
                    for pp in range(k):
                        rhs[pp] = 0.0
                    for pp in range(vst[j], vsp[j]):
                        rhs[pp] = t[pp]
                    _chol_solve(low, diag, rhs, ys[j])
                for i in range(m):
                    for j in range(m):
                        if not (free[i] and free[j]):
                            dnv2[i, j] = 0.0
                            continue
                        racc = 0.0
                        for pp in range(vst[i], vsp[i]):
                            racc += (t[pp].conjugate() * ys[j, pp]).real
                        dnv2[i, j] = -2.0 * racc  # d ||t_i||^2 / d d_j
                # secular Newton on 1/||t_i|| - 1/sqrt(c_i) = 0 (free blocks)
                sec_ok = True
                for i in range(m):
                    if free[i] and not (nv2[i] > 1e-200 and c[i] > 1e-200):
                        sec_ok = False
                if sec_ok:
                    for i in range(m):
                        iv = 1.0 / math.sqrt(nv2[i]) if free[i] else 0.0
                        for j in range(m):
                            amat[i, j] = -0.5 * iv * iv * iv * dnv2[i, j]
                        cand[i] = (1.0 / math.sqrt(c[i]) - iv) if free[i] else 0.0
                    sec_ok = _solve_real(amat, cand, free, sec, real_work, idx)
                if sec_ok:
                    ascent = 0.0
                    for i in range(m):
                        ascent += -slack[i] * (max(d[i] + sec[i], 0.0) - d[i])
                    sec_ok = ascent > 0.0
                newton_ready = False  # the projected Newton step, solved when first needed
                phi_before = phi
                floor = phi - 1e-15 * (unit + abs(phi))
                best_phi = -math.inf
                last_best = False
                compare = it > 0
                # candidates: 0 secular, 1 Newton, 2 Cauchy, 3 floored Newton (with compare)
                n_cand = 4 if compare else 3
                for which in range(n_cand):
                    if which == 0:
                        if not sec_ok:
                            continue
                        for i in range(m):
                            cand[i] = max(d[i] + sec[i], 0.0)
                    elif which == 1:
                        if not compare and best_phi > -math.inf:
                            break  # the secular step was accepted
                        if not newton_ready:  # (-Hessian) step = gradient on the free set
                            _newton_step(dnv2, slack, free, newton, amat, cand, real_work, idx)
                            newton_ready = True
                        for i in range(m):
                            cand[i] = max(d[i] + newton[i], 0.0)
                    elif which == 2:
                        curv = 0.0
                        gg = 0.0
                        for i in range(m):
                            gi = -slack[i] if free[i] else 0.0
                            gg += gi * gi
                            for j in range(m):
                                gj = -slack[j] if free[j] else 0.0
                                curv += gi * (-dnv2[i, j]) * gj
                        length = gg / curv if curv > 0.0 else 0.0
                        for i in range(m):
                            gi = -slack[i] if free[i] else 0.0
                            cand[i] = max(d[i] + length * gi, 0.0)
                    else:
                        for i in range(m):
                            cand[i] = max(d[i] + newton[i], 1e-4 * d[i])
                    okc, phic = _evaluate(
                        cand, gram, gdiag, b, pm, w0, c, vst, vsp, h, sc, lown, diagn, tn, nv2n
                    )
                    last_best = okc and phic >= floor and phic > best_phi
                    if last_best:
                        best_phi = phic
                        for i in range(m):
                            best_d[i] = cand[i]
                if best_phi == -math.inf:  # reduced step, floored step, ratio test and halvings
                    if not newton_ready:
                        _newton_step_call(dnv2, slack, free, newton, amat, cand, real_work, idx)
                        newton_ready = True
                    alpha = 1.0
                    for i in range(m):
                        if newton[i] < 0.0 and d[i] > 0.0:
                            alpha = min(alpha, 0.9 * d[i] / -newton[i])
                    for trial in range(BACKTRACKS):
                        if trial == 0:  # what the full step sends below 0 held at 0
                            for i in range(m):
                                hit = (d[i] + newton[i] < 0.0) and d[i] > 0.0
                                red[i] = free[i] and not hit
                                sec[i] = -d[i] if hit else 0.0  # the move of the held ones
                            for i in range(m):
                                racc = -slack[i]
                                for j in range(m):
                                    racc += dnv2[i, j] * sec[j]
                                    amat[i, j] = -dnv2[i, j]
                                cand[i] = racc
                            if not _solve_real_call(amat, cand, red, step, real_work, idx):
                                for i in range(m):
                                    step[i] = 0.0
                            for i in range(m):
                                cand[i] = max(d[i] + (step[i] if red[i] else sec[i]), 0.0)
                        elif trial == 1:
                            for i in range(m):
                                cand[i] = max(d[i] + newton[i], 1e-4 * d[i])
                        else:
                            for i in range(m):
                                cand[i] = max(d[i] + alpha * newton[i], 0.0)
                            alpha *= 0.5
                        okc, phic = _evaluate_call(
                            cand, gram, gdiag, b, pm, w0, c, vst, vsp, h, sc, lown, diagn, tn, nv2n
                        )
                        last_best = okc and phic >= floor
                        if last_best:
                            best_phi = phic
                            for i in range(m):
                                best_d[i] = cand[i]
                            break
                if best_phi == -math.inf:  # stalled: no ascent left, the witness judges
                    done_ok = True
                    break
                for i in range(m):
                    d[i] = best_d[i]
                if last_best:  # the last point evaluated: take its state
                    phi = best_phi
                    for pp in range(k):
                        t[pp] = tn[pp]
                        diag[pp] = diagn[pp]
                        for q in range(pp):
                            low[pp, q] = lown[pp, q]
                    for i in range(m):
                        nv2[i] = nv2n[i]
                else:
                    ok, phi = _evaluate_call(
                        d, gram, gdiag, b, pm, w0, c, vst, vsp, h, sc, low, diag, t, nv2
                    )
                    if not ok:  # cannot happen (the same point was accepted); be safe
                        ok_a, phi, its, cond = False, 0.0, iterations, 0.0
                        break
                gain = phi - phi_before
                flat = flat + 1 if gain <= 1e-14 * (unit + abs(phi_before)) else 0
            if not done_ok:
                ok_a, its, cond = False, iterations, 0.0
                break
            # the pivot ratio over the active blocks' rows: a forced block's rows are
            # identity rows, decoupled, whose pivot 1 says nothing of H_tt's conditioning
            # (beside a multiplier of 1e12 it would read as a singular H_tt)
            lo = math.inf
            hi = 0.0
            for blk in range(m):
                if not active[blk]:
                    continue
                for pp in range(vst[blk], vsp[blk]):
                    q = diag[pp] * diag[pp]
                    lo = min(lo, q)
                    hi = max(hi, q)
            ok_a, its, cond = True, iterations, lo / max(hi, TINY)

        ok = ok_a
        if not ok:
            continue
        # witness: Delta_i = v_i z_i^H / ||z_i||^2 clipped to norm 1, w = w0 - P Delta z
        vc2 = 0.0
        for i in range(k):
            vv[i] = 0.0
            vc2 += _abs2(t[i])
        for blk in range(m):
            zn2 = c[blk]
            safe = zn2 > TINY
            ratio = math.sqrt(nv2[blk] / zn2) if safe else 0.0
            shrink = (1.0 / max(ratio, TINY) if ratio > 1.0 else 1.0) if safe else 0.0
            for i in range(vst[blk], vsp[blk]):
                vv[i] = _scale(t[i], shrink)
                if safe:
                    for j in range(zst[blk], zsp[blk]):
                        dmat_out[n, i, j] = _scale(t[i] * zu[j].conjugate(), shrink / zn2)
        up2 = 0.0
        for i in range(nw):
            acc = w0[i]
            for j in range(k):
                acc -= pm[i, j] * vv[j]
            w_out[n, i] = acc
            up2 += _abs2(acc)
        for i in range(nv):
            v_out[n, i] = vv[i]
        up = math.sqrt(up2)
        lo = math.sqrt(max(phi, 0.0))
        rn = 0.0
        for i in range(ny):
            rn += _abs2(r[i])
        tight = math.isfinite(up) and (
            up - lo <= 1e-9 * (up + math.sqrt(rn)) + 1e-10 * math.sqrt(vc2 + wn2)
        )
        lower[n] = lo if lo <= up else up  # the two meet to round-off: never lower > upper
        upper[n] = up
        if tight and (cond >= 1e-12 or phi <= 0.0):
            status[n] = DONE
            worst = max(worst, its)
    return worst


def size_token(dims: tuple[int, ...]) -> tuple[tuple[int, ...], ...]:
    """``dims`` as tuples of zeros of those lengths (``sizes`` of :func:`solve_bins`).

    A tuple's length is part of its numba type: given these, the kernel is compiled (and
    cached on disk) for those dimensions alone, every loop bound and buffer shape a
    constant, so LLVM unrolls the few-by-few loops and indexes the buffers statically.
    Measured on the tank window: ~30 % less time than with the dimensions as ints (same
    arithmetic, bit-identical results).
    """
    return tuple((0,) * d for d in dims)


@dataclass(frozen=True)
class KernelOutput:
    """What :func:`solve_window` returns (bin axis first).

    Attributes:
        lower: (n,) float, certified lower bound on min ||w|| (valid where ``status`` is
            :data:`DONE`).
        upper: (n,) float, ``||w||`` of the witness.
        w: (n, nw) complex. v: (n, nv) complex. z: (n, nz) complex (``P13 U``).
        dmat: (n, nv, nz) complex, block-diagonal witness ``Delta``.
        r: (n, ny) complex, ``Y - P23 U`` (every bin).
        status: (n,) int8, :data:`DONE` or :data:`DEFER`.
        kind: (n,) int8, :data:`KIND_EXPLAINED`, :data:`KIND_DIRECT` or :data:`KIND_DUAL`.
        iterations: Newton iterations of the slowest bin answered on the dual.
        sized: whether the kernel compiled for these dimensions ran (:data:`SIZED`).
    """

    lower: np.ndarray
    upper: np.ndarray
    w: np.ndarray
    v: np.ndarray
    z: np.ndarray
    dmat: np.ndarray
    r: np.ndarray
    status: np.ndarray
    kind: np.ndarray
    iterations: int
    sized: bool = False


def solve_window(
    p: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    *,
    u_scale: float,
    blocks: BlockStructure,
    nw: int,
    max_iter: int,
    threads: int | None = None,
    sized: bool | None = None,
) -> KernelOutput:
    """Run the kernel on every bin of a window.

    The bins are independent: a window of at least ``2 * MIN_CHUNK`` bins is cut into
    contiguous chunks run at once in ``threads`` threads (the kernel releases the GIL); the
    result does not depend on the cut.

    Args:
        p: (n, nz + ny, nv + nw + nu) complex, P at the bins
            (:func:`~twotank_validation.core.fast.rules.kernel_applies` holds).
        u: (n, nu) complex.
        y: (n, ny) complex.
        u_scale: largest ``||U(n)||`` of the window.
        blocks: block structure.
        nw: noise dimension.
        max_iter: Newton iterations at most.
        threads: threads to use (default :data:`THREADS`).
        sized: run the kernel compiled for these dimensions (:func:`size_token`) rather
            than the general one; default: where the dimensions are in :data:`SIZED`. The
            results are the same to the bit.
    """
    n = p.shape[0]
    nz, nv = blocks.nz, blocks.nv
    ny = p.shape[1] - nz
    vst = np.array([s.start for s in blocks.v_slices], dtype=np.int64)
    vsp = np.array([s.stop for s in blocks.v_slices], dtype=np.int64)
    zst = np.array([s.start for s in blocks.z_slices], dtype=np.int64)
    zsp = np.array([s.stop for s in blocks.z_slices], dtype=np.int64)
    p = np.ascontiguousarray(p, dtype=complex)
    u = np.ascontiguousarray(u, dtype=complex)
    y = np.ascontiguousarray(y, dtype=complex)
    out = KernelOutput(
        lower=np.empty(n),
        upper=np.empty(n),
        w=np.empty((n, nw), dtype=complex),
        v=np.empty((n, nv), dtype=complex),
        z=np.empty((n, nz), dtype=complex),
        dmat=np.empty((n, nv, nz), dtype=complex),
        r=np.empty((n, ny), dtype=complex),
        status=np.empty(n, dtype=np.int8),
        kind=np.empty(n, dtype=np.int8),
        iterations=0,
    )

    nu = p.shape[2] - nv - nw
    dims = (nz, nv, nw, nu, blocks.n_blocks)
    sized = dims in SIZED if sized is None else sized
    sizes = size_token(dims) if sized else dims

    def run(a: int, b: int) -> int:
        return int(
            solve_bins(
                p[a:b],
                u[a:b],
                y[a:b],
                float(u_scale),
                sizes,
                vst,
                vsp,
                zst,
                zsp,
                int(max_iter),
                out.lower[a:b],
                out.upper[a:b],
                out.w[a:b],
                out.v[a:b],
                out.dmat[a:b],
                out.z[a:b],
                out.r[a:b],
                out.status[a:b],
                out.kind[a:b],
            )
        )

    n_chunks = max(1, min(threads or THREADS, n // MIN_CHUNK))
    cuts = [round(i * n / n_chunks) for i in range(n_chunks + 1)]
    if n_chunks == 1:
        iterations = run(0, n)
    else:
        pending = [_pool().submit(run, a, b) for a, b in itertools.pairwise(cuts[1:])]
        iterations = max([run(cuts[0], cuts[1]), *(f.result() for f in pending)])
    return dataclasses.replace(out, iterations=iterations, sized=sized)


def _default_threads() -> int:
    env = os.environ.get("TWOTANK_FAST_THREADS", "")
    if env.strip():
        try:
            return max(1, int(env))
        except ValueError:
            raise ValueError(
                f"TWOTANK_FAST_THREADS: {env.strip()!r} is not an integer (threads for the "
                "fast path's kernel)"
            ) from None
    return max(1, min(4, len(os.sched_getaffinity(0))))


THREADS = _default_threads()
"""Threads a window's bins are shared among: the CPUs this process may use, at most 4
(``TWOTANK_FAST_THREADS`` overrides; 1 runs everything in the calling thread)."""


def _sized_default() -> frozenset[tuple[int, ...]]:
    dims = {(2, 2, 2, 2, 2)}  # the tank models: two scalar blocks, two noises, two inputs
    for item in os.environ.get("TWOTANK_FAST_SIZED", "").split(";"):
        if not item.strip():
            continue
        try:
            entry = tuple(int(x) for x in item.split(","))
        except ValueError:
            entry = ()
        if len(entry) != 5 or min(entry) < 0:
            raise ValueError(
                f"TWOTANK_FAST_SIZED: {item.strip()!r} is not five non-negative integers "
                "nz,nv,nw,nu,m (entries separated by ';')"
            )
        dims.add(entry)
    return frozenset(dims)


SIZED = _sized_default()
"""Dimensions ``(nz, nv, nw, nu, number of blocks)`` that get a kernel compiled for them
(:func:`size_token`, ~30 % faster); every other structure runs the general kernel.
Each entry costs one more compile (~30 s, once per checkout, then cached on disk),
so the list holds the shipped models' structure; ``TWOTANK_FAST_SIZED="nz,nv,nw,nu,m;..."``
adds more."""
MIN_CHUNK = 256
"""Fewest bins worth a thread of their own."""


@functools.cache
def _pool() -> ThreadPoolExecutor:
    """The worker threads, started at first use (``THREADS - 1``: the caller runs a chunk)."""
    return ThreadPoolExecutor(max(1, THREADS - 1), thread_name_prefix="twotank-fast")


# a forked child has none of the parent's threads: it starts a pool of its own
os.register_at_fork(after_in_child=_pool.cache_clear)
