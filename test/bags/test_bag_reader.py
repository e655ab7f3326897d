"""The bag reader: round trips per storage, the golden corpus, refusals, damage and fuzzing.

Fixture bags are written by the libraries' own writers (rosbags for rosbag2 MCAP/SQLite3,
mcap_ros2 for plain MCAP) through ``test/data/make_bags.py``, never by the package, so a
round trip checks the reader against an independent producer. Messages are written in
topic-major order, so log-time order across topics can only come from the reader. Every
read of a damaged bag runs under a timeout (a hang fails the test).
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import random
import re
import shutil
import signal
import sqlite3
import struct
import sys
import tempfile
import tracemalloc
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twotank_validation.bags import (
    BagCorruptError,
    BagEmptyError,
    BagError,
    BagFormatError,
    BagNotFoundError,
    TopicMissingError,
    TopicTypeError,
    expected_types,
    open_bag,
)
from twotank_validation.errors import TwotankError

DATA = Path(__file__).resolve().parents[1] / "data"


def _load_make_bags() -> Any:
    spec = importlib.util.spec_from_file_location("make_bags", DATA / "make_bags.py")
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["make_bags"] = module
    spec.loader.exec_module(module)
    return module


mb = _load_make_bags()
TOPICS = list(mb.TOPIC_TYPES)


# ------------------------------------------------------------------ helpers


class Hang(BaseException):  # BaseException: the reader must not catch it
    """A read took longer than the test allows."""


@contextlib.contextmanager
def deadline(seconds: float = 20.0) -> Iterator[None]:
    """Fail with Hang if the block runs longer than ``seconds`` (SIGALRM, main thread)."""

    def fire(signum: int, frame: Any) -> None:
        raise Hang(f"no result after {seconds} s")

    old = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def as_tuple(m: Any) -> tuple[Any, ...]:
    """(topic, type, log time, stamp ns, values) of a BagMessage."""
    st_ = m.msg.header.stamp
    values = tuple(float(getattr(m.msg, k)) for k in VALUE_FIELDS[m.msgtype])
    return (m.topic, m.msgtype, m.log_time_ns, st_.sec * 10**9 + st_.nanosec, values)


VALUE_FIELDS = {
    mb.FLOW_CMD_TYPE: ("hot", "cold"),
    mb.HEIGHT_TYPE: ("fluid_pressure", "variance"),
    mb.TEMPERATURE_TYPE: ("temperature", "variance"),
}


def expected_tuple(s: Any) -> tuple[Any, ...]:
    return (s.topic, s.msgtype, s.log_time_ns, s.stamp_ns, tuple(s.values.values()))


def read_all(path: Path, topics: list[str] | None = None) -> tuple[list[Any], BagError | None]:
    """Messages read (as tuples) and the BagError that ended the read, if any (with a deadline)."""
    got: list[Any] = []
    with deadline():
        try:
            with open_bag(path) as bag:
                for m in bag.messages(topics or list(bag.info.topics)):
                    got.append(as_tuple(m))
        except BagError as err:
            return got, err
    return got, None


def write(kind: str, path: Path, msgs: list[Any], **kw: Any) -> Path:
    """A bag of ``kind`` (mcap, sqlite3: rosbag2; plain: MCAP file) at ``path``."""
    if kind == "plain":
        return mb.write_plain_mcap(path.with_suffix(".mcap"), msgs, **kw)
    return mb.write_rosbag2(path, kind, msgs, **kw)


KINDS = ["mcap", "sqlite3", "plain"]


@pytest.fixture(scope="module")
def samples() -> list[Any]:
    return mb.samples(6)


# ------------------------------------------------------------------ round trips


@pytest.mark.parametrize("kind", KINDS)
def test_round_trip_exact_values_stamps_and_log_time_order(tmp_path, samples, kind):
    kw = {"chunk_size": 200} if kind == "plain" else {}  # many chunks overlapping in time
    path = write(kind, tmp_path / "bag", samples, **kw)
    with open_bag(path) as bag:
        info = bag.info
        got = [as_tuple(m) for m in bag.messages(TOPICS)]
    want = [expected_tuple(s) for s in sorted(samples, key=lambda s: s.log_time_ns)]
    assert got == want  # values, stamps and the interleaved log-time order, exactly
    assert info.storage == {"mcap": "mcap", "sqlite3": "sqlite3", "plain": "mcap-plain"}[kind]
    assert info.path == path
    assert info.topics == mb.TOPIC_TYPES
    assert info.message_counts == dict.fromkeys(TOPICS, 6)
    assert (info.start_ns, info.end_ns) == (want[0][2], want[-1][2])
    assert info.damage is None


@pytest.mark.parametrize("kind", KINDS)
def test_subset_of_topics_and_check_topics(tmp_path, samples, kind):
    path = write(kind, tmp_path / "bag", samples)
    with open_bag(path) as bag:
        bag.check_topics(expected_types())  # all present with the right types
        got = [as_tuple(m) for m in bag.messages(["height"])]
    want = [expected_tuple(s) for s in samples if s.topic == "height"]
    assert got == want


def test_expected_types_are_the_interface_types():
    from twotank_validation.online import streams as itf  # noqa: PLC0415

    assert expected_types() == {
        "flow_cmd": (itf.FLOW_CMD_TYPE,),
        "height": (itf.HEIGHT_TYPE,),
        "temperature": (itf.TEMPERATURE_TYPE,),
    }


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_storage_file_or_metadata_inside_a_bag_opens_the_bag(tmp_path, samples, storage):
    bag_dir = write(storage, tmp_path / "bag", samples)
    inner = next(p for p in bag_dir.iterdir() if p.suffix in (".mcap", ".db3"))
    for path in (inner, bag_dir / "metadata.yaml"):
        with open_bag(path) as bag:
            assert bag.info.path == bag_dir
            assert bag.info.storage == storage
            assert sum(1 for _ in bag.messages(TOPICS)) == len(samples)


def test_lone_db3_file_without_metadata(tmp_path, samples):
    bag_dir = write("sqlite3", tmp_path / "bag", samples)
    lone = tmp_path / "lone.db3"
    shutil.copy(bag_dir / "bag.db3", lone)
    got, err = read_all(lone)
    assert err is None
    assert got == [expected_tuple(s) for s in sorted(samples, key=lambda s: s.log_time_ns)]


def test_plain_mcap_without_chunks_or_index(tmp_path, samples):
    path = mb.write_unindexed_mcap(tmp_path / "stream.mcap", samples)  # topic-major order
    with open_bag(path) as bag:
        assert bag.info.storage == "mcap-plain"
        assert bag.info.damage is None  # a valid file: read by a scan, nothing damaged
        assert bag.info.message_counts == dict.fromkeys(TOPICS, 6)
    got, err = read_all(path)
    assert err is None
    assert got == [expected_tuple(s) for s in sorted(samples, key=lambda s: s.log_time_ns)]


def test_humble_bag_without_definitions_uses_the_package_types(tmp_path, samples):
    path = write("sqlite3", tmp_path / "bag", samples, definitions=False)
    db = sqlite3.connect(path / "bag.db3")
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    db.close()
    assert "message_definitions" not in tables  # the bag cannot define FlowCommand itself
    got, err = read_all(path)
    assert err is None
    assert got == [expected_tuple(s) for s in sorted(samples, key=lambda s: s.log_time_ns)]


def test_relative_topic_names_find_absolute_ones(tmp_path):
    topics = {f"/{t}": ty for t, ty in mb.TOPIC_TYPES.items()}
    msgs = mb.samples(3, topics=topics)
    path = write("mcap", tmp_path / "bag", msgs)
    with open_bag(path) as bag:
        assert bag.resolve_topic("height") == "/height"
        assert bag.resolve_topic("/height") == "/height"
        assert bag.resolve_topic("nothing") is None
        bag.check_topics(expected_types())
        got = {m.topic for m in bag.messages(["height", "temperature"])}
    assert got == {"height", "temperature"}  # reported under the requested names


# ------------------------------------------------------------------ golden corpus


def test_golden_corpus():
    golden = json.loads((DATA / "golden.json").read_text())
    want = [
        (m["topic"], m["msgtype"], m["log_time_ns"], m["stamp_ns"], tuple(m["values"].values()))
        for m in golden["messages"]
    ]
    for name, storage in [
        ("golden_mcap", "mcap"),
        ("golden_sqlite3", "sqlite3"),
        ("golden_plain.mcap", "mcap-plain"),
    ]:
        with open_bag(DATA / name) as bag:
            assert bag.info.storage == storage, name
            assert bag.info.topics == golden["topics"], name
            got = [as_tuple(m) for m in bag.messages(list(golden["topics"]))]
        assert got == want, name


def test_golden_truncated_file_yields_every_complete_record_then_raises():
    golden = json.loads((DATA / "golden.json").read_text())
    recovered = golden["truncated"]["recovered"]
    want = [
        (m["topic"], m["msgtype"], m["log_time_ns"], m["stamp_ns"], tuple(m["values"].values()))
        for i, m in enumerate(golden["messages"])
        if i in recovered
    ]
    got, err = read_all(DATA / "golden_truncated.mcap")
    assert got == want  # in log-time order although the file was written topic by topic
    assert isinstance(err, BagCorruptError)
    assert err.messages_read == len(want)
    assert err.last_good_ns == want[-1][2]
    assert "truncated at byte" in str(err)
    assert f"{len(want)} message(s) read" in str(err)


# ------------------------------------------------------------------ refusals


@pytest.mark.parametrize("kind", KINDS)
def test_empty_bag(tmp_path, kind):
    path = write(kind, tmp_path / "bag", [])
    with open_bag(path) as bag:
        # rosbag2 lists its connections; an empty plain MCAP has no channel at all
        assert bag.info.message_counts == ({} if kind == "plain" else dict.fromkeys(TOPICS, 0))
        assert bag.info.start_ns is None
        with pytest.raises(BagEmptyError, match="holds no messages"):
            bag.check_topics(expected_types())
        with pytest.raises(BagEmptyError):
            bag.messages(TOPICS)


@pytest.mark.parametrize("kind", KINDS)
def test_missing_topic_is_named_and_the_bag_topics_listed(tmp_path, kind):
    msgs = [s for s in mb.samples(2) if s.topic != "temperature"]
    path = write(kind, tmp_path / "bag", msgs)
    with open_bag(path) as bag:
        with pytest.raises(TopicMissingError) as info:
            bag.check_topics(expected_types())
        err = info.value
        assert err.missing == ("temperature",)
        assert set(err.available) == {"flow_cmd", "height"}
        assert "'temperature'" in str(err)
        assert "height (sensor_msgs/msg/FluidPressure, 2 messages)" in str(err)
        assert isinstance(err, KeyError)
        assert isinstance(err, TwotankError)
        with pytest.raises(TopicMissingError, match="temperature"):
            bag.messages(["height", "temperature"])


def test_recorded_topic_without_messages_counts_as_missing(tmp_path):
    msgs = [s for s in mb.samples(2) if s.topic != "temperature"]
    path = write("mcap", tmp_path / "bag", msgs, topics=dict(mb.TOPIC_TYPES))
    with open_bag(path) as bag:
        assert bag.info.message_counts["temperature"] == 0
        with pytest.raises(TopicMissingError, match="holds no readable message"):
            bag.check_topics(expected_types())
        assert list(bag.messages(["temperature"])) == []


@pytest.mark.parametrize("kind", KINDS)
def test_topic_with_unexpected_type(tmp_path, kind):
    topics = {"flow_cmd": mb.FLOW_CMD_TYPE, "height": mb.FLOAT64_TYPE}
    path = write(kind, tmp_path / "bag", mb.samples(2, topics=topics))
    with open_bag(path) as bag, pytest.raises(TopicTypeError) as info:
        bag.check_topics({"flow_cmd": mb.FLOW_CMD_TYPE, "height": (mb.HEIGHT_TYPE,)})
    err = info.value
    assert (err.topic, err.found, err.expected) == ("height", mb.FLOAT64_TYPE, (mb.HEIGHT_TYPE,))
    assert isinstance(err, TypeError)
    assert mb.FLOAT64_TYPE in str(err)
    assert mb.HEIGHT_TYPE in str(err)


def test_missing_path(tmp_path):
    with pytest.raises(BagNotFoundError, match="does not exist") as info:
        open_bag(tmp_path / "nope")
    assert isinstance(info.value, FileNotFoundError)
    assert str(tmp_path / "nope") in str(info.value)


def test_directory_that_is_not_a_bag(tmp_path, samples):
    with pytest.raises(BagFormatError, match=r"no metadata\.yaml"):
        open_bag(tmp_path)
    mb.write_plain_mcap(tmp_path / "x.mcap", samples)
    with pytest.raises(BagFormatError, match=r"x\.mcap: open such a file directly"):
        open_bag(tmp_path)


def test_file_that_is_not_a_bag(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("hello")
    with pytest.raises(BagFormatError, match="neither MCAP nor SQLite3"):
        open_bag(path)


@pytest.mark.parametrize(
    "text",
    ["{unclosed: [", "just a string", "rosbag2_bagfile_information: {storage_identifier: lmdb}"],
)
def test_unreadable_metadata(tmp_path, samples, text):
    path = write("mcap", tmp_path / "bag", samples)
    (path / "metadata.yaml").write_text(text)
    with pytest.raises(BagFormatError, match="metadata") as info:
        open_bag(path)
    assert "ros2 bag reindex" in str(info.value)


def test_metadata_listing_a_missing_file(tmp_path, samples):
    path = write("sqlite3", tmp_path / "bag", samples)
    (path / "bag.db3").unlink()
    with pytest.raises(BagFormatError, match=r"bag\.db3, which is not in the directory"):
        open_bag(path)


def test_closed_reader_refuses(tmp_path, samples):
    path = write("mcap", tmp_path / "bag", samples)
    bag = open_bag(path)
    stream = bag.messages(TOPICS)
    next(stream)
    bag.close()
    bag.close()  # idempotent
    with pytest.raises(BagError, match="closed"):
        next(stream)
    with pytest.raises(BagError, match="closed"):
        bag.messages(TOPICS)


# ------------------------------------------------------------------ damage


def file_of(path: Path) -> Path:
    return path if path.is_file() else next(p for p in path.iterdir() if p.name != "metadata.yaml")


@pytest.mark.parametrize(
    ("kind", "compression"),
    [("mcap", None), ("plain", "none"), ("plain", "zstd"), ("plain", "lz4")],
)
def test_truncated_mcap_yields_the_messages_before_the_cut(tmp_path, kind, compression):
    msgs = sorted(mb.samples(40), key=lambda s: s.log_time_ns)
    kw = {"chunk_size": 1500, "compression": compression} if kind == "plain" else {}
    path = write(kind, tmp_path / "bag", msgs, **kw)
    victim = file_of(path)
    data = victim.read_bytes()
    want = [expected_tuple(s) for s in msgs]
    rng = random.Random(7)
    cuts = sorted(
        {0, 1, 7, 8, 9, 20, len(data) - 1, *(rng.randrange(len(data)) for _ in range(14))}
    )
    recovered_some = False
    for cut in cuts:
        victim.write_bytes(data[:cut])
        got, err = read_all(path)
        if err is None:  # only the summary was lost: the scan read the whole data section
            assert got == want, cut
            with open_bag(path) as bag:
                assert bag.info.damage is not None
            continue
        assert isinstance(err, BagCorruptError | BagFormatError), (cut, err)
        # what was read is exactly the first messages, in order, with exact values
        assert got == want[: len(got)], cut
        if isinstance(err, BagCorruptError):
            assert err.messages_read == len(got)
            assert err.last_good_ns == (got[-1][2] if got else None)
        if compression in (None, "none"):  # uncompressed: every complete record is recovered
            assert len(got) == sum(mb.last_fields(s) in data[:cut] for s in msgs), cut
        recovered_some |= 0 < len(got) < len(want)
    assert recovered_some


def test_truncated_mid_chunk_of_a_rosbags_mcap(tmp_path):
    """rosbags writes one uncompressed chunk (< 1 MiB): a cut inside it keeps its head."""
    msgs = sorted(mb.samples(40), key=lambda s: s.log_time_ns)
    path = write("mcap", tmp_path / "bag", msgs)
    victim = file_of(path)
    data = victim.read_bytes()
    cut = data.index(mb.last_fields(msgs[70])) + 16  # just after message 70's record
    victim.write_bytes(data[:cut])
    with open_bag(path) as bag:
        assert "truncated at byte" in (bag.info.damage or "")
        assert bag.info.message_counts == {"flow_cmd": 24, "height": 24, "temperature": 23}
    got, err = read_all(path)
    assert got == [expected_tuple(s) for s in msgs[:71]]
    assert isinstance(err, BagCorruptError)
    assert "truncated at byte" in str(err)
    assert "71 message(s) read" in str(err)
    assert "the messages before it were delivered" in str(err)


def test_truncated_plain_mcap_keeps_log_time_order_across_overlapping_chunks(tmp_path):
    msgs = mb.samples(30)  # topic-major: each chunk holds one topic, chunks overlap in time
    path = write("plain", tmp_path / "bag", msgs, chunk_size=400, compression="none")
    data = path.read_bytes()
    cut = data.index(mb.last_fields(msgs[75])) + 20  # inside temperature's chunks
    path.write_bytes(data[:cut])
    got, err = read_all(path)
    assert isinstance(err, BagCorruptError)
    kept = [s for s in msgs if mb.last_fields(s) in data[:cut]]
    assert len(kept) == 76
    assert got == [expected_tuple(s) for s in sorted(kept, key=lambda s: s.log_time_ns)]
    assert {g[0] for g in got} == set(TOPICS)


def test_truncated_sqlite3_recovers_rows_before_the_damage(tmp_path):
    msgs = sorted(mb.samples(120), key=lambda s: s.log_time_ns)
    path = write("sqlite3", tmp_path / "bag", msgs)
    victim = file_of(path)
    data = victim.read_bytes()
    want = [expected_tuple(s) for s in msgs]
    best = 0
    for frac in (0.0, 0.05, 0.3, 0.6, 0.75, 0.9, 0.99):
        cut = int(len(data) * frac)
        victim.write_bytes(data[:cut])
        got, err = read_all(path)
        assert err is None or isinstance(err, BagCorruptError | BagFormatError), (cut, err)
        assert all(g in want for g in got)  # exact values
        assert [g[2] for g in got] == sorted(g[2] for g in got)  # in log-time order
        best = max(best, len(got))
    assert best >= len(want) // 2  # the row scan reaches past the damaged index


def test_corrupt_db3_pages(tmp_path):
    msgs = sorted(mb.samples(60), key=lambda s: s.log_time_ns)
    path = write("sqlite3", tmp_path / "bag", msgs)
    victim = file_of(path)
    data = bytearray(victim.read_bytes())
    want = {expected_tuple(s) for s in msgs}
    for page in range(1, len(data) // 4096):
        damaged = bytearray(data)
        damaged[page * 4096 : page * 4096 + 64] = b"\xa5" * 64  # a page header destroyed
        victim.write_bytes(bytes(damaged))
        got, err = read_all(path)
        assert err is None or isinstance(err, BagCorruptError | BagFormatError), (page, err)
        assert set(got) <= want


def test_inconsistent_mcap_statistics_fall_back_to_the_scan(tmp_path, samples):
    """Statistics claiming no message must not make a full file look empty."""
    path = write("plain", tmp_path / "bag", samples, chunk_size=300)
    data = bytearray(path.read_bytes())
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 20)  # footer
    at = summary_start
    while data[at] != 0x0B:  # walk the summary records to the statistics record
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    struct.pack_into("<Q", data, at + 9, 0)  # its message_count
    path.write_bytes(bytes(data))
    with open_bag(path) as bag:
        assert "inconsistent" in (bag.info.damage or "")
        assert bag.info.message_counts == dict.fromkeys(TOPICS, 6)
    got, err = read_all(path)
    assert err is None
    assert got == [expected_tuple(s) for s in sorted(samples, key=lambda s: s.log_time_ns)]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_metadata_counting_no_message_does_not_hide_the_data(tmp_path, samples, storage):
    path = write(storage, tmp_path / "bag", samples)
    meta = path / "metadata.yaml"
    meta.write_text(re.sub(r"message_count: \d+", "message_count: 0", meta.read_text()))
    with open_bag(path) as bag:
        assert "counts no message" in (bag.info.damage or "")
    got, err = read_all(path)
    assert err is None
    assert len(got) == len(samples)


def test_crc_mismatch_in_a_chunk_stops_the_read(tmp_path, samples):
    path = write(
        "plain",
        tmp_path / "bag",
        sorted(samples, key=lambda s: s.log_time_ns),
        chunk_size=300,
        compression="none",
    )
    data = bytearray(path.read_bytes())
    at = data.index(mb.last_fields(sorted(samples, key=lambda s: s.log_time_ns)[10]))
    data[at] ^= 0x01  # a value bit flipped inside a CRC-protected chunk
    path.write_bytes(bytes(data))
    got, err = read_all(path)
    assert isinstance(err, BagCorruptError)
    assert 0 < len(got) < len(samples)
    assert "crc" in str(err).lower()


# ------------------------------------------------------------------ fuzzing


@pytest.fixture(scope="module")
def fuzz_fixtures(tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    """name -> (bag path, file in it to damage)."""
    root = tmp_path_factory.mktemp("fuzz")
    msgs = sorted(mb.samples(8), key=lambda s: s.log_time_ns)
    out = {}
    for kind in ("mcap", "sqlite3"):
        bag = write(kind, root / f"bag_{kind}", msgs)
        out[kind] = (bag, file_of(bag))
    for comp in ("none", "zstd"):
        bag = write("plain", root / f"plain_{comp}", msgs, chunk_size=500, compression=comp)
        out[f"plain_{comp}"] = (bag, bag)
    return out


@settings(max_examples=100)  # cheap (about 30 ms each); derandomized by the ci profile
@given(
    name=st.sampled_from(["mcap", "sqlite3", "plain_none", "plain_zstd"]),
    flips=st.lists(
        st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 7)), min_size=1, max_size=6
    ),
)
def test_flipped_bits_give_only_bag_errors(fuzz_fixtures, name, flips):
    src, victim = fuzz_fixtures[name]
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / src.name
        if src.is_dir():
            shutil.copytree(src, bag)
            target = bag / victim.name
        else:
            shutil.copy(src, bag)
            target = bag
        data = bytearray(target.read_bytes())
        for where, bit in flips:
            data[int(where * len(data))] ^= 1 << bit
        target.write_bytes(bytes(data))
        with deadline():
            try:
                with open_bag(bag) as reader:
                    with contextlib.suppress(TopicMissingError, TopicTypeError, BagEmptyError):
                        reader.check_topics(expected_types())
                    for _ in reader.messages(list(reader.info.topics)):
                        pass
            except BagError:
                pass  # any other exception (or Hang) fails the test


# ------------------------------------------------------------------ streaming


def peak_bytes_while_reading(path: Path) -> tuple[int, int]:
    """(messages read, peak traced memory above the open reader's) over a full read."""
    n = 0
    tracemalloc.start()
    try:
        with open_bag(path) as bag:
            base = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            with contextlib.suppress(BagCorruptError):
                for _ in bag.messages(TOPICS):
                    n += 1
            peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    return n, peak


@pytest.mark.parametrize("kind", ["plain", "plain-truncated", "sqlite3", "sqlite3-truncated"])
def test_memory_does_not_grow_with_the_length_of_the_bag(tmp_path, kind):
    peaks = []
    for n in (400, 1600):
        msgs = sorted(mb.samples(n), key=lambda s: s.log_time_ns)
        if kind.startswith("sqlite3"):
            path = write("sqlite3", tmp_path / f"bag{n}", msgs)
            if kind == "sqlite3-truncated":  # read row by row, not through rosbags
                victim = file_of(path)
                data = victim.read_bytes()
                victim.write_bytes(data[: len(data) * 95 // 100])
        else:
            path = write("plain", tmp_path / f"bag{n}", msgs, chunk_size=16384)
            if kind == "plain-truncated":  # read by the scan, not through the index
                data = path.read_bytes()
                path.write_bytes(data[: len(data) * 95 // 100])
        read, peak = peak_bytes_while_reading(path)
        assert read > 0.9 * 3 * n
        peaks.append(peak)
    # four times the messages, about the same peak (a reader holding the bag would need 4x)
    assert peaks[1] < 1.5 * peaks[0] + 64_000, peaks
