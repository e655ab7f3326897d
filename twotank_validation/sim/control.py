"""PI control of tank 1 through its two valves: pure, steppable, ROS-free.

**Structure (the decoupling).** The tank's two balances decouple in the total inflow
``F = f_h + f_c`` and the hot fraction ``phi = f_h / F``:

* ``A1 dh1/dt = F - f1(h1)``: the level depends on ``F`` only;
* ``A1 h1 dt1/dt = F (phi t_h + (1 - phi) t_c - t1)``: at equilibrium ``t1 = t_c + phi (t_h -
  t_c)`` whatever the level, and linearised at an equilibrium (where the bracket is zero) the
  temperature deviation depends on ``phi`` alone.

So a **level PI drives the total flow** and a **temperature PI drives the hot fraction**; the
valve commands are ``hot = phi F``, ``cold = (1 - phi) F``. Each loop sees a first-order plant
(level: gain ``alpha`` = 1.34, time constant ``A1 alpha`` = 122.5 s; temperature: gain
``t_h - t_c`` = 1, time constant ``A1 h1 / F`` = 53.8 s, plus the rig's mixing delay of
15 s), which a plain 2x2 pairing (hot valve on temperature, cold valve on level) does not
give: there each valve moves both outputs.

**Tuning.** The default gains follow Skogestad's SIMC rules (J. Process Control 13, 2003) for
a first-order plant ``K e^{-theta s} / (1 + tau s)``: ``kp = tau / (K (tau_c + theta))``,
``Ti = min(tau, 4 (tau_c + theta))``, with slow closed-loop time constants (level 100 s,
temperature 60 s with theta = 15 s) so that the loop leaves the excitation's band (above
about 0.005 Hz) in the valve commands.

**The PI law** (position form, sample period ``ts``, error ``e = r - y`` per loop)::

    v_k   = kp e_k + I_k                      (unsaturated output: F or phi)
    a_k   = what the valves actually deliver of v_k (after the limits below)
    I_k+1 = I_k + ts (kp / Ti) e_k + (ts / Tt) (a_k - v_k)

**Anti-windup: back-calculation** (Åström & Hägglund, *Advanced PID Control*, 2006,
Sec. 3.5): when a limit cuts the output, the integrator is pulled towards the value that
would have produced the delivered output, with the tracking time ``Tt`` (``Tt = inf``
switches it off; kept for comparison only). The limits are ``0 <= F <= 2 u_max``,
``0 <= phi <= 1`` and each valve command in ``[u_min, u_max]``; the delivered ``F`` and
``phi`` are recomputed from the clipped valve commands, so a saturated valve winds neither
loop up.

**Measurement filter.** Both measurements pass a first-order low-pass filter
``yf_k = yf_k-1 + (1 - exp(-ts / Tf)) (y_k - yf_k-1)`` (started at the first measurement)
before the PI laws, ``Tf = filter_s`` (2 s by default, far below the loops' time constants):
it keeps the sensor noise out of the valve commands, which otherwise carry it through the
proportional gains and vary from one excitation period to the next by much more.

**Excitation.** :attr:`ControllerConfig.excitation_entry` says where the periodic
excitation enters: ``"output"`` adds it to the valve commands (a dither at the plant input,
the usual closed-loop identification set-up), ``"setpoint"`` adds it to the level and
temperature setpoints. Either way the validator is fed the valve commands actually sent.

**Hold (safe mode).** :meth:`PIController.hold` freezes the PI state and holds the valves at
the mean command of the last ``hold_samples`` samples (one excitation period: the excitation
averages out, so this is the last good operating point), with the output excitation still
added (``excite_when_held``: the open-loop periodic experiment, which the validator keeps
judging); :meth:`PIController.resume`
re-initialises the integrators from the held output so that the PI part of the next command
equals it (bumpless transfer).

Units: levels, temperatures, flows and commands in model units, times in seconds.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from twotank_validation.core.closed_loop import PIPair
from twotank_validation.defaults import (
    PERIOD_SAMPLES,
    RIG_PI_FILTER_S,
    RIG_PI_KP,
    RIG_PI_TI_S,
    TS_S,
)
from twotank_validation.errors import ModelError

__all__ = [
    "CLOSED_LOOP_INPUT_PERIODIC_RTOL",
    "CLOSED_LOOP_TRANSIENT",
    "EXCITATION_ENTRIES",
    "ControllerConfig",
    "ControllerError",
    "PIController",
    "valves_from_flow",
]

FloatArray = NDArray[np.float64]

EXCITATION_ENTRIES: Final = ("output", "setpoint")
"""Where the excitation enters the loop: the valve commands or the setpoints."""

CLOSED_LOOP_INPUT_PERIODIC_RTOL: Final = 0.25
"""The validator's ``input_periodic_rtol`` for closed-loop data. The valve commands of a closed
loop are not periodic (the controller feeds back the sensor noise and any disturbance), so
the default gate (1e-6: the excitation repeats exactly) would judge no window. With the
default gains and measurement filter the commands change from one period to the next by at
most 0.11 of their RMS on the nominal rig (24 simulated hours, 2 seeds, after the loop's
start-up; median 0.07), and by 0.4-0.7 while the loop moves the plant to a new setpoint or
answers a fault. 0.25 judges the steady loop and leaves those transients unjudged, as the
open-loop gate does after a change of the excitation or the operating point: a setpoint
change in closed loop is then not taken for a model error, and a persistent fault is held by
the operating-point check once the loop has settled (the inputs moved, the outputs did not
move as the model predicts). The value is calibrated for the default loop (Ts 0.1 s, the
excitation at the output); another loop, sample time or noise needs its own: the steady
loop's variation is every window's ``input_change`` (``WindowReport``, the validate JSON),
and the gate goes between it and the moves (at Ts 0.8 s the steady loop reaches
0.33, with the excitation at the setpoints 0.43; at Ts 0.1 s with it at the setpoints 0.19).
The test itself does not need a periodic input (docs/theory.md, closed loop)."""


_MIN_FLOW: Final = 1e-9
"""Below this total flow the hot fraction of the delivered commands is undefined."""


class ControllerError(ModelError):
    """A controller setting is invalid (the message names the setting and the fix)."""


@dataclass(frozen=True, kw_only=True)
class ControllerConfig:
    """Gains, setpoints and limits of the two PI loops.

    Attributes:
        ts_s: Sample period (s), > 0.
        height_setpoint: Level setpoint (model units).
        temperature_setpoint: Temperature setpoint (model units).
        kp_level: Level loop gain, total flow per unit of level error, > 0.
        ti_level_s: Level loop integral time (s), > 0.
        tt_level_s: Level loop anti-windup tracking time (s), > 0; inf switches it off.
        kp_temperature: Temperature loop gain, hot fraction per unit of temperature
            error, > 0.
        ti_temperature_s: Temperature loop integral time (s), > 0.
        tt_temperature_s: Temperature loop tracking time (s), > 0; inf switches it off.
        u_min: Lowest valve command, >= 0.
        u_max: Highest valve command, <= 1, > u_min.
        excitation_entry: ``"output"`` (added to the valve commands) or ``"setpoint"``
            (added to the setpoints).
        hold_samples: Commands averaged into the held value of the safe mode (one
            excitation period), >= 1.
        excite_when_held: In the safe mode, keep adding the output excitation to the held
            commands (``excitation_entry = "output"``): the plant then runs the open-loop
            periodic experiment, so the validator keeps judging the model and can see the
            fault persist or go. False: the valves are held still (no window can be judged
            until the loops resume).
        filter_s: Time constant (s) of a first-order low-pass filter on both measurements
            before the PI laws, >= 0; 0 switches it off. It keeps the sensor noise out of the
            valve commands (the proportional gains would pass it straight through).

    Raises:
        ControllerError: naming the setting.
    """

    ts_s: float = TS_S
    height_setpoint: float = 0.47
    temperature_setpoint: float = 0.5
    kp_level: float = RIG_PI_KP[0]
    ti_level_s: float = RIG_PI_TI_S[0]
    tt_level_s: float = 60.0
    kp_temperature: float = RIG_PI_KP[1]
    ti_temperature_s: float = RIG_PI_TI_S[1]
    tt_temperature_s: float = 30.0
    u_min: float = 0.0
    u_max: float = 1.0
    excitation_entry: str = "output"
    hold_samples: int = PERIOD_SAMPLES
    filter_s: float = RIG_PI_FILTER_S
    excite_when_held: bool = True

    def __post_init__(self) -> None:
        for name in ("ts_s", "kp_level", "ti_level_s", "kp_temperature", "ti_temperature_s"):
            _positive(name, getattr(self, name), finite=True)
        for name in ("tt_level_s", "tt_temperature_s"):
            _positive(name, getattr(self, name), finite=False)
        if isinstance(self.filter_s, bool) or not isinstance(self.filter_s, int | float):
            raise ControllerError(f"controller filter_s={self.filter_s!r} is not a number")
        if not (math.isfinite(self.filter_s) and self.filter_s >= 0.0):
            raise ControllerError(
                f"controller filter_s={self.filter_s!r} must be finite and >= 0 (0: no filter)"
            )
        for name in ("height_setpoint", "temperature_setpoint", "u_min", "u_max"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ControllerError(f"controller {name}={value!r} is not a number")
            if not math.isfinite(value):
                raise ControllerError(f"controller {name}={value!r} must be finite")
        if not 0.0 <= self.u_min < self.u_max <= 1.0:
            raise ControllerError(
                f"controller valve limits u_min={self.u_min!r}, u_max={self.u_max!r} must "
                "satisfy 0 <= u_min < u_max <= 1"
            )
        if self.excitation_entry not in EXCITATION_ENTRIES:
            raise ControllerError(
                f"controller excitation_entry={self.excitation_entry!r} is unknown; use one of "
                f"{EXCITATION_ENTRIES}"
            )
        if (
            isinstance(self.hold_samples, bool)
            or not isinstance(self.hold_samples, int | np.integer)
            or self.hold_samples < 1
        ):
            raise ControllerError(
                f"controller hold_samples={self.hold_samples!r} must be an integer >= 1 "
                "(one excitation period)"
            )
        if self.tt_level_s < self.ts_s or self.tt_temperature_s < self.ts_s:
            raise ControllerError(
                f"controller tracking times tt_level_s={self.tt_level_s!r}, "
                f"tt_temperature_s={self.tt_temperature_s!r} must be >= ts_s={self.ts_s!r} "
                "(shorter ones overcorrect the integrator in one step)"
            )

    def linear(self) -> PIPair:
        """The two loops' law in its linear region (no limit active).

        For the validator's closed-loop formulation (docs/theory.md §21).
        """
        return PIPair(
            ts_s=self.ts_s,
            kp=(self.kp_level, self.kp_temperature),
            ti_s=(self.ti_level_s, self.ti_temperature_s),
            filter_s=self.filter_s,
        )


def _positive(name: str, value: object, *, finite: bool) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        raise ControllerError(f"controller {name}={value!r} is not a number")
    if value <= 0.0 or (finite and not math.isfinite(value)):
        kind = "a finite number > 0" if finite else "> 0 (inf switches it off)"
        raise ControllerError(f"controller {name}={value!r} must be {kind}")


def valves_from_flow(total: float, hot_fraction: float) -> tuple[float, float]:
    """``(hot, cold) = (phi F, (1 - phi) F)``: the valve commands of a total flow and fraction."""
    return hot_fraction * total, (1.0 - hot_fraction) * total


def _as_pair(value: ArrayLike, name: str) -> tuple[float, float]:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ControllerError(f"{name} must be a finite (2,) array, got {value!r}")
    return float(arr[0]), float(arr[1])


class PIController:
    """The two PI loops of :mod:`twotank_validation.sim.control`, one sample at a time.

    Args:
        config: Gains, setpoints, limits.
        initial: (2,) [hot, cold] valve commands to start from (e.g. the operating point's
            ``commands``): the integrators start so that zero error gives them (bumpless
            start).

    Raises:
        ControllerError: ``initial`` not a finite pair.
    """

    def __init__(self, config: ControllerConfig, initial: ArrayLike) -> None:
        self.config = config
        self.setpoints = (config.height_setpoint, config.temperature_setpoint)
        hot, cold = _as_pair(initial, "initial commands")
        self._held: tuple[float, float] | None = None
        self._recent: deque[tuple[float, float]] = deque(maxlen=config.hold_samples)
        self._last_measured: tuple[float, float] | None = None
        self._last_excitation = (0.0, 0.0)
        self._filter_gain = (
            1.0 - math.exp(-config.ts_s / config.filter_s) if config.filter_s > 0.0 else 1.0
        )
        self._set_integrators(hot, cold, (0.0, 0.0))

    # --- state ----------------------------------------------------------------------------

    @property
    def holding(self) -> bool:
        """True in the safe mode (valves held, PI frozen)."""
        return self._held is not None

    @property
    def held(self) -> FloatArray | None:
        """(2,) the held [hot, cold] commands in the safe mode, else None."""
        return None if self._held is None else np.array(self._held)

    @property
    def integrators(self) -> FloatArray:
        """(2,) the integrator states [total flow, hot fraction]."""
        return np.array([self._i_flow, self._i_frac])

    def set_setpoints(self, height: float, temperature: float) -> None:
        """New level and temperature setpoints (model units), from the next step on."""
        if not (math.isfinite(height) and math.isfinite(temperature)):
            raise ControllerError(f"setpoints ({height!r}, {temperature!r}) must be finite")
        self.setpoints = (float(height), float(temperature))

    def _errors(
        self, measured: tuple[float, float], excitation: tuple[float, float]
    ) -> tuple[float, float]:
        r_h, r_t = self.setpoints
        if self.config.excitation_entry == "setpoint":
            r_h, r_t = r_h + excitation[0], r_t + excitation[1]
        return r_h - measured[0], r_t - measured[1]

    def _set_integrators(
        self, hot: float, cold: float, errors: tuple[float, float], *, measured: bool = False
    ) -> None:
        total = hot + cold
        frac = hot / total if total > _MIN_FLOW else 0.5
        cfg = self.config
        self._i_flow = total - (cfg.kp_level * errors[0] if measured else 0.0)
        self._i_frac = frac - (cfg.kp_temperature * errors[1] if measured else 0.0)

    # --- the law --------------------------------------------------------------------------

    def step(self, measured: ArrayLike, excitation: ArrayLike = (0.0, 0.0)) -> FloatArray:
        """The valve commands for this sample, and the PI state advanced by one sample.

        Args:
            measured: (2,) measured [height, temperature], model units.
            excitation: (2,) this sample's excitation: [hot, cold] valve deviations for
                ``excitation_entry = "output"``, [height, temperature] setpoint deviations
                for ``"setpoint"``.

        Returns:
            (2,) [hot, cold] valve commands in [u_min, u_max]; in the safe mode the held
            value, plus the output excitation with ``excite_when_held`` (the measurement
            filter keeps running, the PI state is frozen).

        Raises:
            ControllerError: non-finite or misshaped arguments.
        """
        raw = _as_pair(measured, "measured [height, temperature]")
        exc = _as_pair(excitation, "excitation")
        y = raw
        if self._last_measured is not None:  # the measurement filter (gain 1 when off)
            old, a = self._last_measured, self._filter_gain
            y = (old[0] + a * (raw[0] - old[0]), old[1] + a * (raw[1] - old[1]))
        self._last_measured, self._last_excitation = y, exc
        if self._held is not None:
            return self._held_command(exc)
        cfg = self.config
        e_h, e_t = self._errors(y, exc)
        v_flow = cfg.kp_level * e_h + self._i_flow
        v_frac = cfg.kp_temperature * e_t + self._i_frac
        flow = min(max(v_flow, 0.0), 2.0 * cfg.u_max)
        frac = min(max(v_frac, 0.0), 1.0)
        hot, cold = valves_from_flow(flow, frac)
        out_exc = exc if cfg.excitation_entry == "output" else (0.0, 0.0)
        hot_c = min(max(hot + out_exc[0], cfg.u_min), cfg.u_max)
        cold_c = min(max(cold + out_exc[1], cfg.u_min), cfg.u_max)
        # what the PI part actually delivers, excitation taken out again
        hot_a, cold_a = hot_c - out_exc[0], cold_c - out_exc[1]
        flow_a = hot_a + cold_a
        frac_a = hot_a / flow_a if abs(flow_a) > _MIN_FLOW else frac
        frac_a = min(max(frac_a, 0.0), 1.0)
        self._i_flow += cfg.ts_s * cfg.kp_level / cfg.ti_level_s * e_h
        self._i_frac += cfg.ts_s * cfg.kp_temperature / cfg.ti_temperature_s * e_t
        if math.isfinite(cfg.tt_level_s):
            self._i_flow += cfg.ts_s / cfg.tt_level_s * (flow_a - v_flow)
        if math.isfinite(cfg.tt_temperature_s):
            self._i_frac += cfg.ts_s / cfg.tt_temperature_s * (frac_a - v_frac)
        self._recent.append((hot_c, cold_c))
        return np.array([hot_c, cold_c])

    def open_command(self, excitation: ArrayLike = (0.0, 0.0)) -> FloatArray:
        """The command sent before any measurement arrived: the integrators' output.

        The PI part is the current integrator state (the initial commands at the start),
        output excitation added and clipped to [u_min, u_max]; the state does not change.
        In the safe mode, the held value (with the output excitation, see
        ``excite_when_held``).
        """
        if self._held is not None:
            return self._held_command(_as_pair(excitation, "excitation"))
        exc = _as_pair(excitation, "excitation")
        if self.config.excitation_entry != "output":
            exc = (0.0, 0.0)
        flow = min(max(self._i_flow, 0.0), 2.0 * self.config.u_max)
        frac = min(max(self._i_frac, 0.0), 1.0)
        hot, cold = valves_from_flow(flow, frac)
        lo, hi = self.config.u_min, self.config.u_max
        return np.array([min(max(hot + exc[0], lo), hi), min(max(cold + exc[1], lo), hi)])

    # --- safe mode ------------------------------------------------------------------------

    def _held_command(self, exc: tuple[float, float]) -> FloatArray:
        """(2,) the safe mode's command: the held value, plus the output excitation."""
        assert self._held is not None
        cfg = self.config
        if not (cfg.excite_when_held and cfg.excitation_entry == "output"):
            return np.array(self._held)
        lo, hi = cfg.u_min, cfg.u_max
        return np.array([min(max(h + e, lo), hi) for h, e in zip(self._held, exc, strict=True)])

    def hold(self) -> FloatArray:
        """Enter the safe mode: hold the valves at the mean command of the last period.

        The mean is over the last ``hold_samples`` commands (fewer if fewer were sent; the
        initial commands if none were). The PI state is frozen until :meth:`resume`.
        Holding again while holding keeps the first held value.

        Returns:
            (2,) the held [hot, cold] commands.
        """
        if self._held is None:
            if self._recent:
                mean = np.mean(np.asarray(self._recent), axis=0)
                self._held = (float(mean[0]), float(mean[1]))
            else:
                hot, cold = valves_from_flow(self._i_flow, self._i_frac)
                self._held = (hot, cold)
        return np.array(self._held)

    def resume(self) -> None:
        """Leave the safe mode bumplessly: the integrators restart from the held output.

        With the last measurement (and excitation) received, the PI part of the next command
        equals the held command if the measurement does not change. The command history
        restarts, so a later hold averages only commands sent after the resume. No-op when
        not holding.
        """
        if self._held is None:
            return
        hot, cold = self._held
        self._held = None
        self._recent.clear()
        if self._last_measured is None:
            self._set_integrators(hot, cold, (0.0, 0.0))
        else:
            errors = self._errors(self._last_measured, self._last_excitation)
            self._set_integrators(hot, cold, errors, measured=True)


CLOSED_LOOP_TRANSIENT: Final = "auto"
"""The validator's ``transient`` for closed-loop data unless given: the windows the opened gate
passes are judged without the transient term, those it leaves unjudged (the loop moving
after a setpoint change or answering a fault) with it (docs/theory.md §20: in closed loop
it detects every rig fault as soon as or sooner than the gate, the stuck valve too, with no
false transition in 48 nominal hours with setpoint changes)."""
