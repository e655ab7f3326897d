"""The online validator: the one path from stamped stream values to window reports.

:class:`OnlineValidator` is what the live ROS node and bag replay both feed: it runs the
:class:`~twotank_validation.online.aligner.SampleAligner`, the
:class:`~twotank_validation.online.window.WindowMonitor` (gates, validation, alarm) and keeps
the input-fault state (:class:`~twotank_validation.online.faults.InputFaults`). It is
ROS-free: callers feed it stamped values (integer nanoseconds) and get
:class:`~twotank_validation.online.window.WindowReport` objects back.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from twotank_validation.core.model import LFTModel
from twotank_validation.defaults import JITTER_FRACTION
from twotank_validation.errors import DatumError
from twotank_validation.online.alarm import Alarm
from twotank_validation.online.aligner import (
    COMMAND,
    AlignerCounters,
    Sample,
    SampleAligner,
    SampleBlock,
)
from twotank_validation.online.faults import STOPPED_STREAMS, InputFaults
from twotank_validation.online.livediag import LiveDiagnoser
from twotank_validation.online.streams import (
    FLOW_CMD,
    MEASUREMENTS,
    STREAM_KINDS,
    STREAMS,
)
from twotank_validation.online.window import MonitorConfig, WindowMonitor, WindowReport


def parse_oversampling(entries: Sequence[str]) -> dict[str, int]:
    """``["flow_cmd=2", "height=2"]`` -> ``{"flow_cmd": 2, "height": 2}`` (empty entries skipped).

    Raises:
        DatumError: an entry that is not ``STREAM=N`` with a known stream and a whole N >= 1.
    """
    out: dict[str, int] = {}
    for entry in entries:
        if not entry.strip():
            continue
        name, sep, count = entry.partition("=")
        name = name.strip()
        try:
            n = int(count) if sep else 0
        except ValueError:
            n = 0
        if name not in STREAMS or n < 1:
            raise DatumError(
                f"oversampling entry {entry!r}: give STREAM=N, a stream of {list(STREAMS)} and "
                "the whole number N >= 1 of its messages per sample"
            )
        out[name] = n
    return out


class OnlineValidator:
    """Aligner + window monitor + input faults: stamped stream values in, window reports out.

    The live node and bag replay both feed it ``(stream, stamp_ns, value)`` events, where
    ``stream`` is one of :data:`~twotank_validation.online.streams.STREAMS` and ``value`` is
    ``(hot, cold)`` for ``flow_cmd`` and a model-unit float for the measurements.

    Args:
        config: monitor settings.
        models: models to validate.
        jitter_fraction: accepted stamp distance from the sample grid (fraction of ts).
        oversampling: messages per sample of each stream published faster than the sample
            grid (stream name -> whole number; 1 for streams not named). A grid at a slower
            sensor's rate (``config.ts_s`` a multiple of the commands' period) decimates the
            faster streams (:class:`~twotank_validation.online.aligner.SampleAligner`).
        diagnoser: the live diagnosis (:class:`~twotank_validation.online.livediag.LiveDiagnoser`):
            it sees every judged window's report and samples, and each report carries the
            answer in force (``WindowReport.diagnosis``); None: no diagnosis.

    Attributes:
        sample_listeners: called with each aligned :class:`Sample` or :class:`SampleBlock`
            before the monitor gets it (e.g. to record the samples).
    """

    def __init__(
        self,
        config: MonitorConfig,
        models: Sequence[LFTModel],
        *,
        jitter_fraction: float = JITTER_FRACTION,
        oversampling: Mapping[str, int] | None = None,
        diagnoser: LiveDiagnoser | None = None,
    ) -> None:
        self.config = config
        self.diagnoser = diagnoser
        if diagnoser is not None:
            diagnoser.bind(config.ts_s, config.period_samples)
        over = dict(oversampling or {})
        if unknown := sorted(set(over) - set(STREAMS)):
            raise DatumError(f"oversampling names unknown stream(s) {unknown}; streams: {STREAMS}")
        self._monitor = WindowMonitor(config, models, MEASUREMENTS)
        self._aligner = SampleAligner(
            config.ts_s,
            2,
            MEASUREMENTS,
            jitter_fraction=jitter_fraction,
            oversampling=[over.get(name, 1) for name in STREAMS],
        )
        self.command_period_s = config.ts_s / over.get(FLOW_CMD, 1)
        """Period of the command messages (s): the sample period over their oversampling."""
        self.samples_seen = 0
        self.sample_listeners: list[Callable[[Sample | SampleBlock], None]] = []
        self._faults = InputFaults(
            self._aligner.counters, window_samples=config.window_samples, n_streams=len(STREAMS)
        )

    def feed(self, stream: str, stamp_ns: int, value: Any) -> list[WindowReport]:
        """One event in, the reports of any window it completes out; input faults noted."""
        seen = self.samples_seen
        if stream == FLOW_CMD:
            samples = self._aligner.push_command(stamp_ns, value)
        elif stream in MEASUREMENTS:
            try:
                number = float(value)
            except (TypeError, ValueError) as err:
                raise DatumError(f"{stream} value {value!r} is not a number") from err
            samples = self._aligner.push_measurement(STREAM_KINDS[stream], stamp_ns, number)
        else:
            raise DatumError(f"unknown stream {stream!r}; expected one of {STREAMS}")
        reports = self._deliver(samples, None) if samples else []
        self._faults.after_event(seen, self.samples_seen, reports)
        return reports

    def feed_many(
        self,
        kinds: np.ndarray,
        stamps_ns: np.ndarray,
        values: np.ndarray,
        on_report: Callable[[WindowReport], None] | None = None,
    ) -> list[WindowReport]:
        """A batch of events in arrival order; the same reports as :meth:`feed` one by one.

        The batch's input faults are noted at its end (for :meth:`input_problems`); a run of
        stale stamps, and the clearing of :attr:`input_fault` by a later judged window, are
        followed event by event only (:meth:`feed`).

        Args:
            kinds: (n,) int, :data:`~twotank_validation.online.streams.STREAM_KINDS` of each
                event's stream.
            stamps_ns: (n,) int64 stamps.
            values: (n, 2) float: ``(hot, cold)`` of a command; a measurement (model units)
                in column 0.
            on_report: called with each report as soon as its window is evaluated (while
                :meth:`last_window` still returns that window).
        """
        kinds = np.asarray(kinds)
        if len(kinds) and (kinds.min() < COMMAND or kinds.max() > 1):
            raise DatumError(f"unknown event kind in {np.unique(kinds)}; expected -1, 0 or 1")
        values = np.asarray(values, dtype=float)
        if values.shape != (len(kinds), 2) or len(stamps_ns) != len(kinds):
            raise DatumError(
                f"feed_many needs (n,) kinds and stamps and (n, 2) values, found "
                f"{kinds.shape}, {np.shape(stamps_ns)}, {values.shape}"
            )
        seen = self.samples_seen
        pieces = self._aligner.push_events(kinds, np.asarray(stamps_ns, dtype=np.int64), values)
        out = self._deliver(pieces, on_report)
        self._faults.note(seen)
        return out

    def _deliver(
        self,
        pieces: Sequence[Sample | SampleBlock],
        on_report: Callable[[WindowReport], None] | None,
    ) -> list[WindowReport]:
        out: list[WindowReport] = []
        monitor = self._monitor
        listeners = self.sample_listeners
        diagnoser = self.diagnoser

        def take(rep: WindowReport) -> None:
            # while the monitor's last window is this report's (the diagnoser copies nothing
            # it does not keep: last_window returns copies)
            if diagnoser is not None:
                if rep.judged and diagnoser.wants(rep.model):
                    diagnoser.observe(rep, *monitor.last_window())
                elif diagnoser.wants(rep.model):
                    diagnoser.note_means(rep, *monitor.last_window())
                answer = diagnoser.attach(rep)
                if answer is not None:
                    rep = dataclasses.replace(rep, diagnosis=answer)
            out.append(rep)
            if on_report is not None:
                on_report(rep)

        for piece in pieces:
            for listener in listeners:
                listener(piece)
            if isinstance(piece, SampleBlock):
                self.samples_seen += len(piece)
                monitor.push_block(piece, take)
                continue
            self.samples_seen += 1
            for rep in monitor.push(piece):
                take(rep)
        return out

    def restart(self) -> None:
        """Forget alignment and buffered samples (clock jumped back); alarms are kept.

        An input fault (a clock jump), unless nothing was received yet (e.g. a simulated
        clock's first jump).
        """
        seen = self.samples_seen
        started = self._aligner.t0_ns is not None
        self._aligner.counters.clock_resets += 1
        self._aligner.reset()
        self._monitor.reset_buffer()
        if not started:
            self._faults.rebase()
        self._faults.note(seen)

    def note_stopped_streams(self) -> None:
        """A stream went silent (the caller's watchdog saw it): an input fault."""
        self._faults.note(self.samples_seen, STOPPED_STREAMS)

    @property
    def input_fault(self) -> str | None:
        """The current input fault in words (the status is STALE), None while there is none.

        Set from the moment input arrives that makes the coming windows unfit to judge
        (non-finite or implausible values, off-grid stamps, gaps, clock jumps, a stream
        stopping, a run of stale stamps) until a window after it is judged.
        """
        return self._faults.text

    def input_problems(self) -> list[str]:
        """The input faults of the whole run so far in words (empty if there were none)."""
        return self._faults.summary()

    def counters(self) -> AlignerCounters:
        """What the aligner refused or repaired so far (a copy)."""
        return dataclasses.replace(self._aligner.counters)

    @property
    def next_index(self) -> int:
        """Grid index of the next sample to complete."""
        return self._aligner.next_index

    def last_window(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(stamps_ns, u, y)`` of the most recent window: (n,), (n, nu), (n, ny) copies."""
        return self._monitor.last_window()

    def alarm_levels(self) -> dict[str, Alarm]:
        """Current alarm level of each model."""
        return {name: state.level for name, state in self._monitor.alarms.items()}

    def reset_alarms(self) -> None:
        """Clear latched alarms of every model."""
        self._monitor.reset_alarms()

    def reset_operating_points(self) -> None:
        """Forget every model's reference operating point (given again, or commission anew)."""
        self._monitor.reset_operating_points()

    def operating_points(self) -> dict[str, Any]:
        """Per model: the reference's state and its input and output means (None if none)."""
        return {
            name: {
                "state": str(t.state),
                "u": None if t.reference is None else t.reference.u.tolist(),
                "y": None if t.reference is None else t.reference.y.tolist(),
            }
            for name, t in self._monitor.operating_points.items()
        }
