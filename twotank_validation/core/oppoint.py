"""The operating point: Problem 3 at the zero-frequency bin of the deviation from a reference.

The paper removes each window's mean before the DFT: its datum holds the dynamics, and a
fault that moves the plant to another steady state (a leak, a sensor bias, a weak or stuck
valve, a heat loss) shows only while the plant moves, in the windows around the change. Given
a reference operating point (input and output means, model units), the window's means are
one more datum: the zero-frequency bin of the deviation from it,

    U(0) = c_N N (ū − u_ref),   Y(0) = c_N N (ȳ − y_ref),

with the DFT prefactor ``c_N`` of the norm convention (power: the deviations themselves).
Problem 3 at that bin, with the plant evaluated at z = 1 (its steady-state gain, the
perturbation weights and the noise weights at zero frequency), gives the smallest ``|W(0)|``
that some ``||Δ|| ≤ 1`` pairs with to explain the move. It is the term the paper's sum over
bins leaves out; adding it back keeps the meaning of β (docs/theory.md §8):

    β_total = sqrt(β² + β_op²) > 1:  no member of the model set explains the window's
    dynamics and its operating point together.

A slow drift of the operating point that the model set does not describe (ambient
temperature, sensor ageing) is allowed for by a dead band per output: the output deviation
is shrunk towards zero by ``allowance`` before the bin is formed, i.e. the model set is
widened by an unknown constant output offset of at most ``allowance``.

Pure functions over numpy arrays; no ROS, no state (the reference is kept by the caller).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twotank_validation.core.datum import NormConvention
from twotank_validation.core.model import LFTModel, PlantResponse
from twotank_validation.core.validate import lower_bins
from twotank_validation.errors import DimensionError


@dataclass(frozen=True)
class OperatingPoint:
    """A reference operating point: steady input and output means.

    Attributes:
        u: (nu,) float, input means (model units).
        y: (ny,) float, output means (model units).
    """

    u: np.ndarray
    y: np.ndarray


@dataclass(frozen=True)
class OperatingPointCheck:
    """Problem 3 at zero frequency for one window's means against a reference.

    Attributes:
        beta: smallest ``|W(0)|`` (lower bound of the solver; exact for the closed form);
            ``inf`` where no noise of the model reaches an output that moved.
        du: (nu,) float, input means minus the reference (model units).
        dy: (ny,) float, output means minus the reference (model units), before the
            allowance.
        dy_beyond: (ny,) float, the output deviation beyond the allowance (what the bin
            holds, model units).
    """

    beta: float
    du: np.ndarray
    dy: np.ndarray
    dy_beyond: np.ndarray

    @property
    def explained(self) -> bool:
        """The model set explains the move on its own (``beta <= 1``)."""
        return bool(self.beta <= 1.0)


def dc_response(model: LFTModel, ts_s: float) -> PlantResponse:
    """The generalised plant at z = 1 (one bin), memoised on the model per sample period."""
    key = ("dc_response", float(ts_s))
    if key not in model.cache:
        model.cache[key] = model.response(np.zeros(1), ts_s)
    resp: PlantResponse = model.cache[key]
    return resp


def dead_band(dy: np.ndarray, allowance: np.ndarray) -> np.ndarray:
    """``sign(dy) max(|dy| − allowance, 0)`` per output: the deviation beyond the allowance."""
    dy = np.asarray(dy, dtype=float)
    return np.sign(dy) * np.maximum(np.abs(dy) - np.asarray(allowance, dtype=float), 0.0)


@dataclass(frozen=True)
class DcTransient:
    """The transient term at the zero-frequency bin of a window that is not steady.

    Built by :func:`twotank_validation.core.transient.dc_correction` (docs/theory.md §20).

    Attributes:
        shift: (ny,) float, the transient's share of the window's output means (model units):
            ``T_hat(0) / (c_N N)``, taken off the means before the check.
        noise_scale: ``s_0``, the noise of the bin with the estimate's error (the noise
            channels are scaled by it: the bin's minimum is divided by it).
        rho: the least noise that the model error picked up from the fit lines can need
            (§20); the bin's minimum is lowered by it.
    """

    shift: np.ndarray
    noise_scale: float
    rho: float


def check_operating_point(
    model: LFTModel,
    ts_s: float,
    reference: OperatingPoint,
    window: OperatingPoint,
    *,
    n_samples: int,
    convention: NormConvention = NormConvention.POWER,
    allowance: np.ndarray | float = 0.0,
    method: str = "auto",
    transient: DcTransient | None = None,
) -> OperatingPointCheck:
    """Problem 3 at the zero-frequency bin of the window's deviation from the reference.

    Args:
        model: the model set.
        ts_s: sample period (s) the model is discretised at.
        reference: the reference operating point (model units).
        window: the window's input and output means (model units).
        n_samples: samples in the window (N; the bin's scale under the energy convention).
        convention: norm convention of the window's β.
        allowance: (ny,) or scalar, dead band on each output's deviation (model units).
        method: solver route, as :func:`~twotank_validation.core.validate.validate`.
        transient: a window that is not steady: its transient term at DC (taken off the
            output means; the minimum divided by its noise scale and lowered by its rho).

    Returns:
        The check; its ``beta`` adds to the window's β as ``sqrt(beta² + beta_op²)``.

    Raises:
        DimensionError: the means do not match the model's inputs and outputs.
    """
    du = np.asarray(window.u, dtype=float) - np.asarray(reference.u, dtype=float)
    dy = np.asarray(window.y, dtype=float) - np.asarray(reference.y, dtype=float)
    if transient is not None:
        dy = dy - np.asarray(transient.shift, dtype=float)
    if du.shape != (model.nu,) or dy.shape != (model.ny,):
        raise DimensionError(
            f"model {model.name!r} has {model.nu} inputs and {model.ny} outputs; the operating "
            f"point has {du.size} input and {dy.size} output means"
        )
    beyond = dead_band(dy, np.broadcast_to(np.asarray(allowance, dtype=float), dy.shape))
    scale = NormConvention(convention).dft_scale(n_samples) * n_samples  # bin 0 = c_N N mean
    lower = lower_bins(
        dc_response(model, ts_s),
        (scale * du).astype(complex)[None, :],
        (scale * beyond).astype(complex)[None, :],
        method=method,
    )
    beta = float(lower[0])
    if transient is not None:
        beta = max(0.0, beta / transient.noise_scale - transient.rho)
    return OperatingPointCheck(beta=beta, du=du, dy=dy, dy_beyond=beyond)


def combined_beta(beta: float, beta_op: float) -> float:
    """``sqrt(beta² + beta_op²)``: β over the window's bins and its zero-frequency bin."""
    return float(np.hypot(beta, beta_op))
