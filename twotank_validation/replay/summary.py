"""A replay's JSON summary (:func:`summary_json`) and why no window of a model was judged."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from typing import Any

from twotank_validation.defaults import NS_PER_S
from twotank_validation.online import Alarm
from twotank_validation.online.states import WindowQuality
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
    """The documented JSON (docs/cli.md, "validate JSON"): times in seconds of bag time.

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
        entry["windows"].append(
            {
                "start": sec(rep.start_ns),
                "end": sec(rep.end_ns),
                "beta": rep.beta if rep.judged and math.isfinite(rep.beta) else None,
                "invalidated": bool(rep.invalidated),
                "alarm": rep.alarm.name,
                "reason": None if rep.judged else rep.data_quality,
                "data_quality": rep.data_quality,
                "margin": rep.margin if rep.judged and math.isfinite(rep.margin) else None,
                "warnings": list(rep.warnings),
                "beta_op": rep.beta_op if math.isfinite(rep.beta_op) else None,
                "beta_total": rep.beta_total if math.isfinite(rep.beta_total) else None,
                "raised_by": str(rep.raised_by),
                "operating_point": rep.operating_point,
                "diagnosis": None if rep.diagnosis is None else rep.diagnosis.to_json(),
            }
        )
        if (
            rep.judged
            and math.isfinite(rep.beta)
            and (entry["beta_max"] is None or rep.beta > entry["beta_max"])
        ):
            entry["beta_max"] = rep.beta
        if rep.alarm is Alarm.ERROR and entry["first_alarm"] is None:
            entry["first_alarm"] = sec(rep.end_ns)
    return {
        "bag": str(result.path),
        "source": result.source,
        "complete": result.complete,
        "problems": list(result.problems),
        "messages": result.messages,
        "counters": dict(result.counters),
        "models": models,
    }


def reason_category(quality: WindowQuality) -> str:
    """The kind of reason a window was not judged, for counting: its typed state.

    A window with unusable samples whose first flagged sample is a gap is
    ``"unusable samples (gap)"``; one still settling ``"settling"``
    (:attr:`~twotank_validation.online.states.WindowQuality.category`).
    """
    return quality.category


_FIXES: dict[str, str] = {
    "settling": (
        "the recording holds too few whole periods for the settling and window periods: "
        "record longer, or check --period"
    ),
    "input not periodic": (
        "the commands do not repeat every --period samples: pass the excitation period "
        "(--period), or --closed-loop if a controller computed them"
    ),
    "too little excitation": (
        "the inputs hardly move: check the command topic (--topic flow_cmd=...) and that the "
        "excitation was on"
    ),
    "unusable samples (gap)": (
        "samples are missing on the sample grid: check --ts and that every topic was recorded"
    ),
    "unusable samples (non-finite)": (
        "the data hold non-finite or implausible values: check the topics and their units"
    ),
    "unusable samples (off grid)": (
        "stamps fall between the samples of the grid: check --ts (the command stamps' grid)"
    ),
    "unusable samples (no command)": "no valid valve command: check the command topic",
}


def unjudged_models(
    summary: Mapping[str, Any],
    timing: Timing | None = None,
    config: ReplayConfig | None = None,
) -> list[str]:
    """One line per model of which no window could be judged: the main reason and the fix.

    Args:
        summary: :func:`summary_json` of the replay (models without any window listed too).
        timing: the timing used (adds what the data suggest to the fix), or None.
        config: the replay settings (to say how long a recording one window needs).
    """
    out = []
    hints = list(timing.conflicts) if timing is not None else []
    for name, entry in summary["models"].items():
        if entry["judged"]:
            continue
        reasons = entry["not_judged_reasons"]
        if reasons:
            main = max(reasons, key=reasons.get)
            why = f"{main} ({reasons[main]} of {entry['not_judged']} window(s))"
            fix = _FIXES.get(main, "see each window's reason in the JSON")
        elif summary["problems"]:
            why, fix = "no window was formed", summary["problems"][0]
        else:
            why = "the recording holds no whole window"
            fix = "record longer"
            if config is not None:
                mon = config.monitor
                need = (mon.settle_periods + mon.periods_per_window) * mon.period_samples
                fix = (
                    f"one window needs {need} samples ({fmt_s(need * mon.ts_s)} s: "
                    f"{mon.settle_periods} settling + {mon.periods_per_window} window periods "
                    f"of {mon.period_samples}): record longer or check --period"
                )
        out.append(f"no window of model {name} could be judged: {why}; " + "; ".join([fix, *hints]))
    return out
