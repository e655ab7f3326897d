"""python-control interop: models in and out as ``control`` objects.

References: our own ``LFTModel.response`` (each part discretised and evaluated on its own,
then placed into P by index) against python-control's evaluation of the interconnected state
space; round trips compare P(e^{j theta}) at every bin to 1e-12.
"""

from __future__ import annotations

import copy

import control
import numpy as np
import pytest

from twotank_validation.core.control_interop import frequency_response, to_control_set
from twotank_validation.core.control_lti import from_control, to_control
from twotank_validation.core.lti import StateSpace
from twotank_validation.core.model import load_model, load_model_document, model_from_dict
from twotank_validation.errors import ModelError, ModelFileError

TS = 0.1
THETA = np.linspace(1e-3, np.pi - 1e-3, 200)


def _every_kind() -> dict:
    """Model B's document with an input-multiplicative and an additive block added."""
    doc, _ = load_model_document("B")
    doc = copy.deepcopy(doc)
    doc["perturbations"] += [
        {"name": "valves", "kind": "input_multiplicative", "inputs": ["hot", "cold"],
         "weight": [{"tf": {"num": [0.2, 0.05], "den": [1.0, 1.0]}}, 0.1]},
        {"name": "cross", "kind": "additive", "inputs": ["cold"], "outputs": ["temperature"],
         "weight": {"tf": {"num": [0.02], "den": [5.0, 1.0]}}},
    ]  # fmt: skip
    return doc


def _models() -> list:
    return [load_model("A"), load_model("B"), model_from_dict(_every_kind(), "every kind")]


def _with_control_parts(doc: dict, cs) -> dict:
    """``doc`` with its nominal and every weight replaced by the python-control objects."""
    new = copy.deepcopy(doc)
    new["nominal"] = cs.nominal
    for node in new.get("perturbations", []) + new.get("noise", []):
        node["weight"] = cs.weights[node["name"]]
    return new


@pytest.mark.parametrize("index", range(3))
def test_discrete_plant_has_the_validators_response(index: int) -> None:
    model = _models()[index]
    cs = to_control_set(model, TS)
    got = frequency_response(cs.plant, THETA)
    want = model.response(THETA, TS).p
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert cs.plant.ninputs == model.blocks.nv + model.nw + model.nu
    assert cs.plant.noutputs == model.blocks.nz + model.ny
    assert cs.block_shapes == model.blocks.shapes
    y, u = cs.output_slices["y"], cs.input_slices["u"]
    np.testing.assert_allclose(got[:, y, u], frequency_response(cs.nominal, THETA), atol=1e-12)


@pytest.mark.parametrize("discrete", [False, True])
@pytest.mark.parametrize("name", ["A", "B"])
def test_round_trip_through_python_control(name: str, discrete: bool) -> None:
    """Model -> control objects -> load_model: the same P(e^{j theta}) to 1e-12."""
    doc, _ = load_model_document(name)
    model = load_model(name)
    cs = to_control_set(model, TS if discrete else None)
    assert cs.nominal.dt == (TS if discrete else 0)
    back = load_model(_with_control_parts(doc, cs))
    np.testing.assert_allclose(
        back.response(THETA, TS).p, model.response(THETA, TS).p, rtol=0, atol=1e-12
    )


def test_continuous_plant_round_trips_as_a_generalised_plant() -> None:
    """The continuous P of a parallel structure, validated as a generalised-plant model."""
    model = load_model("B")
    cs = to_control_set(model)
    p = from_control(cs.plant)
    doc = {
        "name": "B_P",
        "inputs": list(model.input_names),
        "outputs": list(model.output_names),
        "generalized_plant": {
            "ss": {"A": p.a.tolist(), "B": p.b.tolist(), "C": p.c.tolist(), "D": p.d.tolist()},
            "blocks": [list(s) for s in cs.block_shapes],
            "noise_inputs": cs.nw,
        },
    }
    back = model_from_dict(doc)
    np.testing.assert_allclose(
        back.response(THETA, TS).p, model.response(THETA, TS).p, rtol=0, atol=1e-12
    )


def test_transfer_functions_are_accepted_for_nominal_and_weights() -> None:
    """control.tf weights give the YAML tf weights' response; a discrete tf keeps its dt."""
    doc, _ = load_model_document("A")
    new = copy.deepcopy(doc)
    new["perturbations"][1]["weight"] = control.tf([16.5, 0.1], [20.0, 1.0])
    new["noise"][1]["weight"] = control.tf([0.03], [1.0], TS)
    got = load_model(new)
    want = load_model("A")
    np.testing.assert_allclose(
        got.response(THETA, TS).p, want.response(THETA, TS).p, rtol=0, atol=1e-12
    )
    assert got.noise[1].weight.dt_s == TS


def test_bad_python_control_systems_are_clear_errors() -> None:
    doc, _ = load_model_document("A")
    new = copy.deepcopy(doc)
    new["noise"][0]["weight"] = control.tf([0.01], [1.0], True)
    with pytest.raises(ModelFileError, match=r"noise\[0\]\.weight.*dt=True.*give dt in seconds"):
        load_model(new)
    new["noise"][0]["weight"] = control.tf([1.0, 0.0, 0.0], [1.0, 1.0])  # improper
    with pytest.raises(ModelFileError, match=r"noise\[0\]\.weight"):
        load_model(new)
    delayed = StateSpace(
        np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[1.0]], None, (2.0,)
    )
    with pytest.raises(ModelError, match="output delays"):
        to_control(delayed)
