"""The SROS2 access-control policy (security/twotank_policy.xml) against the node graph.

References: the sros2 policy schema (test/data/sros2_policy.xsd, from ros2/sros2) for the
format, and the ROS graph of the nodes themselves, started in-process with their default
parameters, models A and B and the launch files' clock settings (use_sim_time, the plant
publishing /clock): per enclave, the topics it may publish and subscribe and the services it
may serve and call must be exactly the ones its node creates. The one deliberate difference
is named: the supervisor's enclave may call the validator's resets (the issue's rule: reset
only from the supervisor's enclave or an operator's), which the supervisor node itself does
not call today. Names resolve as sros2's permissions template resolves them (absolute,
``~/`` private, else relative to the profile's namespace).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from twotank_validation.ros.controller_node import ControllerNode
from twotank_validation.ros.excitation_node import ExcitationNode
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.plant_node import PlantNode
from twotank_validation.ros.supervisor_node import SupervisorNode
from twotank_validation.ros.validator_node import ValidatorNode
from twotank_validation.ros.view_node import ViewNode

ROOT = Path(__file__).resolve().parents[2]
POLICY = ROOT / "security" / "twotank_policy.xml"
SCHEMA = ROOT / "test" / "data" / "sros2_policy.xsd"
PREFIX = "/twotank_validation/"
RESETS = {"/reset_alarm", "/reset_operating_point", "/supervisor/reset"}
# the supervisor with its ros2_control switch on (its client is then in the graph)
SWITCH_ON = [
    Parameter("controller_manager", value="/controller_manager"),
    Parameter("fallback_controllers", value=["hold"]),
]
# what each permission of a <topics>/<services> element is about
KINDS = {"publish": "pub", "subscribe": "sub", "reply": "srv", "request": "cli"}


def resolve(name: str, ns: str, node: str) -> str:
    """A policy name as sros2's permissions.xsl resolves it (its ``fqn`` template)."""
    base = ns if ns.endswith("/") else ns + "/"
    if name.startswith("/"):
        return name
    if name.startswith("~"):
        return base + node + name[1:]
    return base + name


def policy_grants(root: ET.Element) -> dict[tuple[str, str, str], set[str]]:
    """(enclave, ALLOW|DENY, pub|sub|srv|cli) -> resolved names, over all profiles."""
    grants: dict[tuple[str, str, str], set[str]] = defaultdict(set)
    for enclave in root.iter("enclave"):
        path = enclave.attrib["path"]
        for profile in enclave.iter("profile"):
            ns, node = profile.attrib["ns"], profile.attrib["node"]
            for rule in profile:
                assert rule.tag in ("topics", "services"), rule.tag  # no actions here
                for perm, qualifier in rule.attrib.items():
                    names = {resolve(e.text or "", ns, node) for e in rule}
                    grants[path, qualifier, KINDS[perm]] |= names
    return grants


def test_the_policy_is_valid_against_the_sros2_schema():
    xmlschema = pytest.importorskip("xmlschema")
    # allow="local": the schema's import of the XML namespace schema (a w3.org URL) falls
    # back to xmlschema's own copy; nothing is fetched
    schema = xmlschema.XMLSchema(str(SCHEMA), allow="local")
    schema.validate(str(POLICY))
    # the schema is not a rubber stamp: a wrong qualifier and the old root are refused
    text = POLICY.read_text()
    assert not schema.is_valid(text.replace('publish="ALLOW"', 'publish="YES"', 1))
    assert not schema.is_valid(text.replace("enclave", "context"))


@pytest.fixture(scope="module")
def graph():
    """(node name -> kind -> names) of the six nodes, read from the ROS graph."""
    ctx = Context()
    rclpy.init(context=ctx)
    sim = Parameter("use_sim_time", value=True)  # as the launch files run them
    ab = Parameter("models", value=["A", "B"])
    nodes = [
        bring_up(ValidatorNode(context=ctx, parameter_overrides=[sim, ab])),
        bring_up(
            PlantNode(
                context=ctx, parameter_overrides=[sim, Parameter("publish_clock", value=True)]
            )
        ),
        ExcitationNode(context=ctx, parameter_overrides=[sim]),
        bring_up(ControllerNode(context=ctx, parameter_overrides=[sim])),
        bring_up(SupervisorNode(context=ctx, parameter_overrides=[sim, ab, *SWITCH_ON])),
        ViewNode(None, ["A", "B"], context=ctx),  # type: ignore[arg-type]  # never fed here
    ]
    try:
        q = nodes[0]  # the graph of this participant holds its own entities at once
        calls = {
            "pub": q.get_publisher_names_and_types_by_node,
            "sub": q.get_subscriber_names_and_types_by_node,
            "srv": q.get_service_names_and_types_by_node,
            "cli": q.get_client_names_and_types_by_node,
        }
        yield {
            n.get_name(): {
                kind: {topic for topic, _ in call(n.get_name(), n.get_namespace())}
                for kind, call in calls.items()
            }
            for n in nodes
        }
    finally:
        for n in nodes:
            n.destroy_node()
        rclpy.shutdown(context=ctx)


def test_each_enclave_is_allowed_exactly_what_its_node_creates(graph):
    root = ET.parse(POLICY).getroot()
    grants = policy_grants(root)
    profiles = {
        e.attrib["path"]: [p.attrib["node"] for p in e.iter("profile")]
        for e in root.iter("enclave")
    }
    expected_enclaves = {"validator", "plant", "excitation", "controller", "supervisor", "view"}
    assert set(profiles) == {PREFIX + k for k in expected_enclaves | {"operator"}}
    for path, (node,) in profiles.items():
        if path == PREFIX + "operator":
            continue
        assert node in graph, f"{path} names node {node}, which none of the nodes is"
        for kind in KINDS.values():
            allowed = grants.get((path, "ALLOW", kind), set())
            created = graph[node][kind]
            if path == PREFIX + "supervisor" and kind == "cli":
                created = created | {"/reset_alarm", "/reset_operating_point"}
            assert allowed == created, (path, kind, allowed ^ created)
    assert {n for ps in profiles.values() for n in ps} - {"operator"} == set(graph)
    # the graph is not empty of what matters: the validator serves the resets
    assert {"/reset_alarm", "/reset_operating_point"} <= graph["twotank_validator"]["srv"]
    assert "/supervisor/reset" in graph["twotank_supervisor"]["srv"]


def test_only_the_supervisor_and_the_operator_may_call_the_resets():
    grants = policy_grants(ET.parse(POLICY).getroot())
    callers = {
        path
        for (path, qualifier, kind), names in grants.items()
        if qualifier == "ALLOW" and kind == "cli" and names & RESETS
    }
    assert callers == {PREFIX + "supervisor", PREFIX + "operator"}
    assert grants[PREFIX + "operator", "ALLOW", "cli"] == RESETS
    switch = "/controller_manager/switch_controller"  # the supervisor's ros2_control switch
    assert grants[PREFIX + "supervisor", "ALLOW", "cli"] - {switch} == RESETS - {
        "/supervisor/reset"
    }
    # and every other enclave is denied them outright (a later wildcard cannot grant them)
    for path in {p for p, _, _ in grants} - callers:
        assert grants[path, "DENY", "cli"] == RESETS, path
