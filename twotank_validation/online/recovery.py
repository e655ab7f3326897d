"""Isolated unusable samples of a periodic steady state, recovered from the other periods.

On a real network a few messages are lost, late or duplicated. A window is judged in
periodic steady state: the commands repeat exactly every period, and the outputs repeat up to
noise. So a sample that did not arrive is taken from the same phase of the other periods of
the span (the window and its settling periods): the commands exactly, the outputs as the mean
of the other periods' samples at that phase. A window is still judged when no signal has more
than a set fraction of the window recovered (``max_recovered_fraction``, default 2 %); beyond
that, or where a phase is missing in every period, it is not judged, with the reason.

What it does to β (docs/theory.md §7): an output sample replaced by the mean of ``q`` other
periods' samples differs from the one that was lost by a zero-mean error of variance
``(1 + 1/q) σ²`` (σ² the sensor noise variance), and it carries no transient (the window is
steady by the settling gate). ``m`` such samples in a window of ``N`` change the per-bin noise
energy by a fraction of order ``m / N`` (1 % of the window: about 1 % of the energy, so β
by about 0.5 %); ``test/online/test_recovery.py`` measures it against the clean record.

The commands need one more rule. A lost command message is not a gap for the aligner: the
valve holds its last command, and so does the record. Such a sample equals its predecessor
while the periods in which that phase's command was fresh (differs from its predecessor) agree
on a different value; it is recovered like a missing one (and counts against the same cap).

Written here because no library imputes a periodic record by phase with these rules.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Recovery:
    """A span with its recoverable samples filled in, or why it cannot be.

    Attributes:
        u: (n, nu) float, the commands, recovered samples filled in (model units).
        y: (n, ny) float, the outputs, the window's recovered samples filled in.
        recovered: (nu + ny,) int, samples recovered in the window per signal (inputs, then
            outputs; commands of the settling periods are recovered too, not counted).
        reason: why the span cannot be judged (too many or unrecoverable samples), or None.
    """

    u: np.ndarray
    y: np.ndarray
    recovered: np.ndarray
    reason: str | None

    def summary(self, names: Sequence[str]) -> str:
        """``"height 2, temperature 1"``: the signals with recovered samples."""
        return ", ".join(
            f"{name} {int(c)}" for name, c in zip(names, self.recovered, strict=True) if c
        )


def _off_grid_channel(flag: str, output_names: Sequence[str]) -> int | None:
    for j, name in enumerate(output_names):
        if flag.startswith(f"{name} stamp ") and "off the sample grid" in flag:
            return j
    return None


def missing_mask(
    u: np.ndarray, y: np.ndarray, flags: Sequence[str | None], output_names: Sequence[str]
) -> np.ndarray:
    """Which entries of flagged samples are unusable.

    Non-finite entries (gaps, non-finite or implausible values, no valid command), and the
    output a sample's off-grid stamp belongs to.

    Args:
        u: (n, nu) float, commands.
        y: (n, ny) float, outputs.
        flags: (n,) the aligner's flag of each sample (None: clean).
        output_names: names of the outputs, as the aligner's flags name them.

    Returns:
        (n, nu + ny) bool.
    """
    values = np.hstack([u, y])
    bad = ~np.isfinite(values)
    nu = u.shape[1]
    for k, flag in enumerate(flags):
        if flag is None:
            continue
        j = _off_grid_channel(flag, output_names)
        if j is not None:
            bad[k, nu + j] = True
        elif not bad[k].any():
            bad[k, nu:] = True  # a flag naming nothing we can place: the outputs are suspect
    return bad


def _held_commands(u: np.ndarray, bad_u: np.ndarray, period: int, rtol: float) -> np.ndarray:
    """Commands held from the previous sample where the other periods agree on another value.

    That is how a lost command message shows in the record (the valve holds its command).

    Args:
        u: (n, nu) float, commands.
        bad_u: (n, nu) bool, unusable commands.
        period: samples per period.
        rtol: tolerance of "the commands agree", relative to each command's RMS.

    Returns:
        (n, nu) bool.
    """
    n, nu = u.shape
    held = np.zeros((n, nu), dtype=bool)
    q = n // period
    if q < 2 or n % period:
        return held
    ok = ~bad_u
    same_as_before = np.zeros((n, nu), dtype=bool)
    same_as_before[1:] = (u[1:] == u[:-1]) & ok[1:] & ok[:-1]
    for j in range(nu):
        if not same_as_before[:, j].any():
            continue
        col = u[:, j]
        rms = float(np.sqrt(np.mean((col[ok[:, j]] - col[ok[:, j]].mean()) ** 2)))
        tol = rtol * max(rms, 1e-12)
        rows = col.reshape(q, period)
        same = same_as_before[:, j].reshape(q, period)
        # the value at each phase from the periods where it was fresh (not equal to its
        # predecessor: received, not held); held samples that differ from it were lost
        fresh = ok[:, j].reshape(q, period) & ~same
        have = fresh.any(axis=0)
        lo = np.where(fresh, rows, np.inf).min(axis=0)
        hi = np.where(fresh, rows, -np.inf).max(axis=0)
        agree = have & (hi - lo <= tol)
        with np.errstate(invalid="ignore"):  # inf - inf at phases with no fresh sample
            differs = np.abs(rows - lo[None, :]) > tol
        held[:, j] = (same & agree[None, :] & differs).ravel()
    return held


def recover_span(
    u: np.ndarray,
    y: np.ndarray,
    flags: Sequence[str | None],
    *,
    period: int,
    window: int,
    max_fraction: float,
    names: Sequence[str],
    output_names: Sequence[str],
    rtol: float = 1e-6,
) -> Recovery:
    """Fill the recoverable samples of a span in from the same phase of its other periods.

    Args:
        u: (n, nu) float, commands of the span (window and settling periods, time order).
        y: (n, ny) float, outputs of the span.
        flags: (n,) the aligner's flag of each sample (None: clean).
        period: samples per excitation period.
        window: samples of the window (the last ``window`` of the span).
        max_fraction: largest fraction of the window that may be recovered per signal (0:
            nothing is recovered; a flagged sample leaves the window unjudged).
        names: the signals' names, inputs then outputs (for the reason).
        output_names: the outputs' names as the aligner's flags spell them.
        rtol: tolerance of "the commands agree", relative to each command's RMS.

    Returns:
        The span with the samples filled in, the counts, and the reason if it cannot be.
    """
    n, nu = u.shape
    n_signals = nu + y.shape[1]
    flagged = flags.count(None) != len(flags)
    if max_fraction <= 0.0:
        reason = "unusable samples (recovery off)" if flagged else None
        return Recovery(u, y, np.zeros(n_signals, int), reason)
    if flagged:
        bad = missing_mask(u, y, flags, output_names)
        bad[:, :nu] |= _held_commands(u, bad[:, :nu], period, rtol)
    else:  # nothing flagged: only held commands can be unusable
        held = _held_commands(u, np.zeros((n, nu), dtype=bool), period, rtol)
        if not held.any():
            return Recovery(u, y, np.zeros(n_signals, int), None)
        bad = np.zeros((n, n_signals), dtype=bool)
        bad[:, :nu] = held
    if not bad.any():
        return Recovery(u, y, np.zeros(n_signals, int), None)
    in_window = np.arange(n) >= n - window
    # outputs matter only in the window (the settling periods' are not used); commands are
    # recovered in the whole span (the periodicity gate reads it), exactly, and count
    # against the cap in the window only, like the outputs
    need = bad.copy()
    need[:, nu:] &= in_window[:, None]
    counts = (need & in_window[:, None]).sum(axis=0)
    cap = int(np.floor(max_fraction * window))
    if np.any(counts > cap):
        j = int(np.argmax(counts - cap))
        return Recovery(
            u,
            y,
            counts,
            f"{int(counts[j])} unusable {names[j]} sample(s), more than the {cap} "
            f"({100 * max_fraction:g} % of the window) that can be recovered per signal",
        )
    values = np.hstack([u, y])
    filled = values.copy()
    phase = np.arange(n) % period
    for k, j in zip(*np.nonzero(need), strict=True):
        donors = [i for i in range(phase[k], n, period) if i != k and not bad[i, j]]
        if not donors:
            return Recovery(
                u,
                y,
                counts,
                f"{names[j]} sample at phase {phase[k]} of the period is unusable in every "
                "period of the window and its settling periods",
            )
        filled[k, j] = float(np.mean(values[donors, j]))
    return Recovery(filled[:, :nu], filled[:, nu:], counts, None)
