"""Report of the experiment: Markdown summary, JSON numbers and PNG figures (matplotlib)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib as mpl
import yaml

mpl.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from twotank_validation.core import lti
from twotank_validation.core.datum import Datum
from twotank_validation.core.model import LFTModel, load_model
from twotank_validation.core.validate import ValidationResult, inverse_dft
from twotank_validation.diagnose import Diagnosis, excited_bins
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


def plot_nyquist(model: LFTModel, d: Datum, path: Path, n_discs: int = 12) -> None:
    """Nominal hot-flow-to-temperature response with its perturbation discs (paper Fig. 6)."""
    theta = np.linspace(1e-4, np.pi / 20, 600)
    g = lti.frequency_response(model.nominal_discrete(d.ts_s), theta)[:, 1, 0]
    pert = next(p for p in model.perturbations if 1 in p.outputs)
    harm = np.flatnonzero(d.harmonic_bins)[1 : n_discs + 1]
    th_d = d.theta[harm]
    g_d = lti.frequency_response(model.nominal_discrete(d.ts_s), th_d)[:, 1, 0]
    w_d = lti.frequency_response(lti.discretise(pert.weight, d.ts_s), th_d)[:, 0, 0]
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(g.real, g.imag, "k-", lw=1, label="nominal t1/f_hc")
    for gi, wi in zip(g_d, w_d, strict=True):
        ax.add_patch(
            plt.Circle((gi.real, gi.imag), abs(wi * gi), fill=False, color="tab:blue", lw=0.8)
        )
    ax.plot(
        g_d.real, g_d.imag, "o", ms=3, color="tab:blue", label="perturbation discs at harmonics"
    )
    ax.set_aspect("equal")
    ax.axhline(0, color="0.8", lw=0.5)
    ax.axvline(0, color="0.8", lw=0.5)
    ax.set_xlabel("Re")
    ax.set_ylabel("Im")
    ax.set_title(f"Model {model.name}: temperature response with |W_Δt G| discs")
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_per_bin(results: Mapping[str, ValidationResult], path: Path, title: str = "") -> None:
    """Per-bin minimum ||W(n)|| against frequency for every model."""
    fig, ax = plt.subplots(figsize=(8, 4))
    convention = ""
    for name, v in results.items():
        convention = v.convention.value
        keep = v.freqs_hz > 0
        ax.semilogx(
            v.freqs_hz[keep], v.w_min[keep], lw=0.8, label=f"Model {name} (β = {v.beta:.2f})"
        )
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("min ||W(n)||")
    ax.set_title(title or f"Per-bin minimum noise norm ({convention} convention)")
    ax.legend()
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
        axes[1, col].set_ylabel("perturbation output v")
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
        "- `nyquist_A.png`, `nyquist_B.png`: nominal temperature response with perturbation discs "
        "(paper Fig. 6).",
        "- `per_bin.png`: per-bin minimum ||W(n)|| for both models.",
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
        plot_nyquist(model, res.datum, out_dir / f"nyquist_{name}.png")
    plot_per_bin(results, out_dir / "per_bin.png")
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
        "`diagnosis_effect.png` (the fitted effect against the measured/modelled ratio).",
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
            beta = w["beta"]
            y = beta if beta is not None else 0.0
            ax.plot(
                [w["start"], w["end"]],
                [y, y],
                color=colours[w["alarm"]],
                lw=3,
                solid_capstyle="butt",
            )
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.set_ylabel(f"β, model {name}")
        ax.grid(alpha=0.3)
    for level, colour in colours.items():
        axes[0, 0].plot([], [], color=colour, lw=3, label=level)
    axes[0, 0].legend(loc="upper left", fontsize=7, ncol=4)
    axes[-1, 0].set_xlabel("bag time (s)")
    axes[0, 0].set_title("Validation windows (bar = window span; grey at 0 = not judged)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_replay_report(
    replay: Any, models: Mapping[str, LFTModel], summary: Mapping[str, Any], out_dir: Path
) -> list[Path]:
    """Figures of a bag replay.

    The alarm timeline, and per model and window of interest (largest beta, first alarm) the
    demo's figures: Nyquist discs, per-bin min ||W(n)||, minimum-norm time signals.

    Args:
        replay: a :class:`twotank_validation.replay.ReplayResult`.
        models: the models by name.
        summary: :func:`twotank_validation.replay.summary_json` of it.
        out_dir: folder to write into.
    """
    from twotank_validation.core.datum import make_datum  # noqa: PLC0415
    from twotank_validation.core.validate import validate  # noqa: PLC0415

    out_dir.mkdir(parents=True, exist_ok=True)
    written = [out_dir / "alarm_timeline.png"]
    plot_alarm_timeline(summary, written[0])
    for name, snaps in replay.snapshots.items():
        model = models[name]
        for why, snap in snaps.items():
            rep = snap.report
            d = make_datum(
                snap.u,
                snap.y,
                ts_s=float(np.median(np.diff(snap.stamps_ns))) / 1e9,
                period_samples=rep.n_samples // rep.n_periods,
            )
            res = validate(d, model)
            stem = f"{name}_{why}"
            plot_nyquist(model, d, out_dir / f"nyquist_{stem}.png")
            plot_per_bin({name: res}, out_dir / f"per_bin_{stem}.png", title=f"model {name}, {why}")
            t = (snap.stamps_ns - replay.bag_start_ns) / 1e9
            plot_time_signals({name: res}, {name: model}, t, out_dir / f"time_signals_{stem}.png")
            written += [
                out_dir / f"{kind}_{stem}.png" for kind in ("nyquist", "per_bin", "time_signals")
            ]
    return written


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
    lines.append("")
    if diag.effects:
        lines.append("Added:")
        for e in diag.effects:
            entry = e.to_dict(diag.outputs)
            params = ", ".join(f"{k} = {v:.4g}" for k, v in entry["parameters"].items())
            lines.append(f"  + {e.spec.label(diag.outputs)} ({params})")
            lines.append(f"    why: {e.evidence}")
    else:
        lines.append("Nothing added: the model is adequate for this datum.")
    lines.append("Rejected:")
    for label, _, why in diag.rejected:
        lines.append(f"  - {label}: {why}")
    for label, why in diag.not_applicable:
        lines.append(f"  - {label}: {why}")
    if model_file:
        lines.append(f"Changed model written to {model_file}")
    return "\n".join(lines)


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
    """Measured/modelled ratio at the fit bins and the fitted effect's ratio, per channel.

    Only bins where the modelled output exceeds five times the noise amplitude are shown.
    """
    data, before, after = diag.fit_bins, diag.nominal_before, diag.nominal_after
    if data is None or before is None or after is None or not diag.effects:
        return
    ts = diag.heldout[0].ts_s
    channels = sorted({e.spec.channel for e in diag.effects})
    fig, axes = plt.subplots(2, len(channels), figsize=(5 * len(channels), 6), squeeze=False)
    order = np.argsort(data.theta)
    f = data.theta[order] / ts / (2 * np.pi)
    g0 = before.response(data.theta, ts)
    g1 = after.response(data.theta, ts)
    yb = np.einsum("kij,kj->ki", g0, data.u)[order]
    ya = np.einsum("kij,kj->ki", g1, data.u)[order]
    ym = data.y[order]
    noise_amp = np.sqrt(data.noise[order]) * data.scale[order]
    for col, ch in enumerate(channels):
        # bins where the modelled output stands clear of the noise (ratios elsewhere are noise)
        ok = np.abs(yb[:, ch]) > 5.0 * noise_amp[:, ch]
        meas = ym[ok, ch] / yb[ok, ch]
        fit = ya[ok, ch] / yb[ok, ch]
        axes[0, col].semilogx(f[ok], np.abs(meas), "o", ms=4, label="measured / model")
        axes[0, col].semilogx(f[ok], np.abs(fit), "-", label="fitted effect")
        axes[1, col].semilogx(f[ok], np.degrees(np.unwrap(np.angle(meas))), "o", ms=4)
        axes[1, col].semilogx(f[ok], np.degrees(np.unwrap(np.angle(fit))), "-")
        labels = ", ".join(e.spec.label(diag.outputs) for e in diag.effects if e.spec.channel == ch)
        axes[0, col].set_title(f"{diag.outputs[ch]}: {labels}")
        axes[0, col].set_ylabel("magnitude ratio")
        axes[1, col].set_ylabel("phase (deg)")
        axes[1, col].set_xlabel("frequency (Hz)")
        axes[0, col].legend(fontsize=8)
        for ax in axes[:, col]:
            ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_diagnosis_report(diag: Diagnosis, out_dir: Path, model_file: str | None = None) -> None:
    """``diagnosis.md`` and the evidence figures (spectra, outputs, fitted effect)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "diagnosis.md").write_text(
        "# Diagnosis\n\n```\n" + diagnosis_text(diag, model_file) + "\n```\n"
    )
    plot_diagnosis_spectra(diag, out_dir / "diagnosis_spectra.png")
    plot_diagnosis_outputs(diag, out_dir / "diagnosis_outputs.png")
    plot_diagnosis_effect(diag, out_dir / "diagnosis_effect.png")
