"""Evidence on an alarm: the bag written when the alarm rises, read back by ``diagnose``.

An in-process run (``ros.live.run_live``: plant, excitation and validator nodes on a simulated
clock, Ts = 0.8 s, a 256-sample period) with a leak of 0.04 from 900 s and the validator's
``evidence_dir`` set. References: the samples the validator consumed (the run's record, bit
for bit against the bag's messages read through the same interface map); the live
diagnosis's answer (``diagnose`` on the bag names the same kind on the same channel, its
outflow within 10 % of the live one, and both within 15 % of the injected 0.04); the
settings' bounds (ring buffer length, bags kept, bag size) counted directly; a writer
slowed by a monkeypatched sleep against a feeding loop timed by the wall clock; a bag cut
in the middle of its file against the messages written before the cut.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from twotank_validation import cli
from twotank_validation.bags import BagCorruptError, open_bag
from twotank_validation.bags.evidence import MAP_FILE, EvidenceRecorder, evidence_bags
from twotank_validation.diagnose.kinds import expected_effect
from twotank_validation.errors import DatumError
from twotank_validation.online import Alarm
from twotank_validation.online.extraction import extract
from twotank_validation.online.interface_map import load_interface_map
from twotank_validation.online.streams import two_tank_map
from twotank_validation.online.validator_settings import EvidenceConfig
from twotank_validation.ros import messages
from twotank_validation.ros.live import LiveConfig, run_live
from twotank_validation.sim.faults import parse_fault

PERIOD_S = 204.8
LEAK = "leak=0.04@900"
BEFORE, AFTER = 8, 4  # periods kept before the rise, written after it


class _Diagnostics:
    """Collects the evidence keys of the validator's /diagnostics statuses."""

    def __init__(self) -> None:
        self.keys: list[dict[str, str]] = []
        self.diagnoses: list = []

    def attach(self, ctx):
        from diagnostic_msgs.msg import DiagnosticArray  # noqa: PLC0415
        from rclpy.node import Node  # noqa: PLC0415

        node = Node("twotank_evidence_listener", context=ctx)
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on, 10)
        node.create_subscription(
            messages.diagnosis_class(), "/validation/B/diagnosis", self.diagnoses.append, 10
        )
        # run_live's discovery wait counts an attached node among the interface's readers
        for topic, msgtype in two_tank_map().topics().items():
            cls = messages.message_class(msgtype.msgtype)
            node.create_subscription(cls, topic, lambda _m: None, 10)
        return [node], lambda _k: True

    def _on(self, arr) -> None:
        for st in arr.status:
            kv = {v.key: v.value for v in st.values}
            if "evidence_bag" in kv:
                self.keys.append(kv)


@pytest.fixture(scope="module")
def leak_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("evidence")
    listener = _Diagnostics()
    cfg = LiveConfig(
        duration_s=1900.0,
        ts_s=0.8,
        period_samples=256,
        models=("B",),
        faults=(LEAK,),
        validator={
            "evidence_dir": str(out),
            "evidence_periods_before": BEFORE,
            "evidence_periods_after": AFTER,
        },
        node_info_log=False,
    )
    return run_live(cfg, attach=listener.attach), out, listener


def _bag_values(bag_path: Path) -> dict[int, tuple[list[float], list[float]]]:
    """stamp -> (u, y) of the bag's messages, through the two-tank map (as the node reads)."""
    imap = two_tank_map()
    found: dict[int, tuple[list[float], list[float]]] = {}
    with open_bag(bag_path) as bag:
        for m in bag.messages(["flow_cmd", "height", "temperature"]):
            u, y = found.setdefault(m.log_time_ns, ([np.nan] * 2, [np.nan] * 2))
            for names, vals in ((imap.inputs, u), (imap.outputs, y)):
                for k, src in enumerate(names):
                    if src.topic == m.topic:
                        vals[k] = extract(m.msg, src)
    return found


def test_the_alarm_writes_the_samples_before_and_after_it_bit_for_bit(leak_run) -> None:
    res, out, listener = leak_run
    keys = listener.keys
    assert res.evidence is not None
    (bag,) = res.evidence.bags
    assert evidence_bags(out) == [Path(bag)]
    # named on /diagnostics: no bag before the rise, this one from it on
    assert keys[0]["evidence_bag"] == ""
    assert keys[-1]["evidence_bag"] == bag
    assert {k["evidence_dropped"] for k in keys} == {"0"}
    # and in the live diagnosis's message (its field evidence_bag)
    assert listener.diagnoses
    assert {d.evidence_bag for d in listener.diagnoses} == {bag}
    assert res.evidence.dropped == 0
    assert res.evidence.error == ""
    # the validator's interface map inside the bag (for a map other than the preset's)
    assert load_interface_map(Path(bag) / MAP_FILE) == two_tank_map()
    rise = next(r for r in res.reports if r.alarm is Alarm.ERROR)
    meta = json.loads(open_bag(bag).info.custom_data["twotank_validation.evidence"])
    assert meta["alarm_rise_s"] == rise.end_ns / 1e9
    values = _bag_values(Path(bag))
    stamps = sorted(values)
    period_ns = round(PERIOD_S * 1e9)
    # before: the ring buffer's periods (the run is shorter: from its start); after: until the
    # live diagnosis's last answer or AFTER periods
    assert stamps[0] <= max(rise.end_ns - BEFORE * period_ns, 0)
    assert rise.end_ns + (AFTER - 1) * period_ns <= stamps[-1] <= rise.end_ns + AFTER * period_ns
    live = {s.stamp_ns: s for s in res.samples}
    for t in stamps:
        u, y = values[t]
        assert np.array_equal(live[t].u, u), t
        assert np.array_equal(live[t].y, y), t
    assert len(stamps) == stamps[-1] // 800_000_000 + 1 - stamps[0] // 800_000_000


def test_diagnose_on_the_bag_names_what_the_live_diagnosis_named(leak_run, tmp_path) -> None:
    res, _, _ = leak_run
    (bag,) = res.evidence.bags
    live = [r.diagnosis for r in res.reports if r.diagnosis is not None]
    assert live
    answer = live[-1]
    want = tuple(str(x) for x in expected_effect(parse_fault(LEAK)))
    assert (answer.kind, answer.channel) == want
    out = tmp_path / "d.json"
    assert (
        cli.main(["diagnose", bag, "--model", "B", "--max-effects", "1", "--json", str(out)]) == 0
    )
    d = json.loads(out.read_text())
    (leak,) = [e for e in d["effects"] if (e["kind"], e["channel"]) == want]
    assert leak["parameters"]["outflow"] == pytest.approx(answer.parameters["outflow"], rel=0.1)
    for outflow in (leak["parameters"]["outflow"], answer.parameters["outflow"]):
        assert outflow == pytest.approx(0.04, rel=0.15)


def test_a_bag_cut_mid_write_is_read_up_to_the_cut(leak_run, tmp_path, capsys) -> None:
    res, _, _ = leak_run
    (bag,) = res.evidence.bags
    cut = tmp_path / "cut"
    shutil.copytree(bag, cut)
    (mcap,) = cut.glob("*.mcap")
    whole = _bag_values(Path(bag))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) * 6 // 10])  # killed in the middle of the file
    got: list[int] = []
    with open_bag(cut) as reader, pytest.raises(BagCorruptError, match=r"truncated"):
        got.extend(m.log_time_ns for m in reader.messages(["flow_cmd"]))
    assert set(got) <= set(whole)
    assert len(got) > 0.4 * len(whole)  # the messages before the cut (60 % of the file)
    code = cli.main(["validate", str(cut), "--model", "B", "--no-diagnosis"])
    err = capsys.readouterr().err
    assert code != 0
    assert "truncated" in err, err
    assert "Traceback" not in err


# ------------------------------------------------------------------- the recorder alone


def _recorder(tmp_path: Path, **kw) -> EvidenceRecorder:
    cfg = EvidenceConfig(dir=str(tmp_path / "ev"), **kw)
    return EvidenceRecorder(
        cfg,
        topics={"height": "sensor_msgs/msg/FluidPressure"},
        ts_s=1.0,
        period_samples=4,
        messages_per_sample=1,
        needed_periods=3,
        models=["B"],
    )


def _cdr(k: int) -> bytes:
    from twotank_validation.bags.writer import fluid_pressure, typestore  # noqa: PLC0415

    return bytes(
        typestore().serialize_cdr(fluid_pressure(k * 10**9, 0.5), "sensor_msgs/msg/FluidPressure")
    )


def test_a_ring_buffer_shorter_than_a_window_is_refused(tmp_path) -> None:
    with pytest.raises(DatumError, match=r"periods_before = 2 .* needs .* = 3 periods"):
        _recorder(tmp_path, periods_before=2)


def test_the_ring_buffer_and_the_disk_use_are_bounded(tmp_path) -> None:
    rec = _recorder(tmp_path, periods_before=3, periods_after=100, max_bags=2, max_bag_mb=0.01)
    msg = _cdr(1)
    k = 0
    for _ in range(4):
        for _ in range(40):
            rec.note("height", k * 10**9, msg)
            assert len(rec.ring) <= 3 * 4  # periods_before x period x messages per sample
            k += 1
        rec.on_report("B", Alarm.ERROR, k * 10**9)
        for _ in range(400):  # beyond max_bag_mb (10 kB): the bag stops growing
            rec.note("height", k * 10**9, msg)
            k += 1
        rec.on_report("B", Alarm.OK, k * 10**9)
        assert rec.wait_idle()
    rec.close()
    st = rec.status()
    assert len(st.bags) == 4
    assert st.removed == 2
    assert st.over_size > 0
    kept = evidence_bags(tmp_path / "ev")
    assert [str(p) for p in kept] == st.bags[-2:]
    for p in kept:
        assert sum(f.stat().st_size for f in p.iterdir()) < 0.01e6 * 1.5
        with open_bag(p) as bag:
            n = bag.info.message_counts["height"]
            assert 12 < n < 10_000 / 64  # the ring (3 periods of 4), then up to the size


def test_a_slow_writer_never_blocks_feeding_and_the_drop_is_reported(tmp_path, monkeypatch) -> None:
    from twotank_validation.bags.writer import BagWriter  # noqa: PLC0415

    slow = BagWriter.write_raw

    def crawl(self, *args):
        time.sleep(0.05)
        return slow(self, *args)

    monkeypatch.setattr(BagWriter, "write_raw", crawl)
    rec = _recorder(tmp_path, periods_before=3, periods_after=100, queue=16)
    msg = _cdr(1)
    for k in range(12):
        rec.note("height", k * 10**9, msg)
    rec.on_report("B", Alarm.ERROR, 12 * 10**9)
    t0 = time.perf_counter()
    for k in range(12, 212):
        rec.note("height", k * 10**9, msg)
    fed = time.perf_counter() - t0
    assert fed < 0.5  # 200 messages; the writer needs 0.05 s for each
    assert rec.status().dropped > 100
    rec.close(timeout_s=5.0)


KILLED = """
import sys, time
from twotank_validation.bags.evidence import EvidenceRecorder
from twotank_validation.bags.writer import fluid_pressure, typestore
from twotank_validation.errors import DatumError
from twotank_validation.online import Alarm
from twotank_validation.online.validator_settings import EvidenceConfig

rec = EvidenceRecorder(
    EvidenceConfig(dir=sys.argv[1], periods_before=3, periods_after=1000),
    topics={"height": "sensor_msgs/msg/FluidPressure"}, ts_s=1.0, period_samples=4,
    messages_per_sample=1, needed_periods=3, models=["B"],
)
store = typestore()
for k in range(int(sys.argv[2])):
    msg = store.serialize_cdr(fluid_pressure(k * 10**9, 0.5 + k), "sensor_msgs/msg/FluidPressure")
    rec.note("height", k * 10**9, bytes(msg))
    if k == 11:
        rec.on_report("B", Alarm.ERROR, k * 10**9)
assert rec.wait_idle()
time.sleep(0.5)  # the writer flushes when its queue runs dry (0.2 s)
print("ready", flush=True)
time.sleep(60)
"""


def test_a_recorder_killed_while_writing_leaves_a_bag_read_to_its_last_flush(tmp_path) -> None:
    """SIGKILL while the bag is open: the directory is a bag holding every message noted."""
    import signal  # noqa: PLC0415
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    n = 1000
    proc = subprocess.Popen(
        [sys.executable, "-c", KILLED, str(tmp_path), str(n)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    (bag,) = evidence_bags(tmp_path)
    got: list[tuple[int, float]] = []
    with open_bag(bag) as reader, pytest.raises(BagCorruptError, match="truncated"):
        # every message first, then the missing summary and footer said (validate and
        # diagnose: a warning and exit 3 with the windows judged)
        got.extend((m.log_time_ns, m.msg.fluid_pressure) for m in reader.messages(["height"]))
    # the ring (the 12 messages up to the rise) and everything noted after it, in order
    from twotank_validation.bags.writer import fluid_pressure  # noqa: PLC0415

    assert got == [(k * 10**9, fluid_pressure(k * 10**9, 0.5 + k).fluid_pressure) for k in range(n)]
