"""Validate recorded bags and tables through the live validator's code path.

Messages stream from :mod:`twotank_validation.bags.reader`, go through the same extractors as
the ROS node (:mod:`twotank_validation.online.streams`, ROS-free) and the same
:class:`~twotank_validation.online.validator.OnlineValidator` (alignment, windows, gates, alarm,
input faults). A CSV or Parquet table (:mod:`twotank_validation.tables`, read through an
interface map of columns) goes the same way, row by row: :func:`replay_table`;
:func:`replay_recording` takes either.
Memory stays bounded: only the window buffer and per-window summaries are kept, plus the samples
of a few windows of interest (largest beta, first alarm) for the figures.

Speed: messages go a few thousand at a time. The reader reads an indexed MCAP bag chunk by
chunk as arrays and decodes the three fixed-layout input types in bulk
(:meth:`~twotank_validation.bags.reader.BagReader.field_batches`, the generic deserialiser for
anything else), the extractors' unit conversions run on arrays
(:func:`~twotank_validation.online.streams.stream_values`, the same float operations), and
:meth:`~twotank_validation.online.validator.OnlineValidator.feed_many` aligns regular stretches at
once (the same samples and reports as feeding the messages one by one, which is what it does
with anything irregular). A one-hour 10 Hz bag replays for two models in about 0.3 s, most of
it the validation of the windows (``bench/bench_replay.py``).

The package: :mod:`.config` (ReplayConfig, ReplayResult), :mod:`.recording` (a recording
opened once), :mod:`.feed` (a bag or a table through the validator), :mod:`.timing` (the
periods of a recording), :mod:`.timebase` (the clock its windows are timed by),
:mod:`.summary` (the JSON summary, the reasons no window was judged), :mod:`.windows`
(windows for diagnose and calibrate).
"""

from twotank_validation.replay.config import (
    ReplayConfig,
    ReplayConfigError,
    ReplayInterrupted,
    ReplayResult,
    TimeBase,
    WindowSnapshot,
    model_documents,
)
from twotank_validation.replay.feed import OnReport, replay_bag, replay_recording, replay_table
from twotank_validation.replay.recording import Recording, is_table_input, open_recording
from twotank_validation.replay.summary import (
    NoWindow,
    Unjudged,
    reason_category,
    summary_json,
    unjudged,
    warning_kind,
    window_entry,
)
from twotank_validation.replay.timebase import TimeBaseError, stamp_base
from twotank_validation.replay.timing import (
    GivenBy,
    Timing,
    TimingConflict,
    TimingSetting,
    resolve_timing,
)
from twotank_validation.replay.windows import (
    range_time_s,
    windows_from_bag,
    windows_from_recording,
    windows_with_findings,
)

__all__ = [
    "GivenBy",
    "NoWindow",
    "OnReport",
    "Recording",
    "ReplayConfig",
    "ReplayConfigError",
    "ReplayInterrupted",
    "ReplayResult",
    "TimeBase",
    "TimeBaseError",
    "Timing",
    "TimingConflict",
    "TimingSetting",
    "Unjudged",
    "WindowSnapshot",
    "is_table_input",
    "model_documents",
    "open_recording",
    "range_time_s",
    "reason_category",
    "replay_bag",
    "replay_recording",
    "replay_table",
    "resolve_timing",
    "stamp_base",
    "summary_json",
    "unjudged",
    "warning_kind",
    "window_entry",
    "windows_from_bag",
    "windows_from_recording",
    "windows_with_findings",
]
