"""The shipped aggregator analyzers match the statuses the nodes really publish (issue 31).

The status names are read from ``/diagnostics`` while a validator (models A and B) and a
supervisor run in-process with a real executor. diagnostic_aggregator is not on PyPI, so its
GenericAnalyzer rules are restated below from ros/diagnostics (``generic_analyzer.cpp``:
``startswith``/``contains``/``name``/``expected``/``regex`` match, ``find_and_remove_prefix``
is both ``startswith`` and ``remove_prefix``; ``analyzer.hpp``'s ``removeLeadingNameChaff``:
a chaff right after the last ``/`` of ``path/name`` is cut, then one ``:``, then the leading
spaces).
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from twotank_validation.ros.controller_node import ControllerNode
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.plant_node import PlantNode
from twotank_validation.ros.supervisor_node import SupervisorNode
from twotank_validation.ros.validator_node import ValidatorNode

CONFIG = Path(__file__).resolve().parents[2] / "config" / "twotank_analyzers.yaml"


def _strings(value) -> list[str]:
    return [value] if isinstance(value, str) else list(value or [])


def _remove_chaff(output: str, chaff: str) -> str:
    """ros/diagnostics ``removeLeadingNameChaff``."""
    slash = output.rfind("/")
    head, leaf = output[: slash + 1], output[slash + 1 :]
    if chaff and leaf.startswith(chaff):
        leaf = leaf[len(chaff) :]
        if leaf.startswith(":"):
            leaf = leaf[1:]
        leaf = leaf.lstrip(" ")
    return head + leaf


def _generic(cfg: dict, path: str):
    """(match, output name) of one GenericAnalyzer's parameters under ``path``."""
    chaff = _strings(cfg.get("remove_prefix")) + _strings(cfg.get("find_and_remove_prefix"))
    starts = _strings(cfg.get("startswith")) + _strings(cfg.get("find_and_remove_prefix"))
    contains = _strings(cfg.get("contains"))
    exact = _strings(cfg.get("name")) + _strings(cfg.get("expected"))
    regex = [re.compile(r) for r in _strings(cfg.get("regex"))]

    def match(name: str) -> bool:
        return (
            any(name.startswith(s) for s in starts)
            or any(c in name for c in contains)
            or name in exact
            or any(r.fullmatch(name) for r in regex)
        )

    def output(name: str) -> str:
        out = f"{path}/{name}"
        for c in chaff:
            out = _remove_chaff(out, c)
        return out

    return match, output


def _analyzers(tree: dict, base: str = "") -> list:
    """The GenericAnalyzers of an analyzer tree, each with its full path."""
    found = []
    for key, cfg in tree.items():
        if not isinstance(cfg, dict) or "type" not in cfg:
            continue
        path = f"{base}/{cfg['path']}" if base else cfg["path"]
        if cfg["type"] == "diagnostic_aggregator/AnalyzerGroup":
            found += _analyzers(cfg["analyzers"], path)
        else:
            assert cfg["type"] == "diagnostic_aggregator/GenericAnalyzer", key
            found.append(_generic(cfg, path))
    return found


def _published_names() -> set[str]:
    ctx = Context()
    rclpy.init(context=ctx)
    names: set[str] = set()
    try:
        val = bring_up(
            ValidatorNode(
                context=ctx,
                parameter_overrides=[
                    Parameter("models", value=["A", "B"]),
                    Parameter("diagnosis", value=False),
                ],
            )
        )
        sup = bring_up(
            SupervisorNode(
                context=ctx,
                parameter_overrides=[
                    Parameter("models", value=["A", "B"]),
                    Parameter("check_period_s", value=0.1),
                ],
            )
        )
        # the plant and the controller say only their lifecycle state: one active, one inactive
        plant = bring_up(
            PlantNode(context=ctx, parameter_overrides=[Parameter("self_timed", value=False)])
        )
        ctl = bring_up(
            ControllerNode(context=ctx, parameter_overrides=[Parameter("self_timed", value=False)]),
            activate=False,
        )
        listener = Node("diagnostics_listener", context=ctx)
        listener.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda arr: names.update(s.name for s in arr.status),
            10,
        )
        ex = SingleThreadedExecutor(context=ctx)
        for n in (val, sup, plant, ctl, listener):
            ex.add_node(n)
        end = time.monotonic() + 5.0
        while time.monotonic() < end and len(names) < 5:
            ex.spin_once(timeout_sec=0.05)
        ex.shutdown()
        for n in (listener, ctl, plant, sup, val):
            n.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return names


def test_each_published_status_lands_in_one_analyzer_under_a_clean_name() -> None:
    names = _published_names()
    assert names == {
        "twotank_validation: model A",
        "twotank_validation: model B",
        "twotank_validation: supervisor",
        "twotank_validation: plant",
        "twotank_validation: controller",
    }
    doc = yaml.safe_load(CONFIG.read_text())
    params = doc["analyzers"]["ros__parameters"]
    assert "path" not in params, "no root path: the file adds to a robot's configuration"
    analyzers = _analyzers(params)
    outputs = {}
    for name in names:
        assert "/" not in name  # a slash would split the aggregator's tree
        hits = [out(name) for match, out in analyzers if match(name)]
        assert len(hits) == 1, f"{name!r} matched by {len(hits)} analyzers (0: 'Other')"
        outputs[name] = hits[0]
    assert outputs == {
        "twotank_validation: model A": "Model validation/Models/A",
        "twotank_validation: model B": "Model validation/Models/B",
        "twotank_validation: supervisor": "Model validation/Supervisor/supervisor",
        "twotank_validation: plant": "Model validation/Rig/plant",
        "twotank_validation: controller": "Model validation/Rig/controller",
    }
