"""Online validation: sample alignment, windowing, data-quality gates and the debounced alarm.

This is the one code path shared by the live ROS node, bag replay and offline use. It is
ROS-free: callers feed it stamped values (integer nanoseconds) and get
:class:`WindowReport` objects back.

* :class:`SampleAligner` puts three streams (valve commands, level, temperature) on the
  sample grid ``t0 + k ts``: measurements are matched to a grid point within a jitter
  tolerance, commands are zero-order held. Duplicates, out-of-order stamps, NaN/inf and gaps
  are counted and flagged on the samples they affect; nothing is silently dropped.
* :class:`WindowMonitor` buffers aligned samples and, at every excitation-period boundary,
  validates the last ``periods_per_window`` periods against every model — but only when the
  window is fit to judge (no flagged samples, input periodic for ``settle_periods`` more
  periods before it, enough excitation). Otherwise the report says why and carries STALE.
* :func:`update_alarm` debounces the raw per-window verdicts into the alarm level.
"""

from __future__ import annotations

import enum
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from twotank_validation.core import fast
from twotank_validation.core.datum import NormConvention, make_datum
from twotank_validation.core.model import LFTModel, PlantResponse
from twotank_validation.core.validate import (
    check_compatible,
    pulse_moment,
    takes_fast_path,
    validate,
)
from twotank_validation.defaults import METHODS, NS_PER_S, PERIOD_SAMPLES, TS_S, Method
from twotank_validation.errors import DatumError, ModelError, TwotankError


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


# --------------------------------------------------------------------------- alignment


@dataclass(frozen=True)
class Sample:
    """One grid sample.

    Attributes:
        index: grid index k (``stamp_ns = t0 + k ts``).
        stamp_ns: grid time (ns).
        u: (n_inputs,) float, zero-order-held commands (NaN before the first command).
        y: (n_outputs,) float, measurements (NaN where missing or bad).
        flag: ``None`` for a clean sample, else why it cannot be used.
    """

    index: int
    stamp_ns: int
    u: np.ndarray
    y: np.ndarray
    flag: str | None = None


@dataclass(frozen=True)
class SampleBlock:
    """Consecutive grid samples as arrays (what the aligner's batch path hands out).

    Attributes:
        first_index: grid index of the first row; row i is index ``first_index + i``.
        stamps_ns: (m,) int64, grid times.
        u: (m, n_inputs) float, held commands.
        y: (m, n_outputs) float, measurements.
        flags: m entries, ``None`` for a clean sample, else why it cannot be used.
    """

    first_index: int
    stamps_ns: np.ndarray
    u: np.ndarray
    y: np.ndarray
    flags: list[str | None]

    def __len__(self) -> int:
        """Number of samples."""
        return len(self.flags)

    def samples(self) -> list[Sample]:
        """The rows as :class:`Sample` objects (copies)."""
        return [
            Sample(self.first_index + i, int(t), self.u[i].copy(), self.y[i].copy(), f)
            for i, (t, f) in enumerate(zip(self.stamps_ns.tolist(), self.flags, strict=True))
        ]


COMMAND = -1
"""Event kind of a command in :meth:`SampleAligner.push_events` (measurements: channel)."""

_MIN_RUN = 8  # groups: shorter regular runs go event by event
_MAX_RUN = 4096  # groups examined at once
_MAX_BACKOFF = 1 << 12  # events before the next look for a regular run, at most


@dataclass
class AlignerCounters:
    """What the aligner refused or repaired, for diagnostics."""

    duplicates: int = 0
    out_of_order: int = 0
    off_grid: int = 0
    non_finite: int = 0
    missing: int = 0
    clock_resets: int = 0


class _Pending:
    """Measurements of one grid index received so far (plain Python: no per-sample arrays)."""

    __slots__ = ("flag", "n_seen", "seen", "y")

    def __init__(self, n_outputs: int) -> None:
        self.y = [math.nan] * n_outputs
        self.seen = [False] * n_outputs
        self.n_seen = 0
        self.flag: str | None = None


class SampleAligner:
    """Put stamped commands and per-channel measurements on the sample grid.

    Every event costs a few microseconds: the state is plain Python (lists, tuples, a dict of
    pending grid indices and the largest of them), and numpy arrays are made only for the
    samples handed out.

    Args:
        ts_s: sample period (s).
        n_inputs: number of command entries.
        output_names: measurement channel names (order of ``y``).
        jitter_fraction: accepted distance of a measurement stamp from its grid point, as a
            fraction of the sample period.
        reset_after_s: a measurement stamped this much before the last finalised sample is
            taken for a clock jump backwards (a restarted recording or simulation) and the
            aligner starts over; later-than-that stragglers are dropped as out of order. A
            live node also resets on a backward jump of its ROS clock. A command stamped this
            much before the last command, on the measurements' clock, while the last command
            is more than ``jump_after_s`` ahead of them, means the queued commands carried
            bogus future stamps: they are dropped.
        jump_after_s: a stamp this much after the newest one is taken for a clock jump
            forwards (a bogus or far-future stamp): the aligner starts over there instead of
            filling the silence with missing samples (which would cost time and memory in
            proportion to the jump). Shorter silences are reported sample by sample as gaps.
        max_abs_value: measurements and commands beyond this magnitude (model units) are
            implausible and flagged like non-finite ones (a judged window of such values
            would overflow the DFT).
    """

    def __init__(
        self,
        ts_s: float,
        n_inputs: int,
        output_names: Sequence[str],
        *,
        jitter_fraction: float = 0.25,
        reset_after_s: float = 60.0,
        jump_after_s: float = 3600.0,
        max_abs_value: float = 1e6,
    ) -> None:
        if not (math.isfinite(ts_s) and ts_s > 0):
            raise DatumError(f"sample period must be positive, found {ts_s}")
        self.ts_ns = round(ts_s * NS_PER_S)
        self.n_inputs = n_inputs
        self.output_names = tuple(output_names)
        self.tol_ns = round(jitter_fraction * self.ts_ns)
        self.reset_ns = round(reset_after_s * NS_PER_S)
        self.jump_ns = round(max(jump_after_s, reset_after_s) * NS_PER_S)
        self.max_abs = float(max_abs_value)
        self._reanchor_after = 20 * max(len(output_names), 1)
        self.counters = AlignerCounters()
        self._half_ns = self.ts_ns // 2
        self._n_outputs = len(self.output_names)
        self._clear()

    def _clear(self) -> None:
        self.t0_ns: int | None = None
        self.next_index = 0
        self._pending: dict[int, _Pending] = {}
        # largest pending index; exact while _pending is non-empty (entries leave only from
        # the front, at next_index), and below every future index once it is empty
        self._newest = -1
        self._commands: deque[tuple[int, tuple[float, ...], bool]] = deque()
        self._held: tuple[float, ...] = (math.nan,) * self.n_inputs
        self._held_finite = self.n_inputs == 0
        self.last_command_ns: int | None = None
        self._retry_at = 0  # event (of the current batch) from which to look for a run
        self._off_run = 0  # consecutive off-grid measurements (re-anchor the grid after many)
        self._backoff = self._n_outputs + 1

    def reset(self) -> None:
        """Start over (new grid origin); counters are kept."""
        self._clear()

    def grid_time(self, index: int) -> int:
        """Stamp (ns) of grid index ``index``."""
        assert self.t0_ns is not None
        return self.t0_ns + index * self.ts_ns

    def _command_tuple(self, values: Sequence[float]) -> tuple[float, ...]:
        # exact types only: anything else converts through numpy, as before
        if (
            (type(values) is tuple or type(values) is list)
            and len(values) == self.n_inputs
            and all(type(v) is float for v in values)
        ):
            return tuple(values)
        u = np.asarray(values, dtype=float)
        if u.shape != (self.n_inputs,):
            raise DatumError(f"command needs {self.n_inputs} values, found shape {u.shape}")
        return tuple(u.tolist())

    def push_command(self, stamp_ns: int, values: Sequence[float]) -> list[Sample]:
        """Add a command (held from ``stamp_ns`` on). Returns samples it completes."""
        u = self._command_tuple(values)
        last = self.last_command_ns
        if (
            last is not None
            and stamp_ns < last - self.reset_ns
            and self.t0_ns is not None
            and last > self.grid_time(max(self._newest, self.next_index)) + self.jump_ns
            and abs(stamp_ns - self.grid_time(self.next_index)) <= self.reset_ns
        ):
            # the queued commands were stamped far ahead of the measurements' clock (a bogus
            # stamp): drop them, or every later command would look out of order
            self.counters.clock_resets += 1
            self._commands = deque(c for c in self._commands if c[0] < stamp_ns)
            last = self._commands[-1][0] if self._commands else None
            self.last_command_ns = last
        if last is not None and stamp_ns <= last:
            if stamp_ns == last:
                self.counters.duplicates += 1
            else:
                self.counters.out_of_order += 1
            return []
        finite = all(math.isfinite(x) and abs(x) <= self.max_abs for x in u)
        if not finite:
            self.counters.non_finite += 1
        self._commands.append((stamp_ns, u, finite))
        self.last_command_ns = stamp_ns
        return self._finalise() if self._pending else []

    def push_measurement(self, channel: int, stamp_ns: int, value: float) -> list[Sample]:
        """Add one measurement of output ``channel``. Returns the samples now complete."""
        t0 = self.t0_ns
        if t0 is None:
            self.t0_ns = t0 = stamp_ns
        ts = self.ts_ns
        offset = stamp_ns - t0
        k = (offset + self._half_ns) // ts
        if k > max(self._newest, self.next_index) + self.jump_ns // ts:
            self.counters.clock_resets += 1  # clock jump forwards: start over there
            self._clear()
            return self.push_measurement(channel, stamp_ns, value)
        if k < self.next_index:
            if stamp_ns < self.grid_time(self.next_index) - self.reset_ns:
                self.counters.clock_resets += 1
                self._clear()
                return self.push_measurement(channel, stamp_ns, value)
            self.counters.out_of_order += 1
            return []
        pend = self._pending.get(k)
        if pend is None:
            pend = self._pending[k] = _Pending(self._n_outputs)
            self._newest = max(self._newest, k)
        seen = pend.seen
        if seen[channel]:
            self.counters.duplicates += 1
            return []
        seen[channel] = True
        pend.n_seen += 1
        if abs(offset - k * ts) > self.tol_ns:
            self._off_run += 1
            if self._off_run > self._reanchor_after:
                # the grid origin (first stamp after a start or reset) was itself off the
                # sender's grid: every later stamp would be flagged. Start over on this one.
                self.counters.clock_resets += 1
                self._clear()
                return self.push_measurement(channel, stamp_ns, value)
            self.counters.off_grid += 1
            pend.flag = pend.flag or (
                f"{self.output_names[channel]} stamp {stamp_ns} ns is off the sample grid by "
                f"{(offset - k * ts) / 1e6:.1f} ms"
            )
        else:
            self._off_run = 0
        if math.isfinite(value) and abs(value) <= self.max_abs:
            pend.y[channel] = float(value)
        else:
            self.counters.non_finite += 1
            what = "non-finite" if not math.isfinite(value) else "implausible"
            pend.flag = pend.flag or f"{what} {self.output_names[channel]} ({value})"
        return self._finalise()

    def _finalise(self) -> list[Sample]:
        out: list[Sample] = []
        pending = self._pending
        n_out = self._n_outputs
        while pending:
            k = self.next_index
            pend = pending.get(k)
            t_k = self.t0_ns + k * self.ts_ns  # type: ignore[operator]  # set with _pending
            later = self._newest > k + 1
            if pend is not None and pend.n_seen == n_out:
                if not later:
                    last = self.last_command_ns
                    if last is None or last < t_k - self.tol_ns:
                        break  # wait for the command of this instant
                flag = pend.flag
                y = pend.y
            elif later:
                # later samples are complete or arriving: this one will not be completed
                self.counters.missing += 1
                if pend is not None:
                    names = ", ".join(
                        n for n, s in zip(self.output_names, pend.seen, strict=True) if not s
                    )
                    y = pend.y
                else:
                    names = ", ".join(self.output_names)
                    y = [math.nan] * n_out
                flag = f"gap: no {names} sample at t = {t_k / NS_PER_S:.3f} s"
            else:
                break
            cmds = self._commands
            limit = t_k + self.tol_ns
            while cmds and cmds[0][0] <= limit:
                _, self._held, self._held_finite = cmds.popleft()
            if flag is None and not self._held_finite:
                flag = (
                    "no valid valve command yet"
                    if self.last_command_ns is None
                    else "non-finite valve command"
                )
            if pend is not None:
                del pending[k]
            self.next_index = k + 1
            out.append(
                Sample(k, t_k, np.array(self._held, dtype=float), np.array(y, dtype=float), flag)
            )
        return out

    # -- batches

    def push_events(
        self, kinds: np.ndarray, stamps_ns: np.ndarray, values: np.ndarray
    ) -> list[Sample | SampleBlock]:
        """Add a batch of events in arrival order; returns what they complete, in order.

        Exactly the same as pushing the events one by one (:meth:`push_command` for kind
        :data:`COMMAND`, :meth:`push_measurement` for a channel), only faster: a regular run
        (per grid index one finite command and one finite, on-grid measurement per channel,
        each sample completed within its group of events) is aligned with array operations
        and handed out as one :class:`SampleBlock`; anything else goes event by event.

        Args:
            kinds: (n,) int, :data:`COMMAND` or the measurement channel.
            stamps_ns: (n,) int64 stamps.
            values: (n, w) float, w >= max(n_inputs, 1): a command's values in the first
                ``n_inputs`` columns, a measurement in the first.
        """
        n = len(kinds)
        group = self._n_outputs + 1
        nu = self.n_inputs
        out: list[Sample | SampleBlock] = []
        # events taken one by one are converted to Python values a slice at a time
        base = 0
        kinds_l: list[int] = []
        stamps_l: list[int] = []
        rows: list[list[float]] = []
        i = 0
        while i < n:
            if (
                i >= self._retry_at
                and not self._pending
                and self.t0_ns is not None
                and n - i >= group * _MIN_RUN
            ):
                block = self._regular_run(kinds, stamps_ns, values, i)
                if block is not None:
                    out.append(block)
                    self._off_run = 0  # a regular run is on the grid
                    i += group * len(block)
                    self._backoff = group
                    continue
                self._retry_at = i + self._backoff
                self._backoff = min(2 * self._backoff, _MAX_BACKOFF)
            if not base <= i < base + len(kinds_l):
                base = i
                kinds_l = kinds[i : i + 64].tolist()
                stamps_l = stamps_ns[i : i + 64].tolist()
                rows = values[i : i + 64].tolist()
            kind = kinds_l[i - base]
            if kind == COMMAND:
                out.extend(self.push_command(stamps_l[i - base], rows[i - base][:nu]))
            else:
                out.extend(self.push_measurement(kind, stamps_l[i - base], rows[i - base][0]))
            i += 1
        self._retry_at -= n
        return out

    def _regular_run(
        self, kinds: np.ndarray, stamps_ns: np.ndarray, values: np.ndarray, start: int
    ) -> SampleBlock | None:
        """Align the longest regular run of event groups at ``start`` at once (None if short).

        Precondition: nothing pending and the grid origin set. Group j (grid index
        k = next_index + j, time t) has one command and one measurement per channel, in any
        order. Event by event, such a group would complete sample k at its last measurement
        if the latest command then known is stamped >= t - tol, else at its command if that
        comes last and is stamped >= t - tol; otherwise the run ends before the group. Each
        sample holds the last command pushed by then with stamp <= t + tol (commands are
        pushed in increasing stamp order, so that is a prefix of them all).
        """
        ny, nu = self._n_outputs, self.n_inputs
        group = ny + 1
        m = min((len(kinds) - start) // group, _MAX_RUN)
        stop = start + group * m
        kk = kinds[start:stop].reshape(m, group)
        ss = stamps_ns[start:stop].astype(np.int64, copy=False).reshape(m, group)
        vv = values[start:stop].reshape(m, group, values.shape[1])
        t0, ts, tol, first = self.t0_ns, self.ts_ns, self.tol_ns, self.next_index
        assert t0 is not None
        rows = np.arange(m)
        ok = (np.sort(kk, axis=1) == np.arange(-1, ny)).all(axis=1)
        cmd_pos = np.argmin(kk, axis=1)
        grid = t0 + (first + rows) * ts  # t of each group
        is_meas = kk != COMMAND
        offset = ss - t0
        index = (offset + self._half_ns) // ts
        dev = offset - (first + rows)[:, None] * ts
        meas_ok = (index == (first + rows)[:, None]) & (np.abs(dev) <= tol)
        meas_ok &= np.abs(vv[:, :, 0]) <= self.max_abs  # False for NaN and inf too
        ok &= (meas_ok | ~is_meas).all(axis=1)
        cmd = ss[rows, cmd_pos]
        cmd_u = vv[rows, cmd_pos, :nu]
        ok &= (np.abs(cmd_u) <= self.max_abs).all(axis=1)
        last = self.last_command_ns
        prev = np.empty(m, dtype=np.int64)
        prev[1:] = cmd[:-1]
        has_prev = np.ones(m, dtype=bool)
        if last is None:
            has_prev[0] = False
            prev[0] = 0
        else:
            prev[0] = last
        ok &= ~has_prev | (cmd > prev)
        cmd_last = cmd_pos == group - 1
        known_before = has_prev & (prev >= grid - tol)  # at the last measurement, if cmd last
        known_own = cmd >= grid - tol
        # command pushed when the sample completes (event by event)
        pushed = ~cmd_last | ~known_before
        ok &= np.where(cmd_last, known_before | known_own, known_own)
        bad = np.flatnonzero(~ok)
        m = int(bad[0]) if len(bad) else m
        if m < _MIN_RUN:
            return None
        rows, cmd, cmd_u, pushed, grid = rows[:m], cmd[:m], cmd_u[:m], pushed[:m], grid[:m]
        # held command of each sample: index into (pending commands, run's commands)
        queued = list(self._commands)
        d = len(queued)
        seq_t = np.concatenate([np.array([c[0] for c in queued], dtype=np.int64), cmd])
        seq_u = np.concatenate(
            [np.array([c[1] for c in queued], dtype=float).reshape(d, nu), cmd_u]
        )
        seq_finite = np.concatenate(
            [np.array([c[2] for c in queued], dtype=bool), np.ones(m, bool)]
        )
        n_pushed = rows + pushed
        held_i = np.minimum(d + n_pushed, np.searchsorted(seq_t, grid + tol, side="right")) - 1
        u = np.empty((m, nu))
        finite = np.empty(m, dtype=bool)
        have = held_i >= 0
        u[have] = seq_u[held_i[have]]
        finite[have] = seq_finite[held_i[have]]
        u[~have] = self._held
        finite[~have] = self._held_finite
        flags: list[str | None] = [None] * m
        for j in np.flatnonzero(~finite).tolist():
            none_yet = last is None and n_pushed[j] == 0
            flags[j] = "no valid valve command yet" if none_yet else "non-finite valve command"
        y = np.empty((m, ny))
        kk, vv = kk[:m], vv[:m]
        for c in range(ny):
            y[:, c] = vv[rows, np.argmax(kk == c, axis=1), 0]
        # the state event-by-event processing would leave
        top = int(held_i[-1])
        if top >= 0:
            self._held = tuple(seq_u[top].tolist())
            self._held_finite = bool(seq_finite[top])
        self._commands = deque(
            (int(t), tuple(r), True) if k >= d else queued[k]
            for k, (t, r) in enumerate(zip(seq_t.tolist(), seq_u.tolist(), strict=True))
            if k > top
        )
        self.last_command_ns = int(cmd[-1])
        self.next_index = first + m
        self._newest = first + m - 1
        return SampleBlock(first, grid.astype(np.int64), u, y, flags)


# --------------------------------------------------------------------------- windows


@dataclass(frozen=True)
class MonitorConfig:
    """Settings of the online validator (all shared by the node's ROS parameters).

    Attributes:
        ts_s: sample period (s).
        period_samples: excitation period (samples).
        periods_per_window: periods validated together (a window every period).
        settle_periods: periods of periodic input required before a window is judged (the
            plant settles after the excitation started or changed).
        min_excitation_rms: a window is judged only if some input's RMS deviation reaches
            this (model units).
        input_periodic_rtol: accepted period-to-period input change, relative to its RMS.
        convention: norm convention of ||w||.
        method: solver choice passed to :func:`validate`.
        alarm: debouncing.
    """

    ts_s: float = TS_S
    period_samples: int = PERIOD_SAMPLES
    periods_per_window: int = 2
    settle_periods: int = 1
    min_excitation_rms: float = 0.005
    input_periodic_rtol: float = 1e-6
    convention: NormConvention = NormConvention.POWER
    method: str = "auto"
    alarm: AlarmConfig = field(default_factory=AlarmConfig)

    def __post_init__(self) -> None:
        checks = [
            (
                math.isfinite(self.ts_s) and self.ts_s > 0,
                f"ts_s must be positive, found {self.ts_s}",
            ),
            (self.period_samples >= 4, f"period_samples must be >= 4, found {self.period_samples}"),
            (
                self.periods_per_window >= 1,
                f"periods_per_window must be >= 1, found {self.periods_per_window}",
            ),
            (self.settle_periods >= 0, f"settle_periods must be >= 0, found {self.settle_periods}"),
            (
                self.min_excitation_rms >= 0,
                f"min_excitation_rms must be >= 0, found {self.min_excitation_rms}",
            ),
            (
                self.input_periodic_rtol >= 0,
                f"input_periodic_rtol must be >= 0, found {self.input_periodic_rtol}",
            ),
            (
                self.method in METHODS,
                f"unknown method {self.method!r}",
            ),
        ]
        for ok, msg in checks:
            if not ok:
                raise ValueError(msg)

    @property
    def window_samples(self) -> int:
        """Samples per validated window."""
        return self.periods_per_window * self.period_samples

    @property
    def span_samples(self) -> int:
        """Samples that must be clean and periodic before a window is judged."""
        return (self.periods_per_window + self.settle_periods) * self.period_samples


@dataclass(frozen=True)
class WindowReport:
    """One model's verdict on one window (everything the ROS ValidationReport carries).

    Attributes:
        model: model name.
        start_ns: stamp of the first sample of the window (ns).
        end_ns: stamp of the last sample (ns).
        n_periods: periods in the window.
        n_samples: samples in the window.
        judged: the window was fit to judge.
        data_quality: ``"ok"`` or why it was not judged.
        beta: total min ||w|| (NaN when not judged).
        beta_lower: general solver's certified lower bound (NaN for the closed form).
        beta_upper: general solver's witness upper bound (NaN for the closed form).
        margin: ``1 - beta``.
        invalidated: raw verdict (``beta > 1``).
        alarm: debounced alarm after this window.
        convention: norm convention name.
        solver: solver that ran (empty when not judged).
        freqs_hz: (n_bins,) float.
        w_min: (n_bins,) float.
        compute_time_s: wall time of the validation.
    """

    model: str
    start_ns: int
    end_ns: int
    n_periods: int
    n_samples: int
    judged: bool
    data_quality: str
    beta: float
    beta_lower: float
    beta_upper: float
    margin: float
    invalidated: bool
    alarm: Alarm
    convention: str
    solver: str
    freqs_hz: np.ndarray
    w_min: np.ndarray
    compute_time_s: float


class WindowMonitor:
    """Buffer aligned samples; every period, validate the last window against each model.

    Args:
        config: monitor settings.
        models: models to validate (inputs/outputs must match the samples).
    """

    def __init__(self, config: MonitorConfig, models: Sequence[LFTModel]) -> None:
        if not models:
            raise ModelError("the monitor needs at least one model")
        self.config = config
        self.models = tuple(models)
        nu, ny = self.models[0].nu, self.models[0].ny
        for m in self.models:
            if (m.nu, m.ny) != (nu, ny):
                raise ModelError(
                    f"models disagree on dimensions: {self.models[0].name} is {ny}x{nu}, "
                    f"{m.name} is {m.ny}x{m.nu}"
                )
        self.n_inputs, self.n_outputs = nu, ny
        cap = self._cap = config.span_samples
        self._period = config.period_samples
        self._window = config.window_samples
        self._u = np.zeros((cap, nu))
        self._y = np.zeros((cap, ny))
        self._stamp = np.zeros(cap, dtype=np.int64)
        self._flag: list[str | None] = [None] * cap
        self._count = 0
        self._last_index: int | None = None
        n = config.window_samples
        theta = 2.0 * np.pi * np.arange(n // 2 + 1) / n
        # everything that depends only on the models and the settings is computed now, not in
        # the first window (whose report would wait for it): P at the window's bins, and the
        # leakage bound's pulse-response moment (memoised on the model)
        self._responses: dict[str, PlantResponse] = {
            m.name: m.response(theta, config.ts_s) for m in self.models
        }
        for m in self.models:
            pulse_moment(m, config.ts_s)
            # and the fast path's compiled kernel, where validate will use it
            if takes_fast_path(self._responses[m.name], config.method):
                fast.warm_up(self._responses[m.name])
        self.alarms: dict[str, AlarmState] = {m.name: AlarmState() for m in self.models}

    def reset_buffer(self) -> None:
        """Forget buffered samples (after a clock reset); alarm states are kept."""
        self._count = 0
        self._last_index = None

    def reset_alarms(self) -> None:
        """Clear latched alarms of every model."""
        self.alarms = {k: reset_alarm(v) for k, v in self.alarms.items()}

    def push(self, sample: Sample) -> list[WindowReport]:
        """Add one aligned sample; returns one report per model at each period boundary."""
        index = sample.index
        if self._last_index is not None and index != self._last_index + 1:
            # the aligner restarted (clock reset): periods restart from here
            self._count = 0
        self._last_index = index
        count = self._count
        pos = count % self._cap
        self._u[pos] = sample.u
        self._y[pos] = sample.y
        self._stamp[pos] = sample.stamp_ns
        self._flag[pos] = sample.flag
        self._count = count = count + 1
        if count % self._period or count < self._window:
            return []
        return self._evaluate()

    def push_block(
        self, block: SampleBlock, on_report: Callable[[WindowReport], None] | None = None
    ) -> list[WindowReport]:
        """Add consecutive samples at once: the same reports as pushing them one by one.

        ``on_report`` is called with each report as soon as its window is evaluated, while
        :meth:`last_window` still returns that window.
        """
        m = len(block)
        if m == 0:
            return []
        if self._last_index is not None and block.first_index != self._last_index + 1:
            self._count = 0  # the aligner restarted (clock reset)
        self._last_index = block.first_index + m - 1
        out: list[WindowReport] = []
        cap, period = self._cap, self._period
        i = 0
        while i < m:
            count = self._count
            take = min(m - i, period - count % period)
            pos = count % cap
            while take:  # at most two pieces: up to the end of the ring, then from its start
                piece = min(take, cap - pos)
                self._u[pos : pos + piece] = block.u[i : i + piece]
                self._y[pos : pos + piece] = block.y[i : i + piece]
                self._stamp[pos : pos + piece] = block.stamps_ns[i : i + piece]
                self._flag[pos : pos + piece] = block.flags[i : i + piece]
                i += piece
                take -= piece
                count += piece
                pos = 0
            self._count = count
            if count % period == 0 and count >= self._window:
                reports = self._evaluate()
                out.extend(reports)
                if on_report is not None:
                    for rep in reports:
                        on_report(rep)
        return out

    def last_window(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(stamps_ns, u, y)`` of the most recent window: (n,), (n, nu), (n, ny) copies."""
        u, y, stamps, _ = self._ordered(min(self._count, self.config.window_samples))
        return stamps.copy(), u.copy(), y.copy()

    def _ordered(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str | None]]:
        """Last ``n`` buffered samples in time order (copies)."""
        cap = self._cap
        start = (self._count - n) % cap
        if start + n <= cap:  # one piece of the ring
            sl = slice(start, start + n)
            return self._u[sl].copy(), self._y[sl].copy(), self._stamp[sl].copy(), self._flag[sl]
        head, tail = slice(start, cap), slice(0, start + n - cap)  # two pieces
        return (
            np.concatenate([self._u[head], self._u[tail]]),
            np.concatenate([self._y[head], self._y[tail]]),
            np.concatenate([self._stamp[head], self._stamp[tail]]),
            self._flag[head] + self._flag[tail],
        )

    def _quality(self) -> str:
        cfg = self.config
        L = cfg.period_samples
        span = min(self._count, cfg.span_samples)
        u, _, _, flags = self._ordered(span)
        bad = [f for f in flags if f is not None]
        if bad:
            return (
                f"{len(bad)} unusable sample(s) in the window or its settling periods; "
                f"first: {bad[0]}"
            )
        if self._count < cfg.span_samples:
            return (
                f"settling: {cfg.settle_periods} period(s) of periodic input are needed before "
                f"the window ({self._count // L - cfg.periods_per_window} so far)"
            )
        rms = np.sqrt(np.mean((u - u.mean(axis=0)) ** 2, axis=0))
        change = np.max(np.abs(u[L:] - u[:-L]), axis=0) if span > L else np.zeros(self.n_inputs)
        if np.any(change > cfg.input_periodic_rtol * np.maximum(rms, 1e-12)):
            j = int(np.argmax(change / np.maximum(rms, 1e-12)))
            return (
                f"input not periodic: input {j} changes by {change[j]:.3g} from one period to "
                "the next (excitation started or changed; waiting for the plant to settle)"
            )
        win_u = u[-cfg.window_samples :]
        win_rms = np.sqrt(np.mean((win_u - win_u.mean(axis=0)) ** 2, axis=0))
        if float(np.max(win_rms)) < cfg.min_excitation_rms:
            return (
                f"too little excitation: input RMS {np.array2string(win_rms, precision=4)} below "
                f"min_excitation_rms = {cfg.min_excitation_rms}"
            )
        return "ok"

    def _evaluate(self) -> list[WindowReport]:
        cfg = self.config
        n = cfg.window_samples
        u, y, stamps, _ = self._ordered(n)
        start_ns, end_ns = int(stamps[0]), int(stamps[-1])
        quality = self._quality()
        datum = None
        if quality == "ok":
            try:
                datum = make_datum(
                    u,
                    y,
                    ts_s=cfg.ts_s,
                    period_samples=cfg.period_samples,
                    convention=cfg.convention,
                )
            except TwotankError as err:
                quality = f"datum rejected: {err}"
        reports = []
        for model in self.models:
            if datum is None:
                reports.append(self._unjudged(model.name, start_ns, end_ns, quality))
                continue
            check_compatible(datum, model)
            t0 = time.perf_counter()
            res = validate(datum, model, method=cfg.method, response=self._responses[model.name])
            elapsed = time.perf_counter() - t0
            state = update_alarm(
                self.alarms[model.name],
                cfg.alarm,
                judged=True,
                invalidated=res.invalidated,
                beta=res.beta,
            )
            self.alarms[model.name] = state
            general = res.method in (Method.SDP, Method.FAST)  # certified lower bound and a witness
            reports.append(
                WindowReport(
                    model=model.name,
                    start_ns=start_ns,
                    end_ns=end_ns,
                    n_periods=cfg.periods_per_window,
                    n_samples=n,
                    judged=True,
                    data_quality="ok",
                    beta=res.beta,
                    beta_lower=res.beta if general else math.nan,
                    beta_upper=res.beta_upper if general else math.nan,
                    margin=res.margin,
                    invalidated=res.invalidated,
                    alarm=state.level,
                    convention=cfg.convention.value,
                    solver=res.method,
                    freqs_hz=res.freqs_hz,
                    w_min=res.w_min,
                    compute_time_s=elapsed,
                )
            )
        return reports

    def _unjudged(self, name: str, start_ns: int, end_ns: int, reason: str) -> WindowReport:
        state = update_alarm(
            self.alarms[name], self.config.alarm, judged=False, invalidated=False, beta=math.nan
        )
        self.alarms[name] = state
        return WindowReport(
            model=name,
            start_ns=start_ns,
            end_ns=end_ns,
            n_periods=self.config.periods_per_window,
            n_samples=self.config.window_samples,
            judged=False,
            data_quality=reason,
            beta=math.nan,
            beta_lower=math.nan,
            beta_upper=math.nan,
            margin=math.nan,
            invalidated=False,
            alarm=state.level,
            convention=self.config.convention.value,
            solver="",
            freqs_hz=np.zeros(0),
            w_min=np.zeros(0),
            compute_time_s=0.0,
        )


def monitor_record(
    stamps_ns: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    config: MonitorConfig,
    models: Sequence[LFTModel],
) -> list[WindowReport]:
    """Offline: feed an already aligned record through the same monitor as the live node.

    Args:
        stamps_ns: (n,) int, sample stamps (ns), on the grid.
        u: (n, n_inputs) float.
        y: (n, n_outputs) float.
        config: monitor settings.
        models: models.
    """
    mon = WindowMonitor(config, models)
    t0 = int(stamps_ns[0])
    ts_ns = round(config.ts_s * NS_PER_S)
    out: list[WindowReport] = []
    for k in range(len(stamps_ns)):
        idx = (int(stamps_ns[k]) - t0 + ts_ns // 2) // ts_ns
        plausible = np.all(np.abs(u[k]) <= 1e6) and np.all(np.abs(y[k]) <= 1e6)  # NaN: False
        flag = None if plausible else "non-finite or implausible value"
        out.extend(
            mon.push(
                Sample(
                    idx, int(stamps_ns[k]), np.asarray(u[k], float), np.asarray(y[k], float), flag
                )
            )
        )
    return out


STREAMS = ("flow_cmd", "height", "temperature")
STREAM_KINDS = {"flow_cmd": COMMAND, "height": 0, "temperature": 1}
"""Event kind of each stream in :meth:`OnlineValidator.feed_many`."""


class OnlineValidator:
    """Aligner + window monitor: the one path from stamped stream values to window reports.

    The live node and bag replay both feed it ``(stream, stamp_ns, value)`` events, where
    ``stream`` is one of :data:`STREAMS` and ``value`` is ``(hot, cold)`` for ``flow_cmd`` and a
    model-unit float for the measurements.

    Args:
        config: monitor settings.
        models: models to validate.
        jitter_fraction: accepted stamp distance from the sample grid (fraction of ts).
    """

    def __init__(
        self, config: MonitorConfig, models: Sequence[LFTModel], *, jitter_fraction: float = 0.25
    ) -> None:
        self.config = config
        self.monitor = WindowMonitor(config, models)
        self.aligner = SampleAligner(
            config.ts_s, 2, ("height", "temperature"), jitter_fraction=jitter_fraction
        )
        self.samples_seen = 0

    def feed(self, stream: str, stamp_ns: int, value: Any) -> list[WindowReport]:
        """One event in, the reports of any window it completes out."""
        if stream == "flow_cmd":
            samples = self.aligner.push_command(stamp_ns, value)
        elif stream in ("height", "temperature"):
            try:
                number = float(value)
            except (TypeError, ValueError) as err:
                raise DatumError(f"{stream} value {value!r} is not a number") from err
            channel = 0 if stream == "height" else 1
            samples = self.aligner.push_measurement(channel, stamp_ns, number)
        else:
            raise DatumError(f"unknown stream {stream!r}; expected one of {STREAMS}")
        if not samples:
            return []
        return self._deliver(samples, None)

    def feed_many(
        self,
        kinds: np.ndarray,
        stamps_ns: np.ndarray,
        values: np.ndarray,
        on_report: Callable[[WindowReport], None] | None = None,
    ) -> list[WindowReport]:
        """A batch of events in arrival order; the same reports as :meth:`feed` one by one.

        Args:
            kinds: (n,) int, :data:`STREAM_KINDS` of each event's stream.
            stamps_ns: (n,) int64 stamps.
            values: (n, 2) float: ``(hot, cold)`` of a command; a measurement (model units)
                in column 0.
            on_report: called with each report as soon as its window is evaluated (while
                ``monitor.last_window()`` still returns that window).
        """
        kinds = np.asarray(kinds)
        if len(kinds) and (kinds.min() < COMMAND or kinds.max() > 1):
            raise DatumError(f"unknown event kind in {np.unique(kinds)}; expected -1, 0 or 1")
        values = np.asarray(values, dtype=float)
        if values.shape != (len(kinds), 2) or len(stamps_ns) != len(kinds):
            raise DatumError(
                f"feed_many needs (n,) kinds and stamps and (n, 2) values, found "
                f"{kinds.shape}, {np.shape(stamps_ns)}, {values.shape}"
            )
        pieces = self.aligner.push_events(kinds, np.asarray(stamps_ns, dtype=np.int64), values)
        return self._deliver(pieces, on_report)

    def _deliver(
        self,
        pieces: Sequence[Sample | SampleBlock],
        on_report: Callable[[WindowReport], None] | None,
    ) -> list[WindowReport]:
        out: list[WindowReport] = []
        monitor = self.monitor
        for piece in pieces:
            if isinstance(piece, SampleBlock):
                self.samples_seen += len(piece)
                out.extend(monitor.push_block(piece, on_report))
                continue
            self.samples_seen += 1
            reports = monitor.push(piece)
            if reports:
                out.extend(reports)
                if on_report is not None:
                    for rep in reports:
                        on_report(rep)
        return out

    def restart(self) -> None:
        """Forget alignment and buffered samples (clock jumped back); alarms are kept."""
        self.aligner.counters.clock_resets += 1
        self.aligner.reset()
        self.monitor.reset_buffer()
