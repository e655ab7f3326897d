"""What a use case returns: the exit code, the recording's status, typed messages.

A job (:mod:`~twotank_validation.usecases.jobs`) never prints: it returns an outcome that a
front end shows (the command line prints its text and messages and exits with its code; a
fleet summarises it) and says its notes and warnings as they arise to a callback.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Any

from twotank_validation.errors import ExitCode, UsageError

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
