"""Calibrate on a recording (bag or table, read through the replay path) and report it.

:func:`calibrate_recording` cuts the judged windows out of a recording as the validator saw
them (:func:`~twotank_validation.replay.windows_from_recording`) and calibrates on them;
:func:`calibration_text` and :func:`write_calibration_report` say what came out, in words and
in figures (matplotlib): beta per window before and after, and each block's weight
magnitudes against its per-bin requirement, with the band the data covered.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from twotank_validation.calibrate.calibration import (
    NO_WEIGHT_CHANGED,
    BlockCalibration,
    Calibration,
    CalibrationConfig,
    calibrate,
)
from twotank_validation.calibrate.scaling import CalibrationError, model_blocks
from twotank_validation.core import lti
from twotank_validation.core.model import LFTModel, model_from_dict
from twotank_validation.replay import (
    ReplayConfig,
    ReplayResult,
    unjudged,
    windows_from_recording,
)


def calibrate_recording(
    path: str | Path,
    doc: Mapping[str, Any],
    config: CalibrationConfig | None = None,
    replay_config: ReplayConfig | None = None,
    *,
    blocks: Sequence[str] | None = None,
    source: str = "model",
) -> tuple[Calibration, ReplayResult]:
    """Calibrate ``doc``'s model on the judged, non-overlapping windows of a recording.

    Args:
        path: a rosbag2 bag, an MCAP file, or a CSV/Parquet table (with an interface map in
            ``replay_config``).
        doc: the model document.
        config: calibration settings.
        replay_config: topics, units, window settings (its norm convention is used).
        blocks: the blocks to calibrate (None: all).
        source: the model's label.

    Raises:
        CalibrationError: no window of the recording could be judged (the message says why
            and what to do), an unknown block; and as
            :func:`~twotank_validation.replay.windows_from_recording`.
    """
    cfg = replay_config or ReplayConfig()
    model = model_from_dict(doc, source)
    windows, replayed = windows_from_recording(path, model, cfg)
    if not windows:
        why = [u.text() for u in unjudged(replayed, [model.name], None, cfg)]
        raise CalibrationError(
            "; ".join(why) or f"no window of model {model.name} could be judged in {path}"
        )
    result = calibrate(
        windows, doc, config, blocks=blocks, source=source, convention=cfg.monitor.convention
    )
    return result, replayed


def _fmt(x: float) -> str:
    return "inf" if math.isinf(x) else f"{x:.4g}"


def calibration_text(cal: Calibration, model_file: str | None = None) -> str:
    """What the calibration found, in a few lines."""
    lo, hi = cal.band_hz
    lines = [
        f"calibration of model {cal.model} on {cal.window_starts_s.size} judged window(s) "
        f"(beta {_fmt(float(np.min(cal.window_beta)))} .. {_fmt(float(np.max(cal.window_beta)))}, "
        f"{cal.convention.value} norm)",
        f"the data covered {lo:.4g} .. {hi:.4g} Hz (the excited harmonics): weights outside "
        "this band are extrapolated, the data say nothing there",
        "factor: what a block's stated weight is multiplied by; alone: the smallest for which "
        "no window is invalidated, the other blocks as stated; written: the factor in the new "
        + (
            "model file, the block's joint factor (the chosen blocks scaled together) times "
            "the margin"
            if cal.joint is not None
            else "model file, found in order (the blocks above as calibrated, so it may be "
            "below the factor alone) times the margin"
        ),
    ]
    for b in cal.blocks:
        lines.append("  " + b.used_text())
        per = ", ".join(_fmt(s) for s in b.window_scaling)
        lines.append(f"    factor alone, per window: {per}")
        if b.fitted is not None:
            f = b.fitted
            lines.append(
                f"    fitted weight of order {f.order} ({_node_text(f.to_node())}) covers "
                f"{f.margin:g} × the per-bin requirement at {b.freqs_hz.size} excited bin(s), "
                f"{f.mean_excess_db:.1f} dB above it on average"
            )
            ext = cal.extrapolated.get(b.name, {})
            if ext:
                lines.append(
                    "    extrapolated: |W| "
                    + ", ".join(f"{k.replace('_', ' ')} {v:.3g}" for k, v in ext.items())
                )
        if b.note:
            lines.append(f"    {b.note}")
    if cal.joint is not None:
        lines += cal.joint.text()
    j = cal.judged
    for held, label in ((False, "fit"), (True, "held-out")):
        sel = j.held_out == held
        if np.any(sel):
            lines.append(
                f"{label} windows: beta {_list(j.beta[sel])} before, "
                f"{_list(j.beta_after[sel])} after"
            )
    if cal.document is None:
        lines.append(NO_WEIGHT_CHANGED)
    elif model_file:
        lines.append(f"calibrated model written to {model_file}")
    return "\n".join(lines)


def _list(xs: np.ndarray) -> str:
    return "[" + ", ".join(_fmt(float(x)) for x in xs) + "]"


def _node_text(node: Mapping[str, Any]) -> str:
    if "gain" in node:
        return f"gain {node['gain']:.4g}"
    tf = node["tf"]
    num = ", ".join(f"{x:.4g}" for x in tf["num"])
    den = ", ".join(f"{x:.4g}" for x in tf["den"])
    return f"tf num [{num}] den [{den}]"


def _curve(
    sys: lti.StateSpace, theta: np.ndarray, ts_s: float, intersample: lti.Intersample
) -> np.ndarray:
    resp = lti.bin_response(sys, theta, ts_s, intersample)
    gain: np.ndarray = np.linalg.norm(resp, ord=2, axis=(1, 2))
    return gain


def weight_curves(
    cal: Calibration, stated: LFTModel, ts_s: float, n_points: int = 400
) -> dict[str, dict[str, np.ndarray]]:
    """Each block's weight magnitudes on a log grid up to Nyquist.

    Returns:
        Per block name: ``freqs_hz``, and the magnitudes ``stated``, ``scaled`` (stated x
        the uniform scaling) and ``calibrated`` (the calibrated model's weight).
    """
    lo = max(cal.band_hz[0] / 20.0, 1e-6) if cal.band_hz[0] > 0 else 1e-4 / ts_s
    freqs = np.geomspace(lo, 0.5 / ts_s, n_points)
    theta = 2 * np.pi * freqs * ts_s
    after = model_from_dict(cal.document, "calibrated") if cal.document is not None else stated
    before_blocks = {b.name: b for b in model_blocks(stated)}
    after_blocks = {b.name: b for b in model_blocks(after)}
    out = {}
    for bc in cal.blocks:
        b0, b1 = before_blocks[bc.name].weight, after_blocks[bc.name].weight
        if b0 is None or b1 is None:
            continue
        s0 = _curve(b0, theta, ts_s, stated.intersample)
        out[bc.name] = {
            "freqs_hz": freqs,
            "stated": s0,
            "scaled": s0 * bc.scaling if math.isfinite(bc.scaling) else np.full_like(s0, np.nan),
            "calibrated": _curve(b1, theta, ts_s, after.intersample),
        }
    return out


def write_calibration_report(
    cal: Calibration, stated: LFTModel, ts_s: float, out_dir: Path, model_file: str | None = None
) -> list[Path]:
    """``calibration.md``, ``calibration_beta.png`` and ``calibration_weights.png`` in ``out_dir``.

    Returns:
        The files written.
    """
    import matplotlib as mpl  # noqa: PLC0415 (figures only)

    mpl.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    j = cal.judged
    fig, ax = plt.subplots(figsize=(7, 3.5))
    x = np.arange(j.start_s.size)
    ax.bar(x - 0.2, j.beta, 0.4, label="stated model", color="tab:gray")
    ax.bar(x + 0.2, j.beta_after, 0.4, label="calibrated model", color="tab:blue")
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    labels = [
        f"{t:.0f} s" + (" (held out)" if h else "")
        for t, h in zip(j.start_s, j.held_out, strict=True)
    ]
    ax.set_xticks(x, labels, rotation=20, fontsize=7)
    ax.set_ylabel(f"beta ({cal.convention.value} norm)")
    ax.set_title(f"model {cal.model}: beta per window before and after calibration")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out_dir / "calibration_beta.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    files.append(path)
    curves = weight_curves(cal, stated, ts_s)
    shown = [b for b in cal.blocks if b.name in curves]
    if shown:
        fig, axes = plt.subplots(len(shown), 1, figsize=(7, 2.8 * len(shown)), squeeze=False)
        for ax, b in zip(axes[:, 0], shown, strict=True):
            _weight_axes(ax, b, curves[b.name], cal.band_hz)
        axes[-1, 0].set_xlabel("frequency (Hz)")
        fig.tight_layout()
        path = out_dir / "calibration_weights.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)
    path = out_dir / "calibration.md"
    pictures = "".join(f"![{p.stem}]({p.name})\n\n" for p in files)
    path.write_text(
        f"# Calibration of model {cal.model}\n\n```\n{calibration_text(cal, model_file)}\n```\n\n"
        + pictures
    )
    files.append(path)
    return files


def _weight_axes(
    ax: Any, b: BlockCalibration, curve: Mapping[str, np.ndarray], band_hz: tuple[float, float]
) -> None:
    f = curve["freqs_hz"]
    ax.loglog(f, curve["stated"], color="tab:gray", label="stated")
    if np.all(np.isfinite(curve["scaled"])) and b.scaling > 0:
        label = f"stated × {b.scaling:.3g} (the factor alone)"
        ax.loglog(f, curve["scaled"], color="tab:gray", ls=":", label=label)
    ax.loglog(f, curve["calibrated"], color="tab:blue", label="calibrated")
    req = b.required
    ok = np.isfinite(req) & (req > 0) & (b.freqs_hz > 0)
    if np.any(ok):
        ax.loglog(b.freqs_hz[ok], req[ok], ".", ms=3, color="tab:red", label="per-bin requirement")
    if band_hz[1] > 0 and b.kind != "noise":  # a noise weight is judged at every bin
        ax.axvspan(f[0], band_hz[0], color="0.9", lw=0)
        ax.axvspan(band_hz[1], f[-1], color="0.9", lw=0, label="extrapolated (not excited)")
    ax.set_ylabel("|W|")
    ax.set_title(b.name, fontsize=9)
    ax.legend(fontsize=7, loc="best")
