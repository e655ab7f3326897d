"""The columnar reader and batched decoder against the per-message path they replace.

Reference everywhere: rosbags' generic deserialiser on each message, as the reader's
:meth:`~twotank_validation.bags.reader.BagReader.messages` delivers them (the bag's own
order, errors included). The batched path (:meth:`BagReader.field_batches`: indexed MCAP
chunks read through their message index, the three interface layouts decoded with numpy)
must give the same messages, stamps and values bit for bit, and end with the same error
after the same messages on a damaged bag.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import math
import random
import re
import struct
from pathlib import Path
from typing import Any

import make_bags as mb
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from report_checks import assert_same_reports
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

from twotank_validation import bags, replay
from twotank_validation.bags import columnar, decode
from twotank_validation.core.model import load_model
from twotank_validation.online import MonitorConfig
from twotank_validation.online import streams as itf
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.online.interface_text import interface_map_from_text
from twotank_validation.replay import feed as replay_feed
from twotank_validation.sim import scenario as sc
from twotank_validation.sim.faults import parse_fault

REPO = Path(__file__).resolve().parents[2]

STORE = mb.typestore()
NS = 1_000_000_000
TYPES = {
    mb.FLOW_CMD_TYPE: ("hot", "cold"),
    mb.HEIGHT_TYPE: ("fluid_pressure", "variance"),
    mb.TEMPERATURE_TYPE: ("temperature", "variance"),
}
TOPICS = list(mb.TOPIC_TYPES)
FIELDS = {
    "flow_cmd": ("hot", "cold"),
    "height": ("fluid_pressure",),
    "temperature": ("temperature",),
}
"""The float fields the two-tank preset map reads from each of the rig's topics."""


def message(msgtype: str, sec: int, nanosec: int, a: float, b: float, frame: str) -> Any:
    time_cls = STORE.types["builtin_interfaces/msg/Time"]
    header = STORE.types["std_msgs/msg/Header"](
        stamp=time_cls(sec=sec, nanosec=nanosec), frame_id=frame
    )
    f1, f2 = TYPES[msgtype]
    return STORE.types[msgtype](header=header, **{f1: a, f2: b})


def cdr(msg: Any, msgtype: str, little: bool = True) -> bytes:
    return bytes(STORE.serialize_cdr(msg, msgtype, little_endian=little))


def bits(values: list[float]) -> bytes:
    return struct.pack(f"<{len(values)}d", *values)


# ------------------------------------------------------------------ the decoder alone


def columns_of(datas: list[bytes], msgtypes: list[str]) -> columnar._Columns:
    """Messages as the reader's columns: one channel per type, all in one buffer."""
    kinds = sorted(set(msgtypes))
    channels = [
        (
            t,
            t,
            decode._Codec(
                lambda data, t=t: STORE.deserialize_cdr(data, t), t, lambda: STORE.fielddefs
            ),
        )
        for t in kinds
    ]
    sizes = np.array([len(d) for d in datas], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    return columnar._Columns(
        channels,
        np.array([kinds.index(t) for t in msgtypes], dtype=np.intp),
        np.arange(len(datas), dtype=np.int64),
        np.zeros(len(datas), dtype=np.intp),
        starts,
        sizes,
        [np.frombuffer(b"".join(datas), dtype=np.uint8)],
    )


floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([0.0, -0.0, 5e-324, math.nan, -math.nan, math.inf, -math.inf]),
)
frames = st.one_of(
    st.sampled_from(["", "rig", "tank\u00e9", "\u6c34\u69fd", "a" * 7, "b" * 8]),
    st.text(max_size=20),
)
rows = st.tuples(
    st.sampled_from(sorted(TYPES)),
    st.integers(-(2**31), 2**31 - 1),
    st.integers(0, 2**32 - 1),
    floats,
    floats,
    frames,
    st.booleans(),
)


@settings(max_examples=200, deadline=None)
@given(drawn=st.lists(rows, min_size=1, max_size=40), repeat=st.integers(1, 5))
def test_batched_decoder_equals_rosbags_on_drawn_messages(drawn, repeat) -> None:
    """Drawn messages (each repeated with new values, so groups form), both byte orders:
    every stamp and field bit for bit as rosbags reads it."""
    datas, types, want = [], [], []
    for k, (msgtype, sec, nsec, a0, b, frame, little) in enumerate(drawn * repeat):
        a = a0 if k < len(drawn) or not math.isfinite(a0) else float(k) * a0
        raw = cdr(message(msgtype, sec, nsec, a, b, frame), msgtype, little)
        ref = STORE.deserialize_cdr(raw, msgtype)
        stamp = int(ref.header.stamp.sec) * NS + int(ref.header.stamp.nanosec)
        want.append((stamp, [float(getattr(ref, f)) for f in TYPES[msgtype]]))
        datas.append(raw)
        types.append(msgtype)
    cols = columns_of(datas, types)
    spec = {t: TYPES[t] for t in TYPES}
    out, failure = decode._decode_columns(cols, dict.fromkeys(TYPES, 0), spec, 2, ("all",))
    assert failure is None
    assert len(out) == len(want)
    assert out.stamp_ns.tolist() == [s for s, _ in want]
    for i, (_, vals) in enumerate(want):
        assert bits(out.values[i].tolist()) == bits(vals)
    # a group (one type, one size) with at most 8 distinct headers is read in bulk whole
    heads: dict[tuple[str, int], set[tuple[str, bool]]] = {}
    for d, (msgtype, *_, frame, little) in zip(datas, drawn * repeat, strict=True):
        heads.setdefault((msgtype, len(d)), set()).add((frame, little))
    if repeat >= 2 and all(len(h) <= 8 for h in heads.values()):
        assert out.bulk_decoded == len(want)


def test_a_damaged_message_ends_the_batch_where_rosbags_fails() -> None:
    """A broken frame_id terminator or length in message 30: bulk up to it, then the error."""
    msgtype = mb.HEIGHT_TYPE
    datas = [cdr(message(msgtype, k, 7, 1000.0 + k, 0.5, "rig"), msgtype) for k in range(50)]
    for edit in ("nul", "len"):
        broken = list(datas)
        bad = bytearray(broken[30])
        if edit == "nul":
            bad[15 + int.from_bytes(bad[12:16], "little")] = 65
        else:
            bad[12] ^= 0x40
        broken[30] = bytes(bad)
        with pytest.raises(Exception):  # noqa: B017, PT011 - whatever rosbags raises
            STORE.deserialize_cdr(broken[30], msgtype)
        out, failure = decode._decode_columns(
            columns_of(broken, [msgtype] * 50),
            {msgtype: 0},
            {msgtype: TYPES[msgtype]},
            2,
            ("t",),
        )
        assert failure is not None
        assert len(out) == 30
        assert out.stamp_ns.tolist() == [k * NS + 7 for k in range(30)]


# ------------------------------------------------------------------ whole bags


def via_messages(path: Path, topics: list[str], fields: dict[str, tuple[str, ...]]):
    """The reference: messages() (rosbags' deserialiser per message) and getattr."""
    got, err = [], None
    try:
        with bags.open_bag(path) as bag:
            for m in bag.messages(topics):
                st_ = m.msg.header.stamp
                vals = [float(getattr(m.msg, f)) for f in fields[m.topic]]
                got.append((m.topic, m.log_time_ns, int(st_.sec) * NS + int(st_.nanosec), vals))
    except bags.BagError as e:
        err = e
    return got, err


def via_batches(path: Path, topics: list[str], fields: dict[str, tuple[str, ...]], size: int):
    got, err, bulk = [], None, 0
    try:
        with bags.open_bag(path) as bag:
            for b in bag.field_batches(topics, fields, size=size):
                bulk += b.bulk_decoded
                for i in range(len(b)):
                    t = b.topics[int(b.topic[i])]
                    vals = b.values[i, : len(fields[t])].tolist()
                    got.append((t, int(b.log_time_ns[i]), int(b.stamp_ns[i]), vals))
    except bags.BagError as e:
        err = e
    return got, err, bulk


def assert_same(
    path: Path, topics: list[str] | None = None, size: int = 4096
) -> tuple[int, int, bags.BagError | None]:
    """field_batches == messages(): messages, stamps, values (bits), then the same error."""
    topics = TOPICS if topics is None else topics
    fields = {t: FIELDS.get(t, ()) for t in topics}
    want, werr = via_messages(path, topics, fields)
    got, gerr, bulk = via_batches(path, topics, fields, size)
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        assert a[:3] == b[:3]
        assert bits(a[3]) == bits(b[3])
    assert type(gerr) is type(werr)
    if werr is not None:
        assert str(gerr) == str(werr)
        if isinstance(werr, bags.BagCorruptError):
            assert (gerr.messages_read, gerr.last_good_ns) == (
                werr.messages_read,
                werr.last_good_ns,
            )
    return len(got), bulk, werr


def chunk_reader(path: Path, topics: list[str] = TOPICS) -> columnar._McapColumns:
    """Read the bag through the chunk reader to its end; the reader, to ask how it went."""
    with bags.open_bag(path) as bag:
        names = frozenset(bag.resolve_topic(t) for t in topics)
        it = bag._backend.iter_columns(names, [])
        assert isinstance(it, columnar._McapColumns)
        for _ in it:
            pass
    return it


def write_bag(
    path: Path,
    events: list[tuple[str, int, bytes]],
    compression: CompressionMode | None = None,
) -> Path:
    """A rosbag2 MCAP bag of raw (topic, log time, CDR) events, in the given order."""
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compression is not None:
        writer.set_compression(compression, CompressionFormat.ZSTD)
    with writer:
        conns = {
            t: writer.add_connection(t, ty, typestore=STORE) for t, ty in mb.TOPIC_TYPES.items()
        }
        for topic, t, raw in events:
            writer.write(conns[topic], t, raw)
    return path


def scenario_events(n: int, jitter_s: float = 0.0, seed: int = 0) -> list[tuple[str, int, bytes]]:
    """n samples of the three topics (long frame_ids: about 1,000 samples a 1 MiB chunk; odd
    frame_ids and values now and then), log times jittered by up to ``jitter_s`` so chunks
    overlap in time when it is large."""
    rng = random.Random(seed)
    out = []
    for k in range(n):
        t = mb.T0_NS + k * 100_000_000
        for i, (topic, msgtype) in enumerate(mb.TOPIC_TYPES.items()):
            frame = "rig_" + "r" * 300 if k % 17 else "\u00e9tage_" + "x" * (k % 5)
            a = [math.nan, -0.0, math.inf][k % 3] if k % 29 == 0 else 1000.0 + k
            msg = message(msgtype, t // NS, t % NS, a, 0.25, frame)
            log = t + i + int(rng.uniform(-jitter_s, jitter_s) * NS)
            out.append((topic, log, cdr(msg, msgtype, little=k % 31 != 7)))
    return out


@pytest.mark.parametrize(
    ("compression", "jitter"),
    [(None, 0.0), (CompressionMode.STORAGE, 0.0), (None, 400.0), (CompressionMode.MESSAGE, 0.0)],
)
def test_multi_chunk_bags_read_in_bulk_equal_messages(tmp_path, compression, jitter) -> None:
    """Bags of several 1 MiB chunks (plain, zstd chunks, log times jumbled across chunks,
    zstd messages): the same stream as messages(), and the chunk reader did it."""
    n = 3000
    path = write_bag(tmp_path / "bag", scenario_events(n, jitter), compression)
    count, bulk, err = assert_same(path)
    assert err is None
    assert count == 3 * n
    # every layout here is a fixed one; a lone message of its size in a batch goes generic
    assert bulk > 0.99 * count
    if compression is CompressionMode.MESSAGE:
        with bags.open_bag(path) as bag:
            names = frozenset(TOPICS)
            assert not isinstance(bag._backend.iter_columns(names, []), columnar._McapColumns)
        return
    reader = chunk_reader(path)
    assert reader.fell_back is None
    assert reader.chunks_read >= 3
    for size in (1000, 7):  # batches end anywhere
        assert assert_same(path, size=size)[0] == count
    assert assert_same(path, topics=["height"])[0] == n


@settings(max_examples=25, deadline=None)
@given(drawn=st.lists(rows, min_size=1, max_size=30), repeat=st.integers(1, 4))
def test_drawn_messages_in_a_bag_read_the_same_in_bulk(tmp_path_factory, drawn, repeat) -> None:
    """Drawn messages (both byte orders) written to a bag in turn on the three topics."""
    topic_of = {ty: t for t, ty in mb.TOPIC_TYPES.items()}
    events = []
    for k, (msgtype, sec, nsec, a, b, frame, little) in enumerate(drawn * repeat):
        raw = cdr(message(msgtype, sec, nsec, a, b, frame), msgtype, little)
        events.append((topic_of[msgtype], mb.T0_NS + k * 1000, raw))
    path = write_bag(tmp_path_factory.mktemp("drawn") / "bag", events)
    topics = sorted({e[0] for e in events})
    count, _, err = assert_same(path, topics=topics, size=16)
    assert err is None
    assert count == len(events)


def scenarios() -> list[str]:
    return sorted(p.stem for p in (Path(sc.__file__).parent / "scenarios").glob("*.yaml"))


@pytest.mark.parametrize("name", scenarios())
def test_every_shipped_scenario_reads_the_same_in_bulk(tmp_path, name) -> None:
    """Each scenario's first 1,200 samples, its faults moved to start at sample 600: what
    the simulator writes, read in bulk."""
    scen = sc.load_scenario(name)
    faults = tuple(re.sub(r"@[0-9.]+", f"@{600 * scen.ts_s:g}", f) for f in scen.faults)
    scen = dataclasses.replace(scen, duration_s=1200 * scen.ts_s, faults=faults)
    assert all(parse_fault(f).onset_s < scen.duration_s for f in scen.faults)
    path = bags.write_scenario_bag(scen, tmp_path / name)
    count, bulk, err = assert_same(path)
    assert err is None
    assert count == 3 * scen.n_samples
    assert bulk == count
    assert chunk_reader(path).fell_back is None


# ------------------------------------------------------------------ damaged bags


def _fuzz_module() -> Any:
    spec = importlib.util.spec_from_file_location("fuzz_bags", REPO / "bench" / "fuzz_bags.py")
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


FUZZ = _fuzz_module()


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory) -> dict[str, tuple[Path, str | None]]:
    return FUZZ.build_fixtures(tmp_path_factory.mktemp("fixtures"))


def test_fuzzed_bags_read_the_same_in_bulk(fixtures, tmp_path) -> None:
    """The fuzzer's damaged bags (every storage; cut, flipped, noise, zeros, deleted
    bytes): the same messages before the damage, and the same error."""
    outcomes: dict[str, int] = {}
    for index in range(120):
        path, _ = FUZZ.make_case(fixtures, tmp_path / "case", 7, index)
        try:
            _, _, err = assert_same(path, size=5)
        except bags.BagError as e:  # refused at open: the same for both
            err = e
        outcomes[type(err).__name__] = outcomes.get(type(err).__name__, 0) + 1
    assert outcomes.get("NoneType", 0) > 5
    assert outcomes.get("BagCorruptError", 0) > 5


@pytest.mark.parametrize("seed", range(6))
def test_damaged_multi_chunk_bags_stop_where_rosbags_stops(tmp_path, seed) -> None:
    """A bag of several chunks damaged inside one (cut, flipped or zeroed bytes): the chunk
    reader delivers what rosbags delivers before the damage and then its error."""
    src = write_bag(tmp_path / "src", scenario_events(4000, 0.0 if seed % 2 else 200.0, seed))
    data_file = next(src.glob("*.mcap"))
    raw = data_file.read_bytes()
    rng = random.Random(seed)
    damaged = bytearray(raw)
    at = rng.randrange(len(raw) // 4, len(raw) * 3 // 4)
    kind = ["cut", "flip", "zero"][seed % 3]
    if kind == "cut":
        damaged = damaged[:at]
    elif kind == "flip":
        for k in range(4):
            damaged[at + 97 * k] ^= 1 << rng.randrange(8)
    else:
        damaged[at : at + 64] = bytes(64)
    data_file.write_bytes(bytes(damaged))
    with contextlib.suppress(bags.BagError):  # refused at open: the same for both
        assert_same(src, size=1000)


def chunk_infos(path: Path) -> list[Any]:
    """rosbags' ChunkInfo of each chunk of the bag's one MCAP file, in file order."""
    with bags.open_bag(path) as bag:
        storage = bag._backend._reader.readers[0].storage.storages[0]
        return sorted(storage.chunks, key=lambda c: c.chunk_start_offset)


@pytest.mark.parametrize("damage", ["record length", "message index", "compressed data"])
def test_a_chunk_the_index_cannot_vouch_for_is_read_as_rosbags_reads_it(tmp_path, damage):
    """Damage in the second chunk that the chunk reader must notice: a record length (its
    index no longer tiles the records: rosbags' walk fails there), the chunk's message index
    (the records are walked one by one instead: all still read), the zstd data (rosbags
    fails to decompress). Same messages and error as messages() in each case."""
    compression = CompressionMode.STORAGE if damage == "compressed data" else None
    path = write_bag(tmp_path / "bag", scenario_events(3000), compression)
    chunks = chunk_infos(path)
    assert len(chunks) >= 3
    second = chunks[1]
    data_file = next(path.glob("*.mcap"))
    raw = bytearray(data_file.read_bytes())
    if damage == "record length":
        body = second.chunk_start_offset + 9 + 40 + len(second.compression)
        raw[body + 5] ^= 0x10  # the length of the chunk's first record
    elif damage == "message index":
        at = second.chunk_start_offset + second.chunk_length
        raw[at : at + second.message_index_length] = bytes(second.message_index_length)
    else:
        body = second.chunk_start_offset + 9 + 40 + len(second.compression)
        raw[body + second.compressed_size // 2] ^= 0xFF
    data_file.write_bytes(bytes(raw))
    count, bulk, err = assert_same(path, size=500)
    reader = chunk_reader_lenient(path)
    if damage == "message index":
        assert err is None
        assert count == 9000
        assert reader.fell_back is None
    else:
        assert isinstance(err, bags.BagCorruptError)
        assert 0 < count < 9000
        assert reader.fell_back is not None
    assert bulk > 0.99 * count


def chunk_reader_lenient(path: Path) -> columnar._McapColumns:
    """As chunk_reader, for a bag whose reading ends in an error."""
    with bags.open_bag(path) as bag:
        it = bag._backend.iter_columns(frozenset(TOPICS), [])
        assert isinstance(it, columnar._McapColumns)
        with contextlib.suppress(Exception):
            for _ in it:
                pass
    return it


# ------------------------------------------------------------------ replay through a map

FAST = MonitorConfig(ts_s=0.8, period_samples=256)


def replay_both(path: Path, imap: InterfaceMap) -> tuple[replay.ReplayResult, replay.ReplayResult]:
    """The replay through ``imap`` in bulk, and through the per-message mapped path."""
    cfg = replay.ReplayConfig(monitor=FAST, interface=imap)
    models = [load_model("A"), load_model("B")]
    bulk = replay.replay_bag(path, models, cfg)
    replay_feed._BULK = False
    try:
        per_message = replay.replay_bag(path, models, cfg)
    finally:
        replay_feed._BULK = True
    return bulk, per_message


def assert_same_result(a: replay.ReplayResult, b: replay.ReplayResult) -> None:
    assert len(a.reports) == len(b.reports)
    assert_same_reports(a.reports, b.reports)
    assert (a.messages, a.complete, a.problems, a.counters) == (
        b.messages,
        b.complete,
        b.problems,
        b.counters,
    )


def mapped_bag(path: Path, cut: float | None = None) -> Path:
    """The nominal scenario at 0.8 s with a few bad samples, optionally cut short."""
    stamps, u, y = sc.simulate_scenario(
        dataclasses.replace(
            sc.load_scenario("nominal"), ts_s=0.8, period_samples=256, duration_s=5 * 204.8
        )
    )
    units = itf.RigUnits()
    with bags.BagWriter(path, "mcap") as bag:
        for topic, msgtype in mb.TOPIC_TYPES.items():
            bag.add_topic(topic, msgtype)
        for k, t in enumerate(stamps.tolist()):
            if 500 <= k < 505:
                continue
            level = math.nan if k == 700 else y[k, 0]
            bag.write("flow_cmd", t, bags.flow_command(t, *u[k]))
            bag.write("height", t + 1, bags.fluid_pressure(t, level, units))
            bag.write("temperature", t + 2, bags.temperature_msg(t, y[k, 1], units))
    if cut is not None:
        data = next(path.glob("*.mcap"))
        raw = data.read_bytes()
        data.write_bytes(raw[: int(len(raw) * cut)])
    return path


MAPS = {
    "shipped": None,
    "receive stamps, other units": (
        [
            "hot=flow_cmd:twotank_validation_msgs/msg/FlowCommand:hot,stamp=receive",
            "cold=flow_cmd:twotank_validation_msgs/msg/FlowCommand:cold,offset=0,stamp=receive",
        ],
        [
            "height=height:sensor_msgs/msg/FluidPressure:fluid_pressure,scale=9806.65",
            "temperature=temperature:sensor_msgs/msg/Temperature:temperature,offset=15,scale=50",
        ],
    ),
}


@pytest.mark.parametrize("name", sorted(MAPS))
@pytest.mark.parametrize("cut", [None, 0.6])
def test_replay_through_a_map_in_bulk_equals_the_per_message_mapped_replay(
    tmp_path, name, cut
) -> None:
    """Sources on plain float64 fields of the interface types are read in bulk: the same
    reports, counters, problems and message count as reading them message by message."""
    texts = MAPS[name]
    imap = itf.two_tank_map() if texts is None else interface_map_from_text(*texts)
    path = mapped_bag(tmp_path / "bag", cut)
    with bags.open_bag(path) as bag:
        assert bag.float_fields("height") == ("fluid_pressure", "variance")
        assert bag.float_fields("flow_cmd") == ("hot", "cold")
        topics = imap.topics()
        assert replay_feed._bulk_fields(bag, list(topics), topics) is not None  # bulk taken
    bulk, per_message = replay_both(path, imap)
    assert_same_result(bulk, per_message)
    assert sum(r.judged for r in bulk.reports) >= (2 if cut else 4)
    assert bulk.complete is (cut is None)


def test_a_map_reading_a_header_field_goes_message_by_message(tmp_path) -> None:
    """A source on ``header.stamp.sec`` is no plain float64 field: the per-message path."""
    texts = MAPS["receive stamps, other units"]
    odd = (
        texts[0],
        [texts[1][0], "temperature=temperature:sensor_msgs/msg/Temperature:header.stamp.sec"],
    )
    path = mapped_bag(tmp_path / "bag")
    with bags.open_bag(path) as bag:
        topics = interface_map_from_text(*odd).topics()
        assert replay_feed._bulk_fields(bag, list(topics), topics) is None
        topics = interface_map_from_text(*texts).topics()
        assert replay_feed._bulk_fields(bag, list(topics), topics) == {
            "flow_cmd": ("hot", "cold"),
            "height": ("fluid_pressure",),
            "temperature": ("temperature",),
        }
