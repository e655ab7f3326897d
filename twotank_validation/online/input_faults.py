"""Input faults: what the input streams did wrong, the STALE decision and its text.

From the moment input arrives that makes the coming windows unfit to judge (non-finite or
implausible values, off-grid stamps, gaps, clock jumps, a stream stopping, a run of stale
stamps) until a window after it is judged, the validator's status is STALE and says why:
:class:`InputFaults` keeps that state. The live node and bag replay both get their words from
here, so the same facts give the same text.
"""

from __future__ import annotations

from collections.abc import Sequence

from twotank_validation.online.aligner import AlignerCounters
from twotank_validation.online.window import WindowReport

FAULT_COUNTERS = {
    "non_finite": "non-finite or implausible values",
    "off_grid": "stamps off the sample grid",
    "missing": "gaps",
    "clock_resets": "clock jumps (alignment restarted)",
}
"""Aligner counters whose rise means the coming windows are not fit to judge (flagged samples or
a restart), and their words; duplicates and out-of-order stragglers are dropped and harm nothing
by themselves."""

STOPPED_STREAMS = "stopped streams"
"""Input fault: a stream went silent (the live node's watchdog sees that)."""

STALE_STAMPS = "stale or out-of-order stamps"
"""Input fault: a run of messages stamped before the last sample (a stale source)."""


def input_fault_text(kinds: set[str]) -> str:
    """The status text of input faults of these kinds (a STALE status)."""
    return (
        "input fault: " + ", ".join(sorted(kinds)) + "; windows are not judged "
        "until clean data have settled"
    )


class InputFaults:
    """The input-fault state of one validator (ROS-free; fed by :class:`OnlineValidator`).

    Counts are in samples completed by the aligner (``samples_seen``): a fault noted while
    ``seen`` samples were complete is cleared by a judged window that starts after it.

    Args:
        counters: the aligner's counters (read, never written).
        window_samples: samples per validated window.
        n_streams: number of input streams (a run of ``3 n_streams`` stale messages is a
            fault).

    Attributes:
        text: the current input fault in words (STALE), None while there is none.
        kinds_seen: every kind of input fault seen since the start (for a run's summary).
    """

    def __init__(
        self, counters: AlignerCounters, *, window_samples: int, n_streams: int = 3
    ) -> None:
        self._counters = counters
        self._window = window_samples
        self._stale_run = 3 * n_streams
        self.text: str | None = None
        self._seen = 0  # samples seen before the event that showed the fault
        self._kinds: set[str] = set()  # kinds of the current fault
        self.kinds_seen: set[str] = set()
        self._counts = self._fault_counts()
        self._late_run = 0  # out-of-order messages since the core last completed a sample
        self._late = 0

    def _fault_counts(self) -> tuple[int, ...]:
        c = self._counters
        return tuple(getattr(c, name) for name in FAULT_COUNTERS)

    def rebase(self) -> None:
        """Take the counters as they are now for the baseline (their rises so far: no fault)."""
        self._counts = self._fault_counts()

    def note(self, seen: int, extra: str = "") -> None:
        """Note the counters' rises (and ``extra``, a fault kind) as a fault at ``seen`` samples."""
        counts = self._fault_counts()
        if counts == self._counts and not extra:
            return
        if self.text is None:
            self._kinds = set()
        if extra:
            self._kinds.add(extra)
        self._kinds.update(
            what
            for what, old, new in zip(FAULT_COUNTERS.values(), self._counts, counts, strict=True)
            if new != old
        )
        self.kinds_seen |= self._kinds
        self._counts = counts
        self._seen = seen
        self.text = input_fault_text(self._kinds)

    def after_event(self, seen: int, seen_now: int, reports: Sequence[WindowReport]) -> None:
        """Note what one event showed.

        Args:
            seen: samples seen before the event.
            seen_now: samples seen after it.
            reports: the reports of the windows it completed.
        """
        late = self._counters.out_of_order
        self.note(seen)
        if seen_now != seen:
            self._late_run = 0
        elif late != self._late:
            # messages that complete no sample, stamped before the last one (a stale
            # source): one is harmless (a repeat), a run of them means the data stopped
            self._late_run += 1
            if self._late_run >= self._stale_run:
                self.note(seen, STALE_STAMPS)
        self._late = late
        # a judged window that starts after the fault (its first sample comes after the event
        # that showed it; bounded below from this event's count) clears it
        if (
            reports
            and self.text is not None
            and any(r.judged for r in reports)
            and seen + 2 - self._window > self._seen
        ):
            self.text = None

    def summary(self) -> list[str]:
        """A finished run's input faults in words (empty if there were none)."""
        c = self._counters
        out = [input_fault_text(self.kinds_seen)] if self.kinds_seen else []
        disorder = c.out_of_order + c.duplicates
        if disorder:
            out.append(f"{disorder} message(s) with repeated or out-of-order stamps were dropped")
        return out
