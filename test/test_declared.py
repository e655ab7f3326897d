"""The package declares what it needs: rosdep keys, licence, changelog (issue 31, item 4).

References: the requirement files (what the tests install and run on), the installed
distributions' own metadata (``importlib.metadata``: which package brings which), and
catkin_pkg's parser of package.xml (the one rosdep and colcon use). ``rosdep_keys.yaml`` is the
hand-kept list of keys read from ros/rosdistro's rosdep/python.yaml; rosdep itself and the
rosdistro index are not reachable here, so the key names are checked for consistency, not
resolved.
"""

from __future__ import annotations

import re
from importlib import metadata
from pathlib import Path

import yaml
from catkin_pkg.changelog import get_changelog_from_path
from catkin_pkg.package import parse_package

ROOT = Path(__file__).resolve().parent.parent
KEYS = yaml.safe_load((ROOT / "rosdep_keys.yaml").read_text())


def _norm(name: str) -> str:
    """PEP 503 normalised distribution name."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirements(path: Path) -> dict[str, str]:
    """Normalised name -> pinned version of each requirement line of ``path``."""
    out = {}
    for raw in path.read_text().splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        m = re.fullmatch(r"([A-Za-z0-9_.-]+)(\[[^\]]*\])?==(\S+)", line)
        assert m, f"{path.name}: unpinned or unreadable line {line!r}"
        out[_norm(m.group(1))] = m.group(3)
    return out


RUNTIME = _requirements(ROOT / "requirements.txt")
ROS = _requirements(ROOT / "requirements-ros.txt")
PYTHON = {_norm(k): v for k, v in KEYS["python"].items()}


def _package_keys() -> set[str]:
    pkg = parse_package(str(ROOT / "package.xml"))
    return {d.name for d in (*pkg.exec_depends, *pkg.build_export_depends)}


def test_every_requirement_is_accounted_for() -> None:
    wheels = {_norm(f"ros-{name}") for name in KEYS["ros"]}
    tools = {_norm(t) for t in KEYS["message_build_tools"]}
    missing = [n for n in RUNTIME if n not in PYTHON]
    missing += [n for n in ROS if n not in PYTHON and n not in wheels and n not in tools]
    assert not missing, f"add to rosdep_keys.yaml (a key, via or pip): {missing}"
    stale = [n for n in PYTHON if n not in RUNTIME and n not in ROS]
    stale += [t for t in tools if t not in ROS]
    assert not stale, f"rosdep_keys.yaml names what no requirement file holds: {stale}"


def test_each_entry_says_key_via_or_pip() -> None:
    for name, entry in PYTHON.items():
        kinds = {"key", "via", "pip"} & set(entry)
        assert len(kinds) == 1, f"{name}: exactly one of key, via, pip"
        assert set(entry) <= {"key", "via", "pip", "note"}, name


def test_package_xml_names_exactly_the_keys() -> None:
    keys = {e["key"] for e in PYTHON.values() if "key" in e}
    expected = keys | set(KEYS["ros"])
    declared = _package_keys()
    assert declared == expected, (
        f"package.xml lacks {sorted(expected - declared)}, has extra {sorted(declared - expected)}"
    )
    # the keys rosdistro does not define (the list) stay out
    assert not declared & {"python3-cvxpy", "clarabel", "rosbags", "mcap", "pyarrow"}


def test_via_entries_come_with_their_carrier() -> None:
    """A ``via`` dependency is a declared requirement of the keyed package that carries it."""
    for name, entry in PYTHON.items():
        if "via" not in entry:
            continue
        carrier = _norm(entry["via"])
        assert "key" in PYTHON[carrier], f"{name} via {carrier}, which has no key"
        requires = metadata.requires(carrier) or []
        names = {_norm(re.split(r"[ ;<>=!~\[(]", r, maxsplit=1)[0]) for r in requires}
        assert name in names, f"{carrier} does not require {name}: {requires}"


def test_install_doc_names_the_pip_only_dependencies_at_their_pins() -> None:
    pip_only = {n for n, e in PYTHON.items() if "pip" in e}
    text = (ROOT / "docs" / "install.md").read_text()
    lines = [ln for ln in text.splitlines() if ln.startswith("pip install") and "pyarrow" in ln]
    assert len(lines) == 1, "docs/install.md: one `pip install` line of the keyless deps"
    pins = dict(re.findall(r"([A-Za-z0-9_.-]+)==(\S+)", lines[0]))
    assert {_norm(n) for n in pins} == pip_only
    assert all(RUNTIME[_norm(n)] == v for n, v in pins.items())


def test_licence_and_changelog_match_the_manifest() -> None:
    pkg = parse_package(str(ROOT / "package.xml"))
    assert [str(lic) for lic in pkg.licenses] == ["BSD-3-Clause"]
    licence = (ROOT / "LICENSE").read_text()
    # the three clauses of BSD-3-Clause (SPDX text), the third the non-endorsement one
    assert "Redistributions of source code must retain" in licence
    assert "Redistributions in binary form must reproduce" in licence
    assert "Neither the name of the copyright holder nor the names of its" in licence
    # catkin_pkg's own changelog parser (what bloom and catkin_generate_changelog use)
    changelog = get_changelog_from_path(str(ROOT / "CHANGELOG.rst"), pkg.name)
    assert changelog is not None
    versions = [version for version, _date, _content in changelog.foreach_version()]
    assert versions[0] == pkg.version, f"CHANGELOG.rst starts at {versions[0]}"
    assert (
        (ROOT / "QUALITY_DECLARATION.md")
        .read_text()
        .startswith(f"This document is a declaration of software quality for the `{pkg.name}`")
    )
