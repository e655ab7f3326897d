"""The two-tank rig's physical parameters fitted to a measured frequency response (grey box).

The paper's route (Smith 1995, Sec. 3): a first-principles model whose physical parameters
are estimated from the rig's data, then linearised. Here the model is the rig's nonlinear
balances (:mod:`twotank_validation.sim.rig`) linearised at the measured operating point
(:func:`~twotank_validation.sim.linearise.linearise_model_b`, Model B), with the measured
temperature's mixing delay (proportional to the level) and lag; its response at the DFT bins
under a zero-order hold (the valve commands are held between samples) is fitted to the
measured response ``H`` by weighted least squares,

    ``V(theta) = sum_k sum_ij |H_ij(k) - G_ij(k, theta)|^2 / var_ij(k)``,

with ``scipy.optimize.least_squares`` (the maximum-likelihood cost for circular complex
Gaussian errors of known variance, as :mod:`twotank_validation.identify.fit`). Each
parameter's standard deviation comes from the Jacobian at the optimum,
``cov = (J^T J)^-1 / 2`` (each real component of a unit-variance circular residual has
variance 1/2), inflated by ``sqrt(2 V / dof)`` when the residual exceeds what the response's
σ explains. A parameter the data do not determine (its standard deviation above a third of
its scale) is pinned at its prior value and the rest refitted: it is reported as pinned, not
as an estimate (docs/theory.md §17).

The operating point (level ``h0``, temperature ``t0``) is measured (the outputs' means), not
fitted. At it the response is, valve lag aside,

    ``height / f = alpha / (1 + A alpha s)`` (both valves),
    ``temperature / f_h = ((t_h - t0) / F) / (1 + (A h0 / F) s)``, ``F = (h0 + beta) / alpha``,

and likewise for ``f_c`` with ``t_c``: ``alpha`` and ``A`` from the level, then ``F`` (so
``beta``), ``t_h`` and ``t_c`` from the temperature; every one is identifiable from a 2 x 2
response that resolves both time constants.

Units: the rig's model units and seconds (:class:`~twotank_validation.sim.rig.RigParams`);
frequencies in Hz.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize

from twotank_validation.core import lti
from twotank_validation.core.lti import Intersample, StateSpace
from twotank_validation.errors import IdentificationError, ModelError
from twotank_validation.identify.nonparametric import FrequencyResponse
from twotank_validation.sim.linearise import linearise_model_b
from twotank_validation.sim.rig import OperatingPoint, RigParams, operating_point

__all__ = [
    "GREY_BOX_PARAMETERS",
    "GreyBoxConfig",
    "GreyBoxFit",
    "GreyBoxModel",
    "ParameterEstimate",
    "ParameterStatus",
    "fit_two_tank",
]


class GreyBoxModel(enum.StrEnum):
    """A first-principles model whose parameters ``identify --grey-box`` fits."""

    TWO_TANK = "two-tank"
    """Tank 1 of the two-tank rig: inputs [hot, cold] valve, outputs [height, temperature]."""


class ParameterStatus(enum.StrEnum):
    """What the fit says about a parameter."""

    FITTED = "fitted"
    """Estimated; the data determine it (σ below a third of its scale)."""
    UNDETERMINED = "not determined"
    """Tried and not determined by the data in the band: pinned at its prior value."""
    PINNED = "pinned"
    """Not tried (not in ``GreyBoxConfig.free``): its prior value."""


GREY_BOX_PARAMETERS: tuple[str, ...] = (
    "area",
    "outlet_alpha",
    "outlet_beta",
    "hot_supply_temp",
    "cold_supply_temp",
    "mixing_delay_s",
    "mixing_lag_s",
    "valve_tau_s",
)
"""The RigParams fields the two-tank grey box may fit (the rest are not in its response)."""

_DETERMINED = 3.0
"""A parameter is determined when its standard deviation is below its scale / _DETERMINED."""
_OFF_RANGE = 1e6
"""Each weighted residual where the parameters leave the valves' range (far above any fit)."""
_INPUTS = 2
_OUTPUTS = 2


@dataclass(frozen=True)
class GreyBoxConfig:
    """Settings of the two-tank grey-box fit.

    Attributes:
        prior: the start of the fit and the value of every parameter not fitted (the
            paper's rig by default; the sensor noise and fault fields play no part).
        free: the parameters tried (a subset of :data:`GREY_BOX_PARAMETERS`).
        height: the operating level h0 (model units), the outputs' mean.
        temperature: the operating temperature t0 (model units), the outputs' mean.
    """

    height: float
    temperature: float
    prior: RigParams = field(default_factory=RigParams)
    free: tuple[str, ...] = GREY_BOX_PARAMETERS

    def __post_init__(self) -> None:
        unknown = [p for p in self.free if p not in GREY_BOX_PARAMETERS]
        if unknown:
            raise IdentificationError(
                f"grey box: {unknown} cannot be fitted; choose among {GREY_BOX_PARAMETERS}"
            )
        if not (math.isfinite(self.height) and math.isfinite(self.temperature)):
            raise IdentificationError("grey box: the operating point must be finite")


@dataclass(frozen=True)
class ParameterEstimate:
    """One physical parameter after the fit.

    Attributes:
        name: the RigParams field.
        value: the estimate (``FITTED``) or the prior (otherwise), model units / seconds.
        std: its standard deviation (NaN when pinned).
        status: fitted, not determined (pinned) or pinned.
        prior: the prior value.
    """

    name: str
    value: float
    std: float
    status: ParameterStatus
    prior: float

    def to_json(self) -> dict[str, object]:
        """``{"name", "value", "std", "status", "prior"}`` (std None when pinned)."""
        return {
            "name": self.name,
            "value": self.value,
            "std": None if math.isnan(self.std) else self.std,
            "status": self.status.value,
            "prior": self.prior,
        }


@dataclass(frozen=True)
class GreyBoxFit:
    """The fitted rig, its linearisation and how well it explains the response.

    Attributes:
        params: the rig with the fitted parameters (the rest its prior's).
        op: the operating point the linearisation is taken at.
        estimates: every parameter of :data:`GREY_BOX_PARAMETERS`, in that order.
        covariance: (n_fitted, n_fitted) the fitted parameters' covariance (the order of
            ``fitted``), inflated as the module says.
        fitted: the names of the fitted parameters.
        cost: ``V`` at the optimum.
        n_eq: real equations (twice the complex ones).
        ts_s: the sample period the response is evaluated at (zero-order hold).
    """

    params: RigParams
    op: OperatingPoint
    estimates: tuple[ParameterEstimate, ...]
    covariance: np.ndarray
    fitted: tuple[str, ...]
    cost: float
    n_eq: int
    ts_s: float

    intersample = Intersample.ZOH
    """The valve commands are held between samples: the nominal is written with ``zoh``."""

    @property
    def n_par(self) -> int:
        """Fitted parameters."""
        return len(self.fitted)

    @property
    def dof(self) -> int:
        """Real degrees of freedom left for the noise."""
        return max(self.n_eq - self.n_par, 1)

    @property
    def cost_ratio(self) -> float:
        """``2 V / dof``: about 1 when the response's σ explains the residual."""
        return 2.0 * self.cost / self.dof

    def estimate(self, name: str) -> ParameterEstimate:
        """The estimate of one parameter by its RigParams name."""
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(name)

    def state_space(self) -> StateSpace:
        """Model B at the operating point, the mixing lag appended, the delay on temperature."""
        return _state_space(self.params, self.op)

    def response(self, freqs_hz: np.ndarray) -> np.ndarray:
        """(L, 2, 2) complex: the nominal at the bins of ``freqs_hz`` under a zero-order hold."""
        theta = 2 * math.pi * np.asarray(freqs_hz, dtype=float) * self.ts_s
        return lti.bin_response(self.state_space(), theta, self.ts_s, Intersample.ZOH)

    def to_json(self) -> dict[str, object]:
        """The fit as JSON: the operating point, each parameter ± σ, the residual."""
        return {
            "model": GreyBoxModel.TWO_TANK.value,
            "operating_point": {"height": self.op.height, "temperature": self.op.temperature},
            "parameters": [e.to_json() for e in self.estimates],
            "cost_ratio": self.cost_ratio,
            "correlation": _correlation(self.covariance).tolist(),
            "fitted": list(self.fitted),
        }


def _correlation(cov: np.ndarray) -> np.ndarray:
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = cov / np.outer(sd, sd)
    return np.where(np.isfinite(out), out, 0.0)


def _state_space(params: RigParams, op: OperatingPoint) -> StateSpace:
    """Model B of ``params`` at ``op`` (states [f_h, f_c, h1, E1]), as the rig measures it.

    The measured temperature's first-order lag is a fifth state when ``mixing_lag_s > 0``;
    its mixing delay at ``op.height`` is the temperature output's delay.
    """
    lin = linearise_model_b(params, op)
    a, b, c, d = lin.a, lin.b, lin.c, lin.d
    if params.mixing_lag_s > 0.0:
        k = 1.0 / params.mixing_lag_s
        n = a.shape[0]
        a = np.block([[a, np.zeros((n, 1))], [k * c[1:2], -k * np.ones((1, 1))]])
        b = np.vstack([b, k * d[1:2]])
        c = np.vstack(
            [np.hstack([c[0:1], np.zeros((1, 1))]), np.hstack([np.zeros((1, n)), np.ones((1, 1))])]
        )
        d = np.vstack([d[0:1], np.zeros((1, d.shape[1]))])
    delay = params.mixing_delay_at(op.height)
    return StateSpace(a, b, c, d, output_delays_s=(0.0, delay) if delay > 0 else ())


def _scale(name: str, params: RigParams, op: OperatingPoint) -> float:
    """The size a parameter's σ is judged against (docs/theory.md §17)."""
    if name == "outlet_beta":  # the outflow F = (h0 + beta) / alpha sets beta's scale
        return op.height + params.outlet_beta
    if name in ("hot_supply_temp", "cold_supply_temp"):  # an affine scale: the span
        return params.hot_supply_temp - params.cold_supply_temp
    return abs(float(getattr(params, name)))


def _bounds(name: str, height: float, temperature: float) -> tuple[float, float]:
    """Where the parameter keeps the operating point an equilibrium the valves can hold."""
    if name == "outlet_beta":
        return (-height + 1e-6, math.inf)
    if name == "hot_supply_temp":
        return (temperature + 1e-6, math.inf)
    if name == "cold_supply_temp":
        return (-math.inf, temperature - 1e-6)
    if name in ("mixing_delay_s", "mixing_lag_s"):
        return (0.0, math.inf)
    return (1e-9, math.inf)


def _rig(prior: RigParams, names: tuple[str, ...], x: np.ndarray) -> RigParams:
    return dataclasses.replace(prior, **{n: float(v) for n, v in zip(names, x, strict=True)})


def _check(fr: FrequencyResponse) -> tuple[np.ndarray, np.ndarray]:
    """The response's entries and weights ``1 / σ`` (L, 4)."""
    if fr.g.shape[1:] != (_OUTPUTS, _INPUTS):
        raise IdentificationError(
            f"the two-tank grey box needs a 2 x 2 response (inputs [hot, cold] valve, outputs "
            f"[height, temperature]); this one is {fr.g.shape[1]} x {fr.g.shape[2]}: map the "
            "channels in that order (--map) or leave out --grey-box"
        )
    var = fr.var.reshape(fr.g.shape[0], -1)
    if not (np.all(np.isfinite(var)) and np.all(var > 0)):
        raise IdentificationError(
            "the grey box is weighted by the response's σ, and this response has none: "
            "record two or more periods"
        )
    return fr.g.reshape(fr.g.shape[0], -1), 1.0 / np.sqrt(var)


def fit_two_tank(fr: FrequencyResponse, ts_s: float, config: GreyBoxConfig) -> GreyBoxFit:
    """The two-tank rig's physical parameters fitted to the measured response.

    The parameters in ``config.free`` are fitted from ``config.prior``; the one the data
    determine least (largest σ over its scale) is pinned at its prior and the rest refitted,
    until every fitted parameter is determined.

    Args:
        fr: the measured response, (L, 2, 2): inputs [hot, cold] valve commands, outputs
            [height, temperature], model units; its ``var`` weights the fit.
        ts_s: the sample period (s); the model is evaluated at the bins under a zero-order
            hold.
        config: the operating point, the prior and the parameters tried.

    Raises:
        IdentificationError: not a 2 x 2 response, no σ, an operating point the prior's
            valves cannot hold, or a fit that leaves the rig's valid range.
    """
    h, w = _check(fr)
    theta = 2 * math.pi * fr.freqs_hz * ts_s
    h0, t0 = config.height, config.temperature
    try:
        operating_point(config.prior, h0, t0)
    except ModelError as err:
        raise IdentificationError(f"grey box: {err}") from err
    free = tuple(config.free)
    start = config.prior
    while True:
        fit = _fit(h, w, theta, ts_s, config, free, start)
        if fit is None:
            raise IdentificationError(
                "grey box: the fit left the rig's valid range (a valve flow outside [0, 1] at "
                "the operating point); start from a prior closer to this rig"
            )
        x, cov, cost = fit
        params = _rig(config.prior, free, x)
        op = operating_point(params, h0, t0)
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        ratio = sd / np.array([max(_scale(n, params, op), 1e-300) for n in free])
        worst = int(np.argmax(ratio)) if free else -1
        if not free or ratio[worst] < 1.0 / _DETERMINED:
            break
        free = free[:worst] + free[worst + 1 :]
        # the next fit starts where this one ended, the pinned parameter back at its prior
        start = _rig(config.prior, free, np.delete(x, worst))
    estimates = []
    for name in GREY_BOX_PARAMETERS:
        prior = float(getattr(config.prior, name))
        if name in free:
            i = free.index(name)
            estimates.append(
                ParameterEstimate(name, float(x[i]), float(sd[i]), ParameterStatus.FITTED, prior)
            )
        else:
            status = ParameterStatus.UNDETERMINED if name in config.free else ParameterStatus.PINNED
            estimates.append(ParameterEstimate(name, prior, math.nan, status, prior))
    return GreyBoxFit(
        params=params,
        op=op,
        estimates=tuple(estimates),
        covariance=cov,
        fitted=free,
        cost=cost,
        n_eq=2 * h.size,
        ts_s=ts_s,
    )


def _fit(  # noqa: PLR0917 - private, one caller
    h: np.ndarray,
    w: np.ndarray,
    theta: np.ndarray,
    ts_s: float,
    config: GreyBoxConfig,
    free: tuple[str, ...],
    start: RigParams,
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """``(x, cov, V)`` of the weighted least squares over ``free``; None off the valid range."""
    h0, t0 = config.height, config.temperature

    def residual(x: np.ndarray) -> np.ndarray:
        params = _rig(config.prior, free, x)
        try:
            op = operating_point(params, h0, t0)
        except ModelError:  # the valves cannot hold the point: a step the trust region rejects
            return np.full(2 * h.size, _OFF_RANGE)
        g = lti.bin_response(_state_space(params, op), theta, ts_s, Intersample.ZOH)
        r = w * (g.reshape(h.shape) - h)
        return np.concatenate([r.real, r.imag]).ravel()

    x0 = np.array([float(getattr(start, n)) for n in free])
    if not free:
        r = residual(x0)
        return x0, np.zeros((0, 0)), float(np.sum(r**2) / 2)
    lo, hi = np.array([_bounds(n, h0, t0) for n in free]).T
    inside = 1e-9 * np.maximum(np.abs(x0), 1.0)
    x0 = np.clip(x0, np.where(np.isfinite(lo), lo + inside, lo), hi)
    sol = scipy.optimize.least_squares(residual, x0, bounds=(lo, hi), x_scale="jac")
    if np.any(sol.fun == _OFF_RANGE):
        return None
    cost = float(np.sum(sol.fun**2))  # V = sum |r|^2 over the complex residuals
    jac = sol.jac
    n_eq = sol.fun.size
    dof = max(n_eq - len(free), 1)
    inflate = max(2.0 * cost / dof, 1.0)
    cov = np.linalg.pinv(jac.T @ jac) / 2.0 * inflate
    return sol.x, cov, cost
