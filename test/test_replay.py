"""Bag replay through the live validator's code path (issue #4)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from report_checks import assert_same_reports

from twotank_validation import cli, replay
from twotank_validation.bags import write_scenario_bag
from twotank_validation.core.model import load_model
from twotank_validation.online import Alarm, MonitorConfig, monitor_record
from twotank_validation.sim import scenario as sc

FAST = MonitorConfig(ts_s=0.8, period_samples=256)
FAST_ARGS = ["--ts", "0.8", "--period", "256", "--quiet"]


def fast_scenario(name: str = "nominal", periods: float = 8, **changes) -> sc.Scenario:
    base = sc.load_scenario(name)
    return dataclasses.replace(
        base, ts_s=0.8, period_samples=256, duration_s=periods * 204.8, **changes
    )


@cache
def nominal_bag(tmp: str, storage: str = "mcap") -> Path:
    out = Path(tmp) / f"nominal_{storage}"
    if not out.exists():
        write_scenario_bag(fast_scenario(), out, storage=storage)
    return out


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("bags"))


def models():
    return [load_model("A"), load_model("B")]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_replay_equals_core_on_the_simulated_samples(workdir, storage) -> None:
    """Bag -> reader -> extractors -> OnlineValidator gives, bit for bit, the reports of the
    core monitor fed the scenario's samples directly."""
    bag = nominal_bag(workdir, storage)
    res = replay.replay_bag(bag, models(), replay.ReplayConfig(monitor=FAST))
    assert res.complete, res.problems
    stamps, u, y = sc.simulate_scenario(fast_scenario())
    direct = monitor_record(stamps, u, y, FAST, models())
    # the replay finalises the last sample only when a later message arrives
    assert len(res.reports) in (len(direct), len(direct) - 2)
    for a, b in zip(res.reports, direct, strict=False):
        assert (a.model, a.start_ns, a.end_ns, a.judged, a.alarm) == (
            b.model,
            b.start_ns,
            b.end_ns,
            b.judged,
            b.alarm,
        )
        if a.judged:
            assert a.beta == pytest.approx(
                b.beta, rel=1e-12
            )  # unit conversions round-trip to 1 ulp
    judged_a = [r for r in res.reports if r.model == "A" and r.judged]
    judged_b = [r for r in res.reports if r.model == "B" and r.judged]
    assert judged_a
    assert judged_b
    assert all(r.invalidated for r in judged_a)
    assert not any(r.invalidated for r in judged_b)


def test_json_follows_the_documented_schema(workdir, tmp_path) -> None:
    bag = nominal_bag(workdir)
    out = tmp_path / "r.json"
    code = cli.main(["validate", str(bag), "--json", str(out), *FAST_ARGS])
    assert code == 0
    doc = json.loads(out.read_text())
    assert set(doc["models"]) == {"A", "B"}
    for entry in doc["models"].values():
        assert {"windows", "beta_max", "first_alarm"} <= set(entry)
        for w in entry["windows"]:
            assert {"start", "end", "beta", "invalidated", "alarm", "reason"} <= set(w)
            assert w["alarm"] in {"OK", "WARN", "ERROR", "STALE"}
            assert (w["reason"] is None) == (w["beta"] is not None)
            assert w["end"] > w["start"] >= 0.0
            # the excited lines' summary (docs/cli.md): judged windows only
            assert (w["excited_lines"] is None) == (w["reason"] is not None)
            if w["excited_lines"]:
                lo, hi = w["excited_band_hz"]
                assert 0.0 < lo <= hi < 0.5 / 0.8  # above DC, below Nyquist at FAST's Ts
    a = doc["models"]["A"]
    assert a["first_alarm"] is not None
    assert a["beta_max"] == max(w["beta"] for w in a["windows"] if w["beta"] is not None)
    assert doc["models"]["B"]["first_alarm"] is None


def test_leak_scenario_alarm_in_bag(tmp_path) -> None:
    s = fast_scenario("leak", periods=10, faults=("leak=0.04@1270",))
    bag = write_scenario_bag(s, tmp_path / "leak", storage="mcap")
    res = replay.replay_bag(bag, [load_model("B")], replay.ReplayConfig(monitor=FAST))
    summary = replay.summary_json(res)
    first = summary["models"]["B"]["first_alarm"]
    assert first is not None
    assert 1270 <= first <= 1270 + 3 * 204.8


def truncated_copy(bag: Path, dst: Path, fraction: float) -> Path:
    shutil.copytree(bag, dst)
    data = next(dst.glob("*.mcap"))
    raw = data.read_bytes()
    data.write_bytes(raw[: int(len(raw) * fraction)])
    return dst


def test_truncated_bag_reports_windows_before_the_damage(workdir, tmp_path) -> None:
    bag = truncated_copy(nominal_bag(workdir), tmp_path / "cut", 0.7)
    full = replay.replay_bag(nominal_bag(workdir), models(), replay.ReplayConfig(monitor=FAST))
    res = replay.replay_bag(bag, models(), replay.ReplayConfig(monitor=FAST))
    assert not res.complete
    assert res.problems
    assert 0 < len(res.reports) < len(full.reports)
    for a, b in zip(res.reports, full.reports, strict=False):
        assert a.beta == b.beta or (np.isnan(a.beta) and np.isnan(b.beta))
    code = cli.main(["validate", str(bag), *FAST_ARGS])
    assert code == cli.EXIT_INCOMPLETE


def test_not_a_bag_and_empty_input_fail_clearly(tmp_path, capsys) -> None:
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "x.txt").write_text("hello")
    assert cli.main(["validate", str(tmp_path / "junk"), *FAST_ARGS]) == 2
    assert "ERROR:" in capsys.readouterr().err
    assert cli.main(["validate", str(tmp_path / "missing"), *FAST_ARGS]) == 2


def test_missing_topic_and_remapping(workdir, tmp_path, capsys) -> None:
    bag = nominal_bag(workdir)
    code = cli.main(["validate", str(bag), "--topic", "height=/rig/level", *FAST_ARGS])
    assert code == cli.EXIT_INCOMPLETE  # the missing topic is the cause of nothing judged
    err = capsys.readouterr().err
    assert "/rig/level" in err
    assert "ERROR: no window of model A could be judged" in err
    # remapping to the names in the bag works
    code = cli.main(["validate", str(bag), "--topic", "height=height", *FAST_ARGS])
    assert code == 0


def test_gap_in_the_data_is_flagged_not_bridged(tmp_path) -> None:
    """A recording with a silence: windows touching it are not judged, later ones are."""
    s = fast_scenario(periods=9)
    stamps, u, y = sc.simulate_scenario(s)
    keep = np.ones(len(stamps), bool)
    keep[700:720] = False  # 16 s without any message
    from twotank_validation.online import OnlineValidator, input_fault_text  # noqa: PLC0415

    core = OnlineValidator(FAST, models())
    reports = []
    for k in np.flatnonzero(keep):
        reports += core.feed("flow_cmd", int(stamps[k]), tuple(u[k]))
        reports += core.feed("height", int(stamps[k]), float(y[k, 0]))
        reports += core.feed("temperature", int(stamps[k]), float(y[k, 1]))
    assert core.counters().missing == 20
    touching = [r for r in reports if r.start_ns <= stamps[710] <= r.end_ns]
    assert touching
    assert all(
        not r.judged and "gap" in r.data_quality and r.alarm is Alarm.STALE for r in touching
    )
    assert reports[-1].judged
    # the input fault (the node's STALE text) was cleared by the judged windows after it; the
    # run's summary names it in the same words, as the replay of such a bag does
    assert core.input_fault is None
    assert core.input_problems() == [input_fault_text({"gaps"})]


def test_recorded_live_run_replays_to_the_same_reports_bit_for_bit(tmp_path) -> None:
    """Record the interface topics of a `live` run (raw subscriptions -> rosbags writer),
    replay the bag: the same reports as the node published during the run."""
    from rclpy.parameter import Parameter  # noqa: PLC0415

    from twotank_validation.bags.writer import BagWriter  # noqa: PLC0415
    from twotank_validation.online.streams import STREAM_TYPES  # noqa: PLC0415
    from twotank_validation.ros.live import LiveConfig, run_live  # noqa: PLC0415
    from twotank_validation.ros.record import RecorderNode  # noqa: PLC0415

    out = tmp_path / "live_bag"
    writer = BagWriter(out, storage="mcap")

    def attach(ctx):
        rec = RecorderNode(
            writer,
            dict(STREAM_TYPES),
            context=ctx,
            parameter_overrides=[Parameter("use_sim_time", value=True)],
        )
        return [rec], lambda k: all(c > k for c in rec.counts.values())

    try:
        live = run_live(
            LiveConfig(duration_s=7 * 204.8 + 1.6, ts_s=0.8, period_samples=256, models=("A", "B")),
            attach=attach,
        )
    finally:
        writer.close()
    res = replay.replay_bag(out, models(), replay.ReplayConfig(monitor=FAST))
    assert res.complete, res.problems
    assert len(live.reports) >= 10
    assert abs(len(res.reports) - len(live.reports)) <= 2
    assert_same_reports(live.reports, res.reports)


def test_record_command_writes_what_it_received(tmp_path) -> None:
    """`record` (raw subscriptions -> rosbags writer) for 3 s of wall time while another
    participant publishes; the closed bag holds every message, readable by the replay reader."""
    import threading  # noqa: PLC0415
    import time  # noqa: PLC0415

    import rclpy  # noqa: PLC0415
    from rclpy.context import Context  # noqa: PLC0415
    from rclpy.node import Node  # noqa: PLC0415
    from sensor_msgs.msg import FluidPressure  # noqa: PLC0415

    from twotank_validation.bags import reader  # noqa: PLC0415
    from twotank_validation.ros.record import record  # noqa: PLC0415

    out = tmp_path / "rec"
    counts: dict[str, int] = {}
    thread = threading.Thread(target=lambda: counts.update(record(out, duration_s=3.0)))
    thread.start()
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node("pub", context=ctx)
    pub = node.create_publisher(FluidPressure, "height", 100)
    deadline = time.monotonic() + 2.0
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    sent = 0
    for k in range(20):
        msg = FluidPressure()
        msg.header.stamp.sec = k
        msg.fluid_pressure = 4600.0 + k
        pub.publish(msg)
        sent += 1
        time.sleep(0.01)
    thread.join(timeout=10.0)
    node.destroy_node()
    rclpy.shutdown(context=ctx)
    assert not thread.is_alive()
    assert counts["height"] == sent
    with reader.open_bag(out) as bag:
        got = [m.msg.fluid_pressure for m in bag.messages(["height"])]
    assert got == [4600.0 + k for k in range(sent)]


def test_plain_mcap_of_another_tool_replays_like_the_rosbag2_bag(workdir, tmp_path) -> None:
    """A plain MCAP file (mcap_ros2 writer, no metadata.yaml) with the same samples gives the
    same reports as the rosbag2 bag written by `simulate`."""
    import sys  # noqa: PLC0415

    from twotank_validation.online.streams import RigUnits  # noqa: PLC0415

    sys.path.insert(0, str(Path(__file__).parent / "data"))
    import make_bags as mb  # noqa: PLC0415

    stamps, u, y = sc.simulate_scenario(fast_scenario())
    units = RigUnits()
    msgs = []
    for k, t in enumerate(stamps.tolist()):
        msgs.append(
            mb.Sample("flow_cmd", mb.FLOW_CMD_TYPE, t, t, {"hot": u[k, 0], "cold": u[k, 1]})
        )
        p = units.pressure_from_level(float(y[k, 0]))
        msgs.append(
            mb.Sample("height", mb.HEIGHT_TYPE, t, t, {"fluid_pressure": p, "variance": 0.0})
        )
        c = units.celsius_from_temperature(float(y[k, 1]))
        msgs.append(
            mb.Sample("temperature", mb.TEMPERATURE_TYPE, t, t, {"temperature": c, "variance": 0.0})
        )
    plain = mb.write_plain_mcap(tmp_path / "plain.mcap", msgs)
    cfg = replay.ReplayConfig(monitor=FAST)
    got = replay.replay_bag(plain, models(), cfg)
    ref = replay.replay_bag(nominal_bag(workdir), models(), cfg)
    assert got.complete, got.problems
    assert [r.beta for r in got.reports if r.judged] == [r.beta for r in ref.reports if r.judged]


def test_report_folder_has_timeline_and_windows_of_interest(workdir, tmp_path) -> None:
    out = tmp_path / "figs"
    assert cli.main(["validate", str(nominal_bag(workdir)), "--report", str(out), *FAST_ARGS]) == 0
    names = {p.name for p in out.glob("*.png")}
    assert "alarm_timeline.png" in names
    for kind in ("nyquist", "per_bin", "time_signals"):
        assert f"{kind}_A_max_beta.png" in names
        assert f"{kind}_A_first_alarm.png" in names  # Model A alarms on the nominal rig
        assert f"{kind}_B_max_beta.png" in names
    assert not any(
        n.startswith(("nyquist_B_first", "per_bin_B_first")) for n in names
    )  # B never alarms
