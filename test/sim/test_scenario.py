"""Scenarios: validation, loading, shipped files, and simulation against independent references.

References: ``simulator.simulate`` driven by commands built here from ``excitation`` (the scenario
module runs its own sample-by-sample loop) and the paper's experiment as the demo runs it
(``experiment.simulate_datum``).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader

from twotank_validation import experiment
from twotank_validation.bags import (
    BagError,
    BagExistsError,
    simulate_command,
    write_scenario_bag,
)
from twotank_validation.errors import DatumError, ModelError, TwotankError
from twotank_validation.online.streams import RigUnits
from twotank_validation.sim import excitation, faults, rig, simulator
from twotank_validation.sim.faults import parse_fault
from twotank_validation.sim.scenario import (
    Scenario,
    ScenarioError,
    load_scenario,
    scenario_from_dict,
    shipped_scenarios,
    simulate_scenario,
)


def _reference(
    s: Scenario, substeps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # (time, commands, measured)
    """The scenario rebuilt from the rig and excitation modules, run by simulator.simulate."""
    params = rig.RigParams(
        mixing_delay_s=s.mixing_delay_s,
        noise_std_height=s.noise_std_height,
        noise_std_temperature=s.noise_std_temperature,
    )
    op = rig.operating_point(params, s.height, s.temperature)
    cfg = excitation.ExcitationConfig(
        kind=s.excitation_kind,
        ts_s=s.ts_s,
        period_samples=s.period_samples,
        rms=(s.rms_hot, s.rms_cold),
        cutoff_hz=s.cutoff_hz,
        f_max_hz=s.f_max_hz,
        odd_only=s.odd_only,
        seed=s.excitation_seed,
    )
    period = excitation.excitation_period(cfg)
    n = round(s.duration_s / s.ts_s)
    commands = op.commands + period[np.arange(n) % s.period_samples]
    sim = simulator.simulate(
        params,
        commands,
        s.ts_s,
        op=op,
        seed=s.seed,
        substeps=substeps,
        faults=[parse_fault(f) for f in s.faults],
    )
    return sim.time_s, sim.commands, sim.measured


@pytest.mark.parametrize(
    ("overrides", "substeps"),
    [
        (
            {
                "duration_s": 300.0,
                "faults": ("leak=0.03@100", "sensor_delay:temperature=5@150-250"),
                "seed": 7,
            },
            4,
        ),
        (
            {
                "duration_s": 800.0,
                "ts_s": 0.8,
                "period_samples": 256,
                "excitation_kind": "multisine",
                "rms_hot": 0.03,
                "rms_cold": 0.1,
                "f_max_hz": 0.02,
                "odd_only": True,
                "excitation_seed": 5,
                "faults": ("valve_weak:hot=0.6@400",),
            },
            32,
        ),
    ],
)
def test_simulate_scenario_equals_rig_simulate(overrides: dict[str, Any], substeps: int) -> None:
    s = Scenario(name="x", **overrides)
    stamps, u, y = simulate_scenario(s)
    time_s, u_ref, y_ref = _reference(s, substeps)
    assert stamps.dtype == np.int64
    ts_ns = round(overrides.get("ts_s", 0.1) * 1e9)
    np.testing.assert_array_equal(stamps, np.arange(len(time_s), dtype=np.int64) * ts_ns)
    np.testing.assert_array_equal(u, u_ref)
    np.testing.assert_array_equal(y, y_ref)


def test_paper_scenario_is_the_demo_experiment() -> None:
    s = load_scenario("paper")
    _, u, y = simulate_scenario(s)
    assert len(u) == 7 * 2048
    _, u_rec, y_rec, _ = experiment.simulate_datum(experiment.ExperimentConfig())
    np.testing.assert_array_equal(u[5 * 2048 :], u_rec)
    np.testing.assert_array_equal(y[5 * 2048 :], y_rec)


def test_shipped_scenarios() -> None:
    names = shipped_scenarios()
    assert {"nominal", "paper"} <= set(names)
    kinds = set()
    for name in names:
        s = load_scenario(name)
        assert s.name == name
        assert s.description.strip()
        for spec in s.faults:
            fault = parse_fault(spec)
            kinds.add(fault.kind)
            assert 0.0 < fault.onset_s < s.duration_s
    assert kinds == set(faults.FAULT_KINDS)
    for kind in faults.FAULT_KINDS:  # one scenario per kind, named after it, onset mid-run
        s = load_scenario(kind)
        (spec,) = s.faults
        assert parse_fault(spec).kind == kind
        assert 0.2 < parse_fault(spec).onset_s / s.duration_s < 0.8
    nominal = load_scenario("nominal")
    assert (nominal.duration_s, nominal.faults) == (3000.0, ())
    paper = load_scenario("paper")
    assert paper.duration_s == pytest.approx(7 * 2048 * 0.1)
    assert paper.n_samples == 14336


def test_shipped_files_are_package_data() -> None:
    root = Path(__file__).resolve().parents[2]
    folder = root / "twotank_validation" / "sim" / "scenarios"
    files = sorted(p.stem for p in folder.glob("*.yaml"))
    assert files == list(shipped_scenarios())
    assert '"sim/scenarios/*.yaml"' in (root / "setup.py").read_text()


def test_defaults_and_derived_settings() -> None:
    s = Scenario(name="d", duration_s=10.0)
    assert (s.ts_s, s.period_samples, s.height, s.temperature) == (0.1, 2048, 0.47, 0.5)
    assert (s.rms_hot, s.rms_cold, s.cutoff_hz, s.excitation_seed, s.seed) == (
        0.05,
        0.2,
        0.006,
        2,
        0,
    )
    assert (s.noise_std_height, s.noise_std_temperature, s.mixing_delay_s) == (0.003, 0.01, 15.0)
    assert s.units == RigUnits()
    assert (s.n_samples, s.ts_ns, s.substeps) == (100, 100_000_000, 4)
    assert Scenario(name="d", duration_s=8.0, ts_s=0.8, period_samples=256).substeps == 32
    assert Scenario(name="d", duration_s=1.0, ts_s=0.01).substeps == 4


@pytest.mark.parametrize(
    ("changes", "error", "match"),
    [
        ({"duration_s": 0.0}, ScenarioError, "duration_s=0.0 must be > 0"),
        ({"duration_s": 10.05}, ScenarioError, "duration_s=10.05 must be a whole number"),
        ({"duration_s": "10"}, ScenarioError, "duration_s='10' is not a number"),
        ({"ts_s": -0.1}, ScenarioError, "ts_s=-0.1 must be > 0"),
        ({"ts_s": 1 / 3, "duration_s": 1.0}, ScenarioError, "ts_s=.* whole number of nano"),
        ({"period_samples": 2}, ScenarioError, "period_samples=2 must be an integer >= 4"),
        ({"period_samples": 100.0}, ScenarioError, "period_samples=100.0 must be an integer"),
        ({"height": 0.9}, ScenarioError, "height=0.9 must be <= 0.75"),
        ({"temperature": 1.5}, ScenarioError, "temperature=1.5 .* outside the valve range"),
        ({"temperature": math.nan}, ScenarioError, "temperature=nan must be finite"),
        ({"excitation_kind": "chirp"}, ScenarioError, "excitation_kind='chirp' is unknown"),
        ({"rms_hot": -0.1}, ScenarioError, "rms_hot=-0.1 must be >= 0"),
        ({"rms_cold": True}, ScenarioError, "rms_cold=True is not a number"),
        ({"cutoff_hz": "1e-3"}, ScenarioError, "cutoff_hz='1e-3' .* with a dot"),
        ({"cutoff_hz": 5.0}, ScenarioError, "cutoff_hz=5.0 must be below the Nyquist"),
        ({"f_max_hz": 0.0}, ScenarioError, "f_max_hz=0.0 must be > 0"),
        ({"odd_only": "yes"}, ScenarioError, "odd_only='yes' must be true or false"),
        ({"excitation_seed": -1}, ScenarioError, "excitation_seed=-1 must be an integer >= 0"),
        ({"seed": 1.5}, ScenarioError, "seed=1.5 must be an integer"),
        ({"noise_std_height": -1.0}, ScenarioError, "noise_std_height=-1.0 must be >= 0"),
        ({"noise_std_temperature": math.inf}, ScenarioError, "noise_std_temperature=inf"),
        ({"mixing_delay_s": -1.0}, ScenarioError, "mixing_delay_s=-1.0 must be >= 0"),
        ({"faults": "leak=0.1@5"}, ScenarioError, "faults='leak=0.1@5' must be a list"),
        ({"faults": ("leak=2@5",)}, ScenarioError, r"faults\[0\]: .*leak"),
        ({"faults": ("leak=0.1@5", "flood@3")}, ScenarioError, r"faults\[1\]: .*not a known"),
        ({"faults": ("leak",)}, ScenarioError, r"faults\[0\]: .*KIND"),
        ({"faults": ("leak=0.1@10",)}, ScenarioError, r"faults\[0\]=.* starts at 10 s"),
        ({"faults": (3,)}, ScenarioError, r"faults\[0\]=3 must be a fault spec string"),
        ({"name": ""}, ScenarioError, "name='' must be a non-empty string"),
        ({"description": 3}, ScenarioError, "description=3 must be a string"),
        ({"units": {"pascal_per_unit": 1.0}}, ScenarioError, "units=.* must be a RigUnits"),
        ({"rms_cold": 0.6}, DatumError, "excitation .* cold valve command leaves.* rms_cold <="),
    ],
)
def test_invalid_scenarios_name_the_key(
    changes: dict[str, Any], error: type[Exception], match: str
) -> None:
    kwargs: dict[str, Any] = {"name": "bad", "duration_s": 10.0} | changes
    with pytest.raises(error, match=match) as info:
        Scenario(**kwargs)
    assert isinstance(info.value, TwotankError)
    if error is ScenarioError:
        assert isinstance(info.value, ModelError)


def _write_yaml(path: Path, doc: object) -> Path:
    path.write_text(yaml.safe_dump(doc))
    return path


def test_load_from_file_and_round_trip(tmp_path: Path) -> None:
    doc = {
        "description": "custom",
        "duration_s": 20,
        "period_samples": 64,
        "cutoff_hz": 0.05,
        "rms_cold": 0.1,
        "faults": ["mixing_delay=30@10"],
        "units": {"pascal_per_unit": 1000.0, "temperature_offset_c": 10},
    }
    s = load_scenario(_write_yaml(tmp_path / "my_run.yaml", doc))
    assert s.name == "my_run"  # from the file name
    assert s.duration_s == 20.0
    assert s.faults == ("mixing_delay=30@10",)
    assert s.units == RigUnits(pascal_per_unit=1000.0, temperature_offset_c=10.0)
    assert scenario_from_dict(s.to_dict(), "dict") == s
    assert load_scenario(str(tmp_path / "my_run.yaml")) == s
    back = load_scenario(_write_yaml(tmp_path / "again.yaml", s.to_dict()))
    assert back == s


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        (
            {"duration_s": 10, "durration": 3},
            r"unknown key\(s\) \['durration'\]; allowed keys: name",
        ),
        ({"name": "x"}, "the key duration_s .* is missing"),
        ([1, 2], "must be a mapping"),
        ({"duration_s": 10, "units": {"pascal": 3}}, r"unknown key\(s\) \['pascal'\] in units"),
        ({"duration_s": 10, "units": {"temperature_span_c": -5.0}}, "units: .*positive"),
        ({"duration_s": 10, "units": {"pascal_per_unit": "x"}}, "units.pascal_per_unit='x'"),
        ({"duration_s": 10, "units": 3}, "units must be a mapping"),
        ({"duration_s": 10, "ts_s": 0}, r"bad\.yaml: scenario 'bad': ts_s=0"),
    ],
)
def test_load_rejects_bad_files(tmp_path: Path, doc: object, match: str) -> None:
    with pytest.raises(ScenarioError, match=match):
        load_scenario(_write_yaml(tmp_path / "bad.yaml", doc))


def test_load_unknown_name_and_broken_yaml(tmp_path: Path) -> None:
    with pytest.raises(
        ScenarioError, match=r"neither a file nor a shipped scenario; shipped: .*nominal"
    ):
        load_scenario("no_such_scenario")
    broken = tmp_path / "broken.yaml"
    broken.write_text("duration_s: [1, 2\n")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(broken)
    with pytest.raises(ScenarioError, match=r"allowed keys: .*faults"):
        load_scenario(_write_yaml(tmp_path / "k.yaml", {"duration_s": 1, "fault": []}))


def test_simulate_command_writes_the_bag(tmp_path: Path) -> None:
    path = tmp_path / "run.yaml"
    _write_yaml(path, {"duration_s": 5, "period_samples": 16, "cutoff_hz": 0.5})
    out = simulate_command(str(path), str(tmp_path / "bag"), "sqlite3")
    assert out == tmp_path / "bag"
    assert (out / "bag.db3").is_file()
    with AnyReader([out]) as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == {
            "flow_cmd": 50,
            "height": 50,
            "temperature": 50,
        }
    with pytest.raises(BagExistsError, match="exists already"):
        simulate_command(str(path), str(out), "mcap")
    with pytest.raises(BagError, match="--storage 'bag'"):
        simulate_command(str(path), str(tmp_path / "other"), "bag")
    with pytest.raises(ScenarioError, match="shipped"):
        simulate_command("nope", str(tmp_path / "other"), "mcap")
    assert not (tmp_path / "other").exists()


def test_failed_run_leaves_no_bag(tmp_path: Path) -> None:
    # A leak of 1.0 (more than the whole inflow) empties the tank within about a minute.
    s = Scenario(name="drain", duration_s=300.0, faults=("leak=1@10",))
    with pytest.raises(ModelError, match="tank is empty"):
        write_scenario_bag(s, tmp_path / "drain")
    assert not (tmp_path / "drain").exists()


def test_progress_bar(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    s = Scenario(name="tiny", duration_s=2.0, period_samples=16, cutoff_hz=0.5)
    write_scenario_bag(s, tmp_path / "quiet")  # default: only on a TTY and > 20k samples
    assert "bag tiny" not in capsys.readouterr().err
    write_scenario_bag(s, tmp_path / "loud", progress=True)
    assert "bag tiny" in capsys.readouterr().err


def test_replace_revalidates() -> None:
    s = load_scenario("nominal")
    with pytest.raises(ScenarioError, match="duration_s"):
        dataclasses.replace(s, duration_s=-1.0)
