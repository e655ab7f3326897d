"""The interface map (twotank_validation.online.interface) against independent references.

Messages are built with rosbags' ROS 2 Humble type store (plus FlowCommand from the
repository's ``msg/FlowCommand.msg`` and a nested custom type from ``.msg`` text) and with
rclpy's message classes (imported in the tests only). Values are checked against the fields
set on the messages and against :class:`RigUnits`' own conversions, bit for bit.
"""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from twotank_validation.errors import TwotankError
from twotank_validation.online.extraction import check_message, extract, raw_value, source_stamp_ns
from twotank_validation.online.interface_map import INPUT, OUTPUT, InterfaceMap, load_interface_map
from twotank_validation.online.interface_text import (
    TEXT_FORM,
    interface_map_from_text,
    source_from_text,
    source_to_text,
)
from twotank_validation.online.sources import InterfaceMapError, Source, convert, parse_field_path
from twotank_validation.online.streams import (
    FLOW_CMD,
    HEIGHT,
    TEMPERATURE,
    RigUnits,
)
from twotank_validation.online.streams import two_tank_map as default_interface_map

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "interface.md"
FLOW = "twotank_validation_msgs/msg/FlowCommand"

CUSTOM = {
    "my_rig/msg/Gauge": "float64 value\nfloat32[3] raw\nstring label\n",
    "my_rig/msg/Tank": "my_rig/Gauge[] gauges\nfloat64 volume\n",
    "my_rig/msg/Plant": "std_msgs/Header header\nmy_rig/Tank tank\nint32 mode\n",
}

RIG_DOC: dict[str, Any] = {
    "inputs": [
        {"name": "hot", "topic": "/valves/hot", "type": "std_msgs/msg/Float64", "field": "data",
         "stamp": "receive"},
        {"name": "cold", "topic": "/valves/cold", "type": "std_msgs/msg/Float64", "field": "data",
         "stamp": "receive"},
    ],
    "outputs": [
        {"name": "height", "topic": "/tank/gauge", "type": "sensor_msgs/msg/JointState",
         "field": "position[0]", "offset": 12.0, "scale": 1000.0},
        {"name": "temperature", "topic": "/tank/state",
         "type": "std_msgs/msg/Float64MultiArray", "field": "data[1]", "offset": 15.0,
         "scale": 50.0, "stamp": "receive"},
    ],
}  # fmt: skip


@pytest.fixture(scope="module")
def store() -> Typestore:
    ts = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    types.update(get_types_from_msg((REPO / "msg" / "FlowCommand.msg").read_text(), FLOW))
    for name, text in CUSTOM.items():
        types.update(get_types_from_msg(text, name))
    ts.register(types)
    return ts


def _header(store: Typestore, sec: int = 7, nanosec: int = 250) -> Any:
    t = store.types
    return t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id="tank"
    )


def _multiarray(store: Typestore, data: list[float]) -> Any:
    t = store.types
    layout = t["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
    return t["std_msgs/msg/Float64MultiArray"](layout=layout, data=np.array(data))


def _joint_state(store: Typestore, position: list[float]) -> Any:
    return store.types["sensor_msgs/msg/JointState"](
        header=_header(store),
        name=[f"j{i}" for i in range(len(position))],
        position=np.array(position),
        velocity=np.zeros(len(position)),
        effort=np.array([], dtype=float),
    )


def _plant(store: Typestore) -> Any:
    t = store.types
    gauges = [
        t["my_rig/msg/Gauge"](
            value=10.0 * i + 0.5, raw=np.array([i, i + 0.25, i + 0.5], np.float32), label=f"g{i}"
        )
        for i in range(3)
    ]
    return t["my_rig/msg/Plant"](
        header=_header(store), tank=t["my_rig/msg/Tank"](gauges=gauges, volume=2.5), mode=3
    )


def _raises(match: str) -> Any:
    return pytest.raises(InterfaceMapError, match=re.escape(match))


# --------------------------------------------------------------------------- field paths


@pytest.mark.parametrize(
    ("text", "steps"),
    [
        ("hot", ("hot",)),
        ("data[1]", ("data", 1)),
        ("position[0]", ("position", 0)),
        ("a.b[2].c", ("a", "b", 2, "c")),
        ("m[10][3]", ("m", 10, 3)),
        ("fluid_pressure", ("fluid_pressure",)),
    ],
)
def test_field_paths_parse_into_steps(text: str, steps: tuple[str | int, ...]) -> None:
    assert parse_field_path(text) == steps


@pytest.mark.parametrize(
    "text", ["", "[0]", ".a", "a.", "a..b", "a[1]b", "a[-1]", "a[x]", "a b", "1a", "a[1", "a-b"]
)
def test_bad_field_paths_are_refused(text: str) -> None:
    with pytest.raises(InterfaceMapError, match="field path"):
        parse_field_path(text)


def test_field_path_is_stored_canonical() -> None:
    src = Source("x", "/t", "std_msgs/msg/Float64MultiArray", "data[01]")
    assert (src.field, src.path) == ("data[1]", ("data", 1))


# --------------------------------------------------------------------------- path shapes


def test_paths_on_rosbags_messages(store: Typestore) -> None:
    t = store.types
    cases = [
        (t["std_msgs/msg/Float64"](data=0.375), "data", 0.375),
        (_multiarray(store, [1.5, -2.25, 3.0]), "data[1]", -2.25),
        (_joint_state(store, [0.125, 4.0]), "position[0]", 0.125),
        (_joint_state(store, [0.125, 4.0]), "header.stamp.sec", 7.0),
        (_joint_state(store, [0.125, 4.0]), "header.stamp.nanosec", 250.0),
        (
            t["sensor_msgs/msg/FluidPressure"](
                header=_header(store), fluid_pressure=4903.325, variance=0.5
            ),
            "fluid_pressure",
            4903.325,
        ),
        (
            t["sensor_msgs/msg/Temperature"](header=_header(store), temperature=40.0, variance=0.1),
            "temperature",
            40.0,
        ),
        (_plant(store), "tank.gauges[2].value", 20.5),  # a.b[2].c: through a list of messages
        (_plant(store), "tank.gauges[1].raw[2]", 1.5),  # fixed-size float32 array
        (_plant(store), "tank.volume", 2.5),
        (_plant(store), "mode", 3.0),
    ]
    for msg, path, want in cases:
        got = raw_value(msg, path)
        assert type(got) is float
        assert got == want, path


def test_paths_on_rclpy_messages_match_rosbags(store: Typestore) -> None:
    from sensor_msgs.msg import JointState  # noqa: PLC0415
    from std_msgs.msg import Float64, Float64MultiArray  # noqa: PLC0415

    arr = Float64MultiArray()
    arr.data = [1.5, -2.25, 3.0]  # array.array('d') in rclpy
    arr.layout.data_offset = 4
    js = JointState()
    js.position = [0.125, 4.0]
    js.name = ["j0", "j1"]
    js.header.stamp.sec = 7
    f = Float64()
    f.data = 0.375
    for msg, path, want in [
        (arr, "data[1]", -2.25),
        (arr, "layout.data_offset", 4.0),
        (js, "position[0]", 0.125),
        (js, "header.stamp.sec", 7.0),
        (f, "data", 0.375),
    ]:
        assert raw_value(msg, path) == want, path
    ros = _multiarray(store, [1.5, -2.25, 3.0])
    src = Source("t", "/tank/state", "std_msgs/msg/Float64MultiArray", "data[1]", "receive", 15, 50)
    assert extract(arr, src) == extract(ros, src) == (-2.25 - 15.0) / 50.0


def test_extract_converts_with_offset_and_scale(store: Typestore) -> None:
    src = Source("level", "/g", "sensor_msgs/msg/JointState", "position[0]", offset=12, scale=1e3)
    msg = _joint_state(store, [512.0])
    assert extract(msg, src) == 0.5
    assert (src.offset, src.scale) == (12.0, 1000.0)
    flipped = Source("x", "/g", "sensor_msgs/msg/JointState", "position[0]", scale=-2.0)
    assert extract(msg, flipped) == -256.0


# --------------------------------------------------------------------------- default map


def _fluid(store: Typestore, pa: float) -> Any:
    return store.types["sensor_msgs/msg/FluidPressure"](
        header=_header(store), fluid_pressure=pa, variance=0.0
    )


def _temp(store: Typestore, c: float) -> Any:
    return store.types["sensor_msgs/msg/Temperature"](
        header=_header(store), temperature=c, variance=0.0
    )


@pytest.mark.parametrize(
    "units", [RigUnits(), RigUnits(pascal_per_unit=9810.3, temperature_offset_c=11.7,
                                   temperature_span_c=47.9)]
)  # fmt: skip
def test_default_map_gives_stream_values_bit_for_bit(store: Typestore, units: RigUnits) -> None:
    rng = np.random.default_rng(15)
    n = 500
    pa = np.concatenate([rng.uniform(0, 3e4, n), [0.0, -0.0, 1e-300, 5e5]])
    c = np.concatenate([rng.uniform(-5, 90, n), [0.0, -0.0, 15.0, 1e6]])
    cmd = rng.uniform(0, 1, (len(pa), 2))
    cmd[-1] = (-0.0, 0.0)
    imap = default_interface_map(units)
    hot, cold = imap.inputs
    height, temperature = imap.outputs
    assert (hot.topic, hot.msgtype, hot.field) == (FLOW_CMD, FLOW, "hot")
    assert (cold.topic, cold.field, height.topic, temperature.topic) == (
        FLOW_CMD, "cold", HEIGHT, TEMPERATURE,
    )  # fmt: skip
    # the reference: RigUnits' own conversions, element by element
    want_h = np.array([units.level_from_pressure(float(p)) for p in pa])
    want_t = np.array([units.temperature_from_celsius(float(x)) for x in c])
    want_u = cmd.copy()
    # scalar path, through real messages
    got_h = np.array([extract(_fluid(store, p), height) for p in pa])
    got_t = np.array([extract(_temp(store, x), temperature) for x in c])
    flows = [store.types[FLOW](header=_header(store), hot=a, cold=b) for a, b in cmd]
    got_u = np.array([[extract(m, hot), extract(m, cold)] for m in flows])
    # vectorised path
    for got, want in [
        (got_h, want_h),
        (got_t, want_t),
        (got_u, want_u),
        (convert(pa, height), want_h),
        (convert(c, temperature), want_t),
        (np.column_stack([convert(cmd[:, 0], hot), convert(cmd[:, 1], cold)]), want_u),
    ]:
        assert np.array_equal(got, want)
        assert got.view(np.uint64).tolist() == want.view(np.uint64).tolist()  # signs of zeros
    if units == RigUnits():
        assert np.array_equal(got_h, pa / 9806.65)
        assert np.array_equal(got_t, (c - 15.0) / 50.0)


@given(st.floats(allow_nan=False, allow_infinity=False), st.floats(-1e6, 1e6))
def test_scalar_and_vector_conversions_agree(raw: float, offset: float) -> None:
    src = Source("x", "/t", "std_msgs/msg/Float64", "data", offset=offset, scale=0.3)
    one = src.to_model(raw)
    many = convert(np.array([raw, raw]), src)
    assert struct.pack("<d", one) == many[0].tobytes() == many[1].tobytes()


# --------------------------------------------------------------------------- YAML


def _write(tmp_path: Path, doc: Any) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_rig_example_loads(tmp_path: Path) -> None:
    imap = load_interface_map(_write(tmp_path, RIG_DOC))
    assert imap.input_names == ("hot", "cold")
    assert imap.output_names == ("height", "temperature")
    level = imap.outputs[0]
    assert (level.path, level.offset, level.scale, level.stamp) == (
        ("position", 0), 12.0, 1000.0, "header",
    )  # fmt: skip
    assert imap.inputs[0].stamp == "receive"
    assert (imap.inputs[1].offset, imap.inputs[1].scale) == (0.0, 1.0)


def test_yaml_round_trips_through_to_dict(tmp_path: Path) -> None:
    for imap in [
        InterfaceMap.from_dict(RIG_DOC),
        default_interface_map(),
        default_interface_map(RigUnits(9810.3, 11.7, 47.9)),
    ]:
        folder = tmp_path / str(id(imap))
        folder.mkdir()
        again = load_interface_map(_write(folder, imap.to_dict()))
        assert again == imap
        assert again.to_dict() == imap.to_dict()
    written = InterfaceMap.from_dict(RIG_DOC).to_dict()
    for entry, given_entry in zip(written["outputs"], RIG_DOC["outputs"], strict=True):
        assert {k: entry[k] for k in given_entry} == given_entry


def _mutated(change: Any) -> dict[str, Any]:
    doc = yaml.safe_load(yaml.safe_dump(RIG_DOC))  # deep copy
    change(doc)
    return doc


def _set(role: str, i: int, key: str, value: Any) -> Any:
    return lambda d: d[role][i].__setitem__(key, value)


BAD_MAPS = [
    ("top-level key", lambda d: d.__setitem__("extra", 1), "unknown keys ['extra']"),
    ("source key", _set("inputs", 0, "gain", 2.0), "inputs[0]: unknown keys ['gain']"),
    ("missing field", lambda d: d["inputs"][1].pop("field"), "inputs[1]: missing keys ['field']"),
    ("missing outputs", lambda d: d.pop("outputs"), "missing key 'outputs'"),
    ("empty inputs", lambda d: d.__setitem__("inputs", []), "inputs: expected a non-empty list"),
    ("inputs not a list", lambda d: d.__setitem__("inputs", {"a": 1}), "inputs: expected"),
    ("source not a mapping", lambda d: d["outputs"].append("level"), "outputs[2]: expected a map"),
    ("path syntax", _set("outputs", 1, "field", "data[1"), "outputs[1].field: field path"),
    ("path syntax 2", _set("outputs", 0, "field", "position.[0]"), "outputs[0].field:"),
    ("scale 0", _set("outputs", 0, "scale", 0), "outputs[0].scale: 0 is not a scale"),
    ("offset nan", _set("outputs", 1, "offset", math.nan), "outputs[1].offset: nan is not fin"),
    ("scale inf", _set("outputs", 1, "scale", -math.inf), "outputs[1].scale: -inf is not fin"),
    ("scale text", _set("outputs", 1, "scale", "fifty"), "outputs[1].scale: expected a number"),
    ("scale bool", _set("outputs", 1, "scale", True), "outputs[1].scale: expected a number"),
    ("offset list", _set("inputs", 0, "offset", [1]), "inputs[0].offset: expected a number"),
    ("name int", _set("inputs", 0, "name", 3), "inputs[0].name: expected a non-empty string"),
    ("name empty", _set("inputs", 0, "name", ""), "inputs[0].name: expected a non-empty string"),
    ("name chars", _set("inputs", 0, "name", "hot valve"), "inputs[0].name: 'hot valve' is not"),
    ("topic chars", _set("inputs", 0, "topic", "/a:b"), "inputs[0].topic: '/a:b' is not"),
    ("type form", _set("inputs", 0, "type", "std_msgs/Float64"), "e.g. std_msgs/msg/Float64"),
    ("duplicate names", _set("outputs", 0, "name", "hot"), "outputs[0].name: 'hot' is used alre"),
    ("topic two types", _set("outputs", 1, "topic", "/valves/hot"), "outputs[1].type: topic"),
    (
        "topic two stamps",
        lambda d: d["inputs"][1].update(topic="/valves/hot", stamp="header"),
        "inputs[1].stamp: topic '/valves/hot' is stamped 'header' here but 'receive' at inputs[0]",
    ),
    ("bad stamp", _set("inputs", 0, "stamp", "now"), "inputs[0].stamp: 'now' is not a stamp"),
    ("document a list", lambda d: d.__setitem__("inputs", d["inputs"][0]), "inputs: expected"),
]


@pytest.mark.parametrize(("case", "change", "match"), BAD_MAPS, ids=[c[0] for c in BAD_MAPS])
def test_bad_maps_name_the_file_and_key(tmp_path: Path, case: str, change: Any, match: str) -> None:
    path = _write(tmp_path, _mutated(change))
    with pytest.raises(InterfaceMapError) as info:
        load_interface_map(path)
    text = str(info.value)
    assert text.startswith(f"{path}: "), text
    assert match in text, text
    assert isinstance(info.value, TwotankError)
    assert isinstance(info.value, ValueError)


def test_yaml_1e3_reads_as_a_number(tmp_path: Path) -> None:
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(RIG_DOC).replace("scale: 1000.0", "scale: 1e3"))
    assert yaml.safe_load(path.read_text())["outputs"][0]["scale"] == "1e3"  # YAML 1.1
    assert load_interface_map(path).outputs[0].scale == 1000.0


def test_missing_and_unparsable_files(tmp_path: Path) -> None:
    with _raises(f"cannot read the interface map {tmp_path / 'none.yaml'}"):
        load_interface_map(tmp_path / "none.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("inputs: [\n")
    with _raises(f"{bad}: not valid YAML"):
        load_interface_map(bad)
    with _raises("<dict>: expected a mapping"):
        InterfaceMap.from_dict([1, 2])


def test_direct_construction_is_validated() -> None:
    with _raises("source 'x': scale: 0 is not a scale"):
        Source("x", "/t", "std_msgs/msg/Float64", "data", scale=0.0)
    with _raises("source 'x': msgtype: 'Float64' is not a ROS 2 message type"):
        Source("x", "/t", "Float64", "data")
    with _raises("source 'x': offset: inf is not finite"):
        Source("x", "/t", "std_msgs/msg/Float64", "data", offset=math.inf)
    a = Source("a", "/t", "std_msgs/msg/Float64", "data")
    with _raises("outputs[0].name: 'a' is used already by inputs[0]"):
        InterfaceMap((a,), (a,))
    with _raises("outputs: no sources"):
        InterfaceMap((a,), ())
    b = Source("b", "/t", "std_msgs/msg/Float32", "data")
    with _raises("outputs[0].type: topic '/t' is std_msgs/msg/Float32 here but std_msgs/msg/Float"):
        InterfaceMap((a,), (b,))


def test_topics_group_the_sources() -> None:
    doc = _mutated(lambda d: d["outputs"].append(
        {"name": "aux", "topic": "/tank/state", "type": "std_msgs/msg/Float64MultiArray",
         "field": "data[0]", "stamp": "receive"}
    ))  # fmt: skip
    imap = InterfaceMap.from_dict(doc)
    topics = imap.topics()
    assert list(topics) == ["/valves/hot", "/valves/cold", "/tank/gauge", "/tank/state"]
    state = topics["/tank/state"]
    assert state.msgtype == "std_msgs/msg/Float64MultiArray"
    assert [(b.role, b.position, b.source.name) for b in state.bindings] == [
        (OUTPUT, 1, "temperature"), (OUTPUT, 2, "aux"),
    ]  # fmt: skip
    role, position, src = topics["/valves/cold"].bindings[0]
    assert (role, position, src) == (INPUT, 1, imap.inputs[1])
    dflt = default_interface_map().topics()
    assert [(t, len(v.bindings)) for t, v in dflt.items()] == [
        (FLOW_CMD, 2), (HEIGHT, 1), (TEMPERATURE, 1),
    ]  # fmt: skip


# --------------------------------------------------------------------------- text form

RIG_TEXT = (
    [
        "hot=/valves/hot:std_msgs/msg/Float64:data,stamp=receive",
        "cold=/valves/cold:std_msgs/msg/Float64:data,stamp=receive",
    ],
    [
        "height=/tank/gauge:sensor_msgs/msg/JointState:position[0],scale=1000.0,offset=12.0",
        "temperature=/tank/state:std_msgs/msg/Float64MultiArray:data[1],scale=50.0,offset=15.0,"
        "stamp=receive",
    ],
)


def test_text_form_gives_the_yaml_map_and_back() -> None:
    imap = interface_map_from_text(*RIG_TEXT)
    assert imap == InterfaceMap.from_dict(RIG_DOC)
    assert [source_to_text(s) for s in imap.inputs] == RIG_TEXT[0]
    assert [source_to_text(s) for s in imap.outputs] == RIG_TEXT[1]


def test_text_form_options_any_order_and_spaces() -> None:
    a = source_from_text(" t = /x : std_msgs/msg/Float64MultiArray : data[2] , stamp=receive,"
                         "offset=-1.5 ,scale=2e3 ")  # fmt: skip
    assert a == Source("t", "/x", "std_msgs/msg/Float64MultiArray", "data[2]", "receive",
                       -1.5, 2000.0)  # fmt: skip


@given(
    st.floats(allow_nan=False, allow_infinity=False),
    st.floats(allow_nan=False, allow_infinity=False).filter(lambda s: s != 0.0),
    st.sampled_from(["header", "receive"]),
    st.sampled_from(["data", "data[3]", "a.b[2].c", "position[0]"]),
)
def test_text_form_round_trips(offset: float, scale: float, stamp: str, field: str) -> None:
    src = Source("sig_1", "/ns/topic", "pkg_a/msg/Type9", field, stamp, offset, scale)
    text = source_to_text(src)
    back = source_from_text(text)
    assert back == src
    assert struct.pack("<dd", back.offset, back.scale) == struct.pack("<dd", offset, scale)
    assert source_to_text(back) == text


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("hot", TEXT_FORM),
        ("/valves/hot:std_msgs/msg/Float64:data", TEXT_FORM),
        ("hot=/valves/hot:std_msgs/msg/Float64", TEXT_FORM),
        ("hot=/a:std_msgs/msg/Float64:data:x", TEXT_FORM),
        ("hot=/a:std_msgs/msg/Float64:data,gain=2", "option 'gain=2' is not"),
        ("hot=/a:std_msgs/msg/Float64:data,scale", "option 'scale' is not"),
        ("hot=/a:std_msgs/msg/Float64:data,scale=2,scale=3", "option 'scale' is given twice"),
        ("hot=/a:std_msgs/msg/Float64:data,scale=0", "scale: 0 is not a scale"),
        ("hot=/a:std_msgs/msg/Float64:data,offset=nan", "offset: nan is not finite"),
        ("hot=/a:std_msgs/msg/Float64:data,stamp=now", "stamp: 'now' is not a stamp"),
        ("hot=/a:std_msgs/Float64:data", "type: 'std_msgs/Float64' is not"),
        ("hot=/a:std_msgs/msg/Float64:data[", "field: field path 'data['"),
        ("=/a:std_msgs/msg/Float64:data", "name: expected a non-empty string"),
    ],
)
def test_bad_text_names_the_expected_form(text: str, match: str) -> None:
    with pytest.raises(InterfaceMapError) as info:
        source_from_text(text)
    assert f"source {text!r}" in str(info.value)
    assert match in str(info.value)


def test_text_map_errors_name_the_entry() -> None:
    with _raises("outputs[1]: source 'x' is not NAME=TOPIC:TYPE:FIELD"):
        interface_map_from_text(RIG_TEXT[0], [RIG_TEXT[1][0], "x"])
    with _raises("inputs: expected a list"):
        interface_map_from_text(RIG_TEXT[0][0], RIG_TEXT[1])


# --------------------------------------------------------------------------- bad messages


def test_bad_paths_on_rosbags_messages_name_the_fields(store: Typestore) -> None:
    js = _joint_state(store, [0.5])
    with _raises(
        "topic '/g' (sensor_msgs/msg/JointState): field path 'positon[0]' does not fit the "
        "message: the message (sensor_msgs/msg/JointState) has no field 'positon'; its fields: "
        "header, name, position, velocity, effort"
    ):
        raw_value(js, "positon[0]", topic="/g")
    with _raises("index 1 is out of range: position has length 1"):
        raw_value(js, "position[1]", topic="/g")
    with _raises("position is an array (ndarray) of length 1, not a number; add an index"):
        raw_value(js, "position")
    with _raises("header is a std_msgs/msg/Header message, not a number; its fields: stamp, "):
        raw_value(js, "header")
    with _raises("header.stamp (builtin_interfaces/msg/Time) has no field 'secs'; its fields: "
                 "sec, nanosec"):  # fmt: skip
        raw_value(js, "header.stamp.secs")
    with _raises("name[0] is a str ('j0'), not a number"):
        raw_value(js, "name[0]")
    f = store.types["std_msgs/msg/Float64"](data=1.0)
    with _raises("data is a float (1.0), not an array: [0] cannot index it"):
        raw_value(f, "data[0]")
    plant = _plant(store)
    with _raises("tank.gauges[0] (my_rig/msg/Gauge) has no field 'valu'; its fields: value, raw, "
                 "label"):  # fmt: skip
        raw_value(plant, "tank.gauges[0].valu")
    with _raises("index 3 is out of range: tank.gauges has length 3"):
        raw_value(plant, "tank.gauges[3].value")
    with _raises("tank.volume is a float (2.5), which has no fields; no field 'x'"):
        raw_value(plant, "tank.volume.x")


def test_bad_paths_on_rclpy_messages_name_the_fields() -> None:
    from std_msgs.msg import Float64MultiArray  # noqa: PLC0415

    arr = Float64MultiArray()
    arr.data = [1.0, 2.0]
    with _raises(
        "topic '/s' (std_msgs/msg/Float64MultiArray): field path 'dat[1]' does not fit the "
        "message: the message (std_msgs/msg/Float64MultiArray) has no field 'dat'; its fields: "
        "layout, data"
    ):
        raw_value(arr, "dat[1]", topic="/s")
    with _raises("index 2 is out of range: data has length 2"):
        raw_value(arr, "data[2]")
    with _raises("data is an array (array) of length 2, not a number; add an index, e.g. data[0]"):
        raw_value(arr, "data")
    with _raises("layout (std_msgs/msg/MultiArrayLayout) has no field 'dims'; its fields: dim, "):
        raw_value(arr, "layout.dims[0]")


def test_check_message(store: Typestore) -> None:
    arr = _multiarray(store, [1.0, 2.0])
    src = Source("t", "/s", "std_msgs/msg/Float64MultiArray", "data[1]", stamp="receive")
    check_message(src, arr, "std_msgs/msg/Float64MultiArray")
    with _raises(
        "topic '/s' carries std_msgs/msg/Float64, but the interface map asks for "
        "std_msgs/msg/Float64MultiArray (source 't'); set 'type: std_msgs/msg/Float64'"
    ):
        check_message(src, store.types["std_msgs/msg/Float64"](data=1.0), "std_msgs/msg/Float64")
    far = Source("t", "/s", "std_msgs/msg/Float64MultiArray", "data[5]", stamp="receive")
    with _raises("topic '/s' (std_msgs/msg/Float64MultiArray): field path 'data[5]' does not fit"):
        check_message(far, arr, "std_msgs/msg/Float64MultiArray")
    headerless = Source("t", "/s", "std_msgs/msg/Float64MultiArray", "data[1]")
    with _raises("has no header.stamp to stamp source 't'; set 'stamp: receive'"):
        check_message(headerless, arr, "std_msgs/msg/Float64MultiArray")
    gauge = Source("g", "/g", "sensor_msgs/msg/JointState", "position[0]")
    check_message(gauge, _joint_state(store, [1.0]), "sensor_msgs/msg/JointState")


def test_source_stamp_ns(store: Typestore) -> None:
    msg = _joint_state(store, [1.0])
    src = Source("g", "/g", "sensor_msgs/msg/JointState", "position[0]")
    assert source_stamp_ns(msg, src, 99) == 7 * 10**9 + 250
    rx = Source("g", "/g", "sensor_msgs/msg/JointState", "position[0]", stamp="receive")
    assert source_stamp_ns(msg, rx, 99) == 99


# --------------------------------------------------------------------------- the page


def _doc_blocks(lang: str) -> list[str]:
    """The fenced blocks of docs/interface.md opened by ```lang."""
    blocks: list[str] = []
    current: list[str] | None = None
    kind = ""
    for line in DOC.read_text().splitlines():
        if line.startswith("```") and current is None:
            current, kind = [], line[3:].strip()
        elif line.startswith("```") and current is not None:
            if kind == lang:
                blocks.append("\n".join(current))
            current = None
        elif current is not None:
            current.append(line)
    return blocks


def test_doc_examples_are_the_maps_they_describe() -> None:
    # tables: test_tables.py; the real rig's log: the map file the block shows
    default_block, rig_block, measured_block, _table_block, benchmark_block = _doc_blocks("yaml")
    assert InterfaceMap.from_dict(yaml.safe_load(measured_block)).measured_inputs == ("force",)
    benchmark = REPO / "test" / "data" / "cascaded_tanks" / "estimation.map.yaml"
    assert InterfaceMap.from_dict(yaml.safe_load(benchmark_block)) == load_interface_map(benchmark)
    assert InterfaceMap.from_dict(yaml.safe_load(default_block)) == default_interface_map()
    assert InterfaceMap.from_dict(yaml.safe_load(rig_block)) == InterfaceMap.from_dict(RIG_DOC)
    formula, grammar, text = _doc_blocks("")
    assert formula.strip() == "model = (raw - offset) / scale"
    assert grammar.strip() == TEXT_FORM
    lines = text.split()
    assert interface_map_from_text(lines[:2], lines[2:]) == InterfaceMap.from_dict(RIG_DOC)
