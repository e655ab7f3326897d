"""A bag's time base: header stamps on one clock, log times on another (issue 27, item 6).

A bag recorded from a ``live`` run holds header stamps in simulated time (from 0 s) and log
times on the recorder's wall clock (near 1.8e9 s since the epoch, and advancing slower than
the data, as the run goes faster than real time). The windows are timed by the header
stamps and counted from the first: the reference is the same run written as a scenario bag
(both clocks equal), whose windows must come out the same, time for time and β for β. A
map that mixes the two clocks (a headerless ``std_msgs/Float64`` stamped by its log time
beside header-stamped topics) is refused with the fix where they disagree, and read where
they agree. A scenario bag read on either clock gives the same windows (the second
reference: two clocks that coincide).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import yaml

from twotank_validation import cli, load_model, replay
from twotank_validation.bags import BagWriter, write_scenario_bag
from twotank_validation.bags.writer import flow_command, fluid_pressure, temperature_msg
from twotank_validation.defaults import NS_PER_S
from twotank_validation.online import MonitorConfig
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.online.sources import STAMP_RECEIVE, Source
from twotank_validation.online.streams import (
    FLOW_CMD,
    HEIGHT,
    STREAM_TYPES,
    TEMPERATURE,
    RigUnits,
    two_tank_map,
)
from twotank_validation.replay.timebase import TimeBaseError
from twotank_validation.sim import scenario as sc

UNITS = RigUnits()
MONITOR = MonitorConfig(ts_s=0.8, period_samples=256)
WALL0_NS = 1_795_715_707 * NS_PER_S  # the recorder's wall clock when the run started
SPEED = 50  # the run goes 50x faster than real time: log times advance 1/50 of the stamps
FLOAT_TEMPERATURE = "/tank/temperature"


def scenario() -> sc.Scenario:
    return dataclasses.replace(
        sc.load_scenario("nominal"), ts_s=0.8, period_samples=256, duration_s=6 * 204.8
    )


def write_live_like(path: Path, *, mixed: bool, wall: bool = True) -> Path:
    """The scenario as a recorder on the wall clock would log a run on a simulated clock.

    ``mixed``: the temperature as a headerless std_msgs/Float64 (°C). ``wall``: False logs
    each message at its header stamp (the two clocks agree).
    """
    with BagWriter(path) as bag:
        for topic, msgtype in STREAM_TYPES.items():
            if not (mixed and topic == TEMPERATURE):
                bag.add_topic(topic, msgtype)
        if mixed:
            bag.add_topic(FLOAT_TEMPERATURE, "std_msgs/msg/Float64")
        float64 = bag.typestore.types["std_msgs/msg/Float64"]
        for stamp, hot, cold, height, temperature in sc.iter_scenario(scenario()):
            log = WALL0_NS + stamp // SPEED if wall else stamp
            bag.write(FLOW_CMD, log, flow_command(stamp, hot, cold))
            bag.write(HEIGHT, log, fluid_pressure(stamp, height, UNITS))
            if mixed:
                celsius = UNITS.celsius_from_temperature(float(temperature))
                bag.write(FLOAT_TEMPERATURE, log, float64(data=celsius))
            else:
                bag.write(TEMPERATURE, log, temperature_msg(stamp, temperature, UNITS))
    return path


def mixed_map() -> InterfaceMap:
    """The preset with the temperature read from the headerless topic by its log time."""
    preset = two_tank_map(UNITS)
    temperature = Source(
        TEMPERATURE,
        FLOAT_TEMPERATURE,
        "std_msgs/msg/Float64",
        "data",
        STAMP_RECEIVE,
        UNITS.temperature_offset_c,
        UNITS.temperature_span_c,
    )
    return dataclasses.replace(preset, outputs=(preset.outputs[0], temperature), label="mixed")


def log_time_map() -> InterfaceMap:
    """The preset with every source stamped by its log time."""
    preset = two_tank_map(UNITS)
    return dataclasses.replace(
        preset,
        inputs=tuple(dataclasses.replace(s, stamp=STAMP_RECEIVE) for s in preset.inputs),
        outputs=tuple(dataclasses.replace(s, stamp=STAMP_RECEIVE) for s in preset.outputs),
        label="log times",
    )


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("timebase")
    return {
        "scenario": write_scenario_bag(scenario(), root / "scenario", progress=False),
        "live": write_live_like(root / "live", mixed=False),
        "mixed": write_live_like(root / "mixed", mixed=True),
        "mixed_agreeing": write_live_like(root / "mixed_ok", mixed=True, wall=False),
    }


def windows(doc: dict) -> list[tuple]:
    return [
        (name, w["start"], w["end"], w["beta"], w["alarm"])
        for name, entry in doc["models"].items()
        for w in entry["windows"]
    ]


def summary(path: Path, imap: InterfaceMap | None = None) -> dict:
    cfg = replay.ReplayConfig(monitor=MONITOR, interface=imap)
    result = replay.replay_bag(path, [load_model("B")], cfg)
    assert result.complete, result.problems
    return replay.summary_json(result)


def test_a_live_bag_is_timed_by_its_header_stamps_from_zero(bags) -> None:
    """The live-like bag's windows lie in [0, duration] and equal the scenario bag's."""
    want = summary(bags["scenario"])
    got = summary(bags["live"])
    assert got["time_base"] == "header stamps"
    assert windows(got) == windows(want)
    assert any(w[3] is not None for w in windows(got))  # judged windows
    duration = scenario().duration_s
    assert all(0.0 <= w[1] < w[2] <= duration for w in windows(got))


def test_the_cli_says_which_clock_and_why(bags, tmp_path: Path, capsys) -> None:
    out = tmp_path / "live.json"
    args = ["validate", str(bags["live"]), "--model", "B", "--quiet", "--json", str(out)]
    code = cli.main([*args, "--no-diagnosis"])
    captured = capsys.readouterr()
    assert code == cli.EXIT_OK, captured.err
    assert "windows timed by the header stamps" in captured.err
    assert "log times lie 1.7957" in captured.err  # the wall clock's offset, named
    doc = json.loads(out.read_text())
    assert doc["time_base"] == "header stamps"
    assert all(w["start"] >= 0.0 for w in doc["models"]["B"]["windows"])
    # the table on stdout: the first window starts at 0 s, not at -1.8e9 s
    first = next(line for line in captured.out.splitlines() if "STALE" in line)
    assert first.split("-")[0].strip() == "0.0", first


def test_a_mixture_of_disagreeing_clocks_is_refused_with_the_fix(bags, tmp_path, capsys) -> None:
    with pytest.raises(TimeBaseError) as err:
        summary(bags["mixed"], mixed_map())
    text = str(err.value)
    assert "'flow_cmd', 'height' by the header stamps" in text
    assert f"'{FLOAT_TEMPERATURE}' by the bag's log times" in text
    assert "stamp: receive" in text
    # the command line: exit 2 (unusable input), one line naming the fix, nothing judged
    mapfile = tmp_path / "mixed.yaml"
    mapfile.write_text(yaml.safe_dump(mixed_map().to_dict()))
    out = tmp_path / "mixed.json"
    args = ["validate", str(bags["mixed"]), "--map", str(mapfile), "--model", "B", "--quiet"]
    code = cli.main([*args, "--json", str(out)])
    captured = capsys.readouterr()
    assert code == cli.EXIT_ERROR
    assert "ERROR: " in captured.err
    assert "the windows need one time base" in captured.err
    assert "Traceback" not in captured.err
    assert not out.exists()


def test_a_mixture_whose_clocks_agree_is_read(bags) -> None:
    got = summary(bags["mixed_agreeing"], mixed_map())
    assert got["time_base"] == "header stamps and log times"
    assert windows(got) == windows(summary(bags["scenario"]))


def test_a_scenario_bag_gives_the_same_windows_on_either_clock(bags) -> None:
    by_header = summary(bags["scenario"])
    by_log = summary(bags["scenario"], log_time_map())
    assert (by_header["time_base"], by_log["time_base"]) == ("header stamps", "log times")
    assert windows(by_header) == windows(by_log)
    assert windows(by_header)[0][1] == 0.0
