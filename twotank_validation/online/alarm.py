"""The debounced alarm: per-window raw verdicts in, an alarm level out.

:func:`update_alarm` debounces the raw per-window verdicts into the alarm level; the levels
equal diagnostic_msgs/DiagnosticStatus levels. Two rules (``AlarmConfig.debounce``):

* ``"count"``: ERROR after ``alarm_windows`` invalidating windows in a row;
* ``"sequential"``: a one-sided CUSUM (Page 1954) on the window's β: the evidence
  ``S = min(A, max(0, S + (β − 1) w))`` grows by the excess of β over 1 and shrinks by its
  shortfall, each window weighted by the share of a period it adds (``w = hop / period``)
  and capped at the threshold ``A = evidence``; ERROR rises once ``S`` reaches ``A`` on an
  invalidating window. Weighted by time, the evidence of a β path does not depend on how
  often it is sampled (docs/theory.md §9).

Both clear after ``clear_windows`` valid windows in a row. OK means judged valid in every
respect: after an invalidating window the level returns to OK only through the clear rule's
valid windows, and never while the operating point cannot be checked since the model was
invalidated (``unchecked``: the reference was not commissioned before the fault,
:class:`~twotank_validation.online.op_tracker.OpState` ``SUSPENDED``).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

from twotank_validation.settings import check_settings, setting


class Alarm(enum.IntEnum):
    """Alarm levels, equal to diagnostic_msgs/DiagnosticStatus levels."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


DEBOUNCE_RULES = ("count", "sequential")
"""The debounce rules of :class:`AlarmConfig`."""


@dataclass(frozen=True)
class AlarmConfig:
    """Debouncing of the raw verdicts.

    Attributes:
        alarm_windows: consecutive invalidating windows that raise ERROR.
        clear_windows: consecutive valid windows that clear ERROR.
        warn_beta: beta at or above which a valid window reports WARN.
        latch: keep ERROR until :func:`reset_alarm` even after valid windows.
        debounce: ``"count"`` (``alarm_windows`` in a row) or ``"sequential"`` (the CUSUM
            of the excess of β over 1 reaches ``evidence``).
        evidence: the sequential rule's threshold, in periods times excess β (0.1: one
            period's window at β 1.1, or a quarter period at β 1.4).
    """

    alarm_windows: int = setting(
        2, "consecutive invalidating windows that raise ERROR", low=1, high=1000
    )
    clear_windows: int = setting(3, "consecutive valid windows that clear ERROR", low=1, high=1000)
    warn_beta: float = setting(
        0.8, "beta at or above which a valid window reports WARN", low=1e-6, high=1e6
    )
    latch: bool = setting(
        False, "keep ERROR until the reset_alarm service is called", name="latch_alarm"
    )
    debounce: str = setting(
        "sequential",
        "count: ERROR after alarm_windows invalidating windows in a row; sequential: after "
        "the CUSUM of the excess of beta over 1 (weighted by hop/period) reaches alarm_evidence",
        choices=DEBOUNCE_RULES,
        option="--debounce",
        cli_help="count: ERROR after {alarm_windows} invalidating windows in a row; sequential: "
        "after the CUSUM of beta's excess over 1 (weighted by hop/period) reaches "
        "{alarm_evidence}",
    )
    evidence: float = setting(
        0.1,
        "the sequential debounce's threshold (periods times excess beta)",
        unit="periods",
        low=1e-6,
        high=1e6,
        name="alarm_evidence",
    )

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class AlarmState:
    """Debounce counters and the current level.

    Attributes:
        level: level of the last window.
        in_error: an ERROR is active (raised and not yet cleared or reset).
        invalid_run: consecutive invalidating judged windows.
        valid_run: consecutive valid judged windows.
        evidence: the sequential rule's CUSUM ``S`` (0 under the count rule).
        unsettled: a judged window invalidated the model and the clear rule's run of valid
            judged windows has not followed yet: the level is at least WARN (a fault may be
            active while the windows after it go unjudged or pass the gate one by one).
    """

    level: Alarm = Alarm.OK
    in_error: bool = False
    invalid_run: int = 0
    valid_run: int = 0
    evidence: float = 0.0
    unsettled: bool = False


def update_alarm(
    state: AlarmState,
    config: AlarmConfig,
    *,
    judged: bool,
    invalidated: bool,
    beta: float,
    weight: float = 1.0,
    unchecked: bool = False,
    hold: bool = False,
) -> AlarmState:
    """Next alarm state after one window.

    A window that was not judged leaves the counters alone and reports STALE. A judged window
    extends the run of its verdict; ERROR rises after ``alarm_windows`` invalidating windows in
    a row (the count rule) or once the CUSUM of ``(beta - 1) weight`` reaches ``evidence`` on
    an invalidating window (the sequential rule), and clears after ``clear_windows`` valid
    ones (never, while latched). Otherwise WARN when ``beta >= warn_beta`` or while the
    model stands invalidated by a judged window without the clear rule's valid windows since
    (``AlarmState.unsettled``: the level returns to OK only through them, as ERROR clears)
    or while ``unchecked``, else OK.

    Args:
        state: the state after the previous window.
        config: the debounce.
        judged: the window was fit to judge.
        invalidated: its raw verdict.
        beta: its β (the one the verdict compares with 1).
        weight: the share of a period the window adds to the evidence (hop / period).
        unchecked: part of the verdict could not be judged since the model was invalidated
            (the operating point: its reference suspended): the window is valid in what was
            judged, so it counts towards clearing ERROR, but the level stays at least WARN.
        hold: the window was judged by the weaker of two tests (the transient term where
            the periodicity gate failed, ``transient: auto``): invalidating, it counts as any;
            valid while ERROR stands, it is no evidence of a recovery and leaves the state
            as it is (docs/theory.md §20).
    """
    if not judged:
        return replace(state, level=Alarm.STALE)
    if hold and state.in_error and not invalidated:
        return replace(state, level=Alarm.ERROR)
    if invalidated:
        invalid_run, valid_run = state.invalid_run + 1, 0
    else:
        invalid_run, valid_run = 0, state.valid_run + 1
    evidence = 0.0
    if config.debounce == "sequential":
        excess = beta - 1.0 if math.isfinite(beta) else (1.0 if invalidated else -1.0)
        # capped at the threshold: evidence beyond it proves nothing more, and a CUSUM that
        # grew through an hour-long fault would re-raise ERROR on one window hours later
        evidence = min(config.evidence, max(0.0, state.evidence + excess * weight))
        raise_now = invalidated and evidence >= config.evidence
    else:
        raise_now = invalid_run >= config.alarm_windows
    in_error = state.in_error
    if raise_now:
        in_error = True
    elif in_error and not config.latch and valid_run >= config.clear_windows:
        in_error = False
    unsettled = invalidated or (state.unsettled and valid_run < config.clear_windows)
    if in_error:
        level = Alarm.ERROR
    elif beta >= config.warn_beta or unsettled or unchecked:
        level = Alarm.WARN
    else:
        level = Alarm.OK
    return AlarmState(
        level=level,
        in_error=in_error,
        invalid_run=invalid_run,
        valid_run=valid_run,
        evidence=evidence,
        unsettled=unsettled,
    )


def reset_alarm(state: AlarmState) -> AlarmState:
    """Clear a (latched) ERROR and the counters; the next window decides the level."""
    return AlarmState(level=Alarm.OK if state.level == Alarm.ERROR else state.level)
