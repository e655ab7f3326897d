"""Reports: Markdown summary, JSON numbers, PNG figures (matplotlib) and one HTML page.

The HTML page (:mod:`twotank_validation.report.html`) of ``validate --report`` and
``diagnose --report`` is built from the same dict as the JSON beside it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib as mpl
import yaml

mpl.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from twotank_validation.core.band import excited_lines
from twotank_validation.core.datum import Datum
from twotank_validation.core.model import LFTModel, PlantResponse, load_model
from twotank_validation.core.validate import ValidationResult, inverse_dft
from twotank_validation.diagnose import Diagnosis, EvidencePoints, FittedEffect, excited_bins
from twotank_validation.diagnose.effects import mode_shift_text
from twotank_validation.diagnose.kinds import EffectKind
from twotank_validation.experiment import ExperimentResult

PAPER_BETA = {"A": 1.32, "B": 0.53}


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return None if np.isnan(x) else ("inf" if x > 0 else "-inf")
    return x


def experiment_numbers(res: ExperimentResult) -> dict[str, Any]:
    """Every number of the report as plain JSON-serialisable data."""
    d = res.datum
    out: dict[str, Any] = {
        "norm_convention": d.convention.value,
        "norm_description": d.convention.description,
        "sample_time_s": d.ts_s,
        "period_samples": d.period_samples,
        "n_samples": d.n_samples,
        "n_periods": d.n_periods,
        "height_range": list(res.height_range),
        "periodicity": {
            "input_periodic": d.periodicity.input_periodic,
            "transient_suspected": d.periodicity.transient_suspected,
            "output_variation": d.periodicity.output_variation,
            "output_drift": d.periodicity.output_drift,
            "messages": list(d.periodicity.messages),
        },
        "rig": {
            "mixing_delay_s": res.config.rig.mixing_delay_s,
            "noise_std": [res.config.rig.noise_std_height, res.config.rig.noise_std_temperature],
        },
        "excitation": {
            "kind": res.config.excitation.kind,
            "rms": list(res.config.excitation.rms),
            "cutoff_hz": res.config.excitation.cutoff_hz,
            "seed": res.config.excitation.seed,
        },
        "models": {},
    }
    for name, oc in res.outcomes.items():
        entry = oc.validation.summary()
        entry["paper_beta"] = PAPER_BETA.get(name)
        entry["rms_error"] = oc.rms_error
        entry["residual_tests"] = oc.residual_tests.to_dict()
        if oc.sdp_check is not None:
            cf, sdp = oc.validation, oc.sdp_check
            scale = np.maximum(cf.w_min, 1e-3 * float(np.max(cf.w_min)))
            entry["sdp_check"] = {
                "beta_lower": sdp.beta,
                "beta_upper": sdp.beta_upper,
                "max_rel_diff_per_bin": float(np.max(np.abs(sdp.w_min - cf.w_min) / scale)),
                "beta_rel_diff": abs(sdp.beta - cf.beta) / cf.beta,
                "compute_time_s": sdp.compute_time_s,
            }
        out["models"][name] = entry
    return _jsonable(out)


def _excited_mask(d: Datum) -> np.ndarray:
    """(n_bins,) bool: the excited lines (the band's ``excited``, ``core.band.excited_lines``)."""
    return excited_lines(d.u_bins, d.n_periods, noise_std=d.u_noise_std)


@dataclass(frozen=True)
class NyquistView:
    """What the Nyquist figure of one window shows (the paper's Fig. 8, for any shape).

    Attributes:
        bin: the excited bin of largest min ||W(n)|| (the worst one).
        output: index of the output with the largest raw error ``|Y - G U|`` there.
        input: index of the input whose nominal part of that output ``|G_ji U_i|`` is the
            largest there.
        freq_hz: the bin's frequency (Hz).
        measured: the response the data ask of ``G[output, input]`` at the bin:
            ``(Y_j - sum_{k != i} G_jk U_k) / U_i`` (output units per input unit).
        nominal: ``G[output, input]`` at the bin.
        radius: the perturbations' reach around the nominal there (:func:`_disc_radii`).
        noise_radius: the noise weights' reach at the bin for a unit budget, in response
            units: ``||P22_j|| / |U_i|``.
    """

    bin: int
    output: int
    input: int
    freq_hz: float
    measured: complex
    nominal: complex
    radius: float
    noise_radius: float


def nyquist_view(model: LFTModel, d: Datum, res: ValidationResult) -> NyquistView:
    """The worst bin of a window and the channel pair and disc the Nyquist figure shows."""
    excited = _excited_mask(d)
    if not np.any(excited):
        raise ValueError("the window excites no bin: nothing to show")
    n = int(np.flatnonzero(excited)[np.argmax(res.w_min[excited])])
    p = model.response(d.theta[n : n + 1], d.ts_s)
    g = p.p23[0]  # (ny, nu)
    u, y = d.u_bins[n], d.y_bins[n]
    j = int(np.argmax(np.abs(y - g @ u)))
    reach = np.abs(g[j] * u)  # each input's part of the output's nominal response
    i = int(np.argmax(reach if np.any(reach > 0) else np.abs(u)))
    others = g[j] @ u - g[j, i] * u[i]
    return NyquistView(
        bin=n,
        output=j,
        input=i,
        freq_hz=float(d.freqs_hz[n]),
        measured=complex((y[j] - others) / u[i]),
        nominal=complex(g[j, i]),
        radius=float(_disc_radii(model, p, j, i)[0]),
        noise_radius=float(np.linalg.norm(p.p22[0, j]) / abs(u[i])),
    )


def _disc_radii(model: LFTModel, p: PlantResponse, output: int, input_: int) -> np.ndarray:
    """(k,) float: how far the perturbations move ``G[output, input]`` at each bin.

    The sum over blocks of ``||P21[output, v_b]|| ||P13[z_b, input]||``: each block with
    ``||Delta_b|| <= 1`` moves the response within a disc of that radius (exact for a block
    alone, with no feedback through ``P11``); the blocks together reach the sum.
    """
    radii = np.zeros(p.p.shape[0])
    for vs, zs in zip(model.blocks.v_slices, model.blocks.z_slices, strict=True):
        radii += np.linalg.norm(p.p21[:, output, vs], axis=1) * np.linalg.norm(
            p.p13[:, zs, input_], axis=1
        )
    return radii


def plot_nyquist(
    model: LFTModel, d: Datum, res: ValidationResult, path: Path, n_discs: int = 12
) -> NyquistView:
    """The worst bin of a window on the Nyquist plane (the paper's Fig. 8, any shape).

    The nominal response of the channel pair of :func:`nyquist_view` over the excited band,
    the perturbation discs at up to ``n_discs`` excited harmonics and at the worst bin, and
    the measured point there with the noise weights' reach: the point lies outside the
    worst bin's disc by what ``w`` must make up.
    """
    view = nyquist_view(model, d, res)
    excited = np.flatnonzero(_excited_mask(d))
    theta = np.linspace(d.theta[excited[0]], d.theta[excited[-1]], 600)
    g = model.response(theta, d.ts_s).p23[:, view.output, view.input]
    shown = excited[np.linspace(0, len(excited) - 1, min(n_discs, len(excited))).astype(int)]
    p = model.response(d.theta[shown], d.ts_s)
    ins, outs = model.input_names[view.input], model.output_names[view.output]
    fig, ax = plt.subplots(figsize=(6.4, 6))
    ax.plot(g.real, g.imag, "k-", lw=1, label=f"nominal {outs}/{ins} over the excited band")
    radii = _disc_radii(model, p, view.output, view.input)
    for k in range(len(shown)):
        c = p.p23[k, view.output, view.input]
        ax.add_patch(plt.Circle((c.real, c.imag), radii[k], fill=False, color="tab:blue", lw=0.6))
    c = view.nominal
    ax.add_patch(plt.Circle((c.real, c.imag), view.radius, fill=False, color="tab:blue", lw=1.6))
    ax.plot([], [], color="tab:blue", lw=0.8, label="perturbation discs (‖Δ‖ ≤ 1)")
    m = view.measured
    ax.add_patch(
        plt.Circle((m.real, m.imag), view.noise_radius, fill=False, color="tab:red", ls="--")
    )
    ax.plot(
        [m.real], [m.imag], "x", color="tab:red", ms=9, mew=2,
        label=f"measured at {view.freq_hz:.4g} Hz (noise weight's reach dashed)",
    )  # fmt: skip
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.axhline(0, color="0.8", lw=0.5)
    ax.axvline(0, color="0.8", lw=0.5)
    ax.set_xlabel(f"Re ({outs} units per {ins} unit)")
    ax.set_ylabel(f"Im ({outs} units per {ins} unit)")
    ax.set_title(
        f"Model {model.name}, worst bin {view.freq_hz:.4g} Hz: min‖W(n)‖ "
        f"{res.w_min[view.bin]:.3g}, β {res.beta:.3g}",
        fontsize=9,
    )
    ax.legend(loc="best", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return view


def plot_per_bin(
    results: Mapping[str, ValidationResult],
    path: Path,
    title: str = "",
    excited: np.ndarray | None = None,
    noise_floor: Mapping[str, np.ndarray] | None = None,
) -> None:
    """Per-bin minimum ||W(n)|| against frequency for every model (the paper's figure).

    The budget 1 as a dashed line (one bin at 1 spends the whole unit budget of ||w||; β is
    the root weighted sum of squares over the bins, not the peak) and the excited band
    shaded.

    Args:
        results: the models' results on one datum.
        path: the PNG.
        title: the title (default: the convention).
        excited: (n_bins,) bool, the excited harmonic bins: drawn as markers
            joined in order; the other bins (where only noise is) as faint dots. None: every
            bin joined.
        noise_floor: per model, (n_bins,) float, the per-bin noise floor
            (``ValidationResult.noise_floor``): drawn dotted.
    """
    fig, ax = plt.subplots(figsize=(8, 4))
    convention = ""
    for name, v in results.items():
        convention = v.convention.value
        keep = v.freqs_hz > 0
        label = f"Model {name}: β = √(Σ weight·min‖W(n)‖²) = {v.beta:.3g}"
        if excited is None:
            line = ax.semilogx(v.freqs_hz[keep], v.w_min[keep], lw=0.8, label=label)[0]
        else:
            line = ax.semilogx(
                v.freqs_hz[excited], v.w_min[excited], ".-", lw=0.8, ms=3, label=label
            )[0]
            rest = keep & ~excited
            ax.semilogx(v.freqs_hz[rest], v.w_min[rest], ",", color=line.get_color(), alpha=0.3)
        floor = None if noise_floor is None else noise_floor.get(name)
        if floor is not None and np.any(np.isfinite(floor[keep])):
            ax.semilogx(
                v.freqs_hz[keep], floor[keep], ":", lw=1.0, color=line.get_color(),
                label=f"Model {name}: noise floor (noise alone, expected)",
            )  # fmt: skip
    if excited is not None:
        ax.plot([], [], ",", color="0.5", label="bins not excited (faint)")
        f = next(iter(results.values())).freqs_hz[excited] if results else np.zeros(0)
        if f.size:
            ax.axvspan(
                float(f.min()), float(f.max()), color="tab:green", alpha=0.08,
                label=f"excited band {f.min():.3g}–{f.max():.3g} Hz",
            )  # fmt: skip
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="budget ‖w‖ = 1 (one bin alone spends it)")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("min ‖W(n)‖ (units of ‖w‖; budget 1)")
    ax.set_title(title or f"Per-bin minimum noise norm ({convention} convention)")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_time_signals(
    results: Mapping[str, ValidationResult],
    models: Mapping[str, LFTModel],
    time_s: np.ndarray,
    path: Path,
) -> None:
    """Minimum-norm weighted noise W_n w(k) and perturbation output v(k) (paper Figs. 8-9)."""
    names = list(results)
    fig, axes = plt.subplots(2, len(names), figsize=(5 * len(names), 6), squeeze=False, sharex=True)
    t = time_s - time_s[0]
    for col, name in enumerate(names):
        v = results[name]
        model = models[name]
        w = v.time_domain_noise()
        vv = v.time_domain_perturbation()
        weights = [
            float(ch.weight.d[0, 0]) if ch.weight.n_states == 0 else 1.0 for ch in model.noise
        ]
        for k, ch in enumerate(model.noise):
            axes[0, col].plot(t, weights[k] * w[:, k], lw=0.7, label=f"W_n w ({ch.name})")
        for k, bname in enumerate(model.block_names):
            axes[1, col].plot(t, vv[:, k], lw=0.7, label=f"v ({bname})")
        axes[0, col].set_title(f"Model {name}: minimum-norm signals (β = {v.beta:.2f})")
        axes[0, col].set_ylabel("weighted noise (model units)")
        axes[1, col].set_ylabel("perturbation output v (model units)")
        axes[1, col].set_xlabel("time (s)")
        for ax in axes[:, col]:
            ax.legend(fontsize=7)
            ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_data(res: ExperimentResult, path: Path) -> None:
    """The recorded datum: valve commands and measured outputs."""
    t = res.time_s - res.time_s[0]
    fig, axes = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    axes[0].plot(t, res.u[:, 0], lw=0.7, label="hot command")
    axes[0].plot(t, res.u[:, 1], lw=0.7, label="cold command")
    axes[1].plot(t, res.y[:, 0], lw=0.7, label="level h1")
    axes[1].plot(t, res.y[:, 1], lw=0.7, label="temperature t1")
    axes[1].set_xlabel("time (s)")
    for ax in axes:
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_title("Recorded periods (model units)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _markdown(numbers: dict[str, Any]) -> str:
    lines = [
        "# twotank_validation demo: the paper's experiment in simulation",
        "",
        f"Norm convention: **{numbers['norm_convention']}** ({numbers['norm_description']}).",
        f"Datum: {numbers['n_periods']} periods of {numbers['period_samples']} samples at "
        f"{numbers['sample_time_s']} s (N = {numbers['n_samples']}); level stayed in "
        f"[{numbers['height_range'][0]:.3f}, {numbers['height_range'][1]:.3f}].",
        "",
        "| model | β (this run) | β (paper) | verdict | solver | RMS error level | RMS error temp. "
        "| whiteness (p, level / temp.) | cross-corr. passed |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, m in numbers["models"].items():
        rt = m["residual_tests"]
        white = rt["whiteness"]
        p_vals = " / ".join(f"{white[k]['p_value']:.2g}" for k in white)
        cross_ok = all(
            v["passed"] for per_out in rt["cross_correlation"].values() for v in per_out.values()
        )
        verdict = "invalidated" if m["invalidated"] else "not invalidated"
        lines.append(
            f"| {name} | {m['beta']:.3f} | {m['paper_beta']} | {verdict} | {m['method']} | "
            f"{m['rms_error'][0]:.4f} | {m['rms_error'][1]:.4f} | {p_vals} | {cross_ok} |"
        )
    lines += ["", "## General SDP solver against the closed form", ""]
    for name, m in numbers["models"].items():
        if "sdp_check" in m:
            s = m["sdp_check"]
            lines.append(
                f"- Model {name}: SDP β in [{s['beta_lower']:.9f}, {s['beta_upper']:.9f}], "
                f"closed form {m['beta']:.9f}; max per-bin relative difference "
                f"{s['max_rel_diff_per_bin']:.2e}; "
                f"{s['compute_time_s']:.1f} s."
            )
    lines += [
        "",
        "## Figures",
        "",
        "- `data.png`: the recorded datum.",
        "- `nyquist_A.png`, `nyquist_B.png`: the worst bin on the Nyquist plane: the nominal "
        "response of the output with the largest error to the input with the largest excitation "
        "there, its perturbation discs, and the measured point (paper Fig. 8).",
        "- `per_bin.png`: per-bin minimum ||W(n)|| for both models at the excited bins "
        "(the others faint); β is their root weighted sum of squares, not the peak.",
        "- `time_signals.png`: minimum-norm W_n w(k) and v(k) (paper Figs. 8 and 9).",
        "",
        "Numbers: `results.json`.",
    ]
    return "\n".join(lines) + "\n"


def write_report(
    res: ExperimentResult, out_dir: Path, diagnosis: Diagnosis | None = None
) -> dict[str, Any]:
    """Write summary.md, results.json and the PNG figures into ``out_dir``.

    With a diagnosis, also its evidence figures, the changed model file and a section of
    summary.md (error before and after on held-out windows).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    numbers = experiment_numbers(res)
    if diagnosis is not None:
        model_file = None
        if diagnosis.document is not None:
            path = out_dir / f"model_{diagnosis.model}_diagnosed.yaml"
            path.write_text(yaml.safe_dump(diagnosis.document, sort_keys=False, width=100))
            model_file = path.name
        numbers["diagnosis"] = diagnosis.to_json(model_file)
        write_diagnosis_report(diagnosis, out_dir, model_file)
    (out_dir / "results.json").write_text(json.dumps(numbers, indent=2))
    plot_data(res, out_dir / "data.png")
    models = {name: load_model(name) for name in res.outcomes}
    results = {name: oc.validation for name, oc in res.outcomes.items()}
    for name, model in models.items():
        plot_nyquist(model, res.datum, results[name], out_dir / f"nyquist_{name}.png")
    plot_per_bin(results, out_dir / "per_bin.png", excited=_excited_mask(res.datum))
    plot_time_signals(results, models, res.time_s, out_dir / "time_signals.png")
    text = _markdown(numbers)
    if diagnosis is not None:
        text += _diagnosis_markdown(diagnosis, numbers["diagnosis"]["model_file"])
    (out_dir / "summary.md").write_text(text)
    return numbers


def _diagnosis_markdown(diag: Diagnosis, model_file: str | None) -> str:
    lines = [
        "",
        f"## Diagnosis of Model {diag.model}: the effect it lacks",
        "",
        f"Fit on the windows starting at {', '.join(f'{t:.0f}' for t in diag.fit_windows)} s, "
        "judged on the held-out windows at "
        f"{', '.join(f'{t:.0f}' for t in diag.heldout_windows)} s "
        "(`twotank-validation diagnose`, docs/diagnosis.md).",
        "",
        "```",
        diagnosis_text(diag, model_file),
        "```",
        "",
        "Figures: `diagnosis_spectra.png` (residual spectra before/after), "
        "`diagnosis_outputs.png` (measured output against both models), "
        "`diagnosis_effect.png` (the fitted effect against the measured/modelled ratio at "
        "every bin the fit used, with the noise band and the R² the text quotes).",
    ]
    return "\n".join(lines) + "\n"


def plot_alarm_timeline(summary: Mapping[str, Any], path: Path) -> None:
    """Beta per window against time for each model, coloured by the debounced alarm level."""
    colours = {"OK": "tab:green", "WARN": "tab:orange", "ERROR": "tab:red", "STALE": "0.6"}
    models = summary["models"]
    fig, axes = plt.subplots(
        len(models) or 1, 1, figsize=(9, 2.6 * max(len(models), 1)), squeeze=False, sharex=True
    )
    for ax, (name, entry) in zip(axes[:, 0], models.items(), strict=False):
        for w in entry["windows"]:
            # what the verdict and the alarm use: the dynamics and the operating point
            beta = w["beta_total"] if w.get("beta_total") is not None else w["beta"]
            y = beta if beta is not None else 0.0
            ax.plot(
                [w["start"], w["end"]],
                [y, y],
                color=colours[w["alarm"]],
                lw=3,
                solid_capstyle="butt",
            )
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.set_ylabel(f"β_total, model {name}")
        ax.grid(alpha=0.3)
    for level, colour in colours.items():
        axes[0, 0].plot([], [], color=colour, lw=3, label=level)
    axes[0, 0].legend(loc="upper left", fontsize=7, ncol=4)
    axes[-1, 0].set_xlabel("bag time (s)")
    axes[0, 0].set_title(
        "Validation windows: β_total = √(β² + β_op²), what the verdict and the alarm use "
        "(bar = window span; grey at 0 = not judged; dashed: 1, the limit)",
        fontsize=8,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_window_records(
    model: LFTModel, time_s: np.ndarray, u: np.ndarray, y: np.ndarray, path: Path, *, title: str
) -> None:
    """The time records of one window: the inputs and the measured outputs (model units).

    Args:
        model: names the channels.
        time_s: (n,) float, s (from the recording's start).
        u: (n, nu) float, the inputs.
        y: (n, ny) float, the outputs.
        path: the PNG.
        title: the figure's title.
    """
    fig, axes = plt.subplots(2, 1, figsize=(8, 4.6), sharex=True)
    for k, name in enumerate(model.input_names):
        axes[0].plot(time_s, u[:, k], lw=0.7, label=f"input {name}")
    for k, name in enumerate(model.output_names):
        axes[1].plot(time_s, y[:, k], lw=0.7, label=f"output {name}")
    axes[0].set_ylabel("input (model units)")
    axes[1].set_ylabel("output (model units)")
    axes[1].set_xlabel("time from the recording's start (s)")
    axes[0].set_title(title, fontsize=9)
    for ax in axes:
        ax.legend(fontsize=7, loc="upper right")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def window_view_numbers(
    model: LFTModel, d: Datum, res: ValidationResult, view: NyquistView
) -> dict[str, Any]:
    """The numbers the figures of one window show (JSON-ready; the HTML page's too).

    The worst bin (:func:`nyquist_view`), its frequency, its min ||W(n)|| and the noise floor
    there (``ValidationResult.noise_floor``), the channel pair of the Nyquist figure, the
    band β counts and the excited band.
    """
    f_exc = d.freqs_hz[_excited_mask(d)]
    return _jsonable(
        {
            "beta": res.beta,
            "noise_beta": _finite(res.noise_beta),
            "worst_bin": view.bin,
            "worst_bin_hz": view.freq_hz,
            "worst_bin_w_min": float(res.w_min[view.bin]),
            "worst_bin_noise_floor": _finite(float(res.noise_floor[view.bin])),
            "nyquist_output": model.output_names[view.output],
            "nyquist_input": model.input_names[view.input],
            "excited_band_hz": [float(f_exc.min()), float(f_exc.max())],
            "excited_lines": int(f_exc.size),
            "band": None if model.band is None else model.band.to_dict(),
            "band_text": "every bin up to Nyquist" if model.band is None else model.band.text,
            "band_bins": int(np.sum(res.band_mask)),
        }
    )


def write_replay_report(
    replay: Any, models: Mapping[str, LFTModel], summary: Mapping[str, Any], out_dir: Path
) -> list[Path]:
    """Figures of a bag replay, ``report.json`` and ``report.html``.

    The alarm timeline, and per model and window of interest (largest beta, first alarm) the
    demo's figures: per-bin min ||W(n)|| with the noise floor, Nyquist discs, the window's
    time records and the minimum-norm time signals. ``report.json`` holds the summary (the
    ``--json`` document) and the numbers of each window of interest
    (:func:`window_view_numbers`); ``report.html`` shows the figures and that very dict.

    Args:
        replay: a :class:`twotank_validation.replay.ReplayResult`.
        models: the models by name.
        summary: :func:`twotank_validation.replay.summary_json` of it.
        out_dir: folder to write into.
    """
    from twotank_validation.core.datum import make_datum  # noqa: PLC0415
    from twotank_validation.core.validate import validate  # noqa: PLC0415
    from twotank_validation.report import html  # noqa: PLC0415

    out_dir.mkdir(parents=True, exist_ok=True)
    written = [out_dir / "alarm_timeline.png"]
    plot_alarm_timeline(summary, written[0])
    views: dict[str, dict[str, Any]] = {}
    for name, snaps in replay.snapshots.items():
        model = models[name]
        for why, snap in snaps.items():
            rep = snap.report
            d = make_datum(
                snap.u,
                snap.y,
                ts_s=float(np.median(np.diff(snap.stamps_ns))) / 1e9,
                period_samples=rep.n_samples // rep.n_periods,
                convention=rep.convention,
                measured=snap.measured,
            )
            res = validate(d, model)
            stem = f"{name}_{why}"
            view = nyquist_view(model, d, res)
            plot_nyquist(model, d, res, out_dir / f"nyquist_{stem}.png")
            plot_per_bin(
                {name: res},
                out_dir / f"per_bin_{stem}.png",
                title=f"Model {name}, {html.WHY_TEXT.get(why, why)}",
                excited=_excited_mask(d),
                noise_floor={name: res.noise_floor},
            )
            t = (snap.stamps_ns - replay.bag_start_ns) / 1e9
            plot_window_records(
                model, t, snap.u, snap.y, out_dir / f"records_{stem}.png",
                title=f"Model {name}, {html.WHY_TEXT.get(why, why)}: the window's time records",
            )  # fmt: skip
            plot_time_signals({name: res}, {name: model}, t, out_dir / f"time_signals_{stem}.png")
            written += [
                out_dir / f"{kind}_{stem}.png"
                for kind in ("per_bin", "nyquist", "records", "time_signals")
            ]
            entry = window_view_numbers(model, d, res, view)
            entry |= {"start": (rep.start_ns - replay.bag_start_ns) / 1e9}
            entry |= {"end": (rep.end_ns - replay.bag_start_ns) / 1e9, "stem": stem}
            views.setdefault(name, {})[why] = entry
    numbers = {"summary": _jsonable(dict(summary)), "windows_of_interest": views}
    (out_dir / "report.json").write_text(json.dumps(numbers, indent=2))
    (out_dir / "report.html").write_text(html.validate_page(numbers, out_dir), encoding="utf-8")
    return [*written, out_dir / "report.json", out_dir / "report.html"]


# --------------------------------------------------------------------------- diagnosis


def diagnosis_text(diag: Diagnosis, model_file: str | None = None) -> str:
    """The diagnosis as plain text (console and ``diagnosis.md``)."""
    lines = [diag.summary, ""]
    b, a = diag.before, diag.after
    lines.append(f"{'held-out data':<28}{'before':>12}{'after':>12}")
    lines.append(f"{'beta (max over windows)':<28}{b.beta:>12.3f}{a.beta:>12.3f}")
    for o in diag.outputs:
        lines.append(f"{'RMS error ' + o:<28}{b.rms[o]:>12.4g}{a.rms[o]:>12.4g}")
    for side, name in ((b, "before"), (a, "after")):
        tests = side.residual_tests
        if isinstance(tests, Mapping):
            white = tests.get("whiteness", {})
            parts = [f"{o} p={white[o]['p_value']:.2g}" for o in diag.outputs if o in white]
            lines.append(f"residual whiteness {name}: " + ", ".join(parts))
    ex = diag.explained
    if ex is not None:
        for o in diag.outputs:
            po = ex.per_output[o]
            frac = po["explained_fraction"]
            share = "nothing material" if frac is None else f"{frac:.0%} explained"
            white = "" if o not in ex.white else ", white" if ex.white[o] else ", not white"
            lines.append(
                f"left on {o}: {po['noise_ratio_after']:.1f} x the noise floor "
                f"(before {po['noise_ratio_before']:.1f}; {share}{white})"
            )
        sat = [f for f in diag.findings if f.kind == "saturation"]
        label = (
            f"unexplained by the linear model (the {sat[0].target} saturation below is outside it)"
            if sat
            else "unexplained"
        )
        for why in ex.reasons:
            lines.append(f"{label}: {why}")
    lines.append("")
    if diag.effects:
        partial = diag.unexplained
        lines.append(
            "Partial fit (not the answer; the changed model is partial):" if partial else "Added:"
        )
        for e in diag.effects:
            entry = e.to_dict(diag.outputs)
            params = ", ".join(f"{k} = {v:.4g}" for k, v in entry["parameters"].items())
            lines.append(f"  + {e.spec.label(diag.outputs)} ({params})")
            if e.spec.kind is EffectKind.MODE:  # the shift in one line, with its intervals
                u = e.uncertainty
                low, high = (u.low, u.high) if u is not None else (None, None)
                lines.append(f"    {mode_shift_text(e.spec, e.values, low, high)}")
            lines.extend(f"    {t}" for t in _uncertainty_lines(e))
            lines.append(f"    why: {e.evidence}")
    elif diag.findings:
        lines.append("Nothing added to the model file.")
    elif diag.unexplained:
        lines.append("Nothing added: no effect of the catalogue explains the error.")
    else:
        lines.append("Nothing added: the model is adequate for this datum.")
    if diag.findings:
        lines.append("Found (outside the model file):")
        for f in diag.findings:
            params = ", ".join(f"{k} = {v:.4g}" for k, v in f.parameters.items())
            lines.append(f"  ! {f.kind} on {f.target} ({params})")
            lines.append(f"    why: {f.evidence}")
            lines.append(f"    what to do: {f.recommendation}")
    if diag.runners_up:
        lines.append("Runners-up (held-out score, penalised):")
        for r in diag.runners_up:
            close = " - close call" if r.close_call else ""
            lines.append(
                f"  ~ {r.label}: removes {max(r.reduction, 0.0):.0%} "
                f"(score {r.heldout_cost:.4g}){close}"
            )
    lines.append("Rejected:")
    for label, _, why in diag.rejected:
        lines.append(f"  - {label}: {why}")
    for label, why in diag.not_applicable:
        lines.append(f"  - {label}: {why}")
    if model_file:
        lines.append(f"Changed model written to {model_file}")
    return "\n".join(lines)


def _uncertainty_lines(e: FittedEffect) -> list[str]:
    """``delay_s 20.3 ± 0.8 (95 %: 18.7 – 21.9)`` per parameter of a fitted effect."""
    u = e.uncertainty
    if u is None:
        return []
    level = f"{100 * u.level:.0f} %"
    out = []
    for i, name in enumerate(e.spec.names):
        v, se = float(e.values[i]), float(u.stderr[i])
        if not np.isfinite(se):
            out.append(f"{name} {v:.4g}: not determined by the data (no finite error)")
            continue
        line = f"{name} {v:.4g} ± {se:.2g} ({level}: {u.low[i]:.4g} – {u.high[i]:.4g})"
        if u.at_bound[i]:
            line += f"; at the {u.at_bound[i]} search bound: one-sided interval"
        out.append(line)
    return out


def diagnosis_effect_data(diag: Diagnosis) -> list[tuple[FittedEffect, EvidencePoints]]:
    """The points each evidence panel draws: every chosen effect with its evidence points.

    These are the very objects the evidence text was written from (``FittedEffect.points``),
    so the figure and the text cannot disagree.
    """
    return [(e, e.points) for e in diag.effects if e.points is not None]


def _periodic_output(d: Datum, err: np.ndarray) -> np.ndarray:
    """(N, ny) model output (periodic steady state) = measured minus the raw error."""
    sim_bins = d.y_bins - err
    return inverse_dft(sim_bins, d.n_samples, d.convention) + d.y_bias[None, :]


def plot_diagnosis_spectra(diag: Diagnosis, path: Path) -> None:
    """Residual spectra of the held-out windows, before and after.

    Raw error |E(n)| per output at the excited bins, and the validation's per-bin minimum
    ||W(n)|| of the first held-out window.
    """
    n_out = len(diag.outputs)
    fig, axes = plt.subplots(1, n_out + 1, figsize=(5 * (n_out + 1), 4))
    axes = np.atleast_1d(axes)
    d0 = diag.heldout[0]
    keep = d0.freqs_hz > 0
    for side, label in ((diag.before, diag.model), (diag.after, "diagnosed")):
        if side is diag.after and not diag.effects:
            continue
        r = side.results[0]
        axes[n_out].semilogx(  # linear: bins the perturbation absorbs are exactly 0
            d0.freqs_hz[keep], r.w_min[keep], lw=0.7, label=f"{label} (β = {r.beta:.2f})"
        )
    axes[n_out].set_title("min ||W(n)|| (first held-out window)")
    axes[n_out].set_xlabel("frequency (Hz)")
    axes[n_out].set_ylabel("min ‖W(n)‖ (units of ‖w‖)")
    axes[n_out].grid(True, which="both", alpha=0.3)
    axes[n_out].legend(fontsize=8)
    for k, o in enumerate(diag.outputs):
        ax = axes[k]
        for side, label, mark in ((diag.before, "before", "o"), (diag.after, "after", "x")):
            for i, (d, r) in enumerate(zip(diag.heldout, side.results, strict=True)):
                idx = excited_bins(d, 1e-4)
                ax.loglog(
                    d.freqs_hz[idx],
                    np.abs(r.error[idx, k]),
                    mark,
                    ms=4,
                    color="C0" if label == "before" else "C1",
                    label=label if i == 0 else None,
                )
        odd = np.arange(1, d0.theta.size - 1, 2)
        ax.loglog(d0.freqs_hz[odd], np.abs(d0.y_bins[odd, k]), ",", color="0.6", label="noise")
        ax.set_title(f"{o}: |Y - G U| at the excited bins")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel(f"|Y - G U| ({o}, model units)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_diagnosis_outputs(diag: Diagnosis, path: Path) -> None:
    """Measured outputs of the first held-out window against both models' simulations."""
    d = diag.heldout[0]
    t = np.arange(d.n_samples) * d.ts_s
    y = inverse_dft(d.y_bins, d.n_samples, d.convention) + d.y_bias[None, :]
    before = _periodic_output(d, diag.before.results[0].error)
    after = _periodic_output(d, diag.after.results[0].error)
    fig, axes = plt.subplots(len(diag.outputs), 1, figsize=(9, 3 * len(diag.outputs)), sharex=True)
    axes = np.atleast_1d(axes)
    for k, o in enumerate(diag.outputs):
        ax = axes[k]
        ax.plot(t, y[:, k], lw=0.6, color="0.4", label="measured")
        ax.plot(t, before[:, k], lw=1.0, label=f"{diag.model} (RMS err {diag.before.rms[o]:.3g})")
        if diag.effects:
            ax.plot(
                t,
                after[:, k],
                lw=1.0,
                ls="--",
                label=f"diagnosed (RMS err {diag.after.rms[o]:.3g})",
            )
        ax.set_ylabel(f"{o} (model units)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time in the first held-out window (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_diagnosis_effect(diag: Diagnosis, path: Path) -> None:
    """Measured/modelled ratio at every bin the fit used, the fitted effect and the noise band.

    One column per chosen effect, against the model with the other chosen effects in (as its
    evidence text): magnitude and phase of ``Y / (G U)`` at all fit windows' excited bins,
    with the measurement-noise band of each point (the non-harmonic-bin noise propagated to
    the ratio; in phase ``arcsin(noise / |ratio|)``), the fitted effect's ratio at the
    bins and on a dense log-frequency grid (one line per input when it depends on the
    input), and the R^2 the text quotes, from these very points.
    """
    panels = diagnosis_effect_data(diag)
    if not panels:
        return
    fig, axes = plt.subplots(2, len(panels), figsize=(5.5 * len(panels), 6.5), squeeze=False)
    for col, (e, p) in enumerate(panels):
        mag, ph = axes[0, col], axes[1, col]
        m_abs = np.abs(p.measured)
        below = np.minimum(p.noise, 0.9 * m_abs)  # a log axis: the bar stops above 0
        mag.errorbar(
            p.f_hz, m_abs, yerr=np.vstack([below, p.noise]), fmt="o", ms=3.5, lw=0.6,
            capsize=0, label=f"measured / model ({p.f_hz.size} fit bins, ±1σ noise)",
        )  # fmt: skip
        # a bin's phase is known modulo 360 deg: draw each bin (measured and fitted alike, so
        # their difference and the R^2 are untouched) on the branch of the dense curve
        wrap = np.zeros_like(p.phase_fitted_deg)
        if p.dense_fitted.shape[1]:
            dense_deg = np.degrees(np.unwrap(np.angle(p.dense_fitted[:, 0])))
            at = np.interp(p.f_hz, p.dense_f_hz, dense_deg)
            wrap = 360.0 * np.round((at - p.phase_fitted_deg) / 360.0)
        ph.errorbar(
            p.f_hz, p.phase_measured_deg + wrap, yerr=p.phase_band_deg, fmt="o", ms=3.5,
            lw=0.6, capsize=0,
        )  # fmt: skip
        mag.plot(p.f_hz, np.abs(p.fitted), "x", ms=4, color="C1", label="fitted, at the bins")
        ph.plot(p.f_hz, p.phase_fitted_deg + wrap, "x", ms=4, color="C1")
        for j in range(p.dense_fitted.shape[1]):
            curve = p.dense_fitted[:, j]
            lab = "fitted effect"
            if p.dense_inputs:
                k = p.dense_inputs[j]
                lab += f" (input {diag.inputs[k] if k < len(diag.inputs) else k} alone)"
            mag.plot(p.dense_f_hz, np.abs(curve), "-", lw=1.0, color=f"C{1 + j}", label=lab)
            ph_c = np.degrees(np.unwrap(np.angle(curve)))
            ph.plot(p.dense_f_hz, ph_c, "-", lw=1.0, color=f"C{1 + j}")
        mag.set_xscale("log")
        mag.set_yscale("log")
        ph.set_xscale("log")
        what = "phase line" if p.r2_kind == "phase line" else "fitted effect vs measured"
        mag.set_title(
            f"{diag.outputs[e.spec.channel]}: {e.spec.label(diag.outputs)}\n"
            f"R² {p.r2:.2f} ({what}, these {p.f_hz.size} points)",
            fontsize=9,
        )
        mag.set_ylabel("magnitude ratio")
        ph.set_ylabel("phase (deg)")
        ph.set_xlabel("frequency (Hz, log)")
        mag.legend(fontsize=7)
        for ax in (mag, ph):
            ax.grid(True, which="both", alpha=0.3)
            # plain numbers at 1-2-5 steps: matplotlib's default minor labels overlap here
            ax.xaxis.set_major_locator(mpl.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
            ax.xaxis.set_major_formatter(mpl.ticker.FormatStrFormatter("%g"))
            ax.xaxis.set_minor_formatter(mpl.ticker.NullFormatter())
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_diagnosis_report(
    diag: Diagnosis,
    out_dir: Path,
    model_file: str | None = None,
    numbers: Mapping[str, Any] | None = None,
) -> None:
    """``diagnosis.md``, the evidence figures (spectra, outputs, fitted effect), ``report.html``.

    Args:
        diag: the diagnosis.
        out_dir: folder to write into.
        model_file: the changed model's file, as the text names it.
        numbers: the diagnosis JSON the page shows (``diagnose --json``'s document); None:
            ``diag.to_json(model_file)``.
    """
    from twotank_validation.report import html  # noqa: PLC0415

    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "diagnosis.md").write_text(
        "# Diagnosis\n\n```\n" + diagnosis_text(diag, model_file) + "\n```\n"
    )
    plot_diagnosis_spectra(diag, out_dir / "diagnosis_spectra.png")
    plot_diagnosis_outputs(diag, out_dir / "diagnosis_outputs.png")
    plot_diagnosis_effect(diag, out_dir / "diagnosis_effect.png")
    doc = _jsonable(dict(numbers) if numbers is not None else diag.to_json(model_file))
    (out_dir / "report.html").write_text(html.diagnose_page(doc, out_dir), encoding="utf-8")
