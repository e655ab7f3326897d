"""Nonlinear model of tank 1 of the Caltech two-tank rig: parameters, operating points, balances.

The physics follows R. S. Smith, "Model validation for robust control: an experimental
process control application", Automatica 31(11), 1995. All signals are in the paper's
scaled "model units", nominally in [0, 1]; time is in seconds.

States of the nonlinear model, in this order:

* ``hot_flow``, ``cold_flow``: actual valve flows f_h, f_c, each a first-order lag
  ``1 / (1 + valve_tau_s s)`` of its saturated command,
* ``height``: tank level h1, from the mass balance ``A1 dh1/dt = f_h + f_c - f1`` with the
  outlet law ``f1 = (h1 + beta) / alpha``,
* ``energy``: E1 = h1 t1, from ``A1 dE1/dt = f_h t_h + f_c t_c - f1 t1``.

The outputs are the level h1 and the bulk temperature t1 = E1 / h1. Here: the rig's
parameters (:class:`RigParams`), its operating points (:func:`operating_point`) and the
nominal right-hand side the simulator and the linearisations share (:func:`nominal_rhs`).
The simulator, with the rig's unmodelled physics, sensor noise and faults, is
:mod:`twotank_validation.sim.simulator`; the linearisations are
:mod:`twotank_validation.sim.linearise`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, TypeVar

import numpy as np
from numpy.typing import NDArray

from twotank_validation.errors import ModelError

__all__ = [
    "MODEL_HEIGHT_RANGE",
    "OperatingPoint",
    "RigParams",
    "operating_point",
]

FloatArray = NDArray[np.float64]

MODEL_HEIGHT_RANGE: tuple[float, float] = (0.15, 0.75)
"""Levels (model units) over which the outlet law h1 = alpha f1 - beta was fitted."""

_T = TypeVar("_T", float, complex)


def frozen_array(value: object, name: str) -> FloatArray:
    """Return a read-only float64 copy of ``value``; raise ModelError if it is not finite."""
    arr = np.array(value, dtype=np.float64, copy=True)
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} contains NaN or inf: {arr!r}; pass finite numbers")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class RigParams:
    """Physical parameters of tank 1, its actuators and its sensors (model units, seconds).

    Attributes:
        area: Tank cross-section A1 (model units of flow time per level), > 0.
        outlet_alpha: Outlet law slope alpha in h1 = alpha f1 - beta, > 0.
        outlet_beta: Outlet law offset beta, finite.
        hot_supply_temp: Hot supply temperature t_h, > cold_supply_temp.
        cold_supply_temp: Cold supply temperature t_c.
        valve_tau_s: Time constant of each valve's first-order lag, > 0, seconds.
        mixing_delay_s: Transport delay of the measured temperature at level
            ``mixing_ref_level``, >= 0, seconds; the delay is proportional to the level.
            0 switches the delay off.
        mixing_ref_level: Level at which the delay equals ``mixing_delay_s``, > 0.
        mixing_lag_s: Time constant of a first-order lag after the delay, >= 0, seconds;
            0 switches it off.
        noise_std_height: Standard deviation of the level sensor noise, >= 0.
        noise_std_temperature: Standard deviation of the temperature sensor noise, >= 0.
        ambient_temperature: Ambient temperature (model units) towards which a ``heat_loss``
            fault or ``heat_loss_coeff`` cools the tank.
        leak_per_level: A permanent leak whose outflow grows with the level,
            ``leak_per_level * h1`` (model flow units per level unit), >= 0; 0 = none. Unlike
            the constant ``leak`` fault it changes the level dynamics (an undeclared effect for
            the diagnosis of Models A and B). :func:`operating_point` raises the inflows to hold
            the level.
        heat_loss_coeff: Permanent heat loss to ambient, ``q (t1 - ambient_temperature)`` in
            the energy balance (model flow units), >= 0; 0 = none. :func:`operating_point`
            retunes the inflows to hold the temperature.
    """

    area: float = 91.4
    outlet_alpha: float = 1.34
    outlet_beta: float = 0.6
    hot_supply_temp: float = 1.0
    cold_supply_temp: float = 0.0
    valve_tau_s: float = 0.05
    mixing_delay_s: float = 0.0
    mixing_ref_level: float = 0.47
    mixing_lag_s: float = 0.0
    noise_std_height: float = 0.0
    noise_std_temperature: float = 0.0
    ambient_temperature: float = 0.3
    leak_per_level: float = 0.0
    heat_loss_coeff: float = 0.0

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ModelError(f"RigParams.{name}={value!r} is not a real number; pass a float")
            if not math.isfinite(value):
                raise ModelError(f"RigParams.{name}={value!r} is not finite; pass a finite float")
        for name in ("area", "outlet_alpha", "valve_tau_s", "mixing_ref_level"):
            if getattr(self, name) <= 0.0:
                raise ModelError(
                    f"RigParams.{name}={getattr(self, name)!r} must be positive; "
                    "pass a value > 0 in model units / seconds"
                )
        for name in (
            "mixing_delay_s",
            "mixing_lag_s",
            "noise_std_height",
            "noise_std_temperature",
            "leak_per_level",
            "heat_loss_coeff",
        ):
            if getattr(self, name) < 0.0:
                raise ModelError(
                    f"RigParams.{name}={getattr(self, name)!r} must be >= 0 (0 switches it off)"
                )
        if self.hot_supply_temp <= self.cold_supply_temp:
            raise ModelError(
                f"RigParams.hot_supply_temp={self.hot_supply_temp!r} must exceed "
                f"cold_supply_temp={self.cold_supply_temp!r}, otherwise the temperature "
                "cannot be controlled; swap or correct them"
            )

    def outlet_flow(self, height: float) -> float:
        """Return the outlet flow f1 = (h1 + beta) / alpha (model units) at level ``height``."""
        return (height + self.outlet_beta) / self.outlet_alpha

    def mixing_delay_at(self, height: float) -> float:
        """Return the measured-temperature transport delay (seconds) at level ``height``."""
        return self.mixing_delay_s * height / self.mixing_ref_level


@dataclass(frozen=True)
class OperatingPoint:
    """An equilibrium of tank 1 (model units).

    Attributes:
        height: Level h1, > 0.
        temperature: Bulk temperature t1.
        hot_flow: Hot valve flow f_h in [0, 1] (equal to its command at equilibrium).
        cold_flow: Cold valve flow f_c in [0, 1].
        out_flow: Outlet flow f1; must equal hot_flow + cold_flow (mass balance) to 1e-6.
    """

    height: float
    temperature: float
    hot_flow: float
    cold_flow: float
    out_flow: float

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ModelError(f"OperatingPoint.{name}={value!r} is not a real number")
            if not math.isfinite(value):
                raise ModelError(f"OperatingPoint.{name}={value!r} is not finite")
        if self.height <= 0.0:
            raise ModelError(f"OperatingPoint.height={self.height!r} must be positive")
        for name in ("hot_flow", "cold_flow"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ModelError(
                    f"OperatingPoint.{name}={value!r} is outside the valve range [0, 1]"
                )
        imbalance = self.hot_flow + self.cold_flow - self.out_flow
        if abs(imbalance) > 1e-6:
            raise ModelError(
                f"OperatingPoint is not an equilibrium: hot_flow + cold_flow - out_flow = "
                f"{imbalance:.3g}; build it with operating_point(params, height, temperature)"
            )

    @property
    def commands(self) -> FloatArray:
        """(2,) float, model units: the valve commands [hot, cold] that hold this point."""
        return np.array([self.hot_flow, self.cold_flow], dtype=np.float64)

    @property
    def energy(self) -> float:
        """The energy state E1 = h1 t1 at this point (model units)."""
        return self.height * self.temperature


def operating_point(
    params: RigParams, height: float = 0.47, temperature: float = 0.5
) -> OperatingPoint:
    """Return the equilibrium of tank 1 at a given level and temperature.

    At equilibrium f_h + f_c = F = (h1 + beta) / alpha + lambda h1 (outlet plus the permanent
    leak ``leak_per_level``) and f_h t_h + f_c t_c = F t1 + q (t1 - t_amb) (permanent heat loss
    ``heat_loss_coeff``), so f_h = (F (t1 - t_c) + q (t1 - t_amb)) / (t_h - t_c), f_c = F - f_h.

    Args:
        params: Rig parameters.
        height: Level h1 (model units), within MODEL_HEIGHT_RANGE = (0.15, 0.75).
        temperature: Bulk temperature t1 (model units).

    Returns:
        The operating point.

    Raises:
        ModelError: If the level is outside the model's valid range or if holding the point
            needs a valve flow outside [0, 1].
    """
    if not (math.isfinite(height) and math.isfinite(temperature)):
        raise ModelError(f"height={height!r} and temperature={temperature!r} must be finite")
    lo, hi = MODEL_HEIGHT_RANGE
    if not lo <= height <= hi:
        raise ModelError(
            f"height={height!r} is outside the range {lo}..{hi} over which the outlet law "
            "h1 = alpha f1 - beta is valid; choose a level inside it"
        )
    out_flow = params.outlet_flow(height) + params.leak_per_level * height
    span = params.hot_supply_temp - params.cold_supply_temp
    loss = params.heat_loss_coeff * (temperature - params.ambient_temperature)
    hot_flow = (out_flow * (temperature - params.cold_supply_temp) + loss) / span
    cold_flow = out_flow - hot_flow
    for name, value in (("hot", hot_flow), ("cold", cold_flow)):
        if not 0.0 <= value <= 1.0:
            raise ModelError(
                f"height={height!r}, temperature={temperature!r} needs {name} flow "
                f"{value:.4g}, outside the valve range [0, 1]; choose a temperature between "
                f"the supply temperatures {params.cold_supply_temp} and "
                f"{params.hot_supply_temp} and a lower level"
            )
    return OperatingPoint(
        height=float(height),
        temperature=float(temperature),
        hot_flow=hot_flow,
        cold_flow=cold_flow,
        out_flow=out_flow,
    )


# --- the nonlinear right-hand side, shared by the simulator and the linearisations -----------


class Coefficients(NamedTuple):
    """Precomputed constants of the right-hand side (plain floats, for speed)."""

    inv_tau: float
    inv_area: float
    inv_alpha: float
    beta: float
    hot_temp: float
    cold_temp: float
    leak_per_level: float
    heat_loss: float
    ambient: float

    @classmethod
    def of(cls, params: RigParams) -> Coefficients:
        return cls(
            inv_tau=1.0 / params.valve_tau_s,
            inv_area=1.0 / params.area,
            inv_alpha=1.0 / params.outlet_alpha,
            beta=params.outlet_beta,
            hot_temp=params.hot_supply_temp,
            cold_temp=params.cold_supply_temp,
            leak_per_level=params.leak_per_level,
            heat_loss=params.heat_loss_coeff,
            ambient=params.ambient_temperature,
        )


def nominal_rhs(  # noqa: PLR0917 - positional floats: this is the simulator's hot loop
    k: Coefficients, fh: _T, fc: _T, h: _T, e: _T, uh: _T, uc: _T
) -> tuple[_T, _T, _T, _T]:
    """Time derivative of [f_h, f_c, h1, E1] under saturated commands [uh, uc].

    Written with arithmetic only so that it is analytic: the linearisations differentiate it
    by complex step.
    """
    out = (h + k.beta) * k.inv_alpha + k.leak_per_level * h
    t = e / h
    return (
        (uh - fh) * k.inv_tau,
        (uc - fc) * k.inv_tau,
        (fh + fc - out) * k.inv_area,
        (fh * k.hot_temp + fc * k.cold_temp - out * t - k.heat_loss * (t - k.ambient)) * k.inv_area,
    )


def output(h: _T, e: _T) -> tuple[_T, _T]:
    """Bulk outputs [h1, t1 = E1 / h1] of the state."""
    return (h, e / h)


def op_state(op: OperatingPoint) -> list[float]:
    """Return the state (hot_flow, cold_flow, height, energy) at ``op``, model units."""
    return [op.hot_flow, op.cold_flow, op.height, op.energy]
