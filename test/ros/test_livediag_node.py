"""The validator node names the fault live: a bounded in-process run (real executor, sim time).

Plant, excitation and validator nodes on a simulated clock (``ros.live.run_live``) at
Ts = 0.8 s and a 256-sample period (the paper's 204.8 s period with 8x fewer messages). A
listener node subscribes to ``validation/B/diagnosis`` and ``/diagnostics``. Reference: the
fault injected into the plant (a level-sensor bias of twice its stated limit); nominal: no
fault, no diagnosis.
"""

from __future__ import annotations

from rclpy.node import Node

from twotank_validation.online import Alarm
from twotank_validation.ros import messages
from twotank_validation.ros.live import LiveConfig, run_live

PERIOD_S = 204.8
ONSET_S = round(6.375 * PERIOD_S, 1)


class Listener:
    """Collects the diagnoses and the /diagnostics diagnosis keys the validator publishes."""

    def __init__(self, n_steps: int, *, wait_for_diagnosis: bool) -> None:
        self.n_steps = n_steps
        self.wait = wait_for_diagnosis
        self.diagnoses: list = []
        self.keys: list[dict[str, str]] = []

    def attach(self, ctx):
        from diagnostic_msgs.msg import DiagnosticArray  # noqa: PLC0415

        node = Node("twotank_diagnosis_listener", context=ctx)
        node.create_subscription(
            messages.diagnosis_class(), "/validation/B/diagnosis", self.diagnoses.append, 10
        )
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)

        def synced(k: int) -> bool:
            # the last sample waits (spinning the executor) for a diagnosis published by the
            # validator's background executor
            return k < self.n_steps - 1 or not self.wait or bool(self.diagnoses)

        return [node], synced

    def _on_diag(self, arr) -> None:
        for st in arr.status:
            kv = {v.key: v.value for v in st.values}
            if "diagnosis_kind" in kv:
                self.keys.append(kv)


def run(faults: tuple[str, ...], periods: float, *, wait: bool):
    cfg = LiveConfig(
        duration_s=periods * PERIOD_S + 1.6,
        ts_s=0.8,
        period_samples=256,
        models=("B",),
        faults=faults,
        validator={"diagnosis_max_updates": 2},
        inline_diagnosis=False,  # the deployed path: the node's background executor
    )
    listener = Listener(cfg.n_steps, wait_for_diagnosis=wait)
    res = run_live(cfg, attach=listener.attach)
    return res, listener


def test_node_publishes_the_diagnosis_after_the_alarm() -> None:
    res, listener = run((f"sensor_bias:height=0.05@{ONSET_S}",), 6.375 + 6, wait=True)
    b = [r for r in res.reports if r.model == "B"]
    first_error = next(r for r in b if r.alarm is Alarm.ERROR)
    assert listener.diagnoses, "no diagnosis published"
    d = listener.diagnoses[-1]
    assert d.model == "B"
    assert (d.kind, d.channel) == ("offset", "height"), d.summary
    values = dict(zip(d.parameter_names, d.parameter_values, strict=True))
    assert abs(values["offset"] - 0.05) < 0.005
    assert 0.0 <= d.score <= 1.0
    assert 0.0 <= d.probability <= 1.0
    stamp_ns = d.header.stamp.sec * 1_000_000_000 + d.header.stamp.nanosec
    assert stamp_ns >= first_error.end_ns  # published for a window at or after the alarm
    onset_ns = d.onset.sec * 1_000_000_000 + d.onset.nanosec
    assert onset_ns < first_error.end_ns


def test_node_publishes_no_diagnosis_on_nominal_data() -> None:
    res, listener = run((), 7, wait=False)
    judged = [r for r in res.reports if r.judged]
    assert len(judged) >= 12
    assert all(r.alarm is not Alarm.ERROR for r in judged)
    assert listener.diagnoses == []
    assert listener.keys == []
    assert all(r.diagnosis is None for r in res.reports)
