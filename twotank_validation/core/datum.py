"""The datum: a periodic input-output record, checked, de-biased and transformed by DFT.

Conventions (R. S. Smith 1995, Sec. 2.3, eq. 3; see docs/theory.md):

* The record holds ``n_samples = n_periods * period_samples`` samples of ``u(k)`` (inputs)
  and ``y(k)`` (outputs), uniformly sampled every ``ts_s`` seconds.
* The DFT is ``X(n) = c_N sum_k x(k) exp(-j 2 pi k n / N)``. The prefactor ``c_N`` fixes what
  ``||w|| <= 1`` means:

  - ``NormConvention.POWER`` (default, the reading the paper's figures imply): ``c_N = 1/N``,
    so ``sum_n |W(n)|^2 = (1/N) sum_k |w(k)|^2`` is the mean square (power) of ``w``; a noise
    weight of 0.03 admits 0.03 RMS of sensor noise.
  - ``NormConvention.ENERGY``: ``c_N = 1/sqrt(N)``, so ``sum_n |W(n)|^2 = sum_k |w(k)|^2``.

* Only the bins ``n = 0 .. N//2`` are kept (real signals: bin ``N-n`` is the conjugate of
  bin ``n``); ``bin_weights`` counts each kept bin once or twice so that sums over kept bins
  equal sums over all ``N`` bins.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.signal

from twotank_validation.core.columns import centred, column_max_abs, column_mean, period_mean
from twotank_validation.errors import DatumError, DimensionError

_INPUT_PERIODIC_RTOL = 1e-6
MEASURED_INPUT_RTOL = 0.05
"""Largest noise of a measured input (RMS of its period-to-period spread, relative to the
input's RMS) that the periodicity gate tolerates: the noise's effect on β is reported
(docs/theory.md, "Measured inputs"); a larger spread is a changed excitation, not noise."""
_DRIFT_LIMIT = 0.05
_DECAY_RATIO = 2.0


class NormConvention(enum.StrEnum):
    """Meaning of ``||w||``: mean-square power (default) or energy of the sampled signal."""

    POWER = "power"
    ENERGY = "energy"

    def dft_scale(self, n_samples: int) -> float:
        """The DFT prefactor ``c_N`` for a record of ``n_samples`` samples."""
        if self is NormConvention.POWER:
            return 1.0 / n_samples
        return 1.0 / float(np.sqrt(n_samples))

    @property
    def description(self) -> str:
        """One line for reports."""
        if self is NormConvention.POWER:
            return "power (RMS): ||w||^2 = (1/N) sum_k |w(k)|^2, DFT prefactor 1/N"
        return "energy: ||w||^2 = sum_k |w(k)|^2, DFT prefactor 1/sqrt(N)"


class PeriodicityFinding(enum.StrEnum):
    """A finding of :func:`assess_periodicity`; the value is the start of its text."""

    ONE_PERIOD = "one period only"
    """A single period: neither periodicity nor noise can be checked."""
    INPUT_NOT_PERIODIC = "input not periodic"
    """An input changes from one period to the next (by more than 1e-6 of its RMS)."""
    OUTPUT_DRIFTS = "output mean drifts"
    """An output's period mean moves by more than 5 % of its RMS across the record."""
    VARIATION_SHRINKS = "period-to-period output variation shrinks"
    """The outputs' period-to-period variation halves or more along the record."""

    @property
    def transient(self) -> bool:
        """The finding suggests a transient still decaying in the record."""
        return self in (PeriodicityFinding.OUTPUT_DRIFTS, PeriodicityFinding.VARIATION_SHRINKS)


@dataclass(frozen=True)
class PeriodicityReport:
    """How far a record is from periodic.

    Attributes:
        n_periods: whole excitation periods in the record.
        period_samples: samples per period.
        input_variation: (n_periods-1, n_inputs) RMS of ``u_{r+1} - u_r`` over RMS of ``u``.
        output_variation: (n_periods-1, n_outputs) same for the outputs (noise floor
            ``sqrt(2) * noise_rms / output_rms`` for a settled, periodic response).
        output_drift: (n_outputs,) change of the period mean from the first to the last
            period, over the output's RMS deviation: a decaying transient shows here.
        input_periodic: every input repeats to within 1e-6 relative.
        transient_suspected: a drift above 5 % or a period-to-period variation that halves
            or more across the record (three or more periods).
        findings: what was found, typed (:class:`PeriodicityFinding`), in record order;
            :attr:`messages` says each in words.
        last_change: (period_samples, n_inputs) float, ``u_{p-1}(k) - u_{p-2}(k)``: how the
            last period's input differs from the one before, sample by sample (zeros with
            one period); what the input's leakage is estimated from
            (:func:`input_leakage_transient`).
        input_noise: (n_inputs,) float, each measured input's noise RMS estimated from the
            period-to-period spread (:func:`input_noise_rms`), relative to its RMS; 0 for a
            commanded input (its gate is strict), NaN with one period.
    """

    n_periods: int
    period_samples: int
    input_variation: np.ndarray
    output_variation: np.ndarray
    output_drift: np.ndarray
    input_periodic: bool
    transient_suspected: bool
    findings: tuple[PeriodicityFinding, ...] = ()
    last_change: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    input_noise: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def is_periodic(self) -> bool:
        """True when the input is periodic and no transient is suspected (then R(n) = 0)."""
        return self.input_periodic and not self.transient_suspected

    @property
    def messages(self) -> tuple[str, ...]:
        """Each finding in words (:func:`periodicity_text`)."""
        return tuple(periodicity_text(f, self) for f in self.findings)


def periodicity_text(finding: PeriodicityFinding, report: PeriodicityReport) -> str:
    """A periodicity finding in words, with its number (the one place its prose is written)."""
    if finding is PeriodicityFinding.ONE_PERIOD:
        return f"{finding}: periodicity and noise cannot be checked"
    if finding is PeriodicityFinding.INPUT_NOT_PERIODIC:
        worst = float(report.input_variation.max())
        return f"{finding}: period-to-period variation up to {worst:.3g} of its RMS"
    if finding is PeriodicityFinding.OUTPUT_DRIFTS:
        return (
            f"{finding} by up to {float(report.output_drift.max()):.3g} of its RMS across the "
            "record: a transient may still be decaying (settle longer before recording)"
        )
    return f"{finding} along the record: transient still decaying"


@dataclass(frozen=True)
class Datum:
    """A checked, de-biased, DFT-transformed periodic experiment.

    Attributes:
        u_bins: (n_bins, n_inputs) complex, scaled DFT of the de-biased inputs, bins 0..N//2.
        y_bins: (n_bins, n_outputs) complex, same for the outputs.
        theta: (n_bins,) float, bin frequencies ``2 pi n / N`` in rad/sample.
        freqs_hz: (n_bins,) float, bin frequencies in Hz.
        bin_weights: (n_bins,) float, 1 for DC and Nyquist, 2 otherwise.
        ts_s: sample period (s).
        period_samples: samples per excitation period.
        n_samples: record length N.
        convention: the norm convention (DFT prefactor).
        u_bias: (n_inputs,) removed input means (model units).
        y_bias: (n_outputs,) removed output means (model units).
        u_max: (n_inputs,) max |u(k) - bias|, for the leakage bound.
        periodicity: periodicity findings.
        y_centred: (n_samples, n_outputs) float, the de-biased outputs (what
            :attr:`noise_std` is estimated from, on first use).
        u_noise_std: (n_bins, n_inputs) float, per-bin standard deviation of the noise left
            in ``U(n)`` of a measured input (averaged over the periods, model units scaled
            as ``u_bins``; :func:`noise_estimate` of the logged input at the harmonic bins
            but DC, 0 elsewhere); 0 for a commanded input. Empty: every input commanded.
    """

    u_bins: np.ndarray
    y_bins: np.ndarray
    theta: np.ndarray
    freqs_hz: np.ndarray
    bin_weights: np.ndarray
    ts_s: float
    period_samples: int
    n_samples: int
    convention: NormConvention
    u_bias: np.ndarray
    y_bias: np.ndarray
    u_max: np.ndarray
    periodicity: PeriodicityReport
    y_centred: np.ndarray = field(repr=False)
    u_noise_std: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)

    @cached_property
    def noise_std(self) -> np.ndarray:
        """(n_bins, n_outputs) float, per-bin noise standard deviation of ``Y(n)``.

        Estimated from the period-to-period variation (harmonic bins of the period; NaN at
        the other bins and when the record has one period), on first use.
        """
        return noise_estimate(self.y_centred, self.period_samples, self.convention)

    @property
    def n_inputs(self) -> int:
        """Number of inputs."""
        return int(self.u_bins.shape[1])

    @property
    def n_outputs(self) -> int:
        """Number of outputs."""
        return int(self.y_bins.shape[1])

    @property
    def n_periods(self) -> int:
        """Whole periods in the record."""
        return self.n_samples // self.period_samples

    @property
    def harmonic_bins(self) -> np.ndarray:
        """(n_bins,) bool, bins at harmonics of the excitation period (where U can be non-zero)."""
        return np.arange(self.theta.size) % self.n_periods == 0


def _as_record(x: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise DimensionError(f"{name} must be (n_samples, n_channels), found shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        k, ch = np.argwhere(bad)[0]
        raise DatumError(
            f"{name} holds {int(bad.sum())} NaN/inf values (first at sample {k}, channel {ch}): "
            "cut the record to a clean stretch of whole periods or repair the samples"
        )
    return arr


def check_record(
    u: np.ndarray, y: np.ndarray, period_samples: int
) -> tuple[np.ndarray, np.ndarray]:
    """Check shapes, finiteness and whole periods of a record.

    Args:
        u: (n_samples, n_inputs) or (n_samples,) float, inputs in model units.
        y: (n_samples, n_outputs) or (n_samples,) float, outputs in model units.
        period_samples: excitation period in samples.

    Returns:
        ``(u, y)`` as 2-D float arrays.

    Raises:
        DatumError: NaN/inf, too short, not a whole number of periods, mismatched lengths.
        DimensionError: arrays that are not 1-D or 2-D.
    """
    u2 = _as_record(u, "u")
    y2 = _as_record(y, "y")
    if u2.shape[0] != y2.shape[0]:
        raise DatumError(
            f"u has {u2.shape[0]} samples but y has {y2.shape[0]}: "
            "inputs and outputs must be sampled on the same grid"
        )
    if int(period_samples) != period_samples or period_samples < 2:
        raise DatumError(f"period_samples must be an integer >= 2, found {period_samples}")
    n = u2.shape[0]
    if n < period_samples:
        raise DatumError(
            f"record too short: {n} samples is less than one excitation period "
            f"({period_samples} samples); record at least one whole period"
        )
    if n % period_samples:
        whole = n // period_samples
        raise DatumError(
            f"record of {n} samples is not an integer number of periods of {period_samples} "
            f"samples ({n / period_samples:.3f} periods): keep the last {whole * period_samples} "
            "samples (whole periods only), otherwise R(n) != 0 (leakage)"
        )
    return u2, y2


def assess_periodicity(
    u: np.ndarray, y: np.ndarray, period_samples: int, measured: np.ndarray | None = None
) -> PeriodicityReport:
    """Measure period-to-period variation and drift of a record of whole periods.

    A commanded input is periodic when it repeats to 1e-6 of its RMS; a measured one
    (``measured``) when its noise, the period-to-period spread (:func:`input_noise_rms`), is
    at most :data:`MEASURED_INPUT_RTOL` of its RMS.

    Args:
        u: (n_samples, n_inputs) float, de-biased inputs.
        y: (n_samples, n_outputs) float, de-biased outputs.
        period_samples: samples per period.
        measured: (n_inputs,) bool, the inputs that are measured (logged by a sensor); None:
            every input commanded.
    """
    p = u.shape[0] // period_samples
    up = u.reshape(p, period_samples, -1)
    yp = y.reshape(p, period_samples, -1)
    u_rms = np.sqrt(column_mean(u**2)) + np.finfo(float).tiny
    y_rms = np.sqrt(column_mean(y**2)) + np.finfo(float).tiny
    u_var = np.sqrt(period_mean(np.diff(up, axis=0) ** 2)) / u_rms
    y_var = np.sqrt(period_mean(np.diff(yp, axis=0) ** 2)) / y_rms
    means = period_mean(yp)
    drift = np.abs(means[-1] - means[0]) / y_rms
    findings: list[PeriodicityFinding] = []
    meas = np.zeros(u.shape[1], bool) if measured is None else np.asarray(measured, bool)
    noise = np.where(meas, input_noise_rms(u, period_samples) / u_rms, 0.0)
    strict = np.all(u_var <= _INPUT_PERIODIC_RTOL, axis=0) if p >= 2 else np.ones(meas.size, bool)
    input_periodic = bool(np.all(np.where(meas, ~(noise > MEASURED_INPUT_RTOL), strict)))
    if p < 2:
        findings.append(PeriodicityFinding.ONE_PERIOD)
    elif not input_periodic:
        findings.append(PeriodicityFinding.INPUT_NOT_PERIODIC)
    transient = bool(np.any(drift > _DRIFT_LIMIT))
    if transient:
        findings.append(PeriodicityFinding.OUTPUT_DRIFTS)
    if p >= 3 and np.any(y_var[0] > _DECAY_RATIO * y_var[-1]):
        transient = True
        findings.append(PeriodicityFinding.VARIATION_SHRINKS)
    last = up[-1] - up[-2] if p >= 2 else np.zeros_like(up[0])
    return PeriodicityReport(
        n_periods=p,
        period_samples=period_samples,
        input_variation=u_var,
        output_variation=y_var,
        output_drift=drift,
        input_periodic=input_periodic,
        transient_suspected=transient,
        findings=tuple(findings),
        last_change=last,
        input_noise=noise,
    )


def input_noise_rms(u: np.ndarray, period_samples: int) -> np.ndarray:
    """Noise RMS of each input from its period-to-period spread.

    ``sigma^2 = mean_k var_r u_r(k)``: the unbiased variance over the ``p`` periods at each
    sample of the period, averaged over the period; white noise of RMS ``sigma`` on a
    periodic signal gives ``sigma`` (the periodic part cancels).

    Args:
        u: (n_samples, n_inputs) float, whole periods (model units).
        period_samples: samples per period.

    Returns:
        (n_inputs,) float, model units; NaN with one period.
    """
    p = u.shape[0] // period_samples
    if p < 2:
        return np.full(u.shape[1], np.nan)
    up = u.reshape(p, period_samples, -1)
    return np.asarray(np.sqrt(np.mean(np.var(up, axis=0, ddof=1), axis=0)))


def period_average(x: np.ndarray, period_samples: int) -> np.ndarray:
    """A record replaced by its mean period, repeated: (n_samples, n_channels) float.

    Its DFT over the record equals the record's at the harmonics of the period and is zero
    elsewhere: the average over the periods the DFT over whole periods already takes,
    without the noise at the other bins (docs/theory.md, "Measured inputs").
    """
    p = x.shape[0] // period_samples
    mean = x.reshape(p, period_samples, -1).mean(axis=0)
    return np.tile(mean, (p, 1))


def scaled_dft(x: np.ndarray, convention: NormConvention) -> np.ndarray:
    """One-sided scaled DFT of a real record.

    Args:
        x: (n_samples, n_channels) float.
        convention: fixes the prefactor ``c_N``.

    Returns:
        (n_samples//2 + 1, n_channels) complex, ``c_N * rfft(x)``.
    """
    return np.fft.rfft(x, axis=0) * convention.dft_scale(x.shape[0])


def one_sided_weights(n_samples: int) -> np.ndarray:
    """(n_samples//2 + 1,) multiplicity of each kept bin in the two-sided spectrum."""
    w = np.full(n_samples // 2 + 1, 2.0)
    w[0] = 1.0
    if n_samples % 2 == 0:
        w[-1] = 1.0
    return w


def noise_estimate(y: np.ndarray, period_samples: int, convention: NormConvention) -> np.ndarray:
    """Per-bin noise standard deviation of the full-record ``Y(n)`` from period-to-period variation.

    With ``p`` periods, the full-record bin ``n = p m`` is ``c_N * sum_r S_r(m)`` where
    ``S_r`` is the unscaled DFT of period ``r``; with independent noise its variance is
    ``c_N^2 p var_r(S_r(m))``, estimated with the unbiased sample variance over periods.

    Args:
        y: (n_samples, n_outputs) float, de-biased outputs.
        period_samples: samples per period.
        convention: norm convention.

    Returns:
        (n_samples//2 + 1, n_outputs) float; NaN where not estimable.
    """
    n, ny = y.shape
    p = n // period_samples
    out = np.full((n // 2 + 1, ny), np.nan)
    if p < 2:
        return out
    per_period = np.fft.rfft(y.reshape(p, period_samples, ny), axis=1)  # (p, L//2+1, ny)
    var = np.var(per_period, axis=0, ddof=1)  # complex variance, E|x - mean|^2
    std = convention.dft_scale(n) * np.sqrt(p * var)
    harmonics = np.arange(per_period.shape[1]) * p
    keep = harmonics < out.shape[0]
    out[harmonics[keep]] = std[keep]
    return out


def make_datum(
    u: np.ndarray,
    y: np.ndarray,
    *,
    ts_s: float,
    period_samples: int,
    convention: NormConvention | str = NormConvention.POWER,
    measured: np.ndarray | None = None,
) -> Datum:
    """Build a :class:`Datum` from raw samples.

    A measured input (``measured``) is replaced by its average over the periods
    (:func:`period_average`) and the noise left in it is estimated (``u_noise_std``).

    Args:
        u: (n_samples, n_inputs) float, inputs in model units.
        y: (n_samples, n_outputs) float, outputs in model units.
        ts_s: sample period in seconds.
        period_samples: excitation period in samples; ``n_samples`` must be a multiple.
        convention: ``"power"`` (default) or ``"energy"``.
        measured: (n_inputs,) bool, the inputs logged by a sensor (noisy), not commanded;
            None: every input commanded.

    Raises:
        DatumError: see :func:`check_record`; a non-positive sample period.
    """
    if not (np.isfinite(ts_s) and ts_s > 0):
        raise DatumError(f"sample period must be positive and finite, found {ts_s} s")
    conv = NormConvention(convention)
    u2, y2 = check_record(u, y, period_samples)
    u_bias = column_mean(u2)
    y_bias = column_mean(y2)
    uc = centred(u2, u_bias)
    yc = centred(y2, y_bias)
    n = u2.shape[0]
    theta = 2.0 * np.pi * np.arange(n // 2 + 1) / n
    meas = None if measured is None else np.asarray(measured, bool).reshape(-1)
    if meas is not None and meas.size != uc.shape[1]:
        raise DimensionError(f"measured marks {meas.size} inputs but u has {uc.shape[1]}")
    periodicity = assess_periodicity(uc, yc, int(period_samples), meas)
    u_noise = np.zeros((0, 0))
    if meas is not None and meas.any():
        u_noise = np.where(meas, np.nan_to_num(noise_estimate(uc, period_samples, conv)), 0.0)
        u_noise[0] = 0.0  # the mean, noise included, is removed as the bias
        if n // period_samples < 2:
            u_noise[:, meas] = np.nan
        uc = np.where(meas, period_average(uc, int(period_samples)), uc)
    return Datum(
        u_bins=scaled_dft(uc, conv),
        y_bins=scaled_dft(yc, conv),
        theta=theta,
        freqs_hz=theta / (2.0 * np.pi * ts_s),
        bin_weights=one_sided_weights(n),
        ts_s=float(ts_s),
        period_samples=int(period_samples),
        n_samples=n,
        convention=conv,
        u_bias=u_bias,
        y_bias=y_bias,
        u_max=column_max_abs(uc),
        periodicity=periodicity,
        y_centred=yc,
        u_noise_std=u_noise,
    )


def leakage_bound(
    moment: np.ndarray, u_max: np.ndarray, n_samples: int, convention: NormConvention
) -> np.ndarray:
    """Bound on the leakage term ``|R_i(n)|`` per output (Ljung 1987, Thm 2.1).

    ``Y(n) = P(e^{j theta_n}) U(n) + R(n)`` with, for the 1/sqrt(N)-scaled DFT,
    ``|R(n)| <= (2/sqrt(N)) max|u| sum_k k |p(k)|``. For other prefactors the bound scales
    with ``c_N``: ``|R_i(n)| <= 2 c_N sum_j max|u_j| sum_k k |p_ij(k)|``, the same at every bin.

    Args:
        moment: (n_outputs, n_inputs) float, ``sum_k k |p_ij(k)|`` of the pulse response
            (see :func:`pulse_moment`).
        u_max: (n_inputs,) float, max |u_j(k)| after bias removal.
        n_samples: record length N.
        convention: norm convention.

    Returns:
        (n_outputs,) float.
    """
    return 2.0 * convention.dft_scale(n_samples) * (moment @ np.asarray(u_max, dtype=float))


def input_leakage_transient(
    pulse: np.ndarray, last_change: np.ndarray, n_periods: int, n_samples: int
) -> np.ndarray:
    """The leakage ``r(k)`` of an input that changes from period to period, estimated.

    Over a record of ``N = n_periods * L`` samples, ``y = p * u`` (linear convolution, the
    input before the record included) differs from the circular convolution that
    ``Y(n) = P U(n)`` describes by ``r(k) = sum_{i>=1} p(k+i) d(-i)``, with
    ``d(m) = u(m) - u(m+N)`` the input's change over a record length before the record: its
    DFT is the leakage ``R(n)`` (Ljung 1987, Thm 2.1, whose bound takes ``max|u|`` for
    ``d``). A periodic input has ``d = 0``. ``d`` lies before the record and is not
    observed; it is taken as the last period's change (``last_change``, sample by sample)
    continued as a steady trend over the ``n_periods`` periods of a record length,
    ``d(m) = -n_periods * last_change[m mod L]``: exact for an input that ramps, an
    overestimate (by about ``sqrt(n_periods)``) for changes that do not add up from period
    to period, such as a loop's answer to the noise. The convolution runs by FFT
    (``scipy.signal.fftconvolve``) on the pulse response folded onto the period
    (:func:`fold_pulse`, :func:`folded_leakage`).

    Args:
        pulse: (n_coeffs, n_outputs, n_inputs) float, the pulse response (``p(0) = D``).
        last_change: (L, n_inputs) float, ``u_{p-1}(k) - u_{p-2}(k)``.
        n_periods: whole periods in the record.
        n_samples: record length N.

    Returns:
        (n_samples, n_outputs) float.
    """
    period = last_change.shape[0]
    if period == 0 or not np.any(last_change):
        return np.zeros((n_samples, pulse.shape[1]))
    return folded_leakage(fold_pulse(pulse, period, n_samples), last_change, n_periods, n_samples)


def fold_pulse(pulse: np.ndarray, period: int, n_samples: int) -> np.ndarray:
    """The pulse response folded onto the period: ``F(j) = sum_{t >= 0} p(j + t L)``.

    Args:
        pulse: (n_coeffs, n_outputs, n_inputs) float.
        period: L (samples).
        n_samples: the record length N.

    Returns:
        (m, n_outputs, n_inputs) float, ``F(j)`` at ``j = 1 .. m`` (row ``j - 1``), ``m`` the
        whole periods that cover ``N + L - 1``: what :func:`folded_leakage` needs.
    """
    n_coeffs, ny, nu = pulse.shape
    blocks = -(-(n_samples + period) // period)
    tail = max(0, -(-(n_coeffs - 1) // period) - blocks)
    padded = np.zeros(((blocks + tail) * period, ny, nu))
    padded[: max(n_coeffs - 1, 0)] = pulse[1:]  # padded[j - 1] = p(j)
    stacked = padded.reshape(blocks + tail, period, ny, nu)
    # block by block from the end, F(j) = p(j) + F(j + L): a reverse cumulative sum
    return np.flip(np.cumsum(np.flip(stacked, 0), axis=0), 0)[:blocks].reshape(-1, ny, nu)


def folded_leakage(
    folded: np.ndarray, last_change: np.ndarray, n_periods: int, n_samples: int
) -> np.ndarray:
    """:func:`input_leakage_transient` from the folded pulse response (:func:`fold_pulse`).

    ``d(-s)`` repeats every period, so ``r(k) = sum_{s=1..L} d(-s) F(k + s)``: one
    correlation of the record's length, whatever the pulse response's.

    Returns:
        (n_samples, n_outputs) float.
    """
    period = last_change.shape[0]
    before = -float(n_periods) * last_change[(-np.arange(1, period + 1)) % period]  # d(-s)
    # r(k) = sum_s folded[k + s - 1] d(-s): a correlation, by FFT
    full = scipy.signal.fftconvolve(folded, before[::-1, None, :], axes=0)
    return np.asarray(full[period - 1 : period - 1 + n_samples].sum(axis=2))


def pulse_moment(pulse: np.ndarray) -> np.ndarray:
    """``sum_k k |p(k)|`` of a pulse response.

    Args:
        pulse: (n_coeffs, n_outputs, n_inputs) float.

    Returns:
        (n_outputs, n_inputs) float.
    """
    k = np.arange(pulse.shape[0])[:, None, None]
    return np.sum(k * np.abs(pulse), axis=0)
