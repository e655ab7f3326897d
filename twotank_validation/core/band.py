"""The validation band: the frequencies over which a model set is claimed (pure functions).

A model set is claimed over a band of frequencies, not necessarily up to Nyquist (R. S. Smith
1995 validates over the frequencies of interest). The band is a frequency interval
``[min_hz, max_hz]``, optionally restricted to the excited lines of the command (the harmonic
bins of the period where the command's spectrum carries power). β, the alarm and calibration
count the bins in the band; what lies outside is reported beside it (see docs/theory.md,
"The validation band").
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from twotank_validation.errors import ModelError

EXCITED_FLOOR = 1e-8
"""A harmonic line is excited when the command's power there is at least this fraction of the
largest harmonic line's power (-80 dB): a digital command's unexcited lines sit at rounding
level, far below it; a line the command does not carry has no power in it at all."""


@dataclass(frozen=True)
class Band:
    """Frequencies over which the model set is claimed.

    Attributes:
        min_hz: lowest frequency counted (Hz, inclusive).
        max_hz: highest frequency counted (Hz, inclusive; ``inf`` up to Nyquist).
        excited: count only the command's excited lines inside ``[min_hz, max_hz]``.
    """

    min_hz: float = 0.0
    max_hz: float = math.inf
    excited: bool = False

    def __post_init__(self) -> None:
        if not (self.min_hz >= 0.0 and self.max_hz > self.min_hz):
            raise ModelError(
                f"band needs 0 <= min_hz < max_hz, found min_hz={self.min_hz}, "
                f"max_hz={self.max_hz}: give the frequencies the model is claimed over, in Hz"
            )

    @property
    def text(self) -> str:
        """One line for reports."""
        span = f"{self.min_hz:g} .. {self.max_hz:g} Hz"
        return f"the command's excited lines in {span}" if self.excited else span

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable (``max_hz`` ``None`` for up to Nyquist)."""
        return {
            "min_hz": self.min_hz,
            "max_hz": None if math.isinf(self.max_hz) else self.max_hz,
            "excited": self.excited,
        }


def parse_band(value: Any) -> Band | None:
    """A band from a model file's ``band:`` entry or the ``--band`` option.

    Accepts ``None``/``"all"`` (every bin: no band), ``"excited"``, ``"LO:HI"`` (Hz, either
    side may be empty), ``"excited:LO:HI"``, or a mapping with ``min_hz``, ``max_hz`` and
    ``excited``.

    Raises:
        ModelError: anything else, naming the accepted forms.
    """
    forms = "'all', 'excited', 'LO:HI' or 'excited:LO:HI' (Hz), or {min_hz, max_hz, excited}"
    if value is None or (isinstance(value, str) and value.strip().lower() in ("", "all")):
        return None
    if isinstance(value, Band):
        return value
    try:
        if isinstance(value, Mapping):
            unknown = set(value) - {"min_hz", "max_hz", "excited"}
            if unknown:
                raise ModelError(f"unknown band keys {sorted(unknown)}: use {forms}")
            excited = value.get("excited", False)
            if not isinstance(excited, bool):
                raise ModelError(f"band.excited must be true or false, found {excited!r}")
            return Band(
                float(value.get("min_hz", 0.0)),
                float(value["max_hz"]) if value.get("max_hz") is not None else math.inf,
                excited,
            )
        if isinstance(value, str):
            parts = [p.strip() for p in value.strip().lower().split(":")]
            excited = parts[0] == "excited"
            if excited:
                parts = parts[1:]
            if not parts:
                return Band(excited=True)
            if len(parts) != 2:
                raise ModelError(f"band {value!r} not understood: use {forms}")
            lo = float(parts[0]) if parts[0] else 0.0
            hi = float(parts[1]) if parts[1] else math.inf
            return Band(lo, hi, excited)
    except ModelError:
        raise
    except (TypeError, ValueError) as err:
        raise ModelError(f"band {value!r} not understood ({err}): use {forms}") from err
    raise ModelError(f"band {value!r} not understood: use {forms}")


def excited_lines(
    command_bins: np.ndarray,
    n_periods: int,
    floor: float = EXCITED_FLOOR,
    noise_std: np.ndarray | None = None,
) -> np.ndarray:
    """(n_bins,) bool: the command's excited lines.

    The one definition: the band's ``excited``, the diagnosis's and calibration's excited
    bins (``diagnose.fit.excited_bins``), the reports' figures. A line is excited where it
    is a harmonic of the period (bin ``n`` a multiple of ``n_periods``, ``n > 0``) and the
    command's power there, ``sum_j |U_j(n)|^2``, is at least ``floor`` times the largest
    harmonic's. Only the command decides: a line present in an output but absent from the
    command (mains pickup) is not excited. Where the datum's input is a measurement
    (``noise_std``: the noise left in it, ``Datum.u_noise_std``), a line must also stand
    above that noise, ``sum_j |U_j(n)|^2 > PERIODIC_RATIO^2 sum_j sigma_j(n)^2`` (the rule
    :func:`periodic_lines` applies to the outputs): at the other harmonics the averaged input
    holds its sensor's noise only. A periodic line the sensor picks up at a harmonic stands
    above its noise too: only a logged command tells it apart.

    Args:
        command_bins: (n_bins, n_inputs) complex, scaled DFT of the command (or of the
            datum's inputs), bins 0..N//2.
        n_periods: whole periods in the record (>= 1).
        floor: least power relative to the largest harmonic's, in (0, 1).
        noise_std: (n_bins, n_inputs) float, per-bin noise standard deviation of
            ``command_bins`` (0 for a commanded input; NaN where not estimable: the test is
            then left out); None or empty: every input commanded.
    """
    n = np.arange(command_bins.shape[0])
    harmonic = (n % max(int(n_periods), 1) == 0) & (n > 0)
    power = np.sum(np.abs(command_bins) ** 2, axis=1)
    top = float(np.max(power[harmonic], initial=0.0))
    if top <= 0.0:
        return np.zeros(n.size, dtype=bool)
    excited = harmonic & (power >= floor * top)
    if noise_std is not None and noise_std.size:
        noise = np.sum(np.nan_to_num(noise_std) ** 2, axis=1)
        excited &= power > PERIODIC_RATIO**2 * noise
    return excited


def band_mask(
    freqs_hz: np.ndarray,
    band: Band | None,
    command_bins: np.ndarray | None = None,
    n_periods: int = 1,
    noise_std: np.ndarray | None = None,
) -> np.ndarray:
    """(n_bins,) bool: the bins the band counts.

    Args:
        freqs_hz: (n_bins,) float, bin frequencies (Hz).
        band: the band; ``None`` counts every bin.
        command_bins: (n_bins, n_inputs) complex, the command's scaled DFT (needed when
            ``band.excited``).
        n_periods: whole periods in the record.
        noise_std: (n_bins, n_inputs) float, the noise left in ``command_bins`` where they
            are a measured input's (:func:`excited_lines`); None: a command.
    """
    freqs = np.asarray(freqs_hz, dtype=float)
    if band is None:
        return np.ones(freqs.size, dtype=bool)
    mask = (freqs >= band.min_hz) & (freqs <= band.max_hz)
    if band.excited:
        if command_bins is None:
            raise ModelError("band 'excited' needs the command's spectrum")
        mask &= excited_lines(command_bins, n_periods, noise_std=noise_std)
    return mask


def masked_beta(per_bin: np.ndarray, weights: np.ndarray, mask: np.ndarray | None) -> float:
    """``sqrt(sum over the mask of weight_n per_bin(n)^2)``: Problem 3's total over chosen bins.

    Args:
        per_bin: (n_bins,) float, min ||W(n)|| per bin.
        weights: (n_bins,) float, one-sided bin multiplicities.
        mask: (n_bins,) bool, or ``None`` for every bin.
    """
    if mask is not None:
        per_bin, weights = per_bin[mask], weights[mask]
    with np.errstate(invalid="ignore"):
        return float(np.sqrt(np.dot(weights, per_bin * per_bin)))


def outside_lines(
    per_bin: np.ndarray,
    weights: np.ndarray,
    freqs_hz: np.ndarray,
    mask: np.ndarray,
    top: int = 5,
) -> tuple[tuple[float, float], ...]:
    """The bins outside the band that carry most of β's square there, largest first.

    Returns:
        Up to ``top`` pairs ``(frequency in Hz, sqrt(weight_n) min||W(n)||)``: each bin's
        share of β outside, in units of w (only bins with a non-zero share).
    """
    idx = np.flatnonzero(~mask)
    share = np.sqrt(weights[idx]) * per_bin[idx]
    share = np.where(np.isnan(share), np.inf, share)
    order = idx[np.argsort(-share, kind="stable")][:top]
    out = []
    for n in order:
        s = float(np.sqrt(weights[n]) * per_bin[n])
        if s > 0.0 or math.isnan(s):
            out.append((float(freqs_hz[n]), s))
    return tuple(out)


PERIODIC_RATIO = 5.0
"""A harmonic bin holds a periodic line where some output's ``|Y_i(n)|`` exceeds this many
times its period-to-period noise standard deviation (``Datum.noise_std``)."""


def periodic_lines(
    y_bins: np.ndarray,
    noise_std: np.ndarray,
    freqs_hz: np.ndarray,
    mask: np.ndarray,
    top: int = 5,
) -> tuple[tuple[float, float], ...]:
    """The periodic lines outside the band: harmonic bins whose output stands above its noise.

    A line that repeats from period to period has ``|Y_i(n)|`` far above the spread of
    its period-by-period DFT (``noise_std``, finite at the harmonic bins of a record of two
    or more periods only); outside the excited lines it is a disturbance or nonlinear
    distortion, not noise (docs/theory.md §12).

    Args:
        y_bins: (n_bins, ny) complex, the outputs' scaled DFT.
        noise_std: (n_bins, ny) float, per-bin noise standard deviation (NaN: not estimable).
        freqs_hz: (n_bins,) float.
        mask: (n_bins,) bool, the band.
        top: most lines returned.

    Returns:
        Up to ``top`` pairs ``(Hz, largest |Y_i(n)| / noise_std_i(n))`` outside the band with
        the ratio above :data:`PERIODIC_RATIO`, largest first (DC left out).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.abs(y_bins) / noise_std
    ratio = np.where(np.isnan(ratio), 0.0, ratio).max(axis=1) if ratio.size else ratio
    outside = ~np.asarray(mask, dtype=bool)
    outside[0] = False
    idx = np.flatnonzero(outside & (ratio > PERIODIC_RATIO))
    order = idx[np.argsort(-ratio[idx], kind="stable")][:top]
    return tuple((float(freqs_hz[n]), float(ratio[n])) for n in order)
