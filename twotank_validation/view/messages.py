"""What the page gets of a report: the ``validate --json`` window entry, and its spectrum.

One serialisation for a window everywhere: :func:`~twotank_validation.replay.window_entry`
(the entries of ``validate --json``'s ``windows``), with the model's name beside it and, for
the per-bin plot, the window's per-bin minimum ‖W‖ (:func:`spectrum`), which the JSON file
leaves out.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from twotank_validation.core.band import Band
from twotank_validation.online.window import WindowReport
from twotank_validation.replay import window_entry


def spectrum(rep: WindowReport) -> dict[str, Any]:
    """``{"freqs_hz": [...], "w_min": [...]}`` of a window's bins above 0 Hz (empty if none).

    ``w_min`` is the report's per-bin minimum ‖W(n)‖ (units of ``w``); a value that is not
    finite is ``null``.
    """
    keep = rep.freqs_hz > 0
    w = rep.w_min[keep]
    values: list[float | None] = [float(x) if math.isfinite(x) else None for x in w.tolist()]
    return {"freqs_hz": np.asarray(rep.freqs_hz[keep], dtype=float).tolist(), "w_min": values}


def report_message(rep: WindowReport, start_ns: int = 0) -> dict[str, Any]:
    """The page's message of a report: ``{"type": "report", "model", **window entry}``.

    Args:
        rep: the report.
        start_ns: the stamp times are counted from (``validate``: the recording's start, as
            its JSON; ``live``: 0, the simulated clock's, as ``live --json``).

    The window entry is :func:`~twotank_validation.replay.window_entry`'s (times in s from
    ``start_ns``), plus ``n_periods``, ``convention`` and, where the window was judged,
    ``spectrum`` (:func:`spectrum`).
    """
    msg: dict[str, Any] = {"type": "report", "model": rep.model, **window_entry(rep, start_ns)}
    msg["n_periods"] = rep.n_periods
    msg["convention"] = rep.convention
    if rep.judged and rep.freqs_hz.size:
        msg["spectrum"] = spectrum(rep)
    return msg


def band_entry(band: Band | None) -> dict[str, Any] | None:
    """A model's band for the page (``Band.to_dict``), None where it has none."""
    return None if band is None else band.to_dict()
