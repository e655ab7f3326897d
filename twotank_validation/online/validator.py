"""The online validator: the one path from stamped source values to window reports.

:class:`OnlineValidator` is what the live ROS node and bag replay both feed: it runs the
:class:`~twotank_validation.online.aligner.SampleAligner`, the
:class:`~twotank_validation.online.window.WindowMonitor` (gates, validation, alarm) and keeps
the input-fault state (:class:`~twotank_validation.online.input_faults.InputFaults`). It is
ROS-free: callers feed it stamped values (integer nanoseconds) and get
:class:`~twotank_validation.online.window.WindowReport` objects back.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from twotank_validation.core.closed_loop import Controller
from twotank_validation.core.model import LFTModel
from twotank_validation.defaults import JITTER_FRACTION
from twotank_validation.errors import DatumError
from twotank_validation.online.alarm import Alarm, AlarmConfig
from twotank_validation.online.aligner import (
    COMMAND,
    AlignerCounters,
    Sample,
    SampleAligner,
    SampleBlock,
)
from twotank_validation.online.assembler import CommandAssembler
from twotank_validation.online.channels import Channels, match_channels
from twotank_validation.online.input_faults import STOPPED_STREAMS, InputFaults
from twotank_validation.online.interface_map import (
    INPUT,
    InterfaceMap,
    TopicSources,
    message_sources,
)
from twotank_validation.online.livediag import LiveDiagnoser
from twotank_validation.online.streams import two_tank_map
from twotank_validation.online.window import MonitorConfig, WindowMonitor, WindowReport


def parse_oversampling(entries: Sequence[str]) -> dict[str, int]:
    """``["flow_cmd=2", "height=2"]`` -> ``{"flow_cmd": 2, "height": 2}`` (empty entries skipped).

    The names are topics of the interface map (the validator checks them).

    Raises:
        DatumError: an entry that is not ``TOPIC=N`` with a whole N >= 1.
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
        if not name or n < 1:
            raise DatumError(
                f"oversampling entry {entry!r}: give TOPIC=N, a topic of the interface map and "
                "the whole number N >= 1 of its messages per sample"
            )
        out[name] = n
    return out


@dataclasses.dataclass(frozen=True)
class _Route:
    """Where the values of one topic's message go (its sources in map order).

    Attributes:
        n_values: sources read from the topic (values per message).
        command: the value index of each input, in input order, when the topic carries every
            input (one message is a whole command); None otherwise.
        command_in_order: the topic carries the inputs alone, in input order (its values are
            the command).
        inputs: ``(value index, input)`` of the inputs of a topic that carries some of them
            (assembled into commands with the other topics').
        outputs: ``(value index, output)`` of the outputs the topic carries.
    """

    n_values: int
    command: tuple[int, ...] | None
    command_in_order: bool
    inputs: tuple[tuple[int, int], ...]
    outputs: tuple[tuple[int, int], ...]


def _route(sources: TopicSources, n_inputs: int) -> _Route:
    ins = [(k, b.position) for k, b in enumerate(sources.bindings) if b.role == INPUT]
    outs = tuple((k, b.position) for k, b in enumerate(sources.bindings) if b.role != INPUT)
    whole = len(ins) == n_inputs
    order = tuple(k for k, _ in sorted(ins, key=lambda kp: kp[1])) if whole else None
    return _Route(
        n_values=len(sources.bindings),
        command=order,
        command_in_order=order == tuple(range(n_inputs)) and len(sources.bindings) == n_inputs,
        inputs=() if whole else tuple(ins),
        outputs=outs,
    )


class OnlineValidator:
    """Aligner + window monitor + input faults: stamped source values in, window reports out.

    The live node and every replay (bags and tables) feed it the model-unit values of the
    interface map's sources, a message at a time (:meth:`feed`: a topic and the values of its
    sources, in map order) or many events at once (:meth:`feed_many`). Its channels are the
    map's inputs and outputs; each model takes the channels it names, matched by name
    (:func:`~twotank_validation.online.channels.match_channels`), in its own order.

    Args:
        config: monitor settings.
        models: models to validate.
        interface: the interface map: the channels' names, and which topic carries which
            source; None: the two-tank preset (:func:`~twotank_validation.online.streams.
            two_tank_map`). A table's map (its sources are columns) has one pseudo-topic,
            ``""``: a row.
        jitter_fraction: accepted stamp distance from the sample grid (fraction of ts).
        oversampling: messages per sample of each topic published faster than the sample
            grid (topic -> whole number; 1 for topics not named). A grid at a slower
            sensor's rate (``config.ts_s`` a multiple of the commands' period) decimates the
            faster topics (:class:`~twotank_validation.online.aligner.SampleAligner`). The
            topics that carry inputs share one value.
        diagnoser: the live diagnosis (:class:`~twotank_validation.online.livediag.LiveDiagnoser`):
            it sees every judged window's report and samples, and each report carries the
            answer in force (``WindowReport.diagnosis``); None: no diagnosis.
        controller: the loop's controller, known (closed-loop data; needs the transient
            term): the windows are judged on the closed-loop formulation (docs/theory.md
            §21); None: the direct one.

    Attributes:
        interface: the interface map.
        channels: the channels and each model's place among them.
        sample_listeners: called with each aligned :class:`Sample` or :class:`SampleBlock`
            before the monitor gets it (e.g. to record the samples).

    Raises:
        ChannelError: a model's channels do not match the map's by name.
        DatumError: oversampling names a topic the map does not read, or gives the input
            topics different values.
    """

    def __init__(
        self,
        config: MonitorConfig,
        models: Sequence[LFTModel],
        *,
        interface: InterfaceMap | None = None,
        jitter_fraction: float = JITTER_FRACTION,
        oversampling: Mapping[str, int] | None = None,
        diagnoser: LiveDiagnoser | None = None,
        controller: Controller | None = None,
    ) -> None:
        self.config = config
        self.interface = imap = interface if interface is not None else two_tank_map()
        self.channels: Channels = match_channels(
            imap.input_names, imap.output_names, models, source=imap.label
        )
        self.diagnoser = diagnoser
        self._topics = message_sources(imap)
        over = dict(oversampling or {})
        if unknown := sorted(set(over) - set(self._topics)):
            raise DatumError(
                f"oversampling names {unknown}, which {imap.label} does not read; its topics: "
                f"{sorted(self._topics)}"
            )
        n_in = len(imap.inputs)
        in_rates = {over.get(s.topic, 1) for s in imap.inputs}
        if len(in_rates) > 1:
            raise DatumError(
                f"oversampling gives the input topics {sorted({s.topic for s in imap.inputs})} "
                f"different rates {sorted(in_rates)}; commands are sampled at one rate: give "
                "each input topic the same N"
            )
        cmd_over = in_rates.pop()
        self._monitor = WindowMonitor(
            config,
            models,
            self.channels,
            measured_inputs=imap.measured_inputs,
            controller=controller,
        )
        if diagnoser is not None:
            measured = {m.name: self._monitor.measured_of(m.name) for m in models}
            diagnoser.bind(config.ts_s, config.period_samples, measured)
        self._aligner = SampleAligner(
            config.ts_s,
            n_in,
            imap.output_names,
            jitter_fraction=jitter_fraction,
            oversampling=[cmd_over, *(over.get(s.topic, 1) for s in imap.outputs)],
        )
        self.command_period_s = config.ts_s / cmd_over
        """Period of the command messages (s): the sample period over their oversampling."""
        self._routes = {t: _route(src, n_in) for t, src in self._topics.items()}
        self._assembler = CommandAssembler(n_in, self.command_period_s)
        self.samples_seen = 0
        self.sample_listeners: list[Callable[[Sample | SampleBlock], None]] = []
        self._faults = InputFaults(
            self._aligner.counters,
            window_samples=config.window_samples,
            n_streams=len(self._topics),
        )

    @property
    def topics(self) -> tuple[str, ...]:
        """The topics :meth:`feed` takes (a table's map: ``("",)``, its rows)."""
        return tuple(self._topics)

    def feed(self, topic: str, stamp_ns: int, value: Any) -> list[WindowReport]:
        """One message in, the reports of any window it completes out; input faults noted.

        Args:
            topic: a topic of the interface map (a table's: ``""``, a row).
            stamp_ns: the message's stamp (ns).
            value: the model-unit values of the sources the map reads from the topic, in map
                order (a sequence; a plain number where the topic carries one source). A topic
                that carries every input gives a whole command; inputs on separate topics are
                assembled into commands
                (:class:`~twotank_validation.online.assembler.CommandAssembler`).

        Raises:
            DatumError: an unknown topic, or not one value per source.
        """
        route = self._routes.get(topic)
        if route is None:
            raise DatumError(
                f"unknown topic {topic!r}; {self.interface.label} reads {sorted(self._routes)}"
            )
        values = _values(topic, value, route.n_values)
        seen = self.samples_seen
        aligner = self._aligner
        samples: list[Sample] = []
        if route.command is not None:
            command = values if route.command_in_order else tuple(values[k] for k in route.command)
            samples += aligner.push_command(stamp_ns, command)
        for k, position in route.inputs:
            for s, u in self._assembler.push(position, stamp_ns, values[k]):
                samples += aligner.push_command(s, tuple(u.tolist()))
        for k, channel in route.outputs:
            try:
                number = float(values[k])
            except (TypeError, ValueError) as err:
                name = self.channels.output_names[channel]
                raise DatumError(f"{name} value {values[k]!r} is not a number") from err
            samples += aligner.push_measurement(channel, stamp_ns, number)
        reports = self._deliver(samples, None) if samples else []
        self._faults.after_event(seen, self.samples_seen, reports)
        return reports

    def flush(self) -> list[WindowReport]:
        """The commands still waiting for an input on another topic (end of a recording)."""
        seen = self.samples_seen
        samples: list[Sample] = []
        for s, u in self._assembler.flush():
            samples += self._aligner.push_command(s, tuple(u.tolist()))
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
            kinds: (n,) int: :data:`~twotank_validation.online.aligner.COMMAND` for a whole
                command, else the output channel (index into :attr:`channels`' outputs).
            stamps_ns: (n,) int64 stamps.
            values: (n, w) float with ``w = max(n_inputs, 1)``: a command's values in input
                order; a measurement (model units) in column 0.
            on_report: called with each report as soon as its window is evaluated (while
                :meth:`last_window` still returns that window).
        """
        kinds = np.asarray(kinds)
        n_out = self.channels.n_outputs
        if len(kinds) and (kinds.min() < COMMAND or kinds.max() >= n_out):
            raise DatumError(
                f"unknown event kind in {np.unique(kinds)}; expected {COMMAND} (a command) or "
                f"an output channel 0 .. {n_out - 1}"
            )
        values = np.asarray(values, dtype=float)
        width = max(self.channels.n_inputs, 1)
        if values.shape != (len(kinds), width) or len(stamps_ns) != len(kinds):
            raise DatumError(
                f"feed_many needs (n,) kinds and stamps and (n, {width}) values, found "
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
                    diagnoser.observe(rep, *monitor.last_window(rep.model))
                elif diagnoser.wants(rep.model):
                    diagnoser.note_means(rep, *monitor.last_window(rep.model))
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

    def last_window(self, model: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(stamps_ns, u, y)`` of the most recent window: (n,), (n, nu), (n, ny) copies.

        Args:
            model: a model's name: its channels in its own order; None: every channel in the
                interface map's order.
        """
        return self._monitor.last_window(model)

    def measured_of(self, model: str) -> np.ndarray | None:
        """(nu,) bool, the model's measured inputs (as :meth:`last_window` orders them).

        The interface map's ``kind: measured``; None: every input commanded.
        """
        return self._monitor.measured_of(model)

    def alarm_levels(self) -> dict[str, Alarm]:
        """Current alarm level of each model."""
        return {name: state.level for name, state in self._monitor.alarms.items()}

    def reset_alarms(self) -> None:
        """Clear latched alarms of every model."""
        self._monitor.reset_alarms()

    def set_alarm(self, alarm: AlarmConfig) -> None:
        """Debounce the windows judged from now on with ``alarm``; the alarm states are kept.

        Called between two windows (a node's run-time parameter change).
        """
        self._monitor.set_alarm(alarm)
        self.config = dataclasses.replace(self.config, alarm=alarm)

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


def _values(topic: str, value: Any, n: int) -> tuple[Any, ...]:
    """A message's source values as a tuple of ``n`` (a plain number where ``n`` is 1)."""
    if type(value) is tuple and len(value) == n:
        return value
    if isinstance(value, str | bytes) or not hasattr(value, "__len__"):
        if n == 1:
            return (value,)
    else:
        values = tuple(value.tolist() if isinstance(value, np.ndarray) else value)
        if len(values) == n:
            return values
    raise DatumError(
        f"topic {topic!r} needs {n} values per message (one model-unit value per source the "
        f"map reads from it, in map order), found {value!r}"
    )
