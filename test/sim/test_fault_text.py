"""Text form of rig faults (ROS parameter / command line)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from twotank_validation.errors import ModelError
from twotank_validation.sim.faults import Fault, format_fault, parse_fault


def test_examples() -> None:
    assert parse_fault("leak=0.02@1000") == Fault("leak", 1000.0, 0.02)
    assert parse_fault("sensor_bias:height=-0.05@500") == Fault(
        "sensor_bias", 500.0, -0.05, "height"
    )
    assert parse_fault("valve_stuck:hot@300") == Fault("valve_stuck", 300.0, 0.0, "hot")
    f = parse_fault("valve_weak:cold=0.7@300-900")
    assert (f.channel, f.magnitude, f.onset_s, f.end_s) == ("cold", 0.7, 300.0, 900.0)


@given(
    st.sampled_from(
        [
            ("leak", ""),
            ("heat_loss", ""),
            ("sensor_bias", "temperature"),
            ("valve_weak", "hot"),
            ("mixing_delay", ""),
        ]
    ),
    st.floats(0.01, 1.0),
    st.floats(0.0, 1e5),
    st.one_of(st.just(math.inf), st.floats(1.0, 1e5)),
)
def test_round_trip(kind_channel, magnitude, onset, extra) -> None:
    kind, channel = kind_channel
    end = onset + extra
    fault = Fault(kind, onset, magnitude, channel, end)
    back = parse_fault(format_fault(fault))
    assert (back.kind, back.channel) == (kind, channel)
    assert back.magnitude == pytest.approx(magnitude, rel=1e-5)
    assert back.onset_s == pytest.approx(onset, rel=1e-5, abs=1e-9)


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("leak", "KIND"),
        ("flood=1@3", "not a known fault kind"),
        ("sensor_bias=0.1@3", "channel"),
        ("leak=2@3", "leak"),
        ("leak=0.1@5-2", "end"),
    ],
)
def test_bad_specs_name_the_problem(spec: str, match: str) -> None:
    with pytest.raises(ModelError, match=match):
        parse_fault(spec)
