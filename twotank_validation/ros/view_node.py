"""The live view attached to a running system: its report, diagnosis and mode topics in.

``twotank-validation view --model M ...`` (docs/view.md): a node that subscribes, per model
M, ``validation/M/report`` (ValidationReport) and ``validation/M/diagnosis`` (Diagnosis), and
``control/mode`` (std_msgs/String, transient-local, the supervisor's), and hands each to a
:class:`~twotank_validation.view.ViewServer`. A report message is turned back into the
:class:`~twotank_validation.online.window.WindowReport` the validator published it from
(:func:`report_from_message`), so the page gets the same JSON entry as from ``live``; what the
message does not carry (the warnings' texts, the periodicity measures, the reference's typed
state) is missing there (null).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from twotank_validation.online import Alarm, WindowReport
from twotank_validation.online.livediag import LiveDiagnosis
from twotank_validation.online.states import RaisedBy
from twotank_validation.ros import messages
from twotank_validation.ros.params import LATCHED
from twotank_validation.view.messages import mode_message
from twotank_validation.view.sinks import ReportSink

REPORTS_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
"""The view's subscriptions to reports and diagnoses: reliable, a burst of 100 kept."""


def _ns(t: Any) -> int:
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


def _array(values: Any) -> np.ndarray:
    return np.asarray(values, dtype=np.float64)


def report_from_message(msg: Any) -> WindowReport:
    """The :class:`WindowReport` a ValidationReport message was filled from (what it carries).

    The inverse of :func:`~twotank_validation.ros.messages.report_message` for its fields;
    the rest keep the report's defaults (no warnings, NaN measures, no diagnosis).
    """
    pairs = _array(msg.lines_outside).reshape(-1, 2)
    return WindowReport(
        model=msg.model,
        start_ns=_ns(msg.window_start),
        end_ns=_ns(msg.window_end),
        n_periods=int(msg.n_periods),
        n_samples=int(msg.n_samples),
        judged=bool(msg.judged),
        data_quality=msg.data_quality,
        beta=float(msg.beta),
        beta_lower=float(msg.beta_lower),
        beta_upper=float(msg.beta_upper),
        margin=float(msg.margin),
        invalidated=bool(msg.invalidated),
        alarm=Alarm(int(msg.alarm_level)),
        convention=msg.norm_convention,
        solver=msg.solver,
        freqs_hz=_array(msg.frequencies_hz),
        w_min=_array(msg.w_min),
        compute_time_s=float(msg.compute_time_s),
        beta_op=float(msg.beta_op),
        beta_total=float(msg.beta_total),
        raised_by=RaisedBy(msg.raised_by),
        operating_point=msg.operating_point,
        beta_outside=float(msg.beta_outside),
        lines_outside=tuple((float(hz), float(share)) for hz, share in pairs),
        input_noise=float(msg.input_noise),
        input_noise_effect=float(msg.input_noise_effect),
        noise_beta=float(msg.noise_beta),
        noise_floor=_array(msg.noise_floor),
        excited=_mask(msg.excited_bins, len(msg.frequencies_hz)),
    )


def _mask(indices: Any, n_bins: int) -> np.ndarray:
    """(n_bins,) bool, true at ``indices`` (a report's ``excited_bins``); empty if none given."""
    idx = np.asarray(indices, dtype=np.int64)
    if idx.size == 0 and n_bins == 0:
        return np.zeros(0, dtype=bool)
    out = np.zeros(n_bins, dtype=bool)
    out[idx] = True
    return out


def diagnosis_from_message(msg: Any) -> LiveDiagnosis:
    """The :class:`LiveDiagnosis` a Diagnosis message was filled from."""
    p = float(msg.probability)
    return LiveDiagnosis(
        model=msg.model,
        kind=msg.kind,
        channel=msg.channel,
        parameters=dict(zip(msg.parameter_names, map(float, msg.parameter_values), strict=True)),
        score=float(msg.score),
        summary=msg.summary,
        onset_ns=_ns(msg.onset),
        window_end_ns=_ns(msg.header.stamp),
        windows=int(msg.windows),
        update=int(msg.update),
        probability=None if math.isnan(p) else p,
    )


class ViewNode(Node):
    """Subscribes the models' reports and diagnoses and the supervisor's mode; feeds a view.

    Args:
        view: the server the messages go to.
        models: the models whose topics to follow (``validation/M/...``).
        **kwargs: for :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ...).

    Attributes:
        reports: reports received.
    """

    def __init__(self, view: ReportSink, models: Sequence[str], **kwargs: Any) -> None:
        super().__init__("twotank_view", **kwargs)
        self.view = view
        self.reports = 0
        report_cls = messages.message_classes()[1]
        diagnosis_cls = messages.diagnosis_class()
        for m in models:
            self.create_subscription(
                report_cls, f"validation/{m}/report", self._on_report, REPORTS_QOS
            )
            self.create_subscription(
                diagnosis_cls, f"validation/{m}/diagnosis", self._on_diagnosis, REPORTS_QOS
            )
        self.create_subscription(String, "control/mode", self._on_mode, LATCHED)

    def _on_report(self, msg: Any) -> None:
        self.reports += 1
        self.view.publish_report(report_from_message(msg))

    def _on_diagnosis(self, msg: Any) -> None:
        d = diagnosis_from_message(msg)
        self.view.publish({"type": "diagnosis", "model": d.model, "diagnosis": d.to_json()})

    def _on_mode(self, msg: Any) -> None:
        now = self.get_clock().now().nanoseconds / 1e9
        self.view.publish(mode_message(msg.data, now) | {"wall": time.time()})


def run_view(
    view: ReportSink,
    models: Sequence[str],
    *,
    duration_s: float | None = None,
    stop: Callable[[], bool] = lambda: False,
    context: Context | None = None,
) -> int:
    """Follow the models' topics into ``view`` until ``stop()`` or ``duration_s`` (wall).

    Returns:
        The reports received.
    """
    own = context is None
    ctx = context or Context()
    if own:
        rclpy.init(context=ctx)
    node = ViewNode(view, models, context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    deadline = None if duration_s is None else time.monotonic() + duration_s
    try:
        while not stop() and (deadline is None or time.monotonic() < deadline):
            executor.spin_once(timeout_sec=0.1)
        return node.reports
    finally:
        executor.remove_node(node)
        node.destroy_node()
        if own:
            rclpy.shutdown(context=ctx)
