"""The launch files' arguments and the parameters they pass (issue 31, item 4).

``launch`` and ``launch_ros`` are not on PyPI, so each ``launch/*.launch.py`` is imported with
stand-in modules: ``DeclareLaunchArgument``, ``LaunchConfiguration``, ``OpaqueFunction``,
``LaunchDescription`` and ``launch_ros.actions.Node`` with the upstream constructors'
keyword names and no catch-all (a keyword the real class lacks fails), recording what they
get; ``LaunchConfiguration.perform`` reads a context holding each argument's value (its default
or the test's), and a value outside an argument's ``choices`` fails as in launch. The files'
own code then runs unchanged: their ``generate_launch_description`` and the
``OpaqueFunction`` that builds the nodes. What launch itself does with the result (spawning
processes, loading the params file) is not exercised.

References: the package's console scripts (installed entry points), each node's parameter
table (what the node declares: the settings tree for the validator), and rclpy's own
parameter typing (``Parameter(name, value=...).type_``), which decides whether a node accepts an
override of its declared parameter.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import sys
import types
from importlib import metadata
from pathlib import Path

import pytest
from rclpy.parameter import Parameter

from twotank_validation.online.validator_settings import VALIDATOR_SETTINGS
from twotank_validation.ros.launching import LOG_LEVELS, typed
from twotank_validation.ros.lifecycle import ManagedNode
from twotank_validation.ros.params import Param

ROOT = Path(__file__).resolve().parent.parent
LAUNCH_FILES = sorted((ROOT / "launch").glob("*.launch.py"))
COMMON = {"params_file", "namespace", "use_sim_time", "log_level", "autostart"}


class _Context:
    def __init__(self, values: dict[str, str]) -> None:
        self.launch_configurations = values


class DeclareLaunchArgument:
    def __init__(self, name, *, default_value=None, description=None, choices=None):
        if choices is not None and default_value not in choices:
            raise ValueError(f"{name}: default {default_value!r} not in {choices}")
        self.name, self.default_value, self.description = name, default_value, description
        self.choices = choices


class LaunchConfiguration:
    def __init__(self, variable_name, *, default=None):
        self.variable_name = variable_name

    def perform(self, context):
        return context.launch_configurations[self.variable_name]


class OpaqueFunction:
    def __init__(self, *, function, args=None, kwargs=None):
        self.function, self.args, self.kwargs = function, args or [], kwargs or {}

    def execute(self, context):
        return self.function(context, *self.args, **self.kwargs)


class LaunchDescription:
    def __init__(self, initial_entities=None, *, deprecated_reason=None):
        self.entities = list(initial_entities or [])


class Node:
    def __init__(
        self,
        *,
        executable,
        package=None,
        name=None,
        namespace=None,
        exec_name=None,
        parameters=None,
        remappings=None,
        ros_arguments=None,
        arguments=None,
    ):
        self.executable, self.package, self.namespace = executable, package, namespace
        self.name = name
        self.parameters, self.arguments, self.remappings = parameters, arguments, remappings


class LifecycleNode(Node):
    def __init__(self, *, name, namespace, autostart=False, **kwargs):
        super().__init__(name=name, namespace=namespace, **kwargs)
        self.name, self.autostart = name, autostart


@pytest.fixture
def stub_launch(monkeypatch):
    modules = {
        "launch": {"LaunchDescription": LaunchDescription},
        "launch.actions": {
            "DeclareLaunchArgument": DeclareLaunchArgument,
            "OpaqueFunction": OpaqueFunction,
        },
        "launch.substitutions": {"LaunchConfiguration": LaunchConfiguration},
        "launch_ros": {},
        "launch_ros.actions": {"Node": Node, "LifecycleNode": LifecycleNode},
    }
    for name, attrs in modules.items():
        mod = types.ModuleType(name)
        mod.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, mod)


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(path: Path, given: dict[str, str] | None = None):
    """(declared arguments by name, the nodes built) of a launch file with ``given`` values."""
    desc = _load(path).generate_launch_description()
    declared = {e.name: e for e in desc.entities if isinstance(e, DeclareLaunchArgument)}
    values = {name: arg.default_value for name, arg in declared.items()} | (given or {})
    for name, value in values.items():
        choices = declared[name].choices
        assert choices is None or value in choices, f"{name}={value!r} refused by launch"
    context = _Context(values)
    nodes = [
        node for e in desc.entities if isinstance(e, OpaqueFunction) for node in e.execute(context)
    ]
    return declared, nodes


def _node_params() -> dict[str, tuple[Param, ...]]:
    """Executable -> the parameter table its node declares (from the entry point's module)."""
    scripts = {
        ep.name: ep.value.split(":")[0]
        for ep in metadata.distribution("twotank_validation").entry_points
        if ep.group == "console_scripts" and ep.name.startswith("twotank_")
    }
    out = {}
    for script, module_name in scripts.items():
        module = importlib.import_module(module_name)
        (table,) = (
            v
            for k, v in vars(module).items()
            if k.endswith("_PARAMS") and k != "UNIT_PARAMS" and isinstance(v, tuple)
        )
        out[script] = table
    return out


NODE_PARAMS = _node_params()


def _managed() -> dict[str, str]:
    """Executable -> its managed node's default name (the executables of ManagedNode classes)."""
    out = {}
    for ep in metadata.distribution("twotank_validation").entry_points:
        if ep.group == "console_scripts" and ep.name.startswith("twotank_"):
            module = importlib.import_module(ep.value.split(":")[0])
            for v in vars(module).values():
                mine = isinstance(v, type) and v.__module__ == module.__name__
                if mine and issubclass(v, ManagedNode):
                    out[ep.name] = inspect.signature(v).parameters["name"].default
    assert set(out) == {
        "twotank_validator",
        "twotank_supervisor",
        "twotank_controller",
        "twotank_plant",
    }
    return out


MANAGED = _managed()


def _check_lifecycle(node: Node, autostart: bool, level: str) -> None:
    """A managed node is launched as a LifecycleNode that launch starts (or not); the
    executable is told not to start itself; a plain node as a Node."""
    ros_args = ["--ros-args", "--log-level", level]
    if node.executable in MANAGED:
        assert isinstance(node, LifecycleNode), node.executable
        assert node.name == MANAGED[node.executable]
        assert node.autostart is autostart
        assert node.arguments == ["--autostart", "false", *ros_args]
    else:
        assert not isinstance(node, LifecycleNode), node.executable
        assert node.arguments == ros_args


def _check_overrides(node: Node) -> dict:
    """The node's override dict, each name declared by the node and of its declared type."""
    assert node.package == "twotank_validation"
    table = {p.name: p for p in NODE_PARAMS[node.executable]}
    *_files, overrides = node.parameters
    assert isinstance(overrides, dict)
    for name, value in overrides.items():
        if name == "use_sim_time":  # rclpy declares it on every node
            assert isinstance(value, bool)
            continue
        assert name in table, f"{node.executable} declares no parameter {name!r}"
        want = Parameter(name, value=table[name].default).type_
        assert Parameter(name, value=value).type_ == want, (node.executable, name, value)
    if node.executable == "twotank_validator":
        tree = {s.name for s in VALIDATOR_SETTINGS}
        assert set(overrides) - {"use_sim_time"} <= tree
    return overrides


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_defaults_pass_only_what_the_file_fixes(stub_launch, path: Path) -> None:
    declared, nodes = _run(path)
    assert set(declared) >= COMMON
    assert declared["log_level"].default_value == "info"
    assert set(declared["log_level"].choices) == set(LOG_LEVELS)
    sim = declared["use_sim_time"].default_value == "true"
    assert nodes
    for node in nodes:
        assert node.executable in NODE_PARAMS
        assert node.namespace == ""
        _check_lifecycle(node, True, "info")
        overrides = _check_overrides(node)
        assert len(node.parameters) == 1  # no params file by default
        assert overrides["use_sim_time"] is sim
        # left empty, a parameter argument is not passed: the node's default (the tree) rules
        assert set(overrides) <= {
            "use_sim_time",
            "publish_clock",
            "input_periodic_rtol",
            "transient",
        }


def _text(default) -> str:
    """A launch argument's text for a parameter value (the reverse of ``typed``)."""
    if isinstance(default, bool):
        return "false" if default else "true"  # the other value, so that it shows
    if isinstance(default, list | tuple):
        return ",".join(["X", "Y"])
    return str(default) or "X"  # an empty text would mean not given


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_every_argument_reaches_its_node_typed(stub_launch, path: Path) -> None:
    declared, _ = _run(path)
    module = _load(path)
    # the parameter each argument names, from the file's own argument -> parameter maps
    maps = {k: v for k, v in vars(module).items() if k.endswith("_ARGS") and isinstance(v, dict)}
    by_arg = {arg: param for m in maps.values() for arg, param in m.items()}
    assert set(declared) == COMMON | set(by_arg), "every argument is common or names a parameter"
    given = {"params_file": "/tmp/rig.yaml", "namespace": "rig1", "log_level": "debug"}
    given["autostart"] = "false"
    given["use_sim_time"] = "false" if declared["use_sim_time"].default_value == "true" else "true"
    values: dict[str, object] = {}
    for map_name, mapping in maps.items():
        # VALIDATOR_ARGS names parameters of VALIDATOR_PARAMS (imported by the file)
        table = {q.name: q for q in vars(module)[map_name.replace("_ARGS", "_PARAMS")]}
        for arg, param in mapping.items():
            given[arg] = _text(table[param].default)
            values[arg] = typed(table[param], given[arg])
    _, nodes = _run(path, given)
    passed: dict[str, list] = {}
    for node in nodes:
        assert node.namespace == "rig1"
        _check_lifecycle(node, False, "debug")
        assert node.parameters[0] == "/tmp/rig.yaml"  # first: the arguments override it
        overrides = _check_overrides(node)
        assert overrides["use_sim_time"] is (given["use_sim_time"] == "true")
        for name, value in overrides.items():
            passed.setdefault(name, []).append((node.executable, value))
    for arg, param in by_arg.items():
        assert any(value == values[arg] for _exe, value in passed[param]), (arg, param)


def test_typed_refuses_text_of_another_type() -> None:
    flag = Param("latch_alarm", False, "")
    assert typed(flag, "TRUE") is True
    with pytest.raises(ValueError, match="latch_alarm"):
        typed(flag, "yes")
    assert typed(Param("real_time_factor", 1.0, ""), "2") == 2.0
    assert typed(Param("models", ["A", "B"], ""), "A, B,") == ["A", "B"]
