"""Periodic excitation signals for the frequency-domain validation experiment.

Each valve gets an exactly periodic, zero-mean signal of ``period_samples`` samples, repeated
for ``settle_periods`` periods (transient, discarded) and ``record_periods`` periods
(recorded). With an exactly periodic input and a settled plant, the DFT of one recorded period
has no leakage, so the input-output data can be compared with the model bin by bin.

Two signals are available: circularly low-pass filtered Gaussian noise (Butterworth response
applied at the DFT bins) and a random-phase multisine with a flat amplitude spectrum.
"""

from __future__ import annotations

import copy
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import scipy.signal
import yaml
from numpy.typing import NDArray

from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.errors import DatumError
from twotank_validation.settings import FlatSetting, check_settings, flat, from_flat, setting

__all__ = [
    "EXCITATION_KINDS",
    "LINE_SETS",
    "RIG_DESIGN",
    "ExcitationConfig",
    "ExcitationDesign",
    "ExcitationLines",
    "OddMultisineLines",
    "RecordedDesign",
    "crest_factor",
    "design_document",
    "design_path",
    "excitation_commands",
    "excitation_period",
    "filtered_noise_period",
    "low_crest_multisine",
    "multisine_harmonics",
    "multisine_period",
    "odd_multisine_lines",
    "parse_detection",
    "read_design",
    "record_slice",
    "take_design",
    "write_design",
]

FloatArray = NDArray[np.float64]

EXCITATION_KINDS: tuple[str, ...] = ("filtered_noise", "multisine")
"""The accepted values of ``ExcitationConfig.kind``."""

_VALVES = ("hot", "cold")
_BIN_TOLERANCE = 1e-9
"""Relative slack when deciding whether a harmonic lies on a band edge (rounding of k/(n ts))."""


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def _check_period_args(n: int, ts_s: float) -> None:
    if not _is_int(n) or n < 4:
        raise DatumError(f"period length n={n!r} must be an integer >= 4 samples")
    if not (math.isfinite(ts_s) and ts_s > 0.0):
        raise DatumError(f"ts_s={ts_s!r} must be a positive, finite sample period in seconds")


def _round_down(value: float, digits: int = 4) -> float:
    """Round a non-negative ``value`` down to ``digits`` significant digits (safe advice)."""
    if value <= 0.0:
        return 0.0
    scale = 10.0 ** (digits - 1 - math.floor(math.log10(value)))
    return math.floor(value * scale) / scale


def _unit_rms(x: FloatArray, what: str) -> FloatArray:
    x = x - x.mean()
    rms = float(np.sqrt(np.mean(x**2)))
    if not rms > 0.0:
        raise DatumError(f"{what} has no energy in its band; widen the band or lengthen the period")
    return np.asarray(x / rms, dtype=np.float64)


def multisine_harmonics(
    n: int, ts_s: float, f_min_hz: float, f_max_hz: float, odd_only: bool
) -> NDArray[np.int64]:
    """Return the DFT bins k (frequency k / (n ts_s)) a multisine excites.

    Args:
        n: Period length, samples.
        ts_s: Sample period, seconds.
        f_min_hz: Lowest frequency of the band, Hz, > 0.
        f_max_hz: Highest frequency of the band, Hz, below Nyquist 1 / (2 ts_s).
        odd_only: Keep odd k only.

    Returns:
        (n_harmonics,) int, increasing, each in 1 .. ceil(n/2) - 1 (never DC nor Nyquist);
        band edges count as inside (to a relative 1e-9).
    """
    span = n * ts_s
    k_lo = max(1, math.ceil(f_min_hz * span * (1.0 - _BIN_TOLERANCE)))
    k_hi = min((n - 1) // 2, math.floor(f_max_hz * span * (1.0 + _BIN_TOLERANCE)))
    k = np.arange(k_lo, k_hi + 1, dtype=np.int64)
    if odd_only:
        k = k[k % 2 == 1]
    return k


def filtered_noise_period(
    n: int, ts_s: float, cutoff_hz: float, order: int, rng: np.random.Generator
) -> FloatArray:
    """One period of circularly low-pass filtered white Gaussian noise.

    Draws ``rng.standard_normal(n)``, multiplies its DFT by the digital Butterworth response
    (``scipy.signal.butter(order, cutoff_hz, fs=1/ts_s)``, evaluated with ``sosfreqz`` at the
    DFT bins k / (n ts_s)), removes the DC bin and transforms back. The result is therefore
    exactly periodic with period n.

    Args:
        n: Period length, samples, >= 4.
        ts_s: Sample period, seconds.
        cutoff_hz: Low-pass -3 dB frequency, Hz, below Nyquist 1 / (2 ts_s).
        order: Butterworth order, >= 1.
        rng: Random generator (consumed: one draw of n normals).

    Returns:
        (n,) float: zero mean, unit RMS.

    Raises:
        DatumError: If an argument is out of range.
    """
    _check_period_args(n, ts_s)
    fs = 1.0 / ts_s
    if not (math.isfinite(cutoff_hz) and 0.0 < cutoff_hz < fs / 2.0):
        raise DatumError(
            f"cutoff_hz={cutoff_hz!r} must lie strictly between 0 and the Nyquist "
            f"frequency {fs / 2.0:.6g} Hz"
        )
    if not _is_int(order) or order < 1:
        raise DatumError(f"order={order!r} must be an integer >= 1")
    white = rng.standard_normal(n)
    sos = scipy.signal.butter(order, cutoff_hz, btype="lowpass", output="sos", fs=fs)
    freqs = np.fft.rfftfreq(n, d=ts_s)
    _, response = scipy.signal.sosfreqz(sos, worN=freqs, fs=fs)
    spectrum = np.fft.rfft(white) * response
    spectrum[0] = 0.0
    return _unit_rms(np.fft.irfft(spectrum, n=n), "filtered noise")


def multisine_period(  # noqa: PLR0917 - signature fixed by the package API
    n: int,
    ts_s: float,
    f_min_hz: float,
    f_max_hz: float,
    odd_only: bool,
    rng: np.random.Generator,
) -> FloatArray:
    """One period of a random-phase multisine with a flat amplitude spectrum.

    x[t] = sum_k cos(2 pi k t / n + phi_k) over the bins k of ``multisine_harmonics`` (odd k
    only if ``odd_only``), phases phi_k uniform in [0, 2 pi), then scaled to unit RMS.

    Args:
        n: Period length, samples, >= 4.
        ts_s: Sample period, seconds.
        f_min_hz: Lowest frequency, Hz, > 0.
        f_max_hz: Highest frequency, Hz, >= f_min_hz and below Nyquist 1 / (2 ts_s).
        odd_only: Excite odd harmonics of the period only.
        rng: Random generator (consumed: one draw of n_harmonics uniforms).

    Returns:
        (n,) float: zero mean, unit RMS, exactly periodic.

    Raises:
        DatumError: If the band is invalid or contains no (odd) harmonic of 1 / (n ts_s).
    """
    _check_period_args(n, ts_s)
    nyquist = 0.5 / ts_s
    if not (math.isfinite(f_min_hz) and math.isfinite(f_max_hz)):
        raise DatumError(f"f_min_hz={f_min_hz!r}, f_max_hz={f_max_hz!r} must be finite")
    if not 0.0 < f_min_hz <= f_max_hz < nyquist:
        raise DatumError(
            f"multisine band f_min_hz={f_min_hz!r} .. f_max_hz={f_max_hz!r} must satisfy "
            f"0 < f_min_hz <= f_max_hz < Nyquist = {nyquist:.6g} Hz"
        )
    k = multisine_harmonics(n, ts_s, f_min_hz, f_max_hz, odd_only)
    if k.size == 0:
        parity = "odd " if odd_only else ""
        raise DatumError(
            f"the band {f_min_hz:.6g} .. {f_max_hz:.6g} Hz contains no {parity}harmonic of "
            f"1/(n ts) = {1.0 / (n * ts_s):.6g} Hz; widen the band or lengthen the period"
        )
    phases = rng.uniform(0.0, 2.0 * np.pi, size=k.size)
    spectrum = np.zeros(n // 2 + 1, dtype=np.complex128)
    spectrum[k] = np.exp(1j * phases)
    return _unit_rms(np.fft.irfft(spectrum, n=n), "multisine")


def take_design(owner: object, design: ExcitationDesign, error: type[Exception]) -> None:
    """Set a config's short-form excitation fields from ``design``.

    The short form (``kind``, ``period_samples``, ``f_min_hz``, ``f_max_hz``, ``odd_only``,
    ``cutoff_hz``, ``order``, ``seed``) of :class:`ExcitationConfig` and of the model
    simulator's ``ModelExcitation``; a field given too (not at its default) must agree.
    Where the owner's default is None (the model simulator's "automatic"), a zero of the
    design is None.

    Raises:
        error: ``design`` is no design, or a given field disagrees with it.
    """
    if not isinstance(design, ExcitationDesign):
        raise error(f"excitation design must be an ExcitationDesign, got {design!r}")
    fields = type(owner).__dataclass_fields__  # type: ignore[attr-defined]
    short = {
        "kind": design.kind,
        "period_samples": design.period_samples,
        "f_min_hz": design.f_min_hz,
        "f_max_hz": design.f_max_hz,
        "odd_only": design.lines != "all",
        "cutoff_hz": design.cutoff_hz,
        "order": design.order,
        "seed": design.seed,
    }
    for key, value in short.items():
        default = fields[key].default
        wanted = None if default is None and not value else value
        given = getattr(owner, key)
        if given not in (default, wanted):
            raise error(
                f"excitation {key}={given!r} disagrees with its design's {wanted!r}: give "
                "either the design or the short form"
            )
        object.__setattr__(owner, key, wanted)


@dataclass(frozen=True)
class ExcitationConfig:
    """Design of the periodic excitation of both valves.

    Attributes:
        kind: "filtered_noise" or "multisine".
        ts_s: Sample period, seconds, > 0.
        period_samples: Samples per period, >= 4.
        settle_periods: Periods applied before recording, >= 0; the paper settles for at least
            5 (the default) so that the tank transient (time constants ~54 s and ~122 s) dies
            out.
        record_periods: Periods recorded after settling, >= 1.
        rms: Per-valve RMS [hot, cold] of the deviation, model units, >= 0 (0 leaves that
            valve at its offset).
        cutoff_hz: Filtered noise: Butterworth -3 dB frequency, Hz, below Nyquist.
        order: Filtered noise: Butterworth order, >= 1.
        f_min_hz: Multisine: lowest excited frequency, Hz, > 0.
        f_max_hz: Multisine: highest excited frequency, Hz, below Nyquist.
        odd_only: Multisine: excite odd harmonics of the period only.
        seed: Seed of numpy's default_rng for the random noise or phases.
        design: The whole design (:class:`ExcitationDesign`: odd lines, detection lines,
            line grid, realisations, crest-factor minimisation). None: built of the fields
            above (their short form); given: those fields are set from it (a field given
            too must agree). The signal is drawn from :attr:`the_design`, this or the short
            form's.
    """

    kind: str = "filtered_noise"
    ts_s: float = TS_S
    period_samples: int = PERIOD_SAMPLES
    settle_periods: int = 5
    record_periods: int = 2
    rms: tuple[float, float] = (0.1, 0.1)
    cutoff_hz: float = 0.01
    order: int = 2
    f_min_hz: float = 1.0 / 204.8
    f_max_hz: float = 0.05
    odd_only: bool = False
    seed: int = 0
    design: ExcitationDesign | None = None
    _design: ExcitationDesign = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.design is not None:
            take_design(self, self.design, DatumError)
        if self.kind not in EXCITATION_KINDS:
            raise DatumError(f"kind={self.kind!r} is unknown; use one of {EXCITATION_KINDS}")
        _check_period_args(self.period_samples, self.ts_s)
        if not _is_int(self.settle_periods) or self.settle_periods < 0:
            raise DatumError(
                f"settle_periods={self.settle_periods!r} must be an integer >= 0 (paper: >= 5)"
            )
        if not _is_int(self.record_periods) or self.record_periods < 1:
            raise DatumError(f"record_periods={self.record_periods!r} must be an integer >= 1")
        try:
            rms = tuple(self.rms)
        except TypeError:
            rms = ()
        if len(rms) != 2 or not all(
            isinstance(r, int | float) and not isinstance(r, bool) and math.isfinite(r) and r >= 0
            for r in rms
        ):
            raise DatumError(
                f"rms={self.rms!r} must be two finite, non-negative numbers [hot, cold] "
                "in model units"
            )
        object.__setattr__(self, "rms", (float(rms[0]), float(rms[1])))
        if not _is_int(self.seed):
            raise DatumError(f"seed={self.seed!r} must be an integer")
        nyquist = 0.5 / self.ts_s
        if self.kind == "filtered_noise":
            if not (math.isfinite(self.cutoff_hz) and 0.0 < self.cutoff_hz < nyquist):
                raise DatumError(
                    f"cutoff_hz={self.cutoff_hz!r} must lie strictly between 0 and the "
                    f"Nyquist frequency {nyquist:.6g} Hz of ts_s={self.ts_s}"
                )
            if not _is_int(self.order) or self.order < 1:
                raise DatumError(f"order={self.order!r} must be an integer >= 1")
        else:
            if not (
                math.isfinite(self.f_min_hz)
                and math.isfinite(self.f_max_hz)
                and 0.0 < self.f_min_hz <= self.f_max_hz < nyquist
            ):
                raise DatumError(
                    f"multisine band f_min_hz={self.f_min_hz!r} .. f_max_hz={self.f_max_hz!r} "
                    f"must satisfy 0 < f_min_hz <= f_max_hz < Nyquist = {nyquist:.6g} Hz"
                )
            if self.harmonics().size == 0:
                parity = "odd " if self.odd_only else ""
                raise DatumError(
                    f"the band {self.f_min_hz:.6g} .. {self.f_max_hz:.6g} Hz contains no "
                    f"{parity}harmonic of 1/(period_samples ts_s) = "
                    f"{1.0 / (self.period_samples * self.ts_s):.6g} Hz; widen the band or "
                    "lengthen the period"
                )

        if self.design is not None:
            object.__setattr__(self, "_design", self.design)
        else:
            object.__setattr__(
                self,
                "_design",
                ExcitationDesign(
                    kind=self.kind,
                    period_samples=self.period_samples,
                    f_min_hz=self.f_min_hz,
                    f_max_hz=self.f_max_hz,
                    lines="odd" if self.odd_only else "all",
                    cutoff_hz=self.cutoff_hz,
                    order=self.order,
                    seed=self.seed,
                ),
            )

    @property
    def the_design(self) -> ExcitationDesign:
        """The design the signal is drawn from: ``design``, or the short form's."""
        return self._design

    @property
    def period_s(self) -> float:
        """Length of one period, seconds."""
        return self.period_samples * self.ts_s

    @property
    def total_samples(self) -> int:
        """Samples of the whole experiment: period_samples (settle + record periods)."""
        return self.period_samples * (self.settle_periods + self.record_periods)

    def harmonics(self) -> NDArray[np.int64]:
        """Return the multisine's DFT bins of one period, (n_harmonics,) int (see kind)."""
        return multisine_harmonics(
            self.period_samples, self.ts_s, self.f_min_hz, self.f_max_hz, self.odd_only
        )


def excitation_period(config: ExcitationConfig) -> FloatArray:
    """One cycle of the excitation of both valves: one period for a single realisation.

    Drawn by the design (:meth:`ExcitationDesign.cycle`): the two columns one after the
    other from ``default_rng(config.seed)`` (hot first), so they are independent
    realisations; with several realisations each is tiled over its periods.

    Args:
        config: Excitation design.

    Returns:
        (cycle_periods period_samples, 2) float, model units: zero-mean deviations
        [hot, cold], column i with RMS ``config.rms[i]``.
    """
    return config.the_design.cycle(config.ts_s, np.asarray(config.rms, dtype=np.float64))


def excitation_commands(config: ExcitationConfig, offset: FloatArray) -> FloatArray:
    """Absolute valve commands of the whole experiment: offset plus the tiled period.

    Args:
        config: Excitation design.
        offset: (2,) float, model units: the operating commands [hot, cold], e.g.
            ``OperatingPoint.commands``.

    Returns:
        (period_samples (settle_periods + record_periods), 2) float, model units.

    Raises:
        DatumError: If ``offset`` is not a finite (2,) array or if any command leaves [0, 1]
            (the message names the valve, the excess and an rms that would fit).
    """
    off = np.asarray(offset, dtype=np.float64)
    if off.shape != (2,) or not np.all(np.isfinite(off)):
        raise DatumError(f"offset must be a finite (2,) array [hot, cold], got {off!r}")
    period = excitation_period(config)
    for i, valve in enumerate(_VALVES):
        lo, hi = off[i] + period[:, i].min(), off[i] + period[:, i].max()
        if lo < 0.0 or hi > 1.0:
            excess = max(-lo, hi - 1.0)
            # Largest rms for which this period fits into [0, 1] around the offset.
            limits = [math.inf]
            low, high = float(period[:, i].min()), float(period[:, i].max())
            if low < 0.0:
                limits.append(config.rms[i] * max(off[i], 0.0) / -low)
            if high > 0.0:
                limits.append(config.rms[i] * max(1.0 - off[i], 0.0) / high)
            if 0.0 <= off[i] <= 1.0 and min(limits) < math.inf:
                advice = f"use rms[{i}] <= {_round_down(min(limits))} instead of "
                advice += f"{config.rms[i]:.4g}, or move the offset"
            else:
                advice = "move the offset into [0, 1]"
            raise DatumError(
                f"{valve} valve command leaves [0, 1] by {excess:.4g} (range {lo:.4g} .. "
                f"{hi:.4g} around offset {off[i]:.4g}); {advice}"
            )
    total = config.total_samples
    return np.asarray(off + np.tile(period, (-(-total // len(period)), 1))[:total])


def record_slice(config: ExcitationConfig) -> slice:
    """The samples of the recorded periods (after settling) within excitation_commands.

    Returns:
        slice(period_samples settle_periods, period_samples (settle_periods + record_periods)).
    """
    start = config.period_samples * config.settle_periods
    return slice(start, start + config.period_samples * config.record_periods)


# ----------------------------------------------------------------- design for identification


@dataclass(frozen=True)
class OddMultisineLines:
    """The lines of an odd random-phase multisine with detection lines (one period's DFT).

    Attributes:
        excited: (n_excited,) int, the odd lines carrying the signal.
        detection: (n_detection,) int, the odd lines in the band left out: where odd
            nonlinear distortion shows (the even lines show even distortion).
        first: the band's first line.
        last: the band's last line.
    """

    excited: NDArray[np.int64]
    detection: NDArray[np.int64]
    first: int
    last: int


def odd_multisine_lines(
    n: int,
    ts_s: float,
    f_min_hz: float,
    f_max_hz: float,
    *,
    group: int,
    rng: np.random.Generator,
) -> OddMultisineLines:
    """The odd lines of the band, one in every ``group`` consecutive ones left out at random.

    The design of Pintelon & Schoukens (2012, sec. 4.4): exciting odd lines only keeps even
    distortion off the excited lines; leaving one odd line out in every group leaves room to
    see odd distortion.

    Args:
        n: period length, samples.
        ts_s: sample period, s.
        f_min_hz: lowest frequency, Hz.
        f_max_hz: highest frequency, Hz, below Nyquist.
        group: odd lines per group (one left out in each; 0 or 1: none left out).
        rng: draws which line of each group is left out.

    Raises:
        DatumError: no odd line in the band, or a group of 2 or more with fewer lines than
            the group.
    """
    odd = multisine_harmonics(n, ts_s, f_min_hz, f_max_hz, odd_only=True)
    if odd.size == 0:
        raise DatumError(
            f"the band {f_min_hz:.6g} .. {f_max_hz:.6g} Hz holds no odd line of "
            f"1/(n ts) = {1.0 / (n * ts_s):.6g} Hz: widen the band or lengthen the period"
        )
    if group >= 2 and odd.size < group:
        raise DatumError(
            f"the band holds {odd.size} odd line(s), fewer than a group of {group}: widen "
            "the band or make the groups smaller"
        )
    keep = np.ones(odd.size, dtype=bool)
    if group >= 2:
        for start in range(0, odd.size - group + 1, group):
            keep[start + int(rng.integers(0, group))] = False
    return OddMultisineLines(odd[keep], odd[~keep], int(odd[0]), int(odd[-1]))


def crest_factor(x: FloatArray) -> float:
    """``max|x| / rms(x)`` of one period (the peak the actuator must carry per unit RMS)."""
    x = np.asarray(x, dtype=float)
    return float(np.max(np.abs(x)) / np.sqrt(np.mean(x**2)))


def low_crest_multisine(
    n: int,
    lines: NDArray[np.int64],
    rng: np.random.Generator,
    *,
    iterations: int = 200,
) -> FloatArray:
    """One period of a multisine at ``lines`` with flat amplitudes and a low crest factor.

    Random phases, then the clipping algorithm of van der Ouderaa, Schoukens and Renneboog
    (IEEE Trans. Instrum. Meas. 37(2), 1988): clip the period at a level below its peak,
    keep the phases the clipped period has at the lines and restore the amplitudes, repeat;
    the period with the lowest crest factor seen is returned. The amplitude spectrum stays
    exactly flat at the lines and zero elsewhere, so the crest factor comes from the phases
    alone. Written by hand: scipy has no crest-factor minimisation.

    Args:
        n: period length, samples.
        lines: (F,) int, lines ``1 <= k < n / 2``.
        rng: draws the starting phases.
        iterations: clipping steps.

    Returns:
        (n,) float, zero mean, unit RMS.
    """
    lines = np.asarray(lines, dtype=np.int64)
    spec = np.zeros(n // 2 + 1, dtype=np.complex128)
    spec[lines] = np.exp(2j * np.pi * rng.uniform(size=lines.size))
    best = np.fft.irfft(spec, n=n)
    best_cf = crest_factor(best)
    x = best
    for i in range(iterations):
        level = (0.97 - 0.17 * i / max(iterations - 1, 1)) * np.max(np.abs(x))
        clipped = np.clip(x, -level, level)
        phases = np.angle(np.fft.rfft(clipped)[lines])
        spec = np.zeros(n // 2 + 1, dtype=np.complex128)
        spec[lines] = np.exp(1j * phases)
        x = np.fft.irfft(spec, n=n)
        cf = crest_factor(x)
        if cf < best_cf:
            best, best_cf = x, cf
    return _unit_rms(best, "multisine")


# ----------------------------------------------------------------- the excitation's design

LINE_SETS: tuple[str, ...] = ("all", "odd", "odd_odd")
"""The accepted values of ``ExcitationDesign.lines``: every grid line, the odd ones, or the
odd-odd ones (``j = 1, 5, 9, ...`` times the grid step)."""

_LINES_STREAM = 7
"""Spawn key of the generator that picks the detection lines (the phases use the seed)."""


def parse_detection(text: str) -> tuple[int, int]:
    """The detection setting as ``(M, G)``: M of every G consecutive odd lines left out.

    ``""`` -> ``(0, 0)`` (no detection line); ``"1/3"`` -> ``(1, 3)``; ``1 <= M < G``.

    Raises:
        DatumError: not of that form.
    """
    text = str(text).strip()
    if not text:
        return 0, 0
    m_text, sep, g_text = text.partition("/")
    try:
        m, g = int(m_text), int(g_text)
    except ValueError:
        m, g = 0, 0
    if not sep or not 1 <= m < g:
        raise DatumError(
            f"detection={text!r}: write M/G, M of every G consecutive odd lines left out "
            "(1 <= M < G), e.g. 1/3; empty for none"
        )
    return m, g


@dataclass(frozen=True)
class ExcitationLines:
    """The DFT lines (bins of one period) of a design: excited, detection and even lines.

    The grid is every ``step``-th bin ``k = step j``; the band's grid lines are ``j`` from
    ``first / step`` to ``last / step``. An odd design excites odd ``j`` only: its even grid
    lines (``even``) show even nonlinear distortion, its unexcited odd ones (``detection``:
    left out per group, or the ``j = 3 mod 4`` lines of an odd-odd design) odd distortion.

    Attributes:
        excited: (F,) int, the excited bins, increasing.
        detection: (D,) int, the odd grid lines in the band left unexcited.
        even: (E,) int, the even grid lines in the band (empty for ``lines: all``).
        first: the band's first grid line (bin).
        last: the band's last grid line (bin).
        step: the grid step (bins).
    """

    excited: NDArray[np.int64]
    detection: NDArray[np.int64]
    even: NDArray[np.int64]
    first: int
    last: int
    step: int

    def to_json(self) -> dict[str, object]:
        """Plain data: the bins as lists."""
        return {
            "excited": self.excited.tolist(),
            "detection": self.detection.tolist(),
            "even": self.even.tolist(),
            "first": self.first,
            "last": self.last,
            "step": self.step,
        }


@dataclass(frozen=True)
class ExcitationDesign:
    """The periodic excitation's design: its one definition (settings tree, flat names).

    The excitation node, the controller node and the model plant node take these settings
    as their parameters, ``simulate`` as its options, and scenarios and ``ModelExcitation``
    build one (:func:`design_params`, :meth:`from_flat`). Amplitudes are not part of it: they
    belong to each input (the rig's valves, a model's inputs, the setpoints).

    Each realisation ``r`` of ``realisations`` is one period of random phases (or filtered
    noise), applied for ``realisation_periods`` periods; then the next; after the last, the
    first again. Each input gets its own realisation of the same lines. Realisation 0 is
    drawn first from ``default_rng(seed)`` (one input after the other), then realisation 1,
    and so on; a single realisation of ``lines: all`` or ``odd`` without ``line_step``,
    ``detection`` or ``crest_min`` is exactly :func:`multisine_period` (or
    :func:`filtered_noise_period`) drawn input after input.
    """

    kind: str = setting(
        "filtered_noise",
        "filtered_noise or multisine",
        choices=EXCITATION_KINDS,
        option="--excitation",
    )
    period_samples: int = setting(
        PERIOD_SAMPLES, "excitation period (samples)", unit="samples", low=4, high=10_000_000
    )
    f_min_hz: float = setting(
        1.0 / 204.8,
        "multisine: lowest excited frequency (Hz; 0: the period's first line)",
        unit="Hz",
        low=0.0,
        high=1e9,
    )
    f_max_hz: float = setting(
        0.05,
        "multisine: highest excited frequency (Hz; 0: 0.2 / ts_s)",
        unit="Hz",
        low=0.0,
        high=1e9,
    )
    lines: str = setting(
        "all",
        "multisine: the grid lines excited: all, odd, or odd_odd (1, 5, 9, ... times the step)",
        choices=LINE_SETS,
        option="--lines",
    )
    line_step: int = setting(
        1,
        "multisine: the line grid, every line_step-th DFT bin of the period",
        unit="bins",
        low=1,
        high=1_000_000,
        option="--line-step",
    )
    detection: str = setting(
        "",
        "multisine with odd lines: M/G leaves M of every G consecutive odd lines out at random "
        "(detection lines, where odd distortion shows); empty: none",
        option="--detection",
    )
    crest_min: bool = setting(
        False,
        "multisine: minimise the crest factor (clipping algorithm; the same lines and amplitudes)",
        option="--crest-min",
    )
    realisations: int = setting(
        1,
        "realisations: each a new random draw, applied for realisation_periods periods",
        low=1,
        high=10_000,
        option="--realisations",
    )
    realisation_periods: int = setting(
        0,
        "periods each realisation is applied (its transient included); 0: one realisation "
        "throughout, or simulate's settling and recorded periods",
        unit="periods",
        low=0,
        high=1_000_000,
        option="--realisation-periods",
    )
    cutoff_hz: float = setting(
        0.006,
        "filtered noise: low-pass cutoff (Hz; 0: 0.2 / ts_s)",
        unit="Hz",
        low=0.0,
        high=1e9,
        option="--cutoff",
    )
    order: int = setting(2, "filtered noise: Butterworth order", low=1, high=12)
    seed: int = setting(2, "excitation seed", low=0, high=2**31 - 1)

    def __post_init__(self) -> None:
        check_settings(self, DatumError)
        parse_detection(self.detection)
        if self.kind != "multisine":
            shaped = [
                name
                for name, on in (
                    ("lines", self.lines != "all"),
                    ("line_step", self.line_step != 1),
                    ("detection", bool(self.detection.strip())),
                    ("crest_min", self.crest_min),
                )
                if on
            ]
            if shaped:
                raise DatumError(
                    f"{', '.join(shaped)} shape a multisine, but kind is {self.kind!r}: set "
                    "kind to multisine or leave them out"
                )
        if self.detection.strip() and self.lines != "odd":
            raise DatumError(
                f"detection={self.detection!r} leaves odd lines out of an odd multisine: set "
                f"lines to odd (lines={self.lines!r}; odd_odd has its detection lines already)"
            )

    # ------------------------------------------------------------------ flat form

    @classmethod
    def settings(cls) -> tuple[FlatSetting, ...]:
        """The design's settings, flat (the node parameters' names)."""
        return flat(cls)

    def to_flat(self) -> dict[str, object]:
        """The design as flat (parameter) values; ``from_flat`` of them is the design."""
        return {s.name: getattr(self, s.path[-1]) for s in flat(type(self))}

    # ------------------------------------------------------------------ derived

    @property
    def cycle_periods(self) -> int:
        """Periods before the excitation repeats (1 for a single realisation)."""
        return 1 if self.realisations == 1 else self.realisations * self.realisation_periods

    def with_run(self, periods: int) -> ExcitationDesign:
        """The design with ``realisation_periods`` 0 of several realisations set to ``periods``.

        A simulation's settling and recorded periods.
        """
        if self.realisations > 1 and self.realisation_periods == 0:
            return replace(self, realisation_periods=int(periods))
        return self

    def band_hz(self, ts_s: float) -> tuple[float, float]:
        """``(f_min_hz, f_max_hz)`` with the zeros replaced by their defaults at ``ts_s``."""
        f_min = self.f_min_hz or 1.0 / (self.period_samples * ts_s)
        f_max = self.f_max_hz or 0.2 / ts_s
        return f_min, f_max

    def cutoff(self, ts_s: float) -> float:
        """The filtered noise's cutoff (Hz) at ``ts_s`` (0: ``0.2 / ts_s``)."""
        return self.cutoff_hz or 0.2 / ts_s

    def excitation_lines(self, ts_s: float) -> ExcitationLines:
        """The excited, detection and even lines of the multisine at sample period ``ts_s``.

        The detection lines are drawn from a generator of their own
        (``SeedSequence(seed, spawn_key=(7,))``): the same for every input and realisation.

        Raises:
            DatumError: a band outside ``(0, Nyquist)``, no line of the grid in it, or fewer
                odd lines than a detection group.
        """
        n = self.period_samples
        _check_period_args(n, ts_s)
        f_min, f_max = self.band_hz(ts_s)
        nyquist = 0.5 / ts_s
        if not 0.0 < f_min <= f_max < nyquist:
            raise DatumError(
                f"multisine band f_min_hz={f_min:.6g} .. f_max_hz={f_max:.6g} must satisfy "
                f"0 < f_min_hz <= f_max_hz < Nyquist = {nyquist:.6g} Hz"
            )
        step = self.line_step
        bins = multisine_harmonics(n, ts_s, f_min, f_max, odd_only=False)
        grid = bins[bins % step == 0]
        empty = np.zeros(0, dtype=np.int64)
        j = grid // step
        if self.lines == "all":
            excited, detection, even = grid, empty, empty
        else:
            odd = grid[j % 2 == 1]
            even = grid[j % 2 == 0]
            if self.lines == "odd_odd":
                excited, detection = odd[(odd // step) % 4 == 1], odd[(odd // step) % 4 == 3]
            else:
                excited, detection = odd, empty
                m, g = parse_detection(self.detection)
                if g:
                    if odd.size < g:
                        raise DatumError(
                            f"the band holds {odd.size} odd line(s), fewer than a detection "
                            f"group of {g}: widen the band or make the groups smaller"
                        )
                    rng = np.random.default_rng(
                        np.random.SeedSequence(self.seed, spawn_key=(_LINES_STREAM,))
                    )
                    keep = np.ones(odd.size, dtype=bool)
                    for start in range(0, odd.size - g + 1, g):
                        keep[start + rng.choice(g, size=m, replace=False)] = False
                    excited, detection = odd[keep], odd[~keep]
        if excited.size == 0:
            raise DatumError(
                f"the band {f_min:.6g} .. {f_max:.6g} Hz holds no {self.lines} line of the grid "
                f"(every {step} bin(s) of 1/(n ts) = {1.0 / (n * ts_s):.6g} Hz): widen the "
                "band, lengthen the period or take a finer line_step"
            )
        first = int(grid[0]) if grid.size else int(excited[0])
        last = int(grid[-1]) if grid.size else int(excited[-1])
        return ExcitationLines(
            excited.astype(np.int64),
            detection.astype(np.int64),
            even.astype(np.int64),
            first,
            last,
            step,
        )

    def _legacy(self) -> bool:
        """A single realisation that :func:`multisine_period` draws alike."""
        return (
            self.lines in ("all", "odd")
            and self.line_step == 1
            and not (self.detection.strip() or self.crest_min)
        )

    def realisation_tables(self, ts_s: float, n_columns: int) -> FloatArray:
        """One period of each realisation, each column zero mean and unit RMS.

        Returns:
            (realisations, period_samples, n_columns) float.

        Raises:
            DatumError: an empty band, a cutoff at or above Nyquist.
        """
        return self._draw(ts_s, n_columns)[0]

    def crest_factors(self, ts_s: float, n_columns: int) -> tuple[FloatArray, FloatArray]:
        """Each period's crest factor with its random phases and as applied.

        Returns:
            ``(before, after)``, (realisations, n_columns) each (equal without ``crest_min``).
        """
        _, before, after = self._draw(ts_s, n_columns)
        return before, after

    def _draw(self, ts_s: float, n_columns: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        n = self.period_samples
        rng = np.random.default_rng(self.seed)
        out = np.zeros((self.realisations, n, n_columns))
        before = np.zeros((self.realisations, n_columns))
        if self.kind == "filtered_noise":
            for r in range(self.realisations):
                for i in range(n_columns):
                    out[r, :, i] = filtered_noise_period(
                        n, ts_s, self.cutoff(ts_s), self.order, rng
                    )
                    before[r, i] = crest_factor(out[r, :, i])
            return out, before, before.copy()
        f_min, f_max = self.band_hz(ts_s)
        legacy = self._legacy()
        lines = None if legacy else self.excitation_lines(ts_s).excited
        for r in range(self.realisations):
            for i in range(n_columns):
                if lines is None:
                    x = multisine_period(n, ts_s, f_min, f_max, self.lines == "odd", rng)
                    before[r, i] = crest_factor(x)
                elif self.crest_min:
                    start = np.zeros(n // 2 + 1, dtype=np.complex128)
                    start[lines] = np.exp(2j * np.pi * copy.deepcopy(rng).uniform(size=lines.size))
                    before[r, i] = crest_factor(np.fft.irfft(start, n=n))
                    x = low_crest_multisine(n, lines, rng)
                else:
                    spectrum = np.zeros(n // 2 + 1, dtype=np.complex128)
                    spectrum[lines] = np.exp(1j * rng.uniform(0.0, 2.0 * np.pi, size=lines.size))
                    x = _unit_rms(np.fft.irfft(spectrum, n=n), "multisine")
                    before[r, i] = crest_factor(x)
                out[r, :, i] = x
        after = np.array(
            [
                [crest_factor(out[r, :, i]) for i in range(n_columns)]
                for r in range(self.realisations)
            ]
        ).reshape(before.shape)
        return out, before, after

    def cycle(self, ts_s: float, scale: FloatArray) -> FloatArray:
        """The deviations of one whole cycle: each realisation tiled over its periods.

        Args:
            ts_s: sample period, s.
            scale: (n_columns,) RMS of each column.

        Returns:
            (cycle_periods period_samples, n_columns) float; sample k of a run uses row
            ``k mod len``. One period for a single realisation.

        Raises:
            DatumError: several realisations with ``realisation_periods`` 0 (give it, or let
                a simulation set it: :meth:`with_run`), or the draw's own errors.
        """
        if self.realisations > 1 and self.realisation_periods == 0:
            raise DatumError(
                f"{self.realisations} realisations need realisation_periods >= 1 (the periods "
                "each is applied for, its transient included)"
            )
        scale = np.asarray(scale, dtype=np.float64)
        tables = self.realisation_tables(ts_s, scale.size) * scale
        if self.realisations == 1:
            return np.asarray(tables[0])
        return np.concatenate([np.tile(t, (self.realisation_periods, 1)) for t in tables])

    def summary(self, ts_s: float, n_columns: int = 1) -> dict[str, object]:
        """The design as plain data for a record.

        Its settings, its lines (a multisine's) and the crest factors before and after
        minimisation (per realisation and input).
        """
        out: dict[str, object] = {"design": self.to_flat(), "ts_s": float(ts_s)}
        if self.kind == "multisine":
            out["lines"] = self.excitation_lines(ts_s).to_json()
        before, after = self.crest_factors(ts_s, n_columns)
        out["crest_factor"] = {"random_phase": before.tolist(), "applied": after.tolist()}
        return out


RIG_DESIGN = ExcitationDesign()
"""The rig's excitation by default (scenarios, the excitation and controller nodes): the
design's own defaults, filtered noise of cutoff 0.006 Hz and seed 2 (a multisine from
1/204.8 Hz up to 0.05 Hz)."""


# ----------------------------------------------------------------- the design beside a record

DESIGN_SUFFIX = ".excitation.yaml"
"""Suffix of the excitation design written beside a recording (``run.csv`` ->
``run.excitation.yaml``, a bag ``run`` -> ``run.excitation.yaml``)."""


@dataclass(frozen=True)
class RecordedDesign:
    """The excitation design of a recording, as written beside it.

    Attributes:
        design: the design.
        ts_s: the sample period it was applied at, s.
        lines: its lines (None for filtered noise).
        settle_periods: periods of each realisation before its recorded ones (transient).
        recorded_periods: recorded periods of each realisation.
        start_sample: the record's sample where realisation 0 starts.
    """

    design: ExcitationDesign
    ts_s: float
    lines: ExcitationLines | None
    settle_periods: int
    recorded_periods: int
    start_sample: int = 0

    @property
    def realisation_periods(self) -> int:
        """Periods of each realisation (settling and recorded)."""
        return self.settle_periods + self.recorded_periods


def design_path(recording: str | os.PathLike[str]) -> Path:
    """Where the design of the recording at ``recording`` is written: beside it."""
    path = Path(recording)
    stem = path.stem if path.suffix.lower() == ".csv" else path.name  # as the interface map
    return path.with_name(stem + DESIGN_SUFFIX)


def design_document(
    design: ExcitationDesign,
    ts_s: float,
    n_inputs: int,
    settle_periods: int,
    recorded_periods: int,
) -> dict[str, object]:
    """The design as plain data (:meth:`ExcitationDesign.summary` and the run's periods)."""
    out = design.summary(ts_s, n_inputs)
    out["run"] = {
        "settle_periods": int(settle_periods),
        "recorded_periods": int(recorded_periods),
        "start_sample": 0,
    }
    return out


def write_design(document: dict[str, object], recording: str | os.PathLike[str]) -> Path:
    """Write :func:`design_document` beside the recording (never over an existing file).

    Raises:
        DatumError: the file exists.
    """
    path = design_path(recording)
    if path.exists():
        raise DatumError(f"{path} exists already; recordings are never overwritten")
    path.write_text(yaml.safe_dump(document, sort_keys=False, width=100, default_flow_style=None))
    return path


def read_design(recording: str | os.PathLike[str]) -> RecordedDesign | None:
    """The design written beside ``recording``; None when there is none.

    Raises:
        DatumError: the file is there but is not a design (the message names it).
    """
    path = design_path(recording)
    if not path.is_file():
        return None
    try:
        doc = yaml.safe_load(path.read_text())
        design = from_flat(ExcitationDesign, doc["design"])
        run = doc.get("run", {})
        lines = doc.get("lines")
        recorded = RecordedDesign(
            design=design,
            ts_s=float(doc["ts_s"]),
            lines=None
            if lines is None
            else ExcitationLines(
                np.asarray(lines["excited"], dtype=np.int64),
                np.asarray(lines["detection"], dtype=np.int64),
                np.asarray(lines["even"], dtype=np.int64),
                int(lines["first"]),
                int(lines["last"]),
                int(lines["step"]),
            ),
            settle_periods=int(run.get("settle_periods", 0)),
            recorded_periods=int(run.get("recorded_periods", 0)),
            start_sample=int(run.get("start_sample", 0)),
        )
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as err:
        raise DatumError(
            f"{path} is not an excitation design ({type(err).__name__}: {err}); remove it or "
            "write it again with simulate"
        ) from err
    return recorded
