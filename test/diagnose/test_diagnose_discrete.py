"""diagnose on a discrete-time nominal (a model fitted from sampled data, ``ss`` with ``dt_s``).

References, independent of the diagnosis code: the data are the discrete nominal simulated by
``scipy.signal.dlsim`` with a change injected by hand (an input's column of ``B``/``D``
scaled, an output's row of ``C``/``D`` scaled); the injected value must lie within the
reported interval. The catalogue's lag on a discrete nominal is checked against the closed-form
zero-order hold of ``1 / (1 + T s)`` in series with the channel, its delay against
``exp(-j theta tau / dt)``.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from twotank_validation.diagnose import Nominal, Window, catalogue, diagnose
from twotank_validation.sim import excitation

TS = 0.1
PERIOD = 256
A = [[0.9, 0.05], [0.0, 0.8]]
B = [[0.1, 0.0], [0.05, 0.2]]
C = [[1.0, 0.0], [0.3, 1.0]]
D = [[0.0, 0.0], [0.0, 0.0]]
NOISE = 0.002


def doc(intersample: str = "zoh") -> dict:
    return {
        "name": "fitted",
        "inputs": ["force", "flow"],
        "outputs": ["y1", "y2"],
        "intersample": intersample,
        "nominal": {"ss": {"A": A, "B": B, "C": C, "D": D, "dt_s": TS}},
        "noise": [{"outputs": ["y1", "y2"], "weight": 3 * NOISE}],
    }


def windows(b, c, seed: int, n_windows: int = 4) -> list[Window]:
    """Two periods per window after three of settling, the plant ``(A, b, c, D)`` at ``TS``."""
    exc = excitation.ExcitationConfig(
        kind="multisine", rms=(1.0, 1.0), seed=seed, ts_s=TS, period_samples=PERIOD,
        record_periods=2 * n_windows, settle_periods=3, f_min_hz=1.0 / (PERIOD * TS), f_max_hz=1.0,
    )  # fmt: skip
    u = np.tile(excitation.excitation_period(exc), (exc.settle_periods + exc.record_periods, 1))
    _, y, _ = scipy.signal.dlsim((np.array(A), np.array(b), np.array(c), np.array(D), TS), u)
    y = y + np.random.default_rng(seed).normal(0.0, NOISE, y.shape)
    rec = excitation.record_slice(exc)
    u, y, n = u[rec], y[rec], 2 * PERIOD
    cut = [slice(i * n, (i + 1) * n) for i in range(n_windows)]
    return [Window(u[c], y[c], TS, PERIOD) for c in cut]


def _within(diag, kind: str, channel: str, value: float) -> None:
    (e,) = diag.effects
    assert (str(e.spec.kind), e.to_dict(diag.outputs)["channel"]) == (kind, channel), diag.summary
    assert e.uncertainty is not None
    assert e.uncertainty.low[0] <= value <= e.uncertainty.high[0], (e.values, e.uncertainty)
    assert e.values[0] == pytest.approx(value, abs=0.02)


def test_an_injected_input_gain_is_named_on_a_discrete_nominal() -> None:
    b = np.array(B) * [1.25, 1.0]  # the force path 25 % stronger
    diag = diagnose(windows(b, C, 1), doc(), source="fitted")
    _within(diag, "input_gain", "force", 0.25)


def test_an_injected_output_gain_is_named_on_a_discrete_nominal() -> None:
    c = np.array(C) * [[1.0], [0.8]]  # y2's sensor reads 80 %
    diag = diagnose(windows(B, c, 2), doc("foh"), source="fitted")
    _within(diag, "gain", "y2", -0.2)
    assert diag.to_json()["effects"][0]["channel"] == "y2"


def test_the_catalogue_on_a_discrete_nominal() -> None:
    nom = Nominal.from_document(doc(), "fitted")
    assert nom.dt_s == TS
    found, skipped = catalogue(nom, ["y1", "y2"], period_s=PERIOD * TS, operating_point={})
    kinds = {str(s.kind) for s in found}
    assert {"delay", "lag", "gain", "input_gain"} <= kinds
    why = dict(skipped)
    for k in ("leak", "heat_loss", "hot_supply"):
        assert "nominal is discrete-time" in why[k]
    theta = np.linspace(0.01, 3.0, 7)
    z = np.exp(1j * theta)
    g = nom.hold_response(theta, TS)
    lag = next(s for s in found if s.kind == "lag" and s.channel == 1)
    t = 0.7
    pole = np.exp(-TS / t)  # ZOH of 1 / (1 + T s): (1 - pole) / (z - pole)
    got = lag.apply(nom, np.array([t])).hold_response(theta, TS)
    np.testing.assert_allclose(got[:, 1], g[:, 1] * ((1 - pole) / (z - pole))[:, None], atol=1e-12)
    np.testing.assert_allclose(got[:, 0], g[:, 0], atol=1e-12)
    delay = next(s for s in found if s.kind == "delay" and s.channel == 0)
    got = delay.apply(nom, np.array([0.25])).hold_response(theta, TS)  # 2.5 samples
    np.testing.assert_allclose(got[:, 0], g[:, 0] * np.exp(-2.5j * theta)[:, None], atol=1e-12)
    node = lag.apply(nom, np.array([t])).to_node()
    assert node["ss"]["dt_s"] == TS


def test_a_lag_on_a_discrete_nominal_follows_the_models_hold() -> None:
    """Under foh the lag is the triangle hold of 1 / (1 + T s) (closed form by partial
    fractions: (z-1)^2/(zT) Z{1/(s^2 (s + 1/T))} / T), in series with the channel."""
    nom = Nominal.from_document(doc("foh"), "fitted")
    found, _ = catalogue(nom, ["y1", "y2"], period_s=PERIOD * TS, operating_point={})
    lag = next(s for s in found if s.kind == "lag" and s.channel == 0)
    theta = np.linspace(0.01, 3.0, 7)
    z, t = np.exp(1j * theta), 0.7
    alpha, pole = 1.0 / t, np.exp(-TS / t)
    tri = 1 / alpha - (z - 1) / (alpha**2 * TS) + (z - 1) ** 2 / (alpha**2 * TS * (z - pole))
    got = lag.apply(nom, np.array([t])).hold_response(theta, TS)
    g = nom.hold_response(theta, TS)
    np.testing.assert_allclose(got[:, 0], g[:, 0] * (tri / t)[:, None], atol=1e-12)
    np.testing.assert_allclose(got[:, 1], g[:, 1], atol=1e-12)
