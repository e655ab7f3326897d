"""Channels matched by name, any shape: the interface map's sources to each model's channels.

References: the same model written with its channels in another order (rows and columns of
its state space permuted to match) must give the original's beta on the same data; a plant of
another shape (1x1, 1x3, 3x2) read from a table must give, window by window, the beta of
``validate()`` on the same samples (the core, no stream path); names that do not match are an
error that lists both sides, never a positional match.
"""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import signal

from twotank_validation import cli, replay
from twotank_validation.bags import write_scenario_bag
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model_document, model_from_dict
from twotank_validation.core.validate import validate
from twotank_validation.online import MonitorConfig, OnlineValidator
from twotank_validation.online.channels import ChannelError, match_channels
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.online.sources import Source, TimeColumn
from twotank_validation.sim import scenario as sc

FAST = MonitorConfig(ts_s=0.8, period_samples=256, hop_samples=256)


def _model_b() -> dict[str, Any]:
    return copy.deepcopy(load_model_document("B")[0])


def reordered(doc: dict[str, Any], inputs: list[int], outputs: list[int], name: str) -> dict:
    """The same model with its inputs and outputs listed in another order.

    ``inputs``/``outputs``: the new order as indices into the old lists; the nominal's B and
    D columns and C and D rows follow. Perturbations and noise name their channels by name,
    so they need nothing.
    """
    out = copy.deepcopy(doc)
    out["name"] = name
    out["inputs"] = [doc["inputs"][i] for i in inputs]
    out["outputs"] = [doc["outputs"][i] for i in outputs]
    ss = out["nominal"]["ss"]
    b, c, d = (np.array(ss[k], dtype=float) for k in ("B", "C", "D"))
    ss["B"] = b[:, inputs].tolist()
    ss["C"] = c[outputs].tolist()
    ss["D"] = d[np.ix_(outputs, inputs)].tolist()
    return out


def renamed(doc: dict[str, Any], names: dict[str, str], name: str) -> dict[str, Any]:
    """The same model with its channels renamed (everywhere the file names them)."""
    text = yaml.safe_dump(doc)
    out = yaml.safe_load(text)
    out["name"] = name
    out["inputs"] = [names.get(n, n) for n in doc["inputs"]]
    out["outputs"] = [names.get(n, n) for n in doc["outputs"]]
    if "operating_point" in out:
        out["operating_point"] = {names.get(k, k): v for k, v in out["operating_point"].items()}
    for section in ("perturbations", "noise"):
        for entry in out.get(section, []):
            for key in ("inputs", "outputs"):
                if key in entry:
                    entry[key] = [names.get(n, n) for n in entry[key]]
    return out


# ------------------------------------------------------------------ the matching itself


def test_match_channels_places_each_model_by_name() -> None:
    b = model_from_dict(_model_b())
    swapped = model_from_dict(reordered(_model_b(), [1, 0], [1, 0], "S"))
    ch = match_channels(("hot", "cold"), ("height", "temperature"), [b, swapped])
    assert ch.models["B"].identity
    assert (ch.models["S"].inputs, ch.models["S"].outputs) == ((1, 0), (1, 0))
    u = np.arange(6.0).reshape(3, 2)
    y = -np.arange(6.0).reshape(3, 2)
    su, sy = ch.models["S"].select(u, y)
    assert np.array_equal(su, u[:, ::-1])
    assert np.array_equal(sy, y[:, ::-1])


def test_a_model_channel_the_map_lacks_is_an_error_listing_both_sides() -> None:
    b = model_from_dict(renamed(_model_b(), {"height": "level"}, "L"))
    with pytest.raises(ChannelError) as info:
        match_channels(("hot", "cold"), ("height", "temperature"), [b], source="the map m.yaml")
    text = str(info.value)
    assert "model L names output 'level', which the map m.yaml does not carry" in text
    assert "outputs [level, temperature]" in text  # the model's side
    assert "outputs [height, temperature]" in text  # the map's side
    assert "Channels are matched by name" in text


def test_a_map_channel_no_model_names_is_an_error() -> None:
    b = model_from_dict(_model_b())
    with pytest.raises(ChannelError, match="carries output 'flow', which no model names"):
        match_channels(("hot", "cold"), ("height", "temperature", "flow"), [b])


def test_models_may_share_the_channels_they_name() -> None:
    """One model on the level alone, one on the temperature alone: together they name all."""
    doc = _model_b()
    ss = doc["nominal"]["ss"]
    level = copy.deepcopy(doc)
    level.update(name="H", outputs=["height"], operating_point={"height": 0.47})
    level["nominal"]["ss"].update(C=[ss["C"][0]], D=[ss["D"][0]])
    level["perturbations"] = [p for p in doc["perturbations"] if p["outputs"] == ["height"]]
    level["noise"] = [n for n in doc["noise"] if n["outputs"] == ["height"]]
    h = model_from_dict(level)
    ch = match_channels(("hot", "cold"), ("height", "temperature"), [h, model_from_dict(doc)])
    assert ch.models["H"].outputs == (0,)
    with pytest.raises(ChannelError, match="carries output 'temperature', which no model"):
        match_channels(("hot", "cold"), ("height", "temperature"), [h])


# ------------------------------------------------------------------ the two-tank rig, reordered


@pytest.fixture(scope="module")
def nominal_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    scen = dataclasses.replace(
        sc.load_scenario("nominal"), ts_s=0.8, period_samples=256, duration_s=8 * 204.8
    )
    return write_scenario_bag(scen, tmp_path_factory.mktemp("bag") / "nominal")


def test_model_b_with_its_channels_reordered_gives_the_originals_beta(nominal_bag: Path) -> None:
    """Outputs [temperature, height] (C and D rows swapped) and inputs [cold, hot]: the same
    model, so the same beta on every window, through the same (two-tank) interface."""
    b = model_from_dict(_model_b())
    s = model_from_dict(reordered(_model_b(), [1, 0], [1, 0], "S"))
    res = replay.replay_bag(nominal_bag, [b, s], replay.ReplayConfig(monitor=FAST))
    by = {m: [r for r in res.reports if r.model == m and r.judged] for m in ("B", "S")}
    assert len(by["B"]) >= 3
    assert len(by["B"]) == len(by["S"])
    for rb, rs in zip(by["B"], by["S"], strict=True):
        assert rs.beta == pytest.approx(rb.beta, rel=1e-9)
        assert rs.beta_op == pytest.approx(rb.beta_op, rel=1e-6, abs=1e-12, nan_ok=True)
        assert rs.alarm == rb.alarm
    assert sum(np.isfinite(r.beta_op) for r in by["S"]) >= 2  # the operating point checked
    assert max(r.beta for r in by["B"]) < 1.0  # nominal data, Model B: not invalidated


def test_renamed_channels_need_a_map_that_names_them(nominal_bag: Path, tmp_path, capsys) -> None:
    """Renamed consistently (level, temp): the two-tank preset does not carry those names
    (exit 2, both sides listed); a map that reads the rig's topics under those names gives
    the original's beta."""
    doc = renamed(reordered(_model_b(), [0, 1], [1, 0], "R"), {"height": "level"}, "R")
    model_file = tmp_path / "r.yaml"
    model_file.write_text(yaml.safe_dump(doc))
    code = cli.main(["validate", str(nominal_bag), "--model", str(model_file), "--quiet"])
    err = capsys.readouterr().err
    assert code == cli.EXIT_ERROR
    assert "model R names output 'level', which the two-tank interface" in err
    assert "Traceback" not in err
    for command in (["diagnose"], ["calibrate"]):
        code = cli.main([*command, str(nominal_bag), "--model", str(model_file)])
        err = capsys.readouterr().err
        assert code == cli.EXIT_ERROR, (command, err)
        assert "names output 'level'" in err
        assert "Traceback" not in err
    imap = [
        "--input", "hot=flow_cmd:twotank_validation_msgs/msg/FlowCommand:hot",
        "--input", "cold=flow_cmd:twotank_validation_msgs/msg/FlowCommand:cold",
        "--output", "level=height:sensor_msgs/msg/FluidPressure:fluid_pressure,scale=9806.65",
        "--output", "temperature=temperature:sensor_msgs/msg/Temperature:temperature,"
        "offset=15,scale=50",
    ]  # fmt: skip
    betas = {}
    for name, extra in (("R", ["--model", str(model_file), *imap]), ("B", ["--model", "B"])):
        out = tmp_path / f"{name}.json"
        code = cli.main(["validate", str(nominal_bag), *extra, "--quiet", "--json", str(out)])
        assert code == cli.EXIT_OK, capsys.readouterr().err
        windows = json.loads(out.read_text())["models"][name]["windows"]
        betas[name] = [w["beta"] for w in windows if w["reason"] is None]
    assert len(betas["B"]) >= 3
    assert betas["R"] == pytest.approx(betas["B"], rel=1e-9)


# ------------------------------------------------------------------ other shapes, from a table


def _plant_doc(name: str, nu: int, ny: int, seed: int) -> dict[str, Any]:
    """A stable first-order-per-output plant with ``nu`` inputs and ``ny`` outputs, an
    output-multiplicative uncertainty on the first output and a noise weight on each."""
    rng = np.random.default_rng(seed)
    inputs = [f"u{i}" for i in range(nu)]
    outputs = [f"y{j}" for j in range(ny)]
    a = -np.diag(rng.uniform(0.02, 0.08, ny))
    b = rng.uniform(0.01, 0.05, (ny, nu))
    return {
        "name": name,
        "inputs": inputs,
        "outputs": outputs,
        "nominal": {
            "ss": {
                "A": a.tolist(),
                "B": b.tolist(),
                "C": np.eye(ny).tolist(),
                "D": [[0.0] * nu] * ny,
            }
        },
        "perturbations": [
            {
                "name": "first",
                "kind": "output_multiplicative",
                "outputs": [outputs[0]],
                "weight": {"tf": {"num": [0.05], "den": [1.0]}},
            }
        ],
        "noise": [
            {"name": f"n_{o}", "outputs": [o], "weight": {"tf": {"num": [0.004], "den": [1.0]}}}
            for o in outputs
        ],
    }


def _simulate(doc: dict[str, Any], ts_s: float, period: int, periods: int, seed: int):
    """Stamps (ns), u (n, nu) and y (n, ny): the ZOH-discretised nominal (scipy.signal) driven
    by a periodic random-phase input, plus white noise well inside the noise weight."""
    rng = np.random.default_rng(seed)
    ss = doc["nominal"]["ss"]
    nu, ny = len(doc["inputs"]), len(doc["outputs"])
    sysd = signal.cont2discrete(
        tuple(np.array(ss[k], dtype=float) for k in ("A", "B", "C", "D")), ts_s, method="zoh"
    )
    one = rng.standard_normal((period, nu)) * 0.1
    u = 0.5 + np.tile(one, (periods, 1))
    n = len(u)
    _, y, _ = signal.dlsim((*sysd[:4], ts_s), u - 0.5)
    y = np.asarray(y).reshape(n, ny) + 0.3 + 0.001 * rng.standard_normal((n, ny))
    stamps = np.arange(n, dtype=np.int64) * round(ts_s * 1e9)
    return stamps, u, y


@pytest.mark.parametrize(("nu", "ny"), [(1, 1), (1, 3), (3, 2)])
def test_a_plant_of_any_shape_from_a_table_gives_validates_beta(tmp_path, nu, ny) -> None:
    """The replay of a table, window by window, equals ``validate()`` on the same samples."""
    doc = _plant_doc("P", nu, ny, seed=nu * 10 + ny)
    model = model_from_dict(doc)
    cfg = MonitorConfig(ts_s=1.0, period_samples=128, hop_samples=128)
    stamps, u, y = _simulate(doc, 1.0, 128, 8, seed=ny)
    frame = pd.DataFrame({"t": stamps / 1e9})
    for i, name in enumerate(doc["inputs"]):
        frame[f"col_{name}"] = u[:, i]
    for j, name in enumerate(doc["outputs"]):
        frame[f"col_{name}"] = y[:, j]
    path = tmp_path / "log.csv"
    frame.to_csv(path, index=False)
    # the map lists the outputs in reverse order: matched by name, not position
    imap = InterfaceMap(
        tuple(Source(n, column=f"col_{n}") for n in doc["inputs"]),
        tuple(Source(n, column=f"col_{n}") for n in reversed(doc["outputs"])),
        TimeColumn("t", "s"),
    )
    kept: list[tuple[Any, Any]] = []
    res = replay.replay_table(
        path,
        [model],
        replay.ReplayConfig(monitor=cfg, interface=imap),
        on_window=lambda rep, snap: kept.append((rep, snap)),
    )
    judged = [r for r in res.reports if r.judged]
    assert len(judged) >= 4
    assert len(judged) == len(kept)
    for rep, snap in kept:
        k0 = round(snap.stamps_ns[0] / 1e9)
        window = slice(k0, k0 + cfg.window_samples)
        datum = make_datum(u[window], y[window], ts_s=1.0, period_samples=128)
        want = validate(datum, model).beta
        assert rep.beta == pytest.approx(want, rel=1e-9, abs=1e-12)
        assert np.array_equal(snap.y, y[window])  # the model's order, from a reversed map
    assert max(r.beta for r in judged) < 1.0


def test_the_online_validator_takes_a_1x3_plants_topics() -> None:
    """feed by topic: one Float64MultiArray-like topic carrying all three outputs."""
    doc = _plant_doc("P", 1, 3, seed=5)
    model = model_from_dict(doc)
    imap = InterfaceMap(
        (Source("u0", "/cmd", "std_msgs/msg/Float64", "data", stamp="receive"),),
        tuple(
            Source(f"y{j}", "/ys", "std_msgs/msg/Float64MultiArray", f"data[{j}]", stamp="receive")
            for j in range(3)
        ),
    )
    cfg = MonitorConfig(ts_s=1.0, period_samples=128, hop_samples=128)
    core = OnlineValidator(cfg, [model], interface=imap)
    assert core.topics == ("/cmd", "/ys")
    stamps, u, y = _simulate(doc, 1.0, 128, 6, seed=3)
    reports = []
    for k in range(len(stamps)):
        reports += core.feed("/cmd", int(stamps[k]), float(u[k, 0]))
        reports += core.feed("/ys", int(stamps[k]), tuple(y[k]))
    judged = [r for r in reports if r.judged]
    assert judged
    last = judged[-1]
    n = cfg.window_samples
    datum = make_datum(u[-n:], y[-n:], ts_s=1.0, period_samples=128)
    assert last.beta == pytest.approx(validate(datum, model).beta, rel=1e-9)


def test_fleet_and_live_refuse_mismatched_names_before_any_work(
    nominal_bag: Path, tmp_path, capsys
) -> None:
    """Several recordings, or the live composition, with a model whose channels the two-tank
    interface does not carry: exit 2 naming both sides, before any task or node runs."""
    doc = renamed(_model_b(), {"height": "level"}, "R")
    model_file = tmp_path / "r.yaml"
    model_file.write_text(yaml.safe_dump(doc))
    out = tmp_path / "fleet"
    args = ["validate", str(nominal_bag), str(nominal_bag.parent), "--out", str(out)]
    code = cli.main([*args, "--model", str(model_file), "--serial", "--quiet"])
    err = capsys.readouterr().err
    assert code == cli.EXIT_ERROR
    assert "model R names output 'level', which the two-tank interface" in err
    assert not out.exists()  # nothing ran
    code = cli.main(["live", "--model", str(model_file), "--duration", "20"])
    err = capsys.readouterr().err
    assert code == cli.EXIT_ERROR
    assert "names output 'level'" in err
    assert "Traceback" not in err
