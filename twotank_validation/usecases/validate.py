"""``validate`` of one recording: the models' windows judged through the live validator's code."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from twotank_validation import replay
from twotank_validation.errors import ExitCode, TwotankError
from twotank_validation.online.op_tracker import SUSPENDED_NOTE, OpState
from twotank_validation.usecases.outcome import (
    STATUS_OF_CODE,
    Level,
    Message,
    Outcome,
    Say,
    Status,
    Teller,
    exit_status,
)
from twotank_validation.usecases.reading import (
    ReadSettings,
    load,
    model_names,
    open_recording,
    timed_config,
)

Progress = Callable[[int, int], None]
"""Told (messages read, messages expected) now and then."""


@dataclass(frozen=True)
class ValidateJob:
    """Validate models on one recording (``twotank-validation validate RECORDING``).

    Attributes:
        recording: the bag or table.
        read: how to read it (interface map, window settings, timing options).
        models: model names or YAML paths, in order.
        diagnosis: run the live diagnosis (name the effect once an alarm rises).
        json_path: write the summary JSON here (None: not written).
        report_dir: write the figures here (None: none).
    """

    recording: str
    read: ReadSettings = field(default_factory=ReadSettings)
    models: tuple[str, ...] = ("A", "B")
    diagnosis: bool = True
    json_path: str | None = None
    report_dir: str | None = None

    def at(self, path: str) -> ValidateJob:
        """This job on another recording, writing nothing (a fleet's task)."""
        return dataclasses.replace(self, recording=path, json_path=None, report_dir=None)

    def model_names(self, *, check_channels: bool = False) -> list[str]:
        """The models' names (loading them; ``check_channels``: matched to the map's too)."""
        return model_names(self.models, self.read if check_channels else None)

    def run(self, *, say: Say | None = None, progress: Progress | None = None) -> Outcome:
        """Replay the recording and judge every model's windows.

        Args:
            say: told each note (timing) and warning as it arises.
            progress: told (messages read, messages expected) now and then.

        Returns:
            The outcome: the code, the summary (``document``, as ``--json`` writes it),
            the table of windows (``text``), the counts and errors (``closing``). An error
            reading the recording is an ``UNREADABLE`` outcome with its ``ERROR`` message.
        """
        tell = Teller(say)
        try:
            loaded = [load(m) for m in self.models]
            models = [lm.model for lm in loaded]
            with open_recording(self.read, self.recording) as recording:
                cfg, timing = timed_config(self.read, recording, tell)
                if self.diagnosis:
                    documents = {lm.model.name: lm.document for lm in loaded}
                    cfg = dataclasses.replace(cfg, diagnosis=True, documents=documents)
                result = replay.replay_recording(recording, models, cfg, progress=progress)
        except TwotankError as err:
            return Outcome(
                ExitCode.ERROR,
                Status.UNREADABLE,
                messages=tuple(tell.messages),
                closing=(Message(Level.ERROR, str(err)),),
            )
        summary = replay.summary_json(result, [m.name for m in models])
        summary["timing"] = timing.to_json()
        if self.json_path:
            Path(self.json_path).write_text(json.dumps(summary, indent=2))
        if self.report_dir:
            from twotank_validation import report  # noqa: PLC0415 (matplotlib)

            by_name = {m.name: m for m in models}
            report.write_replay_report(result, by_name, summary, Path(self.report_dir))
        code, errors = exit_status(
            result.complete, replay.unjudged(result, [m.name for m in models], timing, cfg), timing
        )
        counts = (
            f"{result.messages} {'rows' if result.source == 'table' else 'messages'}; "
            f"decoding {result.decode_s:.2f} s, validation {result.validate_s:.2f} s; "
            + ("complete" if result.complete else "INCOMPLETE")
        )
        warnings = [Message(Level.WARNING, p) for p in result.problems]
        return Outcome(
            code,
            STATUS_OF_CODE[code],
            summary,
            summary,
            tuple(tell.messages),
            tuple(windows_text(summary)),
            (*warnings, Message(Level.INFO, counts), *errors),
        )


def windows_text(summary: Mapping[str, Any]) -> list[str]:
    """The table of windows and one line per model of a replay's summary."""
    lines = [f"{'window (s)':>21}  {'model':<6} {'beta':>7} {'beta_op':>7}  {'verdict':<30} alarm"]
    for name, entry in summary["models"].items():
        for w in entry["windows"]:
            verdict = (
                ("INVALIDATED" if w["invalidated"] else "valid")
                if w["beta"] is not None
                else "not judged"
            )
            beta = f"{w['beta']:7.3f}" if w["beta"] is not None else "      -"
            beta += f" {w['beta_op']:7.3f}" if w["beta_op"] is not None else "       -"
            if w["raised_by"]:
                verdict += f" ({w['raised_by']})"
            extra = f"  ({w['reason']})" if w["reason"] else ""
            if w["beta"] is not None and w.get("op_state") == OpState.SUSPENDED:
                extra += f"  (operating point not checked: {SUSPENDED_NOTE})"
            extra += "".join(f"  (warning: {text})" for text in w["warnings"])
            if w["diagnosis"] is not None:
                extra += "  (diagnosis: {})".format(diagnosis_text(w["diagnosis"]))
            lines.append(
                f"{w['start']:9.1f}-{w['end']:9.1f}  {name:<6} {beta}  {verdict:<30} "
                f"{w['alarm']}{extra}"
            )
    for name, entry in summary["models"].items():
        bmax = "-" if entry["beta_max"] is None else f"{entry['beta_max']:.3f}"
        first = "none" if entry["first_alarm"] is None else f"{entry['first_alarm']:.1f} s"
        lines.append(
            f"model {name}: {entry['judged']} of {entry['judged'] + entry['not_judged']} "
            f"window(s) judged, beta_max {bmax}, first alarm {first}"
        )
    return lines


def diagnosis_text(d: Mapping[str, Any]) -> str:
    """``"leak on height (outflow 0.058), probability 0.997"`` of a diagnosis entry.

    The probability that the answer names the fault (docs/diagnosis.md, "The probability of
    an answer"); an ``unexplained`` answer names none; a kind of answer the isolation bench
    did not measure says so.
    """
    params = ", ".join(f"{k} {v:.3g}" for k, v in d["parameters"].items())
    where = f" on {d['channel']}" if d["channel"] else ""
    p = d["probability"]
    if d["kind"] == "unexplained":
        tail = ": no effect of the catalogue explains the change"
    elif p is None:
        tail = ", probability not measured (too rare on the isolation bench)"
    else:
        tail = f", probability {p:.3f}"
    return f"{d['kind']}{where}" + (f" ({params})" if params else "") + tail
