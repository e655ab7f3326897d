"""Sample alignment: stamped stream values onto the sample grid ``t0 + k ts``.

:class:`SampleAligner` puts three streams (valve commands, level, temperature) on the sample
grid: measurements are matched to a grid point within a jitter tolerance, commands are
zero-order held. Duplicates, out-of-order stamps, NaN/inf and gaps are counted and flagged on
the samples they affect; nothing is silently dropped.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from twotank_validation.defaults import JITTER_FRACTION, NS_PER_S
from twotank_validation.errors import DatumError


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
    decimated: int = 0


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
        phase_fit: measurements per output channel whose stamps fix the grid's phase at a
            start or reset (their mean phase modulo ``ts``; they are held back until then
            and aligned in arrival order). A sender's grid is then found under stamp jitter,
            where the first stamp alone can be up to the jitter off it and push jittered
            stamps beyond the tolerance. 0: the grid starts at the first stamp.
        oversampling: messages per grid step of each stream, commands first, then each
            output (all 1 by default). A stream published ``r`` times per step (a grid chosen
            at the rate of a slower sensor) is decimated: a measurement stamped on one of its
            in-between ticks (within the jitter tolerance of that tick) is dropped and counted
            in ``decimated``, and a command is held from the grid point whose tolerance of
            ``ts / r`` it falls in (a zero-order hold sampled at the grid). The grid's phase
            is fit to the streams with the fewest messages per step.
    """

    def __init__(
        self,
        ts_s: float,
        n_inputs: int,
        output_names: Sequence[str],
        *,
        jitter_fraction: float = JITTER_FRACTION,
        reset_after_s: float = 60.0,
        jump_after_s: float = 3600.0,
        max_abs_value: float = 1e6,
        phase_fit: int = 64,
        oversampling: Sequence[int] | None = None,
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
        over = tuple(int(r) for r in (oversampling or (1,) * (1 + self._n_outputs)))
        if len(over) != 1 + self._n_outputs or min(over) < 1:
            raise DatumError(
                f"oversampling needs {1 + self._n_outputs} whole numbers >= 1 (commands, then "
                f"each output), found {over}"
            )
        self._over_y = over[1:]
        self._decimating = max(over) > 1
        # commands: the tolerance of their own tick (the same as the grid's when r = 1)
        self.cmd_tol_ns = round(jitter_fraction * self.ts_ns / over[0])
        # the phase is fit modulo the step of the least oversampled outputs, on their stamps
        r_fit = min(self._over_y, default=1)
        self._fit_channels = frozenset(c for c, r in enumerate(self._over_y) if r == r_fit)
        self._fit_step = self.ts_ns // r_fit
        self._fit_n = max(0, int(phase_fit)) * len(self._fit_channels)
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
        self._held_ns: int | None = None  # stamp of the held command (decimated commands)
        self._held_finite = self.n_inputs == 0
        self.last_command_ns: int | None = None
        self._retry_at = 0  # event (of the current batch) from which to look for a run
        self._off_run = 0  # consecutive off-grid measurements (re-anchor the grid after many)
        self._backoff = self._n_outputs + 1
        self._startup: list[tuple[int, int, float]] = []  # held back until the phase is fit

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
            if self._fit_n:
                return self._fit_phase(channel, stamp_ns, value)
            self.t0_ns = t0 = stamp_ns
        ts = self.ts_ns
        offset = stamp_ns - t0
        k = (offset + self._half_ns) // ts
        # a faster stream's in-between tick (decimated), not a late or lost sample
        between = (
            self._decimating
            and self._over_y[channel] > 1
            and self._between_ticks(channel, offset - k * ts)
        )
        if not between and (
            k > max(self._newest, self.next_index) + self.jump_ns // ts
            or (k < self.next_index and stamp_ns < self.grid_time(self.next_index) - self.reset_ns)
        ):
            # clock jump forwards, or backwards beyond reset_after_s: start over there
            self.counters.clock_resets += 1
            self._clear()
            return self.push_measurement(channel, stamp_ns, value)
        if between or k < self.next_index:
            if between:
                self.counters.decimated += 1
            else:
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

    def _between_ticks(self, channel: int, dev_ns: int) -> bool:
        """Whether a deviation from the grid point is one of the channel's in-between ticks."""
        sub = self.ts_ns // self._over_y[channel]
        j = round(dev_ns / sub)
        return j != 0 and abs(dev_ns - j * sub) <= self.tol_ns // self._over_y[channel]

    def _fit_phase(self, channel: int, stamp_ns: int, value: float) -> list[Sample]:
        """Hold a measurement back until enough have come to fix the grid's phase.

        The grid origin is the first stamp moved to the sender's tick under zero-mean jitter:
        the circular mean of the stamps modulo ``ts`` (a plain mean would fail where the
        stamps straddle a tick boundary), refined by the mean deviation from that grid. Then
        the held measurements are aligned in the order they came.
        """
        held = self._startup
        held.append((channel, stamp_ns, value))
        fit = [s for c, s, _ in held if c in self._fit_channels]
        if len(fit) < self._fit_n:
            return []
        first = fit[0]
        ts = self._fit_step
        angle = 2.0 * math.pi / ts
        c = math.fsum(math.cos(angle * ((s - first) % ts)) for s in fit)
        s_ = math.fsum(math.sin(angle * ((s - first) % ts)) for s in fit)
        shift = round(math.atan2(s_, c) / angle) if math.hypot(c, s_) > 0.0 else 0
        # the circular mean is a coarse estimate where the jitter is a large part of a step:
        # refine with the plain mean of the deviations from the coarse grid (twice)
        for _ in range(2):
            origin = first + shift
            dev = [(s - origin + ts // 2) % ts - ts // 2 for s in fit]
            shift += round(math.fsum(dev) / len(dev))
        self._startup = []
        self.t0_ns = first + shift
        out: list[Sample] = []
        for ch, st, v in held:
            out.extend(self.push_measurement(ch, st, v))
        return out

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
                    if last is None or last < t_k - self.cmd_tol_ns:
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
            limit = t_k + self.cmd_tol_ns
            while cmds and cmds[0][0] <= limit:
                self._held_ns, self._held, self._held_finite = cmds.popleft()
            u = np.array(self._held, dtype=float)
            if flag is None and not self._held_finite:
                flag = (
                    "no valid valve command yet"
                    if self.last_command_ns is None
                    else "non-finite valve command"
                )
            elif (
                self._decimating
                and self._held_ns is not None
                and self._held_ns < t_k - self.cmd_tol_ns
            ):
                # decimated commands: the one of this grid point was lost, and the one held
                # is an in-between tick's, not this sample's value (unusable, recoverable)
                u[:] = math.nan
                flag = flag or (
                    f"gap: no valve command at t = {t_k / NS_PER_S:.3f} s (held "
                    f"{(t_k - self._held_ns) / 1e6:.0f} ms old)"
                )
            if pend is not None:
                del pending[k]
            self.next_index = k + 1
            out.append(Sample(k, t_k, u, np.array(y, dtype=float), flag))
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
                and not self._decimating  # decimated streams are not regular groups
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
        # one event of each kind per group (group events, ny + 1 kinds: each present once)
        ok = _rows_any(kk == COMMAND)
        for kind in range(ny):
            ok &= _rows_any(kk == kind)
        cmd_pos = np.argmin(kk, axis=1)
        grid = t0 + (first + rows) * ts  # t of each group
        is_meas = kk != COMMAND
        offset = ss - t0
        index = (offset + self._half_ns) // ts
        dev = offset - (first + rows)[:, None] * ts
        meas_ok = (index == (first + rows)[:, None]) & (np.abs(dev) <= tol)
        meas_ok &= np.abs(vv[:, :, 0]) <= self.max_abs  # False for NaN and inf too
        ok &= _rows_all(meas_ok | ~is_meas)
        cmd = ss[rows, cmd_pos]
        cmd_u = vv[rows, cmd_pos, :nu]
        ok &= _rows_all(np.abs(cmd_u) <= self.max_abs)
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
        rest = top + 1  # the commands not yet held stay queued
        self._commands = deque(
            (int(t), tuple(r), True) if k >= d else queued[k]
            for k, (t, r) in enumerate(
                zip(seq_t[rest:].tolist(), seq_u[rest:].tolist(), strict=True), start=rest
            )
        )
        self.last_command_ns = int(cmd[-1])
        self.next_index = first + m
        self._newest = first + m - 1
        return SampleBlock(first, grid.astype(np.int64), u, y, flags)


def _rows_all(x: np.ndarray) -> np.ndarray:
    """``x.all(axis=1)`` of a tall (m, k) bool array, column by column.

    One call per column instead of one per row.
    """
    out = x[:, 0].copy()
    for c in range(1, x.shape[1]):
        out &= x[:, c]
    return out


def _rows_any(x: np.ndarray) -> np.ndarray:
    """``x.any(axis=1)`` of a tall (m, k) bool array, column by column."""
    out = x[:, 0].copy()
    for c in range(1, x.shape[1]):
        out |= x[:, c]
    return out
