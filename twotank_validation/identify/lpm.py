"""The local polynomial method: a response from a record that is not in steady state.

A record of ``M`` samples started off the periodic steady state (one period of a multisine
after a start-up, or several periods still settling) has, at every line ``k`` of its DFT,

    ``Y(k) = G(k) U(k) + T(k) + V(k)``

where ``T`` is the transient, a smooth (rational) function of frequency, and ``V`` the noise.
Around each line of interest, ``G`` and ``T`` are replaced by polynomials of degree ``R`` in
the line offset ``r``, fitted by least squares to the ``2 n + 1`` neighbouring lines; ``G(k)``
is the constant term, and the residual gives the noise variance with ``2 n + 1 - n_par``
degrees of freedom (Pintelon, Schoukens, Vandersteen and Barbé, "Estimation of nonparametric
noise and FRF models for multivariable systems", MSSP 24 (2010); Pintelon & Schoukens 2012,
sec. 7.2.4). With ``P > 1`` whole periods the neighbours of an excited line are unexcited,
carry the transient and the noise only, and ``G`` has a single term there.

Written by hand: no maintained Python library implements the local polynomial method.

Units: the record DFT is ``(1/M) sum_t x(t) exp(-j 2 pi k t / M)``; a response is output
units per input unit; frequencies in Hz.
"""

from __future__ import annotations

import numpy as np

from twotank_validation.errors import IdentificationError
from twotank_validation.identify.nonparametric import FrequencyResponse

__all__ = ["local_polynomial", "lpm_half_width"]

_NEGLIGIBLE = 1e-10


def lpm_half_width(n_inputs: int, degree: int, dof: int = 4) -> int:
    """The smallest half-width ``n`` that leaves ``dof`` degrees of freedom for the noise.

    The local model has ``(R + 1)(n_u + 1)`` complex parameters per output; the window has
    ``2 n + 1`` lines.
    """
    n_par = (degree + 1) * (n_inputs + 1)
    return max(1, -(-(n_par + dof - 1) // 2))


def local_polynomial(
    u: np.ndarray,
    y: np.ndarray,
    lines: np.ndarray,
    ts_s: float,
    *,
    degree: int = 2,
    half_width: int | None = None,
    n_periods: int = 1,
) -> FrequencyResponse:
    """The response at ``lines`` of a record's DFT, the transient removed by local polynomials.

    Args:
        u: (M, n_u) float, the input record (any length; no whole periods needed).
        y: (M, n_y) float, the output record.
        lines: (L,) int, lines of the record's DFT (``1 <= k < M / 2``) at which to estimate;
            with ``n_periods = P`` whole periods, the excited lines are multiples of ``P``.
        ts_s: sample period (s).
        degree: polynomial degree ``R`` of the response and the transient (0..4).
        half_width: lines each side of ``k`` in the local window; the smallest that leaves
            four degrees of freedom by default (:func:`lpm_half_width`).
        n_periods: whole periods in the record (frequency of line ``k`` is ``k / (M ts)``).

    Returns:
        The response with the variance of each entry from the local residuals
        (``n_periods`` in the result is the residual's degrees of freedom plus one, so that
        :meth:`FrequencyResponse.radius` uses the right F quantile).

    Raises:
        IdentificationError: non-finite samples, too short a record for the window, or a
            line whose window does not determine the response (no excitation there).
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    if u.ndim != 2 or y.ndim != 2 or u.shape[0] != y.shape[0]:
        raise IdentificationError(
            f"records must be (samples, channels) of one length, got {u.shape} and {y.shape}"
        )
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise IdentificationError(
            "the record holds NaN or infinite samples: cut them out (--start/--end)"
        )
    if not 0 <= degree <= 4:
        raise IdentificationError(f"degree {degree} out of 0..4")
    m, n_u = u.shape
    n_y = y.shape[1]
    width = half_width if half_width is not None else lpm_half_width(n_u, degree)
    last = (m - 1) // 2
    if 2 * width + 1 > last:
        raise IdentificationError(
            f"a record of {m} samples has too few lines for a local window of "
            f"{2 * width + 1}: record longer or lower the degree"
        )
    lines = np.asarray(lines, dtype=int)
    if lines.size == 0 or lines.min() < 1 or lines.max() > last:
        raise IdentificationError(f"lines must lie in 1..{last} for {m} samples")
    uf = np.fft.rfft(u, axis=0) / m
    yf = np.fft.rfft(y, axis=0) / m
    g = np.zeros((lines.size, n_y, n_u), complex)
    var = np.zeros((lines.size, n_y, n_u))
    noise_var = np.zeros((lines.size, n_y))
    dofs = []
    for i, k in enumerate(lines):
        lo = min(max(1, k - width), last - 2 * width)
        idx = np.arange(lo, lo + 2 * width + 1)
        r = (idx - k).astype(float) / max(width, 1)
        powers = np.stack([r**s for s in range(degree + 1)], axis=1)  # (W, R+1)
        g_cols = (uf[idx][:, :, None] * powers[:, None, :]).reshape(idx.size, -1)
        norms = np.linalg.norm(g_cols, axis=0)
        # with whole periods, only the excited line carries the input: drop empty columns
        keep = norms > _NEGLIGIBLE * max(float(norms.max()), 1e-300)
        g_cols = g_cols[:, keep]
        kmat = np.concatenate([g_cols, powers.astype(complex)], axis=1)
        n_par = kmat.shape[1]
        dof = idx.size - n_par
        if dof < 1:
            raise IdentificationError(
                f"line {k}: the local window of {idx.size} lines leaves no degree of freedom "
                "for the noise: widen it (half_width) or lower the degree"
            )
        q, rr = np.linalg.qr(kmat)
        if np.min(np.abs(np.diag(rr))) < _NEGLIGIBLE * np.max(np.abs(np.diag(rr))):
            raise IdentificationError(
                f"line {k} ({k / (m * ts_s):.4g} Hz): the input does not determine the "
                "response there (too little excitation): leave the line out of the band"
            )
        theta = np.linalg.solve(rr, q.conj().T @ yf[idx])  # (n_par, n_y)
        resid = yf[idx] - kmat @ theta
        s2 = np.sum(np.abs(resid) ** 2, axis=0) / dof  # (n_y,)
        noise_var[i] = s2
        cov = np.linalg.inv(rr.conj().T @ rr)
        # the constant term of each input's response: the first kept column of that input
        col_of = np.cumsum(keep) - 1
        for j in range(n_u):
            c0 = j * (degree + 1)
            if not keep[c0]:
                raise IdentificationError(
                    f"line {k}: input {j} is not excited there: leave the line out of the band"
                )
            col = col_of[c0]
            g[i, :, j] = theta[col]
            var[i, :, j] = s2 * float(np.real(cov[col, col]))
        dofs.append(dof)
    return FrequencyResponse(
        lines=lines,
        freqs_hz=lines / (m * ts_s),
        g=g,
        var=var,
        n_periods=int(min(dofs)) + 1,
        n_experiments=1,
        noise_var=noise_var,
    )
