"""The supervisor: the validator's alarm in, the controller's mode out (a pure state machine).

The supervisor decides whether the control loop runs in ``NORMAL`` or in ``SAFE`` mode from
what the validator publishes for the *watched* models: each model's ``invalidated`` flag (the
debounced alarm is ERROR) and the arrival of its window reports. Time is the validator's
clock: report stamps (the end of the window each speaks of) and the current time, both in
seconds (simulated time in a simulation). The ROS node
(:mod:`twotank_validation.ros.supervisor_node`) only turns messages into :data:`Event` values
and the current time into :func:`step` calls.

The rules, evaluated at every event (the node adds a :class:`Tick` every ``check_period_s``):

* **Faults.** For each watched model, in the configured order: *invalidated* while its last
  flag is true (``"invalidated: model B"``); *stale* when its newest report stamp is more than
  ``stale_after_s`` before now, or, before its first report, when more than
  ``startup_grace_s`` have passed since the supervisor started (its first event)
  (``"stale: no report from B for 181.0 s"``, the age from the start if none came yet);
  *unjudged* when it is not stale but its newest judged report is more than
  ``unjudged_after_s`` old (from the start, and at least ``startup_grace_s``, if none was
  judged yet): the validator is alive but cannot check the model
  (``"unjudged: no judged window of B for 1850.0 s"``).
  Flags and reports of models that are not watched are ignored.
* **Entering SAFE.** In NORMAL, any fault switches to SAFE at once (the validator has already
  debounced the alarm); the transition's reason is the faults' texts joined by ``"; "``. With
  ``latch`` the SAFE mode is latched.
* **Hysteresis.** The validator is *good* while there is no fault. SAFE returns to NORMAL at
  the first event at which it has been good for at least ``clear_after_s`` without a break
  *and* each watched model has delivered at least ``clear_reports`` judged reports in that
  good spell (the report that starts the spell, e.g. the first after a silence, counts; a
  window the validator could not judge is no evidence that the model holds), and it is not
  latched. Reason: ``"recovered: valid for 210.0 s and 3 report(s) of each watched model"``.
* **Reset** (:class:`Reset`) clears the latch only when there is no fault: a reset while a
  fault is present is refused (counted; the mode and latch stay); an accepted reset returns
  to NORMAL in the same step if the hysteresis is already satisfied (reason prefixed
  ``"reset and "``), otherwise the hysteresis still runs. A reset in NORMAL is accepted and
  changes nothing.
* **Clock restart** (:class:`Restart`, a backward jump of the clock): the report times, the
  good spell and the start are forgotten (the startup grace applies again); the mode, the
  latch, the flags and the counters are kept. Time otherwise never goes backwards:
  :func:`step` refuses it (:class:`SupervisorError`).

:func:`false_transitions` replays a sequence of reports through the supervisor (the node's
tick included) and counts the transitions that a known fault schedule does not explain: on
nominal data every switch to SAFE is a false one.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

from twotank_validation.defaults import NS_PER_S
from twotank_validation.errors import TwotankError
from twotank_validation.online.alarm import Alarm
from twotank_validation.online.window import WindowReport


class SupervisorError(TwotankError, ValueError):
    """A supervisor setting or event is invalid; the message names it and the fix."""


class Mode(enum.Enum):
    """The control loop's mode; the value is what ``control/mode`` carries."""

    NORMAL = "normal"
    SAFE = "safe"


INVALIDATED = "invalidated"
STALE = "stale"
UNJUDGED = "unjudged"
"""The kinds of fault."""


@dataclass(frozen=True)
class SupervisorConfig:
    """What the supervisor watches and how it switches.

    Attributes:
        watched: names of the models whose alarm it acts on (at least one, no repeats).
        clear_after_s: time (s, validator clock) the validator must stay good before SAFE
            returns to NORMAL.
        clear_reports: reports each watched model must deliver in that good spell.
        latch: stay SAFE until an accepted reset (as well as the hysteresis).
        stale_after_s: a watched model whose newest report stamp is older than this (s) is a
            fault; it must exceed the validator's report interval (a window every hop).
        startup_grace_s: time (s) after the supervisor's first event within which a model that
            has not reported yet is not stale (the validator's first window takes a few
            periods).
        unjudged_after_s: a watched model that keeps reporting but whose newest *judged*
            report is older than this (s) is a fault: the validator is alive but blind (no
            excitation, a valve at its limit, gaps), so the model is not being checked. It
            must exceed the unjudged spells of normal operation (a setpoint change leaves
            the windows spanning the move unjudged); ``inf`` switches the rule off.
    """

    watched: tuple[str, ...] = ("B",)
    clear_after_s: float = 204.8
    clear_reports: int = 2
    latch: bool = False
    stale_after_s: float = 180.0
    startup_grace_s: float = 900.0
    unjudged_after_s: float = 1800.0

    def __post_init__(self) -> None:
        if not self.watched:
            raise SupervisorError("watch at least one model (e.g. watched=('B',))")
        if any(not isinstance(m, str) or not m for m in self.watched):
            raise SupervisorError(f"model names must be non-empty strings, found {self.watched}")
        if len(set(self.watched)) != len(self.watched):
            raise SupervisorError(f"a watched model is named twice: {self.watched}")
        for name in ("clear_after_s", "startup_grace_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise SupervisorError(f"{name} must be finite and >= 0 (s), found {value}")
        if not (math.isfinite(self.stale_after_s) and self.stale_after_s > 0):
            raise SupervisorError(
                f"stale_after_s must be finite and > 0 (s), found {self.stale_after_s}"
            )
        if not (self.unjudged_after_s > 0):  # inf allowed: the rule off
            raise SupervisorError(
                f"unjudged_after_s must be > 0 (s; inf: off), found {self.unjudged_after_s}"
            )
        if self.clear_reports < 0:
            raise SupervisorError(f"clear_reports must be >= 0, found {self.clear_reports}")


# ------------------------------------------------------------------------------- events


@dataclass(frozen=True)
class Invalidated:
    """A model's ``invalidated`` flag (its debounced alarm is ERROR) was received."""

    model: str
    value: bool


@dataclass(frozen=True)
class Report:
    """A model's window report arrived; ``stamp_s`` is its stamp (end of its window, s).

    ``judged`` false: the window was not fit to judge (gaps, a transient, too little
    excitation): it shows the validator is alive, but it is no evidence that the model holds,
    so it does not count towards the reports that clear SAFE.
    """

    model: str
    stamp_s: float
    judged: bool = True


@dataclass(frozen=True)
class Reset:
    """A reset request (clears the latch when there is no fault)."""


@dataclass(frozen=True)
class Tick:
    """Time passed (the staleness and hysteresis are checked)."""


@dataclass(frozen=True)
class Restart:
    """The clock restarted (jumped backwards): forget report times, the good spell, the start."""


Event = Invalidated | Report | Reset | Tick | Restart


# ------------------------------------------------------------------------------- state


@dataclass(frozen=True)
class Transition:
    """One mode change: when (s), from, to and why."""

    time_s: float
    from_mode: Mode
    to_mode: Mode
    reason: str


@dataclass(frozen=True)
class Counters:
    """Counts since the supervisor started.

    Attributes:
        to_safe: switches NORMAL -> SAFE.
        to_normal: switches SAFE -> NORMAL.
        invalidated: switches to SAFE with an invalidated model among the reasons.
        stale: switches to SAFE with a stale model among the reasons.
        unjudged: switches to SAFE with an unjudged model among the reasons.
        resets_accepted: reset requests accepted.
        resets_refused: reset requests refused (a fault was present).
    """

    to_safe: int = 0
    to_normal: int = 0
    invalidated: int = 0
    stale: int = 0
    unjudged: int = 0
    resets_accepted: int = 0
    resets_refused: int = 0

    @property
    def transitions(self) -> int:
        """All mode changes."""
        return self.to_safe + self.to_normal


@dataclass(frozen=True)
class SupervisorState:
    """Everything the supervisor knows (replaced whole by :func:`step`, never changed in place).

    Attributes:
        mode: the current mode.
        reason: the reason of the last transition (``"start"`` before any).
        latched: SAFE is latched (waits for an accepted reset).
        faults: the current faults, ``(kind, model)`` in watched order, invalidated before
            stale or unjudged.
        invalidated: the watched models whose last flag is true.
        last_report_s: per watched model, its newest report stamp (s); absent before any.
        last_judged_s: per watched model, its newest judged report's stamp (s).
        good_since_s: start of the current good spell (no fault), None while a fault is present.
        good_reports: per watched model, reports received in the current good spell.
        start_s: time of the first event (or of the last clock restart); None before any.
        now_s: time of the last event; None before any.
        counters: transition and reset counts.
        last_reset: the answer to the last reset request (``""`` before any).
    """

    mode: Mode = Mode.NORMAL
    reason: str = "start"
    latched: bool = False
    faults: tuple[tuple[str, str], ...] = ()
    invalidated: frozenset[str] = frozenset()
    last_report_s: dict[str, float] = field(default_factory=dict)
    last_judged_s: dict[str, float] = field(default_factory=dict)
    good_since_s: float | None = None
    good_reports: dict[str, int] = field(default_factory=dict)
    start_s: float | None = None
    now_s: float | None = None
    counters: Counters = Counters()
    last_reset: str = ""


def judged_age_s(state: SupervisorState, model: str, now_s: float) -> float:
    """Seconds since the model's newest judged report stamp, or since the start if none."""
    last = state.last_judged_s.get(model)
    ref = last if last is not None else state.start_s
    return now_s - (ref if ref is not None else now_s)


def report_age_s(state: SupervisorState, model: str, now_s: float) -> float:
    """Seconds since the model's newest report stamp, or since the start if none came yet."""
    last = state.last_report_s.get(model)
    ref = last if last is not None else state.start_s
    return now_s - (ref if ref is not None else now_s)


def _faults(
    state: SupervisorState, config: SupervisorConfig, now_s: float
) -> tuple[tuple[str, str], ...]:
    out: list[tuple[str, str]] = []
    for m in config.watched:
        if m in state.invalidated:
            out.append((INVALIDATED, m))
        limit = config.stale_after_s if m in state.last_report_s else config.startup_grace_s
        if report_age_s(state, m, now_s) > limit:
            out.append((STALE, m))
        elif m in state.last_report_s:
            limit = config.unjudged_after_s
            if m not in state.last_judged_s:
                limit = max(limit, config.startup_grace_s)
            if judged_age_s(state, m, now_s) > limit:
                out.append((UNJUDGED, m))
    return tuple(out)


def fault_text(state: SupervisorState, now_s: float) -> str:
    """The current faults as text, ``"; "``-joined (``""`` when there is none)."""
    parts = []
    for kind, m in state.faults:
        if kind == INVALIDATED:
            parts.append(f"invalidated: model {m}")
        elif kind == UNJUDGED:
            parts.append(
                f"unjudged: no judged window of {m} for {judged_age_s(state, m, now_s):.1f} s"
            )
        else:
            parts.append(f"stale: no report from {m} for {report_age_s(state, m, now_s):.1f} s")
    return "; ".join(parts)


def _recovered(state: SupervisorState, config: SupervisorConfig, now_s: float) -> bool:
    if state.mode is not Mode.SAFE or state.faults or state.latched:
        return False
    if state.good_since_s is None or now_s - state.good_since_s < config.clear_after_s:
        return False
    return all(state.good_reports.get(m, 0) >= config.clear_reports for m in config.watched)


def step(
    state: SupervisorState, config: SupervisorConfig, now_s: float, event: Event
) -> tuple[SupervisorState, Transition | None]:
    """The supervisor's state after one event at time ``now_s``, and the transition it made.

    Args:
        state: the state before the event.
        config: the rules' settings.
        now_s: the current time (s, validator clock), not before the previous event's.
        event: what happened.

    Returns:
        The new state and the mode change (None if the mode stayed).

    Raises:
        SupervisorError: time went backwards (use :class:`Restart` after a clock jump) or a
            time or stamp is not finite.
    """
    if not math.isfinite(now_s):
        raise SupervisorError(f"the current time must be finite, found {now_s}")
    if isinstance(event, Restart):
        state = replace(
            state,
            last_report_s={},
            last_judged_s={},
            good_since_s=None,
            good_reports={},
            start_s=now_s,
        )
    elif state.now_s is not None and now_s < state.now_s:
        raise SupervisorError(
            f"time went back from {state.now_s} s to {now_s} s: send a Restart event after a "
            "clock jump"
        )
    if state.start_s is None:
        state = replace(state, start_s=now_s)
    state = replace(state, now_s=now_s)
    watched = isinstance(event, Invalidated | Report) and event.model in config.watched
    if watched and isinstance(event, Invalidated):
        flags = (
            state.invalidated | {event.model} if event.value else state.invalidated - {event.model}
        )
        state = replace(state, invalidated=flags)
    elif watched and isinstance(event, Report):
        if not math.isfinite(event.stamp_s):
            raise SupervisorError(f"report stamp of {event.model} is not finite: {event.stamp_s}")
        last = state.last_report_s.get(event.model, -math.inf)
        state = replace(
            state, last_report_s={**state.last_report_s, event.model: max(last, event.stamp_s)}
        )
        if event.judged:
            last = state.last_judged_s.get(event.model, -math.inf)
            judged = {**state.last_judged_s, event.model: max(last, event.stamp_s)}
            state = replace(state, last_judged_s=judged)

    faults = _faults(state, config, now_s)
    state = replace(state, faults=faults)
    if faults:
        state = replace(state, good_since_s=None, good_reports={})
    else:
        if state.good_since_s is None:
            state = replace(state, good_since_s=now_s, good_reports={})
        if watched and isinstance(event, Report) and event.judged:
            n = state.good_reports.get(event.model, 0) + 1
            state = replace(state, good_reports={**state.good_reports, event.model: n})

    prefix = ""
    if isinstance(event, Reset):
        c = state.counters
        if faults:
            state = replace(
                state,
                counters=replace(c, resets_refused=c.resets_refused + 1),
                last_reset=f"refused: {fault_text(state, now_s)}",
            )
        else:
            answer = "latch cleared" if state.latched else f"{state.mode.value}: nothing latched"
            state = replace(
                state,
                latched=False,
                counters=replace(c, resets_accepted=c.resets_accepted + 1),
                last_reset=answer,
            )
            prefix = "reset and "

    if state.mode is Mode.NORMAL and faults:
        reason = fault_text(state, now_s)
        kinds = {kind for kind, _ in faults}
        c = state.counters
        counters = replace(
            c,
            to_safe=c.to_safe + 1,
            invalidated=c.invalidated + (INVALIDATED in kinds),
            stale=c.stale + (STALE in kinds),
            unjudged=c.unjudged + (UNJUDGED in kinds),
        )
        tr = Transition(now_s, Mode.NORMAL, Mode.SAFE, reason)
        return replace(
            state, mode=Mode.SAFE, reason=reason, latched=config.latch, counters=counters
        ), tr
    if _recovered(state, config, now_s):
        assert state.good_since_s is not None  # _recovered checked it
        n = min(state.good_reports.get(m, 0) for m in config.watched)
        reason = (
            f"{prefix}recovered: valid for {now_s - state.good_since_s:.1f} s and {n} report(s) "
            "of each watched model"
        )
        c = state.counters
        tr = Transition(now_s, Mode.SAFE, Mode.NORMAL, reason)
        return replace(
            state,
            mode=Mode.NORMAL,
            reason=reason,
            counters=replace(c, to_normal=c.to_normal + 1),
        ), tr
    return state, None


class Supervisor:
    """The state machine with its transition log: what the node holds.

    Attributes:
        config: the rules' settings.
        state: the current state.
        log: every transition, oldest first.
    """

    def __init__(self, config: SupervisorConfig) -> None:
        self.config = config
        self.state = SupervisorState()
        self.log: list[Transition] = []

    def step(self, now_s: float, event: Event) -> Transition | None:
        """Apply one event at ``now_s`` (see :func:`step`); the transition is also logged."""
        self.state, tr = step(self.state, self.config, now_s, event)
        if tr is not None:
            self.log.append(tr)
        return tr

    def reset(self, now_s: float) -> tuple[bool, str]:
        """A reset request: (accepted, the answer's text, with the transition it made)."""
        before = self.state.counters.resets_accepted
        tr = self.step(now_s, Reset())
        accepted = self.state.counters.resets_accepted > before
        answer = self.state.last_reset + (f"; {tr.to_mode.value}: {tr.reason}" if tr else "")
        return accepted, answer

    @property
    def mode(self) -> Mode:
        """The current mode."""
        return self.state.mode

    @property
    def counters(self) -> Counters:
        """Transition and reset counts."""
        return self.state.counters


# ------------------------------------------------------------------------------- replay


@dataclass(frozen=True)
class ReportRecord:
    """One report as the supervisor sees it.

    Stamp (s), model, the model's flag after it, and whether the window was judged.
    """

    stamp_s: float
    model: str
    invalidated: bool
    judged: bool = True


def report_records(reports: Iterable[WindowReport]) -> list[ReportRecord]:
    """The records of window reports, as the validator node publishes them.

    The node publishes each report, then the model's ``invalidated`` flag, true exactly while
    the report's debounced alarm is ERROR.
    """
    return [
        ReportRecord(r.end_ns / NS_PER_S, r.model, r.alarm is Alarm.ERROR, r.judged)
        for r in reports
    ]


def replay(
    records: Sequence[ReportRecord],
    config: SupervisorConfig,
    *,
    tick_s: float = 1.0,
    end_s: float | None = None,
) -> Supervisor:
    """Run report records through a supervisor, as the node receives them.

    Each record arrives at its stamp: a :class:`Report`, then its :class:`Invalidated` flag.
    Ticks come every ``tick_s`` from the first stamp (the node's staleness timer), up to the
    last stamp or ``end_s``.

    Args:
        records: the reports, in any order (sorted by stamp, stably).
        config: the supervisor's settings.
        tick_s: the timer's period (s), > 0.
        end_s: tick on until this time (s); None: stop at the last record.

    Raises:
        SupervisorError: ``tick_s`` not positive, or a stamp not finite.
    """
    if not (math.isfinite(tick_s) and tick_s > 0):
        raise SupervisorError(f"tick_s must be finite and > 0, found {tick_s}")
    recs = sorted(records, key=lambda r: r.stamp_s)
    sup = Supervisor(config)
    if not recs:
        return sup
    t0 = recs[0].stamp_s
    if not math.isfinite(t0) or not math.isfinite(recs[-1].stamp_s):
        raise SupervisorError("report stamps must be finite")
    k = 1
    for rec in recs:
        while t0 + k * tick_s < rec.stamp_s:
            sup.step(t0 + k * tick_s, Tick())
            k += 1
        sup.step(rec.stamp_s, Report(rec.model, rec.stamp_s, rec.judged))
        sup.step(rec.stamp_s, Invalidated(rec.model, rec.invalidated))
    if end_s is not None:
        while t0 + k * tick_s <= end_s:
            sup.step(t0 + k * tick_s, Tick())
            k += 1
    return sup


@dataclass(frozen=True)
class FalseTransitions:
    """Transitions a fault schedule does not explain.

    Attributes:
        false_safe: switches to SAFE outside every fault interval (extended by the lag).
        false_normal: returns to NORMAL while a fault is active.
        transitions: every transition of the run.
        duration_s: the span of the replay (first stamp to last stamp or ``end_s``), s.
    """

    false_safe: tuple[Transition, ...]
    false_normal: tuple[Transition, ...]
    transitions: tuple[Transition, ...]
    duration_s: float

    @property
    def count(self) -> int:
        """All false transitions."""
        return len(self.false_safe) + len(self.false_normal)

    @property
    def per_24h(self) -> float:
        """False transitions per 24 hours of the replayed span (NaN for an empty span)."""
        return self.count * 86400.0 / self.duration_s if self.duration_s > 0 else math.nan


def false_transitions(
    records: Sequence[ReportRecord],
    config: SupervisorConfig,
    faults: Sequence[tuple[float, float]] = (),
    *,
    lag_s: float = 0.0,
    tick_s: float = 1.0,
    end_s: float | None = None,
) -> FalseTransitions:
    """Replay reports through the supervisor and count the transitions faults do not explain.

    A switch to SAFE is false unless it falls in a fault interval ``[onset, end + lag_s]``
    (the alarm lags the fault by up to a window, so the lag covers a switch caused by the
    fault's last windows); a return to NORMAL is false while a fault is active
    (``onset <= t <= end``). On nominal data (no faults) every switch to SAFE is false.

    Args:
        records: the reports (:func:`report_records` of a replay's or a live run's reports).
        config: the supervisor's settings.
        faults: ``(onset_s, end_s)`` of each injected fault, on the stamps' clock (an open
            fault: ``end_s = math.inf``).
        lag_s: allowance after each fault's end (s), >= 0.
        tick_s: the staleness timer's period (s).
        end_s: replay on until this time (s): a silence at the end is then judged too.

    Raises:
        SupervisorError: a negative lag or an interval that ends before it starts.
    """
    if not lag_s >= 0:
        raise SupervisorError(f"lag_s must be >= 0, found {lag_s}")
    for onset, end in faults:
        if not onset <= end:
            raise SupervisorError(f"fault interval ({onset}, {end}) ends before it starts")
    sup = replay(records, config, tick_s=tick_s, end_s=end_s)
    log = tuple(sup.log)
    false_safe = tuple(
        tr
        for tr in log
        if tr.to_mode is Mode.SAFE and not any(a <= tr.time_s <= b + lag_s for a, b in faults)
    )
    false_normal = tuple(
        tr
        for tr in log
        if tr.to_mode is Mode.NORMAL and any(a <= tr.time_s <= b for a, b in faults)
    )
    if records:
        stamps = [r.stamp_s for r in records]
        last = max(stamps if end_s is None else [*stamps, end_s])
        duration = last - min(stamps)
    else:
        duration = 0.0
    return FalseTransitions(false_safe, false_normal, log, duration)
