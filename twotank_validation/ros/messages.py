"""The package's generated ROS messages: importing their classes, filling a ValidationReport.

Kept apart from :mod:`twotank_validation.online.streams` (ROS-free: type names, units,
extractors), since these import the generated message packages.
"""

from __future__ import annotations

import array
import importlib
import math
from typing import Any

import numpy as np

from twotank_validation.online.livediag import LiveDiagnosis
from twotank_validation.online.streams import set_stamp
from twotank_validation.online.window import WindowReport


def message_classes() -> tuple[Any, Any]:
    """``(FlowCommand, ValidationReport)`` generated message classes.

    Raises:
        ImportError: with a hint when the package's messages were not built.
    """
    try:
        from twotank_validation_msgs.msg import (  # noqa: PLC0415
            FlowCommand,
            ValidationReport,
        )
    except ImportError as err:  # pragma: no cover - depends on the install
        raise ImportError(
            "the messages twotank_validation_msgs/FlowCommand and ValidationReport are not "
            "built: run `bash scripts/run exec true` (bootstraps the venv and builds them) "
            "or build the package with colcon"
        ) from err
    return FlowCommand, ValidationReport


def diagnosis_class() -> Any:
    """The generated ``Diagnosis`` message class.

    Raises:
        ImportError: with a hint when the package's messages were not built.
    """
    try:
        from twotank_validation_msgs.msg import Diagnosis  # noqa: PLC0415
    except ImportError as err:  # pragma: no cover - depends on the install
        raise ImportError(
            "the message twotank_validation_msgs/Diagnosis is not built: run "
            "`bash scripts/run exec true` (bootstraps the venv and builds the messages)"
        ) from err
    return Diagnosis


def diagnosis_message(diagnosis: LiveDiagnosis, cls: Any, evidence_bag: str = "") -> Any:
    """Fill a Diagnosis message from a :class:`LiveDiagnosis` (and its alarm's evidence bag)."""
    msg = cls()
    set_stamp(msg.header.stamp, diagnosis.window_end_ns)
    msg.model = diagnosis.model
    msg.kind = diagnosis.kind
    msg.channel = diagnosis.channel
    msg.parameter_names = list(diagnosis.parameters)
    msg.parameter_values = [float(v) for v in diagnosis.parameters.values()]
    p = diagnosis.probability
    msg.probability = math.nan if p is None else float(p)
    msg.score = float(diagnosis.score)
    set_stamp(msg.onset, max(diagnosis.onset_ns, 0))
    msg.windows = int(diagnosis.windows)
    msg.update = int(diagnosis.update)
    msg.summary = diagnosis.summary
    msg.evidence_bag = evidence_bag
    return msg


def message_class(msgtype: str) -> Any:
    """The rclpy message class of ``pkg/msg/Name``.

    Raises:
        ImportError: the type's package is not installed, or has no such message (the
            message names the type and what to install).
    """
    pkg, _, name = msgtype.partition("/msg/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), name)
    except (ImportError, AttributeError) as err:
        raise ImportError(
            f"cannot import the message type {msgtype}: install (or source) the ROS package "
            f"{pkg!r} that defines it, or fix the type's name"
        ) from err


def _doubles(values: np.ndarray) -> array.array[float]:
    return array.array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes())


def report_message(report: WindowReport, cls: Any) -> Any:
    """Fill a ValidationReport message from a core :class:`WindowReport`."""
    msg = cls()
    set_stamp(msg.header.stamp, report.end_ns)
    msg.model = report.model
    set_stamp(msg.window_start, report.start_ns)
    set_stamp(msg.window_end, report.end_ns)
    msg.n_periods = report.n_periods
    msg.n_samples = report.n_samples
    msg.judged = report.judged
    msg.data_quality = report.data_quality
    msg.beta = float(report.beta)
    msg.beta_lower = float(report.beta_lower)
    msg.beta_upper = float(report.beta_upper)
    msg.margin = float(report.margin)
    msg.invalidated = bool(report.invalidated)
    msg.alarm_level = int(report.alarm)
    msg.norm_convention = report.convention
    msg.solver = report.solver
    # array('d') is taken as is; a list would be type- and range-checked element by element
    # (milliseconds for a 4096-sample window's 2049 bins)
    msg.frequencies_hz = _doubles(report.freqs_hz)
    msg.w_min = _doubles(report.w_min)
    msg.compute_time_s = float(report.compute_time_s)
    msg.beta_op = float(report.beta_op)
    msg.beta_total = float(report.beta_total)
    msg.raised_by = report.raised_by
    msg.operating_point = report.operating_point
    msg.beta_outside = float(report.beta_outside)
    # (Hz, share) pairs flattened (one sequence: the message's layout reads the same in rclpy
    # and rosbags, which pad an empty float64 sequence differently; a float64 follows it)
    msg.lines_outside = _doubles(np.array(report.lines_outside, dtype=np.float64).reshape(-1))
    msg.input_noise = float(report.input_noise)
    msg.input_noise_effect = float(report.input_noise_effect)
    msg.excited_bins = array.array("I", np.flatnonzero(report.excited).astype(np.uint32).tobytes())
    msg.noise_floor = _doubles(report.noise_floor)
    msg.noise_beta = float(report.noise_beta)
    return msg
