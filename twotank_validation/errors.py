"""Exceptions of twotank_validation: one root, subclasses that also inherit the builtin.

And the exit codes the command line turns outcomes and errors into (:class:`ExitCode`).
"""

from enum import IntEnum


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
    BROKEN_PIPE = 141
    """The reader of stdout went away (``| head``) while printing: 128 + SIGPIPE, as a shell
    reports a program ended by it."""
