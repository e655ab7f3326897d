"""The fault named live: which windows to diagnose once an alarm rises, when, and the answer.

When a model's alarm reaches ERROR, :class:`LiveDiagnoser` diagnoses the windows *after the
onset* against the windows *before it*: a diagnosis job (:class:`DiagnosisJob`) holds the
non-overlapping judged windows after the estimated onset (the newest
``max_post_windows``), the non-overlapping windows before it (their steady means are the
reference operating point) and the per-hop means of the recent windows (how the operating
point moved). Which effect the job names is computed by a function it is given (ROS-free
and diagnosis-free here; :func:`twotank_validation.diagnose.live_jobs.catalogue_diagnosis` runs the
catalogue), synchronously or in a :class:`concurrent.futures.Executor`.

**Onset.** The end of the last judged window that did not invalidate the model before the
alarm (the fault was present, at most, from somewhat before it). Windows *after* the onset
start after it; windows *before* it end at or before it.

**Updates.** A job runs when the alarm rises and then at every new non-overlapping window
after the onset, at most ``max_updates`` times per alarm episode. The episode (and the
answer) ends when the alarm leaves ERROR.

**When an answer shows (the rule that makes replay and live agree).** Every answer carries
the stamp of the window whose report started its job (:attr:`LiveDiagnosis.window_end_ns`).
Jobs of one model finish in the order they started (one job at a time per diagnoser; an
executor with one worker). An answer is attached to the first report of its model handled
*after* the job finished, and to every later report while the alarm stays ERROR, until a
newer answer replaces it. Synchronously (bag replay, tests) the job finishes before its own
report is returned, so the answer rides on that report; in the node (a background executor)
it is published on ``validation/M/diagnosis`` as soon as it is done and rides on a later
report. The answers themselves (the windows diagnosed, kind, parameters, score, probability) are the
same in both: they depend only on the windows, never on the timing.

Memory is bounded: per model the last ``keep_windows`` judged windows' samples and the last
``keep_means`` windows' means.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from twotank_validation.errors import DatumError
from twotank_validation.online.alarm import Alarm
from twotank_validation.online.states import RaisedBy
from twotank_validation.settings import check_settings, setting

UNEXPLAINED = "unexplained"
"""The answer's kind when no effect explains the change
(``twotank_validation.diagnose.kinds.EffectKind.UNEXPLAINED`` is this text)."""


@dataclass(frozen=True)
class LiveDiagnosis:
    """The most likely effect behind a model's alarm, as the node publishes it.

    Attributes:
        model: model name.
        kind: the text of a ``twotank_validation.diagnose.kinds.EffectKind``: an effect of
            the catalogue (``delay``, ``lag``, ``gain``, ``input_gain``, ``coupling``,
            ``leak``, ``heat_loss``, ``hot_supply``), ``offset`` or ``saturation`` (reported
            findings), ``stuck`` (a valve that follows no command), or ``unexplained``.
        channel: the output or input it acts on (``""`` for ``unexplained``).
        parameters: fitted parameters (SI units, model units for levels and offsets).
        score: the diagnosis's own ranking of how clearly the effect stood out, in [0, 1];
            its meaning differs between kinds of answer, so it is no probability (see
            ``probability``).
        probability: the probability that this answer names the fault behind the alarm:
            the frequency with which answers of this kind and score named the injected
            fault on the isolation bench, cross-validated over its seeds (docs/diagnosis.md,
            "The probability of an answer"); None for ``unexplained`` (no fault named) and
            for a kind of answer the bench did not measure.
        summary: the answer in one sentence.
        onset_ns: the estimated onset (end of the last valid window before the alarm).
        window_end_ns: end stamp of the window whose report started the job (the answer's
            stamp).
        windows: windows after the onset that were diagnosed.
        update: the answer's number in its alarm episode (1 for the first).
    """

    model: str
    kind: str
    channel: str
    parameters: Mapping[str, float]
    score: float
    summary: str
    onset_ns: int = 0
    window_end_ns: int = 0
    windows: int = 0
    update: int = 0
    probability: float | None = None

    @property
    def unexplained(self) -> bool:
        """No effect explains the change."""
        return self.kind == UNEXPLAINED

    def to_json(self) -> dict[str, Any]:
        """The JSON entry (``validate`` per window, ``live`` per answer).

        ``{"kind", "channel", "parameters", "probability", "score", "onset", "window_end",
        "windows", "update", "summary"}``; times in seconds of the data's time base.
        """
        return {
            "kind": self.kind,
            "channel": self.channel,
            "parameters": {k: float(v) for k, v in self.parameters.items()},
            "probability": None if self.probability is None else float(self.probability),
            "score": float(self.score),
            "onset": self.onset_ns / 1e9,
            "window_end": self.window_end_ns / 1e9,
            "windows": self.windows,
            "update": self.update,
            "summary": self.summary,
        }


@dataclass(frozen=True)
class WindowData:
    """A judged window's samples (model units) and stamps.

    Attributes:
        start_ns, end_ns: stamps of its first and last sample.
        u: (n, nu) float inputs.
        y: (n, ny) float outputs.
    """

    start_ns: int
    end_ns: int
    u: np.ndarray
    y: np.ndarray


@dataclass(frozen=True)
class DiagnosisJob:
    """What one live diagnosis works on.

    Attributes:
        model: model name.
        onset_ns: estimated onset.
        trigger_end_ns: end stamp of the window whose report started the job.
        pre: non-overlapping judged windows before the onset, oldest first (may be empty).
        post: non-overlapping judged windows after the onset, oldest first (at least one).
        means_end_ns: (k,) end stamps of the recent windows (hop apart; judged or not, with
            complete samples), oldest first.
        means_u: (k, nu) input means of each of those windows' last period.
        means_y: (k, ny) output means of the same.
        raised_by: what made the windows since the onset invalidating
            (``WindowReport.raised_by`` of each, joined: ``RaisedBy.BOTH`` when both
            occurred; a text is converted).
        ts_s: sample period (s).
        period_samples: excitation period (samples).
        update: the job's number in its alarm episode.
        earlier: further non-overlapping judged windows before ``pre``, oldest first (the
            runner may take its reference from them when it dates the change earlier than
            ``onset_ns``: a slow fault can leave windows valid after it started).
        measured: (nu,) bool, the model's inputs the interface map marks measured (its
            datums average them as the validator's do); None: every input commanded.
    """

    model: str
    onset_ns: int
    trigger_end_ns: int
    pre: tuple[WindowData, ...]
    post: tuple[WindowData, ...]
    means_end_ns: np.ndarray
    means_u: np.ndarray
    means_y: np.ndarray
    raised_by: RaisedBy
    ts_s: float
    period_samples: int
    update: int
    earlier: tuple[WindowData, ...] = ()
    measured: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "raised_by", RaisedBy(self.raised_by))


DiagnoseFn = Callable[[DiagnosisJob], LiveDiagnosis]
"""Runs one job (e.g. :func:`twotank_validation.diagnose.live_jobs.catalogue_diagnosis`)."""


class Report(Protocol):
    """What the diagnoser reads of a window report (:class:`~.window.WindowReport` has it)."""

    @property
    def model(self) -> str: ...  # noqa: D102
    @property
    def start_ns(self) -> int: ...  # noqa: D102
    @property
    def end_ns(self) -> int: ...  # noqa: D102
    @property
    def judged(self) -> bool: ...  # noqa: D102
    @property
    def invalidated(self) -> bool: ...  # noqa: D102
    @property
    def alarm(self) -> Alarm: ...  # noqa: D102
    @property
    def raised_by(self) -> RaisedBy: ...  # noqa: D102


_INTERNAL = "internal: how much history the diagnosis keeps and offers, sized to the window counts"


@dataclass(frozen=True)
class LiveDiagConfig:
    """Settings of the live diagnosis.

    Attributes:
        max_updates: jobs per alarm episode (the first at the alarm, then one per new
            non-overlapping window after the onset).
        max_post_windows: the newest this many windows after the onset are diagnosed.
        pre_windows: windows before the onset whose means are the reference (and whose
            diagnosis is the model the change is judged against).
        earlier_windows: further windows before those, offered to the runner in case it
            dates the change earlier than the onset (:attr:`DiagnosisJob.earlier`).
        keep_windows: judged windows kept per model (samples): must reach from the windows
            before the onset to the alarm.
        keep_means: judged windows' means kept per model.
        models: diagnose only these models (empty: all).
    """

    max_updates: int = setting(
        6,
        "diagnoses per alarm episode (at the alarm, then one per new non-overlapping window)",
        low=1,
        high=1000,
    )
    max_post_windows: int = setting(
        3, "the newest windows after the onset that are diagnosed", low=1, hidden=_INTERNAL
    )
    pre_windows: int = setting(
        2, "windows before the onset whose means are the reference", low=0, hidden=_INTERNAL
    )
    earlier_windows: int = setting(
        4, "further windows before those, offered to date the change", low=0, hidden=_INTERNAL
    )
    keep_windows: int = setting(48, "judged windows kept per model", low=1, hidden=_INTERNAL)
    keep_means: int = setting(96, "judged windows' means kept per model", low=1, hidden=_INTERNAL)
    models: tuple[str, ...] = setting(
        (),
        "diagnose only these models (empty: all)",
        hidden="the validator diagnoses every model it validates (its models parameter)",
    )

    def __post_init__(self) -> None:
        check_settings(self, DatumError)


@dataclass
class _Episode:
    onset_ns: int
    pre: tuple[WindowData, ...]
    earlier: tuple[WindowData, ...] = ()
    post: list[WindowData] = field(default_factory=list)
    updates: int = 0
    raised_by: set[RaisedBy] = field(default_factory=set)


@dataclass
class _ModelState:
    windows: deque[WindowData]
    means: deque[tuple[int, np.ndarray, np.ndarray]]
    last_valid_end_ns: int | None = None
    raised_since_valid: set[RaisedBy] = field(default_factory=set)
    episode: _Episode | None = None
    pending: deque[Future[LiveDiagnosis]] = field(default_factory=deque)
    current: LiveDiagnosis | None = None


class LiveDiagnoser:
    """Buffers judged windows per model and diagnoses the alarm's onset (module docstring).

    Args:
        run: runs one job.
        config: settings.
        executor: where jobs run; None: synchronously, in the caller's thread (replay, tests).
            A background executor must run one job at a time (``max_workers=1``) so that
            answers come in order.
        on_result: called with each answer as soon as it is ready (from the executor's
            thread in the background; e.g. the node publishes it).
    """

    def __init__(
        self,
        run: DiagnoseFn,
        config: LiveDiagConfig | None = None,
        *,
        executor: Executor | None = None,
        on_result: Callable[[LiveDiagnosis], None] | None = None,
    ) -> None:
        self.run = run
        self.config = config or LiveDiagConfig()
        self.executor = executor
        self.on_result = on_result
        self._ts_s = 0.0
        self._period = 0
        self._measured: dict[str, np.ndarray | None] = {}
        self._states: dict[str, _ModelState] = {}
        self._lock = threading.Lock()
        self.jobs_started = 0
        self.failures: list[str] = []

    def bind(
        self,
        ts_s: float,
        period_samples: int,
        measured: Mapping[str, np.ndarray | None] | None = None,
    ) -> None:
        """The validator's sample period (s), excitation period (samples), measured inputs.

        ``measured``: per model, its measured inputs (:attr:`DiagnosisJob.measured`); none
        given: every input commanded.
        """
        self._ts_s, self._period = ts_s, period_samples
        self._measured = dict(measured or {})

    def _state(self, model: str) -> _ModelState:
        st = self._states.get(model)
        if st is None:
            cfg = self.config
            st = self._states[model] = _ModelState(
                deque(maxlen=cfg.keep_windows), deque(maxlen=cfg.keep_means)
            )
        return st

    def wants(self, model: str) -> bool:
        """Whether this model is diagnosed."""
        return not self.config.models or model in self.config.models

    def observe(self, rep: Report, stamps_ns: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
        """A judged window's report and its samples: buffered; a job started if one is due.

        Args:
            rep: the report (judged).
            stamps_ns: (n,) int sample stamps of the window.
            u: (n, nu) float inputs.
            y: (n, ny) float outputs.
        """
        if not self.wants(rep.model):
            return
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
            return  # a window judged on recovered samples: its raw data hold the gaps
        st = self._state(rep.model)
        data = WindowData(int(stamps_ns[0]), int(stamps_ns[-1]), u, y)
        st.windows.append(data)
        p = self._period or len(u)
        if not st.means or data.end_ns > st.means[-1][0]:
            st.means.append((data.end_ns, u[-p:].mean(axis=0), y[-p:].mean(axis=0)))
        if rep.raised_by:  # what invalidated the windows since the last valid one
            st.raised_since_valid.update(RaisedBy(rep.raised_by).parts)
        if rep.alarm is not Alarm.ERROR:
            st.episode = None
            if not rep.invalidated:
                st.last_valid_end_ns = data.end_ns
                st.raised_since_valid = set()
            return
        ep = st.episode
        if ep is None:
            onset = st.last_valid_end_ns
            if onset is None:  # invalid from the first window on: nothing before the onset
                onset = st.windows[0].start_ns - 1
            before = self._before(st, onset)
            cut = max(len(before) - self.config.pre_windows, 0)
            ep = st.episode = _Episode(onset, before[cut:], before[:cut])
        ep.raised_by.update(st.raised_since_valid)
        grew = self._extend_post(st, ep)
        if (grew or ep.updates == 0) and ep.post and ep.updates < self.config.max_updates:
            ep.updates += 1
            self._start(st, ep, rep)

    def note_means(self, rep: Report, stamps_ns: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
        """A window that was not judged: only its last period's means are kept.

        A window spoiled by a transient (the plant or a feedback loop still settling after
        a change) is not judged, yet its means show how the operating point moved, which
        dates and shapes the change (:attr:`DiagnosisJob.means_y`). Windows shorter than a
        period, with non-finite samples, or not newer than the last kept are ignored.

        Args:
            rep: the report (not judged).
            stamps_ns: (n,) int sample stamps of the window.
            u: (n, nu) float inputs.
            y: (n, ny) float outputs.
        """
        if not self.wants(rep.model) or len(stamps_ns) == 0:
            return
        p = self._period or len(u)
        if len(u) < p or not (np.all(np.isfinite(u[-p:])) and np.all(np.isfinite(y[-p:]))):
            return
        st = self._state(rep.model)
        end = int(stamps_ns[-1])
        if st.means and end <= st.means[-1][0]:
            return
        st.means.append((end, u[-p:].mean(axis=0), y[-p:].mean(axis=0)))

    def _before(self, st: _ModelState, onset_ns: int) -> tuple[WindowData, ...]:
        """Non-overlapping windows ending at or before the onset, oldest first.

        The newest is chained first; ``earlier_windows`` then ``pre_windows`` of them.
        """
        out: list[WindowData] = []
        for w in reversed(st.windows):
            if len(out) >= self.config.pre_windows + self.config.earlier_windows:
                break
            if w.end_ns <= onset_ns and (not out or w.end_ns < out[-1].start_ns):
                out.append(w)
        return tuple(reversed(out))

    def _extend_post(self, st: _ModelState, ep: _Episode) -> bool:
        """Add the buffered windows after the onset that follow the last one without overlap."""
        grew = False
        for w in st.windows:
            last = ep.post[-1].end_ns if ep.post else ep.onset_ns
            if w.start_ns > last:
                ep.post.append(w)
                grew = True
        if len(ep.post) > self.config.max_post_windows:
            del ep.post[: len(ep.post) - self.config.max_post_windows]
        return grew

    def _start(self, st: _ModelState, ep: _Episode, rep: Report) -> None:
        means = list(st.means)
        job = DiagnosisJob(
            model=rep.model,
            onset_ns=ep.onset_ns,
            trigger_end_ns=int(rep.end_ns),
            pre=ep.pre,
            post=tuple(ep.post),
            means_end_ns=np.array([m[0] for m in means], dtype=np.int64),
            means_u=np.array([m[1] for m in means]),
            means_y=np.array([m[2] for m in means]),
            raised_by=RaisedBy.of(ep.raised_by),
            ts_s=self._ts_s,
            period_samples=self._period,
            update=ep.updates,
            earlier=ep.earlier,
            measured=self._measured.get(rep.model),
        )
        self.jobs_started += 1
        if self.executor is None:
            done: Future[LiveDiagnosis] = Future()
            try:
                done.set_result(self.run(job))
            except Exception as err:  # a failed job is noted, never fatal
                done.set_exception(err)
            st.pending.append(done)
            self._notify(done)
            return
        future = self.executor.submit(self.run, job)
        st.pending.append(future)
        future.add_done_callback(self._notify)

    def _notify(self, future: Future[LiveDiagnosis]) -> None:
        if future.cancelled():  # the node is shutting down: nothing to publish
            return
        err = future.exception()
        if err is not None:
            with self._lock:
                self.failures.append(f"{type(err).__name__}: {err}")
            return
        if self.on_result is not None:
            self.on_result(future.result())

    def attach(self, rep: Report) -> LiveDiagnosis | None:
        """The answer that rides on this report (None before any, and while not ERROR)."""
        st = self._states.get(rep.model)
        if st is None:
            return None
        while st.pending and st.pending[0].done():
            future = st.pending.popleft()
            if future.exception() is None:
                st.current = future.result()
        if rep.alarm is not Alarm.ERROR:
            st.current = None
            return None
        return st.current

    def current(self) -> dict[str, LiveDiagnosis | None]:
        """The latest answer of each model diagnosed so far (None: none now)."""
        return {name: st.current for name, st in self._states.items()}
