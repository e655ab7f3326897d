"""Tables (CSV, Parquet) through a map of columns: the same run as a bag gives the same reports.

One simulated run (the leak scenario at Ts 0.8 s, period 256, ten periods, a leak mid-run) is
written as a scenario bag and as tables a PLC or historian would log: the bag's own raw values
(Pa, °C, valves 0..1) with the time in seconds, and the same samples in other units (valves
in percent, the level in mm over a 12 mm zero, °C) with the time in seconds, in integer
milliseconds, as ISO-8601 text and as a Parquet timestamp column. Replayed, each must give the
bag's reports: bit for bit where the float operations are the bag's (the bag's units; CSV
and Parquet of the same raw values alike), and within 1e-12 relative in β where the unit
conversion itself rounds differently (``hot * 100 / 100`` is not always ``hot``: one ulp per
sample, which moves β by ~1e-16 relative; a sample misplaced or a unit wrong moves it by far
more than 1e-12).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import yaml

from twotank_validation import cli, load_model, replay
from twotank_validation.bags import write_scenario_bag
from twotank_validation.errors import TwotankError
from twotank_validation.online import MonitorConfig
from twotank_validation.online.interface_map import InterfaceMap, load_interface_map
from twotank_validation.online.interface_text import (
    TABLE_TEXT_FORM,
    interface_map_from_text,
    source_from_text,
    source_to_text,
    time_column_from_text,
)
from twotank_validation.online.sources import InterfaceMapError, Source, TimeColumn
from twotank_validation.online.streams import RigUnits
from twotank_validation.sim import scenario as sc
from twotank_validation.tables import TableError, is_table, read_table, table_columns

UNITS = RigUnits()
MONITOR = MonitorConfig(ts_s=0.8, period_samples=256, hop_samples=256)  # a window per period
EPOCH = pd.Timestamp("2024-05-01T12:00:00Z")
DOC = Path(__file__).resolve().parent.parent / "docs" / "interface.md"

BAG_UNITS_MAP = {
    "inputs": [{"name": "hot", "column": "hot"}, {"name": "cold", "column": "cold"}],
    "outputs": [
        {"name": "height", "column": "pressure_pa", "scale": UNITS.pascal_per_unit},
        {"name": "temperature", "column": "temp_c", "offset": 15.0, "scale": 50.0},
    ],
    "time": {"column": "t", "unit": "s"},
}
OTHER_UNITS_MAP = {
    "inputs": [
        {"name": "hot", "column": "valve_hot_pct", "scale": 100.0},
        {"name": "cold", "column": "valve_cold_pct", "scale": 100.0},
    ],
    "outputs": [
        {"name": "height", "column": "level_mm", "offset": 12.0, "scale": 1000.0},
        {"name": "temperature", "column": "temp_c", "offset": 15.0, "scale": 50.0},
    ],
}


def scenario() -> sc.Scenario:
    base = sc.load_scenario("leak")
    return dataclasses.replace(
        base, ts_s=0.8, period_samples=256, duration_s=10 * 204.8, faults=("leak=0.04@1000",)
    )


def other_map(column: str = "t", unit: str = "s") -> InterfaceMap:
    return InterfaceMap.from_dict(OTHER_UNITS_MAP | {"time": {"column": column, "unit": unit}})


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The bag and the tables of one run."""
    root = tmp_path_factory.mktemp("tables")
    scn = scenario()
    write_scenario_bag(scn, root / "bag")
    stamp, hot, cold, height, temp = (np.array(c) for c in zip(*sc.iter_scenario(scn), strict=True))
    seconds = stamp / 1e9
    pressure = UNITS.pressure_from_level(height)  # the bag's floats (bags/writer.py)
    celsius = UNITS.celsius_from_temperature(temp)
    own = pd.DataFrame(
        {"t": seconds, "hot": hot, "cold": cold, "pressure_pa": pressure, "temp_c": celsius}
    )
    other = pd.DataFrame(
        {
            "t": seconds,
            "valve_hot_pct": hot * 100.0,
            "valve_cold_pct": cold * 100.0,
            "level_mm": height * 1000.0 + 12.0,
            "temp_c": celsius,
            "note": "ok",
        }
    )
    paths = {"bag": root / "bag", "own.csv": root / "own.csv", "other.csv": root / "other.csv"}
    own.to_csv(paths["own.csv"], index=False)
    other.to_csv(paths["other.csv"], index=False)
    ms = other.drop(columns="t").assign(t_ms=stamp // 1_000_000)
    paths["ms.parquet"] = root / "ms.parquet"
    ms.sample(frac=1.0, random_state=1).to_parquet(paths["ms.parquet"], index=False)  # shuffled
    stamps = EPOCH + pd.to_timedelta(stamp, unit="ns")
    iso = other.drop(columns="t").assign(
        stamp=[s.isoformat().replace("+00:00", "Z") for s in stamps]
    )
    paths["iso.csv"] = root / "iso.csv"
    iso.to_csv(paths["iso.csv"], index=False)
    paths["iso.parquet"] = root / "iso.parquet"
    other.drop(columns="t").assign(time=stamps).to_parquet(paths["iso.parquet"])
    return {"paths": paths, "other": other, "root": root}


def reports(path: Path, imap: InterfaceMap | None = None) -> tuple[replay.ReplayResult, list]:
    cfg = replay.ReplayConfig(monitor=MONITOR, interface=imap)
    res = replay.replay_recording(path, [load_model("A"), load_model("B")], cfg)
    t0 = res.bag_start_ns
    return res, [(r.model, r.start_ns - t0, r.judged, r.beta, r.alarm) for r in res.reports]


def same(got: list, want: list, rtol: float = 0.0, *, alarm: bool = True) -> None:
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert (g[0], g[1], g[2]) == (w[0], w[1], w[2])
        if alarm:
            assert g[4] == w[4]
        if math.isnan(w[3]):
            assert math.isnan(g[3])
        elif rtol == 0.0:
            assert g[3] == w[3]
        else:
            assert g[3] == pytest.approx(w[3], rel=rtol, abs=0.0)


@pytest.fixture(scope="module")
def bag_reports(run: dict[str, Any]) -> list:
    res, want = reports(run["paths"]["bag"])
    assert res.complete
    assert not res.problems
    assert sum(r[2] for r in want) >= 12  # judged windows, both models
    assert any(r[4].name == "ERROR" for r in want)  # and the leak's alarm
    return want


def test_a_table_in_the_bags_units_gives_the_bags_reports_bit_for_bit(run, bag_reports) -> None:
    res, got = reports(run["paths"]["own.csv"], InterfaceMap.from_dict(BAG_UNITS_MAP))
    assert (res.source, res.complete, res.problems) == ("table", True, [])
    assert res.messages == len(run["other"])
    same(got, bag_reports)


@pytest.mark.parametrize(
    ("name", "time"),
    [("other.csv", ("t", "s")), ("ms.parquet", ("t_ms", "ms")), ("iso.csv", ("stamp", "iso")),
     ("iso.parquet", ("", "auto"))],
)  # fmt: skip
def test_tables_in_other_units_give_the_bags_reports(run, bag_reports, name, time) -> None:
    res, got = reports(run["paths"][name], other_map(*time))
    assert res.complete
    assert not res.problems
    same(got, bag_reports, rtol=1e-12)  # one ulp per converted sample (module docstring)
    _, csv_got = reports(run["paths"]["other.csv"], other_map())
    same(got, csv_got)  # the same raw floats: bit for bit, whatever the file and time format


def test_csv_floats_read_back_exactly(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    x = rng.standard_normal(20_000) * 10.0 ** rng.integers(-9, 10, 20_000)
    pd.DataFrame({"t": np.arange(len(x)), "a": x}).to_csv(tmp_path / "x.csv", index=False)
    imap = InterfaceMap(
        (Source("a", column="a"),), (Source("b", column="a", offset=0.5, scale=-3.0),)
    )
    table = read_table(tmp_path / "x.csv", imap)
    assert np.array_equal(table.inputs[:, 0], x)
    assert np.array_equal(table.outputs[:, 0], (x - 0.5) / -3.0)
    assert table.stamps_ns[1] == 1_000_000_000  # unit auto: numbers are seconds


def test_empty_and_bad_cells_leave_those_windows_unjudged(run, bag_reports, tmp_path) -> None:
    frame = pd.read_csv(run["paths"]["other.csv"]).astype({"level_mm": object})
    frame.loc[700:719, "level_mm"] = ""  # 16 s of empty cells: more than a window recovers
    frame.loc[720, "level_mm"] = "--"  # a historian's "no value"
    frame.loc[1100, "valve_hot_pct"] = np.nan  # one lost cell: recovered from the other periods
    path = tmp_path / "gaps.csv"
    frame.to_csv(path, index=False)
    res, got = reports(path, other_map())
    assert res.complete
    assert any(
        "column 'level_mm'" in p and "21 cell(s)" in p and "row 701" in p for p in res.problems
    )
    assert any(
        "column 'valve_hot_pct'" in p and "1 cell(s)" in p and "row 1101" in p for p in res.problems
    )
    step = 800_000_000
    gap = [r for r in res.reports if r.start_ns <= 700 * step < r.end_ns]
    assert gap
    assert not any(r.judged for r in gap)
    assert all("unusable sample" in r.data_quality and "height" in r.data_quality for r in gap)
    lost = [r for r in res.reports if r.start_ns <= 1100 * step < r.end_ns]
    assert lost
    assert all(r.judged and "recovered 1 sample(s)" in r.data_quality for r in lost)
    windows = [w for m in replay.summary_json(res)["models"].values() for w in m["windows"]]
    said = [w for w in windows if "recovered 1 sample(s)" in w["data_quality"]]
    assert len(said) == len(lost)  # the JSON says so too
    assert all(w["reason"] is None and w["beta"] is not None for w in said)
    clean = 1100 * step
    later = [g for g in got if g[1] > clean]
    assert len(later) >= 6
    assert all(g[2] for g in later)
    # the dynamics after the gaps are the bag's; the alarm is not: the gaps kept the steady
    # windows before the leak from commissioning the operating point, so the reference was
    # commissioned on the leaking plant and only the dynamics raise the alarm here
    same(later, [w for w in bag_reports if w[1] > clean], 1e-12, alarm=False)
    summary = replay.summary_json(res)
    assert summary["models"]["A"]["not_judged_reasons"].get("unusable samples (non-finite)")


def test_resolve_timing_reads_the_tables_time_and_commands(run) -> None:
    for name, time in [("other.csv", ("t", "s")), ("iso.parquet", ("", "auto"))]:
        cfg = replay.ReplayConfig(monitor=MONITOR, interface=other_map(*time))
        timing = replay.resolve_timing(run["paths"][name], cfg)
        assert (timing.ts_s, timing.period_samples) == (0.8, 256)
        assert (timing.ts_from, timing.period_from) == ("command stamps", "commands")


def test_windows_from_recording_takes_a_table(run) -> None:
    cfg = replay.ReplayConfig(monitor=MONITOR, interface=other_map("t_ms", "ms"))
    windows, res = replay.windows_from_recording(run["paths"]["ms.parquet"], load_model("B"), cfg)
    bag_windows, _ = replay.windows_from_bag(
        run["paths"]["bag"], load_model("B"), replay.ReplayConfig(monitor=MONITOR)
    )
    assert res.source == "table"
    assert [w.start_s for w in windows] == [w.start_s for w in bag_windows]
    assert len(windows) >= 3


# --------------------------------------------------------------------------- maps of columns


def test_column_sources_in_yaml_text_and_back(tmp_path: Path) -> None:
    imap = other_map()
    assert imap.is_table
    assert imap.time == TimeColumn("t", "s")
    assert imap.inputs[0] == Source("hot", column="valve_hot_pct", scale=100.0)
    assert imap.inputs[0].to_dict() == {
        "name": "hot", "column": "valve_hot_pct", "offset": 0.0, "scale": 100.0,
    }  # fmt: skip
    path = tmp_path / "map.yaml"
    path.write_text(yaml.safe_dump(imap.to_dict()))
    assert load_interface_map(path) == imap
    texts = [[source_to_text(s) for s in imap.inputs], [source_to_text(s) for s in imap.outputs]]
    assert texts[0][0] == "hot=column:valve_hot_pct,scale=100.0"
    assert interface_map_from_text(*texts, "t,unit=s") == imap
    assert source_from_text(" hot = column : valve hot:% , offset=1 ") == Source(
        "hot", column="valve hot:%", offset=1.0
    )
    assert InterfaceMap.from_dict(OTHER_UNITS_MAP).time == TimeColumn()  # found by name
    assert InterfaceMap.from_dict(OTHER_UNITS_MAP | {"time": "stamp"}).time == TimeColumn("stamp")
    assert time_column_from_text(",unit=ms") == TimeColumn("", "ms")


def _raises(match: str) -> Any:
    return pytest.raises(InterfaceMapError, match=re.escape(match))


def _doc(change: Any) -> dict[str, Any]:
    doc = yaml.safe_load(yaml.safe_dump(OTHER_UNITS_MAP))
    change(doc)
    return doc


BAD_MAPS = [
    (
        lambda d: d["outputs"].__setitem__(
            1, {"name": "temperature", "topic": "/t", "type": "std_msgs/msg/Float64",
                "field": "data"}
        ),
        "outputs[1]: reads topic '/t' but inputs[0] reads column 'valve_hot_pct'; a map reads "
        "either a bag",
    ),
    (lambda d: d["inputs"][0].update(topic="/a"), "inputs[0]: 'column' reads a table but ['topic"),
    (lambda d: d["inputs"][0].update(stamp="receive"),
     "inputs[0]: 'column' reads a table but ['stamp'] read a bag"),
    (lambda d: d["inputs"][0].update(column=""), "inputs[0].column: expected the name of a table"),
    (lambda d: d["inputs"][0].update(column=3), "inputs[0].column: expected the name"),
    (lambda d: d["inputs"][0].pop("column"), "inputs[0]: missing keys ['topic', 'type', 'field']"
     " (or 'column', for a CSV/Parquet table)"),
    (lambda d: d.update(time={"column": "t", "unit": "h"}), "time.unit: 'h' is not a time unit"),
    (lambda d: d.update(time={"col": "t"}), "time: unknown keys ['col']; allowed: ['column', 'un"),
    (lambda d: d.update(time=[1]), "time: expected a column name or a mapping"),
    (lambda d: d.update(time={"column": 5}), "time.column: expected the name of the table's time"),
]  # fmt: skip


@pytest.mark.parametrize(("change", "match"), BAD_MAPS)
def test_bad_maps_of_columns_name_the_key_and_fix(change: Any, match: str) -> None:
    with _raises(f"rig.yaml: {match}"):
        InterfaceMap.from_dict(_doc(change), "rig.yaml")


def test_a_map_of_topics_takes_no_time_and_a_map_of_columns_no_topics() -> None:
    topic = Source("a", "/t", "std_msgs/msg/Float64", "data")
    with _raises("time: a map of topics is stamped by its messages"):
        InterfaceMap((topic,), (dataclasses.replace(topic, name="b"),), TimeColumn("t"))
    with _raises("source 'x': column: a source reads either a table's column or a bag's topic"):
        Source("x", "/t", column="c")
    with _raises("source 'x': column: a source reads either"):
        Source("x", column="c", stamp="receive")
    with _raises("the interface map reads the columns ['valve_hot_pct', "):
        other_map().topics()
    with _raises("time: unit: 'hours' is not a time unit"):
        TimeColumn("t", "hours")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("hot=column:", "column: expected the name of a table column"),
        ("hot=column:a,stamp=receive", "option 'stamp=receive' is not scale=S or offset=O"),
        ("hot=column:std_msgs/msg/Float64:data", "is ambiguous: write a topic named 'column' as"),
        ("hot=valve", TABLE_TEXT_FORM),
    ],
)
def test_bad_column_text_names_the_form(text: str, match: str) -> None:
    with pytest.raises(InterfaceMapError) as info:
        source_from_text(text)
    assert f"source {text!r}" in str(info.value)
    assert match in str(info.value)
    with _raises("has no text form"):
        source_to_text(Source("a", column="x,y"))
    with _raises("time 't,units=s': option 'units=s' is not unit=U"):
        time_column_from_text("t,units=s")


# --------------------------------------------------------------------------- bad tables


def _table_error(path: Path, match: str, imap: InterfaceMap | None = None) -> str:
    with pytest.raises(TableError) as info:
        read_table(path, imap or other_map())
    text = str(info.value)
    assert match in text, text
    assert isinstance(info.value, TwotankError)
    assert isinstance(info.value, ValueError)
    return text


def test_bad_tables_name_the_file_the_cell_and_the_fix(run, tmp_path: Path) -> None:
    other = run["other"]
    _table_error(tmp_path / "log.xlsx", "the suffix '.xlsx' is not a table's")
    _table_error(tmp_path / "none.csv", "cannot read the table")
    (tmp_path / "empty.csv").write_text("")
    _table_error(tmp_path / "empty.csv", "is empty: a table needs a header line")
    (tmp_path / "header.csv").write_text(",".join(other.columns) + "\n")
    _table_error(tmp_path / "header.csv", "holds no rows")
    (tmp_path / "junk.parquet").write_bytes(b"not parquet")
    _table_error(tmp_path / "junk.parquet", "is not a readable Parquet file")
    renamed = tmp_path / "renamed.csv"
    other.rename(columns={"level_mm": "Level_mm "}).head(10).to_csv(renamed, index=False)
    text = _table_error(renamed, "no column 'level_mm' (source 'height'); did you mean 'Level_mm '")
    assert "the table's columns: ['t', 'valve_hot_pct'" in text
    no_time = tmp_path / "no_time.csv"
    other.rename(columns={"t": "secs"}).head(10).to_csv(no_time, index=False)
    _table_error(
        no_time,
        "no time column: none of the columns ['secs',",
        InterfaceMap.from_dict(OTHER_UNITS_MAP),
    )
    _table_error(no_time, "no time column 't'; the table's columns: ['secs'")
    two = tmp_path / "two.csv"
    other.assign(Time=1.0).head(10).to_csv(two, index=False)
    _table_error(
        two,
        "the columns ['t', 'Time'] could each be the time",
        InterfaceMap.from_dict(OTHER_UNITS_MAP),
    )


@pytest.mark.parametrize(
    ("cell", "unit", "match"),
    [
        ("abc", "s", "row 4 (after the header): 'abc' is not a number of seconds"),
        ("", "ms", "row 4 (after the header): an empty cell is not a number of milliseconds"),
        ("2024-13-45T00:00:00", "iso", "'2024-13-45T00:00:00' is not an ISO-8601 time"),
        ("1e300", "s", "1e+300 is not a number of seconds"),
    ],
)
def test_a_time_that_cannot_be_read_is_an_error(run, tmp_path, cell, unit, match) -> None:
    frame = run["other"].head(10).astype({"t": object})
    if unit == "iso":
        frame["t"] = [(EPOCH + pd.Timedelta(seconds=s)).isoformat() for s in frame["t"]]
    frame.loc[3, "t"] = cell
    path = tmp_path / "t.csv"
    frame.to_csv(path, index=False)
    text = _table_error(path, match, other_map("t", unit))
    assert "every row needs a time" in text


def test_the_unit_must_fit_the_time_column(run, tmp_path) -> None:
    _table_error(
        run["paths"]["iso.parquet"],
        "holds datetimes, not numbers of s; set its unit to iso",
        other_map("time", "s"),
    )
    _table_error(
        run["paths"]["other.csv"], "holds numbers, not ISO-8601 times", other_map("t", "iso")
    )


def test_replay_refuses_a_table_without_a_map_of_columns(run) -> None:
    models = [load_model("B")]
    with pytest.raises(
        replay.ReplayConfigError, match=r"is a table .* but the two-tank interface .* reads topics"
    ):
        replay.replay_recording(run["paths"]["other.csv"], models)
    with pytest.raises(replay.ReplayConfigError, match="reads the columns of a table, but this"):
        replay.replay_bag(run["paths"]["bag"], models, replay.ReplayConfig(interface=other_map()))
    columns = replay.ReplayConfig(interface=other_map())
    with pytest.raises(TableError, match=r"the suffix \(none\) is not a table's"):
        replay.replay_recording(run["paths"]["bag"], models, columns)  # a bag, a map of columns
    assert is_table("x.CSV")
    assert is_table("x.pq")
    assert not is_table("x.mcap")
    assert table_columns(run["paths"]["ms.parquet"])[-1] == "t_ms"


# --------------------------------------------------------------------------- the command line


@pytest.fixture(scope="module")
def map_file(run: dict[str, Any]) -> Path:
    path = run["root"] / "map.yaml"
    path.write_text(yaml.safe_dump(other_map().to_dict()))
    return path


def test_cli_validates_a_csv_through_the_map(run, map_file, tmp_path, capsys) -> None:
    out = tmp_path / "v.json"
    code = cli.main(
        [
            "validate",
            str(run["paths"]["other.csv"]),
            "--map",
            str(map_file),
            "--quiet",
            "--json",
            str(out),
        ]
    )
    err = capsys.readouterr().err
    assert code == cli.EXIT_OK, err
    assert "sample period 0.8 s inferred from the command stamps" in err
    doc = json.loads(out.read_text())
    assert doc["source"] == "table"
    assert doc["bag"] == str(run["paths"]["other.csv"])
    assert doc["timing"]["period_samples"] == 256
    assert doc["models"]["A"]["first_alarm"] is not None


def test_cli_diagnoses_a_parquet_table(run, map_file, capsys) -> None:
    args = ["diagnose", str(run["paths"]["ms.parquet"]), "--model", "B", "--map", str(map_file)]
    code = cli.main([*args, "--time", "t_ms,unit=ms"])  # --time replaces the map's time
    out, err = capsys.readouterr()
    assert code == cli.EXIT_OK, err
    assert "judged window(s) of model B in" in out


def test_cli_takes_the_columns_as_text(run, capsys) -> None:
    code = cli.main([
        "validate", str(run["paths"]["iso.csv"]), "--model", "B", "--quiet",
        "--input", "hot=column:valve_hot_pct,scale=100",
        "--input", "cold=column:valve_cold_pct,scale=100",
        "--output", "height=column:level_mm,offset=12,scale=1000",
        "--output", "temperature=column:temp_c,offset=15,scale=50",
        "--time", "stamp,unit=iso", "--hop", "256",
    ])  # fmt: skip
    out, err = capsys.readouterr()
    assert code == cli.EXIT_OK, err
    assert "model B: 8 of 9 window(s) judged" in out
    assert "2560 rows" in err


def test_cli_usage_errors_and_unjudged_tables(run, map_file, tmp_path, capsys) -> None:
    table = str(run["paths"]["other.csv"])
    assert cli.main(["validate", table, "--quiet"]) == cli.EXIT_ERROR
    assert (
        "is a table (CSV/Parquet): give the map of its columns with --map FILE"
        in capsys.readouterr().err
    )
    assert (
        cli.main(["validate", str(run["paths"]["bag"]), "--time", "t", "--quiet"]) == cli.EXIT_ERROR
    )
    assert "--time names a table's time column" in capsys.readouterr().err
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(yaml.safe_dump(_doc(lambda d: d["outputs"][0].update(column="level"))))
    assert cli.main(["validate", table, "--map", str(wrong), "--quiet"]) == cli.EXIT_ERROR
    assert "no column 'level' (source 'height')" in capsys.readouterr().err
    short = tmp_path / "short.csv"
    run["other"].head(700).to_csv(short, index=False)  # under one window: read whole, not judged
    args = [
        "validate",
        str(short),
        "--map",
        str(map_file),
        "--ts",
        "0.8",
        "--period",
        "256",
        "--quiet",
    ]
    assert cli.main(args) == cli.EXIT_NOT_JUDGED
    assert "no window of model A could be judged" in capsys.readouterr().err


def test_the_pages_table_example_is_a_map_of_columns() -> None:
    text = DOC.read_text()
    section = text[text.index("## Tables (CSV, Parquet)") :]
    block = section.split("```yaml\n", 1)[1].split("```", 1)[0]
    imap = InterfaceMap.from_dict(yaml.safe_load(block))
    assert imap.is_table
    assert imap == other_map()
    lines = section.split("```text\n", 1)[1].split("```", 1)[0].split()
    assert interface_map_from_text(lines[:2], lines[2:4]) == InterfaceMap.from_dict(OTHER_UNITS_MAP)
