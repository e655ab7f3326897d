"""Bag writing (twotank_validation.bags.writer and write_scenario_bag), read back independently.

References: rosbags' AnyReader (rebuilding the custom types from the definitions stored in the
bag, with a type store that does not know them), the mcap library with mcap-ros2-support's
decoder (MCAP storage), and rclpy's deserialize_message (rclpy imported in the tests only).
Values are checked against the simulated model-unit samples with the unit conversions written
out here (Pa = 9806.65 level, degC = 15 + 50 temperature).
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from twotank_validation.bags import (
    CUSTOM_DATA_KEY,
    STORAGES,
    BagError,
    BagExistsError,
    BagWriter,
    flow_command,
    fluid_pressure,
    interface_msg_dir,
    temperature_msg,
    typestore,
    write_scenario_bag,
)
from twotank_validation.errors import TwotankError
from twotank_validation.online.streams import RigUnits
from twotank_validation.sim.scenario import Scenario, simulate_scenario

FLOW = "twotank_validation_msgs/msg/FlowCommand"
REPORT = "twotank_validation_msgs/msg/ValidationReport"
REPO = Path(__file__).resolve().parents[2]

# 40 s at 0.1 s with a sensor bias from 20 s: 400 samples per topic.
SHORT = Scenario(
    name="short",
    duration_s=40.0,
    period_samples=128,
    cutoff_hz=0.05,
    faults=("sensor_bias:temperature=0.02@20",),
    seed=3,
)


def _read_anyreader(bag: Path) -> dict[str, Any]:
    """{topic: (msgtype, [log times], [decoded messages])} with a store lacking our types."""
    out: dict[str, Any] = {}
    store = get_typestore(Stores.ROS2_KILTED)
    assert FLOW not in store.types
    with AnyReader([bag], default_typestore=store) as reader:
        for conn in reader.connections:
            out[conn.topic] = (conn.msgtype, [], [])
        for conn, log_time, raw in reader.messages():
            out[conn.topic][1].append(log_time)
            out[conn.topic][2].append(reader.deserialize(raw, conn.msgtype))
    return out


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


@pytest.fixture(scope="module")
def simulated() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return simulate_scenario(SHORT)


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """SHORT written once per storage."""
    folder = tmp_path_factory.mktemp("bags")
    out = {}
    for storage in STORAGES:
        out[storage] = write_scenario_bag(SHORT, folder / f"short_{storage}", storage)
        assert out[storage] == folder / f"short_{storage}"
    return out


@pytest.fixture(params=STORAGES)
def short_bag(request: pytest.FixtureRequest, bags: dict[str, Path]) -> Path:
    return bags[request.param]


def test_typestore_registers_the_packages_types() -> None:
    store = typestore()
    assert typestore() is store  # cached
    assert {FLOW, REPORT} <= set(store.types)
    report_fields = [name for name, _ in store.fielddefs[REPORT][1]]
    assert report_fields[:2] == ["header", "model"]
    assert "w_min" in report_fields
    assert "sensor_msgs/msg/FluidPressure" in store.types  # the Kilted base store


def test_msg_dir_prefers_the_installed_package_then_the_repository(tmp_path: Path) -> None:
    installed = Path(sys.prefix, "share", "twotank_validation_msgs", "msg")
    if installed.is_dir():
        assert interface_msg_dir() == installed
    assert interface_msg_dir([tmp_path / "nowhere", REPO / "msg"]) == REPO / "msg"
    with pytest.raises(BagError, match=r"(?s)cannot find the message definitions.*nowhere"):
        interface_msg_dir([tmp_path / "nowhere"])


def test_bag_has_topics_types_counts_and_stamps(short_bag: Path) -> None:
    topics = _read_anyreader(short_bag)
    assert {t: v[0] for t, v in topics.items()} == {
        "flow_cmd": FLOW,
        "height": "sensor_msgs/msg/FluidPressure",
        "temperature": "sensor_msgs/msg/Temperature",
    }
    expected = [k * 100_000_000 for k in range(400)]
    for _, log_times, msgs in topics.values():
        assert len(msgs) == 400
        assert log_times == expected
        assert [_stamp(m) for m in msgs] == expected
        assert {m.header.frame_id for m in msgs} == {"tank1_base"}
    meta = yaml.safe_load((short_bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["message_count"] == 1200
    assert meta["storage_identifier"] == short_bag.name.split("_")[1]
    stored = json.loads(meta["custom_data"][CUSTOM_DATA_KEY])
    assert stored["faults"] == list(SHORT.faults)
    assert stored["duration_s"] == 40.0


def test_bag_values_convert_back_to_the_simulated_samples(
    short_bag: Path, simulated: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> None:
    _, u, y = simulated
    topics = _read_anyreader(short_bag)
    hot = np.array([m.hot for m in topics["flow_cmd"][2]])
    cold = np.array([m.cold for m in topics["flow_cmd"][2]])
    pa = np.array([m.fluid_pressure for m in topics["height"][2]])
    degc = np.array([m.temperature for m in topics["temperature"][2]])
    np.testing.assert_array_equal(np.column_stack([hot, cold]), u)
    # Stored values: the forward conversion, bit for bit (float64 CDR is lossless) ...
    np.testing.assert_array_equal(pa, y[:, 0] * 9806.65)
    np.testing.assert_array_equal(degc, 15.0 + 50.0 * y[:, 1])
    # ... and back to model units to rounding.
    np.testing.assert_allclose(pa / 9806.65, y[:, 0], rtol=1e-15, atol=0)
    np.testing.assert_allclose((degc - 15.0) / 50.0, y[:, 1], rtol=0, atol=1e-15)
    assert {m.variance for m in topics["height"][2] + topics["temperature"][2]} == {0.0}


def test_mcap_file_decodes_with_mcap_ros2(
    bags: dict[str, Path], simulated: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> None:
    _, u, y = simulated
    (mcap_file,) = bags["mcap"].glob("*.mcap")
    got: dict[str, list[Any]] = {"flow_cmd": [], "height": [], "temperature": []}
    schemas: dict[str, str] = {}
    with mcap_file.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            schemas[channel.topic] = schema.name
            assert message.log_time == _stamp(decoded)
            got[channel.topic].append(decoded)
    assert schemas == {
        "flow_cmd": "twotank_validation_msgs/msg/FlowCommand",
        "height": "sensor_msgs/msg/FluidPressure",
        "temperature": "sensor_msgs/msg/Temperature",
    }
    assert [len(v) for v in got.values()] == [400, 400, 400]
    np.testing.assert_array_equal([[m.hot, m.cold] for m in got["flow_cmd"]], u)
    np.testing.assert_allclose([m.fluid_pressure / 9806.65 for m in got["height"]], y[:, 0])
    np.testing.assert_allclose(
        [(m.temperature - 15.0) / 50.0 for m in got["temperature"]], y[:, 1], rtol=0, atol=1e-15
    )
    assert [_stamp(m) for m in got["temperature"]] == [k * 100_000_000 for k in range(400)]


def test_rclpy_deserialises_what_rosbags_wrote(short_bag: Path) -> None:
    serialization = pytest.importorskip("rclpy.serialization")
    msgs = pytest.importorskip("twotank_validation_msgs.msg")
    sensor = pytest.importorskip("sensor_msgs.msg")
    raw: dict[str, list[bytes]] = {}
    with AnyReader([short_bag]) as reader:
        for conn, _, data in reader.messages():
            raw.setdefault(conn.topic, []).append(data)
    ours = _read_anyreader(short_bag)
    for k in (0, 1, 399):
        cmd = serialization.deserialize_message(raw["flow_cmd"][k], msgs.FlowCommand)
        ref = ours["flow_cmd"][2][k]
        assert (cmd.hot, cmd.cold) == (ref.hot, ref.cold)
        assert cmd.header.stamp.sec * 10**9 + cmd.header.stamp.nanosec == k * 100_000_000
        assert cmd.header.frame_id == "tank1_base"
        fp = serialization.deserialize_message(raw["height"][k], sensor.FluidPressure)
        assert fp.fluid_pressure == ours["height"][2][k].fluid_pressure


def test_write_raw_takes_rclpy_bytes(tmp_path: Path) -> None:
    serialization = pytest.importorskip("rclpy.serialization")
    msgs = pytest.importorskip("twotank_validation_msgs.msg")
    cmd = msgs.FlowCommand()
    cmd.header.stamp.sec, cmd.header.stamp.nanosec = 12, 345
    cmd.hot, cmd.cold = 0.25, 0.625
    with BagWriter(tmp_path / "raw") as bag:
        bag.add_topic("flow_cmd", FLOW)
        bag.write_raw("flow_cmd", 12_000_000_345, serialization.serialize_message(cmd))
    (msg,) = _read_anyreader(tmp_path / "raw")["flow_cmd"][2]
    assert (msg.hot, msg.cold, _stamp(msg)) == (0.25, 0.625, 12_000_000_345)


@pytest.mark.parametrize("storage", STORAGES)
def test_interrupted_writer_keeps_what_was_written(tmp_path: Path, storage: str) -> None:
    out = tmp_path / "interrupted"
    opened: list[BagWriter] = []

    def record_then_ctrl_c() -> None:
        with BagWriter(out, storage) as bag:
            opened.append(bag)
            bag.add_topic("flow_cmd", FLOW)
            for k in range(5):
                bag.write("flow_cmd", k * 1000, flow_command(k * 1000, 0.1 * k, 0.5))
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        record_then_ctrl_c()
    assert opened[0].closed
    (_, log_times, got) = _read_anyreader(out)["flow_cmd"]
    assert log_times == [0, 1000, 2000, 3000, 4000]
    assert [m.hot for m in got] == [0.1 * k for k in range(5)]


@pytest.mark.parametrize("storage", STORAGES)
def test_refuses_to_overwrite(tmp_path: Path, storage: str) -> None:
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "keep.txt").write_text("precious")
    a_file = tmp_path / "file.bag"
    a_file.write_text("x")
    for path in (existing, a_file):
        with pytest.raises(BagExistsError, match="exists already"):
            BagWriter(path, storage)
        with pytest.raises(BagExistsError, match="exists already"):
            write_scenario_bag(SHORT, path, storage)
    assert (existing / "keep.txt").read_text() == "precious"  # untouched
    assert sorted(p.name for p in existing.iterdir()) == ["keep.txt"]
    assert a_file.read_text() == "x"


def test_writer_errors_are_clear(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="storage='rosbag1'"):
        BagWriter(tmp_path / "a", "rosbag1")
    assert not (tmp_path / "a").exists()
    bag = BagWriter(tmp_path / "b")
    bag.add_topic("flow_cmd", FLOW)
    with pytest.raises(BagError, match="registered already"):
        bag.add_topic("flow_cmd", FLOW)
    with pytest.raises(BagError, match="not in the type store"):
        bag.add_topic("x", "twotank_validation_msgs/msg/Nope")
    with pytest.raises(BagError, match="not registered"):
        bag.write("height", 0, fluid_pressure(0, 0.5))
    with pytest.raises(BagError, match="carries twotank_validation_msgs/msg/FlowCommand"):
        bag.write("flow_cmd", 0, fluid_pressure(0, 0.5))
    with pytest.raises(BagError, match="log time"):
        bag.write("flow_cmd", -1, flow_command(0, 0.1, 0.2))
    with pytest.raises(BagError, match="integer nanoseconds"):
        bag.write("flow_cmd", 1.5, flow_command(0, 0.1, 0.2))  # type: ignore[arg-type]
    with pytest.raises(BagError, match="CDR"):
        bag.write_raw("flow_cmd", 0, b"")
    bag.close()
    bag.close()  # idempotent
    with pytest.raises(BagError, match="closed"):
        bag.write("flow_cmd", 0, flow_command(0, 0.1, 0.2))
    assert isinstance(BagError("x"), TwotankError)


def test_message_helpers() -> None:
    units = RigUnits(pascal_per_unit=1000.0, temperature_offset_c=10.0, temperature_span_c=40.0)
    stamp = 1_234 * 1_000_000_000 + 56_789
    cmd = flow_command(stamp, 0.3, 0.7)
    assert cmd.__msgtype__ == FLOW
    assert (cmd.header.stamp.sec, cmd.header.stamp.nanosec) == (1234, 56_789)
    assert (cmd.hot, cmd.cold, cmd.header.frame_id) == (0.3, 0.7, "tank1_base")
    fp = fluid_pressure(stamp, 0.47, units)
    assert fp.__msgtype__ == "sensor_msgs/msg/FluidPressure"
    assert fp.fluid_pressure == 470.0
    assert fluid_pressure(0, 0.5).fluid_pressure == 0.5 * 9806.65
    tm = temperature_msg(stamp, 0.5, units)
    assert tm.__msgtype__ == "sensor_msgs/msg/Temperature"
    assert tm.temperature == 30.0
    assert temperature_msg(0, 0.5).temperature == 40.0
    with pytest.raises(BagError, match="stamp"):
        flow_command(-1, 0.1, 0.1)


def test_tracemalloc_peak_does_not_grow_with_length(tmp_path: Path) -> None:
    """Python-side memory of writing is independent of the number of samples (streaming)."""
    peaks = []
    nominal = dataclasses.replace(SHORT, faults=())
    write_scenario_bag(dataclasses.replace(nominal, duration_s=1.0), tmp_path / "warm", "sqlite3")
    for seconds in (50.0, 200.0):  # 500 and 2000 samples
        tracemalloc.start()
        write_scenario_bag(
            dataclasses.replace(nominal, duration_s=seconds), tmp_path / f"s{seconds}", "sqlite3"
        )
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    # Holding the 1500 extra samples' messages would take >= 1500 * 3 * 100 bytes.
    assert peaks[1] - peaks[0] < 150_000, peaks


_TWO_HOURS = """
import resource, sys
from twotank_validation.bags import write_scenario_bag
from twotank_validation.sim.scenario import load_scenario
import dataclasses
s = load_scenario("nominal")
write_scenario_bag(dataclasses.replace(s, duration_s=1.0), sys.argv[1] + "/warm")
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
write_scenario_bag(dataclasses.replace(s, duration_s=7200.0), sys.argv[1] + "/two_hours")
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(before, after)
"""


def test_two_hour_bag_peak_memory(tmp_path: Path) -> None:
    """A 2-hour 10 Hz MCAP bag (72 000 samples per topic) raises peak RSS by < 50 MB."""
    done = subprocess.run(
        [sys.executable, "-c", _TWO_HOURS, str(tmp_path)],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    before_kib, after_kib = map(int, done.stdout.split())
    assert (after_kib - before_kib) * 1024 < 50e6, (before_kib, after_kib)
    meta = yaml.safe_load((tmp_path / "two_hours" / "metadata.yaml").read_text())
    assert meta["rosbag2_bagfile_information"]["message_count"] == 3 * 72_000
