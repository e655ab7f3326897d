"""The record reductions of core/columns.py against numpy's own, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from twotank_validation.core import columns


def records():
    rng = np.random.default_rng(7)
    for n, k in ((4096, 2), (6144, 2), (1, 2), (7, 4), (9, 3), (5, 1), (300, 6)):
        x = rng.standard_normal((n, k)) * rng.choice([1e-6, 1.0, 1e6], k) + rng.normal(0, 10, k)
        yield x
        yield np.asfortranarray(x)  # any layout
        if k >= 2:
            yield np.hstack([x, x])[:, :k]  # rows wider than the record (a column slice)
    x = np.ones((10, 2))
    x[3, 1] = np.nan
    x[4, 0] = np.inf
    yield x
    yield np.full((8, 2), -0.0)
    z = np.full((8, 2), -0.0)
    z[5] = 1.5
    yield z


@pytest.mark.parametrize("x", list(records()), ids=lambda x: f"{x.shape}")
def test_column_reductions_are_numpys_bit_for_bit(x) -> None:
    with np.errstate(invalid="ignore"):
        assert columns.column_sum(x).tobytes() == np.sum(x, axis=0).tobytes()
        assert columns.column_mean(x).tobytes() == np.mean(x, axis=0).tobytes()
        assert columns.column_max_abs(x).tobytes() == np.max(np.abs(x), axis=0).tobytes()
        row = np.mean(x, axis=0)
        got = columns.centred(x, row)
        assert got.shape == x.shape
        assert got.tobytes() == (x - row).tobytes()
        assert columns.centred(x, -row).tobytes() == (x - (-row)).tobytes()


@pytest.mark.parametrize(("p", "k"), [(2, 2), (3, 2), (4, 4), (2, 3), (1, 2)])
def test_period_means_are_numpys_bit_for_bit(p, k) -> None:
    rng = np.random.default_rng(p * 10 + k)
    x = rng.standard_normal((p * 512, k)) * 3.0 + 0.25
    periods = x.reshape(p, 512, k)
    assert columns.period_mean(periods).tobytes() == periods.mean(axis=1).tobytes()
    zeros = -0.0 * np.abs(periods)  # all -0: numpy's sum starts from +0
    assert columns.period_mean(zeros).tobytes() == zeros.mean(axis=1).tobytes()
    diff = np.diff(periods, axis=0) ** 2
    if diff.size:
        assert columns.period_mean(diff).tobytes() == np.mean(diff, axis=1).tobytes()


@pytest.mark.parametrize("k", [1, 2, 3])
def test_row_norms_are_numpys_bit_for_bit(k) -> None:
    rng = np.random.default_rng(k)
    w = rng.standard_normal((5000, k)) + 1j * rng.standard_normal((5000, k))
    w *= rng.choice([1e-160, 1e-3, 1.0, 1e150], (5000, 1))  # underflow and overflow too
    w[0] = 0.0
    w[1] = complex(-0.0, -0.0)
    w[2, 0] = complex(np.nan, 1.0)
    w[3, -1] = complex(-np.inf, 0.0)
    with np.errstate(all="ignore"):
        got, want = columns.row_norm(w), np.linalg.norm(w, axis=1)
        assert got.tobytes() == want.tobytes()
        assert columns.row_norm(w.real).tobytes() == np.linalg.norm(w.real, axis=1).tobytes()
