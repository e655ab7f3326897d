"""``calibrate`` of one recording: the smallest uncertainty it demands, and a fitted model."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from twotank_validation import calibrate as cb
from twotank_validation import replay
from twotank_validation.core.datum import NormConvention
from twotank_validation.errors import ExitCode, TwotankError
from twotank_validation.usecases.outcome import (
    STATUS_OF_CODE,
    Level,
    Message,
    Outcome,
    Say,
    Status,
    Teller,
    exit_status,
)
from twotank_validation.usecases.reading import ReadSettings, load, open_recording, timed_config


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
        json_path: write the calibration JSON here (None: not written).
        report_dir: write the figures here (None: none).
        out_model: write the calibrated model (YAML) here (None: not written).
    """

    recording: str
    model: str
    read: ReadSettings = field(default_factory=ReadSettings)
    blocks: tuple[str, ...] | None = None
    margin: float = 1.2
    max_order: int = 2
    json_path: str | None = None
    report_dir: str | None = None
    out_model: str | None = None

    def run(self, *, say: Say | None = None) -> Outcome:
        """Replay the recording, calibrate the blocks, write what was asked.

        Returns:
            The outcome: ``document`` the calibration JSON, ``text`` the calibration; an
            unusable model, block, recording or setting is an ``ERROR`` outcome with its
            message. So is ``out_model`` when no weight could be changed, after the text
            (each block's note), the JSON (its ``failure``) and the report were written.
        """
        tell = Teller(say)
        try:
            return self._run(tell)
        except TwotankError as err:
            return Outcome(
                ExitCode.ERROR,
                Status.UNREADABLE,
                messages=tuple(tell.messages),
                closing=(Message(Level.ERROR, str(err)),),
            )

    def _run(self, tell: Teller) -> Outcome:
        loaded = load(self.model)
        blocks = list(self.blocks) if self.blocks is not None else None
        cb.choose_blocks(loaded.model, blocks)  # an unknown block is an error before the replay
        config = cb.CalibrationConfig(margin=self.margin, max_order=self.max_order)
        with open_recording(self.read, self.recording) as recording:
            cfg, timing = timed_config(self.read, recording, tell)
            windows, replayed = replay.windows_from_recording(recording, loaded.model, cfg)
        for problem in replayed.problems:
            tell(Level.WARNING, problem)
        summary = replay.summary_json(replayed, [loaded.model.name])
        if unjudged := replay.unjudged(replayed, [loaded.model.name], timing, cfg):
            code, errors = exit_status(replayed.complete, unjudged, timing)
            messages = tuple(tell.messages)
            return Outcome(code, STATUS_OF_CODE[code], None, summary, messages, (), tuple(errors))
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
        text = [cb.calibration_text(cal, model_file)]
        out = cal.to_json(model_file)
        out["failure"] = failure
        out["timing"] = timing.to_json()
        if self.json_path:
            Path(self.json_path).write_text(json.dumps(out, indent=2))
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
