"""A stable rational nominal fitted to a measured frequency response (docs/theory.md).

The model is continuous-time with poles common to every entry,

    ``G(s) = D + sum_i R_i / (s - p_i)``,  ``s = j 2 pi f``,

real poles and complex pairs (each pair stored once, ``Im p > 0``). Two steps:

1. **Start: vector fitting** (Gustavsen & Semlyen, IEEE Trans. Power Delivery 14 (1999)),
   weighted by ``1 / sigma`` per line and entry: starting pairs spread over the band, each
   iteration solves the linearised problem ``sigma(s) G(s) ~ H(s)`` by least squares and moves
   the poles to the zeros of ``sigma``; an unstable pole is reflected into the left half plane.
2. **Refinement: weighted nonlinear least squares** (the maximum-likelihood cost for a
   response with circular complex Gaussian errors of known variance, Pintelon & Schoukens
   2012, sec. 9.11): ``V = sum |H - G|^2 / var`` over the poles by
   ``scipy.optimize.least_squares``, the residues and ``D`` solved linearly inside it
   (variable projection) and the residual's exact Jacobian given (Golub & Pereyra 1973).
   Bounds keep every pole stable and every resonance inside ``1.2 x`` the band's top: the
   fit adds no dynamics outside the band.

Order selection compares the orders' costs by ``V (1 + n_par ln(n_eq) / n_eq)`` (Rissanen's
MDL as Pintelon & Schoukens 2012, sec. 11.4 use it); the chosen fit's cost against its
degrees of freedom says whether the response's own σ explains the residual.

Written by hand: scikit-rf's vector fitting fits square S-parameter networks without per-line
weights; scipy and python-control have no frequency-domain rational fit. ``least_squares`` does
the nonlinear part.

Units: frequencies in Hz, poles in rad/s, a response in output units per input unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize

from twotank_validation.core.lti import StateSpace
from twotank_validation.errors import IdentificationError
from twotank_validation.identify.nonparametric import FrequencyResponse

__all__ = ["RationalFit", "fit_rational", "select_order"]

_VF_ITERATIONS = 12
_VF_SETTLED = 1e-10
"""A vector-fitting iteration that moves no pole by more than this (relative) ends them."""
_PATIENCE = 2
"""Orders tried past the best supported one before the search stops."""
_TOP = 1.2
"""Largest resonance frequency of a fitted pair, relative to the band's top line."""
_GRAM_COND = 1e8
"""Largest condition number of the normal equations (scaled to a unit diagonal) solved as they
are (else a QR)."""
_SUPPORT = 3.0
"""A pole is supported when its standard deviation is below ``|p| / _SUPPORT``."""
_SLOWEST = 1e-2
"""Smallest decay rate of a pole, relative to the lowest line's angular frequency."""


@dataclass(frozen=True)
class RationalFit:
    """A fitted rational model and how well it explains the response.

    Attributes:
        poles: (n,) complex, rad/s: real poles, then one of each complex pair (``Im > 0``).
        pole_std: (n,) complex, rad/s: the standard deviation of each pole's real part (real
            component) and imaginary part (imaginary component), from the noise; NaN
            without σ.
        residues: (n, n_y, n_u) complex, output units per input unit times rad/s.
        d: (n_y, n_u) float, the feedthrough.
        cost: ``V = sum |H - G|^2 / var`` over lines and entries (``var`` the response's).
        n_eq: real equations (twice the complex ones).
        weighted: whether ``var`` came from the data (False: relative weights, no σ).
        top_rad_s: the highest line's angular frequency (rad/s), the band's top.
        slowest_rad_s: the smallest decay rate a pole may have (rad/s): a hundredth of the
            lowest line's angular frequency; slower poles are not seen by the data.
        delays_s: (n_y,) each output's transport delay (s; zeros when not fitted).
        delay_std_s: (n_y,) their standard deviations (s).
    """

    poles: np.ndarray
    pole_std: np.ndarray
    residues: np.ndarray
    d: np.ndarray
    cost: float
    n_eq: int
    weighted: bool
    top_rad_s: float
    slowest_rad_s: float
    delays_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    delay_std_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def order(self) -> int:
        """States per input: real poles count once, complex pairs twice."""
        return int(np.sum(np.where(np.abs(self.poles.imag) > 0, 2, 1)))

    @property
    def n_par(self) -> int:
        """Real parameters: the poles and every entry's residues and feedthrough."""
        n_y, n_u = self.d.shape
        n_tau = n_y if np.any(self.delays_s) else 0
        return self.order * (1 + n_y * n_u) + n_y * n_u + n_tau

    @property
    def dof(self) -> int:
        """Real degrees of freedom left for the noise."""
        return max(self.n_eq - self.n_par, 1)

    @property
    def cost_ratio(self) -> float:
        """``2 V / dof``: about 1 when the response's σ explains the residual.

        Each complex equation with a unit-variance circular error adds 1 to ``E V`` and 2
        real equations, so ``E V = dof / 2`` for a model that leaves only noise.
        """
        return 2.0 * self.cost / self.dof

    def response(self, freqs_hz: np.ndarray) -> np.ndarray:
        """(L, n_y, n_u) complex: the model at the frequencies."""
        s = 2j * np.pi * np.asarray(freqs_hz, dtype=float)
        out = np.broadcast_to(self.d.astype(complex), (s.size, *self.d.shape)).copy()
        for p, r in zip(self.poles, self.residues, strict=True):
            out += r[None] / (s[:, None, None] - p)
            if p.imag > 0:
                out += np.conj(r)[None] / (s[:, None, None] - np.conj(p))
        if self.delays_s.size and np.any(self.delays_s):
            out *= np.exp(-s[:, None, None] * self.delays_s[None, :, None])
        return out

    def state_space(self) -> StateSpace:
        """A real continuous state space of the fit (``order x n_u`` states).

        Each input has its own copy of the poles (a Gilbert realisation): minimal for one
        input, not for several.
        """
        a_blk, b_blk = _pole_blocks(self.poles)
        n_u = self.d.shape[1]
        coeff = _coefficients(self.poles, self.residues)  # (order, n_y, n_u)
        a = np.kron(np.eye(n_u), a_blk)
        b = np.kron(np.eye(n_u), b_blk[:, None])
        c = np.concatenate([coeff[:, :, j].T for j in range(n_u)], axis=1)
        delays = tuple(float(t) for t in self.delays_s) if np.any(self.delays_s) else ()
        return StateSpace(a, b, c, self.d.astype(float), output_delays_s=delays)

    @property
    def supported(self) -> bool:
        """Whether the data determine every pole inside the band.

        A pole inside the band (``|p|`` at most the band's top) is supported when its
        standard deviation is under a third of ``|p|`` and its decay rate is off the
        refinement's lower bound (a pair pinned there is a spike fitted to one line). Poles
        above the band shape the response's top and are not judged. True without σ, where
        nothing can be said.
        """
        if not self.weighted:
            return True
        inside = np.abs(self.poles) <= self.top_rad_s
        loose = np.abs(self.pole_std) >= np.abs(self.poles) / _SUPPORT
        pinned = -self.poles.real <= 2.0 * self.slowest_rad_s
        return not bool(np.any(inside & (loose | pinned)))

    def spurious(self, top_hz: float) -> list[complex]:
        """Lightly damped pairs (ζ < 0.3) resonating above ``1.2 x top_hz``."""
        out = []
        for p in self.poles:
            wn = abs(p)
            if p.imag > 0 and wn > _TOP * 2 * math.pi * top_hz and -p.real / wn < 0.3:
                out.append(complex(p))
        return out


def _pole_blocks(poles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The real realisation ``(A, b)`` of the partial-fraction basis.

    ``1/(s-a)`` per real pole; for a pair ``p = x + jy`` the block ``[[x, y], [-y, x]]`` with
    ``b = [2, 0]``, whose states give ``1/(s-p) + 1/(s-p*)`` and ``j/(s-p) - j/(s-p*)``.
    """
    blocks, bs = [], []
    for p in poles:
        if p.imag > 0:
            blocks.append(np.array([[p.real, p.imag], [-p.imag, p.real]]))
            bs.extend([2.0, 0.0])
        else:
            blocks.append(np.array([[p.real]]))
            bs.append(1.0)
    n = sum(b.shape[0] for b in blocks)
    a = np.zeros((n, n))
    i = 0
    for blk in blocks:
        k = blk.shape[0]
        a[i : i + k, i : i + k] = blk
        i += k
    return a, np.array(bs)


def _basis(s: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """(L, order) complex: the real-coefficient partial-fraction basis at ``s``."""
    cols = []
    for p in poles:
        if p.imag > 0:
            cols.append(1 / (s - p) + 1 / (s - np.conj(p)))
            cols.append(1j / (s - p) - 1j / (s - np.conj(p)))
        else:
            cols.append(1 / (s - p.real))
    return np.stack(cols, axis=1)


def _coefficients(poles: np.ndarray, residues: np.ndarray) -> np.ndarray:
    """(order, n_y, n_u) real basis coefficients of the residues (``R = c1 + j c2``)."""
    rows = []
    for p, r in zip(poles, residues, strict=True):
        if p.imag > 0:
            rows.extend([r.real, r.imag])
        else:
            rows.append(r.real)
    return np.stack(rows)


def _residues(poles: np.ndarray, coeff: np.ndarray) -> np.ndarray:
    out, i = [], 0
    for p in poles:
        if p.imag > 0:
            out.append(coeff[i] + 1j * coeff[i + 1])
            i += 2
        else:
            out.append(coeff[i].astype(complex))
            i += 1
    return np.stack(out)


def _ri(x: np.ndarray) -> np.ndarray:
    """Complex rows stacked as real rows: (2 L, ...)."""
    return np.concatenate([x.real, x.imag], axis=0)


@dataclass(frozen=True)
class _Projection:
    """The weighted linear problem at fixed poles, solved for every entry at once.

    Attributes:
        a: (E, 2 L, m) real, the weighted basis ``w_e Phi`` stacked real over imaginary.
        coef: (m, E) real, the coefficients (last row the feedthrough).
        resid: (L, E) complex, the weighted residual ``w (Phi c - h)``.
        gram: (E, m, m) the normal equations' matrix scaled to unit diagonal
            (``G / (d d^T)``) where they were solved; None where a QR was (``q``, ``r``).
        norms: (E, m) the columns' norms ``d``.
        q: (E, 2 L, m), r: (E, m, m): the QR of ``a`` when the normal equations were
            ill-conditioned; else None.
    """

    a: np.ndarray
    coef: np.ndarray
    resid: np.ndarray
    gram: np.ndarray | None
    norms: np.ndarray
    q: np.ndarray | None
    r: np.ndarray | None

    def removed(self, v: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(E, 2 L, K): ``v - A G^-1 (A^T v + t)`` per entry (``G = A^T A``).

        The variable-projection Jacobian's columns (Golub & Pereyra 1973): ``v`` (E, 2 L, K)
        less its projection on the basis, less ``(A^+)^T t`` for ``t`` (E, m, K).
        """
        if self.gram is not None:
            d = self.norms[:, :, None]
            z = np.linalg.solve(self.gram, (self.a.transpose(0, 2, 1) @ v + t) / d) / d
            out: np.ndarray = v - self.a @ z
            return out
        assert self.q is not None
        assert self.r is not None
        qt = self.q.transpose(0, 2, 1)
        # (A^+)^T t = Q R^-T t
        zt = np.linalg.solve(self.r.transpose(0, 2, 1), t)
        out = v - self.q @ (qt @ v) - self.q @ zt
        return out


def _stack(x: np.ndarray) -> np.ndarray:
    """(E, L, ...) complex as (E, 2 L, ...) real: real parts over imaginary ones."""
    return np.concatenate([x.real, x.imag], axis=1)


def _project(phi: np.ndarray, h: np.ndarray, w: np.ndarray) -> _Projection:
    """The weighted least-squares coefficients of every entry on the basis ``phi``.

    Args:
        phi: (L, m) complex, the basis (the last column the feedthrough's ones).
        h: (L, E) complex, the entries.
        w: (L, E) float, weights ``1 / sigma``.
    """
    wt = np.ascontiguousarray(w.T)[:, :, None]  # (E, L, 1)
    a = np.concatenate([wt * phi.real[None], wt * phi.imag[None]], axis=1)  # (E, 2L, m)
    b = _stack((w * h).T[:, :, None])  # (E, 2L, 1)
    at = a.transpose(0, 2, 1)
    # every entry's problem by its normal equations A^T A c = A^T b (m x m per entry: numpy's
    # lstsq, an SVD per entry, took most of a fit's time; a QR of the tall A is as slow on a
    # machine with threaded BLAS); a batched QR where they are ill-conditioned
    gram = at @ a
    # scaled to unit columns (a slow pole's column is far larger than a fast one's): the
    # scaled matrix's condition decides and its solve loses no more than it says
    d = np.sqrt(np.diagonal(gram, axis1=1, axis2=2))  # (E, m)
    scaled = gram / (d[:, :, None] * d[:, None, :]) if np.all(d > 0) else None
    if scaled is not None and np.max(np.linalg.cond(scaled)) < _GRAM_COND:
        coef = (np.linalg.solve(scaled, (at @ b) / d[:, :, None]) / d[:, :, None])[:, :, 0].T
        q = r = None
        kept: np.ndarray | None = scaled
    else:
        q, r = np.linalg.qr(a)
        coef = np.linalg.solve(r, q.transpose(0, 2, 1) @ b)[:, :, 0].T
        kept = None
    resid = w * (phi @ coef - h)
    return _Projection(a, coef, resid, kept, d, q, r)


def _linear(
    s: np.ndarray, h: np.ndarray, w: np.ndarray, poles: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residues, feedthrough and weighted residual at fixed poles.

    Args:
        s: (L,) complex, ``j omega`` (scaled).
        h: (L, E) complex, the entries.
        w: (L, E) float, weights ``1 / sigma``.
        poles: (n,) complex, scaled.

    Returns:
        coefficients (order + 1, E) real (last row the feedthrough), the weighted complex
        residual (L, E), the basis (L, order + 1).
    """
    phi = np.concatenate([_basis(s, poles), np.ones((s.size, 1))], axis=1)
    proj = _project(phi, h, w)
    return proj.coef, proj.resid, phi


def _augmented(full: np.ndarray, phi: np.ndarray, w: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(E, 2 L, k + n + 1) real: ``[w full, -w h phi, w h]`` per entry, real over imaginary rows.

    Filled block by block from real parts (the same numbers as stacking the complex blocks,
    without their complex temporaries).
    """
    lines, k, n = phi.shape[0], full.shape[1], phi.shape[1]
    wt, wh = np.ascontiguousarray(w.T), np.ascontiguousarray((w * h).T)  # (E, L)
    out = np.empty((wt.shape[0], 2 * lines, k + n + 1))
    out[:, :lines, :k] = wt[:, :, None] * full.real[None]
    out[:, lines:, :k] = wt[:, :, None] * full.imag[None]
    prod = wh[:, :, None] * phi[None]
    out[:, :lines, k : k + n] = -prod.real
    out[:, lines:, k : k + n] = -prod.imag
    out[:, :lines, -1] = wh.real
    out[:, lines:, -1] = wh.imag
    return out


def _vf_step(s: np.ndarray, h: np.ndarray, w: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """One vector-fitting pole relocation: the zeros of ``sigma(s) = 1 + sum c_i phi_i``.

    Per entry ``e`` the linearised problem ``[w full, -w h phi] [c_e; c_sigma] ~ w h`` is
    reduced to ``c_sigma``'s rows: the block ``R22`` and right-hand side ``r2`` of the
    triangular factor of ``[A1 A2 b]`` (``A1`` the entry's own columns). The factor comes
    from the Cholesky factor of the normal equations (the same ``R`` as a QR's, up to the
    rows' signs, which the stacked solve for ``c_sigma`` does not see) where they are
    well-conditioned, else from a QR.
    """
    phi = _basis(s, poles)
    full = np.concatenate([phi, np.ones((s.size, 1))], axis=1)
    k, n = full.shape[1], phi.shape[1]
    m = _augmented(full, phi, w, h)  # (E, 2L, k+n+1)
    gram = m.transpose(0, 2, 1) @ m
    lead = gram[:, : k + n, : k + n]
    d = np.sqrt(np.diagonal(lead, axis1=1, axis2=2))  # the columns' norms: cond unscaled
    if np.all(d > 0) and np.max(np.linalg.cond(lead / (d[:, :, None] * d[:, None, :]))) < (
        _GRAM_COND
    ):
        low = np.linalg.cholesky(lead)  # lead = low low^T, R = low^T
        r_last = np.linalg.solve(low, gram[:, : k + n, -1:])  # R's last column
        r22, r2 = low.transpose(0, 2, 1)[:, k:, k:], r_last[:, k:, 0]
    else:
        r_full: np.ndarray = np.linalg.qr(m, mode="r")  # type: ignore[assignment]
        r22, r2 = r_full[:, k : k + n, k : k + n], r_full[:, k : k + n, -1]
    c_sigma = np.linalg.lstsq(r22.reshape(-1, n), r2.reshape(-1), rcond=None)[0]
    a_blk, b_blk = _pole_blocks(poles)
    return _tidy(np.linalg.eigvals(a_blk - np.outer(b_blk, c_sigma)))


def _tidy(z: np.ndarray) -> np.ndarray:
    """Stable, real poles first then one of each pair; unstable ones reflected."""
    z = np.where(z.real > 0, -z.real + 1j * z.imag, z)
    real = np.sort(z[np.abs(z.imag) <= 1e-9 * np.maximum(np.abs(z), 1e-300)].real)
    pairs = z[z.imag > 1e-9 * np.abs(z)]
    pairs = pairs[np.argsort(pairs.imag)]
    return np.concatenate([real.astype(complex), pairs])


def _start_sets(order: int, bottom: float) -> list[np.ndarray]:
    """Starting poles (scaled: band top = 1), three sets; the fit keeps the best.

    Complex pairs spread linearly over the band (a resonant plant); complex pairs and real
    poles spread logarithmically from the band's bottom (a process plant whose poles lie at
    the band's low end or below it).
    """
    n_pairs = order // 2
    real_odd = np.array([-0.5]) if order % 2 else np.array([])
    lin = np.linspace(1.0 / (n_pairs + 1), 1.0, n_pairs) if n_pairs else np.array([])
    log = np.geomspace(max(bottom, 1e-6), 1.0, n_pairs) if n_pairs else np.array([])
    sets = [
        np.concatenate([real_odd, -lin / 100 + 1j * lin]),
        np.concatenate([real_odd, -log / 10 + 1j * log]),
        -np.geomspace(max(bottom / 3, 1e-6), 1.0, order).astype(complex),
    ]
    return [_tidy(p.astype(complex)) for p in sets]


def _pack(poles: np.ndarray) -> np.ndarray:
    return np.concatenate([poles.real, poles[poles.imag > 0].imag])


def _unpack(x: np.ndarray, is_pair: np.ndarray) -> np.ndarray:
    n = is_pair.size
    out = x[:n].astype(complex)
    out[is_pair] += 1j * x[n:]
    return out


def fit_rational(fr: FrequencyResponse, order: int, *, delays: bool = False) -> RationalFit:
    """A stable rational model of ``order`` states per input fitted to the response.

    With ``delays``, each output also gets a transport delay ``tau_c`` (``G_c(s) e^{-s tau_c}``,
    a process plant's dead time): the delays start from a grid search per output (the
    rational part fitted by vector fitting to the data with the trial delay undone) and are
    refined with the poles; the residues stay linear (the delay undone from the data).

    Args:
        fr: the response; its ``var`` weights the fit (where it is NaN or zero, relative
            weights ``1 / |H|`` are used and :attr:`RationalFit.weighted` is False).
        order: states per input, ``1 <= order`` and fewer parameters than equations.
        delays: fit one transport delay per output (0 to a quarter of the lowest line's
            period).

    Raises:
        IdentificationError: an order the data cannot support (as many parameters as
            equations or more), or a response that is not finite.
    """
    lines, n_y, n_u = fr.g.shape
    h = fr.g.reshape(lines, -1)
    if not np.all(np.isfinite(h)):
        raise IdentificationError("the response holds NaN: leave the unexcited lines out")
    var = fr.var.reshape(lines, -1)
    weighted = bool(np.all(np.isfinite(var)) and np.all(var > 0))
    floor = 1e-12 * float(np.max(np.abs(h)))
    w = 1.0 / np.sqrt(var) if weighted else 1.0 / np.maximum(np.abs(h), floor)
    n_eq = 2 * h.size
    n_par = order * (1 + h.shape[1]) + h.shape[1] + (n_y if delays else 0)
    if order < 1 or n_par >= n_eq:
        raise IdentificationError(
            f"order {order} needs {n_par} parameters and the response gives {n_eq} equations: "
            "lower the order or excite more lines"
        )
    scale = 2 * math.pi * float(np.max(fr.freqs_hz))
    s = 2j * math.pi * fr.freqs_hz / scale
    bottom = float(np.min(fr.freqs_hz)) * 2 * math.pi / scale
    slowest = _SLOWEST * bottom  # a pole far below the band is not seen by the data
    omega = 2 * math.pi * fr.freqs_hz
    tau_max = 0.25 / float(np.min(fr.freqs_hz)) if delays else 0.0
    tau0 = (
        _delay_grid(
            s,
            h,
            w,
            order=order,
            bottom=bottom,
            slowest=slowest,
            omega=omega,
            n_y=n_y,
            n_u=n_u,
            tau_max=tau_max,
        )
        if delays
        else np.zeros(0)
    )
    h0 = _undelayed(h, omega, tau0, n_u)
    # vector fitting from each start; the refinement from the best of them only
    starts = [_vector_fit(s, h0, w, start, slowest) for start in _start_sets(order, bottom)]
    costs = [float(np.sum(np.abs(_linear(s, h0, w, p)[1]) ** 2)) for p in starts]
    sol, is_pair = _refine(
        s,
        h,
        w,
        starts[int(np.argmin(costs))],
        slowest,
        omega=omega,
        tau0=tau0,
        n_u=n_u,
        tau_max=tau_max,
    )
    n_tau = tau0.size
    poles = _unpack(sol.x[: sol.x.size - n_tau], is_pair)
    taus = sol.x[sol.x.size - n_tau :] if n_tau else np.zeros(0)
    coef, r, phi = _linear(s, _undelayed(h, omega, taus, n_u), w, poles)
    if weighted:
        coef, r = _proper_where_supported(phi, _undelayed(h, omega, taus, n_u), w, coef, r)
    order_rows = coef[:-1]
    residues = _residues(poles, order_rows.reshape(-1, n_y, n_u)) * scale
    # the variable-projection Jacobian gives the poles' covariance (Golub & Pereyra 2003);
    # each real component of a unit-variance circular residual has variance 1/2
    jac = sol.jac
    cov = np.linalg.pinv(jac.T @ jac) / 2.0 * (1.0 if weighted else float("nan"))
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0)) * scale
    std = sd[: poles.size].astype(complex)
    std[is_pair] += 1j * sd[poles.size : sd.size - n_tau]
    return RationalFit(
        poles=poles * scale,
        pole_std=std,
        residues=residues,
        d=coef[-1].reshape(n_y, n_u),
        cost=float(np.sum(np.abs(r) ** 2)),
        n_eq=n_eq,
        weighted=weighted,
        top_rad_s=scale,
        slowest_rad_s=slowest * scale,
        delays_s=taus.copy() if n_tau else np.zeros(n_y),
        delay_std_s=sd[sd.size - n_tau :] / scale if n_tau else np.zeros(n_y),
    )


def _proper_where_supported(
    phi: np.ndarray, h: np.ndarray, w: np.ndarray, coef: np.ndarray, resid: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each entry's feedthrough set to zero where the data do not need it.

    A feedthrough the data do not determine is fitted noise, and above the band it is all
    that is left of the entry: ``|G|`` levels off at ``|d|`` instead of rolling off, with a
    notch where the residues' tail cancels it (seen on a strictly proper plant's entry).
    An entry's feedthrough is kept only when dropping it raises that entry's cost by more
    than the 99.9 % point of its distribution, ``chi2_1 / 2`` (one real parameter, each real
    component of a unit-variance circular residual of variance 1/2), scaled by the fit's
    ``2 V / dof`` where that is above 1 (the residual is then more than noise).

    Args:
        phi: (L, m) complex, the basis (last column the feedthrough's ones).
        h: (L, E) complex, the entries (delays undone).
        w: (L, E) float, the weights ``1 / sigma``.
        coef: (m, E) real, the coefficients with the feedthrough.
        resid: (L, E) complex, their weighted residual.

    Returns:
        The coefficients and the weighted residual, the dropped feedthroughs' entries
        refitted on the remaining basis.
    """
    import scipy.stats  # noqa: PLC0415 (only here)

    n_e = h.shape[1]
    dof = 2 * h.size - (coef.shape[0] * n_e + phi.shape[1] - 1)
    ratio = 2.0 * float(np.sum(np.abs(resid) ** 2)) / max(dof, 1)
    allowed = 0.5 * float(scipy.stats.chi2.ppf(0.999, 1)) * max(1.0, ratio)
    coef, resid = coef.copy(), resid.copy()
    reduced = phi[:, :-1]
    for e in range(n_e):
        a = _ri(w[:, e, None] * reduced)
        b = _ri(w[:, e] * h[:, e])
        c, *_ = np.linalg.lstsq(a, b, rcond=None)
        r_e = w[:, e] * (reduced @ c - h[:, e])
        if float(np.sum(np.abs(r_e) ** 2) - np.sum(np.abs(resid[:, e]) ** 2)) <= allowed:
            coef[:-1, e], coef[-1, e] = c, 0.0
            resid[:, e] = r_e
    return coef, resid


def _undelayed(h: np.ndarray, omega: np.ndarray, taus: np.ndarray, n_u: int) -> np.ndarray:
    """(L, E) the entries with each output's delay undone (``h e^{+j omega tau_c}``)."""
    if taus.size == 0:
        return h
    per_entry = np.repeat(taus, n_u)  # entry e = c n_u + i
    return h * np.exp(1j * omega[:, None] * per_entry[None, :])


def _delay_grid(
    s: np.ndarray,
    h: np.ndarray,
    w: np.ndarray,
    *,
    order: int,
    bottom: float,
    slowest: float,
    omega: np.ndarray,
    n_y: int,
    n_u: int,
    tau_max: float,
) -> np.ndarray:
    """(n_y,) each output's starting delay: the best of a grid, its entries fitted alone."""
    grid = np.linspace(0.0, tau_max, 25)
    out = np.zeros(n_y)
    start = _start_sets(order, bottom)[0]
    for c in range(n_y):
        cols = slice(c * n_u, (c + 1) * n_u)
        costs = []
        for tau in grid:
            hc = h[:, cols] * np.exp(1j * omega * tau)[:, None]
            poles = _vector_fit(s, hc, w[:, cols], start, slowest)
            costs.append(float(np.sum(np.abs(_linear(s, hc, w[:, cols], poles)[1]) ** 2)))
        out[c] = grid[int(np.argmin(costs))]
    return out


def _vector_fit(
    s: np.ndarray, h: np.ndarray, w: np.ndarray, start: np.ndarray, slowest: float
) -> np.ndarray:
    """The poles after the vector-fitting iterations from ``start`` (scaled).

    At most :data:`_VF_ITERATIONS`; fewer once an iteration moves no pole by more than
    :data:`_VF_SETTLED` of the largest (the relocation has reached its fixed point, and the
    refinement starts from there).
    """
    poles = start
    for _ in range(_VF_ITERATIONS):
        new = _clip(_vf_step(s, h, w, poles), slowest)
        settled = (
            new.shape == poles.shape
            and np.array_equal(new.imag > 0, poles.imag > 0)
            and float(np.max(np.abs(new - poles))) <= _VF_SETTLED * float(np.max(np.abs(new)))
        )
        poles = new
        if settled:
            break
    return poles


def _basis_derivatives(s: np.ndarray, poles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pole parameter (``_pack``'s order), the two basis columns it moves and how.

    Returns:
        ``cols`` (n_x, 2) int, the columns (:func:`_basis`) each parameter moves (a real
        pole moves one: its second is the feedthrough's, with a zero derivative), and
        ``d`` (L, n_x, 2) complex, their derivatives.

    A real pole ``a``: ``d/da 1/(s-a) = 1/(s-a)^2``. A pair ``p = x + jy`` with
    ``d1 = 1/(s-p)^2``, ``d2 = 1/(s-p*)^2``: its columns ``1/(s-p) + 1/(s-p*)`` and
    ``j/(s-p) - j/(s-p*)`` move by ``(d1 + d2, j d1 - j d2)`` in ``x`` and by
    ``(j d1 - j d2, -d1 - d2)`` in ``y``.
    """
    order = int(np.sum(np.where(poles.imag > 0, 2, 1)))
    re_part: list[tuple[int, int, np.ndarray, np.ndarray]] = []
    im_part: list[tuple[int, int, np.ndarray, np.ndarray]] = []
    zero = np.zeros(s.size, complex)
    col = 0
    for p in poles:
        if p.imag > 0:
            d1, d2 = 1 / (s - p) ** 2, 1 / (s - np.conj(p)) ** 2
            re_part.append((col, col + 1, d1 + d2, 1j * d1 - 1j * d2))
            im_part.append((col, col + 1, 1j * d1 - 1j * d2, -d1 - d2))
            col += 2
        else:
            re_part.append((col, order, 1 / (s - p.real) ** 2, zero))
            col += 1
    every = re_part + im_part
    cols = np.array([(a, b) for a, b, _, _ in every], dtype=int).reshape(-1, 2)
    d = np.stack([np.stack([da, db], axis=1) for _, _, da, db in every], axis=1)
    return cols, d


def _jacobian(
    s: np.ndarray,
    h_und: np.ndarray,
    w: np.ndarray,
    poles: np.ndarray,
    proj: _Projection,
    *,
    omega: np.ndarray,
    n_tau: int,
    n_u: int,
) -> np.ndarray:
    """(2 L E, n_x) the exact Jacobian of the refinement's residual (variable projection).

    The residual is ``r = -P b`` with ``P = I - A A^+`` (``A = w Phi`` real-stacked, ``b``
    the weighted entries with the delays undone). Golub & Pereyra (1973):
    ``dr/dx_k = P (dA/dx_k) c - (A^+)^T (dA/dx_k)^T r`` for a pole parameter; a delay moves
    ``b`` alone (``db/dtau_c = j omega b`` on output ``c``'s entries), ``dr = -P db``.

    Args:
        s: (L,) complex, ``j omega`` (scaled).
        w: (L, E) float, weights ``1 / sigma``.
        poles: (n,) complex, scaled.
        h_und: (L, E) the entries with the delays undone.
        proj: :func:`_project` at ``poles`` and ``h_und``.
        omega: (L,) rad/s, the lines (the delays' unit is s).
        n_tau: delays (0 or one per output).
        n_u: inputs.

    Rows as the residual's (real parts of every line and entry, then imaginary parts).
    """
    lines, n_e = h_und.shape
    cols, d = _basis_derivatives(s, poles)
    n_p = cols.shape[0]
    n_x = n_p + n_tau
    m = proj.coef.shape[0]
    v = np.zeros((n_e, lines, n_x), complex)  # dA_k c per entry
    t = np.zeros((n_e, m, n_x))  # dA_k^T r per entry
    cf = proj.coef[cols]  # (n_p, 2, E): the coefficients of the moved columns
    dc = d[:, :, 0, None] * cf[None, :, 0, :] + d[:, :, 1, None] * cf[None, :, 1, :]
    v[:, :, :n_p] = (w[:, None, :] * dc).transpose(2, 0, 1)
    moved = np.real(d.reshape(lines, -1).conj().T @ (w * proj.resid))  # (n_p 2, E)
    moved = moved.reshape(n_p, 2, n_e).transpose(2, 0, 1)  # (E, n_p, 2)
    k = np.arange(n_p)
    t[:, cols[:, 0], k] = moved[:, :, 0]
    t[:, cols[:, 1], k] += moved[:, :, 1]  # zero where a real pole's second is the feedthrough
    for c in range(n_tau):
        out = slice(c * n_u, (c + 1) * n_u)
        v[out, :, n_p + c] = -(1j * omega * w[:, out].T * h_und[:, out].T)
    jac = proj.removed(_stack(v), t)  # (E, 2L, n_x)
    return jac.transpose(1, 0, 2).reshape(-1, n_x)


def _refine(
    s: np.ndarray,
    h: np.ndarray,
    w: np.ndarray,
    poles: np.ndarray,
    slowest: float,
    *,
    omega: np.ndarray,
    tau0: np.ndarray,
    n_u: int,
    tau_max: float,
) -> tuple[scipy.optimize.OptimizeResult, np.ndarray]:
    """The maximum-likelihood refinement of ``poles`` (and the delays ``tau0``) in bounds.

    ``least_squares`` with the residual's exact Jacobian (:func:`_jacobian`); each point's
    linear solve is shared by the residual and the Jacobian.
    """
    is_pair = poles.imag > 0
    n_tau = tau0.size
    lower = np.concatenate(
        [np.full(poles.size, -50.0), np.zeros(int(is_pair.sum())), np.zeros(n_tau)]
    )
    upper = np.concatenate(
        [np.full(poles.size, -slowest), np.full(int(is_pair.sum()), _TOP),
         np.full(n_tau, max(tau_max, 1e-12))]
    )  # fmt: skip
    x0 = np.clip(np.concatenate([_pack(poles), tau0]), lower + 1e-12, upper - 1e-12)
    last: dict[bytes, tuple[np.ndarray, np.ndarray, _Projection]] = {}

    def solved(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, _Projection]:
        key = x.tobytes()
        if key not in last:
            taus = x[x.size - n_tau :] if n_tau else tau0
            p = _unpack(x[: x.size - n_tau], is_pair)
            h_und = _undelayed(h, omega, taus, n_u)
            phi = np.concatenate([_basis(s, p), np.ones((s.size, 1))], axis=1)
            last.clear()
            last[key] = (p, h_und, _project(phi, h_und, w))
        return last[key]

    def residual(x: np.ndarray) -> np.ndarray:
        return _ri(solved(x)[2].resid).ravel()

    def jacobian(x: np.ndarray) -> np.ndarray:
        p, h_und, proj = solved(x)
        return _jacobian(s, h_und, w, p, proj, omega=omega, n_tau=n_tau, n_u=n_u)

    sol = scipy.optimize.least_squares(
        residual, x0, jac=jacobian, bounds=(lower, upper), x_scale="jac"
    )
    return sol, is_pair


def _clip(poles: np.ndarray, slowest: float) -> np.ndarray:
    """Poles held inside the refinement's bounds (scaled: band top = 1)."""
    re = np.clip(poles.real, -50.0, -slowest)
    im = np.clip(poles.imag, 0.0, _TOP)
    return _tidy(re + 1j * np.where(poles.imag > 0, im, 0.0))


def select_order(
    fr: FrequencyResponse, orders: range, *, delays: bool = False
) -> tuple[RationalFit, list[RationalFit]]:
    """The fit of the order with the smallest MDL cost, and every order's fit.

    ``V_mdl = V (1 + n_par ln(n_eq) / n_eq)`` among the fits whose every pole the data
    determine (:attr:`RationalFit.supported`: a pole within three standard deviations of the
    origin is noise fitted, not dynamics); orders with too few equations are skipped. Where no
    order is supported, the lowest is taken. The orders are tried upwards and the search stops
    once two orders in a row have not lowered the best supported cost (every fit tried is
    returned).

    ``delays``: each order's fit also has one transport delay per output
    (:func:`fit_rational`).

    Raises:
        IdentificationError: no order in the range can be fitted.
    """
    fits: list[RationalFit] = []
    best_mdl, since = math.inf, 0
    for order in orders:
        try:
            fit = fit_rational(fr, order, delays=delays)
        except IdentificationError:
            continue
        fits.append(fit)
        if fit.supported and _mdl(fit) < best_mdl:
            best_mdl, since = _mdl(fit), 0
        else:
            since += 1
        if since >= _PATIENCE:  # two orders in a row added nothing the data support
            break
    if not fits:
        raise IdentificationError(
            f"no order in {orders.start}..{orders.stop - 1} can be fitted to {fr.g.shape[0]} "
            "lines: lower the orders or excite more lines"
        )
    candidates = [f for f in fits if f.supported] or [min(fits, key=lambda f: f.order)]
    return min(candidates, key=_mdl), fits


def _mdl(fit: RationalFit) -> float:
    """Rissanen's MDL cost ``V (1 + n_par ln(n_eq) / n_eq)``."""
    return fit.cost * (1 + fit.n_par * math.log(fit.n_eq) / fit.n_eq)
