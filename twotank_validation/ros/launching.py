"""What the launch files share: their arguments and each node's options, without ``launch``.

``launch/*.launch.py`` declare :func:`common_arguments` (``params_file``, ``namespace``,
``use_sim_time``, ``log_level``, ``autostart``) and, per node, the :func:`parameter_arguments`
they expose, and build each node's ``launch_ros`` options with :func:`node_options` (a plain
node) or :func:`lifecycle_options` (a managed node, launched as ``launch_ros.actions.
LifecycleNode``, whose ``autostart`` drives configure and activate) inside an
``OpaqueFunction``. Nothing here imports ``launch`` (not on PyPI), so the tests run the launch
files' logic with stand-ins (``test/test_launch_files.py``).

Precedence, lowest first: the node's own default (its parameter table, i.e. the settings
tree), the ``params_file``, a launch argument given explicitly. A parameter argument's default
is the empty string, "not given": it is then not passed, and the lower levels decide.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from twotank_validation.ros.params import Param

LOG_LEVELS = ("debug", "info", "warn", "error", "fatal")
"""The ``--log-level`` values of a ROS 2 node."""

BOOLEANS = ("true", "false")


@dataclass(frozen=True)
class LaunchArg:
    """One launch argument: name, default (text), description and allowed values."""

    name: str
    default: str
    description: str
    choices: tuple[str, ...] = ()


def common_arguments(*, use_sim_time: bool) -> tuple[LaunchArg, ...]:
    """The five arguments every launch file declares.

    Args:
        use_sim_time: the default of ``use_sim_time`` (true where the simulated plant owns
            ``/clock``).
    """
    return (
        LaunchArg(
            "params_file",
            "",
            "ROS parameters YAML for the nodes (keys: node names or /**); launch arguments "
            "given explicitly override it; empty: none",
        ),
        LaunchArg(
            "namespace",
            "",
            "namespace of every node: their topics and services move with it (/diagnostics "
            "and /clock are absolute)",
        ),
        LaunchArg(
            "use_sim_time",
            "true" if use_sim_time else "false",
            "use /clock (ROS simulated time) instead of the system clock",
            BOOLEANS,
        ),
        LaunchArg("log_level", "info", "log level of every node", LOG_LEVELS),
        LaunchArg(
            "autostart",
            "true",
            "configure and activate the managed nodes at start (false: they wait unconfigured "
            "for `ros2 lifecycle set` or a lifecycle manager)",
            BOOLEANS,
        ),
    )


def parameter_arguments(params: Sequence[Param], names: Mapping[str, str]) -> tuple[LaunchArg, ...]:
    """Launch arguments for node parameters, described by the parameters' own descriptions.

    Args:
        params: the node's parameter table (e.g. ``VALIDATOR_PARAMS``).
        names: launch argument name -> parameter name.

    Raises:
        KeyError: a parameter the node does not declare.
    """
    table = {p.name: p for p in params}
    out = []
    for arg, name in names.items():
        p = table[name]
        lists = " (comma-separated)" if isinstance(p.default, list | tuple) else ""
        out.append(LaunchArg(arg, "", f"{name}{lists}: {p.description}; empty: the node's default"))
    return tuple(out)


def typed(param: Param, text: str) -> Any:
    """A launch argument's text as the parameter's type (the type its default declares).

    ROS refuses a parameter override of another type than the declared one, so a float
    parameter gets ``1.0`` for ``"1"`` and a string-array parameter a list.

    Raises:
        ValueError: text that is not of the parameter's type (e.g. ``"yes"`` for a bool).
    """
    default = param.default
    if isinstance(default, bool):
        if text.lower() not in BOOLEANS:
            raise ValueError(f"{param.name}: {text!r} is not true or false")
        return text.lower() == "true"
    if isinstance(default, int):
        return int(text)
    if isinstance(default, float):
        return float(text)
    if isinstance(default, list | tuple):
        return [s.strip() for s in text.split(",") if s.strip()]
    return text


def node_options(
    values: Mapping[str, str],
    params: Sequence[Param],
    names: Mapping[str, str] | None = None,
    fixed: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """``launch_ros.actions.Node`` keyword arguments of one node.

    Args:
        values: every launch argument's text (``LaunchConfiguration(...).perform(context)``).
        params: the node's parameter table.
        names: the launch arguments of this node's parameters (argument -> parameter); the
            empty ones are left out.
        fixed: parameters the launch file sets whatever the arguments (e.g. ``publish_clock``
            of the plant that owns ``/clock``).

    Returns:
        ``namespace``, ``parameters`` (the params file if any, then a dict: ``use_sim_time``,
        ``fixed``, the given arguments typed) and ``arguments`` (``--ros-args --log-level``).
    """
    table = {p.name: p for p in params}
    given = {
        name: typed(table[name], values[arg]) for arg, name in (names or {}).items() if values[arg]
    }
    overrides = {"use_sim_time": values["use_sim_time"].lower() == "true", **(fixed or {}), **given}
    files = [values["params_file"]] if values["params_file"] else []
    return {
        "namespace": values["namespace"],
        "parameters": [*files, overrides],
        "arguments": ["--ros-args", "--log-level", values["log_level"]],
    }


def lifecycle_options(
    values: Mapping[str, str],
    name: str,
    params: Sequence[Param],
    names: Mapping[str, str] | None = None,
    fixed: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """``launch_ros.actions.LifecycleNode`` keyword arguments of a managed node.

    :func:`node_options`' plus the node's ``name`` (LifecycleNode requires it) and
    ``autostart`` (the launch argument: launch configures and activates the node through its
    lifecycle services); the executable is told ``--autostart false`` so that launch, not the
    node itself, drives the transitions.
    """
    opts = node_options(values, params, names, fixed)
    opts["arguments"] = ["--autostart", "false", *opts["arguments"]]
    return {**opts, "name": name, "autostart": values["autostart"].lower() == "true"}
