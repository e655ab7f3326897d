"""The validator node's report path: what was made faster and bounded stays the same.

Node tests start DDS participants: run them in a private network namespace with only
loopback up, like test_ros_nodes.py (`scripts/run test` does).
"""

from __future__ import annotations

import math
import struct

import numpy as np
from node_feed import feed_rig_record, validator_node
from report_checks import assert_same_reports

from tools.streamfuzz import clean_record as rig_record
from twotank_validation.core.model import load_model
from twotank_validation.online import Alarm, MonitorConfig, WindowReport, monitor_record
from twotank_validation.online import streams as itf
from twotank_validation.ros import messages

FAST = {"ts_s": 0.8, "period_samples": 256}


def report(judged: bool) -> WindowReport:
    rng = np.random.default_rng(1)
    w = rng.normal(size=129)
    w[[3, 7]] = [math.nan, -0.0]
    return WindowReport(
        model="B",
        start_ns=5,
        end_ns=10**18 + 7,
        n_periods=2,
        n_samples=256,
        judged=judged,
        data_quality="ok" if judged else "settling",
        beta=0.5 if judged else math.nan,
        beta_lower=math.nan,
        beta_upper=math.nan,
        margin=0.5 if judged else math.nan,
        invalidated=False,
        alarm=Alarm.OK if judged else Alarm.STALE,
        convention="power",
        solver="closed_form" if judged else "",
        freqs_hz=np.arange(129) / 204.8 if judged else np.zeros(0),
        w_min=w if judged else np.zeros(0),
        compute_time_s=0.001,
    )


def test_report_message_arrays_equal_the_element_by_element_fill() -> None:
    _, cls = messages.message_classes()
    for judged in (True, False):
        rep = report(judged)
        fast = messages.report_message(rep, cls)
        slow = messages.report_message(rep, cls)
        slow.frequencies_hz = [float(x) for x in rep.freqs_hz]  # the fill it replaced
        slow.w_min = [float(x) for x in rep.w_min]
        for name in ("frequencies_hz", "w_min"):
            a, b = getattr(fast, name), getattr(slow, name)
            assert a.typecode == b.typecode == "d"
            assert struct.pack(f"<{len(a)}d", *a) == struct.pack(f"<{len(b)}d", *b)
        for name in cls.get_fields_and_field_types():
            a, b = getattr(fast, name), getattr(slow, name)
            if isinstance(a, float):
                assert struct.pack("<d", a) == struct.pack("<d", b), name
            elif name not in ("frequencies_hz", "w_min"):
                assert a == b, name


def test_node_history_is_bounded_and_listeners_get_every_report() -> None:
    """24 hours at 10 Hz are 844 reports: the node keeps only the latest; a listener sees
    all of them, equal to the core monitor's on the same samples."""
    stamps, u, y = rig_record(9)
    with validator_node({**FAST, "models": ["A", "B"]}, keep_reports=3) as node:
        every: list[WindowReport] = []
        node.report_listeners.append(every.append)
        feed_rig_record(node, stamps, u, y, wait_each=False)
        cfg = MonitorConfig(ts_s=0.8, period_samples=256)
        units = itf.RigUnits()
        y_rx = np.column_stack(  # what the node gets back from the messages' units
            [
                [units.level_from_pressure(units.pressure_from_level(float(v))) for v in y[:, 0]],
                [
                    units.temperature_from_celsius(units.celsius_from_temperature(float(v)))
                    for v in y[:, 1]
                ],
            ]
        )
        want = monitor_record(stamps, u, y_rx, cfg, [load_model("A"), load_model("B")])
        want = want[: len(every)]  # the last sample is finalised by the next one
        assert len(every) >= 14
        assert len(want) == len(every)
        assert_same_reports(every, want)
        assert list(node.reports) == every[-3:]
