"""The simulator of the two-tank rig: the nonlinear plant stepped sample by sample, with faults.

:class:`TankSimulator` integrates the balances of :mod:`twotank_validation.sim.rig` (RK4
substeps) and adds the rig's unmodelled physics on the measured temperature (a
level-dependent transport delay and an optional mixing lag) and white Gaussian sensor noise.
Neither is in the linear models. :func:`simulate` runs it over a command sequence
(:class:`SimResult`).

Faults and unmodelled effects (:class:`~twotank_validation.sim.faults.Fault`, kinds
:class:`~twotank_validation.sim.faults.FaultKind`) can be switched on at a given simulated time:
a leak, heat loss to ambient, a stuck, weak or saturating valve, a sensor bias or delay, a
changed mixing delay, a changed hot supply temperature. With faults the balances become

* ``A1 dh1/dt = f_h + f_c - f1 - leak``,
* ``A1 dE1/dt = f_h t_h + f_c t_c - (f1 + leak) t1 - q (t1 - t_amb)``,

with ``q`` the heat-loss coefficient, ``t_amb = RigParams.ambient_temperature`` and ``t_h``
shifted by any ``hot_supply`` fault; a weak or saturating valve changes the command its lag
follows (``g min(u, limit)``). Faults are
not in the linearisations (:mod:`twotank_validation.sim.linearise`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from twotank_validation.defaults import TS_S
from twotank_validation.errors import DatumError, DimensionError, ModelError
from twotank_validation.sim.faults import SENSOR_CHANNELS, Fault, FaultEffects, FaultKind
from twotank_validation.sim.rig import (
    Coefficients,
    FloatArray,
    OperatingPoint,
    RigParams,
    nominal_rhs,
    op_state,
    operating_point,
)

__all__ = [
    "SimResult",
    "TankSimulator",
    "simulate",
]

_MIN_SIM_HEIGHT = 1e-3
"""Below this level (model units) the tank is empty and t1 = E1 / h1 is undefined."""

_RK4_STABILITY_MARGIN = 2.5
"""Largest substep / valve_tau_s accepted (RK4 is unstable beyond about 2.785)."""


class _FaultyCoefficients(NamedTuple):
    """Constants of the right-hand side under dynamic faults (leak, heat loss, valves)."""

    inv_tau_hot: float  # 0 when the hot valve is stuck
    inv_tau_cold: float
    inv_area: float
    inv_alpha: float
    beta: float
    hot_temp: float
    cold_temp: float
    leak: float
    leak_per_level: float
    heat_loss: float
    ambient: float

    @classmethod
    def of(cls, params: RigParams, effects: FaultEffects) -> _FaultyCoefficients:
        inv_tau = 1.0 / params.valve_tau_s
        return cls(
            inv_tau_hot=0.0 if effects.stuck[0] else inv_tau,
            inv_tau_cold=0.0 if effects.stuck[1] else inv_tau,
            inv_area=1.0 / params.area,
            inv_alpha=1.0 / params.outlet_alpha,
            beta=params.outlet_beta,
            hot_temp=params.hot_supply_temp + effects.hot_supply_shift,
            cold_temp=params.cold_supply_temp,
            leak=effects.leak,
            leak_per_level=params.leak_per_level,
            heat_loss=effects.heat_loss + params.heat_loss_coeff,
            ambient=params.ambient_temperature,
        )


def _rhs_faulty(  # noqa: PLR0917 - same signature as nominal_rhs
    k: _FaultyCoefficients, fh: float, fc: float, h: float, e: float, uh: float, uc: float
) -> tuple[float, float, float, float]:
    """Time derivative of [f_h, f_c, h1, E1] under the dynamic faults in ``k``.

    ``k`` holds the leak, heat loss, stuck valves and the changed hot supply temperature. Weak
    and saturating valves are applied by the caller, which clips and scales the commands
    [uh, uc] once per sample.
    """
    out = (h + k.beta) * k.inv_alpha + k.leak_per_level * h + k.leak
    t = e / h
    return (
        (uh - fh) * k.inv_tau_hot,
        (uc - fc) * k.inv_tau_cold,
        (fh + fc - out) * k.inv_area,
        (fh * k.hot_temp + fc * k.cold_temp - out * t - k.heat_loss * (t - k.ambient)) * k.inv_area,
    )


_FAULT_TIME_TOLERANCE = 1e-9
"""Fraction of a sample by which a fault time may exceed a sample instant and still hit it."""


def _regrown(history: list[float], j: int, capacity: int, current: float) -> list[float]:
    """Return a ring buffer of ``capacity`` >= len(history) with the same values at grid index j.

    Entries older than the old buffer hold its oldest value; an unrecorded history (length
    <= 1) becomes ``current`` everywhere.
    """
    old = len(history)
    if old <= 1:
        return [current] * capacity
    grown = [history[(j + 1) % old]] * capacity  # the oldest recorded value
    for back in range(old):
        grown[(j - back) % capacity] = history[(j - back) % old]
    return grown


def _read_back(history: list[float], j: int, back: float) -> float:
    """Ring-buffer value ``back`` steps before index ``j``, linearly interpolated.

    ``history[k % len(history)]`` holds step ``k``; reads older than the buffer return its
    oldest retained value.
    """
    capacity = len(history)
    pos = j - back
    lo = math.floor(pos)
    oldest = j - capacity + 1
    if lo < oldest:
        lo, frac = oldest, 0.0
    else:
        frac = pos - lo
    return (1.0 - frac) * history[lo % capacity] + frac * history[(lo + 1) % capacity]


class TankSimulator:
    """Steppable nonlinear simulator (the ROS plant node will step it live, one sample at a time).

    The state [f_h, f_c, h1, E1] is integrated by fixed-step RK4 with ``substeps`` steps per
    sample; each command is saturated to [0, 1] and held over one sample. The bulk temperature
    is stored at every substep so that the measured temperature can be delayed by
    tau(h1) = mixing_delay_s h1 / mixing_ref_level (linear interpolation, h1 the current level),
    then passed through the optional first-order mixing lag (integrated exactly for an input
    that is linear between substeps). The simulator starts in steady state at ``op``, with the
    past bulk temperature equal to ``op.temperature``.

    Faults (:class:`Fault`) given to the constructor or to :meth:`add_fault` switch on at the
    first sample instant k ts_s >= ``onset_s`` and off at the first one >= ``end_s``; they are
    constant over a sample. Sensor faults (bias, delay) act on :meth:`measure` and
    :attr:`clean_output`, not on :attr:`state`. Without faults the simulation is bit-identical
    to that of the fault-free simulator, and with faults it is still deterministic under
    ``seed`` (faults draw no random numbers).

    Args:
        params: Rig parameters.
        ts_s: Sample period, seconds, > 0.
        op: Initial operating point; default ``operating_point(params)``.
        seed: Seed of the sensor noise generator (numpy default_rng).
        substeps: RK4 steps per sample, >= 1.
        faults: Faults to register now, as with :meth:`add_fault`.

    Raises:
        ModelError: If ``ts_s`` or ``substeps`` are invalid, if a substep exceeds 2.5 valve
            time constants (RK4 would be inaccurate or unstable), or if an element of
            ``faults`` is not a Fault.
    """

    def __init__(
        self,
        params: RigParams,
        ts_s: float = TS_S,
        *,
        op: OperatingPoint | None = None,
        seed: int = 0,
        substeps: int = 4,
        faults: Sequence[Fault] = (),
    ) -> None:
        if not (math.isfinite(ts_s) and ts_s > 0.0):
            raise ModelError(f"ts_s={ts_s!r} must be a positive, finite sample period in seconds")
        if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
            raise ModelError(f"substeps={substeps!r} must be an integer >= 1")
        dt = ts_s / substeps
        if dt > _RK4_STABILITY_MARGIN * params.valve_tau_s:
            need = math.ceil(ts_s / (_RK4_STABILITY_MARGIN * params.valve_tau_s))
            raise ModelError(
                f"substep ts_s/substeps = {dt:.4g} s exceeds {_RK4_STABILITY_MARGIN} valve time "
                f"constants ({params.valve_tau_s} s): RK4 would be unstable; use substeps >= {need}"
            )
        self._params = params
        self._op = operating_point(params) if op is None else op
        self._ts = float(ts_s)
        self._substeps = substeps
        self._dt = dt
        self._k = Coefficients.of(params)
        self._rng = np.random.default_rng(seed)
        self._noise_std = (params.noise_std_height, params.noise_std_temperature)
        self._n_samples = 0
        self._fh, self._fc, self._h, self._e = op_state(self._op)
        t0 = self._op.temperature
        # Delay history of the bulk temperature at the substep grid (ring buffer).
        self._delay_per_height = params.mixing_delay_s / params.mixing_ref_level / dt  # substeps
        # Level never exceeds max(h0, 2 alpha - beta): both valves fully open (faults only
        # lower it).
        self._h_cap = max(self._op.height, 2.0 * params.outlet_alpha - params.outlet_beta)
        if params.mixing_delay_s > 0.0:
            capacity = math.ceil(self._delay_per_height * self._h_cap) + 3
        else:
            capacity = 1
        self._history = [t0] * capacity
        self._grid_index = 0
        self._delayed = t0  # delayed bulk temperature at the current grid point
        self._measured_temp = t0  # after the mixing lag
        if params.mixing_lag_s > 0.0:
            decay = math.exp(-dt / params.mixing_lag_s)
            self._lag_decay = decay
            self._lag_ramp = 1.0 - params.mixing_lag_s / dt * (1.0 - decay)
        else:
            self._lag_decay = 0.0
            self._lag_ramp = 1.0
        # Faults: (fault, first sample index, first sample index without it), in registration
        # order. The effects are recomputed only at sample index _next_change.
        self._faults: list[tuple[Fault, float, float]] = []
        self._active: tuple[Fault, ...] = ()
        self._effects = FaultEffects()
        self._faulty_k: _FaultyCoefficients | None = None  # None: nominal dynamics
        self._next_change = -math.inf
        # Fault-free measured [height, temperature] at the substep grid (ring buffers), kept
        # only while a sensor_delay fault is registered.
        self._sensor_history: tuple[list[float], list[float]] = ([], [])
        for fault in faults:
            self.add_fault(fault)

    # --- faults -------------------------------------------------------------------------

    def add_fault(self, fault: Fault) -> None:
        """Register a fault; it takes effect at the first sample instant >= ``fault.onset_s``.

        A fault whose onset is already past (``onset_s <= time_s``) takes effect immediately:
        from the next :meth:`measure` and :meth:`step`. A ``valve_stuck`` fault freezes the
        valve at its flow at that moment. Delay faults (``sensor_delay``, ``mixing_delay``)
        need the past signal: it is retained from construction for the rig's own mixing delay
        and from registration for sensor delays, as far back as the longest delay registered
        so far needs. A delay that reaches further back (added during a run, with its onset
        closer than its delay) reads the oldest retained value instead (exact when added at the
        start, in steady state).

        Args:
            fault: The fault.

        Raises:
            ModelError: If ``fault`` is not a Fault, or if the ``hot_supply`` faults registered
                could together bring the hot supply down to the cold supply temperature.
        """
        if not isinstance(fault, Fault):
            raise ModelError(f"fault={fault!r} is not a Fault; build it with Fault(kind, ...)")
        if fault.kind is FaultKind.HOT_SUPPLY:
            params = self._params
            coolest = params.hot_supply_temp + sum(
                min(f.magnitude, 0.0)
                for f in (*self.faults, fault)
                if f.kind is FaultKind.HOT_SUPPLY
            )
            if coolest <= params.cold_supply_temp:
                raise ModelError(
                    f"hot_supply fault {fault.magnitude:g} would bring the hot supply to "
                    f"{coolest:g}, not above cold_supply_temp={params.cold_supply_temp:g}; "
                    "choose a smaller cooling (the temperature could no longer be controlled)"
                )
        tolerance = _FAULT_TIME_TOLERANCE
        first = float(math.ceil(fault.onset_s / self._ts - tolerance))
        stop = (
            math.inf if math.isinf(fault.end_s) else math.ceil(fault.end_s / self._ts - tolerance)
        )
        self._faults.append((fault, first, float(stop)))
        self._next_change = -math.inf
        if fault.kind is FaultKind.MIXING_DELAY:
            capacity = (
                math.ceil(fault.magnitude / self._params.mixing_ref_level / self._dt * self._h_cap)
                + 3
            )
            if capacity > len(self._history):
                bulk = self._e / self._h
                self._history = _regrown(self._history, self._grid_index, capacity, bulk)
        elif fault.kind is FaultKind.SENSOR_DELAY:
            total = [0.0, 0.0]
            for f, _, _ in self._faults:
                if f.kind is FaultKind.SENSOR_DELAY:
                    total[SENSOR_CHANNELS.index(f.channel)] += f.magnitude
            capacity = math.ceil(max(total) / self._dt) + 3
            hist_h, hist_t = self._sensor_history
            if capacity > len(hist_h):
                j = self._grid_index
                self._sensor_history = (
                    _regrown(hist_h, j, capacity, self._h),
                    _regrown(hist_t, j, capacity, self._measured_temp),
                )

    def clear_faults(self) -> None:
        """Remove every fault, pending or active: the rig is nominal from now on.

        The state is kept (a level lowered by a leak recovers with the tank's own dynamics);
        a stuck valve resumes following its command. The retained signal history is kept too,
        so clearing and re-adding the same faults at once (e.g. to update the list) continues
        the run exactly as if the faults had stayed registered.
        """
        self._faults.clear()
        self._active = ()
        self._effects = FaultEffects()
        self._faulty_k = None
        self._next_change = -math.inf
        self._set_mixing_delay(self._params.mixing_delay_s)

    @property
    def faults(self) -> tuple[Fault, ...]:
        """Every registered fault (past, active and pending), in registration order."""
        return tuple(f for f, _, _ in self._faults)

    @property
    def active_faults(self) -> tuple[Fault, ...]:
        """The faults in effect at the current time ``time_s``, in registration order."""
        if self._faults:
            self._refresh_faults()
        return self._active

    def _refresh_faults(self) -> None:
        """Update the active faults and their combined effect for the current sample."""
        n = self._n_samples
        if n < self._next_change:
            return
        active = []
        next_change = math.inf
        for fault, first, stop in self._faults:
            if first <= n < stop:
                active.append(fault)
                next_change = min(next_change, stop)
            elif first > n:
                next_change = min(next_change, first)
        self._next_change = next_change
        self._active = tuple(active)
        effects = FaultEffects.of(active)
        self._effects = effects
        params = self._params
        self._faulty_k = (
            _FaultyCoefficients.of(params, effects) if effects.changes_dynamics else None
        )
        mixing = params.mixing_delay_s if effects.mixing_delay_s is None else effects.mixing_delay_s
        self._set_mixing_delay(mixing)

    def _set_mixing_delay(self, delay_s: float) -> None:
        """Set the mixing delay at the reference level, effective from the current sample.

        On a change the delayed bulk temperature is re-read from the history with the new
        delay, so that the measurement of this very sample already has it (the mixing lag, if
        any, keeps its state and follows the jump of its input).
        """
        delay_per_height = delay_s / self._params.mixing_ref_level / self._dt
        if delay_per_height == self._delay_per_height:
            return
        self._delay_per_height = delay_per_height
        history = self._history
        if len(history) > 1:
            delayed = _read_back(history, self._grid_index, delay_per_height * self._h)
        else:
            delayed = self._e / self._h
        self._delayed = delayed
        if self._params.mixing_lag_s == 0.0:
            self._measured_temp = delayed

    def _delayed_sensor(self, channel: int, delay_s: float) -> float:
        """Fault-free measurement of ``channel`` ``delay_s`` seconds ago (linear interpolation)."""
        return _read_back(self._sensor_history[channel], self._grid_index, delay_s / self._dt)

    def _clean(self) -> tuple[float, float]:
        """[height, temperature] as measured now without noise, sensor faults included."""
        if not self._faults:
            return self._h, self._measured_temp
        self._refresh_faults()
        effects = self._effects
        height, temperature = self._h, self._measured_temp
        delay_h, delay_t = effects.sensor_delay_s
        if delay_h > 0.0:
            height = self._delayed_sensor(0, delay_h)
        if delay_t > 0.0:
            temperature = self._delayed_sensor(1, delay_t)
        return height + effects.bias[0], temperature + effects.bias[1]

    # --- simulation ---------------------------------------------------------------------

    @property
    def params(self) -> RigParams:
        """The rig parameters."""
        return self._params

    @property
    def op(self) -> OperatingPoint:
        """The initial operating point."""
        return self._op

    @property
    def ts_s(self) -> float:
        """The sample period, seconds."""
        return self._ts

    @property
    def time_s(self) -> float:
        """Simulated time since the start, seconds (sample count times ts_s)."""
        return self._n_samples * self._ts

    @property
    def state(self) -> FloatArray:
        """(4,) float, model units: [hot_flow, cold_flow, height, bulk_temperature] now."""
        return np.array([self._fh, self._fc, self._h, self._e / self._h], dtype=np.float64)

    @property
    def clean_output(self) -> FloatArray:
        """(2,) float, model units: [height, temperature] as measured now, without noise.

        Includes the mixing delay and lag and the active sensor faults (bias, delay).
        """
        return np.array(self._clean(), dtype=np.float64)

    def measure(self) -> FloatArray:
        """Return the measurement now: (2,) float [height, temperature], model units.

        The temperature includes the mixing delay and lag; both include the active sensor
        faults and sensor noise. Each call draws two fresh noise samples.
        """
        noise = self._rng.standard_normal(2)
        height, temperature = self._clean()
        return np.array(
            [
                height + self._noise_std[0] * noise[0],
                temperature + self._noise_std[1] * noise[1],
            ],
            dtype=np.float64,
        )

    def step(self, command: FloatArray | Sequence[float]) -> None:
        """Apply a valve command for one sample period.

        Args:
            command: (2,) float, model units: absolute [hot, cold] command; saturated to [0, 1].

        Raises:
            DatumError: If the command is not of shape (2,) or is not finite.
            ModelError: If the tank empties (level below 1e-3).
        """
        u = np.asarray(command, dtype=np.float64)
        if u.shape != (2,):
            raise DatumError(f"command has shape {u.shape}, expected (2,) [hot, cold]")
        if not np.all(np.isfinite(u)):
            raise DatumError(f"command {u.tolist()} is not finite; pass numbers in [0, 1]")
        self._advance(min(max(float(u[0]), 0.0), 1.0), min(max(float(u[1]), 0.0), 1.0))

    def _advance(self, uh: float, uc: float) -> None:
        """Integrate one sample with the saturated commands held (no validation: hot loop)."""
        k: object = self._k
        rhs: Callable[..., tuple[float, float, float, float]] = nominal_rhs
        if self._faults:
            self._refresh_faults()
            if self._faulty_k is not None:
                k, rhs = self._faulty_k, _rhs_faulty
                gain_hot, gain_cold = self._effects.valve_gain
                limit_hot, limit_cold = self._effects.valve_limit
                uh, uc = min(uh, limit_hot) * gain_hot, min(uc, limit_cold) * gain_cold
        sensor_h, sensor_t = self._sensor_history
        sensor_capacity = len(sensor_h)
        dt = self._dt
        half = 0.5 * dt
        sixth = dt / 6.0
        fh, fc, h, e = self._fh, self._fc, self._h, self._e
        history = self._history
        capacity = len(history)
        delay_per_height = self._delay_per_height
        decay, ramp = self._lag_decay, self._lag_ramp
        delayed, measured = self._delayed, self._measured_temp
        j = self._grid_index
        for _ in range(self._substeps):
            a1, a2, a3, a4 = rhs(k, fh, fc, h, e, uh, uc)
            b1, b2, b3, b4 = rhs(
                k, fh + half * a1, fc + half * a2, h + half * a3, e + half * a4, uh, uc
            )
            c1, c2, c3, c4 = rhs(
                k, fh + half * b1, fc + half * b2, h + half * b3, e + half * b4, uh, uc
            )
            d1, d2, d3, d4 = rhs(k, fh + dt * c1, fc + dt * c2, h + dt * c3, e + dt * c4, uh, uc)
            fh += sixth * (a1 + 2.0 * (b1 + c1) + d1)
            fc += sixth * (a2 + 2.0 * (b2 + c2) + d2)
            h += sixth * (a3 + 2.0 * (b3 + c3) + d3)
            e += sixth * (a4 + 2.0 * (b4 + c4) + d4)
            if not h > _MIN_SIM_HEIGHT:  # also catches NaN
                raise ModelError(
                    f"tank level fell to {h:.3g} at t = {self.time_s:.1f} s: the tank is empty "
                    "and the model is undefined; reduce the excitation amplitude or raise the "
                    "operating level"
                )
            j += 1
            bulk = e / h
            if capacity > 1:
                history[j % capacity] = bulk
                new_delayed = _read_back(history, j, delay_per_height * h)  # lag in substeps
            else:
                new_delayed = bulk
            measured = decay * measured + (1.0 - decay) * delayed + ramp * (new_delayed - delayed)
            delayed = new_delayed
            if sensor_capacity:
                sensor_h[j % sensor_capacity] = h
                sensor_t[j % sensor_capacity] = measured
        self._fh, self._fc, self._h, self._e = fh, fc, h, e
        self._delayed, self._measured_temp = delayed, measured
        self._grid_index = j
        self._n_samples += 1


@dataclass(frozen=True, eq=False)
class SimResult:
    """Record of a simulation (model units, seconds); n is the number of samples.

    Frozen, with read-only arrays; compared by identity (``eq=False``).

    Attributes:
        time_s: (n,) float, sample times k ts_s.
        commands: (n, 2) float, the [hot, cold] commands applied at each sample, after
            saturation to [0, 1].
        measured: (n, 2) float, [height, temperature] sampled at time_s[k] BEFORE command k is
            applied (so y(k) depends on u(k-1) and earlier: strictly proper, matching a
            zero-order-hold discretisation x(k+1) = Ad x(k) + Bd u(k), y(k) = C x(k)),
            including the mixing delay/lag and sensor noise.
        clean: (n, 2) float, the same without sensor noise.
        states: (n, 4) float, [hot_flow, cold_flow, height, bulk_temperature] at time_s[k].
    """

    time_s: FloatArray
    commands: FloatArray
    measured: FloatArray
    clean: FloatArray
    states: FloatArray

    def __post_init__(self) -> None:
        n = np.shape(self.time_s)[0] if np.ndim(self.time_s) == 1 else -1
        expected = {
            "time_s": (n,),
            "commands": (n, 2),
            "measured": (n, 2),
            "clean": (n, 2),
            "states": (n, 4),
        }
        for name, shape in expected.items():
            arr = np.array(getattr(self, name), dtype=np.float64, copy=True)
            if arr.shape != shape:
                raise DimensionError(f"SimResult.{name} has shape {arr.shape}, expected {shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)


def simulate(
    params: RigParams,
    commands: FloatArray | Sequence[Sequence[float]],
    ts_s: float = TS_S,
    *,
    op: OperatingPoint | None = None,
    seed: int = 0,
    substeps: int = 4,
    faults: Sequence[Fault] = (),
) -> SimResult:
    """Simulate the rig from steady state at ``op`` under a sequence of valve commands.

    Sample k is measured before command k is applied; the result equals stepping a fresh
    ``TankSimulator(params, ts_s, op=op, seed=seed, substeps=substeps, faults=faults)`` with
    ``measure()`` then ``step(commands[k])``.

    Args:
        params: Rig parameters.
        commands: (n, 2) float, model units: absolute [hot, cold] valve commands, saturated to
            [0, 1].
        ts_s: Sample period, seconds.
        op: Initial operating point; default ``operating_point(params)``.
        seed: Sensor noise seed.
        substeps: RK4 steps per sample.
        faults: Faults switched on at their onset times (see :class:`Fault`). ``commands``
            in the result are those requested; ``states`` show the actual valve flows.

    Returns:
        The simulation record.

    Raises:
        DatumError: If ``commands`` is not (n, 2) with n >= 1, or contains NaN or inf.
        ModelError: If the simulator settings or a fault are invalid, or the tank empties.
    """
    u = np.asarray(commands, dtype=np.float64)
    if u.ndim != 2 or u.shape[1] != 2 or u.shape[0] < 1:
        raise DatumError(f"commands have shape {u.shape}, expected (n_samples >= 1, 2) [hot, cold]")
    bad = ~np.isfinite(u)
    if np.any(bad):
        row, col = np.argwhere(bad)[0]
        raise DatumError(
            f"commands contain {int(bad.sum())} NaN/inf values, first at sample {row} "
            f"({('hot', 'cold')[col]} valve); pass finite commands in [0, 1]"
        )
    u = np.clip(u, 0.0, 1.0)
    sim = TankSimulator(params, ts_s, op=op, seed=seed, substeps=substeps, faults=faults)
    n = u.shape[0]
    measured = np.empty((n, 2))
    clean = np.empty((n, 2))
    states = np.empty((n, 4))
    for i, (uh, uc) in enumerate(u.tolist()):
        measured[i] = sim.measure()
        clean[i] = sim.clean_output
        states[i] = sim.state
        sim._advance(uh, uc)
    return SimResult(
        time_s=np.arange(n, dtype=np.float64) * sim.ts_s,
        commands=u,
        measured=measured,
        clean=clean,
        states=states,
    )
