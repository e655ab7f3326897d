"""The reader's bulk decoding (field_batches) against rosbags' own deserialiser, and the fast
replay against the per-message replay it replaced.

The bulk decoder reads the fixed layout (header + float64 fields) of the validator's three
input types with numpy. It must give exactly what the generic deserialiser gives on the same
bytes, refuse (leave to the generic path) everything else, and the replay built on it must
report exactly what the per-message replay (reader.messages -> extractors -> feed) reports.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import struct
from pathlib import Path

import make_bags as mb
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from report_checks import assert_same_reports

from tools.events import two_tank_value
from twotank_validation import bags, replay
from twotank_validation.bags import decode
from twotank_validation.core.model import load_model
from twotank_validation.online import MonitorConfig, OnlineValidator
from twotank_validation.online import streams as itf
from twotank_validation.online.sources import convert
from twotank_validation.sim import scenario as sc

DATA = Path(__file__).resolve().parents[1] / "data"
TYPES = {
    mb.FLOW_CMD_TYPE: ("hot", "cold"),
    mb.HEIGHT_TYPE: ("fluid_pressure", "variance"),
    mb.TEMPERATURE_TYPE: ("temperature", "variance"),
}
STORE = mb.typestore()
NS = 1_000_000_000
PRESET_FIELDS = {
    t: tuple(b.source.field for b in ts.bindings) for t, ts in itf.two_tank_map().topics().items()
}
"""The float fields the two-tank preset map reads from each of the rig's topics."""


def message(msgtype: str, sec: int, nanosec: int, a: float, b: float, frame: str = "rig"):
    time_cls = STORE.types["builtin_interfaces/msg/Time"]
    header = STORE.types["std_msgs/msg/Header"](
        stamp=time_cls(sec=sec, nanosec=nanosec), frame_id=frame
    )
    f1, f2 = TYPES[msgtype]
    return STORE.types[msgtype](header=header, **{f1: a, f2: b})


def codec(msgtype: str) -> decode._Codec:
    return decode._Codec(
        lambda data: STORE.deserialize_cdr(data, msgtype), msgtype, lambda: STORE.fielddefs
    )


def reference(datas, msgtype):
    """rosbags on each message: (stamp_ns, fields) up to the first failure, and the failure."""
    rows = []
    for d in datas:
        try:
            msg = STORE.deserialize_cdr(d, msgtype)
        except Exception as err:  # any failure ends the reference
            return rows, err
        st_ = msg.header.stamp
        rows.append(
            (int(st_.sec) * NS + int(st_.nanosec), [getattr(msg, f) for f in TYPES[msgtype]])
        )
    return rows, None


def bulk(datas, msgtype, fields=None):
    fields = TYPES[msgtype] if fields is None else fields
    c = codec(msgtype)
    n = len(datas)
    batch = decode._RawBatch(["t"] * n, [msgtype] * n, list(range(n)), list(datas), [c] * n)
    return decode._decode_fields(batch, {"t": 0}, {"t": tuple(fields)}, len(fields), ("t",))


def assert_same_as_rosbags(datas, msgtype) -> bags.FieldBatch:
    out, failure = bulk(datas, msgtype)
    rows, err = reference(datas, msgtype)
    assert (failure is None) == (err is None)
    assert len(out) == len(rows)
    for i, (stamp, vals) in enumerate(rows):
        assert int(out.stamp_ns[i]) == stamp
        got = out.values[i].tolist()
        # bit for bit (NaN payloads and -0.0 included)
        assert struct.pack("<2d", *got) == struct.pack("<2d", *vals)
    return out


def cdr(msg, msgtype, little=True) -> bytes:
    return bytes(STORE.serialize_cdr(msg, msgtype, little_endian=little))


# ------------------------------------------------------------------ the bytes, one by one

floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([0.0, -0.0, 5e-324, math.nan, -math.inf]),
)
frames = st.one_of(st.sampled_from(["", "rig", "rig_0123", "tank\u00e9"]), st.text(max_size=13))


@settings(max_examples=150, deadline=None)
@given(
    msgtype=st.sampled_from(sorted(TYPES)),
    rows=st.lists(
        st.tuples(
            st.integers(-(2**31), 2**31 - 1),
            st.integers(0, 2**32 - 1),
            floats,
            floats,
        ),
        min_size=1,
        max_size=12,
    ),
    frame=frames,
    other_frame=frames,
    edits=st.lists(
        st.tuples(
            st.integers(0, 11),
            st.sampled_from(["big", "cut", "pad", "pad8", "frame", "nul", "len", "enc", "opt"]),
        ),
        max_size=3,
    ),
)
def test_bulk_decoding_equals_rosbags_on_the_same_bytes(
    msgtype, rows, frame, other_frame, edits
) -> None:
    """Equal-layout messages, then a few altered ones (big endian, cut short, padded, another
    frame_id, a broken terminator, length or encapsulation): the same values as rosbags for
    every message it accepts, and the failure at the same message."""
    datas = [cdr(message(msgtype, *r, frame=frame), msgtype) for r in rows]
    for i, kind in edits:
        if i >= len(datas):
            continue
        d = bytearray(datas[i])
        if kind == "big":
            d = bytearray(cdr(message(msgtype, *rows[i], frame=frame), msgtype, little=False))
        elif kind == "cut":
            d = d[:-3]
        elif kind == "pad":
            d += b"\0\0\0"
        elif kind == "pad8":
            d += b"\0" * 8
        elif kind == "frame":
            d = bytearray(cdr(message(msgtype, *rows[i], frame=other_frame), msgtype))
        elif kind == "nul":
            d[15 + int.from_bytes(d[12:16], "little")] = 65
        elif kind == "len":
            d[12] ^= 4
        elif kind == "enc":
            d[1] = 7
        elif kind == "opt":
            d[3] = 1
        datas[i] = bytes(d)
    assert_same_as_rosbags(datas, msgtype)


def test_bulk_path_is_taken_and_checks_every_message() -> None:
    msgtype = mb.HEIGHT_TYPE
    datas = [cdr(message(msgtype, k, 7, 1000.0 + k, 0.5), msgtype) for k in range(50)]
    out = assert_same_as_rosbags(datas, msgtype)
    assert out.bulk_decoded == 50
    # a message with another frame_id goes the generic way; the others stay in bulk
    datas[20] = cdr(message(msgtype, 20, 7, 1020.0, 0.5, frame="other"), msgtype)
    out = assert_same_as_rosbags(datas, msgtype)
    assert out.bulk_decoded == 49
    # a broken one ends the batch there, as rosbags does
    bad = bytearray(datas[30])
    bad[16 + 3] = 1  # the frame_id terminator
    datas[30] = bytes(bad)
    out, failure = bulk(datas, msgtype)
    assert failure is not None
    assert len(out) == 30


def test_layout_comes_from_the_definition() -> None:
    """Only header + float64 types are read in bulk; the definition decides, not the name."""
    defs = STORE.fielddefs
    assert decode._header_float_layout(defs, mb.FLOW_CMD_TYPE) == ("hot", "cold")
    assert decode._header_float_layout(defs, mb.HEIGHT_TYPE) == ("fluid_pressure", "variance")
    assert decode._header_float_layout(defs, "std_msgs/msg/Float64") is None  # no header
    assert decode._header_float_layout(defs, "sensor_msgs/msg/Range") is None  # uint8, float32
    # a type of the same name with another field order reads by its own definition
    other = mb.typestore()
    other.fielddefs[mb.HEIGHT_TYPE] = (
        [],
        [*defs[mb.HEIGHT_TYPE][1][:1], *defs[mb.HEIGHT_TYPE][1][:0:-1]],
    )
    assert decode._header_float_layout(other.fielddefs, mb.HEIGHT_TYPE) == (
        "variance",
        "fluid_pressure",
    )


def test_vectorised_unit_conversion_equals_the_scalar_extractors() -> None:
    rng = np.random.default_rng(0)
    units = itf.RigUnits(9806.65, 15.0, 50.0)
    x = np.concatenate([rng.normal(size=500) * 1e4, [math.nan, math.inf, -0.0, 5e-324]])
    height, temperature = itf.two_tank_map(units).outputs
    levels = convert(x, height)
    temps = convert(x, temperature)
    for v, lvl, tmp in zip(x.tolist(), levels.tolist(), temps.tolist(), strict=True):
        assert struct.pack("<d", lvl) == struct.pack("<d", units.level_from_pressure(v))
        assert struct.pack("<d", tmp) == struct.pack("<d", units.temperature_from_celsius(v))


# ------------------------------------------------------------------ whole bags


def via_messages(path, topics, fields):
    """What field_batches must equal: messages() and getattr, and the error it ends with."""
    rows = []
    err = None
    try:
        with bags.open_bag(path) as bag:
            for m in bag.messages(topics):
                st_ = m.msg.header.stamp
                vals = [float(getattr(m.msg, f)) for f in fields[m.topic]]
                rows.append((m.topic, m.log_time_ns, int(st_.sec) * NS + int(st_.nanosec), vals))
    except bags.BagError as e:
        err = e
    return rows, err


def via_batches(path, topics, fields, size):
    rows = []
    err = None
    try:
        with bags.open_bag(path) as bag:
            for b in bag.field_batches(topics, fields, size=size):
                for i in range(len(b)):
                    t = b.topics[int(b.topic[i])]
                    vals = b.values[i, : len(fields[t])].tolist()
                    rows.append((t, int(b.log_time_ns[i]), int(b.stamp_ns[i]), vals))
    except bags.BagError as e:
        err = e
    return rows, err


def assert_same_stream(path, topics=("flow_cmd", "height", "temperature"), size=7) -> int:
    fields = {
        "flow_cmd": ("hot", "cold"),
        "height": ("fluid_pressure",),
        "temperature": ("temperature", "variance"),
    }
    fields = {t: fields.get(t, ()) for t in topics}
    want, werr = via_messages(path, list(topics), fields)
    got, gerr = via_batches(path, list(topics), fields, size)
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        assert a[:3] == b[:3]
        assert struct.pack(f"<{len(a[3])}d", *a[3]) == struct.pack(f"<{len(b[3])}d", *b[3])
    assert type(gerr) is type(werr)
    if werr is not None:
        assert str(gerr) == str(werr)
        if isinstance(werr, bags.BagCorruptError):
            assert (gerr.messages_read, gerr.last_good_ns) == (
                werr.messages_read,
                werr.last_good_ns,
            )
    return len(got)


@pytest.mark.parametrize(
    "name", ["golden_mcap", "golden_sqlite3", "golden_plain.mcap", "golden_truncated.mcap"]
)
def test_field_batches_equal_messages_on_the_golden_bags(name) -> None:
    for size in (1, 5, 4096):
        assert assert_same_stream(DATA / name, size=size) > 0


def odd_messages() -> list:
    """Interface messages with everything a reader may meet: frame_ids changing, big-endian
    messages, NaN/inf values, negative and huge stamps."""
    out = []
    for k in range(40):
        t = mb.T0_NS + k * 100_000_000
        for i, (topic, msgtype) in enumerate(mb.TOPIC_TYPES.items()):
            frame = "rig" if k % 13 else "a_longer_frame_id"
            a = [0.1 * k, math.nan, math.inf, -0.0][k % 4] if k % 5 == 0 else 1000.0 + k
            msg = message(msgtype, (t // NS) if k != 17 else -5, t % NS, a, 0.25, frame=frame)
            out.append((topic, msgtype, t + i, msg, k % 11 == 3))
    return out


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_field_batches_equal_messages_on_odd_messages(tmp_path, storage) -> None:
    path = tmp_path / "odd"
    with bags.BagWriter(path, storage) as bag:
        for topic, msgtype in mb.TOPIC_TYPES.items():
            bag.add_topic(topic, msgtype)
        for topic, msgtype, t, msg, big in odd_messages():
            bag.write_raw(topic, t, cdr(msg, msgtype, little=not big))
    for size in (3, 64):
        assert assert_same_stream(path, size=size) == 120
    with bags.open_bag(path) as bag:
        fields = {t: PRESET_FIELDS[t] for t in mb.TOPIC_TYPES}
        decoded = sum(b.bulk_decoded for b in bag.field_batches(list(fields), fields))
    assert decoded == 120  # every frame_id and both byte orders in bulk


def test_field_batches_equal_messages_on_plain_and_cut_mcap(tmp_path) -> None:
    msgs = mb.samples(30)
    plain = mb.write_plain_mcap(tmp_path / "p.mcap", msgs, chunk_size=2000, compression="none")
    assert assert_same_stream(plain) == 90
    data = plain.read_bytes()
    for frac in (0.3, 0.55, 0.8):
        cut = tmp_path / f"cut{frac}.mcap"
        cut.write_bytes(data[: int(len(data) * frac)])
        assert_same_stream(cut)
    unindexed = mb.write_unindexed_mcap(tmp_path / "u.mcap", msgs)
    assert assert_same_stream(unindexed) == 90


# ------------------------------------------------------------------ replay, before and after

FAST = MonitorConfig(ts_s=0.8, period_samples=256)


def models():
    return [load_model("A"), load_model("B")]


def replay_per_message(path, cfg: replay.ReplayConfig):
    """The replay loop before batching: one decoded message, one extractor, one feed."""
    core = OnlineValidator(cfg.monitor, models(), jitter_fraction=cfg.jitter_fraction)
    reports, problems, n, windows = [], [], 0, []
    stream_of = {t: t for t in itf.STREAMS}
    try:
        with bags.open_bag(path) as bag:
            for m in bag.messages(list(stream_of)):
                value = two_tank_value(stream_of[m.topic], m.msg, itf.RigUnits())
                n += 1
                new = core.feed(stream_of[m.topic], itf.stamp_ns(m.msg), value)
                for rep in new:
                    if rep.judged:
                        windows.append(core.last_window())
                reports += new
    except bags.BagCorruptError as err:
        problems.append(str(err))
    return reports, problems, n, dict(vars(core.counters())), windows


def assert_same_replay(path) -> replay.ReplayResult:
    cfg = replay.ReplayConfig(monitor=FAST)
    seen = []
    res = replay.replay_bag(path, models(), cfg, on_window=lambda r, snap: seen.append(snap))
    reports, problems, n, counters, windows = replay_per_message(path, cfg)
    # the on_window hook gets each judged window's data, as the monitor held it then
    assert len(seen) == len(windows)
    for snap, (stamps, u, y) in zip(seen, windows, strict=True):
        np.testing.assert_array_equal(snap.stamps_ns, stamps)
        np.testing.assert_array_equal(snap.u, u)
        np.testing.assert_array_equal(snap.y, y)
    assert len(res.reports) == len(reports)
    assert_same_reports(res.reports, reports)
    assert [r.alarm for r in res.reports] == [r.alarm for r in reports]
    assert res.messages == n
    assert res.counters == counters
    assert [p for p in res.problems if p in problems] == problems
    return res


def fast_scenario(periods: float = 7, **changes) -> sc.Scenario:
    base = sc.load_scenario("nominal")
    return dataclasses.replace(
        base, ts_s=0.8, period_samples=256, duration_s=periods * 204.8, **changes
    )


def test_replay_equals_per_message_replay_on_a_clean_bag(tmp_path) -> None:
    bag = bags.write_scenario_bag(fast_scenario(), tmp_path / "nominal")
    res = assert_same_replay(bag)
    assert res.complete
    assert sum(r.judged for r in res.reports) >= 6


def messy_bag(path: Path, storage: str, seed: int) -> Path:
    """The nominal scenario's samples with every kind of bad input sprinkled in."""
    rng = np.random.default_rng(seed)
    stamps, u, y = sc.simulate_scenario(fast_scenario())
    units = itf.RigUnits()
    with bags.BagWriter(path, storage) as bag:
        for topic, msgtype in mb.TOPIC_TYPES.items():
            bag.add_topic(topic, msgtype)
        shift = 0
        for k, t_log in enumerate(stamps.tolist()):
            if k == 900:
                shift = -120 * NS  # the recording restarted: the stamps jump back
            t = t_log + 300 * NS + shift
            if 300 <= k < 310:
                continue  # a gap
            events = [
                ("flow_cmd", bags.flow_command(t, *u[k])),
                (
                    "height",
                    bags.fluid_pressure(t + int(rng.integers(-5, 5)) * 1_000_000, y[k, 0], units),
                ),
                ("temperature", bags.temperature_msg(t, y[k, 1], units)),
            ]
            if rng.random() < 0.01:
                events[1] = ("height", bags.fluid_pressure(t, math.nan, units))
            if rng.random() < 0.01:
                events.append(events[0])  # duplicate
            if rng.random() < 0.01 and k > 5:
                events.append(
                    ("temperature", bags.temperature_msg(t - 3 * 800_000_000, 0.5, units))
                )
            if rng.random() < 0.01:
                events[2] = ("temperature", bags.temperature_msg(t + 400_000_000, y[k, 1], units))
            for i, (topic, msg) in enumerate(events):
                if k % 97 == 5:  # now and then a big-endian message
                    bag.write_raw(
                        topic, 10 * NS + t_log + i, cdr(msg, mb.TOPIC_TYPES[topic], little=False)
                    )
                else:
                    bag.write(topic, 10 * NS + t_log + i, msg)
    return path


@pytest.mark.parametrize(("storage", "seed"), [("mcap", 0), ("sqlite3", 1), ("mcap", 2)])
def test_replay_equals_per_message_replay_on_messy_bags(tmp_path, storage, seed) -> None:
    res = assert_same_replay(messy_bag(tmp_path / "messy", storage, seed))
    c = res.counters
    for name in ("missing", "duplicates", "out_of_order", "clock_resets", "non_finite", "off_grid"):
        assert c[name] > 0, name


def test_replay_equals_per_message_replay_on_truncated_bags(tmp_path) -> None:
    bag = bags.write_scenario_bag(fast_scenario(), tmp_path / "nominal")
    data = next(bag.glob("*.mcap"))
    raw = data.read_bytes()
    for frac in (0.35, 0.7, 0.93):
        cut = tmp_path / f"cut{frac}"
        shutil.copytree(bag, cut)
        next(cut.glob("*.mcap")).write_bytes(raw[: int(len(raw) * frac)])
        res = assert_same_replay(cut)
        assert not res.complete
