"""Small bag fixtures for ``test/test_bag_reader.py`` and ``bench/fuzz_bags.py``.

Everything here writes bags with the libraries' own writers (``rosbags.rosbag2.Writer`` for
rosbag2 in MCAP and SQLite3 storage, ``mcap_ros2.writer.Writer`` for plain MCAP files), never
with the package's reader or writer, so that a round trip checks the reader against an
independent producer. The custom types are registered from the repository's ``msg/*.msg``.

Run ``python test/data/make_bags.py`` (inside the project venv) to regenerate the golden
corpus next to this file: ``golden_mcap/`` and ``golden_sqlite3/`` (rosbag2 directories),
``golden_plain.mcap`` (plain MCAP, several chunks), ``golden_truncated.mcap`` (the plain file
cut in the middle of its data section) and ``golden.json`` (what a reader must return).
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import struct
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as McapWriter
from mcap_ros2.writer import Writer as McapRos2Writer
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
MSG_DIR = ROOT / "msg"

FLOW_CMD_TYPE = "twotank_validation_msgs/msg/FlowCommand"
REPORT_TYPE = "twotank_validation_msgs/msg/ValidationReport"
HEIGHT_TYPE = "sensor_msgs/msg/FluidPressure"
TEMPERATURE_TYPE = "sensor_msgs/msg/Temperature"
FLOAT64_TYPE = "std_msgs/msg/Float64"

TOPIC_TYPES = {
    "flow_cmd": FLOW_CMD_TYPE,
    "height": HEIGHT_TYPE,
    "temperature": TEMPERATURE_TYPE,
}

NS = 1_000_000_000
T0_NS = 1_700_000_000 * NS + 123_456_789  # log time of the first message


@dataclass(frozen=True)
class Sample:
    """One message as written: topic, type, log time (ns), header stamp (ns), field values."""

    topic: str
    msgtype: str
    log_time_ns: int
    stamp_ns: int
    values: dict[str, float]


def typestore() -> Typestore:
    """ROS 2 Kilted type store plus the package's types read from ``msg/*.msg``."""
    store = get_typestore(Stores.ROS2_KILTED)
    types: dict[str, Any] = {}
    for name in ("FlowCommand", "ValidationReport"):
        text = (MSG_DIR / f"{name}.msg").read_text()
        types.update(get_types_from_msg(text, f"twotank_validation_msgs/msg/{name}"))
    store.register(types)
    return store


def samples(n_per_topic: int = 6, *, topics: dict[str, str] | None = None) -> list[Sample]:
    """Deterministic messages, in *topic-major* order (not log-time order).

    Topic i has log times ``T0 + k * 100 ms + i ms`` and header stamps 3 ms (+ k µs) earlier,
    so the log-time order interleaves the topics and no two messages share a log time. The
    values are doubles with all mantissa bits used, so only an exact round trip matches.
    """
    topics = TOPIC_TYPES if topics is None else topics
    out: list[Sample] = []
    for i, (topic, msgtype) in enumerate(topics.items()):
        for k in range(n_per_topic):
            log_ns = T0_NS + k * 100_000_000 + i * 1_000_000
            stamp_ns = log_ns - 3_000_000 - k * 1_000
            x = (k + 1) / 7.0 + i / 3.0
            if msgtype == FLOW_CMD_TYPE:
                values = {"hot": x / 10.0, "cold": 1.0 - x / 11.0}
            elif msgtype == HEIGHT_TYPE:
                values = {"fluid_pressure": 4000.0 + 97.0 * x, "variance": x / 1e4}
            elif msgtype == TEMPERATURE_TYPE:
                values = {"temperature": 20.0 + x / 3.0, "variance": x / 1e3}
            elif msgtype == FLOAT64_TYPE:
                values = {"data": x}
            else:
                raise ValueError(f"no sample values for {msgtype}")
            out.append(Sample(topic, msgtype, log_ns, stamp_ns, values))
    return out


def _header(store: Typestore, stamp_ns: int) -> Any:
    time_cls = store.types["builtin_interfaces/msg/Time"]
    header_cls = store.types["std_msgs/msg/Header"]
    return header_cls(stamp=time_cls(sec=stamp_ns // NS, nanosec=stamp_ns % NS), frame_id="rig")


def rosbags_message(store: Typestore, sample: Sample) -> Any:
    """The sample as a rosbags message object."""
    cls = store.types[sample.msgtype]
    if sample.msgtype == FLOAT64_TYPE:
        return cls(**sample.values)
    return cls(header=_header(store, sample.stamp_ns), **sample.values)


def dict_message(sample: Sample) -> dict[str, Any]:
    """The sample as the nested dict mcap_ros2's encoder takes."""
    if sample.msgtype == FLOAT64_TYPE:
        return dict(sample.values)
    stamp = {"sec": sample.stamp_ns // NS, "nanosec": sample.stamp_ns % NS}
    return {"header": {"stamp": stamp, "frame_id": "rig"}, **sample.values}


def write_rosbag2(
    path: Path,
    storage: str,
    messages: list[Sample],
    *,
    topics: dict[str, str] | None = None,
    definitions: bool = True,
) -> Path:
    """Write a rosbag2 directory with rosbags' writer; return its path.

    Args:
        path: bag directory to create (must not exist).
        storage: ``"mcap"`` or ``"sqlite3"``.
        messages: written in the given order.
        topics: topic -> type of the connections (default: those of ``messages``, or the
            three interface topics when ``messages`` is empty).
        definitions: False writes an old-style SQLite3 bag (schema 3, as ROS 2 Humble) that
            carries no message definitions, so a reader must know the types itself.
    """
    store = typestore()
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    if topics is None:
        topics = {m.topic: m.msgtype for m in messages} or dict(TOPIC_TYPES)
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {t: writer.add_connection(t, ty, typestore=store) for t, ty in topics.items()}
        for m in messages:
            raw = store.serialize_cdr(rosbags_message(store, m), m.msgtype)
            writer.write(conns[m.topic], m.log_time_ns, raw)
    if not definitions:
        if storage != "sqlite3":
            raise ValueError("definitions=False is only available for sqlite3 storage")
        db = sqlite3.connect(path / f"{path.name}.db3")
        with db:
            db.execute("DROP TABLE message_definitions")
            db.execute("UPDATE schema SET schema_version = 3")
        db.close()
    return path


def write_plain_mcap(
    path: Path,
    messages: list[Sample],
    *,
    chunk_size: int = 1024 * 1024,
    compression: str = "zstd",
) -> Path:
    """Write a plain MCAP file (no metadata.yaml) with mcap_ros2's writer; return its path.

    Args:
        path: file to create.
        messages: written in the given order.
        chunk_size: bytes of records per chunk (small values give many chunks).
        compression: ``"zstd"``, ``"lz4"`` or ``"none"``.
    """
    store = typestore()
    comp = {
        "zstd": CompressionType.ZSTD,
        "lz4": CompressionType.LZ4,
        "none": CompressionType.NONE,
    }[compression]
    with path.open("wb") as f:
        writer = McapRos2Writer(f, chunk_size=chunk_size, compression=comp)
        schemas: dict[str, Any] = {}
        for m in messages:
            if m.msgtype not in schemas:
                text, _ = store.generate_msgdef(m.msgtype, ros_version=2)
                schemas[m.msgtype] = writer.register_msgdef(m.msgtype, text)
            writer.write_message(
                m.topic,
                schemas[m.msgtype],
                dict_message(m),
                log_time=m.log_time_ns,
                publish_time=m.log_time_ns,
            )
        writer.finish()
    return path


def write_unindexed_mcap(path: Path, messages: list[Sample]) -> Path:
    """A valid MCAP file as a streaming writer makes it: no chunks, no statistics, no index.

    Written with mcap's own writer; message bytes from rosbags' CDR serialiser.
    """
    store = typestore()
    with path.open("wb") as f:
        writer = McapWriter(f, use_chunking=False, use_statistics=False, index_types=IndexType.NONE)
        writer.start(profile="ros2", library="make_bags")
        channels: dict[str, int] = {}
        for m in messages:
            if m.topic not in channels:
                text, _ = store.generate_msgdef(m.msgtype, ros_version=2)
                sid = writer.register_schema(m.msgtype, "ros2msg", text.encode())
                channels[m.topic] = writer.register_channel(m.topic, "cdr", sid)
            raw = bytes(store.serialize_cdr(rosbags_message(store, m), m.msgtype))
            writer.add_message(channels[m.topic], m.log_time_ns, raw, m.log_time_ns)
        writer.finish()
    return path


def last_fields(sample: Sample) -> bytes:
    """The CDR bytes of a sample's two trailing float64 fields, which end its message record.

    In an uncompressed MCAP file a message record is complete exactly when these bytes are
    in the file (the values are unique), which gives an oracle for truncation tests that does
    not depend on any reader.
    """
    return struct.pack("<" + "d" * len(sample.values), *sample.values.values())[-16:]


def expected_record(sample: Sample) -> dict[str, Any]:
    """JSON form of a sample, as golden.json stores it."""
    return asdict(sample)


def main(out: Path = HERE) -> None:
    """Regenerate the golden corpus in ``out``."""
    msgs = samples(4)
    for name in ("golden_mcap", "golden_sqlite3"):
        shutil.rmtree(out / name, ignore_errors=True)
    write_rosbag2(out / "golden_mcap", "mcap", msgs)
    write_rosbag2(out / "golden_sqlite3", "sqlite3", msgs)
    db = sqlite3.connect(out / "golden_sqlite3" / "golden_sqlite3.db3")
    db.execute("PRAGMA page_size = 512")  # 4 kB pages by default: shrink the fixture
    db.execute("VACUUM")
    db.close()
    plain = write_plain_mcap(out / "golden_plain.mcap", msgs, chunk_size=300, compression="none")
    data = plain.read_bytes()
    # Cut in the middle of the data section: a recorder killed part-way.
    cut = len(data) // 2
    (out / "golden_truncated.mcap").write_bytes(data[:cut])
    ordered = sorted(msgs, key=lambda m: m.log_time_ns)
    kept = data[:cut]
    golden = {
        "topics": TOPIC_TYPES,
        "messages": [expected_record(m) for m in ordered],
        "truncated": {
            "at_byte": cut,
            # indices into "messages" of the records complete before the cut
            "recovered": [i for i, m in enumerate(ordered) if last_fields(m) in kept],
        },
    }
    (out / "golden.json").write_text(json.dumps(golden, indent=1) + "\n")
    sizes = {p.name: p.stat().st_size for p in sorted(out.rglob("golden*")) if p.is_file()}
    print(json.dumps(sizes, indent=1))


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
