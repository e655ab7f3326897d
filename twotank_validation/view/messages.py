"""What the page gets of a report: the ``validate --json`` window entry, and its spectrum.

One serialisation for a window everywhere: :func:`~twotank_validation.replay.window_entry`
(the entries of ``validate --json``'s ``windows``), with the model's name beside it and, for
the per-bin plot, the window's per-bin arrays (:func:`spectrum`: the minimum ‖W‖, the noise
floor and the excited lines), which the JSON file leaves out.
"""

from __future__ import annotations

import base64
from typing import Any

import numpy as np

from twotank_validation.core.band import Band
from twotank_validation.online.window import WindowReport
from twotank_validation.replay import window_entry


def spectrum(rep: WindowReport) -> dict[str, Any]:
    """A window's bins above 0 Hz: ``{"n_bins", "freqs_hz", "w_min", "noise_floor", "excited"}``.

    ``w_min`` is the report's per-bin minimum ‖W(n)‖ (units of ``w``), ``noise_floor`` what
    the window's noise alone is expected to cost at each bin (the report's ``noise_floor``,
    the per-bin terms of ``noise_beta``; null where the report has none) and ``freqs_hz``
    the bins' frequencies, each the base64 of its float64 values, little-endian (the page
    reads them as a ``Float64Array``): the numbers exactly, NaN and inf as they are, and
    some thousand of them in a few microseconds, where writing them as JSON numbers costs a
    millisecond a window (``bench/bench_view.py``). ``excited``: the indices (into these
    arrays) of the lines the command excites (the report's ``excited``; null where it has
    none).
    """
    keep = rep.freqs_hz > 0
    n = rep.freqs_hz.size
    floor = rep.noise_floor[keep] if rep.noise_floor.size == n else None
    excited = np.flatnonzero(rep.excited[keep]) if rep.excited.size == n else None
    return {
        "n_bins": int(np.count_nonzero(keep)),
        "freqs_hz": _b64(rep.freqs_hz[keep]),
        "w_min": _b64(rep.w_min[keep]),
        "noise_floor": None if floor is None else _b64(floor),
        "excited": None if excited is None else excited.tolist(),
    }


def _b64(x: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(x, dtype="<f8").tobytes()).decode("ascii")


def report_message(
    rep: WindowReport, start_ns: int = 0, *, with_spectrum: bool = True
) -> dict[str, Any]:
    """The page's message of a report: ``{"type": "report", "model", **window entry}``.

    Args:
        rep: the report.
        start_ns: the stamp times are counted from (``validate``: the recording's start, as
            its JSON; ``live``: 0, the simulated clock's, as ``live --json``).
        with_spectrum: add ``spectrum`` where the window was judged.

    The window entry is :func:`~twotank_validation.replay.window_entry`'s (times in s from
    ``start_ns``), plus ``n_periods``, ``convention`` and, where the window was judged,
    ``spectrum`` (:func:`spectrum`; the server sends spectra as messages of their own).
    """
    msg: dict[str, Any] = {"type": "report", "model": rep.model, **window_entry(rep, start_ns)}
    msg["n_periods"] = rep.n_periods
    msg["convention"] = rep.convention
    if with_spectrum and rep.judged and rep.freqs_hz.size:
        msg["spectrum"] = spectrum(rep)
    return msg


def band_entry(band: Band | None) -> dict[str, Any] | None:
    """A model's band for the page (``Band.to_dict``), None where it has none."""
    return None if band is None else band.to_dict()


def mode_message(mode: str, time_s: float, reason: str = "") -> dict[str, Any]:
    """The supervisor's mode for the page: ``{"type": "mode", "mode", "time", "reason"}``.

    Args:
        mode: ``control/mode``'s value (``normal``, ``safe``).
        time_s: since when (s: ``live``, the simulated clock's; ``view``, the node clock's).
        reason: why it changed (the transition's reason; empty where not known).
    """
    return {"type": "mode", "mode": mode, "time": time_s, "reason": reason}
