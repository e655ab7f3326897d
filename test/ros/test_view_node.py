"""``view`` attached to a running system: reports, diagnoses and the mode over DDS to the page.

The reference is what was published: real reports of a replay (a leak, so that β_op and an
alarm are in them) and a live diagnosis, turned into messages as the validator node turns
them (``ros.messages``), published on the node's topics, received by the view node and
pushed to a view. The JSON the view keeps must equal the validate JSON entry of the
original report in every field the message carries, and the spectrum bit for bit.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import String

from twotank_validation import cli
from twotank_validation.bags import write_scenario_bag
from twotank_validation.cli_common import Interrupts
from twotank_validation.online import WindowReport
from twotank_validation.online.livediag import LiveDiagnosis
from twotank_validation.online.window import MonitorConfig
from twotank_validation.replay import window_entry
from twotank_validation.ros import messages
from twotank_validation.ros.params import LATCHED
from twotank_validation.ros.view_node import ViewNode, report_from_message
from twotank_validation.sim import scenario as sc
from twotank_validation.usecases import ValidateJob
from twotank_validation.usecases.reading import ReadSettings
from twotank_validation.view import ViewServer

CARRIED = (
    "start", "end", "beta", "invalidated", "alarm", "reason", "data_quality", "margin",
    "beta_op", "beta_total", "raised_by", "operating_point", "input_noise",
    "input_noise_effect", "beta_outside", "lines_outside", "noise_beta", "excited_lines",
    "excited_band_hz",
)  # fmt: skip
"""The window entry's fields a ValidationReport message carries."""


def _reports(tmp: Path) -> list[WindowReport]:
    s = dataclasses.replace(
        sc.load_scenario("leak"),
        ts_s=0.8,
        period_samples=256,
        duration_s=7 * 204.8,
        faults=("leak=0.04@900",),
    )
    bag = write_scenario_bag(s, tmp / "leak", storage="mcap")
    out: list[WindowReport] = []
    job = ValidateJob(
        str(bag), ReadSettings(monitor=MonitorConfig(ts_s=0.8, period_samples=256)),
        models=("B",), diagnosis=False,
    )  # fmt: skip
    job.run(on_report=lambda r, _s: out.append(r))
    return out


def test_view_node_passes_what_the_validator_publishes(tmp_path: Path) -> None:
    reports = _reports(tmp_path)
    assert any(r.judged for r in reports)
    assert any(math.isfinite(r.beta_op) for r in reports)
    answer = LiveDiagnosis("B", "leak", "height", {"outflow": 0.04}, 0.15, "a leak", 9e11,
                           1.2e12, 2, 1, 0.99)  # fmt: skip
    report_cls = messages.message_classes()[1]
    diagnosis_cls = messages.diagnosis_class()
    ctx = Context()
    rclpy.init(context=ctx)
    view = ViewServer()
    try:
        node = ViewNode(view, ["B"], context=ctx)
        pub_node = Node("fake_validator", context=ctx)
        pub = pub_node.create_publisher(report_cls, "validation/B/report", 100)
        pub_d = pub_node.create_publisher(diagnosis_cls, "validation/B/diagnosis", 10)
        pub_mode = pub_node.create_publisher(String, "control/mode", LATCHED)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        ex.add_node(pub_node)
        deadline = time.monotonic() + 10
        while pub.get_subscription_count() < 1 or pub_d.get_subscription_count() < 1:
            ex.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, "no discovery"
        for r in reports:
            pub.publish(messages.report_message(r, report_cls))
        pub_d.publish(messages.diagnosis_message(answer, diagnosis_cls))
        pub_mode.publish(String(data="safe"))
        while node.reports < len(reports) or view.published < len(reports) + 2:
            ex.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, (node.reports, len(reports))
        first, _ = view.subscribe()
        docs = [json.loads(m) for m in first]
        got = [d for d in docs if d["type"] == "report"]
        assert len(got) == len(reports)
        for d, r in zip(got, reports, strict=True):
            want = window_entry(r, 0)
            assert {k: d.get(k) for k in CARRIED} == {k: want.get(k) for k in CARRIED}
        diag = next(d for d in docs if d["type"] == "diagnosis")
        assert diag["diagnosis"] == answer.to_json()
        assert next(d for d in docs if d["type"] == "mode")["mode"] == "safe"
        # the spectrum, bit for bit (the message's float64 arrays)
        last = reports[-1]
        back = report_from_message(messages.report_message(last, report_cls))
        assert back.w_min.tobytes() == last.w_min.tobytes()
        assert back.freqs_hz.tobytes() == last.freqs_hz.tobytes()
        assert back.noise_floor.tobytes() == last.noise_floor.tobytes()
        assert np.array_equal(back.excited, last.excited)
        assert last.excited.any()
    finally:
        view.close()
        rclpy.shutdown(context=ctx)


def test_view_command_without_a_validator_says_so(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["view", "--model", "B", "--duration", "0.5"])
    assert code == 4
    err = capsys.readouterr().err
    assert "view: http://127.0.0.1:" in err
    assert "no report came on validation/B/report" in err


def test_view_command_s_ctrl_c_says_it_closes_the_view(capfd: pytest.CaptureFixture[str]) -> None:
    """SIGINT while ``view`` follows the topics: a viewer's line, not a run's; no traceback."""

    def interrupt_once_listening() -> None:
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            handler = signal.getsignal(signal.SIGINT)
            if isinstance(getattr(handler, "__self__", None), Interrupts):
                os.kill(os.getpid(), signal.SIGINT)
                return
            time.sleep(0.01)

    killer = threading.Thread(target=interrupt_once_listening)
    killer.start()
    start = time.monotonic()
    code = cli.main(["view", "--model", "B", "--duration", "20"])
    killer.join()
    err = capfd.readouterr().err
    assert time.monotonic() - start < 15.0  # it stopped on the signal, not at --duration
    assert "SIGINT: closing the view" in err
    assert "current sample" not in err
    assert "Traceback" not in err
    assert code == 4  # nothing came: the topics it listened to are named
    assert "no report came on validation/B/report" in err
