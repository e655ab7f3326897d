"""The debounced alarm: per-window raw verdicts in, an alarm level out.

:func:`update_alarm` debounces the raw per-window verdicts into the alarm level; the levels
equal diagnostic_msgs/DiagnosticStatus levels.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace


class Alarm(enum.IntEnum):
    """Alarm levels, equal to diagnostic_msgs/DiagnosticStatus levels."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class AlarmConfig:
    """Debouncing of the raw verdicts.

    Attributes:
        alarm_windows: consecutive invalidating windows that raise ERROR.
        clear_windows: consecutive valid windows that clear ERROR.
        warn_beta: beta at or above which a valid window reports WARN.
        latch: keep ERROR until :func:`reset_alarm` even after valid windows.
    """

    alarm_windows: int = 2
    clear_windows: int = 3
    warn_beta: float = 0.8
    latch: bool = False

    def __post_init__(self) -> None:
        if self.alarm_windows < 1 or self.clear_windows < 1:
            raise ValueError(
                f"alarm_windows and clear_windows must be >= 1, found {self.alarm_windows}, "
                f"{self.clear_windows}"
            )
        if not (math.isfinite(self.warn_beta) and self.warn_beta > 0):
            raise ValueError(f"warn_beta must be positive and finite, found {self.warn_beta}")


@dataclass(frozen=True)
class AlarmState:
    """Debounce counters and the current level.

    Attributes:
        level: level of the last window.
        in_error: an ERROR is active (raised and not yet cleared or reset).
        invalid_run: consecutive invalidating judged windows.
        valid_run: consecutive valid judged windows.
    """

    level: Alarm = Alarm.OK
    in_error: bool = False
    invalid_run: int = 0
    valid_run: int = 0


def update_alarm(
    state: AlarmState, config: AlarmConfig, *, judged: bool, invalidated: bool, beta: float
) -> AlarmState:
    """Next alarm state after one window.

    A window that was not judged leaves the counters alone and reports STALE. A judged window
    extends the run of its verdict; ERROR rises after ``alarm_windows`` invalidating windows in
    a row and clears after ``clear_windows`` valid ones (never, while latched). Otherwise WARN
    when ``beta >= warn_beta``, else OK.
    """
    if not judged:
        return replace(state, level=Alarm.STALE)
    if invalidated:
        invalid_run, valid_run = state.invalid_run + 1, 0
    else:
        invalid_run, valid_run = 0, state.valid_run + 1
    in_error = state.in_error
    if invalid_run >= config.alarm_windows:
        in_error = True
    elif in_error and not config.latch and valid_run >= config.clear_windows:
        in_error = False
    if in_error:
        level = Alarm.ERROR
    elif beta >= config.warn_beta:
        level = Alarm.WARN
    else:
        level = Alarm.OK
    return AlarmState(level=level, in_error=in_error, invalid_run=invalid_run, valid_run=valid_run)


def reset_alarm(state: AlarmState) -> AlarmState:
    """Clear a (latched) ERROR and the counters; the next window decides the level."""
    return AlarmState(level=Alarm.OK if state.level == Alarm.ERROR else state.level)
