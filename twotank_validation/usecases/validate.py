"""``validate`` of one recording: the models' windows judged through the live validator's code."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from twotank_validation import replay
from twotank_validation.core.model import LFTModel
from twotank_validation.errors import ExitCode, Interrupted, TwotankError, UsageError, interruption
from twotank_validation.online import WindowReport
from twotank_validation.online.op_tracker import SUSPENDED_NOTE, OpState
from twotank_validation.online.validator_settings import ValidatorSettings
from twotank_validation.usecases.outcome import (
    STATUS_OF_CODE,
    Level,
    Message,
    Outcome,
    Progress,
    Say,
    Show,
    Status,
    Teller,
    exit_status,
    nothing_judged,
    unreadable,
    write_json,
)
from twotank_validation.usecases.reading import (
    ReadSettings,
    load,
    model_names,
    open_recording,
    timed_config,
)

DEFAULT_MODELS: tuple[str, ...] = ValidatorSettings.models
"""The models judged when none is named: the validator node's ``models`` parameter's."""


@dataclass(frozen=True)
class ValidateJob:
    """Validate models on one recording (``twotank-validation validate RECORDING``).

    Attributes:
        recording: the bag or table.
        read: how to read it (interface map, window settings, timing options).
        models: model names or YAML paths, in order; None: the defaults
            (:data:`DEFAULT_MODELS`, the validator node's ``models`` parameter's), which the
            run says (a note, and ``models_from`` in the JSON).
        diagnosis: run the live diagnosis (name the effect once an alarm rises).
        json_path: write the summary JSON here (None: not written).
        report_dir: write the figures here (None: none).
        fail_on_alarm: the code is ``ALARM`` when a model's alarm rose (ERROR) on a judged
            window (needs the models named: a UsageError otherwise).
    """

    recording: str
    read: ReadSettings = field(default_factory=ReadSettings)
    models: tuple[str, ...] | None = None
    diagnosis: bool = True
    json_path: str | None = None
    report_dir: str | None = None
    fail_on_alarm: bool = False

    def __post_init__(self) -> None:
        if self.fail_on_alarm and not self.models_named:
            raise UsageError(
                "--fail-on-alarm fails the run when any model's alarm rises: name the models "
                f"to judge with --model (the default models {names_text(DEFAULT_MODELS)} "
                "include Model A, invalidated by design on the two-tank rig, whose alarm would "
                "fail every run)"
            )

    @property
    def models_named(self) -> bool:
        """The models were named (else the defaults are judged, and the run says so)."""
        return self.models is not None

    @property
    def sources(self) -> tuple[str, ...]:
        """The models judged: those named, else :data:`DEFAULT_MODELS`."""
        return self.models if self.models is not None else DEFAULT_MODELS

    def at(self, path: str) -> ValidateJob:
        """This job on another recording, writing nothing (a fleet's task)."""
        return dataclasses.replace(self, recording=path, json_path=None, report_dir=None)

    def model_names(self, *, check_channels: bool = False) -> list[str]:
        """The models' names (loading them; ``check_channels``: matched to the map's too)."""
        return model_names(self.sources, self.read if check_channels else None)

    def run(
        self,
        *,
        say: Say | None = None,
        progress: Progress | None = None,
        show: Show | None = None,
        on_report: Callable[[WindowReport, int], None] | None = None,
    ) -> Outcome:
        """Replay the recording and judge every model's windows.

        Args:
            say: told each note (timing) and warning as it arises.
            progress: told (messages read, messages expected) now and then.
            show: told each line of the table as it arises: the header, then a row per
                window as it is judged (the lines ``text`` begins with).
            on_report: told each report as it is judged, with the stamp its times count
                from (the recording's start; e.g. the live view).

        Returns:
            The outcome: the code, the summary (``document``, as ``--json`` writes it),
            the table of windows (``text``: header, a row per window in the order judged,
            a line per model), the counts and errors (``closing``). An error reading the
            recording is an ``UNREADABLE`` outcome with its ``ERROR`` message. SIGINT or
            SIGTERM (a KeyboardInterrupt) is an ``INTERRUPTED`` outcome (code 130 or 143):
            what was judged up to then is in its text, its JSON (``"interrupted": true``) and
            its figures.
        """
        tell = Teller(say)
        if not self.models_named:
            tell(Level.NOTE, default_models_note(self.sources))
        shown: list[str] = []  # the header, once shown

        def streamed(rep: WindowReport, start_ns: int) -> None:
            if on_report is not None:
                on_report(rep, start_ns)
            if show is None:
                return
            if not shown:
                shown.append(TABLE_HEADER)
                show(TABLE_HEADER)
            show(window_row(rep.model, replay.window_entry(rep, start_ns)))

        try:
            loaded = [load(m) for m in self.sources]
            models = [lm.model for lm in loaded]
            with open_recording(self.read, self.recording) as recording:
                cfg, timing = timed_config(self.read, recording, tell)
                if self.diagnosis:
                    documents = {lm.model.name: lm.document for lm in loaded}
                    cfg = dataclasses.replace(cfg, diagnosis=True, documents=documents)
                result = replay.replay_recording(
                    recording, models, cfg, progress=progress, on_report=streamed
                )
        except TwotankError as err:
            return unreadable(err, tell)
        except replay.ReplayInterrupted as stop:
            return self._finish(
                stop.result, models=models, timing=timing, cfg=cfg, tell=tell, stop=stop
            )
        except KeyboardInterrupt as stop:
            empty = replay.ReplayResult(Path(self.recording), complete=False, interrupted=True)
            document = replay.summary_json(empty)
            document |= {"models_from": "named" if self.models_named else "default", "timing": None}
            return nothing_judged(interruption(stop), tell, self.json_path, document)
        return self._finish(result, models=models, timing=timing, cfg=cfg, tell=tell)

    def _finish(
        self,
        result: replay.ReplayResult,
        *,
        models: Sequence[LFTModel],
        timing: replay.Timing,
        cfg: replay.ReplayConfig,
        tell: Teller,
        stop: Interrupted | None = None,
    ) -> Outcome:
        """The summary, its JSON and figures, the text and the code of a replay.

        Interrupted (``stop``): of what was judged before it.
        """
        names = [m.name for m in models]
        summary = replay.summary_json(result, names)
        summary["models_from"] = "named" if self.models_named else "default"
        summary["timing"] = timing.to_json()
        if self.json_path:
            write_json(self.json_path, summary)
        if self.report_dir:
            from twotank_validation import report  # noqa: PLC0415 (matplotlib)

            by_name = {m.name: cfg.monitor.banded(m) for m in models}  # as judged (--band)
            report.write_replay_report(result, by_name, summary, Path(self.report_dir))
        # every report's row in the order judged (those streamed first: the same lines)
        start = result.bag_start_ns
        rows = [window_row(r.model, replay.window_entry(r, start)) for r in result.reports]
        text = (TABLE_HEADER, *rows, *model_lines(summary))
        if stop is not None:
            judged = sum(e["judged"] for e in summary["models"].values())
            ends = [w["end"] for e in summary["models"].values() for w in e["windows"]]
            kept = [f for f in (self.json_path, self.report_dir) if f]
            told = (
                f"interrupted by {stop.name}: {judged} window(s) judged, up to "
                f"{max(ends, default=0.0):.1f} s of the recording; printed"
                + (f", and kept in {' and '.join(kept)}" if kept else "")
            )
            return Outcome(
                stop.exit_code,
                Status.INTERRUPTED,
                summary,
                summary,
                tuple(tell.messages),
                text,
                (Message(Level.INFO, told),),
            )
        code, errors = exit_status(
            result.complete, replay.unjudged(result, names, timing, cfg), timing
        )
        counts = (
            f"{result.messages} {'rows' if result.source == 'table' else 'messages'}; "
            f"decoding {result.decode_s:.2f} s, validation {result.validate_s:.2f} s; "
            + ("complete" if result.complete else "INCOMPLETE")
        )
        warnings = [Message(Level.WARNING, p) for p in result.problems]
        status = STATUS_OF_CODE[code]
        if self.fail_on_alarm and (alarms := first_alarms(summary)):
            code = ExitCode.ALARM  # the answer the pipeline asked for, over 3 and 4
            errors += [
                Message(Level.ERROR, f"the alarm of model {m} rose at {t:.1f} s (--fail-on-alarm)")
                for m, t in alarms.items()
            ]
        return Outcome(
            code,
            status,
            summary,
            summary,
            tuple(tell.messages),
            text,
            (*warnings, Message(Level.INFO, counts), *errors),
        )


def first_alarms(summary: Mapping[str, Any]) -> dict[str, float]:
    """Model -> the time its alarm first rose (ERROR; s from the start), models with one."""
    return {
        name: float(entry["first_alarm"])
        for name, entry in summary["models"].items()
        if entry["first_alarm"] is not None
    }


def names_text(models: Sequence[str]) -> str:
    """``"A and B"``, ``"A, B and C"``."""
    return " and ".join([", ".join(models[:-1]), models[-1]] if len(models) > 1 else models)


def default_models_note(models: Sequence[str]) -> str:
    """What a run judging the default models says (once, on stderr)."""
    return (
        f"no --model given: judging the default models {names_text(models)} (the validator "
        "node's models parameter; Model A, the paper's decoupled model, is invalidated by "
        "design on the two-tank rig, so its alarm is expected): name the models to judge "
        "with --model"
    )


TABLE_HEADER = f"{'window (s)':>21}  {'model':<6} {'beta':>7} {'beta_op':>7}  {'verdict':<30} alarm"
"""The header of ``validate``'s table of windows."""


def window_row(name: str, w: Mapping[str, Any]) -> str:
    """The table's row of a window (its JSON entry, :func:`replay.window_entry`)."""
    verdict = (
        ("INVALIDATED" if w["invalidated"] else "valid") if w["beta"] is not None else "not judged"
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
    return f"{w['start']:9.1f}-{w['end']:9.1f}  {name:<6} {beta}  {verdict:<30} {w['alarm']}{extra}"


def model_lines(summary: Mapping[str, Any]) -> list[str]:
    """One line per model: windows judged, the largest beta, the first alarm."""
    lines = []
    for name, entry in summary["models"].items():
        bmax = "-" if entry["beta_max"] is None else f"{entry['beta_max']:.3f}"
        first = "none" if entry["first_alarm"] is None else f"{entry['first_alarm']:.1f} s"
        lines.append(
            f"model {name}: {entry['judged']} of {entry['judged'] + entry['not_judged']} "
            f"window(s) judged, beta_max {bmax}, first alarm {first}" + _outside_text(entry)
        )
    return lines


def _outside_text(entry: Mapping[str, Any]) -> str:
    """``, beta outside the band up to X`` where the model has a band (empty otherwise)."""
    if "beta_outside_max" not in entry:
        return ""
    top = entry["beta_outside_max"]
    return f" (beta outside the band up to {'inf' if top is None else f'{top:.3f}'})"


def windows_text(summary: Mapping[str, Any]) -> list[str]:
    """The table of windows (grouped by model) and one line per model of a replay's summary.

    ``validate`` prints its rows in the order they were judged (:meth:`ValidateJob.run`).
    """
    rows = [window_row(name, w) for name, e in summary["models"].items() for w in e["windows"]]
    return [TABLE_HEADER, *rows, *model_lines(summary)]


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
