"""Linearisations of the rig's nonlinear model at an operating point (Models A and B).

Model B is the MIMO linearisation of the nonlinear balances of :mod:`twotank_validation.sim.rig`
(by complex-step differentiation); Model A is the paper's decoupled model (the level-to-
temperature coupling removed). Faults are not in the linearisations.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from twotank_validation.errors import DimensionError, ModelError
from twotank_validation.sim.rig import (
    Coefficients,
    FloatArray,
    OperatingPoint,
    RigParams,
    frozen_array,
    nominal_rhs,
    op_state,
    output,
)

_COMPLEX_STEP = 1e-20


def _jacobian(
    func: Callable[[Sequence[complex]], Sequence[complex]], point: Sequence[float]
) -> FloatArray:
    """Jacobian of an analytic ``func`` at real ``point`` by complex step (exact to rounding).

    Returns:
        (n_outputs, n_inputs) float.
    """
    columns = []
    for j in range(len(point)):
        z = [complex(v) for v in point]
        z[j] += 1j * _COMPLEX_STEP
        columns.append([v.imag / _COMPLEX_STEP for v in func(z)])
    return np.array(columns, dtype=np.float64).T


@dataclass(frozen=True, eq=False)
class LinearModel:
    """Continuous-time state-space model in deviations from an operating point.

    Frozen, with read-only arrays; compared by identity (``eq=False``: arrays have no scalar
    equality).

    dx/dt = a x + b u, y = c x + d u, with u = [hot, cold] command deviations and
    y = [height, temperature] deviations, all in model units, time in seconds.

    Attributes:
        a: (n_states, n_states) float.
        b: (n_states, n_inputs) float.
        c: (n_outputs, n_states) float.
        d: (n_outputs, n_inputs) float.
        state_names: n_states names.
        input_names: n_inputs names.
        output_names: n_outputs names.
    """

    a: FloatArray
    b: FloatArray
    c: FloatArray
    d: FloatArray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...] = ("hot", "cold")
    output_names: tuple[str, ...] = ("height", "temperature")

    def __post_init__(self) -> None:
        for name in ("a", "b", "c", "d"):
            object.__setattr__(self, name, frozen_array(getattr(self, name), f"LinearModel.{name}"))
            if getattr(self, name).ndim != 2:
                raise DimensionError(
                    f"LinearModel.{name} must be 2-D, found shape {getattr(self, name).shape}"
                )
        n, m, p = len(self.state_names), len(self.input_names), len(self.output_names)
        expected = {"a": (n, n), "b": (n, m), "c": (p, n), "d": (p, m)}
        for name, shape in expected.items():
            found = getattr(self, name).shape
            if found != shape:
                raise DimensionError(
                    f"LinearModel.{name} has shape {found}, expected {shape} from "
                    f"{n} state, {m} input and {p} output names"
                )

    def dc_gain(self) -> FloatArray:
        """Return the steady-state gain -c a^-1 b + d, (n_outputs, n_inputs) float.

        Raises:
            ModelError: If ``a`` is singular (the model has an integrator).
        """
        try:
            return np.asarray(-self.c @ np.linalg.solve(self.a, self.b) + self.d)
        except np.linalg.LinAlgError as exc:
            raise ModelError("LinearModel.a is singular: the DC gain is infinite") from exc


def linearise_model_b(params: RigParams, op: OperatingPoint) -> LinearModel:
    """Linearise the full nonlinear model (the paper's Model B) at ``op``.

    The matrices are the complex-step Jacobians of the same right-hand side and output
    functions that TankSimulator integrates. The mixing delay and lag are not included.

    Args:
        params: Rig parameters.
        op: Operating point (an equilibrium of ``params``).

    Returns:
        Model with states [hot_flow, cold_flow, height, energy] (E1 = h1 t1),
        inputs [hot, cold], outputs [height, temperature].
    """
    k = Coefficients.of(params)
    point = [*op_state(op), op.hot_flow, op.cold_flow]

    def f(z: Sequence[complex]) -> Sequence[complex]:
        return nominal_rhs(k, z[0], z[1], z[2], z[3], z[4], z[5])

    def g(z: Sequence[complex]) -> Sequence[complex]:
        return output(z[2], z[3])

    jf = _jacobian(f, point)
    jg = _jacobian(g, point)
    return LinearModel(
        a=jf[:, :4],
        b=jf[:, 4:],
        c=jg[:, :4],
        d=jg[:, 4:],
        state_names=("hot_flow", "cold_flow", "height", "energy"),
    )


def linearise_model_a(params: RigParams, op: OperatingPoint) -> LinearModel:
    """Linearise the paper's decoupled Model A at ``op``.

    The height channel is the mass-balance Jacobian (identical to Model B). The temperature
    channel is the energy balance with h1 held at its operating value (so f1 is constant):
    A1 h1 dt1/dt = f_h t_h + f_c t_c - f1 t1, which at the paper's point gives
    t1 = 1.25 / (1 + 53.8 s) f_h and h1 = 1.34 / (1 + 122.5 s) (f_h + f_c), each times the
    valve lag. Both channels are Jacobians of the simulator's right-hand side.

    Args:
        params: Rig parameters.
        op: Operating point (an equilibrium of ``params``).

    Returns:
        Model with states [hot_flow, cold_flow, height, temperature], inputs [hot, cold],
        outputs [height, temperature].
    """
    k = Coefficients.of(params)
    h0 = op.height
    point = [op.hot_flow, op.cold_flow, op.height, op.temperature, op.hot_flow, op.cold_flow]

    def f(z: Sequence[complex]) -> Sequence[complex]:
        dfh, dfc, dh, _ = nominal_rhs(k, z[0], z[1], z[2], h0 * z[3], z[4], z[5])
        # Height held: E1 = h0 t1, so dt1/dt = dE1/dt / h0 with h1 = h0 in the energy balance.
        de_held = nominal_rhs(k, z[0], z[1], complex(h0), h0 * z[3], z[4], z[5])[3]
        return (dfh, dfc, dh, de_held / h0)

    jf = _jacobian(f, point)
    c = np.zeros((2, 4))
    c[0, 2] = 1.0
    c[1, 3] = 1.0
    return LinearModel(
        a=jf[:, :4],
        b=jf[:, 4:],
        c=c,
        d=np.zeros((2, 2)),
        state_names=("hot_flow", "cold_flow", "height", "temperature"),
    )
