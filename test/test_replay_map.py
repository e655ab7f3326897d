"""Replay through an interface map: foreign message types, split topics, field paths.

The same simulated run is written twice: once with the package's own interface, once as a
rig of another make would publish it (each valve on a headerless ``std_msgs/msg/Float64``,
the level in a ``sensor_msgs/msg/JointState``, the temperature as ``data[1]`` of a
``std_msgs/msg/Float64MultiArray``, or the commands under another package's type). The bags
carry their types' definitions (rosbags writes them), so nothing needs installing. Read
through a map, they must give the reports of the first, bit for bit.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import get_types_from_msg

from twotank_validation import cli, load_model, replay
from twotank_validation.bags import BagWriter, write_scenario_bag
from twotank_validation.bags.writer import typestore
from twotank_validation.online import MonitorConfig
from twotank_validation.online.interface_text import interface_map_from_text
from twotank_validation.online.streams import RigUnits
from twotank_validation.sim import scenario as sc

UNITS = RigUnits()
MONITOR = MonitorConfig(ts_s=0.8, period_samples=256)
VALVE_CMD = """std_msgs/Header header
float64 hot
float64 cold
"""
MAP_SPLIT = (
    [
        "hot=/valves/hot:std_msgs/msg/Float64:data,stamp=receive",
        "cold=/valves/cold:std_msgs/msg/Float64:data,stamp=receive",
    ],
    [
        "height=/tank/joints:sensor_msgs/msg/JointState:position[0],scale=9806.65",
        "temperature=/tank/state:std_msgs/msg/Float64MultiArray:data[1],offset=15,scale=50,"
        "stamp=receive",
    ],
)
MAP_CUSTOM = (
    [
        "hot=/cmd:rig_msgs/msg/ValveCmd:hot",
        "cold=/cmd:rig_msgs/msg/ValveCmd:cold",
    ],
    [
        "height=height:sensor_msgs/msg/FluidPressure:fluid_pressure,scale=9806.65",
        "temperature=temperature:sensor_msgs/msg/Temperature:temperature,offset=15,scale=50",
    ],
)


def scenario() -> sc.Scenario:
    base = sc.load_scenario("leak")  # a fault mid-run: the alarm must come at the same window
    return dataclasses.replace(
        base, ts_s=0.8, period_samples=256, duration_s=10 * 204.8, faults=("leak=0.04@1000",)
    )


def write_foreign(path: Path, layout: str) -> Path:
    store = typestore()
    store.register(get_types_from_msg(VALVE_CMD, "rig_msgs/msg/ValveCmd"))
    T = store.types
    with BagWriter(path, store=store) as bag:
        if layout == "split":
            for topic, msgtype in [
                ("/valves/hot", "std_msgs/msg/Float64"),
                ("/valves/cold", "std_msgs/msg/Float64"),
                ("/tank/joints", "sensor_msgs/msg/JointState"),
                ("/tank/state", "std_msgs/msg/Float64MultiArray"),
            ]:
                bag.add_topic(topic, msgtype)
        else:
            for topic, msgtype in [
                ("/cmd", "rig_msgs/msg/ValveCmd"),
                ("height", "sensor_msgs/msg/FluidPressure"),
                ("temperature", "sensor_msgs/msg/Temperature"),
            ]:
                bag.add_topic(topic, msgtype)

        def header(ns: int):
            return T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                frame_id="rig",
            )

        layout_cls, dim_cls = (
            T["std_msgs/msg/MultiArrayLayout"],
            T["std_msgs/msg/MultiArrayDimension"],
        )
        for stamp, hot, cold, height, temp in sc.iter_scenario(scenario()):
            pressure = UNITS.pressure_from_level(float(height))
            celsius = UNITS.celsius_from_temperature(float(temp))
            if layout == "split":
                bag.write("/valves/hot", stamp, T["std_msgs/msg/Float64"](data=float(hot)))
                bag.write("/valves/cold", stamp, T["std_msgs/msg/Float64"](data=float(cold)))
                bag.write(
                    "/tank/joints",
                    stamp,
                    T["sensor_msgs/msg/JointState"](
                        header=header(stamp),
                        name=["level", "stirrer"],
                        position=np.array([pressure, 0.0]),
                        velocity=np.zeros(0),
                        effort=np.zeros(0),
                    ),
                )
                bag.write(
                    "/tank/state",
                    stamp,
                    T["std_msgs/msg/Float64MultiArray"](
                        layout=layout_cls(
                            dim=[dim_cls(label="x", size=2, stride=2)], data_offset=0
                        ),
                        data=np.array([-1.0, celsius]),
                    ),
                )
            else:
                bag.write(
                    "/cmd",
                    stamp,
                    T["rig_msgs/msg/ValveCmd"](
                        header=header(stamp), hot=float(hot), cold=float(cold)
                    ),
                )
                bag.write(
                    "height",
                    stamp,
                    T["sensor_msgs/msg/FluidPressure"](
                        header=header(stamp), fluid_pressure=pressure, variance=0.0
                    ),
                )
                bag.write(
                    "temperature",
                    stamp,
                    T["sensor_msgs/msg/Temperature"](
                        header=header(stamp), temperature=celsius, variance=0.0
                    ),
                )
    return path


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("maps")
    own = root / "own"
    write_scenario_bag(scenario(), own)
    return {
        "own": own,
        "split": write_foreign(root / "split", "split"),
        "custom": write_foreign(root / "custom", "custom"),
    }


def reports(path: Path, imap=None):
    cfg = replay.ReplayConfig(monitor=MONITOR, interface=imap)
    res = replay.replay_bag(path, [load_model("A"), load_model("B")], cfg)
    return res, [(r.model, r.start_ns, r.judged, r.beta, r.alarm) for r in res.reports]


@pytest.mark.parametrize(("layout", "texts"), [("split", MAP_SPLIT), ("custom", MAP_CUSTOM)])
def test_a_foreign_layout_read_through_a_map_gives_the_same_reports(bags, layout, texts) -> None:
    own, want = reports(bags["own"])
    assert own.complete
    assert any(r[2] for r in want)  # judged windows
    assert any(r[4].name == "ERROR" for r in want)  # and the leak's alarm
    got_res, got = reports(bags[layout], interface_map_from_text(*texts))
    assert got_res.problems == own.problems
    assert got_res.complete
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert g[:3] == w[:3]
        assert g[3] == w[3] or (np.isnan(g[3]) and np.isnan(w[3]))
        assert g[4] == w[4]


def test_the_cli_takes_the_map_and_infers_the_timing(bags, tmp_path: Path, capsys) -> None:
    mapfile = tmp_path / "map.yaml"
    import yaml  # noqa: PLC0415

    mapfile.write_text(yaml.safe_dump(interface_map_from_text(*MAP_SPLIT).to_dict()))
    code = cli.main(["validate", str(bags["split"]), "--map", str(mapfile), "--quiet"])
    err = capsys.readouterr().err
    assert code == cli.EXIT_OK, err
    assert "sample period 0.8 s inferred from the command stamps" in err
    assert "excitation period 256 samples" in err


def test_a_map_that_does_not_fit_names_topic_type_and_fields(bags, capsys) -> None:
    wrong_field = (
        MAP_SPLIT[0],
        [
            "height=/tank/joints:sensor_msgs/msg/JointState:pressure",
            MAP_SPLIT[1][1],
        ],
    )
    args = ["validate", str(bags["split"]), "--quiet", "--ts", "0.8", "--period", "256"]
    for i in wrong_field[0]:
        args += ["--input", i]
    for o in wrong_field[1]:
        args += ["--output", o]
    code = cli.main(args)
    err = capsys.readouterr().err
    assert code == cli.EXIT_INCOMPLETE
    assert "/tank/joints" in err
    assert "position" in err  # the fields the message has
    wrong_type = [
        "--input",
        MAP_SPLIT[0][0],
        "--input",
        MAP_SPLIT[0][1].replace("Float64", "Float32"),
    ]
    args = ["validate", str(bags["split"]), "--quiet", "--ts", "0.8", "--period", "256"]
    args += [*wrong_type, "--output", MAP_SPLIT[1][0], "--output", MAP_SPLIT[1][1]]
    code = cli.main(args)
    err = capsys.readouterr().err
    assert code == cli.EXIT_INCOMPLETE
    assert "'/valves/cold' carries std_msgs/msg/Float64" in err
    missing = ["--output", MAP_SPLIT[1][0].replace("/tank/joints", "/tank/nothing")]
    args = ["validate", str(bags["split"]), "--quiet", "--ts", "0.8", "--period", "256"]
    args += ["--input", MAP_SPLIT[0][0], "--input", MAP_SPLIT[0][1], *missing]
    args += ["--output", MAP_SPLIT[1][1]]
    code = cli.main(args)
    err = capsys.readouterr().err
    assert code == cli.EXIT_INCOMPLETE
    assert "'/tank/nothing' of the interface map given as text (--input/--output" in err
    assert "is not in the bag" in err
    assert "/tank/joints (sensor_msgs/msg/JointState)" in err  # what the bag holds


def test_map_options_do_not_mix_with_topic_remaps(bags, capsys) -> None:
    args = ["validate", str(bags["own"]), "--topic", "height=x", "--input", MAP_SPLIT[0][0]]
    assert cli.main(args) == cli.EXIT_ERROR
    assert "--topic remaps the two-tank interface" in capsys.readouterr().err
    args = ["validate", str(bags["own"]), "--input", MAP_SPLIT[0][0]]
    assert cli.main(args) == cli.EXIT_ERROR
    assert "--input and --output go together" in capsys.readouterr().err
