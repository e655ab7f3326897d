"""A replay's JSON summary (:func:`summary_json`) and why no window of a model was judged."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from twotank_validation.defaults import NS_PER_S
from twotank_validation.online import Alarm, WindowReport
from twotank_validation.online.states import SampleFlag, WindowQuality, WindowState
from twotank_validation.replay.config import ReplayConfig, ReplayResult
from twotank_validation.replay.timing import Timing, fmt_s


def warning_kind(text: str) -> str:
    """A warning's kind: its text up to the first number (``"output mean drifts by up to"``).

    The numbers differ from window to window; counting by kind keeps the per-model list short
    on a long run (each window's exact texts stay in its own entry).
    """
    head = re.split(r"[-+]?\d", text, maxsplit=1)[0].strip()
    return head.rstrip(" (:") or text


def summary_json(result: ReplayResult, model_names: Sequence[str] = ()) -> dict[str, Any]:
    """The documented JSON (docs/cli.md, "validate JSON"): times in s from the first stamp.

    Times count from the recording's first stamp in its time base (``time_base``: the
    header stamps, the log times or a table's time column; :attr:`ReplayResult.time_base`).

    Args:
        result: the replay.
        model_names: models to list even if they got no window (the recording too short, a
            topic missing): each with no windows and nothing judged.
    """
    t0 = result.bag_start_ns

    def sec(ns: int) -> float:
        return (ns - t0) / NS_PER_S

    def empty() -> dict[str, Any]:
        return {
            "windows": [],
            "beta_max": None,
            "first_alarm": None,
            "judged": 0,
            "not_judged": 0,
            "not_judged_reasons": {},
            "with_warnings": 0,
            "warnings": {},
        }

    models: dict[str, Any] = {name: empty() for name in model_names}
    for rep in result.reports:
        entry = models.setdefault(rep.model, empty())
        if rep.judged:
            entry["judged"] += 1
        else:
            entry["not_judged"] += 1
            why = reason_category(rep.quality)
            entry["not_judged_reasons"][why] = entry["not_judged_reasons"].get(why, 0) + 1
        if rep.warnings:
            entry["with_warnings"] += 1
            for text in rep.warnings:
                kind = warning_kind(text)
                entry["warnings"][kind] = entry["warnings"].get(kind, 0) + 1
        entry["windows"].append(window_entry(rep, t0))
        if (
            rep.judged
            and math.isfinite(rep.beta)
            and (entry["beta_max"] is None or rep.beta > entry["beta_max"])
        ):
            entry["beta_max"] = rep.beta
        if not math.isnan(rep.beta_outside):  # a band: the largest β outside it (inf: null)
            prev = entry.get("beta_outside_max", 0.0)
            top = math.inf if prev is None else max(prev, rep.beta_outside)
            entry["beta_outside_max"] = top if math.isfinite(top) else None
        if rep.alarm is Alarm.ERROR and entry["first_alarm"] is None:
            entry["first_alarm"] = sec(rep.end_ns)
    return {
        "bag": str(result.path),
        "source": result.source,
        "time_base": str(result.time_base),
        "complete": result.complete,
        "interrupted": result.interrupted,
        "problems": list(result.problems),
        "messages": result.messages,
        "counters": dict(result.counters),
        "models": models,
    }


def window_entry(rep: WindowReport, start_ns: int) -> dict[str, Any]:
    """A report's entry in the JSON's ``windows`` (times in s from ``start_ns``).

    ``beta_outside`` (β over the bins outside the model's band; null where infinite) and
    ``lines_outside`` (``[Hz, share]`` of the bins that carry most of it) only in a judged
    window of a model with a band. ``excited_lines`` (how many lines the command excites)
    and ``excited_band_hz`` (the lowest and highest of them) summarise the report's
    ``excited`` bins; the per-bin arrays (``w_min``, ``noise_floor``, ``excited``) are the
    spectrum's, which the entry leaves out (a window holds thousands of bins).
    """
    b_out = rep.beta_outside
    outside = (
        {}
        if math.isnan(b_out)
        else {
            "beta_outside": b_out if math.isfinite(b_out) else None,
            "lines_outside": [
                [hz, share if math.isfinite(share) else None] for hz, share in rep.lines_outside
            ],
        }
    )
    return outside | {
        "start": (rep.start_ns - start_ns) / NS_PER_S,
        "end": (rep.end_ns - start_ns) / NS_PER_S,
        "beta": rep.beta if rep.judged and math.isfinite(rep.beta) else None,
        "invalidated": bool(rep.invalidated),
        "alarm": rep.alarm.name,
        "reason": None if rep.judged else rep.data_quality,
        "data_quality": rep.data_quality,
        "margin": rep.margin if rep.judged and math.isfinite(rep.margin) else None,
        "warnings": list(rep.warnings),
        "input_leakage": rep.input_leakage if math.isfinite(rep.input_leakage) else None,
        "input_change": rep.input_change if math.isfinite(rep.input_change) else None,
        "input_noise": rep.input_noise if math.isfinite(rep.input_noise) else None,
        "input_noise_effect": (
            rep.input_noise_effect if math.isfinite(rep.input_noise_effect) else None
        ),
        "noise_beta": rep.noise_beta if math.isfinite(rep.noise_beta) else None,
        **_excited_entry(rep),
        "beta_op": rep.beta_op if math.isfinite(rep.beta_op) else None,
        "beta_total": rep.beta_total if math.isfinite(rep.beta_total) else None,
        "raised_by": str(rep.raised_by),
        "operating_point": rep.operating_point,
        "op_state": None if rep.op_state is None else str(rep.op_state),
        "diagnosis": None if rep.diagnosis is None else rep.diagnosis.to_json(),
    }


def _excited_entry(rep: WindowReport) -> dict[str, Any]:
    """``excited_lines`` and ``excited_band_hz`` of a window entry (null where not judged)."""
    if not rep.judged or rep.excited.size != rep.freqs_hz.size:
        return {"excited_lines": None, "excited_band_hz": None}
    f = rep.freqs_hz[rep.excited]
    return {
        "excited_lines": int(f.size),
        "excited_band_hz": [float(f.min()), float(f.max())] if f.size else None,
    }


def reason_category(quality: WindowQuality) -> str:
    """The kind of reason a window was not judged, for counting: its typed state.

    A window with unusable samples whose first flagged sample is a gap is
    ``"unusable samples (gap)"``; one still settling ``"settling"``
    (:attr:`~twotank_validation.online.states.WindowQuality.category`).
    """
    return quality.category


_FIXES: dict[tuple[WindowState, SampleFlag | None], str] = {
    (WindowState.SETTLING, None): (
        "the recording holds too few whole periods for the settling and window periods: "
        "record longer, or check --period"
    ),
    (WindowState.INPUT_NOT_PERIODIC, None): (
        "the commands do not repeat every --period samples: pass the excitation period "
        "(--period), or --closed-loop if a controller computed them; with --transient, the "
        "leakage the transient term leaves reached the budget (input_leakage >= 1): use two "
        "or more periods per window"
    ),
    (WindowState.TOO_LITTLE_EXCITATION, None): (
        "the inputs hardly move: check the command topic (--topic flow_cmd=...) and that the "
        "excitation was on"
    ),
    (WindowState.UNUSABLE_SAMPLES, SampleFlag.GAP): (
        "samples are missing on the sample grid: check --ts and that every topic was recorded"
    ),
    (WindowState.UNUSABLE_SAMPLES, SampleFlag.NON_FINITE): (
        "the data hold non-finite or implausible values: check the topics and their units"
    ),
    (WindowState.UNUSABLE_SAMPLES, SampleFlag.OFF_GRID): (
        "stamps fall between the samples of the grid: check --ts (the command stamps' grid)"
    ),
    (WindowState.UNUSABLE_SAMPLES, SampleFlag.NO_COMMAND): (
        "no valid valve command: check the command topic"
    ),
}
"""The likely fix of the main reason no window of a model was judged, by its typed state."""


class NoWindow(StrEnum):
    """Why a model has no window at all (not even an unjudged one)."""

    NOT_FORMED = "no window was formed"
    """The recording could not be read far enough (its first problem is the fix)."""
    TOO_SHORT = "the recording holds no whole window"


@dataclass(frozen=True)
class Unjudged:
    """A model of which no window could be judged: the main reason, typed, and the fix.

    Attributes:
        model: the model's name.
        reason: the most frequent reason its windows were not judged (the first of equals);
            None where it has no window (``no_window`` says why).
        windows: the windows of that reason.
        of: the model's windows.
        no_window: why it has no window at all; None where it has some.
        fix: the likely fix, in words.
        hints: what the data suggest of the timing (the timing's conflicts, in words).
        subject: what the windows were for, in the text (``"of model B"`` by default; a
            command that judges no model of the user's says what it does instead, e.g.
            ``"to identify from"``).
    """

    model: str
    reason: WindowQuality | None
    windows: int
    of: int
    no_window: NoWindow | None
    fix: str
    hints: tuple[str, ...] = ()
    subject: str = ""

    def text(self) -> str:
        """``"no window of model B could be judged: settling (5 of 5 window(s)); <fix>"``."""
        if self.reason is not None:
            why = f"{self.reason.category} ({self.windows} of {self.of} window(s))"
        else:
            why = str(self.no_window)
        subject = self.subject or f"of model {self.model}"
        return f"no window {subject} could be judged: {why}; " + "; ".join([self.fix, *self.hints])


def unjudged(
    result: ReplayResult,
    model_names: Sequence[str] = (),
    timing: Timing | None = None,
    config: ReplayConfig | None = None,
) -> list[Unjudged]:
    """The models of which no window could be judged, from the replay's typed window states.

    Args:
        result: the replay.
        model_names: the models asked for (listed even without any window), in order; then
            any other model of the reports, in report order (as :func:`summary_json`).
        timing: the timing used (adds what the data suggest to the fix), or None.
        config: the replay settings (to say how long a recording one window needs).
    """
    hints = tuple(timing.conflicts) if timing is not None else ()
    counts: dict[str, dict[str, list[Any]]] = {name: {} for name in model_names}
    judged: dict[str, int] = dict.fromkeys(model_names, 0)
    totals: dict[str, int] = dict.fromkeys(model_names, 0)
    for rep in result.reports:
        counts.setdefault(rep.model, {})
        judged[rep.model] = judged.get(rep.model, 0) + int(rep.judged)
        if not rep.judged:
            totals[rep.model] = totals.get(rep.model, 0) + 1
            seen = counts[rep.model].setdefault(rep.quality.category, [rep.quality, 0])
            seen[1] += 1
    out = []
    for name, reasons in counts.items():
        if judged.get(name, 0):
            continue
        if reasons:
            quality, n = max(reasons.values(), key=lambda seen: seen[1])
            unusable = quality.state is WindowState.UNUSABLE_SAMPLES
            key = (quality.state, quality.flag if unusable else None)
            fix = _FIXES.get(key, "see each window's reason in the JSON")
            out.append(Unjudged(name, quality, n, totals[name], None, fix, hints))
        elif result.problems:
            out.append(Unjudged(name, None, 0, 0, NoWindow.NOT_FORMED, result.problems[0], hints))
        else:
            fix = "record longer"
            if config is not None:
                mon = config.monitor
                need = (mon.settle_periods + mon.periods_per_window) * mon.period_samples
                fix = (
                    f"one window needs {need} samples ({fmt_s(need * mon.ts_s)} s: "
                    f"{mon.settle_periods} settling + {mon.periods_per_window} window periods "
                    f"of {mon.period_samples}): record longer or check --period"
                )
            out.append(Unjudged(name, None, 0, 0, NoWindow.TOO_SHORT, fix, hints))
    return out
