"""Where a run's reports go: the page's server, the Foxglove server, or both (one listener)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

from twotank_validation.online.window import WindowReport


class ReportSink(Protocol):
    """A listener of reports (:class:`~.server.ViewServer`, :class:`~.foxglove.FoxgloveView`).

    ``publish_report`` takes each report (``start_ns``: the stamp times are counted from);
    ``publish`` a message of the page's stream (a diagnosis, the supervisor's mode).
    """

    def publish_report(self, rep: WindowReport, start_ns: int = 0) -> None:
        """Take a report."""

    def publish(self, message: Mapping[str, Any]) -> None:
        """Take a message of the page's stream."""


class Tee:
    """Hand each report and message to every sink, in order."""

    def __init__(self, sinks: Sequence[ReportSink]) -> None:
        self.sinks = tuple(sinks)

    def publish_report(self, rep: WindowReport, start_ns: int = 0) -> None:
        """Each sink's ``publish_report``."""
        for s in self.sinks:
            s.publish_report(rep, start_ns)

    def publish(self, message: Mapping[str, Any]) -> None:
        """Each sink's ``publish``."""
        for s in self.sinks:
            s.publish(message)
