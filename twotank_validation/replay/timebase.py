"""The time base of a bag's windows: its header stamps or its log times, never a mixture.

A bag holds two clocks per message: the header stamp the publisher wrote (where the type has
a header) and the log time the recorder wrote. They agree on a bag recorded on the clock
the data were stamped with, up to the transport's latency; they do not on a bag recorded
from a run on a simulated clock by a recorder on the wall clock (header stamps from 0 s, log
times near 1.8e9 s since the epoch), nor where the recorder's clock is off. The interface
map says, per source, which of the two stamps its samples (``stamp: header``, the default,
or ``stamp: receive``); :func:`stamp_base` reads the first messages of each of the map's
topics and

* names the base the windows are timed in (:class:`TimeBase`) and the first stamp in it,
  from which window times are counted (``ReplayResult.bag_start_ns``);
* refuses a map that stamps some sources by their header and others by the log time when
  the two disagree on this bag by more than a stamp may lie from its sample on the grid
  (:class:`TimeBaseError`, with the fix): the aligner would put the samples of one clock on
  other grid points than those of the other, or on none.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

import twotank_validation.bags as bag_reader
from twotank_validation.defaults import NS_PER_S
from twotank_validation.online.extraction import stamp_ns
from twotank_validation.online.interface_map import InterfaceMap, message_sources
from twotank_validation.online.sources import STAMP_HEADER
from twotank_validation.replay.config import ReplayConfigError, TimeBase

SCAN_MESSAGES = 64
"""Messages read at the start of each topic to compare its two clocks."""


class TimeBaseError(ReplayConfigError):
    """The map mixes header stamps and log times that lie on different clocks in this bag."""


@dataclass(frozen=True)
class StampBase:
    """A bag's time base as :func:`stamp_base` found it.

    Attributes:
        base: the clock the windows are timed by.
        origin_ns: the first stamp in that clock (ns): window times count from it.
        log_offset_s: the largest (by size) median of log time minus header stamp over the
            map's topics stamped by their header (s); None where there is none.
        note: where the header stamps are the base and the log times lie on another clock,
            that in words; None otherwise.
    """

    base: TimeBase
    origin_ns: int
    log_offset_s: float | None = None
    note: str | None = None


@dataclass(frozen=True)
class _TopicClocks:
    """The first messages of one topic: its sources' stamp, log times and header stamps (ns)."""

    topic: str
    header: bool
    log_ns: np.ndarray
    header_ns: np.ndarray | None


def _first_clocks(bag: bag_reader.BagReader, topic: str, header: bool) -> _TopicClocks | None:
    """The first :data:`SCAN_MESSAGES` messages of ``topic`` (None: none could be read).

    A topic that cannot be read (absent, of another type, damaged) is left to the replay,
    which reports it with its fix.
    """
    logs: list[int] = []
    heads: list[int] = []
    with contextlib.suppress(bag_reader.BagError, AttributeError, TypeError, ValueError):
        for m in bag.messages([topic]):
            logs.append(int(m.log_time_ns))
            if getattr(m.msg, "header", None) is not None:
                heads.append(stamp_ns(m.msg))
            if len(logs) >= SCAN_MESSAGES:
                break
    if not logs:
        return None
    head = np.asarray(heads, dtype=np.int64) if len(heads) == len(logs) else None
    return _TopicClocks(topic, header, np.asarray(logs, dtype=np.int64), head)


def _names(topics: Sequence[str]) -> str:
    return ", ".join(repr(t) for t in topics)


@dataclass(frozen=True)
class BagClocks:
    """The two clocks of the first messages of each of a map's topics in a bag.

    Attributes:
        path: the bag (messages name it).
        start_ns: the bag's first log time (ns).
        topics: each readable topic's first messages.
    """

    path: str
    start_ns: int
    topics: tuple[_TopicClocks, ...]

    def base(self, tolerance_s: float) -> StampBase:
        """The clock the windows are timed by, and the first stamp in it.

        Every source stamped by its header: the header stamps, counted from the earliest of
        the map's topics' first header stamps. Every source stamped by the log time: the
        log times, counted from the bag's first log time. A mixture: accepted where, on each
        topic stamped by its header, the log times lie within ``tolerance_s`` of the header
        stamps (median over its first messages), counted from the bag's first log time;
        refused otherwise.

        Args:
            tolerance_s: how far the two clocks may disagree (s): the distance a stamp may
                lie from its grid point (``jitter_fraction * ts_s``), beyond which the same
                instant lands on different samples in the two clocks.

        Raises:
            TimeBaseError: a mixture whose clocks disagree by more than ``tolerance_s`` (the
                message names the topics, the offset and the fix).
        """
        header = [c for c in self.topics if c.header]
        logged = [c.topic for c in self.topics if not c.header]
        offsets = [
            float(np.median(c.log_ns - c.header_ns)) / NS_PER_S
            for c in header
            if c.header_ns is not None
        ]
        worst = max(offsets, key=abs, default=None)
        apart = worst is not None and abs(worst) > tolerance_s
        if header and logged:
            if apart:
                raise TimeBaseError(
                    f"{self.path}: the interface map times {_names([c.topic for c in header])} "
                    f"by the header stamps and {_names(logged)} by the bag's log times, and in "
                    f"this bag the two clocks differ by {worst:.6g} s (log time minus header "
                    f"stamp), more than the {tolerance_s:.3g} s a stamp may lie from its sample "
                    "(e.g. header stamps on a simulated clock, log times on the wall clock): "
                    "the windows need one time base. Stamp every source by its log time "
                    "('stamp: receive' in the map) if the recorder ran on the data's clock, or "
                    f"record {_names(logged)} in a type with a header stamped on the clock of "
                    "the others"
                )
            return StampBase(TimeBase.HEADER_AND_LOG, self.start_ns, worst)
        if not header:
            return StampBase(TimeBase.LOG, self.start_ns, worst)
        # (a topic without a header is the map's error, which the replay reports)
        origin = min(
            (int(np.min(c.header_ns)) for c in header if c.header_ns is not None),
            default=self.start_ns,
        )
        note = None
        if apart:
            note = (
                f"windows timed by the header stamps, in s from the first ({origin / NS_PER_S:.9g}"
                f" s); the bag's log times lie {worst:.6g} s from them (another clock: a "
                "recorder on the wall clock, a run on a simulated one) and are not used"
            )
        return StampBase(TimeBase.HEADER, origin, worst, note)


def bag_clocks(bag: bag_reader.BagReader, imap: InterfaceMap) -> BagClocks:
    """The first messages' clocks of each of the map's topics (:data:`SCAN_MESSAGES` each)."""
    topics = tuple(
        c
        for name, sources in message_sources(imap).items()
        if (c := _first_clocks(bag, name, sources.bindings[0].source.stamp == STAMP_HEADER))
        is not None
    )
    return BagClocks(str(bag.info.path), int(bag.info.start_ns or 0), topics)


def stamp_base(bag: bag_reader.BagReader, imap: InterfaceMap, tolerance_s: float) -> StampBase:
    """The clock a bag's windows are timed by, and the first stamp in it (:meth:`BagClocks.base`).

    Raises:
        TimeBaseError: as :meth:`BagClocks.base`.
    """
    return bag_clocks(bag, imap).base(tolerance_s)
