"""Pace a replay's reports at a multiple of real time (``--replay-speed``)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from twotank_validation.online.window import WindowReport


class Pacer:
    """Hold each report back until its window's end is due at ``speed`` times real time.

    The first report sets the origin; a later one waits until ``(end - first end) / speed``
    wall seconds have passed since. Reports of one window (one per model) go together. The
    pacing is per report because that is what the page shows; the samples between two
    reports are validated as fast as they come.

    Args:
        speed: data seconds per wall second (> 0); ``inf``: no pacing.
        sleep: the wait (tests pass a fake).
        clock: a monotonic clock (s).
    """

    def __init__(
        self,
        speed: float = math.inf,
        *,
        sleep: Callable[[float], None] = time.sleep,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not speed > 0:
            raise ValueError(f"replay speed {speed} must be > 0 (data seconds per wall second)")
        self.speed = speed
        self._sleep = sleep
        self._clock = clock
        self._origin: tuple[float, int] | None = None

    def __call__(self, rep: WindowReport) -> None:
        """Wait until ``rep`` is due."""
        if math.isinf(self.speed):
            return
        if self._origin is None:
            self._origin = (self._clock(), rep.end_ns)
            return
        wall0, end0 = self._origin
        wait = wall0 + (rep.end_ns - end0) / 1e9 / self.speed - self._clock()
        if wait > 0:
            self._sleep(wait)
