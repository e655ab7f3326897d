"""Timing of a recording inferred from its data: the sample period and the excitation period.

A user who replays a recording without ``--ts``/``--period`` gets the values the data show,
said out loud; one who passes them gets a warning where the data contradict them. Both
functions are pure and take plain arrays:

* :func:`infer_sample_period`: the command stamps' grid. The spacing of most consecutive
  stamps (their median) gives the grid roughly and so the number of steps in each gap; the
  whole span divided by the number of steps gives it to the nanosecond, whatever messages
  were lost on the way.
* :func:`infer_excitation_period`: the smallest shift under which the commands repeat, from
  the excitation's first sample on. Every shift's mean squared difference is computed at once
  with FFT correlations (masked for lost samples); the few shifts that come out near zero are
  then checked sample by sample to the window gate's own tolerance. A measured input (a
  sensor's reading, the interface map's ``kind: measured``) repeats only within its noise:
  for it the shift is the first dip of the mean squared difference (a local minimum) within
  twice the squared noise the window gate tolerates (``MEASURED_INPUT_RTOL``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from twotank_validation.core.datum import MEASURED_INPUT_RTOL
from twotank_validation.defaults import NS_PER_S

MIN_PERIOD_SAMPLES = 4
"""Shortest excitation period considered (samples); the monitor needs at least 4."""

_ON_GRID = 0.25
"""A stamp spacing within this fraction of the grid step counts as one step."""

_CANDIDATE_RTOL = 1e-8
"""Shifts whose mean squared difference is below this fraction of the variance are checked."""


@dataclass(frozen=True)
class SamplePeriod:
    """The sample grid the stamps lie on.

    Attributes:
        ts_s: grid step (s), to the nanosecond.
        on_grid: fraction of consecutive stamp spacings that are one step (within 25 %).
        steps_missing: grid steps in the span with no stamp (lost messages).
        n_stamps: distinct stamps used.
    """

    ts_s: float
    on_grid: float
    steps_missing: int
    n_stamps: int


def infer_sample_period(stamps_ns: np.ndarray) -> SamplePeriod | None:
    """Infer the sample period from message stamps.

    Args:
        stamps_ns: (n,) int, stamps in nanoseconds (any order; repeats are dropped).

    Returns:
        The grid, or None when fewer than 3 distinct stamps are given.
    """
    t = np.unique(np.asarray(stamps_ns, dtype=np.int64))
    if len(t) < 3:
        return None
    d = np.diff(t)
    step0 = float(np.median(d))
    span = int(t[-1] - t[0])
    # each gap counted in whole steps on its own, so that a rough step0 cannot miscount a
    # long span (an error of 0.1 % would lose 5 steps in 5000)
    steps = max(1, int(np.sum(np.maximum(np.rint(d / step0), 1))))
    ts_ns = round(span / steps)
    on_grid = float(np.mean(np.abs(d - ts_ns) <= _ON_GRID * ts_ns))
    return SamplePeriod(
        ts_s=ts_ns / NS_PER_S,
        on_grid=on_grid,
        steps_missing=max(0, steps + 1 - len(t)),
        n_stamps=len(t),
    )


def grid_samples(stamps_ns: np.ndarray, values: np.ndarray, ts_s: float) -> np.ndarray:
    """Put stamped values on the sample grid of step ``ts_s``, NaN where none arrived.

    Args:
        stamps_ns: (n,) int, stamps in nanoseconds.
        values: (n, m) float, the values at those stamps.
        ts_s: grid step (s).

    Returns:
        (k, m) float, one row per grid step from the first stamp to the last (a repeated
        step keeps its last value).
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    vals = np.asarray(values, dtype=float).reshape(len(stamps), -1)
    if len(stamps) == 0:
        return np.empty((0, vals.shape[1]))
    ts_ns = round(ts_s * NS_PER_S)
    idx = np.rint((stamps - stamps.min()) / ts_ns).astype(np.int64)
    out = np.full((int(idx.max()) + 1, vals.shape[1]), np.nan)
    out[idx] = vals
    return out


def _correlate(a: np.ndarray, b: np.ndarray, n_fft: int) -> np.ndarray:
    """``c[p] = sum_k a[k] b[k + p]`` for every shift ``p >= 0`` (columns summed)."""
    fa = np.fft.rfft(a, n_fft, axis=0)
    fb = np.fft.rfft(b, n_fft, axis=0)
    return np.fft.irfft(np.conj(fa) * fb, n_fft, axis=0)[: len(a)].sum(axis=1)


def infer_excitation_period(
    u: np.ndarray, rtol: float = 1e-6, measured: np.ndarray | None = None
) -> int | None:
    """The smallest shift (samples) under which the commands repeat.

    Only the part from the excitation's start on is used: the first sample that differs from
    the first row (a record that starts with the inputs held still), or the whole record. A
    shift counts when, over every pair of samples it lines up (both present), no commanded
    input changes by more than ``rtol`` times its RMS, every measured input's mean squared
    change is a local minimum over the shifts and at most ``2 MEASURED_INPUT_RTOL^2`` times
    its mean square (two copies of its noise), and at least one whole period is compared.

    Args:
        u: (n, m) float, inputs on the sample grid (NaN: not received).
        rtol: tolerance relative to each input's RMS (the window gate's
            ``input_periodic_rtol``).
        measured: (m,) bool, the inputs read by a sensor (repeating within their noise);
            None: every input commanded.

    Returns:
        The period in samples, or None when the commands do not repeat within the record.
    """
    x = np.asarray(u, dtype=float)
    x = x.reshape(len(x), -1)
    ok_rows = np.all(np.isfinite(x), axis=1)
    if not np.any(ok_rows):
        return None
    first = x[np.argmax(ok_rows)]
    moved = ok_rows & np.any(np.abs(x - first) > 0.0, axis=1)
    if not np.any(moved):
        return None  # the inputs never move: nothing repeats
    start = int(np.argmax(moved))
    z = x[start:]
    n = len(z)
    mask = np.isfinite(z).astype(float)
    mean = np.nanmean(z, axis=0)
    zc = np.where(mask > 0, z - mean, 0.0)
    rms = np.sqrt(np.nansum(zc**2, axis=0) / np.maximum(mask.sum(axis=0), 1.0))
    scale = np.where(rms > 0, rms, 1.0)
    zs = zc / scale
    meas = np.zeros(x.shape[1], bool) if measured is None else np.asarray(measured, bool)
    n_fft = 1 << (2 * n - 1).bit_length()
    pairs = _correlate(mask, mask, n_fft)
    shifts = np.arange(n)
    usable = (shifts >= MIN_PERIOD_SAMPLES) & (shifts <= n // 2) & (pairs >= 0.5 * shifts)
    candidate = usable.copy()
    if not meas.all():
        candidate &= _msd(zs[:, ~meas], mask[:, ~meas], n_fft) < _CANDIDATE_RTOL
    if meas.any():
        noisy = _msd(zs[:, meas], mask[:, meas], n_fft)
        dip = np.zeros(n, bool)
        dip[1:-1] = (noisy[1:-1] < noisy[:-2]) & (noisy[1:-1] <= noisy[2:])
        candidate &= dip & (noisy <= 2.0 * MEASURED_INPUT_RTOL**2)
    for p in np.flatnonzero(candidate):
        a, b = z[:-p, ~meas], z[p:, ~meas]
        both = np.all(np.isfinite(a) & np.isfinite(b), axis=1)
        if np.count_nonzero(both) < p:
            continue
        change = np.max(np.abs(a[both] - b[both]), axis=0, initial=0.0)
        if np.all(change <= rtol * np.maximum(rms[~meas], 1e-12)):
            return int(p)
    return None


def _msd(zs: np.ndarray, mask: np.ndarray, n_fft: int) -> np.ndarray:
    """(n,) mean over aligned valid pairs (all columns) of ``(z[k] - z[k+p])^2``, every shift.

    By FFT correlations; ``zs`` (n, m) scaled to unit RMS and zero where not valid, ``mask``
    (n, m) 1 where valid.
    """
    sq = zs**2
    diff2 = (
        _correlate(sq, mask, n_fft) + _correlate(mask, sq, n_fft) - 2 * _correlate(zs, zs, n_fft)
    )
    return np.asarray(diff2 / np.maximum(_correlate(mask, mask, n_fft), 1.0))


@dataclass(frozen=True)
class StreamRates:
    """The sample grid the slowest stream supports, as whole steps of the command grid.

    Attributes:
        factor: command-grid steps per sample of the supported grid (1: the commands' own).
        oversampling: messages per sample of the supported grid, per stream (the commands
            and each output with a known rate).
        odd: streams whose period is not a whole multiple of the commands' (s), left out.
    """

    factor: int
    oversampling: dict[str, int]
    odd: dict[str, float]


def supported_rate(
    command_ts_s: float, output_ts_s: dict[str, float], command_stream: str, rtol: float = 0.01
) -> StreamRates:
    """The grid at which every output has a sample: the commands' step times the outputs' steps.

    An output published every ``m`` command steps (``m`` whole, within ``rtol``) has a sample
    on every ``m``-th step only; validating at the least common multiple ``L`` of the ``m``
    gives every signal a sample at every step, each faster stream decimated by ``L / m``.
    An output published ``q`` times per command step is decimated by ``L q``.

    Args:
        command_ts_s: the commands' period (s).
        output_ts_s: each output's period (s), from its stamps.
        command_stream: the commands' stream name (its key in ``oversampling``).
        rtol: accepted relative distance of a ratio from a whole number.

    Returns:
        The factor ``L`` and the messages per sample of each stream.
    """
    steps: dict[str, int] = {}
    faster: dict[str, int] = {}  # outputs published q times per command step
    odd: dict[str, float] = {}
    for name, ts in output_ts_s.items():
        ratio = ts / command_ts_s
        m, q = round(ratio), round(1.0 / ratio)
        if m >= 1 and abs(ratio - m) <= rtol * m:
            steps[name] = m
        elif q >= 2 and abs(1.0 / ratio - q) <= rtol * q:
            faster[name] = q
        else:
            odd[name] = ts
    factor = math.lcm(*steps.values()) if steps else 1
    over = (
        {command_stream: factor}
        | {name: factor // m for name, m in steps.items()}
        | {name: factor * q for name, q in faster.items()}
    )
    return StreamRates(factor=factor, oversampling=over, odd=odd)
