"""What a use case returns: the exit code, the recording's status, typed messages.

A job (:mod:`~twotank_validation.usecases.jobs`) never prints: it returns an outcome that a
front end shows (the command line prints its text and messages and exits with its code; a
fleet summarises it) and says its notes and warnings as they arise to a callback.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from twotank_validation.errors import ExitCode, Interrupted, TwotankError, UsageError

if TYPE_CHECKING:
    from twotank_validation.replay import Timing, Unjudged

__all__ = ["ExitCode", "Level", "Message", "Outcome", "Say", "Status", "UsageError", "exit_status"]


class Status(StrEnum):
    """A recording's status; the value is the text of a fleet's summary table."""

    COMPLETE = "complete"
    """Read completely and every model judged (a diagnosis: diagnosed)."""
    NOT_JUDGED = "not judged"
    """Read completely, but a model had no judged window (a diagnosis: nothing diagnosed)."""
    INCOMPLETE = "incomplete"
    """Not read completely (damage, a topic missing); windows before the damage are judged."""
    UNREADABLE = "unreadable"
    """Nothing could be read (not a recording, empty, unusable settings): the error says why."""
    INTERRUPTED = "interrupted"
    """Stopped by SIGINT or SIGTERM: what was judged before is kept (``"interrupted": true``)."""


STATUS_OF_CODE = {
    ExitCode.OK: Status.COMPLETE,
    ExitCode.INCOMPLETE: Status.INCOMPLETE,
    ExitCode.NOT_JUDGED: Status.NOT_JUDGED,
}
"""A recording's status by the exit code of its replay."""


class Level(StrEnum):
    """How a message is marked on stderr (``INFO``: not marked)."""

    INFO = ""
    NOTE = "note"
    WARNING = "WARNING"
    ERROR = "ERROR"


@dataclass(frozen=True)
class Message:
    """One line for stderr: its level and its text (``str()`` gives the printed line)."""

    level: Level
    text: str

    def __str__(self) -> str:
        return f"{self.level}: {self.text}" if self.level else self.text


Say = Callable[[Message], None]
"""Told each note and warning as it arises (e.g. printed on stderr before a long replay)."""

Progress = Callable[[int, int], None]
"""Told (messages read, messages expected) now and then."""

Show = Callable[[str], None]
"""Told a line of a command's text as it arises (streamed to stdout)."""


@dataclass(frozen=True)
class Outcome:
    """What a job found in one recording.

    Attributes:
        code: the exit code of the command on this recording alone.
        status: the recording's status (a fleet's table).
        document: the JSON the command writes with ``--json`` (None where it writes none).
        summary: the replay's summary (``replay.summary_json``: windows per model), None
            where nothing was read.
        messages: notes and warnings, in the order they arose (each also told to the job's
            ``say`` as it arose).
        text: what the command prints on stdout, in lines.
        closing: said on stderr after the text: counts (``Level.INFO``), then the errors
            that explain the exit code.
    """

    code: ExitCode
    status: Status
    document: dict[str, Any] | None = None
    summary: dict[str, Any] | None = None
    messages: tuple[Message, ...] = ()
    text: tuple[str, ...] = ()
    closing: tuple[Message, ...] = ()

    def said(self) -> tuple[str, ...]:
        """Every marked line (notes, warnings, errors) as printed, in order."""
        return tuple(str(m) for m in (*self.messages, *self.closing) if m.level)


class Teller:
    """Collects a job's messages and tells each to ``say`` as it arises."""

    def __init__(self, say: Say | None) -> None:
        self.messages: list[Message] = []
        self._say = say

    def __call__(self, level: Level, text: str) -> None:
        """Keep the message and tell it."""
        msg = Message(level, text)
        self.messages.append(msg)
        if self._say is not None:
            self._say(msg)


def exit_status(
    complete: bool, unjudged: Sequence[Unjudged], timing: Timing
) -> tuple[ExitCode, list[Message]]:
    """The exit code of a replay, with the reasons of models without a judged window.

    3 if the recording was not read completely (the cause of anything missing), else 4 if a
    model had no judged window, else 0.

    Args:
        complete: the whole recording was read.
        unjudged: the models without a judged window (``replay.unjudged``).
        timing: the timing used.
    """
    lines = [Message(Level.ERROR, u.text()) for u in unjudged]
    if unjudged:  # the timing the windows were cut with, which the errors' fixes refer to
        lines.append(
            Message(
                Level.NOTE,
                f"the windows were formed with sample period {timing.ts_s:.9g} s "
                f"({timing.ts_from}) and excitation period {timing.period_samples} samples "
                f"({timing.period_from})",
            )
        )
    if not complete:
        return ExitCode.INCOMPLETE, lines
    return (ExitCode.NOT_JUDGED if unjudged else ExitCode.OK), lines


def unreadable(err: TwotankError, tell: Teller) -> Outcome:
    """The outcome of a job whose model, recording or setting could not be used: ``err``."""
    return Outcome(
        ExitCode.ERROR,
        Status.UNREADABLE,
        messages=tuple(tell.messages),
        closing=(Message(Level.ERROR, str(err)),),
    )


def write_json(path: str | Path, document: Mapping[str, Any]) -> None:
    """Write a JSON document whole or not at all (a temporary file beside it, then renamed).

    An interrupt while writing leaves the file as it was, never half written.
    """
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(json.dumps(document, indent=2))
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def nothing_judged(
    stop: Interrupted,
    tell: Teller,
    json_path: str | None = None,
    document: dict[str, Any] | None = None,
) -> Outcome:
    """The outcome of a job interrupted before any window was judged.

    ``document`` (its ``"interrupted": true``, no window) is written to ``json_path`` when
    both are given: asked for a JSON, a run always leaves one.
    """
    if json_path and document is not None:
        write_json(json_path, document)
    told = f"interrupted by {stop.name} before any window was judged" + (
        f"; {json_path} says so" if json_path and document is not None else ""
    )
    return Outcome(
        stop.exit_code,
        Status.INTERRUPTED,
        document,
        messages=tuple(tell.messages),
        closing=(Message(Level.INFO, told),),
    )


def interrupted_document(model: str) -> dict[str, Any]:
    """The JSON of a diagnosis or calibration interrupted before any window was judged."""
    return {"model": model, "interrupted": True, "replay": None, "timing": None}


def interrupted_outcome(
    stop: Interrupted,
    model: str,
    summary: dict[str, Any],
    *,
    timing: Timing,
    json_path: str | None,
    tell: Teller,
    task: str = "diagnosed",
) -> Outcome:
    """A diagnosis or calibration interrupted: the windows judged kept, nothing concluded.

    The JSON (when asked for) is ``{"model", "interrupted": true, "replay": <the replay's
    summary up to the interrupt>, "timing"}``.
    """
    document = {
        "model": model,
        "interrupted": True,
        "replay": summary,
        "timing": timing.to_json(),
    }
    if json_path:
        write_json(json_path, document)
    judged = summary["models"].get(model, {}).get("judged", 0)
    told = (
        f"interrupted by {stop.name}: {judged} window(s) of model {model} judged, none "
        f"{task}" + (f"; the windows kept in {json_path}" if json_path else "")
    )
    return Outcome(
        stop.exit_code,
        Status.INTERRUPTED,
        document,
        summary,
        tuple(tell.messages),
        closing=(Message(Level.INFO, told),),
    )
