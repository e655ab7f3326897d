"""The identified frequency response for the page: ``identify --json``'s ``report``, checked.

``identify BAG --json FILE`` writes, per excited line in the band, the measured response
``Ĥ`` with its standard deviations (noise; stochastic nonlinear distortion), the fitted
nominal ``G`` and the magnitude of the written output-multiplicative weight ``|W_c|``
(:meth:`~twotank_validation.identify.requirement.ReportNumbers.to_json`). The page draws,
per output/input entry, ``|Ĥ| ± σ`` against ``|G| (1 ± |W_c|)``: the set of responses the
model set allows at that line has magnitudes in that band (``H = (1 + W_c δ) G``,
``|δ| <= 1``).

The identify JSON names its channels (``inputs``, ``outputs``) and is matched by name; one
without them (written before it named them) is matched by shape (outputs × inputs), and the
written weights' names (``<output>_multiplicative``), where there are any, must name the
models' outputs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["ResponseError", "response_message"]

_FIX = "write one with `twotank-validation identify BAG --json FILE`"


class ResponseError(ValueError):
    """The document is not a usable identify JSON for these channels (the text says why)."""


def _finite(x: np.ndarray) -> Any:
    """Nested lists with NaN and inf as None (the page's JSON has neither)."""
    if x.ndim == 0:
        v = float(x)
        return v if math.isfinite(v) else None
    return [_finite(v) for v in x]


def _array(report: Mapping[str, Any], key: str, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.array(report[key], dtype=float)
    except (KeyError, TypeError, ValueError) as err:
        raise ResponseError(f"its report has no numeric {key!r}: {_FIX}") from err
    if arr.shape != shape:
        raise ResponseError(f"its report's {key!r} has shape {arr.shape}, not {shape}: {_FIX}")
    return arr


def response_message(
    doc: Any, inputs: Sequence[str], outputs: Sequence[str], source: str = ""
) -> dict[str, Any]:
    """The page's ``"response"`` message of an identify JSON, matched to the channels.

    Args:
        doc: the parsed identify JSON.
        inputs: the models' input names (n_u).
        outputs: the models' output names (n_y).
        source: the file's name (shown on the page).

    Returns:
        ``{"type": "response", "source", "inputs", "outputs", "matched"`` ("names" or
        "shape"), ``"level", "freqs_hz"`` (L,), ``"entries"``: per output/input entry
        ``{"output", "input", "measured"`` (L, 2: re, im), ``"std_noise"`` (L,),
        ``"std_distortion"`` (L, or None where the JSON gives the total only),
        ``"std_total"`` (L,), ``"nominal"`` (L, 2), ``"weight"`` (L: ``|W_c|`` of the
        entry's output, 0 where none is written)``}``. Units: the models' (output units
        per input unit); frequencies in Hz; non-finite numbers as None.

    Raises:
        ResponseError: not an identify JSON with a ``report``, or its shape (or names)
            not the channels'.
    """
    report = doc.get("report") if isinstance(doc, Mapping) else None
    if not isinstance(report, Mapping) or "measured" not in report:
        raise ResponseError(
            f"not an identify JSON (no 'report' with the measured response): {_FIX}"
        )
    try:
        freqs = np.array(report.get("freqs_hz"), dtype=float)
        measured = np.array(report["measured"], dtype=float)
    except (TypeError, ValueError) as err:
        raise ResponseError(
            f"its report's 'freqs_hz' or 'measured' is not numeric: {_FIX}"
        ) from err
    if freqs.ndim != 1 or measured.ndim != 4 or measured.shape[::3] != (freqs.size, 2):
        raise ResponseError(f"its report's 'measured' is not (lines, outputs, inputs, 2): {_FIX}")
    n_y, n_u = len(outputs), len(inputs)
    if (got := measured.shape[1:3]) != (n_y, n_u):
        raise ResponseError(
            f"its response has {got[0]} output(s) x {got[1]} input(s), the models' channels "
            f"are {n_y} x {n_u} ({list(outputs)} x {list(inputs)}): identify a recording of "
            "these channels, or view models of that record's"
        )
    shape = (freqs.size, n_y, n_u)
    nominal = _array(report, "nominal", (*shape, 2))
    std_noise = _array(report, "std_noise", shape)
    std_dist: np.ndarray | None = None
    if "std_distortion" in report:
        std_dist = _array(report, "std_distortion", shape)
        std_total = np.hypot(std_noise, std_dist)
    else:  # a report with the total only
        std_total = _array(report, "std", shape)
    pert = report.get("perturbation")
    weight = _array(pert if isinstance(pert, Mapping) else {}, "weight", (freqs.size, n_y))
    matched = _match(doc, inputs, outputs)
    entries = []
    for c, out in enumerate(outputs):
        for i, inp in enumerate(inputs):
            entries.append(
                {
                    "output": out,
                    "input": inp,
                    "measured": _finite(measured[:, c, i]),
                    "std_noise": _finite(std_noise[:, c, i]),
                    "std_distortion": None if std_dist is None else _finite(std_dist[:, c, i]),
                    "std_total": _finite(std_total[:, c, i]),
                    "nominal": _finite(nominal[:, c, i]),
                    "weight": _finite(weight[:, c]),
                }
            )
    level = report.get("level")
    return {
        "type": "response",
        "source": source,
        "inputs": list(inputs),
        "outputs": list(outputs),
        "matched": matched,
        "level": level if isinstance(level, (int, float)) else None,
        "freqs_hz": _finite(freqs),
        "entries": entries,
    }


def _match(doc: Mapping[str, Any], inputs: Sequence[str], outputs: Sequence[str]) -> str:
    """How the entries were matched: "names" (the JSON lists them) or "shape".

    Raises:
        ResponseError: the JSON's names, or its weights' ``<output>_multiplicative``
            names, are not the models' channels.
    """
    named = {k: doc.get(k) for k in ("inputs", "outputs")}
    by_name = all(isinstance(v, list) for v in named.values())
    if by_name and (named["inputs"] != list(inputs) or named["outputs"] != list(outputs)):
        raise ResponseError(
            f"its channels are {named['outputs']} x {named['inputs']}, the models' "
            f"{list(outputs)} x {list(inputs)}: identify a recording of these channels"
        )
    # the weights' names are checked either way: they must agree with the channels too
    weights = doc.get("perturbation_weights") or []
    for w in weights if isinstance(weights, list) else []:
        name = str(w.get("name", "")) if isinstance(w, Mapping) else ""
        out = name.removesuffix("_multiplicative")
        if out != name and out not in outputs:
            raise ResponseError(
                f"its weight {name!r} is on output {out!r}, not one of the models' outputs "
                f"{list(outputs)}: identify a recording of these channels"
            )
    return "names" if by_name else "shape"
