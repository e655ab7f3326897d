"""``calibrate`` of one recording: the smallest uncertainty it demands, and a fitted model."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import yaml

from twotank_validation import calibrate as cb
from twotank_validation import replay
from twotank_validation.core.datum import NormConvention
from twotank_validation.core.noise_budget import NOISE_BUDGET, NOISE_QUANTILE
from twotank_validation.diagnose.inputs import Window
from twotank_validation.errors import ExitCode, TwotankError, UsageError, interruption
from twotank_validation.replay import Timing
from twotank_validation.usecases.outcome import (
    STATUS_OF_CODE,
    Level,
    Message,
    Outcome,
    Progress,
    Say,
    Show,
    Teller,
    exit_status,
    interrupted_document,
    interrupted_outcome,
    nothing_judged,
    unreadable,
    write_json,
)
from twotank_validation.usecases.reading import (
    LoadedModel,
    ReadSettings,
    banded,
    load,
    open_recording,
    timed_config,
)


@dataclass(frozen=True)
class CalibrateJob:
    """Calibrate a model's weights on one recording (``twotank-validation calibrate``).

    Attributes:
        recording: the bag or table.
        model: the model's name or YAML path.
        read: how to read the recording.
        blocks: the perturbation or noise blocks to calibrate, by name, in order; None: all.
        margin: the new weights cover this times the requirement.
        max_order: largest order of a fitted weight.
        together: scale the blocks together (the common factor and the joint factors).
        json_path: write the calibration JSON here (None: not written).
        report_dir: write the figures here (None: none).
        out_model: write the calibrated model (YAML) here (None: not written).
        noise_from_data: set every output's noise weight from the windows' period-to-period
            spread (:func:`~twotank_validation.calibrate.noise_from_data`) instead of
            calibrating blocks; ``blocks`` and ``together`` must then be left unset.
        noise_quantile: with ``noise_from_data``, the share of windows on which the noise
            alone costs at most ``noise_budget``.
        noise_budget: with ``noise_from_data``, the β the noise alone may cost.
    """

    recording: str
    model: str
    read: ReadSettings = field(default_factory=ReadSettings)
    blocks: tuple[str, ...] | None = None
    margin: float = 1.2
    max_order: int = 2
    together: bool = False
    json_path: str | None = None
    report_dir: str | None = None
    out_model: str | None = None
    noise_from_data: bool = False
    noise_quantile: float = NOISE_QUANTILE
    noise_budget: float = NOISE_BUDGET

    def run(
        self,
        *,
        say: Say | None = None,
        progress: Progress | None = None,
        show: Show | None = None,
    ) -> Outcome:
        """Replay the recording, calibrate the blocks, write what was asked.

        Args:
            say: told each note (timing) and warning as it arises.
            progress: told (messages read, messages expected) now and then, while replaying.
            show: told the text's first line (the windows judged) once the replay is done,
                before the long part (the lines ``text`` begins with).

        Returns:
            The outcome: ``document`` the calibration JSON, ``text`` the calibration; an
            unusable model, block, recording or setting is an ``ERROR`` outcome with its
            message. So is ``out_model`` when no weight could be changed, after the text
            (each block's note), the JSON (its ``failure``) and the report were written.
            SIGINT or SIGTERM (a KeyboardInterrupt) is ``INTERRUPTED`` (code 130 or 143):
            the windows judged up to then are kept in the JSON, nothing is calibrated.
        """
        tell = Teller(say)
        try:
            return self._run(tell, progress, show)
        except TwotankError as err:
            return unreadable(err, tell)

    def _run(self, tell: Teller, progress: Progress | None, show: Show | None) -> Outcome:
        loaded = banded(load(self.model), self.read.monitor.band)
        name = loaded.model.name
        blocks = list(self.blocks) if self.blocks is not None else None
        if self.noise_from_data and (blocks or self.together or self.report_dir):
            raise UsageError(
                "--noise-from-data sets the noise weights alone: leave out --block, "
                "--together and --report (calibrate the perturbations on the written model "
                "afterwards)"
            )
        cb.choose_blocks(loaded.model, blocks)  # an unknown block is an error before the replay
        config = cb.CalibrationConfig(
            margin=self.margin, max_order=self.max_order, together=self.together
        )
        try:
            with open_recording(self.read, self.recording) as recording:
                cfg, timing = timed_config(self.read, recording, tell)
                windows, replayed = replay.windows_from_recording(
                    recording, loaded.model, cfg, progress=progress
                )
        except replay.ReplayInterrupted as stop:
            summary = replay.summary_json(stop.result, [name])
            return interrupted_outcome(
                stop,
                name,
                summary,
                timing=timing,
                json_path=self.json_path,
                tell=tell,
                task="calibrated",
            )
        except KeyboardInterrupt as stop:
            document = interrupted_document(self.model)
            return nothing_judged(interruption(stop), tell, self.json_path, document)
        try:
            return self._calibrate(
                loaded,
                blocks=blocks,
                config=config,
                windows=windows,
                replayed=replayed,
                timing=timing,
                cfg=cfg,
                tell=tell,
                show=show,
            )
        except KeyboardInterrupt as stop:  # while calibrating: the windows judged are kept
            summary = replay.summary_json(replayed, [name])
            return interrupted_outcome(
                interruption(stop),
                name,
                summary,
                timing=timing,
                json_path=self.json_path,
                tell=tell,
                task="calibrated",
            )

    def _noise(
        self,
        loaded: LoadedModel,
        *,
        windows: list[Window],
        replayed: replay.ReplayResult,
        timing: Timing,
        tell: Teller,
        text: list[str],
    ) -> Outcome:
        """The noise weights set from the windows' spread; the outcome (as :meth:`run`)."""
        cal = cb.noise_from_data(
            windows,
            loaded.document,
            quantile=self.noise_quantile,
            budget=self.noise_budget,
            source=loaded.source,
            convention=NormConvention(self.read.monitor.convention),
        )
        model_file = None
        if self.out_model:
            Path(self.out_model).write_text(
                "# Written by twotank-validation calibrate --noise-from-data; validate with "
                "--model this file.\n" + yaml.safe_dump(cal.document, sort_keys=False, width=100)
            )
            model_file = str(self.out_model)
        text.append(cal.text(model_file))
        out = cal.to_json(model_file)
        out["timing"] = timing.to_json()
        if self.json_path:
            write_json(self.json_path, out)
        read = ExitCode.OK if replayed.complete else ExitCode.INCOMPLETE
        summary = replay.summary_json(replayed, [loaded.model.name])
        return Outcome(
            read, STATUS_OF_CODE[read], out, summary, tuple(tell.messages), tuple(text), ()
        )

    def _calibrate(
        self,
        loaded: LoadedModel,
        *,
        blocks: list[str] | None,
        config: cb.CalibrationConfig,
        windows: list[Window],
        replayed: replay.ReplayResult,
        timing: Timing,
        cfg: replay.ReplayConfig,
        tell: Teller,
        show: Show | None,
    ) -> Outcome:
        """The blocks calibrated on the judged windows; the outcome (as :meth:`run`)."""
        for problem in replayed.problems:
            tell(Level.WARNING, problem)
        summary = replay.summary_json(replayed, [loaded.model.name])
        if unjudged := replay.unjudged(replayed, [loaded.model.name], timing, cfg):
            code, errors = exit_status(replayed.complete, unjudged, timing)
            messages = tuple(tell.messages)
            return Outcome(code, STATUS_OF_CODE[code], None, summary, messages, (), tuple(errors))
        text = [
            f"{len(windows)} non-overlapping judged window(s) of model {loaded.model.name} in "
            f"{self.recording}"
        ]
        if show is not None:
            show(text[0])
        if self.noise_from_data:
            return self._noise(
                loaded, windows=windows, replayed=replayed, timing=timing, tell=tell, text=text
            )
        cal = cb.calibrate(
            windows,
            loaded.document,
            config,
            blocks=blocks,
            source=loaded.source,
            convention=NormConvention(self.read.monitor.convention),
        )
        model_file = None
        # asked for a model file and no weight could be changed: the text (each block's
        # note), the JSON and the report are still written, then the error
        failure = cb.NO_WEIGHT_CHANGED if self.out_model and cal.document is None else None
        if self.out_model and cal.document is not None:
            Path(self.out_model).write_text(
                "# Written by twotank-validation calibrate; validate with --model this file.\n"
                + yaml.safe_dump(cal.document, sort_keys=False, width=100)
            )
            model_file = str(self.out_model)
        text.append(cb.calibration_text(cal, model_file))
        out = cal.to_json(model_file)
        out["failure"] = failure
        out["timing"] = timing.to_json()
        if self.json_path:
            write_json(self.json_path, out)
        if self.report_dir:
            cb.write_calibration_report(
                cal, loaded.model, timing.ts_s, Path(self.report_dir), model_file
            )
            text.append(f"figures in {self.report_dir}")
        read = ExitCode.OK if replayed.complete else ExitCode.INCOMPLETE
        return Outcome(
            read if failure is None else ExitCode.ERROR,
            STATUS_OF_CODE[read],
            out,
            summary,
            tuple(tell.messages),
            tuple(text),
            () if failure is None else (Message(Level.ERROR, failure),),
        )
