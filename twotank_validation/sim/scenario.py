"""Simulated experiments as scenarios (YAML): definition, loading and running them.

A :class:`Scenario` fixes everything a simulated run of the two-tank rig needs: duration and
sample period, operating point, the periodic excitation (started at t = 0 around the
operating point, as the excitation node does), the rig's unmodelled effects (sensor noise,
mixing delay) and faults in their text form (:mod:`twotank_validation.sim.faults`).
``simulate_scenario`` runs it in memory, ``iter_scenario`` sample by sample; writing it into a
bag is :func:`twotank_validation.bags.scenario.write_scenario_bag`.

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
from twotank_validation.sim import excitation, rig
from twotank_validation.sim.faults import MAX_FAULT_DELAY_S, Fault, parse_fault

__all__ = [
    "MAX_SUBSTEP_S",
    "Scenario",
    "ScenarioError",
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
        units: Conversion of level and temperature to Pa and °C in the messages.

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
    noise_std_height: float = 0.003
    noise_std_temperature: float = 0.01
    mixing_delay_s: float = 15.0
    leak_per_level: float = 0.0
    heat_loss_coeff: float = 0.0
    faults: tuple[str, ...] = ()
    setpoints: tuple[str, ...] = ()
    seed: int = 0
    units: RigUnits = field(default_factory=RigUnits)

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
        put(self, "seed", _integer(where, "seed", self.seed, lo=0))
        put(
            self,
            "mixing_delay_s",
            _real(where, "mixing_delay_s", self.mixing_delay_s, lo=0.0, hi=MAX_FAULT_DELAY_S),
        )
        for key in ("leak_per_level", "heat_loss_coeff"):
            put(self, key, _real(where, key, getattr(self, key), lo=0.0, hi=5.0))
        if not isinstance(self.units, RigUnits):
            raise ScenarioError(f"{where}: units={self.units!r} must be a RigUnits")
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

    def excitation_config(self) -> excitation.ExcitationConfig:
        """The excitation of one period (as the excitation node builds it)."""
        return excitation.ExcitationConfig(
            kind=self.excitation_kind,
            ts_s=self.ts_s,
            period_samples=self.period_samples,
            settle_periods=0,
            record_periods=1,
            rms=(self.rms_hot, self.rms_cold),
            cutoff_hz=self.cutoff_hz,
            f_max_hz=self.f_max_hz,
            odd_only=self.odd_only,
            seed=self.excitation_seed,
        )

    def command_table(self) -> FloatArray:
        """(period_samples, 2) absolute [hot, cold] commands of one period.

        Sample k of the run uses row k mod period_samples (the excitation starts at t = 0).
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

    def fault_objects(self) -> tuple[Fault, ...]:
        """The faults, parsed."""
        return tuple(parse_fault(spec) for spec in self.faults)

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping of the YAML keys (``scenario_from_dict`` inverts it)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out["faults"] = list(self.faults)
        out["setpoints"] = list(self.setpoints)
        out["units"] = dataclasses.asdict(self.units)
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

    Yields:
        ``(stamp_ns, hot, cold, height, temperature)`` for k = 0 .. n_samples - 1: the stamp
        k ts_ns, the commands applied from k ts_s on and the measurement taken at k ts_s
        (before command k acts), as :func:`twotank_validation.sim.rig.simulate`.

    Raises:
        ModelError: If the tank empties.
    """
    rows = scenario.command_table().tolist()
    period = len(rows)
    steps = scenario.setpoint_steps()
    offset = (0.0, 0.0)
    ts_ns = scenario.ts_ns
    sim = rig.TankSimulator(
        scenario.rig_params(),
        scenario.ts_s,
        op=scenario.operating_point(),
        seed=scenario.seed,
        substeps=scenario.substeps,
        faults=scenario.fault_objects(),
    )
    for k in range(scenario.n_samples):
        while steps and k >= steps[0][0]:
            offset = tuple(steps.pop(0)[1].tolist())
        hot, cold = rows[k % period]
        hot, cold = hot + offset[0], cold + offset[1]
        height, temperature = sim.measure().tolist()
        sim.step((hot, cold))
        yield k * ts_ns, hot, cold, height, temperature


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
