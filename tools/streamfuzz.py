"""Hostile message streams for the online validator, and the invariants it must keep.

Used by ``test/online/test_hostile_streams.py`` (a short, bounded, property-based run) and
``bench/fuzz_streams.py`` (long runs). A run is: clean rig data through
:class:`~twotank_validation.online.validator.OnlineValidator` for a while, then a hostile stretch
(random stamps, NaN and inf, huge values, bursts far above the sample rate, long silences,
clock jumps backwards, malformed values), then clean data again. The invariants:

* nothing but the documented :class:`~twotank_validation.errors.DatumError` (for a malformed
  value) ever leaves ``feed``, and the validator keeps working after one;
* no window that overlaps the hostile stretch is judged (unless the stretch holds only exact
  duplicates, which are dropped and harm nothing), and every judged window has a finite beta;
* every report has a reason: a window not judged says why in ``data_quality``, a judged one
  starts with ``"ok"`` and names its warnings there;
* after the hostile stretch the validator judges windows again and Model B's alarm returns
  to OK (the clean data are the nominal rig, which Model B explains).

ROS-free; the rig data come from :mod:`twotank_validation.sim.rig`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np

from twotank_validation import experiment
from twotank_validation.core.model import LFTModel, load_model
from twotank_validation.errors import DatumError
from twotank_validation.online import Alarm, MonitorConfig, OnlineValidator, WindowReport
from twotank_validation.sim import excitation, rig, simulator

CONFIG = MonitorConfig(ts_s=0.8, period_samples=256, max_recovered_fraction=0.0)
"""The same 204.8 s period as the defaults with 8x fewer samples (as the node tests), and no
recovery of unusable samples: the invariants are about the flags themselves (a short hostile
stretch would otherwise be recovered, as :mod:`twotank_validation.online.recovery` does on
purpose; ``test/online/test_recovery.py`` checks that)."""

HOSTILE_KINDS = (
    "nan",
    "inf",
    "huge",
    "random_stamp",
    "duplicate",
    "backwards",
    "clock_reset",
    "burst",
    "silence",
    "malformed",
)


@cache
def clean_record(n_periods: int = 6, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(stamps_ns, u, y)`` of the nominal rig: (n,), (n, 2), (n, 2), model units."""
    return _rig_record(n_periods, seed, None)


def _rig_record(
    n_periods: int, seed: int, start: rig.OperatingPoint | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(stamps_ns, u, y)`` of the excited rig: (n,), (n, 2), (n, 2), model units.

    Excited from the first sample at ts 0.8 s, period 256, started at ``start`` (None: its
    operating point).
    """
    cfg = experiment.ExperimentConfig()
    exc = dataclasses.replace(
        cfg.excitation,
        ts_s=CONFIG.ts_s,
        period_samples=CONFIG.period_samples,
        settle_periods=0,
        record_periods=n_periods,
    )
    u = excitation.excitation_commands(exc, rig.operating_point(cfg.rig).commands)
    sim = simulator.simulate(cfg.rig, u, CONFIG.ts_s, op=start, seed=seed, substeps=16)
    stamps = np.arange(len(u), dtype=np.int64) * round(CONFIG.ts_s * 1e9)
    return stamps, sim.commands, sim.measured


def _events(stamps: np.ndarray, u: np.ndarray, y: np.ndarray) -> list[tuple[str, int, Any]]:
    out: list[tuple[str, int, Any]] = []
    for k in range(stamps.size):
        t = int(stamps[k])
        out.append(("flow_cmd", t, (float(u[k, 0]), float(u[k, 1]))))
        out.append(("height", t, float(y[k, 0])))
        out.append(("temperature", t, float(y[k, 1])))
    return out


@dataclass
class RunResult:
    """What a hostile run produced.

    Attributes:
        reports: every window report, in order.
        errors: messages of the DatumErrors ``feed`` raised (malformed values).
        hostile_span_ns: (first, last) stamp of the hostile stretch (clean timeline).
        kinds: the hostile kinds used.
        violations: broken invariants (empty when the run is good).
    """

    reports: list[WindowReport] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    hostile_span_ns: tuple[int, int] = (0, 0)
    kinds: list[str] = field(default_factory=list)
    violations: list[str] = field(default_factory=list)


def hostile_events(
    rng: np.random.Generator,
    clean: list[tuple[str, int, Any]],
    span: tuple[int, int],
    kinds: list[str] | None = None,
) -> tuple[list[tuple[str, int, Any]], list[str]]:
    """Corrupt the clean events whose stamps fall in ``span`` (ns); returns events, kinds.

    ``kinds`` (of :data:`HOSTILE_KINDS`) are drawn at random unless given.
    """
    lo, hi = span
    if kinds is None:
        kinds = list(rng.choice(HOSTILE_KINDS, size=int(rng.integers(1, 5)), replace=False))
    out: list[tuple[str, int, Any]] = []
    for stream, t, value in clean:
        if not lo <= t <= hi:
            out.append((stream, t, value))
            continue
        if "silence" in kinds and rng.random() < 0.9:
            continue
        kind = kinds[int(rng.integers(len(kinds)))]
        v: Any = value
        stamp = t
        if kind == "nan":
            v = (math.nan, value[1]) if stream == "flow_cmd" else math.nan
        elif kind == "inf":
            v = (value[0], -math.inf) if stream == "flow_cmd" else math.inf
        elif kind == "huge":
            v = (
                (1e300, value[1])
                if stream == "flow_cmd"
                else 1e300 * (1 if rng.random() < 0.5 else -1)
            )
        elif kind == "random_stamp":
            stamp = int(rng.integers(0, 2**62))
        elif kind == "duplicate":
            out.append((stream, t, v))
        elif kind == "backwards":
            stamp = t - int(rng.integers(1, 50)) * 800_000_000
        elif kind == "clock_reset":
            stamp = max(0, t - 120_000_000_000)
        elif kind == "burst":
            for _ in range(int(rng.integers(2, 30))):
                out.append((stream, t + int(rng.integers(0, 800_000_000)), v))
        elif kind == "malformed":
            v = (1.0, 2.0, 3.0) if stream == "flow_cmd" else "not a number"
        out.append((stream, stamp, v))
    return out, kinds


def run(seed: int, models: list[LFTModel] | None = None) -> RunResult:
    """One hostile run: 4 clean periods, a hostile stretch of 1-2 periods, 5 clean periods.

    Returns the reports and any broken invariant (``violations``).
    """
    rng = np.random.default_rng(seed)
    n_periods = 11
    stamps, u, y = clean_record(n_periods, seed % 4)
    period_ns = CONFIG.period_samples * round(CONFIG.ts_s * 1e9)
    lo = 4 * period_ns + int(rng.integers(0, period_ns))
    hi = lo + int(rng.integers(period_ns // 8, 2 * period_ns))
    events, kinds = hostile_events(rng, _events(stamps, u, y), (lo, hi))
    core = OnlineValidator(CONFIG, models or [load_model("A"), load_model("B")])
    result = RunResult(hostile_span_ns=(lo, hi), kinds=kinds)
    for stream, t, value in events:
        try:
            result.reports.extend(core.feed(stream, t, value))
        except DatumError as err:
            result.errors.append(str(err))
        except Exception as err:  # the invariant under test: nothing else may escape
            result.violations.append(f"{type(err).__name__} from feed: {err}")
            return result
    check(result)
    return result


def check(result: RunResult) -> None:
    """Append every broken invariant to ``result.violations``."""
    lo, hi = result.hostile_span_ns
    for r in result.reports:
        if not r.judged:
            if not r.data_quality.strip() or r.invalidated or r.warnings:
                result.violations.append(
                    f"{r.model}: window {r.start_ns}..{r.end_ns} not judged without a reason "
                    f"or with a verdict ({r.data_quality!r}, invalidated {r.invalidated})"
                )
            continue
        if not r.data_quality.startswith("ok") or any(
            f"warning: {w}" not in r.data_quality for w in r.warnings
        ):
            result.violations.append(
                f"{r.model}: judged window {r.start_ns}..{r.end_ns} with data_quality "
                f"{r.data_quality!r} and warnings {r.warnings}"
            )
        if not math.isfinite(r.beta):
            result.violations.append(f"judged window of {r.model} with beta {r.beta}")
        if r.start_ns <= hi and r.end_ns >= lo and set(result.kinds) != {"duplicate"}:
            result.violations.append(
                f"{r.model}: window {r.start_ns}..{r.end_ns} overlaps the hostile stretch "
                f"{lo}..{hi} ({result.kinds}) and was judged (beta {r.beta:.3g})"
            )
    after = [r for r in result.reports if r.model == "B" and r.start_ns > hi]
    if not any(r.judged for r in after):
        result.violations.append(
            f"no judged window of B after the hostile stretch ({result.kinds})"
        )
    elif after[-1].alarm is not Alarm.OK:
        result.violations.append(f"B's alarm did not recover: {after[-1].alarm.name}")


@cache
def transient_record(n_periods: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(stamps_ns, u, y)`` of the rig with a start-up transient: (n,), (n, 2), (n, 2).

    Started off its operating point (level 0.40, temperature 0.42 instead of 0.47, 0.5) with
    the excitation on from the first sample; ts 0.8 s, period 256, model units.
    """
    start = rig.operating_point(experiment.ExperimentConfig().rig, height=0.40, temperature=0.42)
    return _rig_record(n_periods, 0, start)
