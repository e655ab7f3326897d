"""The validator node passes the core's warnings on: /diagnostics and the report message.

A record with a start-up transient (test_report_warnings.py) through the node's subscription
callbacks: each judged window's warnings appear in the status message, in the ``warnings``
key of /diagnostics and in the ValidationReport's ``data_quality``; a clean window's status
is what it was ("ok", no warning text, an empty ``warnings`` value).

Node tests start DDS participants: run them in a private network namespace with only
loopback up, like test_ros_nodes.py (`scripts/run test` does).
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from node_feed import feed_rig_record, validator_node

from tools.streamfuzz import transient_record
from twotank_validation.online import WindowReport
from twotank_validation.ros import messages

FAST = {"ts_s": 0.8, "period_samples": 256}


class _Recorder:
    """Stands in for the /diagnostics publisher: keeps what the node publishes."""

    def __init__(self) -> None:
        self.published: list[DiagnosticArray] = []

    def publish(self, msg: DiagnosticArray) -> None:
        self.published.append(msg)


def test_diagnostics_and_report_carry_the_warnings() -> None:
    stamps, u, y = transient_record(5)
    pairs: list[tuple[WindowReport, DiagnosticArray | None]] = []
    params = {**FAST, "models": ["B"], "settle_periods": 0}
    with validator_node(params) as node:
        diag = _Recorder()
        node._pub_status = diag  # white-box: the node's /diagnostics publisher
        # the diagnostics of a window go out after its report: pair each with the next one
        node.report_listeners.append(lambda rep: pairs.append((rep, None)))
        seen = [0]

        def pair(_k: int) -> None:
            if len(pairs) > seen[0]:
                assert len(pairs) == seen[0] + 1  # one model, one report per window
                assert diag.published
                pairs[-1] = (pairs[-1][0], diag.published[-1])
                seen[0] = len(pairs)

        feed_rig_record(node, stamps, u, y, after_each=pair)

    _, report_cls = messages.message_classes()
    judged = [(rep, arr) for rep, arr in pairs if rep.judged]
    assert len(judged) >= 3
    assert judged[0][0].warnings  # the transient, from the first window on
    assert not judged[-1][0].warnings  # settled by the end
    for rep, arr in pairs:
        assert arr is not None
        (status,) = arr.status
        values = {kv.key: kv.value for kv in status.values}
        assert values["data_quality"] == rep.data_quality
        assert values["warnings"] == " | ".join(rep.warnings)
        msg = messages.report_message(rep, report_cls)
        assert msg.data_quality == rep.data_quality
        if rep.warnings:
            assert rep.data_quality.startswith("ok; warning: ")
            assert status.message.endswith("".join(f"; warning: {w}" for w in rep.warnings))
            assert "transient" in values["warnings"]
        elif rep.judged:
            assert rep.data_quality == "ok"
            assert values["warnings"] == ""
            assert "warning" not in status.message
        else:
            assert status.message == f"window not judged: {rep.data_quality}"
