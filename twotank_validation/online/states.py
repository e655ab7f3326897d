"""A window's typed states: what invalidated it, and why it was (not) judged.

The report's texts (``WindowReport.raised_by``, ``WindowReport.data_quality``) are for
humans; what a program counts or branches on is typed here, set where the state arises and
never parsed back from the words:

* :class:`RaisedBy`: what made a judged window invalidating. A ``StrEnum`` whose value is the
  text every output shows (``""``, ``"dynamics"``, ``"operating point"``, ``"dynamics and
  operating point"``).
* :class:`WindowState`: why a window was judged or not (ok, recovered, unusable samples,
  settling, input not periodic, too little excitation, datum rejected), and
  :class:`SampleFlag`, the kind of the first unusable sample; together a
  :class:`WindowQuality` (``WindowReport.quality``), whose :attr:`~WindowQuality.category`
  is the key of the replay summary's ``not_judged_reasons``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import StrEnum


class RaisedBy(StrEnum):
    """What made a judged window invalidating; its value is the report's text."""

    NONE = ""
    """Valid, or not judged."""
    DYNAMICS = "dynamics"
    OPERATING_POINT = "operating point"
    BOTH = "dynamics and operating point"
    """Both above 1, or each below 1 and together above (``beta_total`` > 1)."""

    @property
    def parts(self) -> frozenset[RaisedBy]:
        """The single causes it holds (``BOTH``: dynamics and operating point)."""
        if self is RaisedBy.BOTH:
            return frozenset((RaisedBy.DYNAMICS, RaisedBy.OPERATING_POINT))
        return frozenset() if self is RaisedBy.NONE else frozenset((self,))

    @property
    def dynamics(self) -> bool:
        """The dynamics took part."""
        return RaisedBy.DYNAMICS in self.parts

    @property
    def operating_point(self) -> bool:
        """The operating point took part."""
        return RaisedBy.OPERATING_POINT in self.parts

    @classmethod
    def of(cls, parts: Iterable[RaisedBy]) -> RaisedBy:
        """The cause that holds all of ``parts`` (``NONE`` for none)."""
        held = frozenset(p for part in parts for p in RaisedBy(part).parts)
        return next(r for r in cls if r.parts == held)


class WindowState(StrEnum):
    """Why a window was judged or not; the value is the start of its ``data_quality``."""

    OK = "ok"
    """Judged on the samples as they came."""
    RECOVERED = "recovered"
    """Judged, with unusable samples recovered from the other periods."""
    UNUSABLE_SAMPLES = "unusable samples"
    """Not judged: unusable samples (flagged or held commands) not recovered."""
    SETTLING = "settling"
    """Not judged: fewer periods of periodic input than the window and its settling need."""
    INPUT_NOT_PERIODIC = "input not periodic"
    """Not judged: an input changes from one period to the next."""
    TOO_LITTLE_EXCITATION = "too little excitation"
    """Not judged: the inputs' RMS is below ``min_excitation_rms``."""
    DATUM_REJECTED = "datum rejected"
    """Not judged: the datum's checks refused the window."""

    @property
    def judged(self) -> bool:
        """A window in this state is judged."""
        return self in (WindowState.OK, WindowState.RECOVERED)


class SampleFlag(StrEnum):
    """The kind of an unusable sample, from the aligner's flag."""

    GAP = "gap"
    OFF_GRID = "off grid"
    NO_COMMAND = "no command"
    NON_FINITE = "non-finite"
    FLAGGED = "flagged"
    """Any other flag, or none (a held command)."""

    @classmethod
    def of(cls, flag: str | None) -> SampleFlag:
        """The kind of an aligner's sample flag; ``FLAGGED`` for any other text or none.

        The first match of :data:`FLAG_WORDS` in the flag's words. The aligner flags a
        sample in words (``"gap: no height sample at t = ..."``); they are classified here,
        once, where the window's state is set.
        """
        if flag is None:
            return cls.FLAGGED
        return next((kind for words, kind in FLAG_WORDS if words in flag), cls.FLAGGED)


FLAG_WORDS: tuple[tuple[str, SampleFlag], ...] = (
    ("gap", SampleFlag.GAP),
    ("off the sample grid", SampleFlag.OFF_GRID),
    ("non-finite valve", SampleFlag.NO_COMMAND),
    ("no valid valve command", SampleFlag.NO_COMMAND),
    ("non-finite", SampleFlag.NON_FINITE),
    ("implausible", SampleFlag.NON_FINITE),
)
"""Words of the aligner's sample flags -> their kind, the first match counts."""


@dataclass(frozen=True)
class WindowQuality:
    """A window's state with its detail (``WindowReport.quality``).

    Attributes:
        state: why it was judged or not.
        flag: for ``UNUSABLE_SAMPLES``, the kind of the first flagged sample (``FLAGGED``
            where none was flagged: held commands); None otherwise.
    """

    state: WindowState
    flag: SampleFlag | None = None

    @property
    def category(self) -> str:
        """The kind of reason, for counting: ``"settling"``, ``"unusable samples (gap)"``."""
        if self.state is WindowState.UNUSABLE_SAMPLES:
            return f"{self.state} ({self.flag or SampleFlag.FLAGGED})"
        return self.state.value


QUALITY_OK = WindowQuality(WindowState.OK)
"""The quality of a window judged on its samples as they came."""
