"""The public surface: ``from twotank_validation import X`` gives the defining module's X."""

from __future__ import annotations

import importlib

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
