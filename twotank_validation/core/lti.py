"""Linear time-invariant building blocks: state space, discretisation, frequency response.

Every model part is held as a state-space quadruple. How a continuous-time part meets the
sampled data is the model's :class:`Intersample` assumption (docs/theory.md §14): a held
input (zero-order hold) or a band-limited one (first-order hold, or the continuous response
evaluated exactly at the DFT bins); :func:`bin_response` is the one place that applies it.
Discretisation is ``scipy.signal.cont2discrete`` at the sample period of the datum, and the
discrete parts are evaluated on the unit circle at the DFT bins.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import scipy.signal

from twotank_validation.errors import DimensionError, ModelError, UnstableModelError

_FloatArray = np.ndarray
_STABILITY_MARGIN = 1e-9


class Intersample(StrEnum):
    """How the input of a continuous-time model part behaves between samples.

    ``ZOH``: held constant over each sample period (a DAC's command): zero-order hold.
    ``FOH``: band-limited, approximated as linear between samples (a measured signal):
    first-order (triangle) hold. ``EXACT``: band-limited (no power at or above Nyquist):
    the continuous response ``G(j omega)`` at each bin, no discretisation; where a
    discrete-time system is needed (a simulation, a pulse response) it is the first-order
    hold's (:meth:`simulation_method`).
    """

    ZOH = "zoh"
    FOH = "foh"
    EXACT = "exact"

    @property
    def simulation_method(self) -> str:
        """The ``cont2discrete`` method of a time-domain simulation under this assumption."""
        return "zoh" if self is Intersample.ZOH else "foh"


@dataclass(frozen=True)
class StateSpace:
    """A state-space system ``x' = A x + B u, y = C x + D u``.

    Attributes:
        a: (n_states, n_states) float.
        b: (n_states, n_inputs) float.
        c: (n_outputs, n_states) float.
        d: (n_outputs, n_inputs) float.
        dt_s: sample period in seconds for a discrete-time system, ``None`` when continuous.
        output_delays_s: per-output transport delay in seconds (each >= 0) applied after the
            rational part, ``y_i(t) = [C x + D u]_i(t - tau_i)``; empty for none. Kept by
            :func:`discretise`; exact in :func:`frequency_response` (``exp(-j theta tau/dt)``,
            also for fractional delays, i.e. the band-limited delay of a periodic signal);
            rounded to whole samples in :func:`impulse_response`.
    """

    a: _FloatArray
    b: _FloatArray
    c: _FloatArray
    d: _FloatArray
    dt_s: float | None = None
    output_delays_s: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        a, b, c, d = (
            np.atleast_2d(np.asarray(m, dtype=float)) for m in (self.a, self.b, self.c, self.d)
        )
        n = a.shape[0] if a.size else 0
        if a.size == 0:
            a = np.zeros((0, 0))
            b = np.zeros((0, d.shape[1]))
            c = np.zeros((d.shape[0], 0))
        if a.shape != (n, n):
            raise DimensionError(f"state matrix A must be square, found shape {a.shape}")
        if b.shape[0] != n or c.shape[1] != n or d.shape != (c.shape[0], b.shape[1]):
            raise DimensionError(
                f"state-space shapes disagree: A {a.shape}, B {b.shape}, C {c.shape}, D {d.shape}; "
                "expected A (n,n), B (n,m), C (p,n), D (p,m)"
            )
        for name, m in (("A", a), ("B", b), ("C", c), ("D", d)):
            if not np.all(np.isfinite(m)):
                raise ModelError(f"state-space matrix {name} holds NaN or inf: fix the model file")
        if self.dt_s is not None and not (np.isfinite(self.dt_s) and self.dt_s > 0):
            raise ModelError(f"sample period must be positive and finite, found {self.dt_s}")
        delays = tuple(float(t) for t in self.output_delays_s)
        if delays:
            if len(delays) != d.shape[0]:
                raise DimensionError(
                    f"output_delays_s has {len(delays)} entries but the system has "
                    f"{d.shape[0]} outputs: give one delay (s) per output"
                )
            if not all(np.isfinite(t) and t >= 0.0 for t in delays):
                raise ModelError(f"output delays must be finite and >= 0 s, found {delays}")
            if not any(delays):
                delays = ()
        object.__setattr__(self, "output_delays_s", delays)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "c", c)
        object.__setattr__(self, "d", d)

    @property
    def n_states(self) -> int:
        """Number of states."""
        return int(self.a.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """(n_outputs, n_inputs)."""
        return (int(self.d.shape[0]), int(self.d.shape[1]))

    @property
    def is_discrete(self) -> bool:
        """True for a discrete-time system."""
        return self.dt_s is not None


def static_gain(gain: _FloatArray | float, dt_s: float | None = None) -> StateSpace:
    """A memoryless system ``y = K u``.

    Args:
        gain: scalar or (n_outputs, n_inputs) matrix.
        dt_s: sample period (s) or ``None`` for continuous time.
    """
    k = np.atleast_2d(np.asarray(gain, dtype=float))
    return StateSpace(
        np.zeros((0, 0)), np.zeros((0, k.shape[1])), np.zeros((k.shape[0], 0)), k, dt_s
    )


def from_transfer_function(num: Sequence[float], den: Sequence[float]) -> StateSpace:
    """Continuous SISO transfer function (coefficients in descending powers of s) to state space.

    Raises:
        ModelError: improper or degenerate transfer function.
    """
    num_a = np.atleast_1d(np.asarray(num, dtype=float))
    den_a = np.atleast_1d(np.asarray(den, dtype=float))
    if den_a.size == 0 or not np.any(den_a):
        raise ModelError(f"transfer-function denominator {den_a.tolist()} is zero")
    den_a = np.trim_zeros(den_a, "f")
    num_a = np.trim_zeros(num_a, "f") if np.any(num_a) else np.zeros(1)
    if num_a.size > den_a.size:
        raise ModelError(
            f"transfer function num={num_a.tolist()} den={den_a.tolist()} is improper "
            "(numerator degree exceeds denominator degree): add poles to the weight"
        )
    if den_a.size == 1:  # a constant: tf2ss would add a spurious state with a pole at 0
        return static_gain(float(num_a[-1]) / float(den_a[0]))
    if not np.any(num_a):  # a zero weight (a block scaled to 0): no states, no warning
        return static_gain(0.0)
    a, b, c, d = scipy.signal.tf2ss(num_a, den_a)
    return StateSpace(a, b, c, d)


def discretise(
    sys: StateSpace, dt_s: float, intersample: Intersample = Intersample.ZOH
) -> StateSpace:
    """Discretisation at ``dt_s`` seconds (identity on discrete systems).

    Zero-order hold by default; ``FOH`` is the first-order (triangle) hold, and ``EXACT``,
    which has no discrete equivalent, also the first-order hold (its time-domain stand-in:
    :func:`bin_response` evaluates it exactly at the bins).

    Raises:
        ModelError: a discrete system with another sample period.
    """
    if sys.is_discrete:
        if not np.isclose(sys.dt_s, dt_s, rtol=1e-9):  # type: ignore[arg-type]
            raise ModelError(
                f"discrete model part has sample period {sys.dt_s} s but the datum has {dt_s} s: "
                "resample the data or give the part in continuous time"
            )
        return sys
    if sys.n_states == 0:
        return StateSpace(sys.a, sys.b, sys.c, sys.d, dt_s, sys.output_delays_s)
    mats = tuple((m.shape, m.tobytes()) for m in (sys.a, sys.b, sys.c, sys.d))
    method = Intersample(intersample).simulation_method
    return _hold(mats, float(dt_s), sys.output_delays_s, method)


@functools.lru_cache(maxsize=512)
def _hold(
    mats: tuple[tuple[tuple[int, ...], bytes], ...],
    dt_s: float,
    delays: tuple[float, ...],
    method: str,
) -> StateSpace:
    """:func:`discretise` of a continuous system given by its matrices' shapes and bytes.

    Memoised on that content (a validator built again for the same models, or for models
    loaded again, does not repeat the matrix exponentials); the arrays it returns are
    read-only, as every caller shares them.
    """
    a, b, c, d = (np.frombuffer(raw, dtype=float).reshape(shape) for shape, raw in mats)
    ad, bd, cd, dd, _ = scipy.signal.cont2discrete((a, b, c, d), dt_s, method=method)
    for m in (ad, bd, cd, dd):
        m.setflags(write=False)
    return StateSpace(ad, bd, cd, dd, dt_s, delays)


def check_stable(sys: StateSpace, what: str) -> None:
    """Raise ``UnstableModelError`` unless every pole is strictly stable.

    Args:
        sys: continuous (Re p < 0) or discrete (|p| < 1) system.
        what: name used in the message.
    """
    if sys.n_states == 0:
        return
    poles = np.linalg.eigvals(sys.a)
    if sys.is_discrete:
        bad = poles[np.abs(poles) >= 1.0 - _STABILITY_MARGIN]
    else:
        bad = poles[poles.real >= -_STABILITY_MARGIN]
    if bad.size:
        raise UnstableModelError(
            f"{what} is not stable (poles {np.array2string(bad, precision=4)}): model validation "
            "by DFT needs a stable nominal; stabilise it in closed loop and supply the "
            "closed-loop P"
        )


def frequency_response(sys: StateSpace, theta: _FloatArray) -> np.ndarray:
    """Evaluate a discrete system at ``z = exp(j theta)``.

    Args:
        sys: discrete-time system.
        theta: (n_bins,) float, normalised angular frequencies (rad/sample).

    Returns:
        (n_bins, n_outputs, n_inputs) complex.
    """
    if not sys.is_discrete:
        raise ModelError("frequency_response needs a discrete system: call discretise() first")
    theta = np.asarray(theta, dtype=float)
    rational = _rational_response(sys, np.exp(1j * theta))
    if sys.output_delays_s:
        tau = np.asarray(sys.output_delays_s) / float(sys.dt_s)  # type: ignore[arg-type]
        rational *= np.exp(-1j * theta[:, None] * tau[None, :])[:, :, None]
    return rational


def continuous_response(sys: StateSpace, omega: _FloatArray) -> np.ndarray:
    """Evaluate a continuous system at ``s = j omega``, its delays as ``exp(-j omega tau)``.

    Args:
        sys: continuous-time system.
        omega: (n_bins,) float, angular frequencies (rad/s).

    Returns:
        (n_bins, n_outputs, n_inputs) complex.
    """
    if sys.is_discrete:
        raise ModelError("continuous_response needs a continuous system")
    omega = np.asarray(omega, dtype=float)
    rational = _rational_response(sys, 1j * omega)
    if sys.output_delays_s:
        tau = np.asarray(sys.output_delays_s)
        rational *= np.exp(-1j * omega[:, None] * tau[None, :])[:, :, None]
    return rational


def bin_response(
    sys: StateSpace,
    theta: _FloatArray,
    dt_s: float,
    intersample: Intersample = Intersample.ZOH,
) -> np.ndarray:
    """A model part's response at the DFT bins under an intersample assumption.

    A discrete part is evaluated at ``z = exp(j theta)`` as it is; a continuous part is
    discretised by ``intersample``'s hold, or under ``EXACT`` evaluated at
    ``s = j theta / dt_s`` (``theta`` above pi wrapped to the negative frequency it aliases,
    ``theta - 2 pi``): no hold, no aliasing of the plant's response (docs/theory.md §14).

    Args:
        sys: continuous or discrete system.
        theta: (n_bins,) float, rad/sample.
        dt_s: sample period (s).
        intersample: the model's assumption about the input between samples.

    Returns:
        (n_bins, n_outputs, n_inputs) complex.

    Raises:
        ModelError: a discrete part with another sample period.
    """
    if sys.is_discrete or Intersample(intersample) is not Intersample.EXACT:
        return frequency_response(discretise(sys, dt_s, intersample), theta)
    theta = np.asarray(theta, dtype=float)
    wrapped = np.where(theta > np.pi, theta - 2.0 * np.pi, theta)
    return continuous_response(sys, wrapped / float(dt_s))


def _rational_response(sys: StateSpace, points: np.ndarray) -> np.ndarray:
    """``C (sI - A)^-1 B + D`` at the complex ``points`` (``exp(j theta)`` or ``j omega``).

    Returns (n_points, n_outputs, n_inputs) complex.
    """
    z = np.asarray(points, dtype=complex)
    p, m = sys.shape
    if sys.n_states == 0:
        return np.broadcast_to(sys.d.astype(complex), (z.size, p, m)).copy()
    # Diagonalise A once when it is well conditioned (O(n_bins n^2)); otherwise solve per bin.
    eigvals, eigvecs = np.linalg.eig(sys.a)
    if np.linalg.cond(eigvecs) < 1e8:
        cb = sys.c @ eigvecs
        bb = np.linalg.solve(eigvecs, sys.b)
        resolvent = 1.0 / (z[:, None] - eigvals[None, :])  # (n_bins, n)
        return np.einsum("pi,ki,im->kpm", cb, resolvent, bb) + sys.d[None, :, :]
    eye = np.eye(sys.n_states)
    zi_a = z[:, None, None] * eye[None] - sys.a[None]
    x = np.linalg.solve(zi_a, np.broadcast_to(sys.b, (z.size, *sys.b.shape)))
    return np.einsum("pn,knm->kpm", sys.c, x) + sys.d[None, :, :]


def impulse_response(sys: StateSpace, n_samples: int) -> np.ndarray:
    """Pulse response coefficients p(k) of a discrete system.

    Args:
        sys: discrete-time system.
        n_samples: number of coefficients.

    Returns:
        (n_samples, n_outputs, n_inputs) float; p(0) = D, p(k) = C A^(k-1) B, each output
        row shifted by its delay rounded to whole samples.
    """
    out = _rational_impulse(sys, n_samples)
    for i, tau in enumerate(sys.output_delays_s):
        shift = min(round(tau / float(sys.dt_s)), n_samples)  # type: ignore[arg-type]
        out[:, i, :] = np.concatenate(
            [np.zeros((shift, out.shape[2])), out[: n_samples - shift, i, :]]
        )
    return out


def _rational_impulse(sys: StateSpace, n_samples: int) -> np.ndarray:
    """Pulse response of the rational part (delays ignored)."""
    p, m = sys.shape
    out = np.zeros((n_samples, p, m))
    out[0] = sys.d
    if n_samples < 2 or sys.n_states == 0:
        return out
    eigvals, eigvecs = np.linalg.eig(sys.a)
    if np.linalg.cond(eigvecs) < 1e8:
        # p(k) = C V diag(lambda^(k-1)) V^-1 B, vectorised over k (no Python loop over samples)
        cv = sys.c @ eigvecs
        vb = np.linalg.solve(eigvecs, sys.b)
        powers = eigvals[None, :] ** np.arange(n_samples - 1)[:, None]  # (n-1, n_states)
        out[1:] = np.einsum("pi,ki,im->kpm", cv, powers, vb).real
        return out
    x = sys.b.copy()
    for k in range(1, n_samples):
        out[k] = sys.c @ x
        x = sys.a @ x
    return out
