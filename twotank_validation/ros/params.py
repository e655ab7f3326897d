"""Declared ROS parameters with descriptions and ranges; invalid values stop a node at start-up."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy

from twotank_validation.errors import TwotankError
from twotank_validation.online.streams import RigUnits
from twotank_validation.settings import FlatSetting, from_flat, to_flat
from twotank_validation.sim.excitation import ExcitationDesign

LATCHED = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)
"""QoS of the state topics (``validation/M/invalidated``, ``control/mode``,
``supervisor/state``): reliable, the last value kept for a late subscriber. Publisher and
subscribers must agree on it, hence one definition."""

VERDICT_DEADLINE_HOPS = 3
"""The verdict topics' offered deadline, in hops (windows): a new report, margin and alarm state
at least every this many hops (a hop is one window's advance, ``hop * ts_s`` of data time)."""

VERDICT_LEASE_S = 5.0
"""The verdict topics' liveliness lease (s, wall clock): AUTOMATIC liveliness, asserted by the
validator's DDS participant while its process lives."""


def verdict_qos(hop_s: float, *, latched: bool = False) -> QoSProfile:
    """QoS of the validator's verdict topics: report and margin, or the alarm (``latched``).

    Offers a deadline of :data:`VERDICT_DEADLINE_HOPS` hops and AUTOMATIC liveliness with a
    :data:`VERDICT_LEASE_S` lease, so that a subscriber that requests them hears of a stopped
    validator (deadline missed) or a dead one (liveliness lost) from DDS itself. Both are wall
    clock: under a simulated clock slower than real time the deadline is missed. A subscriber
    requesting neither (the default) is compatible; one requesting them must request a
    deadline and a lease at least as long (docs/ros.md, QoS).

    Args:
        hop_s: the validator's hop (s of data time; ``hop * ts_s``).
        latched: the alarm topic ``validation/M/invalidated``: depth 1, transient-local
            (:data:`LATCHED`); otherwise depth 10, volatile.
    """
    base = LATCHED if latched else QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    return QoSProfile(
        depth=base.depth,
        reliability=base.reliability,
        durability=base.durability,
        deadline=Duration(nanoseconds=round(VERDICT_DEADLINE_HOPS * hop_s * 1e9)),
        liveliness=LivelinessPolicy.AUTOMATIC,
        liveliness_lease_duration=Duration(nanoseconds=round(VERDICT_LEASE_S * 1e9)),
    )


class ParameterError(TwotankError, ValueError):
    """A node parameter is out of range or inconsistent; the message names it."""


@dataclass(frozen=True)
class Param:
    """One parameter: name, default, description and optional numeric range (inclusive)."""

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()


def setting_params(settings: Sequence[FlatSetting]) -> tuple[Param, ...]:
    """The node parameters of a settings tree's flat settings (the hidden ones left out).

    Name, default (flat form), description, range and choices are the setting's own
    (:mod:`twotank_validation.settings`): the parameters restate nothing.
    """
    return tuple(
        Param(s.name, s.param_default, s.meta.description, s.meta.low, s.meta.high, s.meta.choices)
        for s in settings
        if not s.meta.hidden
    )


def design_params(defaults: ExcitationDesign) -> tuple[Param, ...]:
    """The excitation design's settings as node parameters, with ``defaults``' values.

    Name, description, range and choices are the design's settings'
    (:class:`~twotank_validation.sim.excitation.ExcitationDesign`); the default is the
    node's context's (the rig's excitation, a model's multisine). :func:`design_of` reads
    them back.
    """
    values = defaults.to_flat()
    return tuple(
        Param(
            s.name,
            to_flat(s.kind, values[s.name]),
            s.meta.description,
            s.meta.low,
            s.meta.high,
            s.meta.choices,
        )
        for s in ExcitationDesign.settings()
    )


def design_of(values: Mapping[str, Any]) -> ExcitationDesign:
    """The design of a node's declared parameter values (:func:`design_params`').

    Raises:
        DatumError: an invalid combination (the message names the setting).
    """
    names = {s.name for s in ExcitationDesign.settings()}
    return from_flat(ExcitationDesign, {k: v for k, v in values.items() if k in names})


_UNITS = RigUnits()

UNIT_PARAMS: tuple[Param, ...] = (
    Param(
        "pascal_per_unit",
        _UNITS.pascal_per_unit,
        "gauge pressure (Pa) per model unit of level",
        1e-9,
        1e12,
    ),
    Param(
        "temperature_offset_c",
        _UNITS.temperature_offset_c,
        "temperature (degC) of model unit 0",
        -273.15,
        1e4,
    ),
    Param(
        "temperature_span_c",
        _UNITS.temperature_span_c,
        "degC per model unit of temperature",
        1e-9,
        1e6,
    ),
)
"""The unit conversions of the interface (:class:`RigUnits`), as parameters of the nodes that
convert: the defaults are RigUnits' own."""


def check_value(p: Param, value: Any) -> str | None:
    """Why ``value`` does not fit ``p`` (outside its range, not among its choices), or None."""
    if p.choices:
        items = value if isinstance(value, list | tuple) else [value]
        bad = [v for v in items if v not in p.choices]
        if bad:
            return f"parameter {p.name!r}: {bad} not among {list(p.choices)}"
    numeric = isinstance(value, int | float) and not isinstance(value, bool)
    high = p.high if p.high is not None else math.inf
    if p.low is not None and numeric and not p.low <= value <= high:
        return f"parameter {p.name!r} = {value} is outside [{p.low}, {p.high}]"
    return None


def declare(
    node: Node,
    params: Sequence[Param],
    *,
    runtime: Collection[str] | None = None,
    errors: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Declare ``params`` on ``node`` and return their values, checked.

    Args:
        node: the node.
        params: its parameter table.
        runtime: the names that may change at run time (a managed node's, which validates
            them in its on-set callback); every other one is declared ``read_only``. None: no
            parameter is read-only (the plain nodes).
        errors: collect each refused value here (parameter name -> reason; the parameter then
            keeps its default) instead of raising: a managed node refuses to configure with
            them rather than failing to exist.

    Raises:
        ParameterError: a value outside its range or not among its choices (``errors`` None).
    """
    values: dict[str, Any] = {}
    for p in params:
        desc = ParameterDescriptor(description=p.description)
        if runtime is not None:
            desc.read_only = p.name not in runtime
        if p.low is not None and p.high is not None:
            if isinstance(p.default, bool):
                pass
            elif isinstance(p.default, int):
                desc.integer_range = [
                    IntegerRange(from_value=int(p.low), to_value=int(p.high), step=0)
                ]
            elif isinstance(p.default, float):
                desc.floating_point_range = [
                    FloatingPointRange(from_value=float(p.low), to_value=float(p.high), step=0.0)
                ]
        if p.choices:
            desc.additional_constraints = f"one of {list(p.choices)}"
        try:
            value = node.declare_parameter(p.name, p.default, desc).value
        except Exception as err:  # rclpy raises several types for an out-of-range override
            if errors is None:
                raise ParameterError(f"parameter {p.name!r}: {err}") from err
            errors[p.name] = f"parameter {p.name!r}: {err}"
            value = node.declare_parameter(p.name, p.default, desc, ignore_override=True).value
        problem = check_value(p, value)
        if problem is not None:
            if errors is None:
                raise ParameterError(problem)
            errors[p.name] = problem
        values[p.name] = value
    return values


def run_node(
    factory: Callable[[], Node],
    args: list[str] | None = None,
    *,
    prepare: Callable[[Any], object] | None = None,
) -> int:
    """Entry point body shared by the nodes: init, build (invalid parameters -> exit 1), spin.

    Args:
        factory: builds the node (raises :class:`ParameterError` on bad parameters).
        args: command-line arguments for ``rclpy.init`` (``--ros-args ...``).
        prepare: run on the built node before spinning (a managed node's configure and
            activate); a :class:`ParameterError` from it exits 1 too.
    """
    rclpy.init(args=args)
    try:
        node = factory()
        if prepare is not None:
            prepare(node)
    except ParameterError as err:
        print(f"ERROR: {err}", file=sys.stderr)
        rclpy.shutdown()
        return 1
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
