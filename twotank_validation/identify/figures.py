"""The identification's figures, fit to print: the response and its fit, the weights, the orders.

Each figure is written as a vector PDF and a PNG (matplotlib's Agg; 8 pt type, 7 in wide, the
width of a two-column page), from the numbers :func:`~.requirement.report_numbers` computes
(the same the JSON holds):

* ``identify_bode``: per entry (output, input), the magnitude (dB) of the measured response
  with its 95 % band, the standard deviations of the noise and of the nonlinear distortion
  apart (dB, same units), the nominal over a decade either side of the excited band, and the
  phase (degrees) with each line's 95 % phase interval; the excited band shaded.
* ``identify_weights``: per output, the perturbation weight each line requires (its 95 %
  interval) against the written weight's magnitude, the lines it does not cover marked;
  beside it, the noise weight each line requires against the written flat weight.
* ``identify_orders``: the fit's residual per order against what the response's σ explains.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import matplotlib as mpl

mpl.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from twotank_validation.identify.pipeline import Identification, IdentifiedModel
from twotank_validation.identify.requirement import LEVEL, ReportNumbers, weight_magnitude

__all__ = ["FIGURES", "write_identify_report"]

FIGURES = ("identify_bode", "identify_weights", "identify_orders")
"""The figures' file stems; each is written as ``.pdf`` and ``.png``."""

WIDTH_IN = 7.0
"""A two-column page's text width (in)."""
PRINT_STYLE: dict[str, Any] = {
    "font.size": 8,
    "axes.titlesize": 8,
    "axes.labelsize": 8,
    "legend.fontsize": 6.5,
    "xtick.labelsize": 7,
    "ytick.labelsize": 7,
    "lines.linewidth": 1.0,
    "lines.markersize": 3,
    "pdf.fonttype": 42,
    "savefig.dpi": 150,
}
_BAND = {"color": "0.92", "zorder": -2, "lw": 0}


@contextmanager
def _style() -> Iterator[None]:
    with mpl.rc_context(PRINT_STYLE):
        yield


def _db(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.asarray(20.0 * np.log10(np.abs(x)))


def _grid(freqs_hz: np.ndarray, ts_s: float) -> np.ndarray:
    """Frequencies (Hz) a decade either side of the lines (to Nyquist at most), and the lines."""
    lo = float(freqs_hz.min()) / 10.0
    hi = min(float(freqs_hz.max()) * 10.0, 0.5 / ts_s)
    dense = np.logspace(np.log10(lo), np.log10(hi), 400)
    return np.unique(np.concatenate([dense, freqs_hz]))


def _save(fig: Any, folder: Path, stem: str) -> list[str]:
    paths = []
    for ext in ("pdf", "png"):
        path = folder / f"{stem}.{ext}"
        fig.savefig(path)
        paths.append(str(path))
    plt.close(fig)
    return paths


def _bode(
    ident: Identification,
    nums: ReportNumbers,
    inputs: Sequence[str],
    outputs: Sequence[str],
    folder: Path,
) -> list[str]:
    f = nums.freqs_hz
    grid = _grid(f, ident.ts_s)
    at_lines = np.searchsorted(grid, f)
    nominal = ident.nominal.response(grid)
    n_y, n_u = nums.measured.shape[1:]
    fig, axes = plt.subplots(
        2 * n_y,
        n_u,
        figsize=(WIDTH_IN, 0.6 + 2.9 * n_y),
        squeeze=False,
        sharex=True,
        gridspec_kw={"height_ratios": [1.4, 1.0] * n_y},
    )
    has_distortion = bool(np.any(nums.std_distortion > 0.0))
    for c in range(n_y):
        for i in range(n_u):
            mag_ax, ph_ax = axes[2 * c, i], axes[2 * c + 1, i]
            g = nums.measured[:, c, i]
            mag, rad = np.abs(g), nums.radius[:, c, i]
            levels = _db(
                np.concatenate([mag, nums.std_noise[:, c, i], nums.std_distortion[:, c, i]])
            )
            floor = float(np.min(levels[np.isfinite(levels)])) - 10.0
            mag_ax.fill_between(
                f,
                np.maximum(_db(np.maximum(mag - rad, 0.0)), floor),
                _db(mag + rad),
                color="C0",
                alpha=0.25,
                lw=0,
                label=f"measured ± {LEVEL:.0%} disc",
            )
            mag_ax.semilogx(f, _db(mag), "o", color="C0", mfc="none", label="measured")
            mag_ax.semilogx(f, _db(nums.std_noise[:, c, i]), "--", color="0.4", label="σ noise")
            if has_distortion:
                mag_ax.semilogx(
                    f, _db(nums.std_distortion[:, c, i]), ":", color="C2", lw=1.4,
                    label="σ nonlinear distortion",
                )  # fmt: skip
            mag_ax.semilogx(
                grid,
                _db(nominal[:, c, i]),
                "-",
                color="C3",
                label=_nominal_label(ident),
            )
            mag_ax.set_ylim(bottom=max(mag_ax.get_ylim()[0], floor))
            mag_ax.set_ylabel(f"|{outputs[c]}/{inputs[i]}| (dB)")
            mag_ax.set_title(f"{outputs[c]} / {inputs[i]}", loc="left")
            phase = np.degrees(np.unwrap(np.angle(nominal[:, c, i])))
            ph_nom = phase[at_lines]
            ph_meas = ph_nom + np.degrees(np.angle(g / nominal[at_lines, c, i]))
            ratio = np.divide(rad, mag, where=mag > 0, out=np.ones_like(mag))
            half = np.degrees(np.arcsin(np.minimum(ratio, 1.0)))
            ph_ax.errorbar(
                f, ph_meas, yerr=half, fmt="o", color="C0", mfc="none", elinewidth=0.6,
                capsize=0, label=f"measured ± {LEVEL:.0%}",
            )  # fmt: skip
            ph_ax.semilogx(grid, phase, "-", color="C3", label="nominal")
            ph_ax.set_ylabel("phase (deg)")
            for ax in (mag_ax, ph_ax):
                ax.axvspan(float(f.min()), float(f.max()), **_BAND)
                ax.grid(True, which="major", alpha=0.3, lw=0.4)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    height = fig.get_figheight()  # the title's two lines, then the legend, above the axes
    fig.legend(handles, labels, loc="upper center", ncol=5, bbox_to_anchor=(0.5, 1 - 0.4 / height))
    for i in range(n_u):
        axes[-1, i].set_xlabel("frequency (Hz)")
        axes[-1, i].set_xlim(float(grid.min()), float(grid.max()))
    estimate = ident.estimator.value
    units = "dB re 1 output unit per input unit (the model's units)"
    fig.suptitle(
        f"Measured response ({estimate}, {f.size} lines) and the fitted nominal\n"
        f"grey: the excited band {f.min():.3g}–{f.max():.3g} Hz; magnitudes in {units}",
        fontsize=8,
    )
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.65 / height))
    return _save(fig, folder, FIGURES[0])


def _weights(
    ident: Identification,
    made: IdentifiedModel,
    nums: ReportNumbers,
    outputs: Sequence[str],
    folder: Path,
) -> list[str]:
    f = nums.freqs_hz
    grid = _grid(f, ident.ts_s)
    by_name = {name: (num, den) for name, num, den in made.weights()}
    n_y = len(outputs)
    fig, axes = plt.subplots(
        n_y, 2, figsize=(WIDTH_IN, 1.0 + 2.0 * n_y), squeeze=False, sharex=True
    )
    req = nums.perturbation
    checked = nums.validation_covered
    for c, out in enumerate(outputs):
        ax = axes[c, 0]
        central = _db(req.required[:, c])
        top = _db(req.hi[:, c])
        finite = central[np.isfinite(central)]
        floor = (float(finite.min()) if finite.size else -60.0) - 20.0
        ax.fill_between(
            f,
            np.maximum(_db(req.lo[:, c]), floor),
            np.maximum(top, floor),
            color="C0",
            alpha=0.2,
            lw=0,
            label=f"required, {LEVEL:.0%} interval",
        )
        ax.semilogx(
            f,
            np.maximum(central, floor),
            "o",
            color="C0",
            mfc="none",
            label="required: max_i |Ĥ − G|/|G|",
        )
        if (tf := by_name.get(f"{out}_multiplicative")) is not None:
            written = _db(weight_magnitude(*tf, grid))
            ax.semilogx(grid, written, "-", color="C3", label="|W| written")
        short = ~nums.covered[:, c]
        title = f"{out}: perturbation weight; below the requirement at {int(short.sum())}"
        if np.any(short):
            ax.semilogx(
                f[short], np.maximum(central[short], floor), "x", color="C3", ms=5,
                label="not covered",
            )  # fmt: skip
        if nums.validation_required is not None and checked is not None:
            need = nums.validation_required[:, c]
            shown = np.isfinite(need) & (need > 0.0)
            ax.semilogx(
                f[shown],
                _db(need[shown]),
                "^",
                color="C1",
                mfc="none",
                label="calibrate's per-bin requirement",
            )
            low = shown & ~checked[:, c]
            if np.any(low):
                ax.semilogx(f[low], _db(need[low]), "^", color="C3", label="… not met")
            title += (
                f", calibrate's at {int(np.sum(~checked[:, c]))} of {f.size} lines"
                f"\n(0 at {int(np.sum(need == 0.0))}: the noise explains them; "
                f"no weight at {int(np.sum(np.isinf(need)))}; not judged at "
                f"{int(np.sum(np.isnan(need)))})"
            )
        else:
            title += f" of {f.size} lines"
        ax.set_xscale("log")
        ax.set_ylim(bottom=floor)
        ax.set_ylabel("|W| (dB)")
        ax.set_title(title, loc="left", fontsize=7)
        nx = axes[c, 1]
        gain = float(nums.noise_gains[c])
        if nums.noise_required is not None:
            nx.loglog(f, nums.noise_required[:, c], "s", color="C0", mfc="none",
                      label="noise weight required")  # fmt: skip
        nx.axhline(gain, color="C3", ls="--", label="noise weight written")
        nx.set_yscale("log")
        nx.set_ylabel(f"{out} per unit w")
        nx.set_title(f"{out}: noise weight {gain:.3g}", loc="left", fontsize=7)
        for a in (ax, nx):
            a.axvspan(float(f.min()), float(f.max()), **_BAND)
            a.grid(True, which="major", alpha=0.3, lw=0.4)
    for a in axes[-1]:
        a.set_xlabel("frequency (Hz)")
        a.set_xlim(float(grid.min()), float(grid.max()))
    if made.calibrated:
        how = f"shapes scaled by calibrate (factors {', '.join(f'{x:.3g}' for x in made.factors)})"
    elif made.held_out.any():
        how = "shapes × the margin (the noise weights explained the fit windows)"
    else:
        how = "the error + 2σ × the margin (nothing could be held out)"
    fig.suptitle(
        f"The weights against what each excited line requires; written: {how}\n"
        "grey: the excited band",
        fontsize=8,
    )
    seen: dict[str, Any] = {}
    for a in axes.ravel():
        for h, lab in zip(*a.get_legend_handles_labels(), strict=True):
            seen.setdefault(lab, h)
    height = fig.get_figheight()
    fig.legend(
        list(seen.values()), list(seen), loc="upper center", ncol=4,
        bbox_to_anchor=(0.5, 1 - 0.4 / height),
    )  # fmt: skip
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.62 / height))
    return _save(fig, folder, FIGURES[1])


def _orders(ident: Identification, folder: Path) -> list[str]:
    fig, ax = plt.subplots(figsize=(WIDTH_IN / 2, 2.4))
    orders = [fit.order for fit in ident.fits]
    ratios = [fit.cost_ratio for fit in ident.fits]
    ax.semilogy(orders, ratios, "o-")
    ax.axhline(1.0, color="0.5", ls="--", label="what the response's σ explains")
    ax.plot([ident.fit.order], [ident.fit.cost_ratio], "s", color="C3", label="chosen (MDL)")
    ax.set_xlabel("order (states per input)")
    ax.set_ylabel("residual 2V/dof (–)")
    ax.set_title("The fit's residual against the response's σ", loc="left")
    ax.legend(framealpha=0.9)
    ax.grid(True, which="major", alpha=0.3, lw=0.4)
    fig.tight_layout()
    return _save(fig, folder, FIGURES[2])


def _nominal_label(ident: Identification) -> str:
    if ident.grey_box is not None:
        return "nominal (grey box, linearised)"
    return f"nominal (order {ident.fit.order})"


def write_identify_report(
    ident: Identification,
    made: IdentifiedModel,
    nums: ReportNumbers,
    folder: str | Path,
    *,
    inputs: Sequence[str],
    outputs: Sequence[str],
) -> list[str]:
    """Write the figures (PDF and PNG each) into ``folder`` (created); return their paths."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    with _style():
        return [
            *_bode(ident, nums, inputs, outputs, out),
            *_weights(ident, made, nums, outputs, out),
            *_orders(ident, out),
        ]
