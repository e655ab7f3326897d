"""A simulated model run written as a CSV table and as a bag, each with its interface map."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from twotank_validation.bags.bag_errors import BagExistsError
from twotank_validation.bags.model_bag import CUSTOM_DATA_KEY, simulate_model_command
from twotank_validation.bags.reader import open_bag
from twotank_validation.core.model import load_model
from twotank_validation.online.extraction import extract, source_stamp_ns
from twotank_validation.online.interface_map import load_interface_map
from twotank_validation.sim import model_plant as mp
from twotank_validation.sim import model_record as mr
from twotank_validation.tables import read_table

DATA = Path(__file__).resolve().parents[1] / "data" / "models"
OPTIONS = {"ts_s": 0.1, "period_samples": 64, "periods": 2, "settle_periods": 1, "f_max_hz": 1.0}


@cache
def run(name: str) -> mp.ModelSimResult:
    """What simulate_model_command simulates for ``name`` with OPTIONS and one fault."""
    cfg = mp.ModelSimConfig(
        model=load_model(DATA / f"{name}.yaml"),
        ts_s=0.1,
        excitation=mp.ModelExcitation(period_samples=64, f_max_hz=1.0, offset=0.5),
        periods=2,
        settle_periods=1,
        faults=(FAULT[name],),
    )
    return mp.simulate_model(cfg)


FAULT = {
    "siso": "sensor_bias:flow=0.1@5",
    "one_by_three": "output_delay:p_out=0.3@2",
    "three_by_two": "stuck_input:heater@4",
}


@pytest.mark.parametrize("name", sorted(FAULT))
def test_csv_table_and_its_map_read_back_the_run(tmp_path: Path, name: str) -> None:
    out = simulate_model_command(
        DATA / f"{name}.yaml", tmp_path / "run.csv", "csv", offset=0.5,
        faults=[FAULT[name]], **OPTIONS,
    )  # fmt: skip
    assert out == tmp_path / "run.csv"
    res = run(name)
    imap = load_interface_map(tmp_path / "run.map.yaml")
    assert imap == mr.table_interface_map(res.input_names, res.output_names)
    assert imap.input_names == res.input_names
    assert imap.output_names == res.output_names
    table = read_table(out, imap)
    assert table.time_column == "t"
    np.testing.assert_array_equal(table.stamps_ns, res.stamps_ns)
    np.testing.assert_array_equal(table.inputs, res.u)
    np.testing.assert_array_equal(table.outputs, res.y)
    assert table.columns == ("t", *res.input_names, *res.output_names)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("name", sorted(FAULT))
def test_bag_and_its_map_read_back_the_run(tmp_path: Path, name: str, storage: str) -> None:
    out = simulate_model_command(
        DATA / f"{name}.yaml", tmp_path / "bag", storage, offset=0.5, faults=[FAULT[name]],
        prefix="plant/", **OPTIONS,
    )  # fmt: skip
    res = run(name)
    imap = load_interface_map(tmp_path / "bag.map.yaml")
    assert imap == mr.bag_interface_map(res.input_names, res.output_names, "plant/")
    topics = imap.topics()
    assert set(topics) == {f"plant/{n}" for n in (*res.input_names, *res.output_names)}
    with open_bag(out) as bag:
        settings = json.loads(bag.info.custom_data[CUSTOM_DATA_KEY])
        assert settings["faults"] == [FAULT[name]]
        assert settings["model"] == name
        values: dict[str, list[tuple[int, float]]] = {t: [] for t in topics}
        for m in bag.messages(list(topics)):
            (binding,) = topics[m.topic].bindings
            assert m.msgtype == "std_msgs/msg/Float64"
            stamp = source_stamp_ns(m.msg, binding.source, m.log_time_ns)
            values[m.topic].append((stamp, extract(m.msg, binding.source)))
    for role, data in (("input", res.u), ("output", res.y)):
        names = res.input_names if role == "input" else res.output_names
        for i, n in enumerate(names):
            stamps, vals = zip(*values[f"plant/{n}"], strict=True)
            np.testing.assert_array_equal(stamps, res.stamps_ns)
            np.testing.assert_array_equal(vals, data[:, i])


def test_recordings_are_never_overwritten_and_bad_names_are_refused(tmp_path: Path) -> None:
    model = DATA / "siso.yaml"
    simulate_model_command(model, tmp_path / "a.csv", "csv", **OPTIONS)
    with pytest.raises(BagExistsError, match="never overwritten"):
        simulate_model_command(model, tmp_path / "a.csv", "csv", **OPTIONS)
    (tmp_path / "b.map.yaml").write_text("taken")
    with pytest.raises(mp.ModelSimError, match=r"b\.map\.yaml exists"):
        simulate_model_command(model, tmp_path / "b", "mcap", **OPTIONS)
    assert not (tmp_path / "b").exists()  # nothing half written
    with pytest.raises(mp.ModelSimError, match=r"ending in \.csv"):
        simulate_model_command(model, tmp_path / "c.txt", "csv", **OPTIONS)
    with pytest.raises(Exception, match="format 'parquet'"):
        simulate_model_command(model, tmp_path / "d", "parquet", **OPTIONS)
    with pytest.raises(mp.ModelSimError, match=r"'flow'.*\['valve'\].*\['flow'\]"):
        simulate_model_command(model, tmp_path / "e", faults=["stuck_input:flow@3"], **OPTIONS)
    with pytest.raises(mp.ModelSimError, match="both an input and an output"):
        mr.check_channel_names(["x", "y"], ["y"])
    with pytest.raises(mp.ModelSimError, match=r"channel 'flow rate'.*rename it"):
        mr.check_channel_names(["u"], ["flow rate"])


def test_map_path_sits_beside_the_recording() -> None:
    assert mr.interface_map_path("/r/run.csv") == Path("/r/run.map.yaml")
    assert mr.interface_map_path("/r/run_bag") == Path("/r/run_bag.map.yaml")
