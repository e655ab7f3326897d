"""A low-order, stable, minimum-phase rational weight over a per-bin magnitude requirement.

The weight is continuous-time, of the form::

    W(s) = K prod_i (s / z_i + 1) / (s / p_i + 1),      z_i, p_i > 0,

so it is stable and minimum phase by construction, and biproper (a real pole and zero per
order). Its gain ``K`` is the smallest that makes the weight as the model evaluates it at the
datum's sample period (its ``intersample`` hold, or exactly at the bins) cover ``margin`` times the
requirement at every bin; the corner frequencies minimise the mean excess
``mean_n log(|W(n)| / required(n))`` over the bins, by Nelder-Mead from several starts
(``scipy.optimize.minimize``). Orders 0 (a constant) to ``max_order`` are fitted and the
lowest whose mean excess is within ``order_tolerance_db`` of the best is taken.

Compare MATLAB's ``ucover``, which fits a weight of a given order over the relative errors
of a family of frequency responses; here the requirement comes from validation data.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from twotank_validation.core import lti
from twotank_validation.errors import ModelError


@dataclass(frozen=True)
class FittedWeight:
    """A fitted weight and how it covers its requirement.

    Attributes:
        num: numerator coefficients, descending powers of s.
        den: denominator coefficients, descending powers of s.
        order: number of pole-zero pairs.
        zeros_rad_s: (order,) the zeros' corner frequencies, rad/s (``s = -z``).
        poles_rad_s: (order,) the poles' corner frequencies, rad/s.
        gain: ``K`` (the weight's DC gain).
        magnitude: (k,) ``|W|`` of the discretised weight at the fitted bins.
        margin: the factor by which it covers the requirement at least.
        mean_excess_db: mean of ``20 log10(|W| / required)`` over the bins with a requirement.
    """

    num: tuple[float, ...]
    den: tuple[float, ...]
    order: int
    zeros_rad_s: tuple[float, ...]
    poles_rad_s: tuple[float, ...]
    gain: float
    magnitude: np.ndarray
    margin: float
    mean_excess_db: float

    def system(self) -> lti.StateSpace:
        """The weight as a continuous state space."""
        return lti.from_transfer_function(self.num, self.den)

    def to_node(self) -> dict[str, object]:
        """The weight as a model-file node (``{gain: K}`` or ``{tf: {num, den}}``)."""
        if self.order == 0:
            return {"gain": float(self.gain)}
        return {"tf": {"num": [float(x) for x in self.num], "den": [float(x) for x in self.den]}}


def _coefficients(gain: float, zeros: np.ndarray, poles: np.ndarray) -> tuple[np.ndarray, ...]:
    num = np.array([gain])
    den = np.array([1.0])
    for z, p in zip(zeros, poles, strict=True):
        num = np.polymul(num, [1.0 / z, 1.0])
        den = np.polymul(den, [1.0 / p, 1.0])
    return num, den


def _discrete_gain(
    num: np.ndarray, den: np.ndarray, theta: np.ndarray, ts_s: float, how: lti.Intersample
) -> np.ndarray:
    sys = lti.from_transfer_function(num.tolist(), den.tolist())
    gain: np.ndarray = np.abs(lti.bin_response(sys, theta, ts_s, how)[:, 0, 0])
    return gain


def fit_weight(
    theta: np.ndarray,
    required: np.ndarray,
    ts_s: float,
    *,
    margin: float = 1.2,
    max_order: int = 2,
    order_tolerance_db: float = 1.0,
    intersample: lti.Intersample = lti.Intersample.ZOH,
) -> FittedWeight:
    """The lowest-order weight that covers ``margin`` times ``required`` at every bin.

    Args:
        theta: (k,) bin frequencies, rad/sample.
        required: (k,) required magnitudes (>= 0, finite); bins with 0 need nothing.
        ts_s: sample period (s) at which the weight is evaluated.
        margin: cover factor, >= 1.
        max_order: largest number of pole-zero pairs tried.
        order_tolerance_db: an order is enough when its mean excess is within this of the
            best order's.
        intersample: how the model evaluates a continuous weight at the bins.

    Raises:
        ModelError: a requirement that is negative, infinite or NaN, or a bad setting.
    """
    theta = np.asarray(theta, dtype=float)
    required = np.asarray(required, dtype=float)
    if not margin >= 1.0:
        raise ModelError(f"margin={margin} must be >= 1 (the weight covers margin x requirement)")
    if max_order < 0:
        raise ModelError(f"max_order={max_order} must be >= 0")
    if required.shape != theta.shape or not np.all(np.isfinite(required)) or np.any(required < 0):
        raise ModelError(
            "the per-bin requirement must be finite and >= 0 at every bin: a bin that no "
            "weight explains cannot be covered (calibrate the noise too)"
        )
    pos = required > 0.0
    if not np.any(pos):
        return FittedWeight((0.0,), (1.0,), 0, (), (), 0.0, np.zeros(theta.size), margin, 0.0)
    th, req = theta[pos], required[pos] * margin
    omega = th / ts_s
    log_req = np.log(req)
    band = omega[omega > 0.0] if np.any(omega > 0.0) else np.array([1.0 / ts_s])
    lo_w = math.log(float(band.min()) / 2.0)
    hi_w = math.log(math.pi / ts_s)

    w2 = omega[:, None] ** 2
    add = np.add.reduce

    # the excess runs thousands of times per fit: bare ufuncs (the same operations as
    # np.clip, np.sum and np.mean, without their dispatch)
    def cont_log_shape(x: np.ndarray) -> np.ndarray:
        k = x.size // 2
        corners = np.exp(np.minimum(np.maximum(x, lo_w), hi_w))
        terms = np.log1p(w2 / corners**2)  # zeros' columns, then poles'
        return 0.5 * (add(terms[:, :k], axis=1) - add(terms[:, k:], axis=1))

    def excess(x: np.ndarray) -> float:
        shape = cont_log_shape(x)
        return float(add(np.maximum.reduce(log_req - shape) + shape - log_req) / shape.size)

    fits = []
    for order in range(max_order + 1):
        starts = np.log(
            np.geomspace(float(band.min()), float(band.max()) * 1.01, max(4, 2 * order))
        )
        if order == 0:
            x = np.zeros(0)
        else:
            best = None
            # starts: the zeros and poles at distinct corners spread across the band; the
            # excess is symmetric in the zeros and in the poles, so a start that only reorders
            # them repeats a search (its iterates reordered): each is run once
            tried = set()
            for combo in itertools.islice(itertools.permutations(starts, 2 * order), 24):
                key = (tuple(sorted(combo[:order])), tuple(sorted(combo[order:])))
                if key in tried:
                    continue
                tried.add(key)
                res = scipy.optimize.minimize(
                    excess, np.array(combo), method="Nelder-Mead",
                    options={"xatol": 1e-4, "fatol": 1e-7, "maxiter": 400 * order},
                )  # fmt: skip
                if best is None or res.fun < best.fun:
                    best = res
            assert best is not None
            x = np.clip(best.x, lo_w, hi_w)
        zeros, poles = np.exp(x[:order]), np.exp(x[order:])
        num, den = _coefficients(1.0, zeros, poles)
        shape = _discrete_gain(num, den, th, ts_s, intersample)
        gain = float(np.max(req / shape))
        mag = gain * shape
        fits.append(
            (float(np.mean(20.0 * np.log10(mag / required[pos]))), order, gain, zeros, poles)
        )
    best_excess = min(f[0] for f in fits)
    mean_db, order, gain, zeros, poles = next(
        f for f in fits if f[0] <= best_excess + order_tolerance_db
    )
    num, den = _coefficients(gain, zeros, poles)
    magnitude = _discrete_gain(num, den, theta, ts_s, intersample)
    return FittedWeight(
        tuple(float(v) for v in num),
        tuple(float(v) for v in den),
        order,
        tuple(float(v) for v in zeros),
        tuple(float(v) for v in poles),
        gain,
        magnitude,
        margin,
        mean_db,
    )
