"""The identification's figures: the measured response ± σ, the fit and the weights.

One Bode figure (``identify_bode.png``): per entry (output, input), the magnitude with its
95 % band (noise, and noise with nonlinear distortion where they differ), the nominal fit
and the band the perturbation weight allows around it, and the phase; the excited band is
shaded. One figure of the fit per order (``identify_orders.png``): the residual against what
the response's σ explains, the chosen order marked.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib as mpl

mpl.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from twotank_validation.core import lti
from twotank_validation.identify.pipeline import Identification, IdentifiedModel

__all__ = ["write_identify_report"]


def _weight_magnitudes(made: IdentifiedModel, outputs: Sequence[str], f: np.ndarray) -> np.ndarray:
    """(L, n_y): each output's perturbation weight |W(j 2 pi f)| (0 where it has none)."""
    out = np.zeros((f.size, len(outputs)))
    by_name = {name: (num, den) for name, num, den in made.weights()}
    for c, o in enumerate(outputs):
        if (tf := by_name.get(f"{o}_multiplicative")) is not None:
            sys = lti.from_transfer_function(*tf)
            out[:, c] = np.abs(lti.continuous_response(sys, 2 * np.pi * f)[:, 0, 0])
    return out


def _nominal_label(ident: Identification) -> str:
    if ident.grey_box is not None:
        return "nominal (grey box, linearised)"
    return f"nominal (order {ident.fit.order})"


def write_identify_report(
    ident: Identification,
    made: IdentifiedModel,
    folder: str | Path,
    inputs: Sequence[str],
    outputs: Sequence[str],
) -> list[str]:
    """Write the figures into ``folder`` (created); return their paths."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    fr = ident.response
    f = fr.freqs_hz
    model = ident.nominal.response(f)
    n_y, n_u = fr.g.shape[1:]
    fig, axes = plt.subplots(
        2 * n_y, n_u, figsize=(5.5 * n_u, 3.2 * 2 * n_y), squeeze=False, sharex=True
    )
    wmags = _weight_magnitudes(made, outputs, f)
    k95 = np.sqrt(-np.log(0.05))  # a circular complex Gaussian's 95 % radius over σ
    for c in range(n_y):
        wmag = wmags[:, c]
        for i in range(n_u):
            mag_ax, ph_ax = axes[2 * c, i], axes[2 * c + 1, i]
            g = fr.g[:, c, i]
            total = k95 * np.sqrt(fr.var[:, c, i])
            noise = k95 * np.sqrt(ident.var_noise[:, c, i])
            mag = np.abs(g)
            mag_ax.fill_between(
                f,
                np.maximum(mag - total, mag * 1e-3),
                mag + total,
                color="C0",
                alpha=0.2,
                label="measured ± 95 % (all)",
            )
            if not np.allclose(total, noise):
                mag_ax.fill_between(
                    f,
                    np.maximum(mag - noise, mag * 1e-3),
                    mag + noise,
                    color="C0",
                    alpha=0.4,
                    label="± 95 % (noise)",
                )
            mag_ax.loglog(f, mag, ".", color="C0", ms=3, label="measured")
            fit = np.abs(model[:, c, i])
            mag_ax.loglog(f, fit, "-", color="C3", lw=1.2, label=_nominal_label(ident))
            mag_ax.fill_between(
                f,
                fit * np.maximum(1 - wmag, 1e-3),
                fit * (1 + wmag),
                color="C3",
                alpha=0.12,
                label="nominal × (1 ± |W|)",
            )
            mag_ax.set_ylabel(f"|{outputs[c]} / {inputs[i]}|")
            ph_ax.semilogx(f, np.degrees(np.unwrap(np.angle(g))), ".", color="C0", ms=3)
            ph_ax.semilogx(
                f, np.degrees(np.unwrap(np.angle(model[:, c, i]))), "-", color="C3", lw=1.2
            )
            ph_ax.set_ylabel("phase (deg)")
            for ax in (mag_ax, ph_ax):
                ax.axvspan(f.min(), f.max(), color="0.9", zorder=-1)
                ax.grid(True, which="both", alpha=0.3)
            if c == 0 and i == 0:
                mag_ax.legend(fontsize=7, loc="best")
    for i in range(n_u):
        axes[-1, i].set_xlabel("frequency (Hz)")
    fig.suptitle(
        f"measured response ({ident.estimator.value}) and the identified nominal\n"
        "grey: the band identified",
        fontsize=10,
    )
    fig.tight_layout()
    bode = out / "identify_bode.png"
    fig.savefig(bode, dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    orders = [fit.order for fit in ident.fits]
    ratios = [fit.cost_ratio for fit in ident.fits]
    ax.semilogy(orders, ratios, "o-")
    ax.axhline(1.0, color="0.5", ls="--", label="the response's σ")
    ax.plot([ident.fit.order], [ident.fit.cost_ratio], "s", color="C3", label="chosen (MDL)")
    ax.set_xlabel("order (states per input)")
    ax.set_ylabel("2 V / dof")
    ax.set_title("the fit's residual against the response's own σ")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    orders_png = out / "identify_orders.png"
    fig.savefig(orders_png, dpi=110)
    plt.close(fig)
    return [str(bode), str(orders_png)]
