"""Use cases: validate, diagnose or calibrate a recording, as typed jobs with typed outcomes.

The layer between the domain (replay, diagnose, calibrate, report) and the front ends
(``fleet``, ``ros``, ``cli``). A job is a frozen, picklable dataclass: the recording, the
model sources, how to read the recording (:class:`ReadSettings`: the interface map, the
window settings of the settings tree, the timing options) and the outputs wanted. Its
``run()`` returns an :class:`Outcome`: the exit code (:class:`ExitCode`), the recording's
status, the JSON document, the notes, warnings and errors as typed :class:`Message` items and
the text to print. The command line turns its arguments into a job and prints the outcome; a
fleet ships the job to its workers (``job.at(path).run()``).
"""

from twotank_validation.errors import ExitCode
from twotank_validation.usecases.calibrate import CalibrateJob
from twotank_validation.usecases.diagnose import DiagnoseJob, stretches_text
from twotank_validation.usecases.identify import IdentifyJob
from twotank_validation.usecases.outcome import (
    STATUS_OF_CODE,
    Level,
    Message,
    Outcome,
    Say,
    Status,
    UsageError,
    exit_status,
)
from twotank_validation.usecases.reading import (
    LoadedModel,
    ReadSettings,
    load,
    model_names,
    open_recording,
    timed_config,
)
from twotank_validation.usecases.validate import ValidateJob, diagnosis_text, windows_text

__all__ = [
    "STATUS_OF_CODE",
    "CalibrateJob",
    "DiagnoseJob",
    "ExitCode",
    "IdentifyJob",
    "Level",
    "LoadedModel",
    "Message",
    "Outcome",
    "ReadSettings",
    "Say",
    "Status",
    "UsageError",
    "ValidateJob",
    "diagnosis_text",
    "exit_status",
    "load",
    "model_names",
    "open_recording",
    "stretches_text",
    "timed_config",
    "windows_text",
]
