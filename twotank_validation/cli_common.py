"""What every command of ``twotank-validation`` prints with, and its network settings.

Shared by :mod:`twotank_validation.cli` and :mod:`twotank_validation.cli_models` (a module
below both, so that neither imports the other).
"""

from __future__ import annotations

import json
import math
import os
import sys

from twotank_validation.online import WindowReport
from twotank_validation.online.window import verdict_text

__all__ = ["finite", "live_line", "loopback_only", "out", "progress_wanted", "report_dict"]


def out(*parts: object) -> None:
    """Print to stdout; a reader that went away (``| head``) ends the printing quietly.

    The command goes on (its JSON and report files are still written); only what would have
    been printed is dropped.
    """
    try:
        print(*parts, flush=True)
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # later prints and the exit flush go nowhere
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


def finite(x: float) -> float | None:
    """``x``, or None (JSON null) where it is NaN or infinite."""
    return x if math.isfinite(x) else None


def report_dict(rep: WindowReport) -> dict[str, object]:
    """JSON-friendly summary of a window report (spectrum left out)."""
    return {
        "model": rep.model,
        "start": rep.start_ns / 1e9,
        "end": rep.end_ns / 1e9,
        "judged": rep.judged,
        "beta": rep.beta if rep.judged else None,
        "invalidated": rep.invalidated,
        "alarm": rep.alarm.name,
        "reason": None if rep.judged else rep.data_quality,
        "data_quality": rep.data_quality,
        "warnings": list(rep.warnings),
        "beta_op": finite(rep.beta_op),
        "beta_total": finite(rep.beta_total),
        "raised_by": rep.raised_by,
        "operating_point": rep.operating_point,
    }


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
