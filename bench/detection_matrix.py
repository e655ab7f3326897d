"""Detection figures of the fault alarm: a scenario matrix on the simulated rig (issue #7).

Usage: scripts/run bench detection_matrix.py [--seeds 3] [--phases 0.125,0.375,0.625,0.875]
       [--windows-after 4] [--nominal-hours 4] [--faults SUBSTRING ...] [--jobs 1]
       [--full-horizon] [--no-check] [--markdown FILE]
       scripts/run bench detection_matrix.py --limits [--alarm period|default] [--seeds 2]
       [--phases ...] [--jobs 1]

Default run: about 3.5 minutes on one core (3 seeds x 4 onset phases x 44 fault cases, 12
simulated hours of nominal data); ``--limits``: about 15 minutes (``--jobs 2`` halves both).

Every run is the default scenario (``Scenario`` defaults: filtered-noise excitation 0.05/0.2
RMS, cutoff 0.006 Hz, excitation seed 2, mixing delay 15 s, sensor noise 0.003/0.01, Ts 0.1 s,
2048-sample periods) with noise seed ``seed``, fed sample by sample as the three streams
(``flow_cmd``, ``height``, ``temperature``) into ``online.OnlineValidator`` -- the aligner,
window monitor and debounced alarm of the live node and of bag replay -- with the period/count
alarm (``CONFIG``: 2-period windows judged every period, ERROR after 2 invalidating windows in
a row, the operating-point check on) and Models A and B.

Fault runs: one fault of issue #3 (``faults.Fault``) switched on at ``onset = 4 P + phase P``
(P = 204.8 s, the period; the first judged window ends at 3 P, so two nominal windows come
before the onset), permanent except ``valve_stuck`` (no magnitude in the rig: its severity is
how long the valve stays stuck). Window 1 is the first window that contains faulty samples
(it ends at 5 P), window k the k-th report after onset; a run is followed for
``--windows-after`` windows (stopped early once both models are in ERROR, unless
``--full-horizon``; so Model A's peak beta is taken up to Model B's detection). Detection =
the alarm reaches ERROR on one of those windows; the delay is that window's number and the
time from onset to the window's end stamp. Nominal runs (no fault) of ``--nominal-hours`` per
seed give the false-alarm rate (ERROR episodes per simulated hour) and the distribution of
beta on nominal data, against which each fault's largest beta after onset is compared: a
fault whose beta stays inside the nominal range cannot be told from noise by this model set,
and not alarming on it is correct; one whose beta rises but stays below 1 is explained by the
model set's uncertainty (Model B is not invalidated), also correctly not alarmed.

Shortcut (checked): per seed, the nominal run is simulated and fed once up to 100 s before the
earliest onset, then the simulator and the validator are copied for each fault case and the
fault is registered on the copy (onset >= 100 s later, longer than any delay read back, so the
rig's delay buffers hold the true past). Unless ``--no-check``, one case per fault type is
re-run from scratch through ``sim.scenario.simulate_scenario`` (fault registered at t = 0) and
must give bit-identical reports.

``--limits``: for leak, sensor bias (both channels) and valve loss (``valve_weak`` on each
valve: the lost fraction of the valve's gain; ``valve_stuck`` has no size), bisection of the
size for each onset phase and seed: the smallest size whose alarm reaches ERROR within 3
windows. The stated limit is the worst of these over the phases (for sensor bias over phases
0.1..0.9: a bias starting at a window boundary is never detected, see README), times 1.05,
rounded up to a round number; it is then verified at every phase and seed, at twice it, and
a quarter of it is verified never to raise ERROR (with every window judged).
``--alarm default`` finds the limits of the default alarm instead (``MonitorConfig()``: a
window every quarter period, the sequential debounce), with detection defined by time: ERROR on
a window that ends within 2 periods of the onset (``Criterion``). The matrix itself always
measures the period/count alarm; ``bench_alarm.py`` measures the default one.
"""

from __future__ import annotations

import argparse
import copy
import math
import multiprocessing
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from twotank_validation.core.model import load_model
from twotank_validation.defaults import PERIOD_SAMPLES
from twotank_validation.errors import ModelError
from twotank_validation.online import (
    COMMAND,
    Alarm,
    AlarmConfig,
    MonitorConfig,
    OnlineValidator,
    WindowReport,
)
from twotank_validation.sim import faults, simulator
from twotank_validation.sim.faults import format_fault
from twotank_validation.sim.scenario import Scenario, simulate_scenario

CONFIG = MonitorConfig(hop_samples=PERIOD_SAMPLES, alarm=AlarmConfig(debounce="count"))
"""The alarm whose matrix this bench measures, and the stated limits of ``--alarm period``: one
window per period and the count rule (named, so that the figures keep their meaning whatever
the defaults)."""


@dataclass(frozen=True)
class Criterion:
    """An alarm and what "detected" means for it in the stated limits.

    ``windows``: ERROR on one of the first ``windows`` reports whose window contains faulty
    samples (the period alarm's "within 3 windows", issue #7). ``periods``: ERROR on a report
    whose window ends at most ``periods`` excitation periods after the onset (a time, so that
    it means the same at any hop; the default alarm's "within 2 periods", issue #16's
    worst-case goal).
    """

    name: str
    config: MonitorConfig
    windows: int | None = None
    periods: float | None = None

    @property
    def text(self) -> str:
        if self.windows is not None:
            return f"within {self.windows} windows"
        return f"within {self.periods:g} periods of the onset"

    @property
    def windows_after(self) -> int:
        """Whole-period steps run_case must follow for the verdict to be complete."""
        if self.windows is not None:
            return self.windows
        assert self.periods is not None
        return math.ceil(self.periods) + 1  # window 1 ends within a period of the onset

    def detected(self, reports: Sequence[WindowReport], onset_s: float) -> bool:
        """Model B's alarm reaches ERROR in time (see the class docstring)."""
        after = [r for r in reports if r.model == "B" and r.end_ns / 1e9 >= onset_s]
        if self.windows is not None:
            after = after[: self.windows]
        else:
            assert self.periods is not None
            horizon = onset_s + self.periods * self.config.period_samples * self.config.ts_s
            after = [r for r in after if r.end_ns / 1e9 <= horizon + 1e-9]
        return any(r.alarm is Alarm.ERROR for r in after)


WITHIN = 3  # "detected within 3 windows" (issue #7's stated limits; the matrix's verdicts)
ALARMS = {
    "period": Criterion("period", CONFIG, windows=WITHIN),
    "default": Criterion("default", MonitorConfig(), periods=2.0),
}
"""The alarms ``--limits`` can state limits for: the period/count alarm (``CONFIG``) and the
default alarm (``MonitorConfig()``: a window every quarter period, the sequential debounce)."""


def criterion_of(alarm: str, transient: str = "none") -> Criterion:
    """``ALARMS[alarm]`` with the window's transient term set (``--transient``)."""
    criterion = ALARMS[alarm]
    return replace(criterion, config=replace(criterion.config, transient=transient))


MODELS = ("A", "B")
ONSET_PERIOD = 4  # onsets fall in period 4 (0-based), after the judged windows ending 3P, 4P
GUARD_S = 100.0  # checkpoint this long before the earliest onset (> any delay read back)


@dataclass(frozen=True)
class FaultType:
    """One fault type of issue #3 (kind and channel) and the severities run."""

    kind: str
    channel: str
    severities: tuple[float, ...]
    unit: str

    @property
    def label(self) -> str:
        return f"{self.kind}:{self.channel}" if self.channel else self.kind

    def fault(self, severity: float, onset_s: float) -> faults.Fault:
        if self.kind == "valve_stuck":  # severity = how long it stays stuck
            return faults.Fault(self.kind, onset_s, 0.0, self.channel, end_s=onset_s + severity)
        return faults.Fault(self.kind, onset_s, severity, self.channel)

    def describe(self, severity: float) -> str:
        if self.kind == "valve_stuck":
            return "permanent" if math.isinf(severity) else f"{severity:g} s"
        if self.kind == "valve_weak":
            return f"{severity:g} ({100 * (1 - severity):.0f} % loss)"
        return f"{severity:g}"


MATRIX = (
    FaultType("leak", "", (0.01, 0.02, 0.04, 0.08), "extra outflow (nominal outflow 0.8)"),
    FaultType("sensor_bias", "height", (0.005, 0.02, 0.05, 0.1), "offset, model units"),
    FaultType("sensor_bias", "temperature", (0.02, 0.05, 0.1, 0.2), "offset, model units"),
    FaultType("valve_stuck", "hot", (20.0, 60.0, 200.0, math.inf), "time stuck, s"),
    FaultType("valve_stuck", "cold", (20.0, 60.0, 200.0, math.inf), "time stuck, s"),
    FaultType("valve_weak", "hot", (0.95, 0.9, 0.8, 0.6), "fraction of the flow delivered"),
    FaultType("valve_weak", "cold", (0.95, 0.9, 0.8, 0.6), "fraction of the flow delivered"),
    FaultType("sensor_delay", "height", (1.0, 3.0, 10.0, 30.0), "extra delay, s"),
    FaultType("sensor_delay", "temperature", (2.0, 5.0, 10.0, 30.0), "extra delay, s"),
    FaultType("mixing_delay", "", (20.0, 25.0, 35.0, 45.0), "delay at h1 = 0.47, s (nominal 15)"),
    FaultType("heat_loss", "", (0.05, 0.1, 0.2, 0.4), "heat-loss coefficient"),
)


@dataclass(frozen=True)
class LimitType:
    """A fault type of the stated limits, by size: leak and bias magnitude, valve gain lost."""

    kind: str
    channel: str
    lo: float  # bisection bracket of the size
    hi: float

    @property
    def label(self) -> str:
        return f"{self.kind}:{self.channel}" if self.channel else self.kind

    def fault(self, size: float, onset_s: float) -> faults.Fault:
        magnitude = 1.0 - size if self.kind == "valve_weak" else size
        return faults.Fault(self.kind, onset_s, magnitude, self.channel)

    def describe(self, size: float) -> str:
        if math.isinf(size):
            return "never"
        if self.kind == "valve_weak":
            return f"{100 * size:.3g} % loss (valve_weak={1 - size:.4g})"
        return f"{size:.3g}"


LIMITS = (
    LimitType("leak", "", 0.005, 0.2),
    LimitType("sensor_bias", "height", 0.005, 0.5),
    LimitType("sensor_bias", "temperature", 0.01, 0.8),
    LimitType("valve_weak", "hot", 0.01, 0.6),
    LimitType("valve_weak", "cold", 0.01, 0.6),
)
LIMIT_PHASES = (0.0, 0.02, 0.05, *(round(0.1 + 0.05 * i, 2) for i in range(17)), 0.95, 0.98)
MARGIN = 1.05  # stated limit: the worst threshold found, times this, rounded up to a round number
BAND = (0.1, 0.9)  # onsets at least 10 % of a period from a window boundary
BISECTION_STEPS = 7


# --- one seed: nominal prefix, fault cases, nominal run ------------------------------------------


@dataclass
class CaseResult:
    """What one model's alarm did after the onset of one fault run."""

    label: str
    severity: float
    phase: float
    seed: int
    model: str
    onset_s: float
    error_at_onset: bool
    windows: list[tuple[float, bool, float, Alarm]] = field(default_factory=list)
    emptied_at_s: float | None = None

    @property
    def detection(self) -> tuple[int, float] | None:
        """(window number, seconds after onset) of the first ERROR after onset, or None."""
        for i, (end_s, _judged, _beta, alarm) in enumerate(self.windows, start=1):
            if alarm is Alarm.ERROR:
                return i, end_s - self.onset_s
        return None

    @property
    def peak_beta(self) -> float:
        betas = [b for _, judged, b, _ in self.windows if judged]
        return max(betas) if betas else math.nan


@dataclass
class NominalResult:
    model: str
    seed: int
    hours: float
    judged: int
    error_windows: int
    episodes: int
    betas: list[float]


def events(k0: int, commands: np.ndarray, measured: np.ndarray, ts_ns: int):
    """The three streams of samples k0.. as OnlineValidator.feed_many events (bag order)."""
    n = len(commands)
    stamps = np.repeat(np.arange(k0, k0 + n, dtype=np.int64) * ts_ns, 3)
    kinds = np.tile(np.array([COMMAND, 0, 1]), n)
    values = np.zeros((3 * n, 2))
    values[0::3] = commands
    values[1::3, 0] = measured[:, 0]
    values[2::3, 0] = measured[:, 1]
    return kinds, stamps, values


class Run:
    """A simulator and the node's validator, stepped together (the same loop as iter_scenario)."""

    def __init__(self, scenario: Scenario, config: MonitorConfig, models) -> None:
        self.rows = scenario.command_table()
        self.ts_ns = scenario.ts_ns
        self.ts_s = scenario.ts_s
        self.sim = simulator.TankSimulator(
            scenario.rig_params(),
            scenario.ts_s,
            op=scenario.operating_point(),
            seed=scenario.seed,
            substeps=scenario.substeps,
        )
        self.validator = OnlineValidator(config, models)
        self.k = 0
        self.emptied_at_s: float | None = None

    def copy(self) -> Run:
        return copy.deepcopy(self)

    def advance(self, k_end: int) -> list[WindowReport]:
        """Simulate and feed samples up to k_end (exclusive); stops if the tank empties."""
        k0, n = self.k, k_end - self.k
        if n <= 0 or self.emptied_at_s is not None:
            return []
        period = len(self.rows)
        commands = self.rows[np.arange(k0, k_end) % period]
        measured = np.empty((n, 2))
        sim = self.sim
        # TankSimulator.step without its per-call argument checks, as simulator.simulate does: the
        # scenario's commands are checked finite and inside [0, 1] (the shortcut check compares
        # with simulate_scenario, which calls step)
        advance = sim._advance
        for i, (hot, cold) in enumerate(commands.tolist()):
            measured[i] = sim.measure()
            try:
                advance(hot, cold)
            except ModelError:  # the tank emptied: the run ends with this sample
                self.emptied_at_s = (k0 + i) * self.ts_s
                commands, measured, k_end = commands[: i + 1], measured[: i + 1], k0 + i + 1
                break
        self.k = k_end
        return self.validator.feed_many(*events(k0, commands, measured, self.ts_ns))


def onset_times(phases: Sequence[float], period_s: float) -> list[float]:
    return [round((ONSET_PERIOD + p) * period_s, 1) for p in phases]


def alarm_before(reports: Sequence[WindowReport], model: str) -> Alarm:
    mine = [r for r in reports if r.model == model]
    return mine[-1].alarm if mine else Alarm.OK


def run_case(
    base: Run,
    prefix: list[WindowReport],
    fault: faults.Fault,
    *,
    windows_after: int,
    period: int,
    full_horizon: bool,
) -> tuple[list[WindowReport], float | None]:
    """All reports (prefix included) of one fault run from the checkpoint ``base``."""
    run = base.copy()
    run.sim.add_fault(fault)
    reports = list(prefix)
    onset_k = math.ceil(fault.onset_s / run.ts_s - 1e-9)
    boundary = (onset_k // period + 1) * period  # end of window 1
    for w in range(windows_after):
        new = run.advance(boundary + w * period)
        reports.extend(new)
        after = [r for r in new if r.end_ns / 1e9 >= fault.onset_s]
        if (
            not full_horizon
            and after
            and all(alarm_before(after, m) is Alarm.ERROR for m in MODELS)
        ):
            break
        if run.emptied_at_s is not None:
            break
    return reports, run.emptied_at_s


def case_results(
    reports: list[WindowReport],
    *,
    label: str,
    severity: float,
    phase: float,
    seed: int,
    onset_s: float,
    emptied_at_s: float | None,
) -> list[CaseResult]:
    out = []
    for model in MODELS:
        mine = [r for r in reports if r.model == model]
        before = [r for r in mine if r.end_ns / 1e9 < onset_s]
        res = CaseResult(
            label=label,
            severity=severity,
            phase=phase,
            seed=seed,
            model=model,
            onset_s=onset_s,
            error_at_onset=bool(before) and before[-1].alarm is Alarm.ERROR,
            emptied_at_s=emptied_at_s,
        )
        res.windows = [
            (r.end_ns / 1e9, r.judged, r.beta, r.alarm) for r in mine if r.end_ns / 1e9 >= onset_s
        ]
        out.append(res)
    return out


def nominal_results(reports: list[WindowReport], seed: int, hours: float) -> list[NominalResult]:
    out = []
    for model in MODELS:
        mine = [r for r in reports if r.model == model]
        judged = [r for r in mine if r.judged]
        episodes, previous = 0, Alarm.OK
        for r in mine:
            if r.alarm is Alarm.ERROR and previous is not Alarm.ERROR:
                episodes += 1
            if r.alarm is not Alarm.STALE:
                previous = r.alarm
        out.append(
            NominalResult(
                model=model,
                seed=seed,
                hours=hours,
                judged=len(judged),
                error_windows=sum(r.alarm is Alarm.ERROR for r in judged),
                episodes=episodes,
                betas=[r.beta for r in judged],
            )
        )
    return out


@dataclass(frozen=True)
class Job:
    seed: int
    fault_types: tuple[FaultType, ...]
    phases: tuple[float, ...]
    windows_after: int
    nominal_hours: float
    full_horizon: bool


def run_seed(job: Job) -> tuple[list[CaseResult], list[NominalResult], float]:
    t0 = time.perf_counter()
    config = CONFIG
    models = [load_model(m) for m in MODELS]
    scenario = Scenario(name=f"detection-{job.seed}", duration_s=1.0, seed=job.seed)
    period = config.period_samples
    period_s = period * scenario.ts_s
    onsets = onset_times(job.phases, period_s)
    checkpoint_k = round((min(onsets) - GUARD_S) / scenario.ts_s)
    base = Run(scenario, config, models)
    prefix = base.advance(checkpoint_k)
    cases: list[CaseResult] = []
    for ft in job.fault_types:
        for severity in ft.severities:
            for phase, onset in zip(job.phases, onsets, strict=True):
                reports, emptied = run_case(
                    base,
                    prefix,
                    ft.fault(severity, onset),
                    windows_after=job.windows_after,
                    period=period,
                    full_horizon=job.full_horizon,
                )
                cases += case_results(
                    reports,
                    label=ft.label,
                    severity=severity,
                    phase=phase,
                    seed=job.seed,
                    onset_s=onset,
                    emptied_at_s=emptied,
                )
    nominal: list[NominalResult] = []
    if job.nominal_hours > 0:
        run = base.copy()
        reports = list(prefix)
        k_end = round(job.nominal_hours * 3600 / scenario.ts_s)
        while run.k < k_end:
            reports += run.advance(min(run.k + 20 * period, k_end))
        nominal = nominal_results(reports, job.seed, job.nominal_hours)
    return cases, nominal, time.perf_counter() - t0


def check_shortcut(fault_types: Sequence[FaultType], phase: float, windows_after: int) -> int:
    """Each type's largest severity: checkpointed copy == a from-scratch scenario run, bit for bit."""
    config = CONFIG
    models = [load_model(m) for m in MODELS]
    seed = 0
    scenario = Scenario(name="check", duration_s=1.0, seed=seed)
    period = config.period_samples
    onset = onset_times([phase], period * scenario.ts_s)[0]
    base = Run(scenario, config, models)
    prefix = base.advance(round((onset - GUARD_S) / scenario.ts_s))
    checked = 0
    for ft in fault_types:
        fault = ft.fault(ft.severities[-1], onset)
        fast, emptied = run_case(
            base, prefix, fault, windows_after=windows_after, period=period, full_horizon=True
        )
        if emptied is not None:
            continue
        n = (fast[-1].end_ns // scenario.ts_ns) + 1
        full = Scenario(
            name="check",
            duration_s=round(n * scenario.ts_s, 1),
            seed=seed,
            faults=(format_fault(fault),),
        )
        _, u, y = simulate_scenario(full)
        ref = OnlineValidator(config, models).feed_many(*events(0, u, y, scenario.ts_ns))
        got = [(r.model, r.end_ns, r.judged, r.beta, r.alarm) for r in fast]
        want = [(r.model, r.end_ns, r.judged, r.beta, r.alarm) for r in ref]
        if len(got) != len(want) or any(
            g[:3] != w[:3]
            or g[4] != w[4]
            or not (g[3] == w[3] or math.isnan(g[3]) == math.isnan(w[3]))
            for g, w in zip(got, want, strict=True)
        ):
            raise SystemExit(f"shortcut check FAILED for {format_fault(fault)}:\n{got}\n{want}")
        checked += 1
    return checked


# --- figures ---------------------------------------------------------------------------------


def fmt_delay(d: tuple[int, float] | None) -> str:
    return "-" if d is None else f"{d[0]} / {d[1]:.0f} s"


def pct(x: int, n: int) -> str:
    return "-" if n == 0 else f"{100 * x / n:.0f} %"


def nominal_summary(nominal: list[NominalResult], model: str) -> dict:
    mine = [r for r in nominal if r.model == model]
    betas = np.array([b for r in mine for b in r.betas])
    hours = sum(r.hours for r in mine)
    episodes = sum(r.episodes for r in mine)
    judged = sum(r.judged for r in mine)
    return {
        "hours": hours,
        "runs": len(mine),
        "judged": judged,
        "episodes": episodes,
        "error_windows": sum(r.error_windows for r in mine),
        "rate": episodes / hours if hours else math.nan,
        "beta_median": float(np.median(betas)) if betas.size else math.nan,
        "beta_p99": float(np.percentile(betas, 99)) if betas.size else math.nan,
        "beta_max": float(betas.max()) if betas.size else math.nan,
    }


def cell_rows(cases: list[CaseResult], model: str, beta_max: float):
    """One row per (fault type, severity) of ``model``: the figures of the table."""
    keys: list[tuple[str, float]] = []
    for c in cases:
        if c.model == model and (c.label, c.severity) not in keys:
            keys.append((c.label, c.severity))
    rows = []
    for label, severity in keys:
        runs = [c for c in cases if c.model == model and (c.label, c.severity) == (label, severity)]
        det = [c.detection for c in runs]
        found = [d for d in det if d is not None]
        within = sum(d is not None and d[0] <= WITHIN for d in det)
        peaks = [c.peak_beta for c in runs if not math.isnan(c.peak_beta)]
        above_noise = sum(p > beta_max for p in peaks)
        above_one = sum(p > 1.0 for p in peaks)
        if found:
            wins = sorted(d[0] for d in found)
            secs = sorted(d[1] for d in found)
            median = (statistics.median(wins), statistics.median(secs))
            worst = (wins[-1], secs[-1])
        else:
            median = worst = None
        n = len(runs)
        if within == n:
            verdict = f"detected within {WITHIN} windows"
        elif found:
            verdict = "partly detected"
        elif not peaks or statistics.median(peaks) <= beta_max:
            verdict = "below noise: beta in the nominal range"
        elif above_one == 0:
            verdict = "seen in beta, inside the model set (beta < 1)"
        else:
            verdict = "beta > 1 in single windows only (2 needed)"
        emptied = sum(c.emptied_at_s is not None for c in runs)
        if emptied:
            verdict += f"; tank emptied in {emptied}/{n} runs"
        rows.append(
            {
                "label": label,
                "severity": severity,
                "runs": n,
                "at_onset": sum(c.error_at_onset for c in runs),
                "within": within,
                "found": len(found),
                "median": median,
                "worst": worst,
                "peak_median": statistics.median(peaks) if peaks else math.nan,
                "above_noise": above_noise,
                "above_one": above_one,
                "verdict": verdict,
            }
        )
    return rows


def describe(label: str, severity: float) -> str:
    for ft in MATRIX:
        if ft.label == label:
            return ft.describe(severity)
    return f"{severity:g}"


def fmt_median(m) -> str:
    return "-" if m is None else f"{m[0]:g} / {m[1]:.0f} s"


def print_tables(rows, model: str, windows_after: int, out: list[str]) -> None:
    head = (
        "fault",
        "severity",
        "runs",
        f"ERROR <= {WITHIN} win",
        f"ERROR <= {windows_after} win",
        "delay median (win / s)",
        "delay worst (win / s)",
        "peak beta (median)",
        "beta > nominal max",
        "beta > 1",
        "verdict",
    )
    body = [
        (
            r["label"],
            describe(r["label"], r["severity"]),
            str(r["runs"]),
            pct(r["within"], r["runs"]),
            pct(r["found"], r["runs"]),
            fmt_median(r["median"]),
            fmt_delay(r["worst"]),
            f"{r['peak_median']:.2f}",
            pct(r["above_noise"], r["runs"]),
            pct(r["above_one"], r["runs"]),
            r["verdict"],
        )
        for r in rows
    ]
    widths = [max(len(x) for x in col) for col in zip(head, *body, strict=True)]
    print(f"\nModel {model}")
    for line in (head, *body):
        print("  ".join(x.ljust(w) for x, w in zip(line, widths, strict=True)).rstrip())
    out.append(f"\n**Model {model}**\n")
    out.append("| " + " | ".join(head) + " |")
    out.append("|" + "|".join("---" for _ in head) + "|")
    out.extend("| " + " | ".join(line) + " |" for line in body)


def print_model_a(rows, out: list[str]) -> None:
    head = ("fault", "severity", "runs", "ERROR at onset", "peak beta (median)")
    body = [
        (
            r["label"],
            describe(r["label"], r["severity"]),
            str(r["runs"]),
            pct(r["at_onset"], r["runs"]),
            f"{r['peak_median']:.2f}",
        )
        for r in rows
    ]
    widths = [max(len(x) for x in col) for col in zip(head, *body, strict=True)]
    print("\nModel A (invalidated on the nominal rig: its alarm is ERROR before any fault)")
    for line in (head, *body):
        print("  ".join(x.ljust(w) for x, w in zip(line, widths, strict=True)).rstrip())
    out.append("\n**Model A** (ERROR before any fault: the model's known inadequacy)\n")
    out.append("| " + " | ".join(head) + " |")
    out.append("|" + "|".join("---" for _ in head) + "|")
    out.extend("| " + " | ".join(line) + " |" for line in body)


def nominal_lines(nominal: list[NominalResult]) -> list[str]:
    lines = []
    for model in MODELS:
        s = nominal_summary(nominal, model)
        bound = 3.0 / s["hours"] if s["hours"] else math.nan  # 95 % upper bound for 0 events
        rate = (
            f"{s['rate']:.3g} per hour"
            if s["episodes"]
            else f"0 per hour (0 in {s['hours']:g} h; 95 % upper bound {bound:.2g} per hour)"
        )
        line = (
            f"Model {model}, nominal rig: {s['runs']} runs, {s['hours']:g} simulated h, "
            f"{s['judged']} judged windows; ERROR episodes: {s['episodes']} = {rate}; "
            f"windows in ERROR: {pct(s['error_windows'], s['judged'])}; "
            f"beta median {s['beta_median']:.3f}, 99th percentile {s['beta_p99']:.3f}, "
            f"max {s['beta_max']:.3f}"
        )
        if model == "A" and s["episodes"]:
            line += (
                " -- not false alarms: Model A lacks the level-to-temperature coupling and is "
                "invalidated by design on the nominal rig (Smith 1995); its alarm is ERROR "
                "from its 2nd judged window on, before any fault"
            )
        lines.append(line)
    return lines


# --- limits ----------------------------------------------------------------------------------


def any_error(reports: list[WindowReport], onset_s: float) -> bool:
    return any(
        r.alarm is Alarm.ERROR for r in reports if r.model == "B" and r.end_ns / 1e9 >= onset_s
    )


@dataclass(frozen=True)
class LimitJob:
    seed: int
    types: tuple[LimitType, ...]
    phases: tuple[float, ...]
    alarm: str = "period"
    transient: str = "none"


def limit_seed(job: LimitJob) -> tuple[dict[tuple[str, float], float], float]:
    """Per (type, phase): the smallest size found detected in time (bisection)."""
    t0 = time.perf_counter()
    criterion = criterion_of(job.alarm, job.transient)
    config = criterion.config
    models = [load_model(m) for m in MODELS]
    scenario = Scenario(name=f"limits-{job.seed}", duration_s=1.0, seed=job.seed)
    period = config.period_samples
    onsets = onset_times(job.phases, period * scenario.ts_s)
    base = Run(scenario, config, models)
    prefix = base.advance(round((min(onsets) - GUARD_S) / scenario.ts_s))
    out: dict[tuple[str, float], float] = {}
    for lt in job.types:
        for phase, onset in zip(job.phases, onsets, strict=True):

            def hit(size: float, lt=lt, onset=onset) -> bool:
                reports, _ = run_case(
                    base,
                    prefix,
                    lt.fault(size, onset),
                    windows_after=criterion.windows_after,
                    period=period,
                    full_horizon=False,
                )
                return criterion.detected(reports, onset)

            lo, hi = lt.lo, lt.hi
            if not hit(hi):
                out[lt.label, phase] = math.inf
                continue
            if hit(lo):
                out[lt.label, phase] = lo
                continue
            for _ in range(BISECTION_STEPS):  # geometric: hi/lo shrinks to (hi/lo)^(1/128)
                mid = math.sqrt(lo * hi)
                if hit(mid):
                    hi = mid
                else:
                    lo = mid
            out[lt.label, phase] = hi
    return out, time.perf_counter() - t0


def nice_ceil(x: float) -> float:
    """Smallest of 1, 1.2, 1.5, 2, 2.5, 3, 3.5, 4, 5, 6, 7, 8 (x 10^k) at or above x."""
    if not math.isfinite(x):
        return x
    k = math.floor(math.log10(x))
    for m in (1, 1.2, 1.5, 2, 2.5, 3, 3.5, 4, 5, 6, 7, 8, 10):
        if m * 10**k >= x * (1 - 1e-12):
            return round(m * 10**k, 12)
    return 10 ** (k + 1)


@dataclass(frozen=True)
class VerifyJob:
    seed: int
    cases: tuple[tuple[LimitType, float, float], ...]  # (type, size, phase)
    windows_after: int
    alarm: str = "period"
    transient: str = "none"


def verify_seed(job: VerifyJob) -> list[tuple[str, float, float, int, bool, bool, bool]]:
    """(label, size, phase, seed, ERROR in time, ERROR at all, all judged) per case."""
    criterion = criterion_of(job.alarm, job.transient)
    config = criterion.config
    models = [load_model(m) for m in MODELS]
    scenario = Scenario(name=f"verify-{job.seed}", duration_s=1.0, seed=job.seed)
    period = config.period_samples
    phases = sorted({c[2] for c in job.cases})
    onsets = dict(zip(phases, onset_times(phases, period * scenario.ts_s), strict=True))
    base = Run(scenario, config, models)
    prefix = base.advance(round((min(onsets.values()) - GUARD_S) / scenario.ts_s))
    out = []
    for lt, size, phase in job.cases:
        onset = onsets[phase]
        reports, emptied = run_case(
            base,
            prefix,
            lt.fault(size, onset),
            windows_after=job.windows_after,
            period=period,
            full_horizon=True,
        )
        after = [r for r in reports if r.model == "B" and r.end_ns / 1e9 >= onset]
        out.append(
            (
                lt.label,
                size,
                phase,
                job.seed,
                criterion.detected(reports, onset),
                any_error(reports, onset),
                # followed to the end (whole-period steps; hop windows in between) and all judged
                emptied is None
                and len(after) >= job.windows_after
                and all(r.judged for r in after),
            )
        )
    return out


def run_limits(
    types,
    phases,
    seeds,
    n_procs: int,
    windows_after: int,
    *,
    alarm: str = "period",
    transient: str = "none",
) -> list[str]:
    criterion = criterion_of(alarm, transient)
    jobs = [LimitJob(s, types, phases, alarm, transient) for s in seeds]
    found = _map(limit_seed, jobs, n_procs)
    for job, (_, dt) in zip(jobs, found, strict=True):
        print(f"seed {job.seed}: bisection {dt:.1f} s")
    thresholds = [f for f, _ in found]
    lines = []
    stated: dict[str, float] = {}
    for lt in types:
        print(
            f"\n{lt.label} (Model B): smallest size detected {criterion.text}, per onset "
            f"phase (rows) and seed (columns); bracket {lt.describe(lt.lo)} .. {lt.describe(lt.hi)}"
        )
        worst_all, worst_band = 0.0, 0.0
        for phase in phases:
            vals = [t[lt.label, phase] for t in thresholds]
            print(f"  phase {phase:5.3f}: " + "  ".join(f"{v:8.4g}" for v in vals))
            worst_all = max(worst_all, *vals)
            if BAND[0] <= phase <= BAND[1]:
                worst_band = max(worst_band, *vals)
        band_ok = any(BAND[0] <= p <= BAND[1] for p in phases)
        limit = worst_all if math.isfinite(worst_all) else worst_band
        where = (
            "every onset phase tested"
            if math.isfinite(worst_all)
            else (f"onsets {BAND[0]:g}..{BAND[1]:g} of a period after a window boundary")
        )
        stated[lt.label] = nice_ceil(MARGIN * limit)
        line = (
            f"{lt.label}: worst over all phases {lt.describe(worst_all)}"
            + (
                f", over phases {BAND[0]:g}..{BAND[1]:g} {lt.describe(worst_band)}"
                if band_ok
                else ""
            )
            + f"; stated limit {lt.describe(stated[lt.label])} ({where})"
        )
        print("  -> " + line)
        lines.append(line)
    # verification: the stated limit and twice it at every phase (of its range), a quarter of it
    # at every phase
    cases = []
    for lt in types:
        size = stated[lt.label]
        if not math.isfinite(size):
            continue
        everywhere = all(math.isfinite(t[lt.label, p]) for t in thresholds for p in phases)
        for p in phases:
            if everywhere or BAND[0] <= p <= BAND[1]:
                cases += [(lt, size, p), (lt, 2 * size, p)]
            cases.append((lt, size / 4, p))
    windows_after = max(windows_after, criterion.windows_after)
    results = _map(
        verify_seed,
        [VerifyJob(s, tuple(cases), windows_after, alarm, transient) for s in seeds],
        n_procs,
    )
    flat = [r for rs in results for r in rs]
    print()
    for lt in types:
        size = stated[lt.label]
        at = [r for r in flat if r[0] == lt.label and r[1] == size]
        twice = [r for r in flat if r[0] == lt.label and r[1] == 2 * size]
        below = [r for r in flat if r[0] == lt.label and r[1] == size / 4]
        if not at:
            continue
        line = (
            f"{lt.label}: ERROR {criterion.text} at the stated {lt.describe(size)} in "
            f"{sum(r[4] for r in at)}/{len(at)} runs, at twice it in "
            f"{sum(r[4] for r in twice)}/{len(twice)}; at a quarter ({lt.describe(size / 4)}) "
            f"ERROR in {sum(r[5] for r in below)}/{len(below)} runs over {windows_after} windows "
            f"after onset (all judged in {sum(r[6] for r in below)}/{len(below)})"
        )
        print(line)
        lines.append(line)
    return lines


def _map(fn, jobs, n_procs: int):
    if n_procs > 1:
        with multiprocessing.get_context("fork").Pool(n_procs) as pool:
            return pool.map(fn, jobs)
    return [fn(j) for j in jobs]


# --- main ------------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--seeds", type=int, default=None, help="noise seeds (default 3; --limits 2)"
    )
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument(
        "--phases",
        default=None,
        help="onset phases in the period after 4P, comma separated "
        f"(default 0.125,0.375,0.625,0.875; --limits {','.join(map(str, LIMIT_PHASES))})",
    )
    parser.add_argument(
        "--windows-after", type=int, default=4, help="windows followed after the onset"
    )
    parser.add_argument("--nominal-hours", type=float, default=4.0, help="per seed")
    parser.add_argument("--faults", nargs="*", default=None, help="only types containing these")
    parser.add_argument("--jobs", type=int, default=1, help="processes (seeds in parallel)")
    parser.add_argument("--full-horizon", action="store_true", help="no early stop")
    parser.add_argument("--no-check", action="store_true", help="skip the shortcut check")
    parser.add_argument("--limits", action="store_true", help="bisection for the stated limits")
    parser.add_argument(
        "--alarm",
        choices=sorted(ALARMS),
        default="period",
        help="--limits: the alarm whose limits are found (period: one window per period, "
        "count rule, ERROR within 3 windows; default: the node's default alarm, ERROR within "
        "2 periods of the onset)",
    )
    parser.add_argument(
        "--transient",
        choices=("none", "local_polynomial", "auto"),
        default="none",
        help="--limits: the window's transient term (MonitorConfig.transient; docs/theory.md)",
    )
    parser.add_argument("--markdown", default=None, help="also write the Markdown to this file")
    args = parser.parse_args()

    start = time.perf_counter()
    types = LIMITS if args.limits else MATRIX
    if args.faults:
        types = tuple(t for t in types if any(s in t.label for s in args.faults))
    if args.phases:
        phases = tuple(float(p) for p in args.phases.split(","))
    else:
        phases = LIMIT_PHASES if args.limits else (0.125, 0.375, 0.625, 0.875)
    if not all(0.0 <= p < 1.0 for p in phases):
        raise SystemExit("--phases must lie in [0, 1)")
    n_seeds = args.seeds if args.seeds is not None else (2 if args.limits else 3)
    seeds = range(args.first_seed, args.first_seed + n_seeds)
    period_s = CONFIG.period_samples * CONFIG.ts_s
    onsets = onset_times(phases, period_s)
    alarm_text = (
        "the default alarm (a window every quarter period, sequential debounce, the "
        "operating-point check on; detected = ERROR within 2 periods of the onset)"
        if args.limits and args.alarm == "default"
        else "the period/count alarm (one window per period, ERROR after 2 in a row, the "
        "operating-point check on)"
    )
    print(
        f"default scenario; {alarm_text}; Models A, B; seeds "
        f"{seeds.start}..{seeds.stop - 1}; onsets {', '.join(f'{t:g}' for t in onsets)} s "
        f"(phases {', '.join(map(str, phases))} of the period {period_s:g} s after 4 P; "
        f"window 1 ends at {(ONSET_PERIOD + 1) * period_s:g} s); "
        f"{args.windows_after} windows followed after the onset"
        + (f"; transient term: {args.transient}" if args.limits else "")
    )
    if not args.no_check:
        t = time.perf_counter()
        check_types = MATRIX if not args.faults else types
        n = check_shortcut([t for t in check_types if isinstance(t, FaultType)], phases[0], 3)
        print(
            f"shortcut check: {n} fault types, checkpointed copy == from-scratch scenario run, "
            f"bit for bit ({time.perf_counter() - t:.1f} s)"
        )
    sys.stdout.flush()
    n_procs = max(1, args.jobs)
    out: list[str] = []
    if args.limits:
        lines = run_limits(
            types,
            phases,
            seeds,
            n_procs,
            args.windows_after,
            alarm=args.alarm,
            transient=args.transient,
        )
        out.extend(f"- {line}" for line in lines)
    else:
        jobs = [
            Job(s, types, phases, args.windows_after, args.nominal_hours, args.full_horizon)
            for s in seeds
        ]
        results = _map(run_seed, jobs, n_procs)
        cases = [c for r in results for c in r[0]]
        nominal = [n for r in results for n in r[1]]
        for job, r in zip(jobs, results, strict=True):
            print(f"seed {job.seed}: {r[2]:.1f} s")
        print()
        for line in nominal_lines(nominal):
            print(line)
            out.append(f"- {line}")
        beta_max = {m: nominal_summary(nominal, m)["beta_max"] for m in MODELS}
        print_tables(cell_rows(cases, "B", beta_max["B"]), "B", args.windows_after, out)
        print_model_a(cell_rows(cases, "A", beta_max["A"]), out)
        print(f"\n{len(cases) // len(MODELS)} fault runs")
    print(f"wall time {time.perf_counter() - start:.0f} s")
    print("\n--- Markdown ---")
    print("\n".join(out))
    if args.markdown:
        with open(args.markdown, "w", encoding="utf-8") as fh:
            fh.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
