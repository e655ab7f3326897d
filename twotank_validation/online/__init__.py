"""Online validation: streams, sample alignment, whole-period windows, the alarm and the facade.

Layers, each importing only those before it (and :mod:`twotank_validation.core`):
:mod:`~twotank_validation.online.alarm` (the debounced alarm),
:mod:`~twotank_validation.online.aligner` (stamped values onto the sample grid),
:mod:`~twotank_validation.online.streams` (stream names, message types, units, extractors),
:mod:`~twotank_validation.online.states` (a window's typed states: :class:`RaisedBy`,
:class:`WindowState`, :class:`WindowQuality`),
:mod:`~twotank_validation.online.livediag` (the fault named live: windows buffered, the
diagnosis scheduled once an alarm rises),
:mod:`~twotank_validation.online.window` (gates, validation, reports),
:mod:`~twotank_validation.online.input_faults` (input faults, the STALE text) and
:mod:`~twotank_validation.online.validator` (:class:`OnlineValidator`, which the live node
and bag replay both feed); :mod:`~twotank_validation.online.validator_settings` is the
validator's settings tree, from which the node's parameters and the CLI's window options are
generated.
"""

from twotank_validation.online.alarm import (
    Alarm,
    AlarmConfig,
    AlarmState,
    reset_alarm,
    update_alarm,
)
from twotank_validation.online.aligner import (
    COMMAND,
    AlignerCounters,
    Sample,
    SampleAligner,
    SampleBlock,
)
from twotank_validation.online.input_faults import InputFaults, input_fault_text
from twotank_validation.online.states import (
    RaisedBy,
    SampleFlag,
    WindowQuality,
    WindowState,
)
from twotank_validation.online.streams import STREAM_KINDS, STREAMS, RigUnits
from twotank_validation.online.validator import OnlineValidator
from twotank_validation.online.window import (
    MonitorConfig,
    WindowMonitor,
    WindowReport,
    monitor_record,
)

__all__ = [
    "COMMAND",
    "STREAMS",
    "STREAM_KINDS",
    "Alarm",
    "AlarmConfig",
    "AlarmState",
    "AlignerCounters",
    "InputFaults",
    "MonitorConfig",
    "OnlineValidator",
    "RaisedBy",
    "RigUnits",
    "Sample",
    "SampleAligner",
    "SampleBlock",
    "SampleFlag",
    "WindowMonitor",
    "WindowQuality",
    "WindowReport",
    "WindowState",
    "input_fault_text",
    "monitor_record",
    "reset_alarm",
    "update_alarm",
]
