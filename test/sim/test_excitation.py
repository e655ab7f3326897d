"""Tests of the periodic excitation signals (twotank_validation.sim.excitation).

Independent references: the steady-state response of scipy's time-domain Butterworth filter
to a long repetition of the same white noise, the closed-form magnitude of the bilinear
Butterworth filter, and harmonic sets computed from k / (n ts) by hand.
"""

import math
import re

import numpy as np
import pytest
import scipy.signal
from hypothesis import given
from hypothesis import strategies as st

from twotank_validation.errors import DatumError
from twotank_validation.sim.excitation import (
    ExcitationConfig,
    excitation_commands,
    excitation_period,
    filtered_noise_period,
    multisine_period,
    record_slice,
)

OFFSET = np.array([0.4, 0.4])


def butterworth_magnitude(f_hz, cutoff_hz, order, ts_s):
    """|H| of the digital (bilinear) Butterworth low-pass, closed form."""
    ratio = np.tan(np.pi * f_hz * ts_s) / np.tan(np.pi * cutoff_hz * ts_s)
    return 1.0 / np.sqrt(1.0 + ratio ** (2 * order))


def rms(x):
    return np.sqrt(np.mean(np.square(x), axis=0))


# --- filtered noise ----------------------------------------------------------------------


def test_filtered_noise_equals_steady_state_of_time_domain_filter():
    n, ts, cutoff, order = 1024, 0.1, 0.2, 3
    x = filtered_noise_period(n, ts, cutoff, order, np.random.default_rng(5))
    white = np.random.default_rng(5).standard_normal(n)  # the same draw
    sos = scipy.signal.butter(order, cutoff, output="sos", fs=1 / ts)
    y = scipy.signal.sosfilt(sos, np.tile(white, 30))[-n:]  # transient long gone
    y = (y - y.mean()) / rms(y - y.mean())
    np.testing.assert_allclose(x, y, rtol=0, atol=1e-9)


def test_filtered_noise_spectrum_follows_butterworth():
    n, ts, cutoff, order = 8192, 0.1, 0.2, 2
    x = filtered_noise_period(n, ts, cutoff, order, np.random.default_rng(0))
    white = np.random.default_rng(0).standard_normal(n)
    f = np.fft.rfftfreq(n, ts)[1:]
    ratio = np.abs(np.fft.rfft(x))[1:] / np.abs(np.fft.rfft(white))[1:]
    expected = butterworth_magnitude(f, cutoff, order, ts)
    gain = ratio[0] / expected[0]  # the unit-RMS scaling
    np.testing.assert_allclose(ratio, gain * expected, rtol=1e-8, atol=1e-12)
    # Nearly no energy above 3x the cutoff: the order-2 tail integral is about 1.1 %.
    power = np.abs(np.fft.rfft(x)) ** 2
    freqs = np.fft.rfftfreq(n, ts)
    assert power[freqs > 3 * cutoff].sum() / power.sum() < 0.03
    assert power[freqs > 10 * cutoff].sum() / power.sum() < 1e-3


@given(
    n=st.integers(4, 3000),
    cutoff_fraction=st.floats(0.01, 0.9),
    order=st.integers(1, 6),
    seed=st.integers(0, 2**31),
)
def test_filtered_noise_is_zero_mean_unit_rms(n, cutoff_fraction, order, seed):
    ts = 0.1
    x = filtered_noise_period(n, ts, cutoff_fraction * 5.0, order, np.random.default_rng(seed))
    assert x.shape == (n,)
    assert abs(x.mean()) < 1e-12
    assert rms(x) == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize(
    ("args", "named"),
    [
        ((3, 0.1, 0.01, 2), "n=3"),
        ((64, 0.1, 5.0, 2), "cutoff_hz=5.0"),
        ((64, 0.1, 0.1, 0), "order=0"),
    ],
)
def test_filtered_noise_rejects_bad_arguments(args, named):
    with pytest.raises(DatumError, match=re.escape(named)):
        filtered_noise_period(*args, np.random.default_rng(0))


# --- multisine ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("f_min", "f_max", "odd_only", "bins"),
    [
        (1 / 204.8, 0.05, False, list(range(1, 11))),  # 0.05 Hz = bin 10.24
        (1 / 204.8, 0.05, True, [1, 3, 5, 7, 9]),
        (3 / 204.8, 6 / 204.8, False, [3, 4, 5, 6]),  # band edges on bins are inside
        (3 / 204.8, 6 / 204.8, True, [3, 5]),
    ],
)
def test_multisine_excites_only_requested_harmonics(f_min, f_max, odd_only, bins):
    n, ts = 2048, 0.1
    x = multisine_period(n, ts, f_min, f_max, odd_only, np.random.default_rng(2))
    spectrum = np.abs(np.fft.rfft(x))
    excited = np.flatnonzero(spectrum > 1e-9 * spectrum.max())
    np.testing.assert_array_equal(excited, bins)
    np.testing.assert_allclose(spectrum[bins], spectrum[bins[0]], rtol=1e-10)  # flat
    # Unit RMS, zero mean: each of the K bins holds amplitude sqrt(2/K) (Parseval).
    assert abs(x.mean()) < 1e-13
    assert rms(x) == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(spectrum[bins] * 2 / n, math.sqrt(2 / len(bins)), rtol=1e-10)


def test_multisine_phases_are_random_and_seeded():
    a = multisine_period(512, 0.1, 0.02, 1.0, False, np.random.default_rng(1))
    b = multisine_period(512, 0.1, 0.02, 1.0, False, np.random.default_rng(1))
    c = multisine_period(512, 0.1, 0.02, 1.0, False, np.random.default_rng(2))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.1
    # Random phases keep the crest factor far below the sqrt(2 K) of aligned phases.
    assert np.abs(a).max() < 0.5 * math.sqrt(2 * 102)


@pytest.mark.parametrize(
    ("f_min", "f_max", "odd_only", "match"),
    [
        (0.020, 0.021, False, "no harmonic"),  # bins 4.096 .. 4.30
        (2 / 204.8, 2 / 204.8, True, "no odd harmonic"),
        (0.0, 0.05, False, "f_min_hz=0.0"),
        (0.01, 5.0, False, "Nyquist"),
        (0.03, 0.02, False, "f_min_hz <= f_max_hz"),
    ],
)
def test_multisine_rejects_bad_band(f_min, f_max, odd_only, match):
    with pytest.raises(DatumError, match=re.escape(match)):
        multisine_period(2048, 0.1, f_min, f_max, odd_only, np.random.default_rng(0))


# --- configuration and commands ----------------------------------------------------------


@pytest.mark.parametrize("kind", ["filtered_noise", "multisine"])
def test_excitation_period_scaled_and_independent(kind):
    config = ExcitationConfig(kind=kind, rms=(0.07, 0.03), seed=9)
    period = excitation_period(config)
    assert period.shape == (2048, 2)
    np.testing.assert_allclose(rms(period), [0.07, 0.03], rtol=1e-12)
    np.testing.assert_allclose(period.mean(axis=0), 0.0, atol=1e-15)
    assert abs(np.corrcoef(period.T)[0, 1]) < 0.9  # different realisations per valve
    np.testing.assert_array_equal(period, excitation_period(config))  # seeded
    other = excitation_period(ExcitationConfig(kind=kind, rms=(0.07, 0.03), seed=10))
    assert np.abs(period - other).max() > 0.01


def test_zero_rms_leaves_valve_at_offset():
    config = ExcitationConfig(rms=(0.05, 0.0))
    commands = excitation_commands(config, OFFSET)
    np.testing.assert_array_equal(commands[:, 1], 0.4)
    assert np.ptp(commands[:, 0]) > 0.05


@pytest.mark.parametrize("kind", ["filtered_noise", "multisine"])
def test_commands_are_exactly_periodic_with_offset(kind):
    config = ExcitationConfig(kind=kind, period_samples=512, settle_periods=3, record_periods=2)
    commands = excitation_commands(config, OFFSET)
    assert commands.shape == (512 * 5, 2)
    periods = commands.reshape(5, 512, 2)
    assert np.abs(np.diff(periods, axis=0)).max() <= 1e-15
    np.testing.assert_allclose(periods[0] - OFFSET, excitation_period(config), rtol=0, atol=1e-15)
    np.testing.assert_allclose(commands.mean(axis=0), OFFSET, rtol=0, atol=1e-14)


def test_record_slice_covers_recorded_periods():
    config = ExcitationConfig(period_samples=256, settle_periods=5, record_periods=3)
    sl = record_slice(config)
    commands = excitation_commands(config, OFFSET)
    recorded = commands[sl]
    assert recorded.shape == (3 * 256, 2)
    assert sl.start == 5 * 256
    assert sl.stop == len(commands)
    np.testing.assert_array_equal(recorded[:256], commands[:256])
    assert record_slice(ExcitationConfig(settle_periods=0, record_periods=1)) == slice(0, 2048)


def test_default_config_fits_default_operating_point():
    # Operating commands of the paper's point: 0.3993 per valve.
    op_commands = np.full(2, 0.5 * 1.07 / 1.34)
    for kind in ("filtered_noise", "multisine"):
        commands = excitation_commands(ExcitationConfig(kind=kind), op_commands)
        assert commands.min() >= 0.0
        assert commands.max() <= 1.0
        assert len(commands) == 2048 * 7


def test_out_of_range_commands_raise_with_advice():
    config = ExcitationConfig(rms=(0.05, 0.3), seed=1)
    with pytest.raises(DatumError, match="cold valve") as info:
        excitation_commands(config, OFFSET)
    suggested = float(re.search(r"rms\[1\] <= ([0-9.e-]+)", str(info.value)).group(1))
    assert 0 < suggested < 0.3
    fixed = excitation_commands(ExcitationConfig(rms=(0.05, suggested), seed=1), OFFSET)
    assert fixed.min() >= 0.0
    assert fixed.max() <= 1.0
    # The advice is tight (rounded down to 4 digits): 0.1 % more would not fit.
    with pytest.raises(DatumError):
        excitation_commands(ExcitationConfig(rms=(0.05, 1.001 * suggested), seed=1), OFFSET)
    with pytest.raises(DatumError, match="hot valve"):
        excitation_commands(ExcitationConfig(rms=(0.05, 0.05)), np.array([0.98, 0.4]))


@pytest.mark.parametrize("offset", [np.array([0.4]), np.array([0.4, np.nan])])
def test_bad_offset_raises(offset):
    with pytest.raises(DatumError, match="offset"):
        excitation_commands(ExcitationConfig(), offset)


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"kind": "chirp"}, "kind='chirp'"),
        ({"ts_s": 0.0}, "ts_s=0.0"),
        ({"period_samples": 2}, "n=2"),
        ({"period_samples": True}, "n=True"),
        ({"settle_periods": -1}, "settle_periods=-1"),
        ({"record_periods": 0}, "record_periods=0"),
        ({"rms": (0.1, -0.1)}, "rms="),
        ({"rms": (0.1,)}, "rms="),
        ({"cutoff_hz": 5.0}, "cutoff_hz=5.0"),
        ({"cutoff_hz": 0.0}, "cutoff_hz=0.0"),
        ({"order": 0}, "order=0"),
        ({"kind": "multisine", "f_max_hz": 5.0}, "Nyquist"),
        ({"kind": "multisine", "f_min_hz": 0.02, "f_max_hz": 0.021}, "no harmonic"),
        (
            {"kind": "multisine", "f_min_hz": 2 / 204.8, "f_max_hz": 2 / 204.8, "odd_only": True},
            "no odd harmonic",
        ),
    ],
)
def test_config_validates(kwargs, named):
    with pytest.raises(DatumError, match=re.escape(named)):
        ExcitationConfig(**kwargs)


def test_config_validation_is_kind_specific():
    # A multisine band above Nyquist does not matter for filtered noise and vice versa.
    ExcitationConfig(kind="filtered_noise", f_max_hz=100.0)
    ExcitationConfig(kind="multisine", cutoff_hz=100.0)
    config = ExcitationConfig()
    assert config.settle_periods == 5
    assert config.period_s == pytest.approx(204.8)
    assert config.total_samples == 2048 * 7
