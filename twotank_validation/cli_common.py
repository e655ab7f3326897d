"""What every command of ``twotank-validation`` prints with, and its network settings.

Shared by :mod:`twotank_validation.cli` and :mod:`twotank_validation.cli_models` (a module
below both, so that neither imports the other).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
from dataclasses import dataclass, field
from types import FrameType, TracebackType
from typing import Any, Protocol

from twotank_validation.errors import ExitCode
from twotank_validation.online import Alarm, WindowReport
from twotank_validation.online.livediag import LiveDiagnosis
from twotank_validation.online.window import verdict_text
from twotank_validation.replay.summary import window_entry
from twotank_validation.usecases.validate import diagnosis_text

__all__ = [
    "Interrupts",
    "LiveOutput",
    "answer_line",
    "live_end",
    "live_line",
    "loopback_only",
    "out",
    "progress_wanted",
    "report_dict",
    "stdout_to_devnull",
]


def out(*parts: object) -> None:
    """Print to stdout; a reader that went away (``| head``) ends the printing quietly.

    The command goes on (its JSON and report files are still written); only what would have
    been printed is dropped.
    """
    try:
        print(*parts, flush=True)
    except BrokenPipeError:
        stdout_to_devnull()


def stdout_to_devnull() -> None:
    """Point stdout at /dev/null once its reader went away (``| head``).

    Later prints and the exit's flush then go nowhere instead of failing again (the Python
    docs' recipe, "Note on SIGPIPE").
    """
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def progress_wanted(quiet: bool = False) -> bool:
    """Show a progress bar: not ``--quiet`` and stderr (where bars go) is a terminal.

    Piped or redirected, a command prints no bar.
    """
    return not quiet and sys.stderr.isatty()


def loopback_only() -> None:
    """DDS discovery on loopback only, in a domain of our own unless one was chosen."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", "77")


def report_dict(rep: WindowReport) -> dict[str, object]:
    """A report as ``live --json`` writes it.

    The model's name, whether the window was judged, and its entry of the ``validate --json``
    document (one serialisation for both; times in s of the run's clock, which starts at 0;
    the spectrum left out).
    """
    return {"model": rep.model, "judged": rep.judged} | window_entry(rep, 0)


def live_line(rep: WindowReport, as_json: bool) -> str:
    """The line ``live`` prints for a report.

    Its JSON (``--json``), or the window's span, verdict, alarm and warnings.
    """
    if as_json:
        return json.dumps(report_dict(rep))
    verdict = verdict_text(rep) if rep.judged else f"not judged: {rep.data_quality}"
    warned = "".join(f"  warning: {w}" for w in rep.warnings)
    return (
        f"[{rep.start_ns / 1e9:8.1f}, {rep.end_ns / 1e9:8.1f}] s  model {rep.model}: "
        f"{verdict}  alarm {rep.alarm.name}{warned}"
    )


def answer_line(d: LiveDiagnosis) -> str:
    """The line ``live`` prints when the live diagnosis gives a new answer.

    Stamped with the end of the window whose report started it (the data's time base, the
    simulated clock for ``live``).
    """
    head = f"[{d.window_end_ns / 1e9:8.1f} s] model {d.model}:"
    entry = d.to_json()
    named = "no fault named" if d.unexplained else "fault named"
    return (
        f"{head} {named}: {diagnosis_text(entry)} (answer {d.update} to this alarm, from "
        f"{d.windows} window(s) after {d.onset_ns / 1e9:.1f} s against those before): "
        f"{d.summary}"
    )


@dataclass
class _Episode:
    """One alarm of a model: from its first ERROR window to the first window not ERROR."""

    start_s: float
    end_s: float | None = None
    answer: LiveDiagnosis | None = None
    answers: int = 0


@dataclass
class _ModelTally:
    windows: int = 0
    judged: int = 0
    invalidated: int = 0
    alarm: Alarm = Alarm.STALE
    last_reason: str = ""
    episodes: list[_Episode] = field(default_factory=list)
    last_end_s: float = 0.0


class LiveOutput:
    """What ``live`` prints on stdout: the reports as they come, the answers, a closing summary.

    Per report its line (:func:`live_line`); when a model's live diagnosis gives a new answer
    (text mode) the line :func:`answer_line` after it. With ``as_json`` one JSON object per
    line, each complete and flushed as it is written, the answer in force on each report
    (``"diagnosis"``); the last line is ``{"summary": ...}`` (:meth:`summary`), also when the
    run was interrupted (``"interrupted": true``).

    Args:
        as_json: JSON lines instead of text.
    """

    def __init__(self, as_json: bool) -> None:
        self.as_json = as_json
        self.models: dict[str, _ModelTally] = {}

    def report(self, rep: WindowReport) -> None:
        """Print a report (and a new answer), and count it."""
        t = self.models.setdefault(rep.model, _ModelTally())
        end_s = rep.end_ns / 1e9
        t.windows += 1
        t.judged += int(rep.judged)
        t.invalidated += int(rep.judged and rep.invalidated)
        t.alarm = rep.alarm
        t.last_end_s = end_s
        if not rep.judged:
            t.last_reason = rep.data_quality
        ep = t.episodes[-1] if t.episodes and t.episodes[-1].end_s is None else None
        if rep.alarm is Alarm.ERROR and ep is None:
            ep = _Episode(end_s)
            t.episodes.append(ep)
        elif rep.alarm is not Alarm.ERROR and ep is not None:
            ep.end_s = end_s
            ep = None
        new = ep is not None and rep.diagnosis is not None and rep.diagnosis is not ep.answer
        if new and ep is not None:
            ep.answer = rep.diagnosis
            ep.answers += 1
        out(live_line(rep, self.as_json))
        if new and not self.as_json and rep.diagnosis is not None:
            out(answer_line(rep.diagnosis))

    def not_judged(self) -> list[str]:
        """The models without a judged window, each with its last reason."""
        if not self.models:
            return ["no window completed"]
        return [
            f"model {name}: no window judged (last: {t.last_reason or 'no window completed'})"
            for name, t in self.models.items()
            if t.judged == 0
        ]

    def summary(self, simulated_s: float, interrupted: str | None) -> dict[str, Any]:
        """The closing summary (also printed): per model its windows, alarms, faults named.

        Args:
            simulated_s: simulated seconds run.
            interrupted: the signal's name when the run was interrupted, else None.
        """
        doc: dict[str, Any] = {
            "simulated_s": round(simulated_s, 6),
            "interrupted": interrupted is not None,
            "signal": interrupted,
            "models": {},
        }
        lines = [
            f"summary: {simulated_s:.1f} simulated s"
            + (f", interrupted by {interrupted}" if interrupted else "")
        ]
        for name, t in self.models.items():
            alarms = [
                {
                    "from": ep.start_s,
                    "to": ep.end_s,
                    "answers": ep.answers,
                    "fault": None if ep.answer is None else ep.answer.to_json(),
                }
                for ep in t.episodes
            ]
            doc["models"][name] = {
                "windows": t.windows,
                "judged": t.judged,
                "invalidated": t.invalidated,
                "alarm": t.alarm.name,
                "alarms": alarms,
            }
            lines.append(
                f"  model {name}: {t.windows} window(s), {t.judged} judged, "
                f"{t.invalidated} invalidated; alarm {t.alarm.name} at the end"
            )
            if not t.episodes:
                lines.append("    the alarm never rose: no fault to name")
            for ep in t.episodes:
                span = f"{ep.start_s:.1f} s to " + (
                    f"{ep.end_s:.1f} s" if ep.end_s is not None else "the end"
                )
                if ep.answer is None:
                    named = (
                        "no fault named yet (the diagnosis needs a whole window after the onset)"
                    )
                else:
                    entry = ep.answer.to_json()
                    what = "no fault named" if ep.answer.unexplained else "fault named"
                    named = f"{what}: {diagnosis_text(entry)}"
                lines.append(f"    alarm ERROR {span}: {named}")
        if self.as_json:
            out(json.dumps({"summary": doc}))
        else:
            for line in lines:
                out(line)
        return doc


class Interrupts:
    """SIGINT and SIGTERM ask a run to stop; a second one ends the process at once.

    Use as a context manager around a run that polls it (``stop=interrupts``): the first
    signal only sets the flag, so the run ends between two samples and what it judged is
    printed and summarised; a second one prints one line and exits ``128 + signal``.
    Outside the main thread (no signal handlers there) it never fires.

    Args:
        doing: what the first signal does, said after its name on stderr (default: a run's,
            :data:`STOP_RUN`).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)
    STOP_RUN = "stopping after the current sample; what was judged is kept and summarised"
    """What a run does on the first signal."""

    def __init__(self, doing: str = STOP_RUN) -> None:
        self.signum: int | None = None
        self.doing = doing
        self._old: dict[int, Any] = {}

    def __call__(self) -> bool:
        """Whether a signal asked to stop."""
        return self.signum is not None

    @property
    def name(self) -> str | None:
        """``"SIGINT"`` or ``"SIGTERM"`` once one came, else None."""
        return None if self.signum is None else signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """``128 + signal`` (130 for SIGINT, 143 for SIGTERM), the shells' convention."""
        return 128 + (self.signum or 0)

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        if self.signum is not None:
            os.write(2, f"{signal.Signals(signum).name} again: exiting now\n".encode())
            os._exit(128 + signum)
        self.signum = signum
        os.write(2, f"{signal.Signals(signum).name}: {self.doing}\n".encode())

    def __enter__(self) -> Interrupts:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old = {}


class _RunResult(Protocol):
    @property
    def wall_s(self) -> float: ...
    @property
    def counters(self) -> dict[str, int]: ...


def live_end(
    output: LiveOutput, result: _RunResult, simulated_s: float, interrupts: Interrupts
) -> int:
    """Print ``live``'s closing summary and timing line; its exit code.

    ``128 + signal`` when interrupted; :attr:`ExitCode.NOT_JUDGED` (an ERROR line naming
    the models and why) when a model had no judged window; else 0.
    """
    output.summary(simulated_s, interrupts.name)
    print(
        f"simulated {simulated_s:.0f} s in {result.wall_s:.1f} s wall "
        f"({simulated_s / max(result.wall_s, 1e-9):.0f}x real time); "
        f"{sum(t.windows for t in output.models.values())} reports; aligner: {result.counters}",
        file=sys.stderr,
    )
    if interrupts():
        return interrupts.exit_code
    missing = output.not_judged()
    if missing:
        print(
            "ERROR: " + "; ".join(missing) + ": run longer (--duration: the first window is "
            "judged after a period of settling and two whole periods)",
            file=sys.stderr,
        )
        return int(ExitCode.NOT_JUDGED)
    return int(ExitCode.OK)
