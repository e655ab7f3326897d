"""The public surface: ``from twotank_validation import X`` gives the defining module's X."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import numpy as np
import pytest

import twotank_validation as tv


@pytest.mark.parametrize("name", tv.__all__)
def test_public_name_is_the_defining_modules_object(name: str) -> None:
    module = importlib.import_module(tv._PUBLIC[name])
    assert getattr(tv, name) is getattr(module, name)
    assert name in dir(tv)


def test_all_lists_the_public_names() -> None:
    assert sorted(tv.__all__) == sorted(tv._PUBLIC)


def test_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        _ = tv.nonsense  # type: ignore[attr-defined]


def test_readme_core_example_runs() -> None:
    """The README's core example, on a short datum: Model B explains its own nominal response."""
    from twotank_validation import load_model, make_datum, validate  # noqa: PLC0415

    model = load_model("B")
    rng = np.random.default_rng(0)
    n, p = 256, 128
    u = np.tile(rng.standard_normal((p, 2)) * 0.05, (n // p, 1))
    y = np.zeros((n, 2))  # zero output: explained by some ||w|| > 0 or not at all
    datum = make_datum(u, y, ts_s=0.8, period_samples=p)
    result = validate(datum, model)
    assert result.beta == pytest.approx(validate(datum, model, method="sdp").beta, rel=1e-3)


ROOT = Path(__file__).resolve().parent.parent
PAGES = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))
_DOC_IMPORT = re.compile(r"^from (twotank_validation\S*) import (\([^)]*\)|[^\n]*)", re.MULTILINE)


def _documented_imports() -> list[tuple[str, str, str]]:
    """(page, module, name) of every ``from twotank_validation... import`` in the pages' code."""
    out: set[tuple[str, str, str]] = set()
    for page in PAGES:
        for block in re.findall(r"```python\n(.*?)```", page.read_text(), re.DOTALL):
            for match in _DOC_IMPORT.finditer(block):
                node = ast.parse(match.group(0)).body[0]
                assert isinstance(node, ast.ImportFrom)
                out |= {(page.name, match.group(1), alias.name) for alias in node.names}
    return sorted(out)


def test_the_docs_show_imports() -> None:
    pages = {page for page, _, _ in _documented_imports()}
    assert {"README.md", "api.md", "interface.md"} <= pages


@pytest.mark.parametrize(("page", "module", "name"), _documented_imports())
def test_documented_import_paths_work(page: str, module: str, name: str) -> None:
    """Every name the README and docs import from a module path is there (modules moved)."""
    assert hasattr(importlib.import_module(module), name), f"{page}: from {module} import {name}"
