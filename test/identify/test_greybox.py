"""The two-tank grey box on the simulated rig: its parameters, and the model set it makes.

References: the RigParams the simulator ran (``tools.rig_experiments.RIG``), and the faults
injected into it (docs/detection.md "Stated limits": each at twice its limit).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tools import rig_experiments as rx
from tools.rig_faults import TWICE_STATED_LIMITS
from twotank_validation import cli
from twotank_validation.core.model import model_from_dict
from twotank_validation.core.validate import validate
from twotank_validation.diagnose.inputs import Window
from twotank_validation.errors import IdentificationError
from twotank_validation.identify.greybox import (
    GreyBoxConfig,
    GreyBoxModel,
    ParameterStatus,
    fit_two_tank,
)
from twotank_validation.identify.nonparametric import FrequencyResponse
from twotank_validation.identify.pipeline import IdentifyConfig, identified_model, identify_windows
from twotank_validation.sim.faults import parse_fault
from twotank_validation.sim.rig import RigParams
from twotank_validation.usecases.identify import identification_json

INPUTS, OUTPUTS = ["hot", "cold"], ["height", "temperature"]
PRIOR = RigParams(
    area=60.0,
    outlet_alpha=1.0,
    outlet_beta=0.3,
    hot_supply_temp=0.8,
    cold_supply_temp=0.2,
    mixing_delay_s=5.0,
)
"""The fit's start: every fitted parameter 20-70 % off the simulated rig's."""


@pytest.fixture(scope="module")
def made():
    windows = rx.windows()
    config = IdentifyConfig(
        orders=range(1, 2), grey_box=GreyBoxModel.TWO_TANK, grey_box_prior=PRIOR
    )
    ident = identify_windows(windows, config)
    return ident, identified_model(ident, windows, "grey", INPUTS, OUTPUTS)


def test_the_grey_box_recovers_the_rig_parameters_within_their_intervals(made):
    ident, _ = made
    gb = ident.grey_box
    assert gb is not None
    # linearised at the measured operating point: the windows' mean outputs
    y = np.concatenate([w.y for w in rx.windows()])
    assert (gb.op.height, gb.op.temperature) == pytest.approx(tuple(y.mean(axis=0)))
    fitted = {e.name: e for e in gb.estimates if e.status is ParameterStatus.FITTED}
    # the level's and the temperature's balances: every one of these is identifiable
    assert set(fitted) >= {
        "area", "outlet_alpha", "outlet_beta", "hot_supply_temp", "cold_supply_temp",
        "mixing_delay_s",
    }  # fmt: skip
    for name, e in fitted.items():
        truth = getattr(rx.RIG, name)
        assert abs(e.value - truth) <= 3 * e.std, (name, e.value, e.std, truth)
    # the intervals are informative, not wide enough to hold anything
    assert fitted["area"].std < 0.02 * rx.RIG.area
    assert fitted["outlet_alpha"].std < 0.05 * rx.RIG.outlet_alpha
    assert fitted["hot_supply_temp"].std < 0.05
    assert fitted["mixing_delay_s"].std < 1.0
    # the valve lag (0.05 s) and the rig's absent mixing lag are out of the band's reach:
    # reported as not determined and pinned at the prior, not invented
    for name in ("valve_tau_s", "mixing_lag_s"):
        e = gb.estimate(name)
        assert e.status is ParameterStatus.UNDETERMINED
        assert e.value == e.prior
        assert math.isnan(e.std)


def test_the_grey_box_nominal_is_the_rigs_linearisation_written_with_a_hold(made):
    ident, result = made
    assert result.document["intersample"] == "zoh"
    gb = ident.grey_box
    # the mixing delay grows with the level: at h0 it is mixing_delay_s h0 / mixing_ref_level
    delay = gb.estimate("mixing_delay_s").value * gb.op.height / rx.RIG.mixing_ref_level
    assert result.document["nominal"]["ss"]["output_delays_s"][1] == pytest.approx(delay)
    # the model file's nominal at the lines equals the grey box's response there
    model = model_from_dict(result.document)
    theta = 2 * np.pi * ident.response.lines / rx.PERIOD
    p23 = model.response(theta, rx.TS_S).p23
    np.testing.assert_allclose(p23, ident.grey_box.response(ident.response.freqs_hz), rtol=1e-9)


def test_with_the_temperature_alone_only_ratios_are_determined_and_two_are_pinned(made):
    """The level's entries made uninformative (σ × 10⁴): the temperature gives
    ``A h0 / F``, ``(t_h - t0) / F`` and ``(t_c - t0) / F`` with ``F = (h0 + β) / α``, three
    combinations of the five physical parameters (docs/theory.md §17), so two are pinned."""
    ident, _ = made
    fr = ident.response
    var = fr.var.copy()
    var[:, 0, :] *= 1e8
    blind = dataclasses.replace(fr, var=var)
    physical = ("area", "outlet_alpha", "outlet_beta", "hot_supply_temp", "cold_supply_temp")
    op = ident.grey_box.op
    free = (*physical, "mixing_delay_s")
    gb = fit_two_tank(
        blind, rx.TS_S, GreyBoxConfig(op.height, op.temperature, prior=PRIOR, free=free)
    )
    pinned = [n for n in physical if gb.estimate(n).status is ParameterStatus.UNDETERMINED]
    assert len(pinned) == 2, pinned
    assert gb.estimate("mixing_delay_s").status is ParameterStatus.FITTED


def test_a_pinned_parameter_is_not_fitted_and_a_non_two_by_two_response_is_refused(made):
    ident, _ = made
    fr = ident.response
    gb = fit_two_tank(
        fr,
        rx.TS_S,
        GreyBoxConfig(height=ident.grey_box.op.height, temperature=0.5, free=("area",)),
    )
    assert gb.fitted == ("area",)
    assert gb.estimate("outlet_alpha").status is ParameterStatus.PINNED
    one = FrequencyResponse(fr.lines, fr.freqs_hz, fr.g[:, :1], fr.var[:, :1], 3, 2)
    with pytest.raises(IdentificationError, match="2 x 2 response"):
        fit_two_tank(one, rx.TS_S, GreyBoxConfig(height=0.47, temperature=0.5))


# --- held out and faults ---------------------------------------------------------------------

ONSET_S = (rx.SETTLE + 0.25) * rx.PERIOD * rx.TS_S
"""A quarter period into the held-out record's judged periods."""

# Each rig fault at twice its stated limit (docs/detection.md "Stated limits", the default
# alarm), and the kinds without a stated limit at the detection matrix's sizes that
# test/online/test_livediag.py also uses.
FAULTS = list(TWICE_STATED_LIMITS)


def _held_out(spec: str | None) -> float:
    """β of the grey-box set on one held-out record (2 judged periods, its own noise)."""
    faults = () if spec is None else (parse_fault(f"{spec}@{ONSET_S}"),)
    u, y = rx.experiment(1.0, periods=2, seed=11, faults=faults)
    keep = slice(rx.SETTLE * rx.PERIOD, None)
    return Window(u[keep], y[keep], rx.TS_S, rx.PERIOD).datum()


@pytest.fixture(scope="module")
def model(made):
    return model_from_dict(made[1].document)


def test_the_set_is_valid_on_held_out_nominal_data(made, model):
    _, result = made
    assert np.all(result.beta < 1.0)
    assert validate(_held_out(None), model).beta < 1.0


@pytest.mark.parametrize("spec", FAULTS)
def test_the_set_is_invalidated_by_each_rig_fault(model, spec):
    assert validate(_held_out(spec), model).beta > 1.0


def test_the_json_holds_each_parameter_with_its_sigma(made):
    ident, result = made
    doc = identification_json(ident, result, None)["grey_box"]
    by_name = {p["name"]: p for p in doc["parameters"]}
    for e in ident.grey_box.estimates:
        assert by_name[e.name]["value"] == e.value
        assert by_name[e.name]["status"] == e.status.value
    assert by_name["area"]["std"] == ident.grey_box.estimate("area").std
    assert by_name["valve_tau_s"]["std"] is None  # pinned: no σ


@pytest.mark.parametrize(
    ("name", "message"),
    [("two-tank", "needs 2 inputs"), ("three-tank", "not a known model")],
)
def test_the_cli_refuses_a_grey_box_it_cannot_fit(capsys, name, message):
    code = cli.main(
        [
            "identify", "test/data/cascaded_tanks/dataBenchmark.csv",
            "--map", "test/data/cascaded_tanks/estimation.map.yaml", "--ts", "4",
            "--period", "1024", "--grey-box", name, "--quiet",
        ]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code != cli.EXIT_OK
    assert message in err
    assert "Traceback" not in err
