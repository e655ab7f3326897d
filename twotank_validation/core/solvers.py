"""Per-bin solvers of Smith's Problem 3: the smallest ||W(n)|| that some ||Delta|| <= 1 pairs with.

At each DFT bin, with ``x = [v; w]`` and the datum ``(U, Y)``::

    minimise ||w||^2  s.t.  Y = P21 v + P22 w + P23 U,
                            z = P11 v + P12 w + P13 U,
                            ||v_i|| <= ||z_i||  for every block i.

For a full complex block, "some ``Delta_i`` with ``||Delta_i|| <= 1`` gives ``v_i = Delta_i z_i``"
is exactly ``||v_i|| <= ||z_i||`` (take ``Delta_i = v_i z_i^H / ||z_i||^2``), so each bin is a
non-convex quadratically constrained quadratic program. Two solvers:

* :func:`solve_closed_form` -- exact, when the problem decouples per output (scalar blocks,
  ``P11 = P12 = 0``, each output with at most one block and one noise entry; both tank models).
* :func:`solve_sdp` -- any block structure: the equality constraints are eliminated
  (``x = N t + x0``), the problem is homogenised to ``min xh^H A xh`` s.t.
  ``xh^H Q_i xh >= 0`` and a unit last coordinate, and the complex SDP relaxation is solved by
  cvxpy/Clarabel. It returns a lower bound certified by the dual multipliers, a rank-one
  witness ``(w, Delta)`` that gives an upper bound, and the gap. See docs/theory.md for why
  the bounds meet for one or two blocks.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from twotank_validation.core.columns import row_norm
from twotank_validation.core.model import BlockStructure, PlantResponse
from twotank_validation.defaults import Method

_RANK_RTOL = 1e-10
_NEGLIGIBLE_Z = 1e-10  # |z_i| below this fraction of the bin's unknowns counts as zero
_CONSISTENCY_RTOL = 1e-8
_TINY = 1e-300


@dataclass(frozen=True)
class BinSolutions:
    """Solutions of Problem 3 at every bin.

    Attributes:
        lower: (n_bins,) float, lower bound on min ||W(n)|| (exact for the closed form);
            ``inf`` where no (w, Delta) explains the bin.
        upper: (n_bins,) float, ||w|| of the feasible witness (``inf`` if none found).
        w: (n_bins, nw) complex, the witness unknown input W(n).
        v: (n_bins, nv) complex, the witness perturbation output V(n).
        z: (n_bins, nz) complex, the perturbation input Z(n) of the witness.
        delta: one (n_bins, rows_i, cols_i) complex array per block, ``||Delta_i|| <= 1``.
        certified: (n_bins,) bool, lower bound backed by a closed form or a dual certificate.
        method: ``"closed_form"`` or ``"sdp"``.
    """

    lower: np.ndarray
    upper: np.ndarray
    w: np.ndarray
    v: np.ndarray
    z: np.ndarray
    delta: tuple[np.ndarray, ...]
    certified: np.ndarray
    method: str

    @property
    def gap(self) -> np.ndarray:
        """(n_bins,) float, ``upper - lower`` (0 for the closed form)."""
        with np.errstate(invalid="ignore"):
            g = self.upper - self.lower
        return np.where(np.isfinite(self.upper) & np.isfinite(self.lower), g, 0.0)


# ------------------------------------------------------------------ shared helpers


def witness_from_delta(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, delta: tuple[np.ndarray, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-norm w explaining the datum for a fixed Delta (an exact feasible point).

    With ``S = (I - P11 Delta)^-1``, the datum needs
    ``(P22 + P21 Delta S P12) w = Y - P23 U - P21 Delta S P13 U``; the minimum-norm solution
    is taken. Bins where that system has no solution get ``||w|| = inf``.

    Args:
        resp: plant response, n_bins bins.
        u: (n_bins, nu) complex.
        y: (n_bins, ny) complex.
        delta: per block, (n_bins, rows_i, cols_i) complex.

    Returns:
        ``(w_norm, w, v, z)``: (n_bins,) float, (n_bins, nw), (n_bins, nv), (n_bins, nz).
    """
    nb = u.shape[0]
    blocks = resp.blocks
    dmat = np.zeros((nb, blocks.nv, blocks.nz), dtype=complex)
    for d, vs, zs in zip(delta, blocks.v_slices, blocks.z_slices, strict=True):
        dmat[:, vs, zs] = d
    eye = np.eye(blocks.nz)
    s = np.linalg.inv(eye[None] - resp.p11 @ dmat) if blocks.nz else np.zeros((nb, 0, 0))
    p21ds = resp.p21 @ dmat @ s
    lhs = resp.p22 + p21ds @ resp.p12
    rhs = y - _mv(resp.p23, u) - _mv(p21ds @ resp.p13, u)
    w = np.einsum("kij,kj->ki", np.linalg.pinv(lhs, rcond=_RANK_RTOL), rhs)
    resid = np.linalg.norm(_mv(lhs, w) - rhs, axis=1)
    scale = np.linalg.norm(rhs, axis=1) + np.linalg.norm(y, axis=1) + _TINY
    z = _mv(s, _mv(resp.p12, w) + _mv(resp.p13, u))
    v = _mv(dmat, z)
    w_norm = np.linalg.norm(w, axis=1)
    w_norm = np.where(resid <= 1e-7 * scale, w_norm, np.inf)
    return w_norm, w, v, z


def _mv(m: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Batched matrix-vector product: (n, a, b) @ (n, b) -> (n, a)."""
    return np.einsum("kij,kj->ki", m, x)


def rank_one_delta(v: np.ndarray, z: np.ndarray, blocks: BlockStructure) -> tuple[np.ndarray, ...]:
    """Smallest-norm Delta mapping z to v block by block, clipped to ||Delta_i|| <= 1.

    ``Delta_i = v_i z_i^H / ||z_i||^2`` has spectral norm ``||v_i|| / ||z_i||``; where
    ``z_i = 0`` the block is set to zero.

    Args:
        v: (n_bins, nv) complex.
        z: (n_bins, nz) complex.
        blocks: block structure.

    Returns:
        per block, (n_bins, rows_i, cols_i) complex.
    """
    out = []
    for vs, zs in zip(blocks.v_slices, blocks.z_slices, strict=True):
        vi, zi = v[:, vs], z[:, zs]
        zn2 = np.sum(np.abs(zi) ** 2, axis=1)
        safe = zn2 > _TINY
        d = np.einsum("ki,kj->kij", vi, zi.conj()) / np.where(safe, zn2, 1.0)[:, None, None]
        d[~safe] = 0.0
        norm = np.linalg.norm(vi, axis=1) / np.sqrt(np.where(safe, zn2, 1.0))
        shrink = np.where(norm > 1.0, 1.0 / np.maximum(norm, _TINY), 1.0)
        out.append(d * shrink[:, None, None])
    return tuple(out)


# ------------------------------------------------------------------ closed form


@dataclass(frozen=True)
class DecoupledStructure:
    """Which block and which noise entry act on each output (``-1``: none)."""

    block_of_output: np.ndarray
    noise_of_output: np.ndarray


def decoupled_structure(resp: PlantResponse) -> tuple[DecoupledStructure | None, str]:
    """Decide whether the closed form applies, and why not if it does not.

    Returns:
        ``(structure, reason)``; ``structure`` is ``None`` when the closed form does not apply.
    """
    blocks = resp.blocks
    if not blocks.all_scalar:
        return None, "a block is not scalar"
    if np.any(resp.p11) or np.any(resp.p12):
        return None, "z depends on v or w (P11 or P12 non-zero)"
    maps = []
    for part, what in ((resp.p21, "block"), (resp.p22, "noise entry")):
        pattern = np.any(part != 0, axis=0)  # (ny, n_cols)
        if np.any(pattern.sum(axis=0) > 1):
            return None, f"a {what} acts on more than one output"
        if np.any(pattern.sum(axis=1) > 1):
            return None, f"an output has more than one {what}"
        idx = np.full(resp.ny, -1)
        rows, cols = np.nonzero(pattern)
        idx[rows] = cols
        maps.append(idx)
    return DecoupledStructure(maps[0], maps[1]), "one scalar block and one noise entry per output"


def solve_closed_form(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, structure: DecoupledStructure
) -> BinSolutions:
    """Exact per-bin minimum for output-decoupled structures (vectorised over bins).

    Per output ``i`` with error ``e = Y_i - (P23 U)_i``, block gain ``a = P21[i, b]``,
    block input magnitude ``c = |(P13 U)_b|`` and noise gain ``g = P22[i, k]``:
    ``min |w_k| = max(0, |e| - |a| c) / |g|``, attained by ``v_b = c e |a| / (|e| a)``
    when ``|e| > |a| c`` and ``v_b = e / a`` otherwise (Smith 1995, Problem 3 with m
    independent scalar blocks).

    Args:
        resp: plant response.
        u: (n_bins, nu) complex.
        y: (n_bins, ny) complex.
        structure: from :func:`decoupled_structure`.
    """
    lower, w, v, z = closed_form_bins(resp, u, y, structure)
    return BinSolutions(
        lower=lower,
        upper=lower.copy(),
        w=w,
        v=v,
        z=z,
        delta=rank_one_delta(v, z, resp.blocks),
        certified=np.ones(u.shape[0], dtype=bool),
        method=Method.CLOSED_FORM.value,
    )


@dataclass(frozen=True)
class _OutputGains:
    """What the closed form takes from the response alone for one output.

    See :func:`closed_form_bins`: the block ``b`` and noise entry ``k`` acting on it (``-1``:
    none), ``a = P21[:, i, b]``, ``|a|``, ``|a| > 0``, ``a`` with 1 where it is 0, and the
    same of ``g = P22[:, i, k]``; ``all_block``, ``all_noise``: ``|a| > 0``, ``|g| > 0`` at
    every bin (then selecting where they vanish selects everything).
    """

    b: int
    k: int
    a: np.ndarray
    abs_a: np.ndarray
    ok: np.ndarray
    a_safe: np.ndarray
    g: np.ndarray
    has: np.ndarray
    g_safe: np.ndarray
    all_block: bool
    all_noise: bool


def _output_gains(resp: PlantResponse, structure: DecoupledStructure) -> tuple[_OutputGains, ...]:
    """The closed form's per-output gains, memoised on the response (they hold no datum)."""
    key = (
        "closed_form_gains",
        structure.block_of_output.tobytes(),
        structure.noise_of_output.tobytes(),
    )
    if key in resp.memo:
        gains: tuple[_OutputGains, ...] = resp.memo[key]
        return gains
    none: np.ndarray = np.zeros(0)
    out = []
    p21, p22 = resp.p21, resp.p22
    for i in range(resp.ny):
        b, k = int(structure.block_of_output[i]), int(structure.noise_of_output[i])
        a = abs_a = ok = a_safe = g = has = g_safe = none
        if b >= 0:
            a = p21[:, i, b]
            abs_a = np.abs(a)
            ok = abs_a > 0
            a_safe = np.where(ok, a, 1.0)
        if k >= 0:
            g = p22[:, i, k]
            has = np.abs(g) > 0
            g_safe = np.where(has, g, 1.0)
        out.append(
            _OutputGains(
                b, k, a, abs_a, ok, a_safe, g, has, g_safe, bool(np.all(ok)), bool(np.all(has))
            )
        )
    resp.memo[key] = gains = tuple(out)
    return gains


def _same_part(resp: PlantResponse, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``P13`` and ``P23`` (``a``, ``b``) hold the same bits, memoised on ``resp``.

    Then their products with the same ``U`` are the same bits too (the same numbers through
    the same loop: the two are views of ``p`` with the same strides).
    """
    key = "p13_is_p23"
    if key not in resp.memo:
        resp.memo[key] = (
            a.shape == b.shape and a.strides == b.strides and a.tobytes() == b.tobytes()
        )
    same: bool = resp.memo[key]
    return same


def closed_form_bins(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, structure: DecoupledStructure
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The closed form of :func:`solve_closed_form` without the perturbations Delta.

    What depends on the response alone (the gains, which of them vanish, and whether
    ``P13 = P23`` bit for bit, as for output-multiplicative blocks, so that ``P13 U`` is
    ``P23 U``) is computed at the first call and memoised on ``resp``.

    Returns:
        ``(lower, w, v, z)``: (n_bins,) float, (n_bins, nw), (n_bins, nv), (n_bins, nz)
        complex, as in :class:`BinSolutions`.
    """
    nb = u.shape[0]
    gains = _output_gains(resp, structure)
    p13 = resp.p13
    z = _mv(p13, u)  # P11 = P12 = 0
    e = y - (z if _same_part(resp, p13, resp.p23) else _mv(resp.p23, u))
    v = np.zeros((nb, resp.blocks.nv), dtype=complex)
    w = np.zeros((nb, resp.nw), dtype=complex)
    feasible = np.ones(nb, dtype=bool)
    for i, gain in enumerate(gains):
        b, k = gain.b, gain.k
        ei = e[:, i]
        mag_e = np.abs(ei)
        if b >= 0:
            a = gain.a
            reach = gain.abs_a * np.abs(z[:, b])
            ratio = np.where(mag_e > reach, reach / np.maximum(mag_e, _TINY), 1.0)
            vb = ei * ratio / gain.a_safe
            if not gain.all_block:
                vb = np.where(gain.ok, vb, 0.0)
            v[:, b] = vb
            rest = ei - a * vb
        else:
            rest = ei
        if k >= 0:
            w[:, k] = (
                rest / gain.g_safe
                if gain.all_noise
                else np.where(gain.has, rest / gain.g_safe, 0.0)
            )
            if not gain.all_noise:
                feasible &= ~(~gain.has & (np.abs(rest) > _CONSISTENCY_RTOL * (mag_e + _TINY)))
        else:
            feasible &= ~(np.abs(rest) > _CONSISTENCY_RTOL * (mag_e + _TINY))
    lower = np.where(feasible, row_norm(w), np.inf)
    return lower, w, v, z


# ------------------------------------------------------------------ SDP (general structure)


@dataclass(frozen=True)
class HomogenisedBin:
    """One bin after elimination of the equality constraints and homogenisation.

    ``x = [v; w] = rho * M @ xh`` with ``xh = [t; 1]``; ``||w||^2 = rho^2 xh^H A xh``;
    block constraints ``xh^H Q_i xh >= 0``. ``A`` and each ``Q_i`` are scaled to unit
    spectral norm (``a_scale`` restores the objective).

    Attributes:
        m: (nv + nw, d) complex.
        a: (d, d) complex Hermitian.
        q: (n_blocks, d, d) complex Hermitian.
        rho: variable scaling.
        a_scale: objective scaling.
        feasible: False when the output equation has no solution at all.
    """

    m: np.ndarray
    a: np.ndarray
    q: np.ndarray
    rho: float
    a_scale: float
    feasible: bool


def homogenise_bin(
    p: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    blocks: BlockStructure,
    nw: int,
    *,
    u_scale: float | None = None,
) -> HomogenisedBin:
    """Eliminate ``Y = P21 v + P22 w + P23 U`` and build the quadratic forms of one bin.

    A block whose input ``z_i`` does not depend on ``v, w`` (``P11``, ``P12`` rows zero) and is
    zero -- ``P13 U`` below 1e-12 of ``||P13|| u_scale`` (a bin the excitation does not reach)
    or below 1e-10 of the bin's least-norm unknowns (an input rolled off to round-off level) --
    forces ``v_i = 0``. That is added to the equality constraints instead of being left to the
    SDP, whose feasible set would otherwise have no interior. The second rule changes
    min ||W(n)|| by at most 1e-10 of the bin's scale times ``||P21|| / sigma_min(P22)``.

    Args:
        p: (nz + ny, nv + nw + nu) complex, P at this bin.
        u: (nu,) complex.
        y: (ny,) complex.
        blocks: block structure.
        nw: noise dimension.
        u_scale: largest ||U(n)|| of the window (defaults to this bin's ||U||).
    """
    nz, nv = blocks.nz, blocks.nv
    nx = nv + nw
    zu = p[:nz, nx:] @ u
    scale_u = float(np.linalg.norm(u)) if u_scale is None else u_scale
    p_norm = float(np.linalg.norm(p)) + _TINY
    # scale of the bin's unknowns: the least-norm solution of the output equation
    x_scale = float(
        np.linalg.norm(np.linalg.lstsq(p[nz:, :nx], y - p[nz:, nx:] @ u, rcond=None)[0])
    )
    forced = []
    for vs, zs in zip(blocks.v_slices, blocks.z_slices, strict=True):
        dep = float(np.linalg.norm(p[zs, :nx]))
        drive = float(np.linalg.norm(zu[zs]))
        unexcited = drive <= 1e-12 * float(np.linalg.norm(p[zs, nx:])) * scale_u
        negligible = drive <= _NEGLIGIBLE_Z * x_scale
        if dep <= 1e-13 * p_norm and (unexcited or negligible):
            forced.append(vs)
    rows = [p[nz:, :nx]]
    rhs = [y - p[nz:, nx:] @ u]
    for vs in forced:
        sel = np.zeros((vs.stop - vs.start, nx), dtype=complex)
        sel[:, vs] = np.eye(vs.stop - vs.start)
        rows.append(sel)
        rhs.append(np.zeros(vs.stop - vs.start, dtype=complex))
    bmat = np.concatenate(rows, axis=0)
    r = np.concatenate(rhs)
    # Balance each block's v against the size of its input z (|v_i| <= |z_i|): the SDP then
    # sees quadratic forms of comparable size even where the excitation is weak.
    col = np.ones(nx)
    for vs, zs in zip(blocks.v_slices, blocks.z_slices, strict=True):
        z_size = float(np.linalg.norm(zu[zs])) + float(np.linalg.norm(p[zs, :nx])) * x_scale
        col[vs] = min(1.0, max(z_size / max(x_scale, _TINY), 1e-150))
    bmat = bmat * col[None, :]
    uu, s, vh = np.linalg.svd(bmat, full_matrices=True)
    tol = _RANK_RTOL * max(bmat.shape) * (s[0] if s.size else 0.0)
    k = int(np.sum(s > tol)) if s.size else 0
    ur = uu[:, :k]
    x0 = col * (vh[:k].conj().T @ ((ur.conj().T @ r) / s[:k]))
    resid = r - ur @ (ur.conj().T @ r)
    feasible = bool(
        np.linalg.norm(resid) <= _CONSISTENCY_RTOL * (np.linalg.norm(r) + np.linalg.norm(y) + _TINY)
    )
    null = col[:, None] * vh[k:].conj().T  # (nx, nx - k)
    rho = max(float(np.linalg.norm(x0)), float(np.linalg.norm(zu)), _TINY)
    m = np.concatenate([null, (x0 / rho)[:, None]], axis=1)
    g = p[:nz, :nx] @ m
    g[:, -1] += zu / rho
    mw = m[nv:]
    a = mw.conj().T @ mw
    q = np.empty((blocks.n_blocks, m.shape[1], m.shape[1]), dtype=complex)
    for i, (vs, zs) in enumerate(zip(blocks.v_slices, blocks.z_slices, strict=True)):
        qi = g[zs].conj().T @ g[zs] - m[vs].conj().T @ m[vs]
        nq = np.linalg.norm(qi, 2)
        q[i] = qi / nq if nq > 0.0 else qi
    a_scale = max(float(np.linalg.norm(a, 2)), _TINY)
    return HomogenisedBin(m=m, a=a / a_scale, q=q, rho=rho, a_scale=a_scale, feasible=feasible)


def lagrangian_point(hb: HomogenisedBin, d: np.ndarray) -> np.ndarray | None:
    """Minimiser ``xh = [t; 1]`` of ``xh^H (A - sum d_i Q_i) xh``, or None if ``H_tt`` is not PD."""
    h = hb.a - np.einsum("i,ijk->jk", d, hb.q)
    htt, hts = h[:-1, :-1], h[:-1, -1]
    try:
        chol = np.linalg.cholesky(0.5 * (htt + htt.conj().T))
    except np.linalg.LinAlgError:
        return None
    if np.min(np.abs(np.diag(chol))) ** 2 < 1e-13 * max(1.0, float(np.abs(np.diag(htt)).max())):
        return None
    t = -np.linalg.solve(htt, hts)
    return np.concatenate([t, [1.0 + 0.0j]])


def _lagrangian_value(hb: HomogenisedBin, d: np.ndarray, xh: np.ndarray) -> float:
    """``xh^H (A - sum d_i Q_i) xh``: the dual function at d when xh is the Lagrangian minimiser."""
    h = hb.a - np.einsum("i,ijk->jk", d, hb.q)
    return float(np.real(xh.conj() @ h @ xh))


def polish_dual(
    hb: HomogenisedBin, d0: np.ndarray, max_iter: int = 50
) -> tuple[np.ndarray, np.ndarray] | None:
    """Refine block multipliers by projected Newton ascent on the concave dual.

    The dual function is ``phi(d) = min_t xh^H (A - sum d_i Q_i) xh`` with gradient
    ``-xh^H Q_i xh`` and Hessian ``-2 Re(R^H H_tt^-1 R)``, ``R = [(Q_i xh)_t]``. At a maximiser
    with ``H_tt`` positive definite, ``xh(d)`` is primal feasible and optimal (complementary
    slackness), so the SDP's first-order accuracy is raised to machine precision.

    Returns:
        ``(d, xh)`` or None when ``H_tt`` is singular at the optimum (the "hard case"; the
        caller keeps the SDP's own candidate).
    """
    d = np.maximum(np.asarray(d0, dtype=float), 0.0)
    m = d.size
    for _ in range(max_iter):
        xh = lagrangian_point(hb, d)
        if xh is None:
            return None
        qx = np.einsum("ijk,k->ij", hb.q, xh)  # (m, dim)
        g = np.real(np.einsum("j,ij->i", xh.conj(), qx))
        viol = np.maximum(-g, 0.0)
        comp = np.abs(d * g)
        if np.all(viol <= 1e-13) and np.all(comp <= 1e-13):
            return d, xh
        free = (d > 0) | (g < 0)
        if not np.any(free):
            return d, xh
        h = hb.a - np.einsum("i,ijk->jk", d, hb.q)
        r = qx[:, :-1].T  # (dim-1, m)
        hess = 2.0 * np.real(r.conj().T @ np.linalg.solve(h[:-1, :-1], r))  # = -Hessian of phi
        f = np.flatnonzero(free)
        try:
            step_f = np.linalg.solve(hess[np.ix_(f, f)], -g[f])  # ascent: d += (-Hphi)^-1 grad
        except np.linalg.LinAlgError:
            return None
        step = np.zeros(m)
        step[f] = step_f
        phi0 = _lagrangian_value(hb, d, xh)
        alpha = 1.0
        for _ls in range(40):
            cand = np.maximum(d + alpha * step, 0.0)
            xc = lagrangian_point(hb, cand)
            # accept when H_tt stays positive definite and the concave dual does not decrease
            if xc is not None and _lagrangian_value(hb, cand, xc) >= phi0 - 1e-15 * (
                1.0 + abs(phi0)
            ):
                break
            alpha *= 0.5
        else:
            return None
        d = cand
    xh = lagrangian_point(hb, d)
    return None if xh is None else (d, xh)


def dual_lower_bound(hb: HomogenisedBin, d: np.ndarray) -> float | None:
    """Certified lower bound on ``xh^H A xh`` from block multipliers ``d >= 0``.

    For every feasible ``xh`` (last entry 1), ``xh^H A xh >= xh^H H xh`` with
    ``H = A - sum_i d_i Q_i``, whose minimum over ``t`` is the Schur complement
    ``H_ss - H_st H_tt^+ H_ts`` when ``H_tt >= 0``. Returns ``None`` when ``H_tt`` is not
    positive semidefinite (no certificate from these multipliers).
    """
    h = hb.a - np.einsum("i,ijk->jk", np.maximum(d, 0.0), hb.q)
    h = 0.5 * (h + h.conj().T)
    htt, hts, hss = h[:-1, :-1], h[:-1, -1], h[-1, -1].real
    if htt.size == 0:
        return float(hss)
    ev, evec = np.linalg.eigh(htt)
    if ev[0] < -1e-12 * max(1.0, float(np.abs(ev).max())):
        return None
    proj = evec.conj().T @ hts
    keep = ev > 1e-12 * max(1.0, float(np.abs(ev).max()))
    if np.any(np.abs(proj[~keep]) > 1e-9 * (np.linalg.norm(hts) + 1.0)):
        return None  # H_ts has a component along a null direction of H_tt: unbounded below
    return float(hss - np.sum(np.abs(proj[keep]) ** 2 / ev[keep]))


class _SdpCache:
    """cvxpy problems parametrised by (A, Q_i), one per (dimension, number of blocks)."""

    def __init__(self) -> None:
        self._problems: dict[tuple[int, int], tuple[Any, Any, list[Any], Any, list[Any], Any]] = {}

    def get(self, d: int, m: int) -> tuple[Any, Any, list[Any], Any, list[Any], Any]:
        key = (d, m)
        if key not in self._problems:
            import cvxpy as cp  # noqa: PLC0415 (heavy import, only for the SDP path)

            a = cp.Parameter((d, d), hermitian=True)
            qs = [cp.Parameter((d, d), hermitian=True) for _ in range(m)]
            x = cp.Variable((d, d), hermitian=True)
            norm_con = cp.real(x[d - 1, d - 1]) == 1
            block_cons = [cp.real(cp.trace(q @ x)) >= 0 for q in qs]
            prob = cp.Problem(
                cp.Minimize(cp.real(cp.trace(a @ x))), [x >> 0, norm_con, *block_cons]
            )
            self._problems[key] = (prob, a, qs, x, block_cons, norm_con)
        return self._problems[key]


_CACHE = _SdpCache()


def solve_bin_sdp(hb: HomogenisedBin) -> tuple[float, bool, np.ndarray]:  # noqa: PLR0911
    """Solve the SDP relaxation of one homogenised bin, then polish it on the dual.

    Returns:
        ``(lower_scaled, certified, xh)``: a lower bound on ``xh^H A xh`` (scaled units),
        whether it is certified by dual multipliers, and the rank-one candidate ``xh``
        (last entry 1). A solver breakdown gives the trivial bound 0, uncertified.
    """
    import cvxpy as cp  # noqa: PLC0415

    d, m = hb.a.shape[0], hb.q.shape[0]
    trivial = np.concatenate([np.zeros(d - 1), [1.0]]).astype(complex)
    if d == 1 or m == 0:
        xh = trivial if d == 1 else lagrangian_point(hb, np.zeros(m))
        if xh is None:  # objective flat along some direction: any minimiser will do
            xh = np.concatenate([-np.linalg.pinv(hb.a[:-1, :-1]) @ hb.a[:-1, -1], [1.0]])
        return float(np.real(xh.conj() @ hb.a @ xh)), True, xh
    prob, a, qs, x, block_cons, _ = _CACHE.get(d, m)
    a.value = 0.5 * (hb.a + hb.a.conj().T)
    for q_par, qi in zip(qs, hb.q, strict=True):
        q_par.value = 0.5 * (qi + qi.conj().T)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "inaccurate" is handled by the dual polish below
            prob.solve(solver=cp.CLARABEL)
    except cp.error.SolverError:
        prob = None
    if prob is None or prob.status != "optimal":
        # Clarabel struggles when a block's input is tiny next to its output (a nearly
        # negative semidefinite Q_i, e.g. a weakly excited bin); the concave dual is then
        # maximised directly by projected Newton from a few starts.
        for start in (np.zeros(m), np.ones(m)):
            polished = polish_dual(hb, start, max_iter=200)
            if polished is not None:
                cert = dual_lower_bound(hb, polished[0])
                if cert is not None:
                    return cert, True, polished[1]
    if prob is not None and prob.status in ("infeasible", "infeasible_inaccurate"):
        # The relaxation is infeasible, hence so is the bin: no (w, Delta) explains it.
        return np.inf, prob.status == "infeasible", trivial
    if prob is None or prob.status not in ("optimal", "optimal_inaccurate") or x.value is None:
        return 0.0, False, trivial
    xv = 0.5 * (x.value + x.value.conj().T)
    ev, evec = np.linalg.eigh(xv)
    top = evec[:, -1] * np.sqrt(max(ev[-1], 0.0))
    xh_sdp = top / top[-1] if abs(top[-1]) > 1e-12 else trivial
    duals = np.array([float(np.real(c.dual_value)) for c in block_cons])
    polished = polish_dual(hb, duals)
    if polished is not None:
        d_opt, xh = polished
        cert = dual_lower_bound(hb, d_opt)
        if cert is not None:
            return cert, True, xh
    cert = dual_lower_bound(hb, duals)
    if cert is None:
        return float(prob.value), False, xh_sdp
    return cert, True, xh_sdp


def _pack_delta(delta: tuple[np.ndarray, ...]) -> np.ndarray:
    """Real parameters of a one-bin Delta.

    Scalar blocks: real and imaginary part (radially projected onto the unit disc); full
    blocks: ``M`` with ``Delta = M / sqrt(1 + ||M||_F^2)``.
    """
    parts: list[np.ndarray] = []
    for d in delta:
        if d.shape[1:] == (1, 1):
            parts.append(np.array([d[0, 0, 0].real, d[0, 0, 0].imag]))
        else:
            f = min(float(np.linalg.norm(d[0])), 1.0 - 1e-9)
            mat = d[0] / np.sqrt(max(1.0 - f * f, 1e-18))
            parts.extend([mat.real.ravel(), mat.imag.ravel()])
    return np.concatenate(parts) if parts else np.zeros(0)


def _unpack_delta(x: np.ndarray, blocks: BlockStructure) -> tuple[np.ndarray, ...]:
    out: list[np.ndarray] = []
    k = 0
    for r, c in blocks.shapes:
        if (r, c) == (1, 1):
            val = complex(x[k], x[k + 1])
            out.append(np.array([[[val / max(1.0, abs(val))]]]))
            k += 2
        else:
            n = r * c
            mat = (x[k : k + n] + 1j * x[k + n : k + 2 * n]).reshape(r, c)
            k += 2 * n
            out.append((mat / np.sqrt(1.0 + np.linalg.norm(mat) ** 2))[None])
    return tuple(out)


def refine_witness(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, delta: tuple[np.ndarray, ...]
) -> tuple[np.ndarray, ...]:
    """Local descent on ``||w(Delta)||^2`` over ``||Delta_i|| <= 1`` for one bin.

    Used only where the dual polish cannot recover the primal point (a singular Lagrangian
    Hessian, typically when the minimum is 0 and the optimal set is not a single point): the
    SDP's leading eigenvector is then a good start but not a minimiser. Any Delta it returns
    is feasible, so the upper bound stays valid whatever the descent does.

    Args:
        resp: plant response of one bin.
        u: (1, nu) complex.
        y: (1, ny) complex.
        delta: starting Delta, one (1, rows_i, cols_i) array per block.
    """
    from scipy.optimize import minimize  # noqa: PLC0415

    blocks = resp.blocks

    def objective(x: np.ndarray) -> float:
        val = witness_from_delta(resp, u, y, _unpack_delta(x, blocks))[0][0]
        return float(val * val) if np.isfinite(val) else 1e300

    x0 = _pack_delta(delta)
    bounds: list[tuple[float | None, float | None]] = []
    for r, c in blocks.shapes:
        bounds += [(-1.0, 1.0)] * 2 if (r, c) == (1, 1) else [(None, None)] * (2 * r * c)
    res = minimize(
        objective,
        x0,
        method="L-BFGS-B",
        bounds=bounds,
        options={"ftol": 1e-16, "gtol": 1e-14, "maxiter": 500},
    )
    return _unpack_delta(res.x, blocks) if res.fun < objective(x0) else delta


def solve_sdp(
    resp: PlantResponse,
    u: np.ndarray,
    y: np.ndarray,
    *,
    progress: Callable[[int], None] | None = None,
    u_scale: float | None = None,
) -> BinSolutions:
    """General solver: SDP relaxation per bin (cvxpy + Clarabel), bounds and rank-one witness.

    Args:
        resp: plant response, n_bins bins.
        u: (n_bins, nu) complex.
        y: (n_bins, ny) complex.
        progress: called with 1 after each bin (for a progress bar).
        u_scale: largest ||U(n)|| of the window (default: over these bins); pass it when
            solving a subset of a window's bins.
    """
    nb = u.shape[0]
    blocks = resp.blocks
    nv = blocks.nv
    lower = np.zeros(nb)
    certified = np.zeros(nb, dtype=bool)
    x_cand = np.zeros((nb, nv + resp.nw), dtype=complex)
    if u_scale is None:
        u_scale = float(np.max(np.linalg.norm(u, axis=1))) if nb else 0.0
    for n in range(nb):
        hb = homogenise_bin(resp.p[n], u[n], y[n], blocks, resp.nw, u_scale=u_scale)
        if not hb.feasible:
            lower[n] = np.inf
            certified[n] = True
        else:
            low_s, cert, xh = solve_bin_sdp(hb)
            lower[n] = (
                np.sqrt(max(low_s, 0.0) * hb.a_scale) * hb.rho if np.isfinite(low_s) else np.inf
            )
            certified[n] = cert
            x_cand[n] = hb.rho * (hb.m @ xh)
        if progress is not None:
            progress(1)
    v_c, w_c = x_cand[:, :nv], x_cand[:, nv:]
    z_c = _mv(resp.p11, v_c) + _mv(resp.p12, w_c) + _mv(resp.p13, u)
    delta = rank_one_delta(v_c, z_c, blocks)
    upper, w, v, z = witness_from_delta(resp, u, y, delta)
    scale = np.linalg.norm(y - _mv(resp.p23, u), axis=1)
    with np.errstate(invalid="ignore"):  # inf - inf on infeasible bins, excluded just after
        loose = np.flatnonzero(np.isfinite(lower) & ~(upper - lower <= 1e-9 * (upper + scale)))
    lower = np.where(np.isinf(lower), np.inf, lower)
    if loose.size:
        delta = tuple(d.copy() for d in delta)
        for n in loose.tolist():
            one = PlantResponse(resp.p[n : n + 1], blocks, resp.nw, resp.nu, resp.ny)
            better = refine_witness(
                one, u[n : n + 1], y[n : n + 1], tuple(d[n : n + 1] for d in delta)
            )
            for d, b in zip(delta, better, strict=True):
                d[n] = b[0]
        upper, w, v, z = witness_from_delta(resp, u, y, delta)
    upper = np.where(np.isinf(lower), np.inf, upper)
    lower = np.minimum(lower, upper)
    return BinSolutions(
        lower=lower,
        upper=upper,
        w=w,
        v=v,
        z=z,
        delta=delta,
        certified=certified,
        method=Method.SDP.value,
    )
