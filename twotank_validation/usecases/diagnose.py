"""``diagnose`` of one recording: a model's residual traced to the effect it lacks, per stretch."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from twotank_validation import replay
from twotank_validation.core.datum import NormConvention
from twotank_validation.diagnose import Diagnosis, DiagnosisConfig, DiagnosisError
from twotank_validation.diagnose.inputs import Window
from twotank_validation.diagnose.stretches import (
    RecordingDiagnosis,
    WindowFindings,
    diagnose_stretches,
)
from twotank_validation.errors import ExitCode, TwotankError, interruption
from twotank_validation.replay import Timing
from twotank_validation.usecases.outcome import (
    STATUS_OF_CODE,
    Level,
    Message,
    Outcome,
    Progress,
    Say,
    Show,
    Status,
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
    model_names,
    open_recording,
    timed_config,
)


@dataclass(frozen=True)
class DiagnoseJob:
    """Diagnose a model on one recording (``twotank-validation diagnose RECORDING``).

    Attributes:
        recording: the bag or table.
        model: the model's name or YAML path.
        read: how to read the recording.
        max_effects: effects combined (0, 1 or 2).
        start: diagnose only the windows from this time: seconds from the recording start or
            an ISO 8601 time; None: from the start.
        end: as ``start``, the end of the range; None: to the end.
        segment: search for changes inside the range too (without a range, always).
        json_path: write the diagnosis JSON here (None: not written).
        report_dir: write the evidence figures here (None: none).
        out_model: write the changed model (YAML) here (None: not written).
    """

    recording: str
    model: str
    read: ReadSettings = field(default_factory=ReadSettings)
    max_effects: int = 2
    start: str | None = None
    end: str | None = None
    segment: bool = False
    json_path: str | None = None
    report_dir: str | None = None
    out_model: str | None = None

    def at(self, path: str) -> DiagnoseJob:
        """This job on another recording, writing nothing (a fleet's task)."""
        return dataclasses.replace(
            self, recording=path, json_path=None, report_dir=None, out_model=None
        )

    def model_names(self, *, check_channels: bool = False) -> list[str]:
        """The model's name (loading it; ``check_channels``: matched to the map's too)."""
        return model_names([self.model], self.read if check_channels else None)

    def run(
        self,
        *,
        say: Say | None = None,
        progress: Progress | None = None,
        show: Show | None = None,
    ) -> Outcome:
        """Replay the recording, diagnose its stretches, write what was asked.

        Args:
            say: told each note (timing) and warning as it arises.
            progress: told (messages read, messages expected) now and then, while replaying.
            show: told the text's first line (the windows judged) once the replay is done,
                before the long part (the lines ``text`` begins with).

        Returns:
            The outcome: ``document`` the diagnosis JSON (None where none: no window judged,
            nothing diagnosed), ``summary`` the replay's, ``text`` the windows, stretches and
            diagnosis; an error reading the recording is ``UNREADABLE``, nothing diagnosed
            ``NOT_JUDGED`` with the exit code 2. SIGINT or SIGTERM (a KeyboardInterrupt) is
            ``INTERRUPTED`` (code 130 or 143): the windows judged up to then are kept in the
            JSON (:func:`interrupted_outcome`), nothing is diagnosed.
        """
        tell = Teller(say)
        try:
            loaded = banded(load(self.model), self.read.monitor.band)
            with open_recording(self.read, self.recording) as opened:
                cfg, timing = timed_config(self.read, opened, tell)
                windows, findings, replayed = replay.windows_with_findings(
                    opened, loaded.model, cfg, start=self.start, end=self.end, progress=progress
                )
        except TwotankError as err:
            return unreadable(err, tell)
        except replay.ReplayInterrupted as stop:
            summary = replay.summary_json(stop.result, [loaded.model.name])
            return interrupted_outcome(
                stop, loaded.model.name, summary, timing=timing, json_path=self.json_path, tell=tell
            )
        except KeyboardInterrupt as stop:
            document = interrupted_document(self.model)
            return nothing_judged(interruption(stop), tell, self.json_path, document)
        try:
            return self._diagnose(
                loaded,
                windows=windows,
                findings=findings,
                replayed=replayed,
                timing=timing,
                cfg=cfg,
                tell=tell,
                show=show,
            )
        except KeyboardInterrupt as stop:  # while diagnosing: the windows judged are kept
            summary = replay.summary_json(replayed, [loaded.model.name])
            return interrupted_outcome(
                interruption(stop),
                loaded.model.name,
                summary,
                timing=timing,
                json_path=self.json_path,
                tell=tell,
            )

    def _diagnose(
        self,
        loaded: LoadedModel,
        *,
        windows: list[Window],
        findings: list[WindowFindings],
        replayed: replay.ReplayResult,
        timing: Timing,
        cfg: replay.ReplayConfig,
        tell: Teller,
        show: Show | None,
    ) -> Outcome:
        """The stretches of the judged windows diagnosed; the outcome (as :meth:`run`)."""
        for problem in replayed.problems:
            tell(Level.WARNING, problem)
        summary = replay.summary_json(replayed, [loaded.model.name])
        if unjudged := replay.unjudged(replayed, [loaded.model.name], timing, cfg):
            code, errors = exit_status(replayed.complete, unjudged, timing)
            return Outcome(
                code, STATUS_OF_CODE[code], None, summary, tuple(tell.messages), (), tuple(errors)
            )
        ranged = self.start is not None or self.end is not None
        text = [
            f"{len(windows)} non-overlapping judged window(s) of model {loaded.model.name} in "
            f"{self.recording}"
            + (f" ({windows[0].start_s:.1f} .. {windows[-1].start_s:.1f} s)" if ranged else "")
        ]
        if show is not None:
            show(text[0])
        try:
            recording = diagnose_stretches(
                windows,
                loaded.document,
                findings,
                DiagnosisConfig(max_effects=self.max_effects),
                split=self.segment or not ranged,
                source=loaded.source,
                convention=NormConvention(self.read.monitor.convention),
            )
            current = recording.current
            if current is None or current.relative_to_model is None:
                why = "; ".join(
                    f"{s.stretch.start_s:.1f}-{s.stretch.end_s:.1f} s: {s.not_diagnosed}"
                    for s in recording.stretches
                )
                raise DiagnosisError(f"no stretch of the recording could be diagnosed ({why})")
            diag = current.relative_to_model
            document = self._write(recording, diag, timing, text)
        except TwotankError as err:
            return Outcome(
                ExitCode.ERROR,
                Status.NOT_JUDGED,
                None,
                summary,
                tuple(tell.messages),
                tuple(text),
                (Message(Level.ERROR, str(err)),),
            )
        code = ExitCode.OK if replayed.complete else ExitCode.INCOMPLETE
        return Outcome(
            code, STATUS_OF_CODE[code], document, summary, tuple(tell.messages), tuple(text)
        )

    def _write(
        self, recording: RecordingDiagnosis, diag: Diagnosis, timing: Timing, text: list[str]
    ) -> dict[str, Any]:
        """The model file, the JSON and the figures asked for; the text; the JSON document."""
        from twotank_validation import report  # noqa: PLC0415 (matplotlib)

        model_file = None
        if diag.document is not None and self.out_model:
            Path(self.out_model).write_text(
                "# Written by twotank-validation diagnose; validate with --model this file.\n"
                + yaml.safe_dump(diag.document, sort_keys=False, width=100)
            )
            model_file = str(self.out_model)
        out: dict[str, Any] = diag.to_json(model_file)
        out.update(recording.to_json())
        assert recording.current is not None
        out["stretch"] = recording.stretches.index(recording.current)
        out["timing"] = timing.to_json()
        text.append(stretches_text(recording))
        text.append(report.diagnosis_text(diag, model_file))
        if self.json_path:
            write_json(self.json_path, out)
        if self.report_dir:
            report.write_diagnosis_report(diag, Path(self.report_dir), model_file, numbers=out)
            text.append(f"figures and report.html in {self.report_dir}")
        return out


def stretches_text(recording: RecordingDiagnosis) -> str:
    """One block per stretch: its span, the change that starts it, skipped windows, answers."""
    lines = []
    if not recording.segmented:
        lines.append("the range is taken as one stretch (no change search inside it)")
    elif len(recording.stretches) == 1 and not recording.changes:
        lines.append("no change found: the recording is one stationary stretch")
    for k, st in enumerate(recording.stretches):
        head = f"stretch {k + 1}: {st.stretch.start_s:.1f}-{st.stretch.end_s:.1f} s"
        if st.stretch.change_at_s is not None:
            head += (
                f", changed at {st.stretch.change_at_s:.1f} s (in the window starting "
                f"then): {st.stretch.evidence}"
            )
        lines.append(head)
        lines.append(f"  {len(st.window_starts_s)} window(s) diagnosed")
        lines += [f"  skipped {t:.1f} s: {why}" for t, why in st.skipped]
        if st.not_diagnosed:
            lines.append(f"  not diagnosed: {st.not_diagnosed}")
        if st.relative_to_model is not None:
            lines.append(f"  relative to the model: {st.relative_to_model.summary}")
        if st.relative_to_previous is not None:
            same = st.relative_to_previous is st.relative_to_model
            text = "the same (it needed nothing)" if same else st.relative_to_previous.summary
            lines.append(f"  relative to the stretch before: {text}")
    return "\n".join(lines)
