"""The validator node: the interface map's topics in; reports, margin and alarm out.

Thin adapter over :class:`twotank_validation.online.validator.OnlineValidator`: subscription
callbacks only read each source's value from the message (the interface map's field paths and
unit conversions, :mod:`twotank_validation.online.interface`) and queue the topic's values; a
worker thread feeds the validator (aligner, window monitor, validation, input faults) and
publishes. The channels are matched to the models' by name, in any number (the shape comes
from the models and the map). Topics (node-relative, remappable):

* in: the map's topics, each of the type the map names (imported by name). Without a map
  (parameters ``interface_map``, ``inputs``/``outputs``), the two-tank preset
  (:func:`~twotank_validation.online.streams.two_tank_map`): ``flow_cmd``
  (twotank_validation_msgs/FlowCommand), ``height`` (sensor_msgs/FluidPressure),
  ``temperature`` (sensor_msgs/Temperature), converted by the unit parameters. Inputs on
  separate topics are assembled into commands. A topic whose first message does not fit the
  map is refused with the reason in ``/diagnostics`` (STALE) and the log;
* out, per model M: ``validation/M/report`` (ValidationReport), ``validation/M/margin``
  (std_msgs/Float64, ``1 - beta``), ``validation/M/invalidated`` (std_msgs/Bool,
  transient-local, the debounced alarm == ERROR); ``/diagnostics`` (one status per model);
* out, per model M: ``validation/M/diagnosis`` (twotank_validation_msgs/Diagnosis): once the
  alarm is ERROR, the most likely effect behind it (the live diagnosis,
  :mod:`~twotank_validation.online.livediag`), computed in a background executor and
  published as soon as it is ready, then at each new non-overlapping window after the onset;
* service ``reset_alarm`` (std_srvs/Trigger) clears latched alarms.
* service ``reset_operating_point`` (std_srvs/Trigger) forgets the reference operating point
  (the given one again, or commissioned from the next steady windows).

``/diagnostics`` is STALE (saying why) while a topic is stopped or has a publisher of the wrong
type, and from the moment input arrives that makes the coming windows unfit to judge
(non-finite or implausible values, off-grid stamps, gaps, clock jumps, a topic stopping, a run
of stale stamps) until a window after it is judged (the validator keeps that state,
:attr:`~twotank_validation.online.validator.OnlineValidator.input_fault`); otherwise it carries
the last window's level (published once all models' reports of a window are out).

A managed node (:mod:`twotank_validation.ros.lifecycle`, docs/ros.md "Managed nodes"): it
takes input and judges only while active; inactive, ``/diagnostics`` says so. The alarm's
debouncing and the watchdog's timeout change at run time (:data:`VALIDATOR_RUNTIME`); the
other parameters are read-only.
"""

from __future__ import annotations

import enum
import math
import queue
import sys
import threading
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from time import perf_counter
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import JumpThreshold
from rclpy.duration import Duration
from rclpy.serialization import serialize_message
from std_msgs.msg import Bool, Float64
from std_srvs.srv import Trigger

from twotank_validation.bags.evidence import EvidenceRecorder
from twotank_validation.core.model import LFTModel, load_model_document, model_from_dict
from twotank_validation.defaults import NS_PER_S
from twotank_validation.diagnose.live_jobs import catalogue_diagnosis
from twotank_validation.errors import TwotankError
from twotank_validation.online import (
    Alarm,
    MonitorConfig,
    OnlineValidator,
    WindowReport,
)
from twotank_validation.online import streams as itf
from twotank_validation.online.extraction import check_message, extract, source_stamp_ns
from twotank_validation.online.interface_map import InterfaceMap, load_interface_map
from twotank_validation.online.interface_text import interface_map_from_text
from twotank_validation.online.livediag import LiveDiagConfig, LiveDiagnoser, LiveDiagnosis
from twotank_validation.online.sources import InterfaceMapError
from twotank_validation.online.validator import parse_oversampling
from twotank_validation.online.validator_settings import VALIDATOR_SETTINGS, EvidenceConfig
from twotank_validation.online.window import verdict_text
from twotank_validation.replay import model_documents
from twotank_validation.ros import messages
from twotank_validation.ros.lifecycle import ManagedNode, run_managed
from twotank_validation.ros.params import (
    UNIT_PARAMS,
    Param,
    ParameterError,
    setting_params,
    verdict_qos,
)
from twotank_validation.settings import from_flat

DRAIN_TIMEOUT_S = 600.0
"""Longest wall time to wait for the worker to judge what was queued: at deactivate, and in
``live``'s driver (at the end of a run, and every eighth of a period with a supervisor); with
the diagnosis inline the worker may be a few diagnoses behind, each taking seconds."""

VALIDATOR_PARAMS = (
    *setting_params(VALIDATOR_SETTINGS),  # the settings tree (online/validator_settings.py)
    *UNIT_PARAMS,
    Param(
        "interface_map",
        "",
        "interface map YAML (docs/interface.md): each model input and output from its own "
        "topic, message type, field, stamp and unit conversion; empty: the two-tank topics "
        "flow_cmd, height, temperature",
    ),
    Param(
        "inputs",
        [""],
        "the interface map as text instead of interface_map, one input source per entry in "
        "model order: NAME=TOPIC:TYPE:FIELD[,scale=S][,offset=O][,stamp=receive]; empty: none",
    ),
    Param("outputs", [""], "the interface map's output sources as text, as inputs"),
)


@dataclass(slots=True)
class _Event:
    """A received message, converted: one of the worker's queue items.

    Attributes:
        topic: the map's topic.
        stamp_ns: its stamp (ns): the header stamp or the receive time, as the map says.
        values: the model-unit value of each source the map reads from the topic, in map
            order.
        received: ``perf_counter()`` at reception (report latency).
    """

    topic: str
    stamp_ns: int
    values: tuple[float, ...]
    received: float
    msg: Any = None  # the message itself (serialised for the evidence bag by the worker)


@dataclass(slots=True)
class _Marker:
    """Queue item: set ``done`` once every item queued before it is processed."""

    done: threading.Event


class _Control(enum.Enum):
    """Queue items that carry no data."""

    RESET = enum.auto()  # the clock jumped back: restart alignment and windowing
    STOPPED = enum.auto()  # the watchdog saw a stream stop: an input fault
    EXIT = enum.auto()  # the worker returns


_Item = _Event | _Marker | _Control


_BLANK_REPORT = WindowReport(
    model="",
    start_ns=0,
    end_ns=0,
    n_periods=0,
    n_samples=0,
    judged=False,
    data_quality="",
    beta=0.0,
    beta_lower=0.0,
    beta_upper=0.0,
    margin=0.0,
    invalidated=False,
    alarm=Alarm.OK,
    convention="power",
    solver="",
    freqs_hz=np.zeros(1),
    w_min=np.zeros(1),
    compute_time_s=0.0,
)


def probability_text(p: float | None) -> str:
    """``"0.970"``, or ``"none"`` (``unexplained``, or a kind the bench did not measure)."""
    return "none" if p is None else f"{p:.3f}"


def diagnosis_text(d: LiveDiagnosis) -> str:
    """The node's log line of an answer, stamped with the data's time (the window's end)."""
    where = f" on {d.channel}" if d.channel else ""
    p = "" if d.probability is None else f" (probability {d.probability:.3f})"
    return (
        f"model {d.model}, window ending {d.window_end_ns / NS_PER_S:.1f} s: most likely "
        f"{d.kind}{where}{p}: {d.summary}"
    )


def op_reference_text(op: dict[str, Any]) -> str:
    """``"commissioned: u [0.4, 0.4], y [0.47, 0.5]"`` (or the state alone without one)."""
    if op["u"] is None:
        return str(op["state"])
    fmt = ", ".join
    return (
        f"{op['state']}: u [{fmt(f'{v:.4g}' for v in op['u'])}], "
        f"y [{fmt(f'{v:.4g}' for v in op['y'])}]"
    )


def monitor_config(values: dict[str, Any]) -> MonitorConfig:
    """Build the core config from parameter values (raises ParameterError if inconsistent)."""
    try:
        return from_flat(MonitorConfig, values)
    except ValueError as err:
        raise ParameterError(str(err)) from err


VALIDATOR_RUNTIME = frozenset(
    {
        "alarm_windows",
        "clear_windows",
        "warn_beta",
        "latch_alarm",
        "debounce",
        "alarm_evidence",
        "stale_timeout_s",
    }
)
"""The validator's parameters that change at run time: the alarm's debouncing (taken between
two windows: the next window is judged with it) and the watchdog's timeout. Every other one is
read-only (it shapes the windows, the models or the topics)."""


class ValidatorNode(ManagedNode):
    """Online model validation with a fault-detection alarm.

    A managed node (:mod:`twotank_validation.ros.lifecycle`): configure builds the validator,
    the live diagnosis, the evidence recorder and the publishers; activate subscribes to the
    map's topics, starts the worker thread and the watchdog; deactivate stops judging (the
    messages already queued are judged and published first); cleanup closes the evidence bag.

    Memory stays flat however long it runs: besides the window buffer it keeps only the last
    ``keep_reports`` reports (:attr:`reports`); whoever needs every report registers a
    listener in :attr:`report_listeners` (called from the worker thread after publishing).

    Args:
        models: models to use instead of the ``models`` parameter (tests, composition).
        documents: model name -> model document for the live diagnosis (default: the
            documents the ``models`` parameter names, or the built-in model of each name).
        inline_diagnosis: run the live diagnosis in the worker thread, before the report
            that started it is published (the answer rides on that report, as in replay),
            instead of in a background executor. For a simulated clock, which waits for it
            (``twotank-validation live``); a deployment keeps the default, so that a
            diagnosis never delays a report.
        keep_reports: reports kept in :attr:`reports` (the most recent ones).
        **kwargs: passed to :class:`rclpy.node.Node` (context, parameter_overrides, ...).
    """

    PARAMS = VALIDATOR_PARAMS
    RUNTIME = VALIDATOR_RUNTIME
    ROLE = "validator"
    OWN_STATUS = True

    def __init__(
        self,
        *,
        models: Sequence[LFTModel] | None = None,
        documents: dict[str, Any] | None = None,
        name: str = "twotank_validator",
        keep_reports: int = 16,
        inline_diagnosis: bool = False,
        **kwargs: Any,
    ) -> None:
        self._given_models = None if models is None else list(models)
        self._given_documents = dict(documents or {})
        self._inline_diagnosis = inline_diagnosis
        self.reports: deque[WindowReport] = deque(maxlen=keep_reports)  # the latest published
        self.report_listeners: list[Callable[[WindowReport], None]] = []
        # per window: from receiving the message that completed it to its reports published
        self.report_latency_s: deque[float] = deque(maxlen=1000)
        # the latest live diagnosis of each model (published on its topic when ready)
        self.diagnoses: deque[LiveDiagnosis] = deque(maxlen=keep_reports)
        self._latest_diagnosis: dict[str, LiveDiagnosis] = {}
        self.evidence: EvidenceRecorder | None = None
        self.diagnoser: LiveDiagnoser | None = None
        self._executor: ThreadPoolExecutor | None = None
        self._worker: threading.Thread | None = None
        self._accepting = False  # subscription callbacks queue messages (active)
        self._queue: queue.Queue[_Item] = queue.Queue()
        self._lock = threading.Lock()
        self.received: dict[str, int] = {}
        super().__init__(name, **kwargs)

    def configure_node(self, values: dict[str, Any]) -> None:
        """Build the validator, diagnosis, evidence recorder and publishers."""
        self.config = monitor_config(values)
        try:
            self.units = itf.RigUnits(
                float(values["pascal_per_unit"]),
                float(values["temperature_offset_c"]),
                float(values["temperature_span_c"]),
            )
            docs = dict(self._given_documents)
            if self._given_models is not None:
                self.models = list(self._given_models)
            else:
                loaded = [load_model_document(m) for m in values["models"]]
                self.models = [model_from_dict(doc, source) for doc, source in loaded]
                docs = {m.name: doc for m, (doc, _) in zip(self.models, loaded, strict=True)} | docs
            self.diagnoser = None
            if bool(values["diagnosis"]):
                docs = model_documents(self.models, docs)
                if not self._inline_diagnosis:
                    # one worker: answers come in the order their windows came
                    self._executor = ThreadPoolExecutor(1, thread_name_prefix="twotank_diagnosis")
                self.diagnoser = LiveDiagnoser(
                    catalogue_diagnosis(docs, convention=self.config.convention),
                    LiveDiagConfig(
                        max_updates=int(values["diagnosis_max_updates"]), models=tuple(docs)
                    ),
                    executor=self._executor,
                    on_result=self._on_diagnosis,
                )
            self.interface = _interface_map(values, self.units)
            self.core = OnlineValidator(
                self.config,
                self.models,
                interface=self.interface,
                jitter_fraction=float(values["jitter_fraction"]),
                oversampling=parse_oversampling(values["oversampling"]),
                diagnoser=self.diagnoser,
            )
        except (TwotankError, ValueError) as err:
            raise ParameterError(f"cannot start the validator: {err}") from err
        self.stale_timeout_ns = int(float(values["stale_timeout_s"]) * NS_PER_S)
        _, self._report_cls = messages.message_classes()
        self._topics = self.interface.topics()
        # what the watchdog watches: the map's topics with their types
        self._watched: dict[str, str] = {t: s.msgtype for t, s in self._topics.items()}
        self._classes: dict[str, Any] = {}
        for topic, sources in self._topics.items():
            try:
                self._classes[topic] = messages.message_class(sources.msgtype)
            except ImportError as err:
                raise ParameterError(f"cannot start the validator: {err}") from err
        self.evidence = _evidence_recorder(values, self.config, self.interface, self.models)

        # the operating points as of the last report (read by the /diagnostics publisher)
        self._ops = self.core.operating_points()
        self._last_rx: dict[str, int | None] = dict.fromkeys(self._watched)
        self.received = dict.fromkeys(self._watched, 0)
        # per model: level, text and the last report; replaced whole (never updated in place)
        # once every model's report of a window is out, so the watchdog sees one window
        self._status: dict[str, tuple[Alarm, str, WindowReport | None]] = {
            m.name: (Alarm.STALE, "waiting for data", None) for m in self.models
        }
        self._watch: tuple[Alarm, str] | None = None  # the watchdog's latest finding
        self._refused: dict[str, str] = {}  # map topics whose messages do not fit, and why
        self._checked: set[str] = set()
        # deadline (a few hops) and liveliness offered on the verdict topics (docs/ros.md, QoS)
        verdict = verdict_qos(self.config.hop * self.config.ts_s)
        alarm_qos = verdict_qos(self.config.hop * self.config.ts_s, latched=True)
        pub = self.create_lifecycle_publisher
        self._pub_report = {
            m.name: self.configured(pub(self._report_cls, f"validation/{m.name}/report", verdict))
            for m in self.models
        }
        self._pub_margin = {
            m.name: self.configured(pub(Float64, f"validation/{m.name}/margin", verdict))
            for m in self.models
        }
        self._pub_invalid = {
            m.name: self.configured(pub(Bool, f"validation/{m.name}/invalidated", alarm_qos))
            for m in self.models
        }
        self._diagnosis_cls = messages.diagnosis_class()
        self._pub_diagnosis = {
            m.name: self.configured(pub(self._diagnosis_cls, f"validation/{m.name}/diagnosis", 10))
            for m in self.models
        }
        # the first report message costs milliseconds (lazy imports): pay that now, not in
        # the first window's latency
        messages.report_message(_BLANK_REPORT, self._report_cls)

    def check_runtime(self, values: dict[str, Any]) -> Callable[[], None] | None:
        """The new alarm settings (checked by the settings tree), taken between two windows."""
        alarm = monitor_config(values).alarm
        stale_ns = int(float(values["stale_timeout_s"]) * NS_PER_S)

        def apply() -> None:
            with self._lock:  # the worker judges under it: the change lands between windows
                self.core.set_alarm(alarm)
                self.config = self.core.config
            self.stale_timeout_ns = stale_ns

        return apply if self.is_configured else None

    def activate_node(self) -> None:
        """Subscribe, start the worker and the watchdog; the alarm state as it stands."""
        while not self._queue.empty():  # what the watchdog or a clock jump left at deactivate
            item = self._queue.get_nowait()
            if isinstance(item, _Marker):
                item.done.set()
        with self._lock:
            if any(self.received.values()):
                # reactivated: the data stopped while inactive; align and window afresh
                # (the alarm states are kept)
                self.core.restart()
        self._last_rx = dict.fromkeys(self._watched)
        self._watch = None
        self._accepting = True
        for topic, cls in self._classes.items():
            self.activated(
                self.create_subscription(cls, topic, partial(self._on_message, topic), 1000)
            )
        self.activated(self.create_service(Trigger, "reset_alarm", self._on_reset))
        self.activated(self.create_service(Trigger, "reset_operating_point", self._on_reset_op))
        levels = self.core.alarm_levels()
        for m in self.models:
            self._publish_invalidated(m.name, levels[m.name] is Alarm.ERROR)
        self.activated(self.create_timer(0.5, self._on_watchdog))
        # a backward jump of the (simulated) clock restarts alignment and windowing
        handle = self.get_clock().create_jump_callback(
            JumpThreshold(
                min_forward=None, min_backward=Duration(nanoseconds=-1), on_clock_change=True
            ),
            post_callback=self._on_time_jump,
        )
        self.activated(handle.unregister)
        self._worker = threading.Thread(
            target=self._work, name="twotank_validator_worker", daemon=True
        )
        self._worker.start()

    def deactivate_node(self) -> None:
        """Stop judging: no new messages taken; the queued ones judged and published first."""
        self._accepting = False
        worker, self._worker = self._worker, None
        if worker is not None:
            self._queue.put(_Control.EXIT)
            worker.join(timeout=DRAIN_TIMEOUT_S)

    def cleanup_node(self) -> None:
        """Stop the live diagnosis and close the evidence bag (what came so far is in it)."""
        executor, self._executor = self._executor, None
        if executor is not None:
            executor.shutdown(wait=True, cancel_futures=True)
        evidence, self.evidence = self.evidence, None
        if evidence is not None:
            evidence.close()

    def inactive_names(self) -> list[str]:
        """One status per model, as when active."""
        return [f"twotank_validation: model {m.name}" for m in self.models]

    # ---------------------------------------------------------------- callbacks (never block)

    def _now_ns(self) -> int:
        return int(self.get_clock().now().nanoseconds)

    def _on_message(self, topic: str, msg: Any) -> None:
        """A message of one of the map's topics: its sources' values queued."""
        if not self._accepting:
            return  # deactivating: judging stops here
        now = self._now_ns()
        self._last_rx[topic] = now
        self.received[topic] += 1
        if topic in self._refused:
            return
        sources = self._topics[topic]
        if topic not in self._checked:
            self._checked.add(topic)
            try:
                for b in sources.bindings:
                    check_message(b.source, msg, sources.msgtype)
            except InterfaceMapError as err:
                self._refused[topic] = str(err)
                self.get_logger().error(f"interface map does not fit: {err}")
                return
        received = perf_counter()
        values = []
        for b in sources.bindings:
            try:
                values.append(extract(msg, b.source))
            except InterfaceMapError:
                values.append(math.nan)  # the aligner flags it as a non-finite sample
        stamp = source_stamp_ns(msg, sources.bindings[0].source, now)
        kept = msg if self.evidence is not None else None  # serialised by the worker
        self._queue.put(_Event(topic, stamp, tuple(values), received, kept))

    def _on_time_jump(self, jump: Any) -> None:
        if jump.delta.nanoseconds < 0:
            self._queue.put(_Control.RESET)

    def _on_reset(self, _req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        with self._lock:
            self.core.reset_alarms()
        for m in self.models:
            self._publish_invalidated(m.name, False)
        resp.success = True
        resp.message = "alarms reset"
        return resp

    def _on_reset_op(self, _req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        with self._lock:
            self.core.reset_operating_points()
            self._ops = self.core.operating_points()
        resp.success = True
        resp.message = (
            "operating point reset: the given reference again, or commissioned from the next "
            "steady windows"
        )
        return resp

    # ---------------------------------------------------------------- worker thread

    def feed(self, topic: str, stamp: int, value: Any) -> list[WindowReport]:
        """Run one message's values through the validator: :meth:`OnlineValidator.feed`.

        The worker calls this; tests may too.
        """
        with self._lock:
            reports = self.core.feed(topic, stamp, value)
            if reports:
                self._ops = self.core.operating_points()
            return reports

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if item is _Control.EXIT:
                return
            if isinstance(item, _Marker):
                item.done.set()
                continue
            if item is _Control.STOPPED:
                self.core.note_stopped_streams()
                continue
            if item is _Control.RESET:
                with self._lock:
                    self.core.restart()
                continue
            self._process(item.topic, item.stamp_ns, item.values, item.received, item.msg)

    def _process(
        self, topic: str, stamp_ns: int, value: Any, received: float, msg: Any = None
    ) -> None:
        """Feed one message's values to the validator and publish the reports it completes."""
        evidence = self.evidence
        try:
            if evidence is not None and msg is not None:
                evidence.note(topic, stamp_ns, serialize_message(msg))
            reports = self.feed(topic, stamp_ns, value)
        except Exception as err:  # keep the node alive; the status says what happened
            self.get_logger().error(f"validator failed on {topic} at {stamp_ns} ns: {err}")
            self._status = {
                name: (Alarm.STALE, f"internal error: {err}", rep)
                for name, (_, _, rep) in self._status.items()
            }
            return
        if reports:
            status = dict(self._status)
            for rep in reports:
                if evidence is not None:
                    evidence.on_report(rep.model, rep.alarm, rep.end_ns, diagnosed=self._last(rep))
                status[rep.model] = self._publish(rep)
            self._status = status
            self._publish_diagnostics()  # once every model's status is new
            self.report_latency_s.append(perf_counter() - received)

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Block until the worker has processed every queued event (tests, composition).

        Not active (no worker): nothing is judged, True at once.
        """
        if self._worker is None:
            return True
        done = threading.Event()
        self._queue.put(_Marker(done))
        return done.wait(timeout_s)

    def _publish(self, rep: WindowReport) -> tuple[Alarm, str, WindowReport]:
        self._pub_report[rep.model].publish(messages.report_message(rep, self._report_cls))
        self._pub_margin[rep.model].publish(Float64(data=float(rep.margin)))
        self._publish_invalidated(rep.model, rep.alarm == Alarm.ERROR)
        text = (
            verdict_text(rep) if rep.judged else f"window not judged: {rep.data_quality}"
        ) + "".join(f"; warning: {w}" for w in rep.warnings)
        self.reports.append(rep)
        for listener in self.report_listeners:
            listener(rep)
        return rep.alarm, text, rep

    def _on_diagnosis(self, d: LiveDiagnosis) -> None:
        """A live diagnosis is ready (executor thread): publish it at once."""
        self._latest_diagnosis[d.model] = d
        self.diagnoses.append(d)
        bag = self.evidence.status().by_model.get(d.model, "") if self.evidence else ""
        self._pub_diagnosis[d.model].publish(
            messages.diagnosis_message(d, self._diagnosis_cls, bag)
        )
        self.get_logger().info(diagnosis_text(d))

    def _diagnosis_values(self, name: str, rep: WindowReport) -> list[KeyValue]:
        """The /diagnostics keys of the latest live diagnosis while the alarm is ERROR."""
        d = self._latest_diagnosis.get(name)
        if d is None or rep.alarm is not Alarm.ERROR or d.onset_ns >= rep.end_ns:
            return []
        params = ", ".join(f"{k}={v:.6g}" for k, v in d.parameters.items())
        return [
            KeyValue(key="diagnosis_kind", value=d.kind),
            KeyValue(key="diagnosis_channel", value=d.channel),
            KeyValue(key="diagnosis_parameters", value=params),
            KeyValue(key="diagnosis_probability", value=probability_text(d.probability)),
            KeyValue(key="diagnosis_score", value=f"{d.score:.3f}"),
            KeyValue(key="diagnosis_summary", value=d.summary),
        ]

    def _last(self, rep: WindowReport) -> bool:
        """The report carries the live diagnosis's last answer to its alarm (all are in)."""
        d = rep.diagnosis
        return (
            d is not None
            and self.diagnoser is not None
            and (d.update >= self.diagnoser.config.max_updates)
        )

    def _evidence_values(self, name: str) -> list[KeyValue]:
        """The /diagnostics keys of the evidence bags (none when evidence_dir is empty)."""
        if self.evidence is None:
            return []
        st = self.evidence.status()
        return [
            KeyValue(key="evidence_bag", value=st.by_model.get(name, "")),
            KeyValue(key="evidence_state", value=st.state),
            KeyValue(key="evidence_dropped", value=str(st.dropped)),
            KeyValue(key="evidence_error", value=st.error),
        ]

    def _publish_invalidated(self, name: str, value: bool) -> None:
        self._pub_invalid[name].publish(Bool(data=value))

    def _publish_diagnostics(self, override: tuple[Alarm, str] | None = None) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        # bad input seen since the last judged window: the status says so at once, not only at
        # the next window boundary (set and cleared by the worker, read by the watchdog too)
        fault = self.core.input_fault
        override = override or self._watch
        status = self._status
        # the latest the worker saw: a timer callback never waits for a window being judged
        # (or diagnosed) under the lock
        ops = self._ops
        for m in self.models:
            level, text, rep = status[m.name]
            if override is not None:
                level, text = override
            elif fault is not None:
                level, text = Alarm.STALE, fault
            st = DiagnosticStatus()
            st.level = bytes([int(level)])
            st.name = f"twotank_validation: model {m.name}"
            st.hardware_id = self.get_fully_qualified_name()
            st.message = text
            if rep is not None:
                st.values = [
                    KeyValue(key="beta", value=f"{rep.beta:.6g}"),
                    KeyValue(key="margin", value=f"{rep.margin:.6g}"),
                    KeyValue(key="window_end_s", value=f"{rep.end_ns / NS_PER_S:.3f}"),
                    KeyValue(key="data_quality", value=rep.data_quality),
                    KeyValue(key="warnings", value=" | ".join(rep.warnings)),
                    KeyValue(key="beta_op", value=f"{rep.beta_op:.6g}"),
                    KeyValue(key="beta_total", value=f"{rep.beta_total:.6g}"),
                    KeyValue(key="raised_by", value=rep.raised_by),
                    KeyValue(key="operating_point", value=rep.operating_point),
                    KeyValue(key="op_reference", value=op_reference_text(ops[m.name])),
                    *self._diagnosis_values(m.name, rep),
                    *self._evidence_values(m.name),
                ]
            arr.status.append(st)
        self._pub_status.publish(arr)

    # ---------------------------------------------------------------- watchdog

    def _wrong_types(self) -> list[str]:
        problems = []
        for name, msgtype in self._watched.items():
            topic = self.resolve_topic_name(name)
            for info in self.get_publishers_info_by_topic(topic):
                if info.topic_type != msgtype:
                    problems.append(
                        f"{topic} has a publisher of type {info.topic_type}, expected {msgtype}"
                    )
        return [*problems, *self._refused.values()]

    def _on_watchdog(self) -> None:
        now = self._now_ns()
        problems = self._wrong_types()
        stopped = False
        for stream, last in self._last_rx.items():
            if last is None:
                problems.append(f"no {stream} received yet")
            elif now - last > self.stale_timeout_ns:
                problems.append(f"{stream} stopped {(now - last) / NS_PER_S:.1f} s ago")
                stopped = True
        # the watchdog's finding holds for every status until its next tick; a stopped stream
        # is also an input fault (until a window after it is judged)
        self._watch = (Alarm.STALE, "; ".join(problems)) if problems else None
        if stopped:
            self._queue.put(_Control.STOPPED)
        self._publish_diagnostics()


def _interface_map(values: dict[str, Any], units: itf.RigUnits) -> InterfaceMap:
    """The interface map of the parameters; without one, the two-tank preset in ``units``.

    Raises:
        ParameterError, InterfaceMapError: the parameters name no usable map.
    """
    inputs = [s for s in values["inputs"] if s]
    outputs = [s for s in values["outputs"] if s]
    path = str(values["interface_map"])
    if path and (inputs or outputs):
        raise ParameterError("give interface_map or inputs/outputs, not both")
    if path:
        return load_interface_map(path)
    if inputs or outputs:
        if not (inputs and outputs):
            raise ParameterError("inputs and outputs go together: give every input and output")
        return interface_map_from_text(inputs, outputs)
    return itf.two_tank_map(units)


def _evidence_recorder(
    values: dict[str, Any], config: MonitorConfig, imap: InterfaceMap, models: Sequence[LFTModel]
) -> EvidenceRecorder | None:
    """The evidence recorder of the ``evidence_*`` parameters (None: ``evidence_dir`` empty).

    Raises:
        ParameterError: settings that cannot hold (too few periods kept, a directory that
            cannot be made).
    """
    cfg = from_flat(EvidenceConfig, values, prefix="evidence_")
    if not cfg.dir:
        return None
    topics = {t: s.msgtype for t, s in imap.topics().items()}
    over = parse_oversampling(values["oversampling"])
    try:
        return EvidenceRecorder(
            cfg,
            topics=topics,
            ts_s=config.ts_s,
            period_samples=config.period_samples,
            messages_per_sample=sum(over.get(t, 1) for t in topics),
            needed_periods=config.settle_periods + config.periods_per_window,
            models=[m.name for m in models],
            interface=imap,
        )
    except TwotankError as err:
        raise ParameterError(f"cannot start the validator: {err}") from err


def main(args: list[str] | None = None) -> int:
    """``ros2 run twotank_validation twotank_validator`` entry point."""
    return run_managed(ValidatorNode, args)


if __name__ == "__main__":
    sys.exit(main())
