"""Batched fast path for Problem 3: every bin of a window solved together with numpy.

The per-bin reference (:func:`twotank_validation.core.solvers.solve_sdp`) builds one cvxpy SDP per
DFT bin, a few milliseconds each. Here every bin's problem is solved on its Lagrangian dual

    phi(d) = min_x ||w||^2 - sum_i d_i (||z_i||^2 - ||v_i||^2),     d >= 0 (one per block),

a concave function of at most three variables, maximised for all bins at once (a secular
Newton step, then projected Newton ascent with safeguards; see :func:`dual._dual_ascent`). At the
maximiser, with the Lagrangian's Hessian positive definite, its minimiser is primal optimal
(complementary slackness): the dual value is a certified lower bound and the rank-one
``Delta`` built from the minimiser an exactly feasible witness, so the bounds meet. Two
parametrisations of the unknowns:

* bins where ``z = P13 U`` (``P11 = P12 = 0``: every structured model) and ``P22`` is
  square and well conditioned: ``w = P22^-1 (Y - P23 U - P21 v)``, the dual in ``v``
  itself (:class:`dual._VKernel`);
* any other bin: the equality constraints eliminated and the problem homogenised as in
  :func:`solvers.homogenise_bin` (``min xh^H A xh`` s.t. ``xh^H Q_i xh >= 0``), the dual on
  those forms (:class:`dual._Kernel`). See docs/theory.md, Sec. 4 and 6.

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

from dataclasses import dataclass

import numpy as np

from twotank_validation.core import solvers
from twotank_validation.core.fast.dual import _dual_ascent, _Kernel, _VKernel
from twotank_validation.core.fast.forms import (
    _CONSISTENCY_RTOL,
    _classify,
    _homogenise,
    _take_window,
    _Window,
)
from twotank_validation.core.fast.linalg import (
    _cols,
    _gram,
    _inverse_small,
    _matmul,
    _matvec,
    _max_row_norm,
    _row_space,
    _sq,
)
from twotank_validation.core.fast.rules import (  # the rules the compiled kernel shares
    NOISE_GAIN,
    TINY,
    kernel_applies,
)
from twotank_validation.core.fast.witness import _lagrangian_agrees, _witness
from twotank_validation.core.model import BlockStructure, PlantResponse
from twotank_validation.defaults import Method

MAX_BLOCKS = 3
"""Most blocks the fast path takes (the dual is exact for one or two, a bound for three)."""
MAX_UNKNOWNS = 16
"""Most unknowns ``nv + nw`` per bin (the kernels loop in Python over matrix entries)."""


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
            (:data:`kernel.SIZED`), not the general one.
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
    """Bins solved by :class:`dual._VKernel` (``z = P13 U``, ``P22`` invertible): dual, witness.

    The witness is exact without a further solve: ``v'_i = Delta_i z_i`` (the clipped
    ``v_i``) and ``w = w0 - P v'``. The dual value is the Lagrangian evaluated at its
    minimiser; where ``H_tt`` is ill conditioned at the end (pivot ratio below 1e-12) the
    minimiser is not trusted and the bin falls back.

    Args:
        win: the bins' :class:`forms._Window`.
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
            :data:`kernel.THREADS`; the result does not depend on it).

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
