"""The batched dual ascent: every bin's Lagrangian dual maximised at once.

The dual is evaluated on homogenised forms (:class:`_Kernel`, built from
:class:`forms._Forms`) or, where ``z = P13 U`` and ``P22`` is invertible, in ``v`` itself
(:class:`_VKernel`); :func:`_dual_ascent` maximises it (a secular Newton step, then projected
Newton ascent with safeguards: :func:`_steps`, :func:`_advance`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from twotank_validation.core.fast.forms import _Forms
from twotank_validation.core.fast.linalg import (
    _chol_solve,
    _cholesky,
    _cols,
    _matvec,
    _solve_small,
    _sq,
)
from twotank_validation.core.fast.rules import (
    BACKTRACKS,
    FLAT_ITERATIONS,
    PHI_RUNAWAY,
    STARTS_NATURAL,
    STARTS_SCALED,
    TINY,
)
from twotank_validation.core.model import BlockStructure


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

    def pivot_rows(self, active: np.ndarray) -> np.ndarray | None:
        """The rows of ``H_tt`` whose pivots tell its conditioning: all (None)."""
        return None

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

    def pivot_rows(self, active: np.ndarray) -> np.ndarray:
        """(k, g) bool, the rows of ``H_tt`` whose pivots tell its conditioning.

        Those of the active blocks: a forced block's rows are identity rows, decoupled from
        the rest, whose pivot 1 says nothing of ``H_tt`` (beside a multiplier of 1e12, the
        pivot ratio would read as a singular ``H_tt``).

        Args:
            active: (m, g) bool, blocks not forced.
        """
        rows = np.zeros(self.b.shape, dtype=bool)
        for i, vs in enumerate(self.blocks.v_slices):
            rows[vs] = active[i]
        return rows

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
            ok_out, cond_out = ~runaway, _pivot_ratio(bt.pt, bt.kern.pivot_rows(bt.active))
            break
        if np.any(done):
            fin = live[done]
            d_out[:, fin], xh_out[:, fin] = _cols(bt.d, done), _cols(bt.pt.xh, done)
            phi_out[fin] = bt.pt.phi[done]
            ok_out[fin] = ~runaway[done]
            cond_out[fin] = _cols(_pivot_ratio(bt.pt, bt.kern.pivot_rows(bt.active)), done)
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
            cond_out[fin] = _cols(_pivot_ratio(bt.pt, bt.kern.pivot_rows(bt.active)), stalled)
            keep = np.flatnonzero(~stalled)
            if keep.size == 0:
                break
            live, bt, flat = live[keep], _take_batch(bt, keep), flat[keep]
    return _DualResult(d_out, xh_out, phi_out, ok_out, iterations, cond_out)


def _pivot_ratio(pt: _Point, rows: np.ndarray | None = None) -> np.ndarray:
    """(g,) float, smallest over largest squared Cholesky pivot of ``H_tt`` (conditioning).

    ``rows``: (k, g) bool, the pivots counted (None: all; see ``_VKernel.pivot_rows``).
    """
    piv = pt.diag * pt.diag
    if rows is None:
        small, large = np.min(piv, axis=0), np.max(piv, axis=0)
    else:
        rows = rows | ~np.any(rows, axis=0)  # no active block: every row (identity)
        small = np.min(np.where(rows, piv, np.inf), axis=0)
        large = np.max(np.where(rows, piv, 0.0), axis=0)
    out: np.ndarray = small / np.maximum(large, TINY)
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
