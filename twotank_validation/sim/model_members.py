"""The member Δ of a model's perturbation set, and the discrete state spaces of a simulation.

:class:`Member` chooses the member (``nominal``, ``gains``, ``random``; text form in
:func:`parse_member`); :func:`delta_system` builds it as a discrete system. The model's parts
are discretised and assembled into the generalised plant ``P: [v; w; u] -> [z; y]``
(:func:`discrete_plant`, transport delays as shift registers by :func:`undelay`), and the loop
``v = Δ z`` is closed (:func:`close_loop`). :func:`settling_periods` says how many periods the
transient from rest needs to die out. The simulation itself is
:mod:`twotank_validation.sim.model_plant`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from twotank_validation.core import lti
from twotank_validation.core.lti import StateSpace
from twotank_validation.core.model import LFTModel
from twotank_validation.errors import UnstableModelError
from twotank_validation.sim.model_faults import ModelSimError, _integer, _num, _real

__all__ = [
    "MAX_SETTLE_PERIODS",
    "MEMBER_KINDS",
    "SETTLE_TOL",
    "Member",
    "close_loop",
    "delta_system",
    "discrete_plant",
    "format_member",
    "parse_member",
    "settling_periods",
    "undelay",
]

FloatArray = NDArray[np.float64]

MEMBER_KINDS: Final = ("nominal", "gains", "random")
"""Members of the perturbation set :class:`Member` offers."""

SETTLE_TOL: Final = 1e-9
"""Automatic settling: periods until ``||A_cl^(k)||_2`` of the closed loop is below this."""

MAX_SETTLE_PERIODS: Final = 1000
"""Automatic settling refuses a closed loop that needs more periods than this."""


# --------------------------------------------------------------------------- members


@dataclass(frozen=True, kw_only=True)
class Member:
    """Which member Δ of the model's perturbation set the simulated plant is.

    Text form (:func:`parse_member`): ``nominal``, ``gains=G`` or ``gains=G1,G2,...`` (one
    per block), ``random`` with optional ``,seed=S`` and ``,scale=R``.

    Attributes:
        kind: ``"nominal"`` (Δ = 0: the nominal plant), ``"gains"`` (block i is the real
            gain ``gains[i]`` times the identity, ``Δ_i = δ_i I`` of the block's shape;
            a non-square block takes the rectangular identity), or ``"random"`` (each block a
            random stable discrete system, see :func:`delta_system`).
        gains: ``gains``: one δ_i per block, each in [-1, 1] (one value: the same for all).
        seed: ``random``: seed of the draw, >= 0.
        scale: ``random``: ``||Δ_i||∞`` of every block, in (0, 1].
    """

    kind: str = "nominal"
    gains: tuple[float, ...] = ()
    seed: int = 0
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in MEMBER_KINDS:
            raise ModelSimError(f"member kind={self.kind!r} is unknown; use one of {MEMBER_KINDS}")
        gains = tuple(self.gains) if isinstance(self.gains, Sequence) else (self.gains,)
        values = tuple(_real(f"member gains[{i}]", g) for i, g in enumerate(gains))
        if any(abs(g) > 1.0 for g in values):
            raise ModelSimError(
                f"member gains {list(values)} must lie in [-1, 1]: the model's set holds "
                "||Δ_i|| <= 1 only"
            )
        if self.kind == "gains" and not values:
            raise ModelSimError("member 'gains' needs at least one gain, e.g. gains=0.5")
        if self.kind != "gains" and values:
            raise ModelSimError(f"member {self.kind!r} takes no gains; use kind='gains'")
        object.__setattr__(self, "gains", values)
        object.__setattr__(self, "seed", _integer("member seed", self.seed, lo=0))
        scale = _real("member scale", self.scale, lo=0.0, lo_open=True)
        if scale > 1.0:
            raise ModelSimError(f"member scale={scale!r} must be <= 1 (||Δ||∞ <= 1)")
        object.__setattr__(self, "scale", scale)

    def block_gains(self, n_blocks: int) -> tuple[float, ...]:
        """The gain of each of ``n_blocks`` blocks (``gains`` member).

        Raises:
            ModelSimError: A count other than 1 or ``n_blocks``.
        """
        if len(self.gains) == 1:
            return self.gains * n_blocks
        if len(self.gains) != n_blocks:
            raise ModelSimError(
                f"member gains {list(self.gains)}: the model has {n_blocks} perturbation "
                "block(s); give one gain per block or one for all"
            )
        return self.gains


def parse_member(text: str) -> Member:
    """``"nominal"``, ``"gains=0.5,-1"``, ``"random"``, ``"random,seed=3,scale=0.8"`` -> Member.

    Raises:
        ModelSimError: Text of another form (the message shows the forms).
    """
    usage = (
        f"member {text!r}: write nominal, gains=G[,G...] (one per block, each in [-1, 1]) or "
        "random[,seed=S][,scale=R]"
    )
    if not isinstance(text, str):
        raise ModelSimError(usage)
    body = text.strip()
    if body == "nominal":
        return Member()
    try:
        if body.startswith("gains="):
            return Member(kind="gains", gains=tuple(float(g) for g in body[6:].split(",")))
        head, *options = body.split(",")
        if head != "random":
            raise ModelSimError(usage)
        kwargs: dict[str, float | int] = {}
        for opt in options:
            key, sep, value = opt.partition("=")
            if not sep or key.strip() not in ("seed", "scale") or key.strip() in kwargs:
                raise ModelSimError(usage)
            kwargs[key.strip()] = int(value) if key.strip() == "seed" else float(value)
        return Member(
            kind="random", seed=int(kwargs.get("seed", 0)), scale=float(kwargs.get("scale", 1.0))
        )
    except ValueError as err:
        raise ModelSimError(f"{usage} ({err})") from err


def format_member(member: Member) -> str:
    """Inverse of :func:`parse_member`."""
    if member.kind == "gains":
        return "gains=" + ",".join(_num(g) for g in member.gains)
    if member.kind == "random":
        return f"random,seed={member.seed},scale={_num(member.scale)}"
    return "nominal"


# --------------------------------------------------------------------------- state spaces


def _stack(
    parts: Sequence[tuple[StateSpace, FloatArray, FloatArray]], n_in: int, n_out: int, dt_s: float
) -> StateSpace:
    """Sum of paths ``M_out S M_in``: states stacked, ``(S, M_in, M_out)`` each."""
    a = scipy.linalg.block_diag(*[s.a for s, _, _ in parts]) if parts else np.zeros((0, 0))
    n = a.shape[0]
    b = np.zeros((n, n_in))
    c = np.zeros((n_out, n))
    d = np.zeros((n_out, n_in))
    row = 0
    for s, m_in, m_out in parts:
        k = s.n_states
        b[row : row + k] = s.b @ m_in
        c[:, row : row + k] = m_out @ s.c
        d += m_out @ s.d @ m_in
        row += k
    return StateSpace(a if n else np.zeros((0, 0)), b, c, d, dt_s)


def _series(first: StateSpace, second: StateSpace) -> StateSpace:
    """``second`` after ``first`` (discrete, delay-free)."""
    n1 = first.n_states
    a = np.block(
        [
            [first.a, np.zeros((n1, second.n_states))],
            [second.b @ first.c, second.a],
        ]
    )
    b = np.vstack([first.b, second.b @ first.d])
    c = np.hstack([second.d @ first.c, second.c])
    return StateSpace(a if a.size else np.zeros((0, 0)), b, c, second.d @ first.d, first.dt_s)


def undelay(sys: StateSpace) -> StateSpace:
    """A discrete system with its output delays turned into shift-register states.

    Output i delayed by d_i samples (``output_delays_s[i] / dt_s``) gets d_i states
    ``s_1(k+1) = [C x + D u]_i(k)``, ``s_j(k+1) = s_{j-1}(k)``, ``y_i = s_{d_i}``.

    Raises:
        ModelSimError: A delay that is not a whole number of samples (the time domain cannot
            hold the band-limited fractional delay the validator's frequency response uses).
    """
    if not sys.output_delays_s:
        return sys
    assert sys.dt_s is not None
    shifts = []
    for i, tau in enumerate(sys.output_delays_s):
        samples = tau / sys.dt_s
        if abs(samples - round(samples)) > 1e-9 * max(1.0, samples):
            raise ModelSimError(
                f"output {i} has a transport delay of {tau:g} s, not a whole number of samples "
                f"of ts_s={sys.dt_s:g}: simulate at a ts_s that divides it, or round the delay "
                "in the model file"
            )
        shifts.append(round(samples))
    n0, (p, m) = sys.n_states, sys.shape
    total = n0 + sum(shifts)
    a = np.zeros((total, total))
    b = np.zeros((total, m))
    c = np.zeros((p, total))
    d = np.zeros((p, m))
    a[:n0, :n0], b[:n0] = sys.a, sys.b
    pos = n0
    for i, k in enumerate(shifts):
        if k == 0:
            c[i, :n0], d[i] = sys.c[i], sys.d[i]
            continue
        a[pos, :n0], b[pos] = sys.c[i], sys.d[i]  # s_1(k+1) = (C x + D u)_i
        for j in range(1, k):
            a[pos + j, pos + j - 1] = 1.0
        c[i, pos + k - 1] = 1.0
        pos += k
    return StateSpace(a, b, c, d, sys.dt_s)


def _select(rows: int, cols: int, pairs: Sequence[tuple[int, int]]) -> FloatArray:
    m = np.zeros((rows, cols))
    for r, c in pairs:
        m[r, c] = 1.0
    return m


def discrete_plant(model: LFTModel, ts_s: float) -> StateSpace:
    """The generalised plant ``P: [v; w; u] -> [z; y]`` as one discrete, delay-free state space.

    Each continuous part is discretised at ``ts_s`` on its own by the model's hold (as
    :meth:`LFTModel.response`: zero-order hold, or first-order hold under ``intersample:
    foh``), so ``P(e^{jθ})`` equals ``model.response(θ, ts_s).p`` (for whole-sample delays).
    Under ``intersample: exact`` the parts are first-order-hold discretised too (a
    simulation needs a discrete system): ``P`` then differs from the exact response at the
    bins by the first-order hold's error (docs/theory.md §14). A structured model is the sum
    of its paths: the nominal G on u (into y and into the z of output-multiplicative
    blocks), per block its weight on v (into y, through G[:, S] for an input-multiplicative
    block) and its selection of u or G u into z, per noise channel its weight on w.

    Args:
        model: The model set.
        ts_s: Sample period, s.

    Returns:
        (nz + ny, nv + nw + nu) discrete state space with sample period ``ts_s``.

    Raises:
        ModelError: A discrete part with another sample period; a fractional delay.
    """
    nz, nv, nw, nu, ny = model.blocks.nz, model.blocks.nv, model.nw, model.nu, model.ny
    n_in, n_out = nv + nw + nu, nz + ny
    if model.generalized is not None:
        return undelay(lti.discretise(model.generalized, ts_s, model.intersample))
    assert model.nominal is not None
    g = undelay(lti.discretise(model.nominal, ts_s, model.intersample))
    u_cols = [nv + nw + j for j in range(nu)]
    y_rows = [nz + i for i in range(ny)]
    # the nominal on u, into y; output-multiplicative blocks read their z from this copy of G
    y_all = _select(n_out, ny, [(y_rows[i], i) for i in range(ny)])
    u_in = _select(nu, n_in, [(j, u_cols[j]) for j in range(nu)])
    g_out = y_all.copy()
    parts: list[tuple[StateSpace, FloatArray, FloatArray]] = []
    for pert, vs, zs in zip(
        model.perturbations, model.blocks.v_slices, model.blocks.z_slices, strict=True
    ):
        w = undelay(lti.discretise(pert.weight, ts_s, model.intersample))
        v_in = _select(w.shape[1], n_in, [(k, vs.start + k) for k in range(w.shape[1])])
        if pert.kind == "output_multiplicative":
            for k, o in enumerate(pert.outputs):
                g_out[zs.start + k, o] = 1.0  # z_i = E_S G u, from the nominal's copy of G
            y_sel = [(y_rows[o], k) for k, o in enumerate(pert.outputs)]
            parts.append((w, v_in, _select(n_out, w.shape[0], y_sel)))
            continue
        # z_i = E_in u: a static path
        z_sel = _select(n_out, nu, [(zs.start + k, j) for k, j in enumerate(pert.inputs)])
        parts.append((lti.static_gain(np.eye(nu), ts_s), u_in, z_sel))
        if pert.kind == "input_multiplicative":  # y += G E_S^T W v
            ins = list(pert.inputs)
            g_s = StateSpace(g.a, g.b[:, ins], g.c, g.d[:, ins], ts_s)
            parts.append((_series(w, g_s), v_in, y_all))
        else:  # additive: y[S_out] += W v
            y_sel = [(y_rows[o], k) for k, o in enumerate(pert.outputs)]
            parts.append((w, v_in, _select(n_out, w.shape[0], y_sel)))
    col = nv
    for ch in model.noise:
        w = undelay(lti.discretise(ch.weight, ts_s, model.intersample))
        k_in = w.shape[1]
        w_in = _select(k_in, n_in, [(k, col + k) for k in range(k_in)])
        y_sel = [(y_rows[o], k) for k, o in enumerate(ch.outputs)]
        parts.append((w, w_in, _select(n_out, w.shape[0], y_sel)))
        col += k_in
    return _stack([(g, u_in, g_out), *parts], n_in, n_out, ts_s)


def _random_allpass(rng: np.random.Generator, ts_s: float) -> StateSpace:
    """A stable first-order discrete all-pass ``(z^-1 - a) / (1 - a z^-1)``, |H(e^{jθ})| = 1."""
    a = float(rng.uniform(-0.9, 0.9))
    # H(z) = (1 - a z) / (z - a) = -a + (1 - a^2) / (z - a)
    return StateSpace(
        np.array([[a]]), np.array([[1.0]]), np.array([[1.0 - a * a]]), np.array([[-a]]), ts_s
    )


def delta_system(model: LFTModel, member: Member, ts_s: float) -> StateSpace:
    """The member Δ = diag(Δ_1 .. Δ_m) as one discrete state space ``z -> v`` (nv x nz).

    * ``nominal``: 0.
    * ``gains``: ``Δ_i = δ_i I`` (rectangular identity for a non-square block), static.
    * ``random``: ``Δ_i(z) = s Q_1 diag(g_k A_k(z)) Q_2`` with ``Q_1``, ``Q_2`` random
      orthogonal matrices (QR of a Gaussian matrix; a sign for 1 x 1), ``g_k`` uniform in
      [-1, 1] divided by the largest ``|g_k|``, ``A_k`` a random stable first-order all-pass
      (pole uniform in (-0.9, 0.9)). The singular values of ``Δ_i(e^{jθ})`` are ``s |g_k|``
      at every θ, so ``||Δ_i||∞ = s = scale`` exactly (no frequency grid) and Δ_i is
      stable. Drawn from ``default_rng(member.seed)``.

    Raises:
        ModelSimError: A ``gains`` member with the wrong number of gains.
    """
    shapes = model.blocks.shapes
    parts: list[tuple[StateSpace, FloatArray, FloatArray]] = []
    nv, nz = model.blocks.nv, model.blocks.nz
    if member.kind == "nominal" or not shapes:
        return lti.static_gain(np.zeros((nv, nz)), ts_s)
    rng = np.random.default_rng(member.seed)
    gains = member.block_gains(len(shapes)) if member.kind == "gains" else ()
    for i, ((rows, cols), vs, zs) in enumerate(
        zip(shapes, model.blocks.v_slices, model.blocks.z_slices, strict=True)
    ):
        m_in = _select(cols, nz, [(k, zs.start + k) for k in range(cols)])
        m_out = _select(nv, rows, [(vs.start + k, k) for k in range(rows)])
        if member.kind == "gains":
            parts.append((lti.static_gain(gains[i] * np.eye(rows, cols), ts_s), m_in, m_out))
            continue
        r = min(rows, cols)
        q1, q2 = _orthogonal(rng, rows), _orthogonal(rng, cols)
        g = rng.uniform(-1.0, 1.0, size=r)
        g /= np.max(np.abs(g))  # the largest |g_k| is 1: ||Δ_i||∞ = scale exactly
        for k in range(r):
            ap = _random_allpass(rng, ts_s)
            col_in = q2[k : k + 1, :]  # (1, cols): the k-th row of Q_2
            col_out = member.scale * g[k] * q1[:, k : k + 1]  # (rows, 1)
            parts.append((ap, col_in @ m_in, m_out @ col_out))
    return _stack(parts, nz, nv, ts_s)


def _orthogonal(rng: np.random.Generator, n: int) -> FloatArray:
    """A random n x n orthogonal matrix (QR of a Gaussian matrix, signs fixed: Haar)."""
    q, r = np.linalg.qr(rng.standard_normal((n, n)))
    return np.asarray(q * np.sign(np.diag(r))[None, :])


def close_loop(p: StateSpace, delta: StateSpace, nz: int, nv: int) -> StateSpace:
    """The upper LFT ``F_u(P, Δ)``: ``[w; u] -> y`` with ``v = Δ z``.

    Args:
        p: ``[v; w; u] -> [z; y]``, discrete, delay-free.
        delta: ``z -> v`` (nv x nz), discrete, delay-free, same sample period.
        nz: Rows of z in P's outputs (the first ones).
        nv: Columns of v in P's inputs (the first ones).

    Returns:
        The closed loop, states ``[x_P; x_Δ]``.

    Raises:
        ModelSimError: ``I - D11 D_Δ`` singular (the loop is not well posed).
        UnstableModelError: The closed loop is unstable for this member.
    """
    a, b, c, d = p.a, p.b, p.c, p.d
    b1, b2 = b[:, :nv], b[:, nv:]
    c1, c2 = c[:nz], c[nz:]
    d11, d12, d21, d22 = d[:nz, :nv], d[:nz, nv:], d[nz:, :nv], d[nz:, nv:]
    ad, bd, cd, dd = delta.a, delta.b, delta.c, delta.d
    np_, nd = p.n_states, delta.n_states
    loop = np.eye(nz) - d11 @ dd
    if nz and np.linalg.cond(loop) > 1e12:
        raise ModelSimError(
            "the loop v = Δ z is not well posed for this member (I - P11(∞) Δ(∞) is "
            "singular): choose smaller gains"
        )
    m = np.linalg.inv(loop) if nz else np.zeros((0, 0))
    # z = Zx [x_P; x_Δ] + Zq q,  v = Vx x + Vq q  (q = [w; u])
    zx = m @ np.hstack([c1, d11 @ cd])
    zq = m @ d12
    vx = np.hstack([np.zeros((nv, np_)), cd]) + dd @ zx
    vq = dd @ zq
    a_cl = np.vstack(
        [
            np.hstack([a, np.zeros((np_, nd))]) + b1 @ vx,
            np.hstack([np.zeros((nd, np_)), ad]) + bd @ zx,
        ]
    )
    b_cl = np.vstack([b2 + b1 @ vq, bd @ zq])
    c_cl = np.hstack([c2, np.zeros((c2.shape[0], nd))]) + d21 @ vx
    d_cl = d22 + d21 @ vq
    n = np_ + nd
    sys = StateSpace(a_cl if n else np.zeros((0, 0)), b_cl, c_cl, d_cl, p.dt_s)
    if n and np.max(np.abs(np.linalg.eigvals(sys.a))) >= 1.0 - 1e-9:
        raise UnstableModelError(
            "the simulated plant (the model closed with the chosen member Δ) is unstable: "
            "choose the nominal or smaller gains, or a model whose P11 has gain < 1"
        )
    return sys


def settling_periods(system: StateSpace, period_samples: int, tol: float = SETTLE_TOL) -> int:
    """Periods after which the transient from rest has decayed: ``||A^(p N)||_2 <= tol``.

    Args:
        system: The discrete closed loop.
        period_samples: N.
        tol: Relative size of the remaining transient.

    Returns:
        The smallest p >= 1 (0 for a static system).

    Raises:
        ModelSimError: More than :data:`MAX_SETTLE_PERIODS` periods would be needed (give
            ``settle_periods`` yourself, or lengthen the period).
    """
    if system.n_states == 0:
        return 0
    step = np.linalg.matrix_power(system.a, period_samples)
    power = step.copy()
    for p in range(1, MAX_SETTLE_PERIODS + 1):
        if np.linalg.norm(power, 2) <= tol:
            return p
        power = power @ step
    raise ModelSimError(
        f"the plant's transient needs more than {MAX_SETTLE_PERIODS} periods of "
        f"{period_samples} samples to decay by {tol:g}: lengthen the period or set "
        "settle_periods yourself"
    )
