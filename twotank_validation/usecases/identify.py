"""``identify`` of one recording: the measured response, a fitted nominal and a model set."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from twotank_validation import replay
from twotank_validation.core.band import parse_band
from twotank_validation.errors import ExitCode, TwotankError, UsageError, interruption
from twotank_validation.identify.figures import write_identify_report
from twotank_validation.identify.greybox import GreyBoxModel, ParameterStatus
from twotank_validation.identify.pipeline import (
    Identification,
    IdentifiedModel,
    IdentifyConfig,
    identified_model,
    identify_windows,
    probe_model,
)
from twotank_validation.identify.requirement import (
    ReportNumbers,
    output_noise_at_lines,
    report_numbers,
    validation_requirement,
)
from twotank_validation.sim.excitation import read_design
from twotank_validation.usecases.outcome import (
    STATUS_OF_CODE,
    Level,
    Outcome,
    Progress,
    Say,
    Show,
    Teller,
    exit_status,
    nothing_judged,
    unreadable,
    write_json,
)
from twotank_validation.usecases.reading import ReadSettings, open_recording, timed_config


def parse_orders(text: str) -> range:
    """``"N"`` or ``"A..B"`` (inclusive) as a range of orders.

    Raises:
        UsageError: not of that form, or an order below 1.
    """
    try:
        if ".." in text:
            lo, hi = (int(x) for x in text.split("..", 1))
        else:
            lo = hi = int(text)
    except ValueError as err:
        raise UsageError(f"--orders {text!r}: give N or A..B (e.g. 2..8)") from err
    if lo < 1 or hi < lo:
        raise UsageError(f"--orders {text!r}: orders are >= 1 and A <= B (e.g. 2..8)")
    return range(lo, hi + 1)


@dataclass(frozen=True)
class IdentifyJob:
    """Identify a model set from one recording (``twotank-validation identify``).

    Attributes:
        recording: the bag or table.
        read: how to read it (the interface map names the channels; no model is needed).
        orders: the orders tried (``"N"`` or ``"A..B"``).
        delays: fit a transport delay per output with the nominal.
        grey_box: a first-principles model (``"two-tank"``) whose physical parameters are
            fitted and linearised as the nominal; None: the black-box fit is the nominal.
        start: use the windows from this time (s from the start, or ISO 8601); None: all.
        end: up to this time; None: to the end.
        name: the identified model's name.
        json_path: write the identification as JSON here (None: not written).
        report_dir: write the figures here (None: none).
        out_model: write the model set (YAML) here (None: not written).
    """

    recording: str
    read: ReadSettings = field(default_factory=ReadSettings)
    orders: str = "1..8"
    delays: bool = False
    grey_box: str | None = None
    start: float | str | None = None
    end: float | str | None = None
    name: str = "identified"
    json_path: str | None = None
    report_dir: str | None = None
    out_model: str | None = None

    def run(
        self,
        *,
        say: Say | None = None,
        progress: Progress | None = None,
        show: Show | None = None,
    ) -> Outcome:
        """Replay the recording, identify, write what was asked.

        Returns:
            The outcome: ``document`` the identification JSON, ``text`` its summary; an
            unusable recording, setting or a record that cannot be identified (no
            excitation in the band, too few periods for the inputs, an order the data
            cannot support) is an ``ERROR`` outcome naming the fix; no judged window is
            ``NOT_JUDGED`` (code 4) with the reasons; SIGINT or SIGTERM before the end is
            ``INTERRUPTED`` with nothing written but the JSON saying so.
        """
        tell = Teller(say)
        try:
            return self._run(tell, progress, show)
        except TwotankError as err:
            return unreadable(err, tell)

    def _run(self, tell: Teller, progress: Progress | None, show: Show | None) -> Outcome:
        orders = parse_orders(self.orders)
        grey = _grey_box(self.grey_box, self.read.interface)
        # the band (--band, the settings tree's) limits the lines the response and the fit use
        band = parse_band(self.read.monitor.band) if self.read.monitor.band else None
        imap = self.read.interface
        probe = probe_model(imap.input_names, imap.output_names)
        try:
            with open_recording(self.read, self.recording) as recording:
                cfg, timing = timed_config(self.read, recording, tell)
                windows, _, replayed = replay.windows_with_findings(
                    recording, probe, cfg, start=self.start, end=self.end, progress=progress
                )
        except KeyboardInterrupt as stop:
            document = {"interrupted": True, "recording": self.recording}
            return nothing_judged(interruption(stop), tell, self.json_path, document)
        for problem in replayed.problems:
            tell(Level.WARNING, problem)
        summary = replay.summary_json(replayed, [probe.name])
        if unjudged := replay.unjudged(replayed, [probe.name], timing, cfg):
            # the probe is no model of the user's: say what the windows were for
            unjudged = [dataclasses.replace(u, subject="to identify from") for u in unjudged]
            code, errors = exit_status(replayed.complete, unjudged, timing)
            return Outcome(
                code, STATUS_OF_CODE[code], None, summary, tuple(tell.messages), (), tuple(errors)
            )
        first = f"{len(windows)} non-overlapping window(s) of whole periods in {self.recording}"
        if show is not None:
            show(first)
        design = read_design(self.recording)  # simulate's, beside the recording
        lines = None if design is None else design.lines
        config = IdentifyConfig(
            orders=orders, band=band, delays=self.delays, grey_box=grey, lines=lines
        )
        ident = identify_windows(windows, config)
        made = identified_model(ident, windows, self.name, imap.input_names, imap.output_names)
        for note in ident.notes:
            tell(Level.NOTE, note)
        model_file = None
        if self.out_model:
            Path(self.out_model).write_text(
                "# Written by twotank-validation identify; validate with --model this file.\n"
                + yaml.safe_dump(made.document, sort_keys=False, width=100)
            )
            model_file = str(self.out_model)
        outputs = imap.output_names
        nums = report_numbers(
            ident,
            made,
            outputs,
            output_noise_at_lines(ident, windows),
            validation_requirement(windows, made.document, ident.response.lines, outputs),
        )
        document = identification_json(ident, made, model_file, nums)
        document["timing"] = timing.to_json()
        if self.report_dir:
            document["figures"] = write_identify_report(
                ident,
                made,
                nums,
                self.report_dir,
                inputs=imap.input_names,
                outputs=imap.output_names,
            )
        if self.json_path:
            write_json(self.json_path, document)
        text = [first, *identification_text(ident, made, model_file)]
        read = ExitCode.OK if replayed.complete else ExitCode.INCOMPLETE
        return Outcome(
            read, STATUS_OF_CODE[read], document, summary, tuple(tell.messages), tuple(text)
        )


def _grey_box(name: str | None, imap: Any) -> GreyBoxModel | None:
    """The grey box asked for, checked against the map's channels.

    Raises:
        UsageError: an unknown model, or a map that is not inputs [hot, cold] valve and
            outputs [height, temperature] (two of each, in that order).
    """
    if name is None:
        return None
    try:
        model = GreyBoxModel(name)
    except ValueError as err:
        kinds = ", ".join(m.value for m in GreyBoxModel)
        raise UsageError(f"--grey-box {name!r} is not a known model; use one of: {kinds}") from err
    if len(imap.input_names) != 2 or len(imap.output_names) != 2:
        raise UsageError(
            f"--grey-box {name} needs 2 inputs (hot, cold valve) and 2 outputs (height, "
            f"temperature), in that order; the map has {list(imap.input_names)} and "
            f"{list(imap.output_names)}: map them so, or leave out --grey-box"
        )
    return model


def _c(x: np.ndarray) -> list[Any]:
    """A complex array as nested ``[re, im]`` pairs."""
    arr = np.asarray(x)
    if arr.ndim == 0:
        return [float(arr.real), float(arr.imag)]
    return [_c(v) for v in arr]


def identification_json(
    ident: Identification,
    made: IdentifiedModel,
    model_file: str | None,
    nums: ReportNumbers | None = None,
) -> dict[str, Any]:
    """The identification as JSON: the response, the fit, the weights and the verdicts.

    ``nums``: the report's numbers per line (``report``: what its figures draw).
    """
    fr = ident.response
    fit = ident.fit
    document = {
        # the channels, in the order of every array's output and input axes
        "inputs": list(made.document["inputs"]),
        "outputs": list(made.document["outputs"]),
        "estimator": ident.estimator.value,
        "ts_s": ident.ts_s,
        "period_samples": ident.period_samples,
        "windows": ident.n_windows,
        "response": {
            "freqs_hz": fr.freqs_hz.tolist(),
            "g": _c(fr.g),
            "std": np.sqrt(fr.var).tolist(),
            "std_noise": np.sqrt(ident.var_noise).tolist(),
        },
        "fit": {
            "order": fit.order,
            "poles_rad_s": _c(fit.poles),
            "pole_std_rad_s": _c(fit.pole_std),
            "cost_ratio": fit.cost_ratio,
            "delays_s": fit.delays_s.tolist(),
            "delay_std_s": fit.delay_std_s.tolist(),
            "relative_error_max": float(np.max(ident.relative_error)),
            "orders": [
                {"order": f.order, "cost_ratio": f.cost_ratio, "n_par": f.n_par} for f in ident.fits
            ],
        },
        "perturbation_weights": [
            {"name": name, "num": num, "den": den} for name, num, den in made.weights()
        ],
        "calibrated": made.calibrated,
        "joint_factors": list(made.factors),
        "noise": {
            "gains": made.noise.gains.tolist(),
            "noise_rms": made.noise.noise_rms.tolist(),
            "quantile": made.noise.quantile,
            "budget": made.noise.budget,
        },
        "beta": made.beta.tolist(),
        "held_out": made.held_out.tolist(),
        "grey_box": None if ident.grey_box is None else ident.grey_box.to_json(),
        "notes": list(ident.notes),
        "model_file": model_file,
        "distortion": None
        if (d := ident.distortion) is None
        else {
            "odd": d.odd.tolist(),
            "even": d.even.tolist(),
            "noise_odd": d.noise_odd.tolist(),
            "noise_even": d.noise_even.tolist(),
            "n_odd": d.n_odd,
            "n_even": d.n_even,
        },
    }
    if nums is not None:
        document["report"] = nums.to_json()
    return document


def identification_text(
    ident: Identification, made: IdentifiedModel, model_file: str | None
) -> list[str]:
    """The identification in a few lines."""
    fr = ident.response
    fit = ident.fit
    lines = [
        f"response: {ident.estimator.value}, {fr.freqs_hz.size} lines "
        f"{fr.freqs_hz.min():.4g}..{fr.freqs_hz.max():.4g} Hz, median σ/|G| "
        f"{float(np.median(np.sqrt(fr.var) / np.maximum(np.abs(fr.g), 1e-300))):.3g}",
        f"{'nominal' if ident.grey_box is None else 'black-box fit (not the nominal)'}: "
        f"order {fit.order} per input (MDL over {len(ident.fits)} orders), residual "
        f"{fit.cost_ratio:.2f} x what the response's σ explains, largest relative error "
        f"{float(np.max(ident.relative_error)):.3g}",
    ]
    if ident.grey_box is not None:
        fitted = ", ".join(
            f"{e.name} {e.value:.4g} ± {e.std:.2g}"
            for e in ident.grey_box.estimates
            if e.status is ParameterStatus.FITTED
        )
        lines.append(
            f"grey box {GreyBoxModel.TWO_TANK.value} (the nominal): {fitted}; residual "
            f"{ident.grey_box.cost_ratio:.2f} x what σ explains"
        )
    if (d := ident.distortion) is not None:
        lines.append(
            "output power at the design's unexcited lines, per output (noise there): odd "
            f"{np.array2string(d.odd, precision=3)} ({np.array2string(d.noise_odd, precision=3)}) "
            f"over {d.n_odd} detection line(s), even {np.array2string(d.even, precision=3)} "
            f"({np.array2string(d.noise_even, precision=3)}) over {d.n_even}"
        )
    held = made.held_out
    if held.any():
        lines.append(
            f"β on {int(held.sum())} held-out window(s): max {float(made.beta[held].max()):.3f}; "
            f"on the {int((~held).sum())} fit window(s): max {float(made.beta[~held].max()):.3f}"
        )
    else:
        lines.append(
            f"β on the {made.beta.size} window(s) it was fitted on: max "
            f"{float(made.beta.max()):.3f} (nothing could be held out: validate the model set "
            "on another record)"
        )
    if model_file:
        lines.append(f"model set written to {model_file}: validate with --model {model_file}")
    return lines


__all__ = ["IdentifyJob", "identification_json", "identification_text", "parse_orders"]
