"""The package's layers: imports run only downward, there is no cycle, ROS stays in ``ros/``.

The layers, lowest first (a module may import its own layer and the layers below it):

    errors, defaults, settings -> core -> online -> sim -> bags -> tables -> diagnose -> replay
    -> experiment -> calibrate -> identify -> report -> usecases -> fleet -> view -> ros -> cli

The package root (``twotank_validation/__init__.py``) is the public surface above them all; it
loads its names on first use and imports nothing at import time. Every ``import`` statement
is read from the source (function-level imports included), so a lazy import cannot hide an
upward arrow.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "twotank_validation"
LAYERS = (
    ("errors", "defaults", "settings"),
    ("core",),
    ("online",),
    ("sim",),
    ("bags",),
    ("tables",),
    ("diagnose",),
    ("replay",),
    ("experiment",),
    ("calibrate",),
    ("identify",),
    ("report",),
    ("usecases",),
    ("fleet",),
    ("view",),
    ("ros",),
    ("cli", "cli_options", "cli_common", "cli_models", "cli_view"),
)
ROS_ONLY = ("rclpy", "rosidl_runtime_py", "rosgraph_msgs", "diagnostic_msgs", "std_srvs")


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted((ROOT / PACKAGE).rglob("*.py"))}


def _imports(name: str, path: Path) -> Iterator[tuple[str, int]]:
    """Yield (imported module, line) for every import in the file, absolute names."""
    is_pkg = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base if is_pkg else base[:-1]
                base = base[: len(base) - node.level + 1]
                mod = ".".join([*base, node.module] if node.module else base)
            else:
                mod = node.module or ""
            yield mod, node.lineno
            for alias in node.names:  # "from pkg import module" imports the module
                yield f"{mod}.{alias.name}", node.lineno


def _resolve(target: str, modules: dict[str, Path]) -> str | None:
    """The package module that ``target`` names (longest existing prefix), or None."""
    parts = target.split(".")
    while parts:
        cand = ".".join(parts)
        if cand in modules:
            return cand
        parts.pop()
    return None


def _layer(module: str) -> int | None:
    """Index in LAYERS of a package module; None for the package root."""
    parts = module.split(".")
    if len(parts) == 1:
        return None
    top = parts[1]
    for i, names in enumerate(LAYERS):
        if top in names:
            return i
    pytest.fail(f"module {module} is in no layer: add {top!r} to LAYERS in {__file__}")


def _graph() -> dict[str, set[tuple[str, int]]]:
    modules = _modules()
    graph: dict[str, set[tuple[str, int]]] = {}
    for name, path in modules.items():
        edges = graph.setdefault(name, set())
        for target, line in _imports(name, path):
            dep = _resolve(target, modules)
            if dep is not None and dep != name and not name.startswith(dep + "."):
                edges.add((dep, line))  # a package's own __init__ is not an arrow back up
    return graph


def test_every_layer_exists() -> None:
    tops = {m.split(".")[1] for m in _modules() if "." in m}
    named = {n for layer in LAYERS for n in layer}
    assert tops == named, f"layers without modules: {named - tops}; unlisted: {tops - named}"


def test_imports_run_only_downward() -> None:
    upward = []
    for name, edges in _graph().items():
        here = _layer(name)
        for dep, line in sorted(edges):
            there = _layer(dep)
            if here is None:
                continue  # the public surface may name anything (it imports nothing eagerly)
            if there is None:
                upward.append(f"{name}:{line} imports the package root ({dep})")
            elif there > here:
                upward.append(f"{name}:{line} imports {dep} (layer {LAYERS[there]})")
    assert not upward, "imports that run upward:\n" + "\n".join(upward)


def test_no_import_cycle() -> None:
    graph = {k: {d for d, _ in v} for k, v in _graph().items()}
    state: dict[str, int] = {}  # 1: on the stack, 2: done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                return [*stack[stack.index(dep) :], dep]
            if dep not in state and (cycle := visit(dep)) is not None:
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)) is not None:
            pytest.fail("import cycle: " + " -> ".join(cycle))


def test_ros_is_imported_only_in_ros() -> None:
    offenders = []
    for name, path in _modules().items():
        if name.startswith(f"{PACKAGE}.ros"):
            continue
        for target, line in _imports(name, path):
            top = target.split(".")[0]
            if top in ROS_ONLY or top.endswith("_msgs"):
                offenders.append(f"{name}:{line} imports {target}")
    assert not offenders, "ROS imports outside ros/:\n" + "\n".join(offenders)


def test_the_package_root_imports_nothing_eagerly() -> None:
    """Importing twotank_validation loads none of its layers (names load on first use)."""
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    code = (
        "import sys, twotank_validation as t\n"
        "print(sorted(m for m in sys.modules if m.startswith('twotank_validation.')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def _levels() -> str:
    """The import graph by levels: layers and what each imports, then modules by depth."""
    graph = {k: {d for d, _ in v} for k, v in _graph().items() if _layer(k) is not None}
    lines = ["layers (top first) and the layers they import:"]
    for i in range(len(LAYERS) - 1, -1, -1):
        below = {
            _layer(d)
            for n, deps in graph.items()
            if _layer(n) == i
            for d in deps
            if _layer(d) not in (None, i)
        }
        names = ", ".join(n for j in sorted(below, reverse=True) for n in LAYERS[j])
        lines.append(f"  {' + '.join(LAYERS[i]):18s} -> {names or '(nothing in the package)'}")
    level: dict[str, int] = {}

    def depth(node: str) -> int:
        if node not in level:
            level[node] = 0  # a cycle would recurse forever; test_no_import_cycle forbids one
            level[node] = 1 + max((depth(d) for d in graph[node] if d in graph), default=0)
        return level[node]

    for node in graph:
        depth(node)
    lines.append("modules by level (1 + the level of the deepest module each imports):")
    for lvl in range(max(level.values()), 0, -1):
        names = sorted(n.removeprefix(f"{PACKAGE}.") for n, v in level.items() if v == lvl)
        lines.append(f"  level {lvl:2d}: " + ", ".join(names))
    return "\n".join(lines)


if __name__ == "__main__":
    print(_levels())
