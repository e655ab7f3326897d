"""The operating-point check with the transient term at DC (docs/theory.md §20, issue 32).

References: the exact transient of a plant simulated by ``scipy.signal.dlsim`` from an
initial state off its periodic steady state (its share of the window's output mean is the
mean of ``y - y_steady``, the steady response simulated from far before the window); a
Monte-Carlo of white noise for the estimate's noise scale ``s_0``.
"""

from __future__ import annotations

import numpy as np
from scipy import signal
from transient_plant import MODEL, PERIOD, PERIODS, TS, N, multisine

from twotank_validation.core.datum import make_datum
from twotank_validation.core.oppoint import OperatingPoint, dc_response
from twotank_validation.core.transient import (
    dc_correction,
    dc_estimate,
    denominator,
    model_poles,
)
from twotank_validation.online.op_tracker import OperatingPointTracker, OpPointConfig

DC = dc_estimate(denominator(model_poles(MODEL, TS), N), PERIODS, 2, 2)
U_REF, Y_REF = 0.1, 0.3  # an equilibrium: the nominal's gain at DC is 3


def _window(x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Input, output and settled output (deviations from the equilibrium) from state x0."""
    sys = MODEL.nominal_discrete(TS)
    u = multisine(0)
    ss = (sys.a, sys.b, sys.c, sys.d, TS)
    _, y, _ = signal.dlsim(ss, u[:, None], x0=x0)
    _, steady, _ = signal.dlsim(ss, np.tile(u[:PERIOD], 40)[:, None])
    return u, y[:, 0], steady[-N:, 0]


def test_the_estimate_at_dc_matches_the_exact_transient_of_a_plant_started_off_equilibrium():
    u, y, steady = _window(np.array([30.0, 20.0]))
    exact = y.mean() - steady.mean()  # the transient's share of the window's mean
    datum = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    resp = MODEL.response(datum.theta, TS)
    got = dc_correction(DC, datum, resp, dc_response(MODEL, TS))
    assert abs(exact) > 0.1  # 1.45: the plain check would read it as 70 noise weights
    assert abs(got.shift[0] - exact) < 1e-4 * abs(exact)  # 2e-7 relative measured
    assert got.rho == 0.0  # a periodic input has no line among the fit lines
    plain = dc_estimate(np.ones(N // 2 + 1, complex), PERIODS, 2, 2)
    rough = dc_correction(plain, datum, resp, dc_response(MODEL, TS)).shift[0]
    assert abs(rough - exact) > 100 * abs(got.shift[0] - exact)  # the model's poles matter


def test_the_noise_left_at_dc_grows_by_the_noise_scale():
    """E|V(0) - V_hat(0)|^2 = s_0^2 E|V(0)|^2 for white noise (Monte-Carlo, 400 records)."""
    rng = np.random.default_rng(2)
    v = rng.standard_normal((400, N))
    bins = np.fft.rfft(v, axis=1) / N  # the power convention's c_N = 1/N
    left = np.array([b[0].real - DC.apply(b[:, None])[0] for b in bins])
    ratio = np.mean(left**2) / np.mean(bins[:, 0].real ** 2)
    assert abs(np.sqrt(ratio) / DC.noise_scale - 1.0) < 0.1


def test_a_drifting_window_of_a_member_off_equilibrium_is_not_invalidated_at_dc():
    """The tracker checks a window whose outputs drift with the term at DC; the plain check
    of the same means (as if steady) reads the transient as a fault."""
    u, y, _ = _window(np.array([30.0, 20.0]))
    datum = make_datum(U_REF + u, Y_REF + y, ts_s=TS, period_samples=PERIOD)
    means = OperatingPoint(datum.u_bias, datum.y_bias)
    resp = MODEL.response(datum.theta, TS)

    def tracker() -> OperatingPointTracker:
        cfg = OpPointConfig(reference_u=(U_REF,), reference_y=(Y_REF,))
        return OperatingPointTracker(MODEL, cfg, TS, N)

    term = dc_correction(DC, datum, resp, dc_response(MODEL, TS))
    checked = tracker().observe(means, steady=False, transient=term)
    assert checked.check is not None
    assert checked.beta < 0.01
    assert "transient term at DC" in checked.note
    assert tracker().observe(means, steady=False).check is None  # the term off: not checked
    assert tracker().observe(means, steady=True).beta > 10.0
