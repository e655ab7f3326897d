"""How far an input's change from period to period may move β (issue 27, item 4).

References: the leakage measured from the DFT relation itself, ``R(n) = Y(n) - P U(n)``,
on a record whose output is simulated by ``scipy.signal.dlsim`` from far before the record
(the linear convolution ``Y = P U`` leaves out); brute-force loops for the transient; and
the periodicity findings' words, which must read as before now that they are typed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from twotank_validation.core.datum import (
    PeriodicityFinding,
    input_leakage_transient,
    make_datum,
)
from twotank_validation.core.model import model_from_dict
from twotank_validation.core.validate import input_leakage, result_caveats, validate

NOISE = 0.05
FIRST_ORDER = {
    "name": "lag",
    "inputs": ["u"],
    "outputs": ["y"],
    "nominal": {"tf": {"num": [2.0], "den": [5.0, 1.0]}},
    "perturbations": [{"kind": "output_multiplicative", "outputs": ["y"], "weight": 0.1}],
    "noise": [{"outputs": ["y"], "weight": NOISE}],
}
TS, PERIOD, PERIODS = 0.5, 64, 3
N = PERIOD * PERIODS


def ramp_record(slope: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u(k) = a k + a periodic excitation, from 40 time constants before the record.

    Returns the record's u and y (the plant's output, no noise) and the whole u.
    """
    model = model_from_dict(FIRST_ORDER)
    sys = model.nominal_discrete(TS)
    rng = np.random.default_rng(seed)
    before = 40 * round(5.0 / TS)  # the pre-history the leakage comes from
    k = np.arange(-before, N)
    u = slope * k + np.resize(rng.normal(size=PERIOD), k.size)  # periodic part: any phase
    _, y, _ = signal.dlsim((sys.a, sys.b, sys.c, sys.d, TS), u[:, None])
    return u[before:], y[before:, 0], u


def measured_leakage(u: np.ndarray, y: np.ndarray) -> float:
    """||R / noise weight|| with R(n) = Y(n) - P(z_n) U(n): the leakage the data hold."""
    model = model_from_dict(FIRST_ORDER)
    datum = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    p = model.response(datum.theta, TS).p23[:, 0, 0]
    r = datum.y_bins[:, 0] - p * datum.u_bins[:, 0]
    return math.sqrt(float(np.dot(datum.bin_weights, np.abs(r) ** 2))) / NOISE


@pytest.mark.parametrize("slope", [1e-3, -4e-3])
def test_a_ramp_leaks_exactly_as_estimated(slope: float) -> None:
    """A ramp changes by the same amount every period: the estimate is the leakage itself."""
    u, y, _ = ramp_record(slope)
    datum = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    model = model_from_dict(FIRST_ORDER)
    assert PeriodicityFinding.INPUT_NOT_PERIODIC in datum.periodicity.findings
    want = measured_leakage(u, y)
    assert want > 0.1  # a leakage that matters to the noise weight
    assert input_leakage(datum, model) == pytest.approx(want, rel=1e-6)
    # and it is the leakage β pays: the noise-free record of the true plant has β of it alone
    assert validate(datum, model).beta <= want + 1e-9


def test_a_periodic_input_leaks_nothing() -> None:
    u, y, _ = ramp_record(0.0)
    datum = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    assert datum.periodicity.findings == ()
    assert input_leakage(datum, model_from_dict(FIRST_ORDER)) == 0.0
    assert measured_leakage(u, y) < 1e-9


def test_the_transient_is_the_linear_minus_the_circular_convolution() -> None:
    """Brute force: r(k) = sum_{i >= 1} p(k + i) d(-i) with d the assumed pre-record change."""
    rng = np.random.default_rng(3)
    pulse = rng.normal(size=(40, 2, 3))
    change = rng.normal(size=(5, 3))
    got = input_leakage_transient(pulse, change, 4, 20)
    want = np.zeros((20, 2))
    for k in range(20):
        for i in range(1, 40 - k):
            want[k] += pulse[k + i] @ (-4 * change[(-i) % 5])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_the_warning_comes_only_where_the_leakage_may_decide_the_verdict() -> None:
    """The same non-periodic record: a caveat for β near 1, none for β far from it."""
    u, y, _ = ramp_record(1e-3)
    datum = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    model = model_from_dict(FIRST_ORDER)
    rho = input_leakage(datum, model)
    near = result_caveats(datum, model, 1.0 + 0.5 * rho)
    far = result_caveats(datum, model, 1.0 + 2.0 * rho)
    assert PeriodicityFinding.INPUT_NOT_PERIODIC in near.findings
    assert near.texts[0].startswith("input not periodic: its change from one period")
    assert f"by up to {rho:.3g}" in near.texts[0]
    assert PeriodicityFinding.INPUT_NOT_PERIODIC not in far.findings
    assert not any(t.startswith("input not periodic") for t in far.texts)
    # the ramp's other finding (its output drifts) stays in both
    assert PeriodicityFinding.OUTPUT_DRIFTS in near.findings
    assert PeriodicityFinding.OUTPUT_DRIFTS in far.findings
    assert near.input_leakage == far.input_leakage == rho


def test_the_periodicity_findings_read_as_they_did() -> None:
    """Typed findings; the words (what the reports, JSON and diagnosis read) unchanged."""
    rng = np.random.default_rng(0)
    u = rng.normal(size=(4 * 32, 2))
    y = rng.normal(size=(4 * 32, 1)) + np.linspace(0.0, 3.0, 4 * 32)[:, None]
    per = make_datum(u, y, ts_s=1.0, period_samples=32).periodicity
    assert per.findings[:2] == (
        PeriodicityFinding.INPUT_NOT_PERIODIC,
        PeriodicityFinding.OUTPUT_DRIFTS,
    )
    words = per.messages
    assert words[0] == (
        "input not periodic: period-to-period variation up to "
        f"{float(per.input_variation.max()):.3g} of its RMS"
    )
    assert words[1].startswith("output mean drifts by up to ")
    assert words[1].endswith(
        "of its RMS across the record: a transient may still be decaying (settle longer "
        "before recording)"
    )
    assert all(f.transient for f in per.findings[1:])
    one = make_datum(u[:32], y[:32], ts_s=1.0, period_samples=32).periodicity
    assert one.messages == ("one period only: periodicity and noise cannot be checked",)
