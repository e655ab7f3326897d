"""The settings tree and its front ends agree: node parameters, CLI options, docs (issue 26).

Each setting is declared once, as a field of a config dataclass
(:mod:`twotank_validation.settings`, the root
:class:`~twotank_validation.online.validator_settings.ValidatorSettings`). These tests are the
register, as python-control's ``kwargs_test.py`` is for its keywords: a node parameter, a CLI
option or a docs row that is not a setting of the tree (or listed below with the reason it is
not one) fails, and so does a setting that no front end exposes and no reason hides, or a
default, range or choice that differs anywhere.
"""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path
from typing import Any

import pytest

from twotank_validation.cli import build_parser, option_dest
from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.online import MonitorConfig
from twotank_validation.online.validator_settings import VALIDATOR_SETTINGS, ValidatorSettings
from twotank_validation.settings import FlatSetting, SettingError, flat, from_flat
from twotank_validation.sim.excitation import RIG_DESIGN, ExcitationDesign

DOCS = Path(__file__).resolve().parent.parent / "docs"
BY_NAME = {s.name: s for s in VALIDATOR_SETTINGS}
EXPOSED = [s for s in VALIDATOR_SETTINGS if not s.meta.hidden]
BY_OPTION = {
    s.meta.option: s for s in VALIDATOR_SETTINGS if s.meta.option and s.path[0] == "monitor"
}
"""The bag commands' window and alarm options."""
LIVE_OPTIONS = {
    s.meta.option: s for s in VALIDATOR_SETTINGS if s.meta.option and s.path[0] == "evidence"
}
"""``live``'s options of the tree: the evidence on an alarm (validator parameters)."""

NOT_SETTINGS_PARAMS = {
    "pascal_per_unit": "interface: unit conversion (RigUnits), shared by the converting nodes",
    "temperature_offset_c": "interface: unit conversion (RigUnits)",
    "temperature_span_c": "interface: unit conversion (RigUnits)",
    "interface_map": "interface: the map of topics and fields (online/interface.py)",
    "inputs": "interface: the map as text",
    "outputs": "interface: the map as text",
}
"""Validator parameters that are not settings of the tree, and why."""

TIMING_OPTIONS = {"--ts": "ts_s", "--period": "period_samples"}
"""Options named after the setting they set (``live``); the bag commands default them to None:
the recording's metadata or stamps, else the tree's default (checked below)."""

NOT_SETTINGS_OPTIONS = {
    "--help": "argparse",
    "--model": "the models: repeated in validate and live (None: the models setting's "
    "default, checked below), one in diagnose and calibrate",
    "--json": "output file",
    "--report": "output folder",
    "--out": "output folder or bag",
    "--out-model": "output file",
    "--quiet": "progress display",
    "--no-diagnosis": "turns the live diagnosis of a replay off (replay's own switch)",
    "--fail-on-alarm": "validate: the exit code when an alarm rose (not a validator setting)",
    "--topic": "interface: a two-tank topic remapped",
    "--map": "interface: the interface map",
    "--input": "interface: the map as text",
    "--output": "interface: the map as text",
    "--time": "interface: a table's time column",
    "--pascal-per-unit": "interface: unit conversion (RigUnits' default)",
    "--temperature-offset-c": "interface: unit conversion (RigUnits' default)",
    "--temperature-span-c": "interface: unit conversion (RigUnits' default)",
    "--closed-loop": "validate: sets input_periodic_rtol to the closed-loop gate and, unless "
    "--transient is given, transient to auto; live: the controller runs (not a validator "
    "setting)",
    "--workers": "fleet: Dask processes",
    "--serial": "fleet: no Dask",
    "--scheduler": "fleet: a Dask scheduler",
    "--tls-ca-file": "fleet: the Dask client's TLS files",
    "--tls-cert": "fleet: the Dask client's TLS files",
    "--tls-key": "fleet: the Dask client's TLS files",
    "--max-effects": "diagnose's own setting (the diagnosis, not the validator)",
    "--start": "diagnose: the time range",
    "--end": "diagnose: the time range",
    "--segment": "diagnose: change search inside the range",
    "--block": "calibrate: the blocks",
    "--margin": "calibrate's own setting (CalibrationConfig)",
    "--max-order": "calibrate's own setting (CalibrationConfig)",
    "--together": "calibrate's own setting (CalibrationConfig)",
    "--noise-from-data": "calibrate's own mode (calibrate.noise_from_data)",
    "--noise-budget": "calibrate --noise-from-data's own setting (core.noise_budget)",
    "--noise-quantile": "calibrate --noise-from-data's own setting (core.noise_budget)",
    "--duration": "live: the simulated run",
    "--fault": "live: the simulated plant",
    "--seed": "live, demo: the simulation",
    "--excitation-entry": "live: the controller node's parameter",
    "--supervisor": "live: the supervisor node's models",
    "--no-sdp": "demo: the cross-check",
    "--plant-model": "live: any model's simulated plant (the model plant node's model)",
    "--member": "live: the model plant node's member of its set",
    "--noise-scale": "live: the model plant node's noise",
    "--view": "validate, live: the live view (a listener of the reports, docs/view.md)",
    "--view-port": "validate, live: the live view's port",
    "--view-response": "validate, live: an identify JSON the live view shows (docs/view.md)",
    "--replay-speed": "validate --view: the replay's pace for the view",
    "--foxglove": "validate, live: the reports over Foxglove's protocol (a listener, docs/view.md)",
    "--foxglove-port": "validate, live: the Foxglove server's port",
}
# (simulate's excitation design options are the design's settings: checked below)
"""Options of the checked commands that are not settings of the tree, and why."""

COMMANDS = ("validate", "diagnose", "calibrate", "live", "demo")


# ------------------------------------------------------------------------------ the tree


def test_every_setting_is_a_parameter_or_says_why_not() -> None:
    assert len(BY_NAME) == len(VALIDATOR_SETTINGS)  # flat names are unique (flat() checks)
    for s in VALIDATOR_SETTINGS:
        assert s.meta.description, s.name
        if s.meta.hidden:
            assert len(s.meta.hidden) > 10, f"{s.name}: say why it is no parameter"
            assert not s.meta.option, f"{s.name} is hidden but a CLI option"


def test_every_field_is_a_setting_or_a_group() -> None:
    @__import__("dataclasses").dataclass(frozen=True)
    class Loose:
        x: int = 1

    with pytest.raises(TypeError, match=r"Loose\.x is neither a setting nor a group"):
        flat(Loose)


def test_the_tree_builds_the_configs_the_code_takes() -> None:
    tree = ValidatorSettings()
    assert tree.monitor == MonitorConfig()
    assert from_flat(ValidatorSettings, {}) == tree
    assert from_flat(ValidatorSettings, {s.name: s.param_default for s in EXPOSED}) == tree
    assert BY_NAME["ts_s"].default == TS_S
    assert BY_NAME["period_samples"].default == PERIOD_SAMPLES


def _outside(s: FlatSetting) -> list[Any]:
    """Values just outside the setting's range (a NaN for a float with a range)."""
    bad: list[Any] = []
    step = 1 if s.kind is int else None
    if s.meta.high is not None:
        bad.append(s.meta.high + 1 if step else s.meta.high * 1.5 + 1e-3)
    if s.meta.low is not None:
        bad.append(s.meta.low - 1 if step else s.meta.low - max(abs(s.meta.low), 1e-9))
    if s.kind is float and bad:
        bad.append(math.nan)
    return bad


@pytest.mark.parametrize("s", [s for s in VALIDATOR_SETTINGS if _outside(s)], ids=lambda s: s.name)
def test_ranges_are_enforced_by_the_configs(s: FlatSetting) -> None:
    for value in _outside(s):
        with pytest.raises(ValueError, match=re.escape(s.path[-1])) as err:
            from_flat(ValidatorSettings, {s.name: value})
        assert s.meta.range_text() in str(err.value)
    # the bounds themselves are allowed (inclusive), where the rest of the config allows them
    for bound in (s.meta.low, s.meta.high):
        if bound is not None and s.name not in ("hop_samples", "period_samples"):
            from_flat(ValidatorSettings, {s.name: bound})


@pytest.mark.parametrize(
    "s", [s for s in VALIDATOR_SETTINGS if s.meta.choices], ids=lambda s: s.name
)
def test_choices_are_enforced_by_the_configs(s: FlatSetting) -> None:
    for choice in s.meta.choices:
        from_flat(ValidatorSettings, {s.name: choice})
    with pytest.raises(ValueError, match=s.path[-1]):
        from_flat(ValidatorSettings, {s.name: "bogus"})


def test_a_range_error_names_the_setting_the_value_and_the_range() -> None:
    with pytest.raises(SettingError) as err:
        MonitorConfig(periods_per_window=65)
    assert str(err.value) == (
        "MonitorConfig.periods_per_window = 65 is outside its allowed range [1, 64]"
    )
    with pytest.raises(SettingError, match=r"alarm_evidence \(AlarmConfig.evidence\) = 0.0"):
        from_flat(MonitorConfig, {"alarm_evidence": 0.0})


# ------------------------------------------------------------------------------ node parameters


def test_validator_parameters_are_the_settings() -> None:
    from twotank_validation.ros.params import UNIT_PARAMS  # noqa: PLC0415
    from twotank_validation.ros.validator_node import VALIDATOR_PARAMS  # noqa: PLC0415

    names = [p.name for p in VALIDATOR_PARAMS]
    assert len(set(names)) == len(names)
    assert not set(NOT_SETTINGS_PARAMS) & set(BY_NAME)
    assert {p.name for p in UNIT_PARAMS} <= set(NOT_SETTINGS_PARAMS)
    for p in VALIDATOR_PARAMS:
        if p.name in NOT_SETTINGS_PARAMS:
            continue
        assert p.name in BY_NAME, f"parameter {p.name} is no setting of the tree: declare it there"
        s = BY_NAME[p.name]
        assert not s.meta.hidden, p.name
        assert p.default == s.param_default, p.name
        assert type(p.default) is type(s.param_default), p.name
        assert (p.description, p.low, p.high, p.choices) == (
            s.meta.description,
            s.meta.low,
            s.meta.high,
            s.meta.choices,
        ), p.name
    assert {s.name for s in EXPOSED} <= set(names)


def test_declared_parameters_carry_the_tree_on_a_real_node() -> None:
    """Declared on an rclpy node: values, types, ranges and constraints are the tree's."""
    import rclpy  # noqa: PLC0415
    from rcl_interfaces.msg import ParameterType  # noqa: PLC0415
    from rclpy.context import Context  # noqa: PLC0415
    from rclpy.node import Node  # noqa: PLC0415
    from rclpy.parameter import Parameter  # noqa: PLC0415

    from twotank_validation.ros.lifecycle import bring_up  # noqa: PLC0415
    from twotank_validation.ros.params import ParameterError, declare  # noqa: PLC0415
    from twotank_validation.ros.validator_node import (  # noqa: PLC0415
        VALIDATOR_PARAMS,
        ValidatorNode,
    )

    types = {
        bool: ParameterType.PARAMETER_BOOL,
        int: ParameterType.PARAMETER_INTEGER,
        float: ParameterType.PARAMETER_DOUBLE,
        str: ParameterType.PARAMETER_STRING,
    }
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = Node("settings_probe", context=ctx)
        values = declare(node, VALIDATOR_PARAMS)
        for s in EXPOSED:
            assert values[s.name] == s.param_default, s.name
            desc = node.describe_parameter(s.name)
            value = s.param_default
            if isinstance(value, list):
                assert desc.type in (
                    ParameterType.PARAMETER_STRING_ARRAY,
                    ParameterType.PARAMETER_DOUBLE_ARRAY,
                ), s.name
            else:
                assert desc.type == types[type(value)], s.name
            ranges = list(desc.integer_range) + list(desc.floating_point_range)
            if s.meta.low is not None and not isinstance(value, bool):
                assert len(ranges) == 1, s.name
                assert (ranges[0].from_value, ranges[0].to_value) == (s.meta.low, s.meta.high)
            else:
                assert not ranges, s.name
            if s.meta.choices:
                assert desc.additional_constraints == f"one of {list(s.meta.choices)}"
        node.destroy_node()
        # an out-of-range override stops a node, naming the parameter
        for s in (BY_NAME["periods_per_window"], BY_NAME["jitter_fraction"]):
            probe = Node(
                "settings_probe_bad",
                context=ctx,
                parameter_overrides=[Parameter(s.name, value=_outside(s)[0])],
            )
            with pytest.raises(ParameterError, match=s.name):
                declare(probe, VALIDATOR_PARAMS)
            probe.destroy_node()
        # the validator node itself: its config is the tree's, with overrides by flat name
        val = bring_up(
            ValidatorNode(
                context=ctx,
                parameter_overrides=[
                    Parameter("diagnosis", value=False),
                    Parameter("hop_samples", value=512),
                    Parameter("latch_alarm", value=True),
                    Parameter("op_reference_u", value=[0.4, 0.4]),
                    Parameter("op_reference_y", value=[0.47, 0.5]),
                ],
            )
        )
        try:
            tree = ValidatorSettings().monitor
            assert val.config.alarm.latch
            assert val.config.hop_samples == 512
            assert val.config.op.reference_u == (0.4, 0.4)
            assert val.config == from_flat(
                MonitorConfig,
                {
                    "hop_samples": 512,
                    "latch_alarm": True,
                    "op_reference_u": [0.4, 0.4],
                    "op_reference_y": [0.47, 0.5],
                },
            )
            assert val.config.ts_s == tree.ts_s
            assert val.config.alarm.debounce == tree.alarm.debounce
        finally:
            val.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


# ------------------------------------------------------------------------------ CLI options


def _commands() -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return {name: sub.choices[name] for name in COMMANDS}


def _options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {
        next(o for o in a.option_strings if o.startswith("--")): a
        for a in parser._actions
        if a.option_strings
    }


@pytest.mark.parametrize("command", COMMANDS)
def test_cli_options_are_settings_or_say_why_not(command: str) -> None:
    parser = _commands()[command]
    for option, action in _options(parser).items():
        if option in NOT_SETTINGS_OPTIONS:
            assert option not in BY_OPTION
            continue
        if option in TIMING_OPTIONS:
            s = BY_NAME[TIMING_OPTIONS[option]]
            assert action.type is s.kind, option
            bag = command in ("validate", "diagnose", "calibrate")
            assert action.default == (None if bag else s.param_default), (command, option)
            continue
        if command == "live" and option in LIVE_OPTIONS:
            s = LIVE_OPTIONS[option]
            assert (action.default, action.type) == (s.param_default, s.kind), option
            continue
        assert option in BY_OPTION, (
            f"{command} {option} is neither a setting's option nor listed in NOT_SETTINGS_OPTIONS"
        )
        s = BY_OPTION[option]
        assert action.dest == option_dest(option)
        assert action.default == s.param_default, (command, option)
        if s.meta.choices:
            assert tuple(action.choices or ()) == s.meta.choices, (command, option)
            assert action.type is None
        else:
            assert action.choices is None
            assert action.type is s.kind, (command, option)


@pytest.mark.parametrize("command", ["validate", "diagnose", "calibrate"])
def test_bag_commands_offer_every_option_setting(command: str) -> None:
    assert set(BY_OPTION) <= set(_options(_commands()[command]))
    # every option is a window or alarm setting: _replay_config builds MonitorConfig of them
    assert all(s.path[0] == "monitor" for s in BY_OPTION.values())


def test_cli_options_build_the_trees_monitor_config() -> None:
    from twotank_validation import cli  # noqa: PLC0415

    args = build_parser().parse_args(["validate", "bag"])
    cfg = cli._replay_config(args, TS_S, PERIOD_SAMPLES)
    assert cfg.monitor == ValidatorSettings().monitor  # type: ignore[attr-defined]
    args = build_parser().parse_args(
        ["validate", "bag", "--hop", "64", "--debounce", "count", "--norm", "energy"]
    )
    cfg = cli._replay_config(args, 0.8, 256)
    assert cfg.monitor == from_flat(  # type: ignore[attr-defined]
        MonitorConfig,
        {
            "ts_s": 0.8,
            "period_samples": 256,
            "hop_samples": 64,
            "debounce": "count",
            "norm_convention": "energy",
        },
    )
    args = build_parser().parse_args(["validate", "bag", "--periods-per-window", "65"])
    with pytest.raises(cli.UsageError, match=r"periods_per_window = 65 .*\[1, 64\]"):
        cli._replay_config(args, TS_S, PERIOD_SAMPLES)


def test_cli_model_default_is_the_trees() -> None:
    from twotank_validation import cli  # noqa: PLC0415

    args = build_parser().parse_args(["validate", "bag"])
    assert cli._model_names(args) == list(ValidatorSettings().models)


# ------------------------------------------------------------------------------ docs


def _rows_of(table: str) -> dict[str, list[str]]:
    """The rows of a markdown table (from its header line): first-cell names -> other cells."""
    rows: dict[str, list[str]] = {}
    for line in table.strip("\n").splitlines()[2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        for name in re.findall(r"`([^`]+)`", cells[0]):
            rows[name.split()[0]] = cells[1:]
    return rows


def _doc_value(cell: str) -> Any:
    """A docs cell's value: numbers, true/false, bracketed lists, text (backticks dropped)."""
    text = cell.replace("`", "").strip()
    if text.startswith("[") and text.endswith("]"):
        return [_doc_value(v) for v in text[1:-1].split(",")] if text[1:-1] else []
    if text in ("true", "false"):
        return text == "true"
    if text in ('""', "''"):
        return ""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text.strip("\"'")


def _doc_range(cell: str) -> tuple[float | None, float | None, tuple[str, ...]]:
    text = cell.replace("`", "").strip()
    if not text:
        return None, None, ()
    if m := re.fullmatch(r"(-?[\d.e+-]+)\s*(?:–|\.\.)\s*([\d.e+-]+)", text):
        return float(m[1]), float(m[2]), ()
    return None, None, tuple(sorted(c.strip() for c in text.split(",")))


def test_ros_docs_list_the_validator_parameters_with_the_trees_defaults_and_ranges() -> None:
    header = "| parameter | default | range | meaning |"
    rows = _rows_of(header + (DOCS / "ros.md").read_text().split(header)[1])
    for name, cells in rows.items():
        if name in NOT_SETTINGS_PARAMS:
            continue
        assert name in BY_NAME, f"docs/ros.md lists {name}, no setting of the tree"
        s = BY_NAME[name]
        assert _doc_value(cells[0]) == s.param_default, (name, cells[0])
        low, high, choices = _doc_range(cells[1])
        assert (low, high) == (s.meta.low, s.meta.high), (name, cells[1])
        assert choices == tuple(sorted(s.meta.choices)), (name, cells[1])
    missing = {s.name for s in EXPOSED} - set(rows)
    assert not missing, f"parameters missing from docs/ros.md: {sorted(missing)}"


def test_cli_docs_list_the_options_with_the_trees_defaults() -> None:
    # the live table is the first one; validate's is the one with --periods-per-window
    tables = (DOCS / "cli.md").read_text().split("| option | default | meaning |")
    header = "| option | default | meaning |"
    live = _rows_of(header + tables[1])
    bag = next(r for t in tables[1:] if "--periods-per-window" in (r := _rows_of(header + t)))
    for option, s in BY_OPTION.items():
        assert option in bag, f"docs/cli.md's validate table lacks {option}"
        assert _doc_value(bag[option][0]) == s.param_default, (option, bag[option][0])
    for option, name in TIMING_OPTIONS.items():
        assert _doc_value(live[option][0]) == BY_NAME[name].param_default, option
    for option, s in LIVE_OPTIONS.items():
        assert option in live, f"docs/cli.md's live table lacks {option}"
        assert _doc_value(live[option][0]) == s.param_default, (option, live[option][0])
    debounce = bag["--debounce"][1]
    for name in ("alarm_windows", "alarm_evidence"):
        assert str(BY_NAME[name].default) in debounce, (name, debounce)


# ------------------------------------------------------------------ the excitation design

DESIGN = {s.name: s for s in ExcitationDesign.settings()}


def test_the_design_round_trips_through_its_flat_form() -> None:
    d = ExcitationDesign(
        kind="multisine", lines="odd", detection="1/4", line_step=2, realisations=3,
        realisation_periods=6, crest_min=True, seed=9,
    )  # fmt: skip
    assert from_flat(ExcitationDesign, d.to_flat()) == d
    assert from_flat(ExcitationDesign, {}) == ExcitationDesign() == RIG_DESIGN


@pytest.mark.parametrize("node", ["excitation", "controller", "model_plant"])
def test_nodes_take_the_designs_settings_as_parameters(node: str) -> None:
    """Name, description, range and choices are the design's; the default its context's."""
    from twotank_validation.ros import (  # noqa: PLC0415
        controller_node,
        excitation_node,
        model_plant_node,
    )

    params, context = {
        "excitation": (excitation_node.EXCITATION_PARAMS, RIG_DESIGN),
        "controller": (controller_node.CONTROLLER_PARAMS, RIG_DESIGN),
        "model_plant": (model_plant_node.MODEL_PLANT_PARAMS, model_plant_node.MODEL_DESIGN),
    }[node]
    by_name = {p.name: p for p in params}
    assert "odd_only" not in by_name  # lines replaces it
    defaults = context.to_flat()
    for name, s in DESIGN.items():
        p = by_name[name]
        assert (p.description, p.low, p.high, p.choices) == (
            s.meta.description,
            s.meta.low,
            s.meta.high,
            s.meta.choices,
        ), (node, name)
        assert p.default == defaults[name], (node, name)
        assert type(p.default) is type(s.param_default), (node, name)
    # the node's design of its defaults is its context's
    from twotank_validation.ros.params import design_of  # noqa: PLC0415

    assert design_of({p.name: p.default for p in params}) == context


def test_simulate_offers_the_designs_options() -> None:
    from twotank_validation.cli_models import DESIGN_BAND_OPTION  # noqa: PLC0415

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    options = _options(sub.choices["simulate"])
    with_option = {s.meta.option: s for s in DESIGN.values() if s.meta.option}
    assert set(with_option) | {DESIGN_BAND_OPTION} <= set(options)
    for option, s in with_option.items():
        action = options[option]
        assert action.default is None, option  # the scenario's own, or --model's multisine
        assert action.dest == option_dest(option)
        if s.kind is bool:
            assert action.nargs == 0, option
        elif s.meta.choices:
            assert tuple(action.choices or ()) == s.meta.choices, option
        else:
            assert action.type is s.kind, option
    # the design's period and seed are simulate's --period and --seed; f_min/f_max its --band
    assert {s.name for s in DESIGN.values() if not s.meta.option} == {
        "period_samples", "f_min_hz", "f_max_hz", "order", "seed",
    }  # fmt: skip
    args = build_parser().parse_args(
        ["simulate", "--model", "B", "--out", "x", "--band", "0.01..0.2", "--lines", "odd",
         "--detection", "1/3", "--realisations", "4", "--crest-min", "--period", "256"]
    )  # fmt: skip
    from twotank_validation.cli_models import model_design  # noqa: PLC0415

    assert model_design(args, 256) == ExcitationDesign(
        kind="multisine", period_samples=256, f_min_hz=0.01, f_max_hz=0.2, lines="odd",
        detection="1/3", realisations=4, crest_min=True, cutoff_hz=0.0, seed=0,
    )  # fmt: skip


def test_cli_docs_list_simulates_design_options() -> None:
    header = "| option | default | meaning |"
    tables = (DOCS / "cli.md").read_text().split(header)
    rows = next(r for t in tables[1:] if "--detection" in (r := _rows_of(header + t)))
    for s in DESIGN.values():
        if s.meta.option:
            assert s.meta.option in rows, s.meta.option
    assert "--band" in rows


def test_ros_docs_list_the_design_parameters_with_the_rigs_defaults() -> None:
    header = "| design parameter | rig default | range | meaning |"
    rows = _rows_of(header + (DOCS / "ros.md").read_text().split(header)[1])
    for name, s in DESIGN.items():
        assert name in rows, f"docs/ros.md's design table lacks {name}"
        value = _doc_value(rows[name][0])
        want = RIG_DESIGN.to_flat()[name]
        assert value == pytest.approx(want) if isinstance(want, float) else value == want, name
        low, high, choices = _doc_range(rows[name][1])
        assert (low, high) == (s.meta.low, s.meta.high), name
        assert choices == tuple(sorted(s.meta.choices)), name
