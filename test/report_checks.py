"""Shared assertion for tests that compare two runs' window reports."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from twotank_validation.online import WindowReport


def assert_same_reports(got: Sequence[WindowReport], want: Sequence[WindowReport]) -> None:
    """Pairwise equal windows, verdicts, reasons and warnings; judged windows bit for bit
    (beta, w_min)."""
    for a, b in zip(got, want, strict=False):
        assert (a.model, a.start_ns, a.end_ns, a.judged, a.alarm, a.data_quality) == (
            b.model,
            b.start_ns,
            b.end_ns,
            b.judged,
            b.alarm,
            b.data_quality,
        )
        assert a.warnings == b.warnings
        assert (a.raised_by, a.operating_point, a.invalidated) == (
            b.raised_by,
            b.operating_point,
            b.invalidated,
        )
        if a.judged:
            assert a.beta == b.beta  # bit for bit
            np.testing.assert_array_equal(a.w_min, b.w_min)
            np.testing.assert_array_equal([a.beta_op, a.beta_total], [b.beta_op, b.beta_total])
