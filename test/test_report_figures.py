"""The report's figures show what their captions claim, for any shape of model.

References: data made in the frequency domain as the nominal plant's exact periodic steady
state (``Y = G U`` at every bin, by construction), so the measured point of the Nyquist figure
must sit on the nominal; an output scaled by ``1 + g`` must put it at ``(1 + g) G``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from twotank_validation import report
from twotank_validation.core import lti
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model
from twotank_validation.core.validate import validate

HERE = Path(__file__).parent
PERIOD = 256
TS = 0.8


def steady_state(
    model,
    n_periods: int = 2,
    seed: int = 0,
    gain: dict[int, float] | None = None,
    inputs: tuple[int, ...] | None = None,
):
    """(u, y): a random periodic input (on ``inputs``, default all) and the nominal's exact
    periodic response to it (each output ``j`` of ``gain`` scaled by ``1 + gain[j]``)."""
    rng = np.random.default_rng(seed)
    spec = np.zeros((PERIOD // 2 + 1, model.nu), dtype=complex)
    spec[1:40] = rng.standard_normal((39, model.nu)) + 1j * rng.standard_normal((39, model.nu))
    if inputs is not None:
        spec[:, [k for k in range(model.nu) if k not in inputs]] = 0.0
    one = np.fft.irfft(spec, n=PERIOD, axis=0)
    u = np.tile(one, (n_periods, 1))
    theta = 2 * np.pi * np.arange(PERIOD // 2 + 1) / PERIOD
    g = lti.frequency_response(model.nominal_discrete(TS), theta)  # (bins, ny, nu)
    y_one = np.fft.irfft(np.einsum("kij,kj->ki", g, spec), n=PERIOD, axis=0)
    for j, factor in (gain or {}).items():
        y_one[:, j] *= 1.0 + factor
    return u, np.tile(y_one, (n_periods, 1)) + 0.3


@pytest.mark.parametrize("name", ["B", str(HERE / "data" / "models" / "one_by_three.yaml")])
def test_the_measured_point_of_nominal_data_is_the_nominal(tmp_path, name) -> None:
    model = load_model(name)
    u, y = steady_state(model)
    d = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    res = validate(d, model)
    view = report.plot_nyquist(model, d, res, tmp_path / "n.png")
    assert view.measured == pytest.approx(view.nominal, rel=1e-9, abs=1e-12)
    assert (tmp_path / "n.png").stat().st_size > 0


def test_a_scaled_output_moves_the_point_by_that_factor(tmp_path) -> None:
    model = load_model("B")
    # the hot valve alone excited, the temperature 40 % too large
    u, y = steady_state(model, gain={1: 0.4}, inputs=(0,))
    d = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
    view = report.nyquist_view(model, d, validate(d, model))
    assert (view.output, view.input) == (1, 0)  # the error is on the temperature alone
    assert view.measured == pytest.approx(1.4 * view.nominal, rel=1e-9)


def test_the_figure_depends_on_the_window(tmp_path) -> None:
    """Two windows of other data give other pictures (they once were byte-identical)."""
    model = load_model("B")
    paths = []
    for seed in (0, 1):
        u, y = steady_state(model, seed=seed, gain={1: 0.4})
        d = make_datum(u, y, ts_s=TS, period_samples=PERIOD)
        paths.append(tmp_path / f"n{seed}.png")
        report.plot_nyquist(model, d, validate(d, model), paths[-1])
    assert paths[0].read_bytes() != paths[1].read_bytes()


def test_the_alarm_timeline_plots_what_the_alarm_uses(tmp_path, monkeypatch) -> None:
    """An ERROR window raised by the operating point is drawn at beta_total, not at beta."""
    drawn: list[float] = []
    real = report.plt.Axes.plot

    def spy(self, x, y, *args, **kwargs):
        if len(y) == 2 and kwargs.get("lw") == 3:
            drawn.append(float(y[0]))
        return real(self, x, y, *args, **kwargs)

    monkeypatch.setattr(report.plt.Axes, "plot", spy)
    window = {"start": 0.0, "end": 1.0, "beta": 0.5, "beta_total": 5.02, "alarm": "ERROR"}
    report.plot_alarm_timeline({"models": {"B": {"windows": [window]}}}, tmp_path / "t.png")
    assert drawn == [5.02]
