"""Exceptions of twotank_validation: one root, subclasses that also inherit the builtin.

And the exit codes the command line turns outcomes and errors into (:class:`ExitCode`).
"""

import contextlib
import signal
from collections.abc import Iterator
from enum import IntEnum
from types import FrameType


class TwotankError(Exception):
    """Root of every error raised on purpose by this package."""


class DatumError(TwotankError, ValueError):
    """The input-output record cannot be validated as it is (length, periods, NaN, shapes)."""


class ModelError(TwotankError, ValueError):
    """A model is malformed, inconsistent with the data, or not robustly usable."""


class ModelFileError(ModelError):
    """A YAML model file is missing, unreadable or does not follow the schema."""


class DimensionError(ModelError):
    """Array or model dimensions do not match (the message names expected and found)."""


class UnstableModelError(ModelError):
    """The nominal model is unstable, so its frequency response does not describe the data."""


class SolverError(TwotankError, RuntimeError):
    """A numerical solver failed in a way that is not a property of the data."""


class UsageError(TwotankError, ValueError):
    """A command-line argument or a job's setting is not usable (the message says which)."""


class IdentificationError(TwotankError, ValueError):
    """A record cannot give the asked estimate; the message names the fix.

    Too few periods or experiments, no excitation in the band, an order the data cannot
    support.
    """


class ExitCode(IntEnum):
    """The command line's exit codes (a fleet's is its most severe recording's)."""

    OK = 0
    """The command ran and judged what it was asked to judge."""
    ERROR = 2
    """Bad arguments or a file that cannot be used (the message says what to change)."""
    INCOMPLETE = 3
    """The recording could not be read completely (a topic missing or of the wrong type)."""
    NOT_JUDGED = 4
    """Read completely, but no window of a model could be judged (the message says why)."""
    UNREADABLE = 5
    """A fleet: some recording could not be read at all (or its task failed)."""
    ALARM = 6
    """``validate --fail-on-alarm``: a model's alarm rose (ERROR) on a judged window."""
    INTERRUPTED = 130
    """SIGINT (Ctrl-C), 128 + 2: stopped; what was judged is kept (printed, JSON, figures)."""
    TERMINATED = 143
    """SIGTERM, 128 + 15: stopped as on SIGINT."""
    BROKEN_PIPE = 141
    """The reader of stdout went away (``| head``) while printing: 128 + SIGPIPE, as a shell
    reports a program ended by it."""


class Interrupted(KeyboardInterrupt):
    """A signal asked the command to stop (SIGINT or SIGTERM); what was judged is kept.

    The command line's signal handlers raise it; a plain ``KeyboardInterrupt`` (Python's own
    Ctrl-C) counts as SIGINT (:func:`interruption`).

    Attributes:
        signum: the signal's number.
    """

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    @property
    def name(self) -> str:
        """``"SIGINT"``, ``"SIGTERM"``."""
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> ExitCode:
        """130 for SIGINT, 143 for SIGTERM (128 + the signal's number)."""
        return ExitCode.TERMINATED if self.signum == signal.SIGTERM else ExitCode.INTERRUPTED


def interruption(stop: BaseException) -> Interrupted:
    """The interruption a ``KeyboardInterrupt`` stands for (a plain one: SIGINT)."""
    return stop if isinstance(stop, Interrupted) else Interrupted(signal.SIGINT)


class _Held:
    """The state of :func:`held_interrupts` (the main thread's: signals are handled there)."""

    depth = 0
    pending: Interrupted | None = None


def raise_interrupted(signum: int, _frame: FrameType | None) -> None:
    """The SIGINT and SIGTERM handler of the command line: raise :class:`Interrupted`.

    Inside :func:`held_interrupts` the signal waits for the end of the block.
    """
    if _Held.depth:
        _Held.pending = _Held.pending or Interrupted(signum)
        return
    raise Interrupted(signum)


@contextlib.contextmanager
def held_interrupts() -> Iterator[None]:
    """A signal (:func:`raise_interrupted`) arriving inside is raised at the end of the block.

    For what must not be cut in two: a line printed and counted, a cluster started.
    """
    _Held.depth += 1
    try:
        yield
    finally:
        _Held.depth -= 1
        if not _Held.depth and _Held.pending is not None:
            stop, _Held.pending = _Held.pending, None
            raise stop
