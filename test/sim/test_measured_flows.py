"""The shipped ``measured_flows`` scenario: the rig's flows logged by noisy flow meters.

One bag of the scenario (shortened to 7 periods) holds the exact commands (``flow_cmd``) and
the meters' readings (``flow_meter``) of the same run, the outputs and their sensor noise
being the same. Reading the inputs from ``flow_cmd`` (the two-tank preset) is the same
seed's noise-free record: the reference. Through the map written beside the bag (inputs
``kind: measured``) every window the reference judges is judged, Model B's β stays below 1
and within the window's reported ``input_noise_effect`` of the reference β (docs/theory.md
§11: the first-order bound of the move), the reported input noise is the injected one, and
Model A is still invalidated. Marked ``kind: commanded`` the same readings are refused by the
periodicity gate in every window.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from twotank_validation import cli
from twotank_validation.sim.model_record import interface_map_path
from twotank_validation.sim.scenario import (
    ScenarioError,
    flow_meter_readings,
    iter_metered,
    load_scenario,
    simulate_scenario,
)

PERIODS = 7


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    shipped = load_scenario("measured_flows")
    short = dataclasses.replace(shipped, duration_s=PERIODS * shipped.period_samples * shipped.ts_s)
    path = tmp_path_factory.mktemp("scenario") / "measured_flows.yaml"
    path.write_text(yaml.safe_dump(short.to_dict()))
    return path


@pytest.fixture(scope="module")
def bag(scenario_file: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bag") / "mf"
    assert cli.main(["simulate", "--scenario", str(scenario_file), "--out", str(out)]) == 0
    assert interface_map_path(out).is_file()
    return out


def _windows(bag: Path, *options: str) -> dict[str, list[dict[str, Any]]]:
    summary = bag.with_name(f"summary{len(list(bag.parent.glob('summary*')))}.json")
    code = cli.main(
        [
            "validate", str(bag), *options, "--model", "A", "--model", "B",
            "--quiet", "--no-diagnosis", "--json", str(summary),
        ]
    )  # fmt: skip
    assert code == cli.EXIT_OK
    models = json.loads(summary.read_text())["models"]
    return {m: models[m]["windows"] for m in ("A", "B")}


def test_the_meters_read_the_commands_plus_noise_of_its_own_stream(scenario_file: Path) -> None:
    scen = load_scenario(scenario_file)
    assert scen.noise_std_temperature >= 2 * 0.01  # well above the default sensor noise
    _, commands, measured = simulate_scenario(scen)
    rows = np.array(list(iter_metered(scen)))
    np.testing.assert_array_equal(rows[:, 1:3], commands)
    np.testing.assert_array_equal(rows[:, 3:5], measured)
    reading = flow_meter_readings(scen, commands)
    np.testing.assert_array_equal(rows[:, 5:7], reading)
    # the sensor noise does not depend on the meters: the noise-free run's outputs are equal
    _, _, clean = simulate_scenario(dataclasses.replace(scen, flow_meter_noise=0.0))
    np.testing.assert_array_equal(clean, measured)
    rms = np.array([scen.rms_hot, scen.rms_cold])
    std = np.std(reading - commands, axis=0) / rms
    # a sample standard deviation of n normals: relative standard error 1/sqrt(2n)
    assert std == pytest.approx([scen.flow_meter_noise] * 2, rel=4 / np.sqrt(2 * len(reading)))


def test_measured_flows_are_judged_within_the_noise_effect_and_commanded_ones_refused(
    bag: Path,
) -> None:
    reference = _windows(bag)  # the preset: inputs from flow_cmd, the exact commands
    measured = _windows(bag, "--map", str(interface_map_path(bag)))
    judged_ref = [w for w in reference["B"] if w["beta"] is not None]
    assert len(judged_ref) >= 4 * (PERIODS - 3)
    noise = load_scenario("measured_flows").flow_meter_noise
    se = 0.5 * np.sqrt(2.0 / 2048)  # sigma from 2 periods of 2048: 2048 degrees of freedom
    for model in ("A", "B"):
        assert len(measured[model]) == len(reference[model])
        for w, ref in zip(measured[model], reference[model], strict=True):
            assert (w["beta"] is None) == (ref["beta"] is None), (w, ref)
            if ref["beta"] is None:
                continue
            assert w["input_noise"] == pytest.approx(noise, rel=4 * se)
            assert w["input_noise_effect"] > 0.0
            assert abs(w["beta"] - ref["beta"]) <= w["input_noise_effect"], (w, ref)
            if model == "B":
                assert w["beta"] < 1.0
            else:
                assert w["beta"] > 1.0  # Model A lacks the coupling: still invalidated
    commanded_map = bag.with_name("commanded.map.yaml")
    commanded_map.write_text(
        interface_map_path(bag).read_text().replace("kind: measured", "kind: commanded")
    )
    summary = bag.with_name("commanded.json")
    code = cli.main(
        [
            "validate", str(bag), "--map", str(commanded_map), "--model", "B", "--quiet",
            "--no-diagnosis", "--json", str(summary),
        ]
    )  # fmt: skip
    assert code != cli.EXIT_OK  # nothing judged is never exit 0
    windows = json.loads(summary.read_text())["models"]["B"]["windows"]
    assert windows
    assert all(w["beta"] is None for w in windows)
    judged_before = {w["start"] for w in judged_ref}
    refused = [w for w in windows if w["start"] in judged_before]
    assert refused
    assert all("input not periodic" in w["reason"] for w in refused), refused


def test_bad_meter_noise_and_an_existing_map_are_clear_errors(
    scenario_file: Path, tmp_path: Path, capsys
) -> None:
    with pytest.raises(ScenarioError, match=r"flow_meter_noise=0.1 must be <= 0.05"):
        dataclasses.replace(load_scenario(scenario_file), flow_meter_noise=0.1)
    out = tmp_path / "taken"
    interface_map_path(out).write_text("mine")
    code = cli.main(["simulate", "--scenario", str(scenario_file), "--out", str(out)])
    assert code == cli.EXIT_ERROR
    assert "exists already" in capsys.readouterr().err
    assert not out.exists()
    assert interface_map_path(out).read_text() == "mine"
