"""Simulated experiments as scenarios (YAML): definition, loading and running them.

A :class:`Scenario` fixes everything a simulated run of the two-tank rig needs: duration and
sample period, operating point, the periodic excitation (started at t = 0 around the
operating point, as the excitation node does), the rig's unmodelled effects (sensor noise,
mixing delay) and faults in their text form (:mod:`twotank_validation.sim.faults`).
With a ``closed_loop`` section (:class:`ClosedLoop`) the valves are driven by the PI
controller of :mod:`twotank_validation.sim.control` and the excitation enters at its output or
its setpoints. ``simulate_scenario`` runs it in memory, ``iter_scenario`` sample by sample;
writing it into a bag is :func:`twotank_validation.bags.scenario_bag.write_scenario_bag`.

Shipped scenarios live in ``twotank_validation/sim/scenarios/*.yaml`` (``shipped_scenarios()``);
a YAML file holds the keys of :class:`Scenario` (``units`` as a mapping of
:class:`~twotank_validation.online.streams.RigUnits` fields).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Final

import numpy as np
import yaml
from numpy.typing import NDArray

from twotank_validation.defaults import NS_PER_S, PERIOD_SAMPLES, TS_S
from twotank_validation.errors import DatumError, ModelError
from twotank_validation.online.streams import RigUnits
from twotank_validation.settings import from_flat
from twotank_validation.sim import control, excitation, rig, simulator
from twotank_validation.sim.excitation import ExcitationConfig, ExcitationDesign
from twotank_validation.sim.faults import MAX_FAULT_DELAY_S, Fault, parse_fault

__all__ = [
    "MAX_SUBSTEP_S",
    "ClosedLoop",
    "Scenario",
    "ScenarioError",
    "flow_meter_readings",
    "iter_metered",
    "iter_scenario",
    "load_scenario",
    "scenario_from_dict",
    "shipped_scenarios",
    "simulate_scenario",
]

FloatArray = NDArray[np.float64]

MAX_SUBSTEP_S: Final = 0.025
"""Longest RK4 substep (s); substeps = max(4, ceil(ts_s / 0.025)), as the plant node."""

_UNIT_KEYS: Final = tuple(f.name for f in dataclasses.fields(RigUnits))


class ScenarioError(ModelError):
    """A scenario is invalid or cannot be found (the message names the key or the file)."""


# --- field checks -----------------------------------------------------------------------------


def _number_hint(value: object) -> str:
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            return ""
        return " (YAML reads it as text: write exponents with a dot, e.g. 1.0e-3)"
    return ""


def _real(
    where: str,
    key: str,
    value: object,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
) -> float:
    """A finite real in [lo, hi] (or (lo, hi] with lo_open); ScenarioError naming the key."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ScenarioError(f"{where}: {key}={value!r} is not a number{_number_hint(value)}")
    x = float(value)
    if not math.isfinite(x):
        raise ScenarioError(f"{where}: {key}={value!r} must be finite")
    if lo is not None and (x <= lo if lo_open else x < lo):
        rel = ">" if lo_open else ">="
        raise ScenarioError(f"{where}: {key}={value!r} must be {rel} {lo:g}")
    if hi is not None and x > hi:
        raise ScenarioError(f"{where}: {key}={value!r} must be <= {hi:g}")
    return x


def _integer(where: str, key: str, value: object, *, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ScenarioError(f"{where}: {key}={value!r} must be an integer >= {lo}")
    if value < lo:
        raise ScenarioError(f"{where}: {key}={value!r} must be an integer >= {lo}")
    return int(value)


_CC: Final = control.ControllerConfig()

_DESIGN_KEYS: Final = tuple(
    s.name
    for s in excitation.ExcitationDesign.settings()
    if s.name not in ("kind", "period_samples", "f_max_hz", "cutoff_hz", "seed")
)
"""The design settings a scenario takes in its ``excitation`` mapping (the others are its
own keys: ``excitation_kind``, ``period_samples``, ``f_max_hz``, ``cutoff_hz``,
``excitation_seed``)."""


@dataclass(frozen=True, kw_only=True)
class ClosedLoop:
    """The ``closed_loop:`` section of a scenario: the PI controller that drives the valves.

    YAML: a mapping of these keys (``closed_loop: {}`` or ``closed_loop: true`` for the
    defaults; absent, ``null`` or ``false``: open loop). Gains and times as
    :class:`~twotank_validation.sim.control.ControllerConfig` (defaults: its own).

    Attributes:
        excitation: ``"output"``: the scenario's excitation (``rms_hot``, ``rms_cold``, ...)
            is added to the valve commands; ``"setpoint"``: an excitation of the same kind,
            cutoff and seed with RMS ``setpoint_rms_height`` / ``setpoint_rms_temperature``
            is added to the level and temperature setpoints.
        height_setpoint: Level setpoint; None: the scenario's ``height`` (where the rig
            starts).
        temperature_setpoint: Temperature setpoint; None: the scenario's ``temperature``.
        setpoint_rms_height: RMS of the level setpoint excitation (``excitation: setpoint``).
        setpoint_rms_temperature: RMS of the temperature setpoint excitation.
        kp_level, ti_level_s, tt_level_s, kp_temperature, ti_temperature_s,
        tt_temperature_s, u_min, u_max, filter_s: as ControllerConfig.
    """

    excitation: str = _CC.excitation_entry
    height_setpoint: float | None = None
    temperature_setpoint: float | None = None
    setpoint_rms_height: float = 0.02
    setpoint_rms_temperature: float = 0.05
    kp_level: float = _CC.kp_level
    ti_level_s: float = _CC.ti_level_s
    tt_level_s: float = _CC.tt_level_s
    kp_temperature: float = _CC.kp_temperature
    ti_temperature_s: float = _CC.ti_temperature_s
    tt_temperature_s: float = _CC.tt_temperature_s
    u_min: float = _CC.u_min
    u_max: float = _CC.u_max
    filter_s: float = _CC.filter_s

    def __post_init__(self) -> None:
        where = "closed_loop"
        for key in ("setpoint_rms_height", "setpoint_rms_temperature"):
            object.__setattr__(self, key, _real(where, key, getattr(self, key), lo=0.0, hi=0.5))
        for key in ("height_setpoint", "temperature_setpoint"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, _real(where, key, getattr(self, key)))
        try:
            self.controller_config(TS_S, 0.47, 0.5, PERIOD_SAMPLES)
        except control.ControllerError as err:
            raise ScenarioError(f"{where}: {err}") from err

    def controller_config(
        self, ts_s: float, height: float, temperature: float, period_samples: int
    ) -> control.ControllerConfig:
        """The controller of a scenario run at ``ts_s`` starting at (height, temperature)."""
        return control.ControllerConfig(
            ts_s=ts_s,
            height_setpoint=height if self.height_setpoint is None else self.height_setpoint,
            temperature_setpoint=(
                temperature if self.temperature_setpoint is None else self.temperature_setpoint
            ),
            kp_level=self.kp_level,
            ti_level_s=self.ti_level_s,
            tt_level_s=self.tt_level_s,
            kp_temperature=self.kp_temperature,
            ti_temperature_s=self.ti_temperature_s,
            tt_temperature_s=self.tt_temperature_s,
            u_min=self.u_min,
            u_max=self.u_max,
            excitation_entry=self.excitation,
            hold_samples=period_samples,
            filter_s=self.filter_s,
        )


_CLOSED_LOOP_KEYS: Final = tuple(f.name for f in dataclasses.fields(ClosedLoop))


def closed_loop_from(value: object, source: str) -> ClosedLoop | None:
    """The ``closed_loop`` YAML value as a :class:`ClosedLoop` (None for open loop).

    Raises:
        ScenarioError: not a mapping, true, false or null; unknown keys; invalid values.
    """
    if value is None or value is False:
        return None
    if isinstance(value, ClosedLoop):
        return value
    if value is True:
        return ClosedLoop()
    if not isinstance(value, Mapping):
        raise ScenarioError(
            f"{source}: closed_loop={value!r} must be a mapping of controller settings, true "
            "(the defaults) or false (open loop)"
        )
    bad = sorted(set(map(str, value)) - set(_CLOSED_LOOP_KEYS))
    if bad:
        raise ScenarioError(
            f"{source}: unknown key(s) {bad} in closed_loop; allowed keys: "
            f"{', '.join(_CLOSED_LOOP_KEYS)}"
        )
    try:
        return ClosedLoop(**{str(k): v for k, v in value.items()})
    except ScenarioError as err:
        raise ScenarioError(f"{source}: {err}") from err


# --- the scenario -----------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class Scenario:
    """A simulated run of the rig: settings, excitation, unmodelled effects and faults.

    Times in seconds, signals in model units. Validated on construction.

    Attributes:
        name: Short name (a shipped scenario's file stem).
        description: One line saying what the scenario shows.
        duration_s: Length of the run, > 0, a whole number of samples.
        ts_s: Sample period, > 0, a whole number of nanoseconds.
        period_samples: Excitation period, samples, >= 4.
        height: Operating level h1, within the model's range 0.15 .. 0.75.
        temperature: Operating temperature t1 (the valves must hold it).
        excitation_kind: ``"filtered_noise"`` or ``"multisine"``.
        rms_hot: RMS of the hot-valve excitation, >= 0.
        rms_cold: RMS of the cold-valve excitation, >= 0.
        cutoff_hz: Filtered noise: low-pass cutoff, below Nyquist.
        f_max_hz: Multisine: highest frequency, below Nyquist (lowest: 1/204.8 Hz, as the
            excitation node).
        odd_only: Multisine: odd harmonics only.
        excitation_seed: Seed of the excitation's random draws, >= 0.
        excitation: The rest of the excitation's design (:meth:`design`), by the names of
            :class:`~twotank_validation.sim.excitation.ExcitationDesign`: ``f_min_hz``,
            ``lines``, ``line_step``, ``detection``, ``crest_min``, ``realisations``,
            ``realisation_periods``, ``order`` (the keys above set the others; ``lines``
            replaces ``odd_only``).
        noise_std_height: Level sensor noise, standard deviation, >= 0.
        noise_std_temperature: Temperature sensor noise, standard deviation, >= 0.
        mixing_delay_s: The rig's unmodelled transport delay of the measured temperature at
            h1 = 0.47 (grows with level), >= 0.
        leak_per_level: A permanent leak of outflow ``leak_per_level * h1`` (undeclared in
            Models A and B; the inflows are retuned to hold the level), >= 0.
        heat_loss_coeff: A permanent heat loss to ambient (undeclared in the models; the
            inflows are retuned to hold the temperature), >= 0.
        faults: Fault specs ``KIND[:CHANNEL][=MAGNITUDE]@ONSET_S[-END_S]``
            (:func:`twotank_validation.sim.faults.parse_fault`), each with its onset inside
            the run.
        setpoints: Setpoint changes ``height=H[,temperature=T]@TIME_S`` (either key or
            both): from that time on the valves are commanded around the equilibrium of the
            new level and temperature (:func:`parse_setpoint`); the excitation goes on.
        seed: Seed of the sensor noise, >= 0.
        flow_meter_noise: Flow meters on both valves: each logs the flow the valve is
            commanded to deliver over the sample plus white Gaussian noise of standard
            deviation ``flow_meter_noise`` times that valve's excitation RMS (``rms_hot``,
            ``rms_cold``), in [0, 0.05] (the measured-input gate's tolerance). The plant is
            driven by the true flows; only the logged readings carry the noise
            (:func:`iter_metered`, the bag's ``flow_meter`` topic). Drawn from a generator
            of its own (``seed``, stream 1), so the sensor noise is the same with and
            without the meters. 0 (default): no meters.
        units: Conversion of level and temperature to Pa and °C in the messages.
        closed_loop: The PI controller driving the valves (:class:`ClosedLoop`, or in YAML a
            mapping of its keys / ``true``); None: open loop, the excitation's commands go to
            the valves as they are. In closed loop the ``setpoints`` change the
            controller's setpoints, and command k is computed from measurement k - 1 (one
            sample of computation delay, as the controller node in ``live``).

    Raises:
        ScenarioError: (a ModelError) naming the offending key.
        DatumError: If the excitation does not fit (commands leave [0, 1], empty band).
    """

    name: str
    description: str = ""
    duration_s: float
    ts_s: float = TS_S
    period_samples: int = PERIOD_SAMPLES
    height: float = 0.47
    temperature: float = 0.5
    excitation_kind: str = "filtered_noise"
    rms_hot: float = 0.05
    rms_cold: float = 0.2
    cutoff_hz: float = 0.006
    f_max_hz: float = 0.05
    odd_only: bool = False
    excitation_seed: int = 2
    excitation: Mapping[str, Any] = field(default_factory=dict)
    noise_std_height: float = 0.003
    noise_std_temperature: float = 0.01
    mixing_delay_s: float = 15.0
    leak_per_level: float = 0.0
    heat_loss_coeff: float = 0.0
    faults: tuple[str, ...] = ()
    setpoints: tuple[str, ...] = ()
    seed: int = 0
    flow_meter_noise: float = 0.0
    units: RigUnits = field(default_factory=RigUnits)
    closed_loop: ClosedLoop | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ScenarioError(f"scenario name={self.name!r} must be a non-empty string")
        where = f"scenario {self.name!r}"
        if not isinstance(self.description, str):
            raise ScenarioError(f"{where}: description={self.description!r} must be a string")
        put = object.__setattr__
        put(self, "ts_s", _real(where, "ts_s", self.ts_s, lo=0.0, lo_open=True))
        ts_ns = self.ts_s * NS_PER_S
        if ts_ns < 1.0 or abs(ts_ns - round(ts_ns)) > 1e-3:
            raise ScenarioError(
                f"{where}: ts_s={self.ts_s!r} must be a whole number of nanoseconds (>= 1 ns) so "
                "that sample k is stamped exactly k ts_s"
            )
        put(self, "duration_s", _real(where, "duration_s", self.duration_s, lo=0.0, lo_open=True))
        n = self.duration_s / self.ts_s
        if round(n) < 1 or abs(n - round(n)) > 1e-6:
            raise ScenarioError(
                f"{where}: duration_s={self.duration_s!r} must be a whole number (>= 1) of "
                f"samples of ts_s={self.ts_s!r}, e.g. {max(1, round(n)) * self.ts_s:g}"
            )
        put(self, "period_samples", _integer(where, "period_samples", self.period_samples, lo=4))
        lo_h, hi_h = rig.MODEL_HEIGHT_RANGE
        put(self, "height", _real(where, "height", self.height, lo=lo_h, hi=hi_h))
        put(self, "temperature", _real(where, "temperature", self.temperature))
        if self.excitation_kind not in excitation.EXCITATION_KINDS:
            raise ScenarioError(
                f"{where}: excitation_kind={self.excitation_kind!r} is unknown; use one of "
                f"{excitation.EXCITATION_KINDS}"
            )
        for key in ("rms_hot", "rms_cold", "noise_std_height", "noise_std_temperature"):
            put(self, key, _real(where, key, getattr(self, key), lo=0.0))
        nyquist = 0.5 / self.ts_s
        for key in ("cutoff_hz", "f_max_hz"):
            value = _real(where, key, getattr(self, key), lo=0.0, lo_open=True)
            if value >= nyquist:
                raise ScenarioError(
                    f"{where}: {key}={value!r} must be below the Nyquist frequency "
                    f"{nyquist:g} Hz of ts_s={self.ts_s!r}"
                )
            put(self, key, value)
        if not isinstance(self.odd_only, bool):
            raise ScenarioError(f"{where}: odd_only={self.odd_only!r} must be true or false")
        put(self, "excitation_seed", _integer(where, "excitation_seed", self.excitation_seed, lo=0))
        if not isinstance(self.excitation, Mapping):
            raise ScenarioError(
                f"{where}: excitation={self.excitation!r} must be a mapping of design settings "
                f"({', '.join(_DESIGN_KEYS)})"
            )
        put(self, "excitation", dict(self.excitation))
        bad = sorted(set(map(str, self.excitation)) - set(_DESIGN_KEYS))
        if bad:
            raise ScenarioError(
                f"{where}: unknown key(s) {bad} in excitation; allowed: {', '.join(_DESIGN_KEYS)} "
                "(kind, period, band top, cutoff and seed are the scenario's own keys)"
            )
        if self.odd_only and "lines" in self.excitation:
            raise ScenarioError(f"{where}: give either odd_only or excitation.lines, not both")
        try:
            self.design()
        except DatumError as err:
            raise ScenarioError(f"{where}: excitation: {err}") from err
        put(self, "seed", _integer(where, "seed", self.seed, lo=0))
        put(
            self,
            "mixing_delay_s",
            _real(where, "mixing_delay_s", self.mixing_delay_s, lo=0.0, hi=MAX_FAULT_DELAY_S),
        )
        for key in ("leak_per_level", "heat_loss_coeff"):
            put(self, key, _real(where, key, getattr(self, key), lo=0.0, hi=5.0))
        put(
            self,
            "flow_meter_noise",
            _real(where, "flow_meter_noise", self.flow_meter_noise, lo=0.0, hi=0.05),
        )
        if not isinstance(self.units, RigUnits):
            raise ScenarioError(f"{where}: units={self.units!r} must be a RigUnits")
        put(self, "closed_loop", closed_loop_from(self.closed_loop, where))
        faults: object = self.faults  # YAML gives lists; anything else is refused
        if isinstance(faults, str) or not isinstance(faults, tuple | list):
            raise ScenarioError(
                f"{where}: faults={faults!r} must be a list of fault specs such as "
                "['leak=0.04@1500']"
            )
        put(self, "faults", tuple(faults))
        for i, spec in enumerate(self.faults):
            if not isinstance(spec, str):
                raise ScenarioError(f"{where}: faults[{i}]={spec!r} must be a fault spec string")
            try:
                fault = parse_fault(spec)
            except ModelError as err:
                raise ScenarioError(f"{where}: faults[{i}]: {err}") from err
            if fault.onset_s >= self.duration_s:
                raise ScenarioError(
                    f"{where}: faults[{i}]={spec!r} starts at {fault.onset_s:g} s, not before the "
                    f"end of the run (duration_s={self.duration_s:g}); move the onset earlier"
                )
        points: object = self.setpoints
        if isinstance(points, str) or not isinstance(points, tuple | list):
            raise ScenarioError(
                f"{where}: setpoints={points!r} must be a list such as ['height=0.49@2000']"
            )
        put(self, "setpoints", tuple(points))
        for i, spec in enumerate(self.setpoints):
            try:
                height, temperature, at = parse_setpoint(spec)
                rig.operating_point(
                    self.rig_params(),
                    self.height if height is None else height,
                    self.temperature if temperature is None else temperature,
                )
            except ModelError as err:
                raise ScenarioError(f"{where}: setpoints[{i}]: {err}") from err
            if not 0.0 < at < self.duration_s:
                raise ScenarioError(
                    f"{where}: setpoints[{i}]={spec!r} at {at:g} s is not inside the run "
                    f"(0 .. {self.duration_s:g} s)"
                )
        # Combined checks: operating point, rig, excitation range (cheap: one period).
        try:
            self.operating_point()
        except ModelError as err:
            raise ScenarioError(f"{where}: height/temperature/rig settings: {err}") from err
        if self.closed_loop is not None:
            cfg = self.controller_config()
            try:
                rig.operating_point(
                    self.rig_params(), cfg.height_setpoint, cfg.temperature_setpoint
                )
            except ModelError as err:
                raise ScenarioError(f"{where}: closed_loop setpoints: {err}") from err
        try:
            self.command_table()
        except DatumError as err:
            text = str(err).replace("rms[0]", "rms_hot").replace("rms[1]", "rms_cold")
            raise DatumError(
                f"{where}: excitation (excitation_kind, rms_hot, rms_cold, cutoff_hz, f_max_hz, "
                f"odd_only, period_samples) around the operating point: {text}"
            ) from err

    # --- derived settings ---------------------------------------------------------------

    @property
    def n_samples(self) -> int:
        """Samples in the run: duration_s / ts_s."""
        return round(self.duration_s / self.ts_s)

    @property
    def ts_ns(self) -> int:
        """Sample period in integer nanoseconds; sample k is stamped k ts_ns."""
        return round(self.ts_s * NS_PER_S)

    @property
    def substeps(self) -> int:
        """RK4 substeps per sample: max(4, ceil(ts_s / MAX_SUBSTEP_S)), as the plant node."""
        return max(4, math.ceil(self.ts_s / MAX_SUBSTEP_S - 1e-9))

    def rig_params(self) -> rig.RigParams:
        """Rig parameters: defaults plus this scenario's delay, noise, leak and heat loss."""
        return rig.RigParams(
            mixing_delay_s=self.mixing_delay_s,
            noise_std_height=self.noise_std_height,
            noise_std_temperature=self.noise_std_temperature,
            leak_per_level=self.leak_per_level,
            heat_loss_coeff=self.heat_loss_coeff,
        )

    def operating_point(self) -> rig.OperatingPoint:
        """Equilibrium at (height, temperature)."""
        return rig.operating_point(self.rig_params(), self.height, self.temperature)

    def design(self) -> ExcitationDesign:
        """The excitation's design: the scenario's keys and its ``excitation`` mapping.

        Raises:
            DatumError: an invalid combination (the message names the setting).
        """
        values: dict[str, Any] = {
            "kind": self.excitation_kind,
            "period_samples": self.period_samples,
            "f_min_hz": excitation.RIG_DESIGN.f_min_hz,
            "f_max_hz": self.f_max_hz,
            "lines": "odd" if self.odd_only else "all",
            "cutoff_hz": self.cutoff_hz,
            "seed": self.excitation_seed,
        }
        return from_flat(excitation.ExcitationDesign, values | dict(self.excitation))

    def with_design(self, values: Mapping[str, Any]) -> Scenario:
        """The scenario with these design settings (flat names) in place of its own.

        ``kind``, ``period_samples``, ``f_max_hz``, ``cutoff_hz`` and ``seed`` set the
        scenario's keys (``excitation_kind``, ..., ``excitation_seed``), ``lines`` replaces
        ``odd_only``, the rest go into its ``excitation`` mapping.

        Raises:
            ScenarioError, DatumError: the result is not a valid scenario.
        """
        own = {
            "kind": "excitation_kind",
            "period_samples": "period_samples",
            "f_max_hz": "f_max_hz",
            "cutoff_hz": "cutoff_hz",
            "seed": "excitation_seed",
        }
        changes: dict[str, Any] = {own[k]: v for k, v in values.items() if k in own}
        rest = {k: v for k, v in values.items() if k not in own}
        if "lines" in rest:
            changes["odd_only"] = False
        changes["excitation"] = dict(self.excitation) | rest
        return dataclasses.replace(self, **changes)

    def excitation_config(self) -> ExcitationConfig:
        """The excitation of one cycle, as the excitation node builds it.

        One period for a single realisation.
        """
        design = self.design()
        return excitation.ExcitationConfig(
            ts_s=self.ts_s,
            settle_periods=0,
            record_periods=design.cycle_periods,
            rms=(self.rms_hot, self.rms_cold),
            design=design,
        )

    def command_table(self) -> FloatArray:
        """(cycle, 2) absolute [hot, cold] commands of one cycle (a period if one realisation).

        Sample k of the run uses row k mod its length (the excitation starts at t = 0).
        """
        return excitation.excitation_commands(
            self.excitation_config(), self.operating_point().commands
        )

    def setpoint_steps(self) -> list[tuple[int, FloatArray]]:
        """``(first sample, command offset)`` of each setpoint, in time order.

        The offset moves the excitation's centre from the scenario's equilibrium commands to
        those of the new level and temperature (later changes start from the earlier ones).
        """
        base = self.operating_point().commands
        height, temperature = self.height, self.temperature
        steps = []
        for spec in sorted(self.setpoints, key=lambda x: parse_setpoint(x)[2]):
            h, t, at = parse_setpoint(spec)
            height = height if h is None else h
            temperature = temperature if t is None else t
            new = rig.operating_point(self.rig_params(), height, temperature).commands
            steps.append((math.ceil(at / self.ts_s - 1e-9), new - base))
        return steps

    def controller_config(self) -> control.ControllerConfig:
        """The closed loop's controller settings (ScenarioError in open loop)."""
        if self.closed_loop is None:
            raise ScenarioError(f"scenario {self.name!r} has no closed_loop section")
        return self.closed_loop.controller_config(
            self.ts_s, self.height, self.temperature, self.period_samples
        )

    def excitation_table(self) -> FloatArray:
        """(period_samples, 2) zero-mean excitation of one period, where it enters.

        Open loop and ``excitation: output``: [hot, cold] deviations of the valve commands
        (``command_table()`` less the operating commands); ``excitation: setpoint``:
        [height, temperature] deviations of the setpoints.
        """
        loop = self.closed_loop
        if loop is not None and loop.excitation == "setpoint":
            cfg = dataclasses.replace(
                self.excitation_config(),
                rms=(loop.setpoint_rms_height, loop.setpoint_rms_temperature),
            )
            return excitation.excitation_period(cfg)
        return self.command_table() - self.operating_point().commands

    def flow_meter_std(self) -> FloatArray:
        """(2,) standard deviation of the [hot, cold] flow meters' noise (model units)."""
        return self.flow_meter_noise * np.array([self.rms_hot, self.rms_cold])

    def fault_objects(self) -> tuple[Fault, ...]:
        """The faults, parsed."""
        return tuple(parse_fault(spec) for spec in self.faults)

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping of the YAML keys (``scenario_from_dict`` inverts it)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out["faults"] = list(self.faults)
        out["setpoints"] = list(self.setpoints)
        out["units"] = dataclasses.asdict(self.units)
        out["excitation"] = dict(self.excitation)
        if self.closed_loop is not None:
            out["closed_loop"] = dataclasses.asdict(self.closed_loop)
        return out


_SCENARIO_KEYS: Final = tuple(f.name for f in dataclasses.fields(Scenario))


def parse_setpoint(spec: object) -> tuple[float | None, float | None, float]:
    """``"height=0.49,temperature=0.52@2000"`` -> ``(0.49, 0.52, 2000.0)`` (a key left out: None).

    Raises:
        ModelError: not of that form.
    """
    usage = (
        f"setpoint {spec!r}: write height=H[,temperature=T]@TIME_S (either key or both), "
        "e.g. 'height=0.49@2000'"
    )
    if not isinstance(spec, str) or spec.count("@") != 1:
        raise ModelError(usage)
    body, _, when = spec.partition("@")
    values: dict[str, float] = {}
    try:
        at = float(when)
        for part in body.split(","):
            key, sep, value = part.partition("=")
            if not sep or key.strip() not in ("height", "temperature") or key.strip() in values:
                raise ModelError(usage)
            values[key.strip()] = float(value)
    except ValueError as err:
        raise ModelError(usage) from err
    if not values or not all(math.isfinite(v) for v in (*values.values(), at)):
        raise ModelError(usage)
    return values.get("height"), values.get("temperature"), at


def scenario_from_dict(doc: object, source: str, default_name: str = "") -> Scenario:
    """Build a :class:`Scenario` from a parsed YAML mapping.

    Args:
        doc: Mapping of :class:`Scenario` keys; ``units`` a mapping of RigUnits fields,
            ``faults`` a list of spec strings; ``name`` defaults to ``default_name``.
        source: What the mapping came from, for messages.
        default_name: Name when the mapping has none.

    Raises:
        ScenarioError: Not a mapping, unknown or missing keys, invalid values.
        DatumError: If the excitation does not fit.
    """
    if not isinstance(doc, Mapping):
        raise ScenarioError(
            f"{source}: a scenario must be a mapping of keys, got {type(doc).__name__}"
        )
    kwargs: dict[str, Any] = {str(k): v for k, v in doc.items()}
    unknown = sorted(set(kwargs) - set(_SCENARIO_KEYS))
    if unknown:
        raise ScenarioError(
            f"{source}: unknown key(s) {unknown}; allowed keys: {', '.join(_SCENARIO_KEYS)}"
        )
    if "duration_s" not in kwargs:
        raise ScenarioError(f"{source}: the key duration_s (length of the run, s) is missing")
    kwargs.setdefault("name", default_name)
    if kwargs.get("description") is None:
        kwargs["description"] = ""
    if kwargs.get("faults") is None:
        kwargs["faults"] = ()
    if kwargs.get("setpoints") is None:
        kwargs["setpoints"] = ()
    if kwargs.get("excitation", {}) is None:
        kwargs["excitation"] = {}
    if "closed_loop" in kwargs:
        kwargs["closed_loop"] = closed_loop_from(kwargs["closed_loop"], source)
    if "units" in kwargs:
        units = kwargs["units"]
        if not isinstance(units, Mapping):
            raise ScenarioError(
                f"{source}: units must be a mapping with keys {', '.join(_UNIT_KEYS)}"
            )
        bad = sorted(set(map(str, units)) - set(_UNIT_KEYS))
        if bad:
            raise ScenarioError(
                f"{source}: unknown key(s) {bad} in units; allowed keys: {', '.join(_UNIT_KEYS)}"
            )
        for key, value in units.items():
            _real(source, f"units.{key}", value)
        try:
            kwargs["units"] = RigUnits(**{str(k): float(v) for k, v in units.items()})
        except ValueError as err:
            raise ScenarioError(f"{source}: units: {err}") from err
    try:
        return Scenario(**kwargs)
    except ScenarioError as err:
        raise ScenarioError(f"{source}: {err}") from err
    except DatumError as err:
        raise DatumError(f"{source}: {err}") from err


def shipped_scenarios() -> tuple[str, ...]:
    """Names of the scenarios shipped in ``twotank_validation/sim/scenarios/`` (sorted)."""
    folder = resources.files("twotank_validation.sim").joinpath("scenarios")
    if not folder.is_dir():
        return ()
    return tuple(
        sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))
    )


def load_scenario(path_or_name: str | os.PathLike[str]) -> Scenario:
    """Load a scenario from a YAML file, or a shipped one by name (e.g. ``"nominal"``).

    An existing file wins over a shipped name.

    Raises:
        ScenarioError: Missing file or unknown name (the message lists the shipped names),
            invalid YAML, unknown keys (the message lists the allowed ones), invalid values.
        DatumError: If the excitation does not fit.
    """
    path = Path(path_or_name)
    name = str(path_or_name)
    if path.is_file():
        source, default_name = str(path), path.stem
        try:
            text = path.read_text()
        except OSError as err:
            raise ScenarioError(f"cannot read the scenario file {path}: {err}") from err
    elif name in shipped_scenarios():
        source, default_name = f"shipped scenario {name!r}", name
        text = (
            resources.files("twotank_validation.sim")
            .joinpath("scenarios", f"{name}.yaml")
            .read_text()
        )
    else:
        raise ScenarioError(
            f"scenario {name!r} is neither a file nor a shipped scenario; shipped: "
            f"{', '.join(shipped_scenarios()) or '(none)'}"
        )
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ScenarioError(f"{source}: not valid YAML: {err}") from err
    return scenario_from_dict(doc, source, default_name)


# --- running it -------------------------------------------------------------------------------


def iter_scenario(scenario: Scenario) -> Iterator[tuple[int, float, float, float, float]]:
    """Run the scenario one sample at a time (memory independent of its length).

    Open loop, the valves get the excitation's commands (moved by the ``setpoints``). In
    closed loop (``scenario.closed_loop``) a :class:`~twotank_validation.sim.control.PIController`
    started at the operating point's commands computes command k from measurement k - 1 and
    excitation row k (command 0, before any measurement: :meth:`PIController.open_command`);
    the ``setpoints`` change its setpoints. Either way the commands yielded are the ones
    applied, i.e. what the validator is fed.

    Yields:
        ``(stamp_ns, hot, cold, height, temperature)`` for k = 0 .. n_samples - 1: the stamp
        k ts_ns, the commands applied from k ts_s on and the measurement taken at k ts_s
        (before command k acts), as :func:`twotank_validation.sim.simulator.simulate`.

    Raises:
        ModelError: If the tank empties.
    """
    ts_ns = scenario.ts_ns
    sim = simulator.TankSimulator(
        scenario.rig_params(),
        scenario.ts_s,
        op=scenario.operating_point(),
        seed=scenario.seed,
        substeps=scenario.substeps,
        faults=scenario.fault_objects(),
    )
    if scenario.closed_loop is not None:
        yield from _iter_closed_loop(scenario, sim)
        return
    rows = scenario.command_table().tolist()
    period = len(rows)
    steps = scenario.setpoint_steps()
    offset = (0.0, 0.0)
    for k in range(scenario.n_samples):
        while steps and k >= steps[0][0]:
            offset = tuple(steps.pop(0)[1].tolist())
        hot, cold = rows[k % period]
        hot, cold = hot + offset[0], cold + offset[1]
        height, temperature = sim.measure().tolist()
        sim.step((hot, cold))
        yield k * ts_ns, hot, cold, height, temperature


METER_STREAM: Final = 1
"""Spawn key of the flow meters' noise generator (the sensor noise uses the seed itself)."""

_METER_CHUNK: Final = 4096
"""Rows of meter noise drawn at a time (the same numbers as one draw of the whole run)."""


def iter_metered(
    scenario: Scenario,
) -> Iterator[tuple[int, float, float, float, float, float, float]]:
    """:func:`iter_scenario` with the flow meters' readings of each sample.

    Yields:
        ``(stamp_ns, hot, cold, height, temperature, hot_read, cold_read)``: those of
        :func:`iter_scenario` and the readings ``hot + n_hot``, ``cold + n_cold``, the noise
        white Gaussian of :meth:`Scenario.flow_meter_std`, drawn from
        ``default_rng(SeedSequence(seed, spawn_key=(METER_STREAM,)))`` as one (n, 2) array
        (in chunks; equal to the readings ``flow_meter_readings`` gives).
    """
    rng = np.random.default_rng(np.random.SeedSequence(scenario.seed, spawn_key=(METER_STREAM,)))
    std_hot, std_cold = scenario.flow_meter_std().tolist()
    if std_hot == std_cold == 0.0:  # no meters (or silent ones): the readings are the flows
        for stamp, hot, cold, height, temperature in iter_scenario(scenario):
            yield stamp, hot, cold, height, temperature, hot, cold
        return
    noise: list[list[float]] = []
    for k, (stamp, hot, cold, height, temperature) in enumerate(iter_scenario(scenario)):
        j = k % _METER_CHUNK
        if j == 0:
            noise = rng.standard_normal((_METER_CHUNK, 2)).tolist()
        n_hot, n_cold = noise[j]
        yield stamp, hot, cold, height, temperature, hot + std_hot * n_hot, cold + std_cold * n_cold


def flow_meter_readings(scenario: Scenario, commands: FloatArray) -> FloatArray:
    """(n, 2) the flow meters' readings of the (n, 2) commands of ``simulate_scenario``.

    The same numbers :func:`iter_metered` yields (model units).
    """
    rng = np.random.default_rng(np.random.SeedSequence(scenario.seed, spawn_key=(METER_STREAM,)))
    n = len(commands)
    chunks = -(-n // _METER_CHUNK)
    noise = rng.standard_normal((chunks * _METER_CHUNK, 2))[:n]
    return np.asarray(commands + scenario.flow_meter_std() * noise)


def _iter_closed_loop(
    scenario: Scenario, sim: simulator.TankSimulator
) -> Iterator[tuple[int, float, float, float, float]]:
    """The closed-loop body of :func:`iter_scenario`."""
    cfg = scenario.controller_config()
    controller = control.PIController(cfg, scenario.operating_point().commands)
    table = scenario.excitation_table()
    period = len(table)
    changes = []
    height, temperature = cfg.height_setpoint, cfg.temperature_setpoint
    for spec in sorted(scenario.setpoints, key=lambda x: parse_setpoint(x)[2]):
        h, t, at = parse_setpoint(spec)
        height = height if h is None else h
        temperature = temperature if t is None else t
        changes.append((math.ceil(at / scenario.ts_s - 1e-9), height, temperature))
    ts_ns = scenario.ts_ns
    previous: FloatArray | None = None
    for k in range(scenario.n_samples):
        while changes and k >= changes[0][0]:
            _, h_new, t_new = changes.pop(0)
            controller.set_setpoints(h_new, t_new)
        exc = table[k % period]
        measured = sim.measure()
        if previous is None:
            command = controller.open_command(exc)
        else:
            command = controller.step(previous, exc)
        previous = measured
        sim.step(command)
        hot, cold = command.tolist()
        height_k, temperature_k = measured.tolist()
        yield k * ts_ns, hot, cold, height_k, temperature_k


def simulate_scenario(
    scenario: Scenario,
) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
    """Run the scenario in memory.

    Returns:
        ``(stamps_ns, commands, measured)``: (n,) int64 stamps k ts_ns; (n, 2) [hot, cold]
        commands; (n, 2) measured [height, temperature], model units.

    Raises:
        ModelError: If the tank empties.
    """
    n = scenario.n_samples
    stamps = np.empty(n, dtype=np.int64)
    commands = np.empty((n, 2))
    measured = np.empty((n, 2))
    for k, (stamp, hot, cold, height, temperature) in enumerate(iter_scenario(scenario)):
        stamps[k] = stamp
        commands[k] = hot, cold
        measured[k] = height, temperature
    return stamps, commands, measured
