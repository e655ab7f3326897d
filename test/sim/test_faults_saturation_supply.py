"""The simulated rig's ``valve_saturation`` and ``hot_supply`` faults.

References: a nominal run of a rig whose ``RigParams.hot_supply_temp`` is changed by hand, and
its equilibrium from ``operating_point`` (hot supply); a nominal run fed commands clipped by
hand with ``np.minimum`` (valve saturation); the fault-free run for the samples before an
onset; the range and channel rules written out in the tests (text form and bad values).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twotank_validation.errors import ModelError
from twotank_validation.sim.faults import Fault, format_fault, parse_fault
from twotank_validation.sim.rig import RigParams, operating_point
from twotank_validation.sim.simulator import SimResult, TankSimulator, simulate

TS = 0.1
BASE = RigParams(mixing_delay_s=15.0, noise_std_height=0.003, noise_std_temperature=0.01)


def excitation(seed: int, n: int, *, rms: tuple[float, float] = (0.1, 0.2)) -> np.ndarray:
    """(n, 2) commands: the operating-point commands plus a slow random staircase."""
    rng = np.random.default_rng(seed)
    steps = rng.standard_normal((n // 50 + 1, 2)) * np.array(rms)
    return operating_point(BASE).commands + np.repeat(steps, 50, axis=0)[:n]


def assert_same_run(a: SimResult, b: SimResult, *, exact: bool) -> None:
    for name in ("states", "clean", "measured"):
        x, y = getattr(a, name), getattr(b, name)
        if exact:
            np.testing.assert_array_equal(x, y, err_msg=name)
        else:
            np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-13, err_msg=name)


# --- hot_supply -------------------------------------------------------------------------------


@settings(max_examples=10)
@given(shift=st.floats(-0.5, 0.5).filter(lambda s: abs(s) > 1e-3), seed=st.integers(0, 2**16))
def test_hot_supply_acts_as_a_changed_supply_temperature(shift: float, seed: int) -> None:
    u = excitation(seed, 3000)
    op = operating_point(BASE)
    faulty = simulate(BASE, u, TS, op=op, seed=seed, faults=[Fault("hot_supply", 0.0, shift)])
    changed = RigParams(**{**BASE.__dict__, "hot_supply_temp": BASE.hot_supply_temp + shift})
    reference = simulate(changed, u, TS, op=op, seed=seed)
    assert_same_run(faulty, reference, exact=False)
    # the change is not nothing: the bulk temperature moved by far more than the tolerance
    assert np.max(np.abs(faulty.states[:, 3] - simulate(BASE, u, TS, op=op).states[:, 3])) > 1e-4


@pytest.mark.parametrize(("shift", "temperature"), [(-0.1, 0.45), (-0.45, 0.4), (0.3, 0.6)])
def test_hot_supply_settles_at_the_operating_point_of_the_changed_rig(
    shift: float, temperature: float
) -> None:
    params = RigParams()
    changed = RigParams(hot_supply_temp=params.hot_supply_temp + shift)
    target = operating_point(changed, 0.47, temperature)
    ts = 0.5  # substep 0.125 s: coarse samples keep the 2000 s settling run fast
    n = round(2000.0 / ts)
    run = simulate(
        params,
        np.tile(target.commands, (n, 1)),
        ts,
        op=operating_point(params),
        faults=[Fault("hot_supply", 0.0, shift)],
    )
    hot, cold, height, temp = run.states[-1]
    assert hot == pytest.approx(target.hot_flow, abs=1e-9)
    assert cold == pytest.approx(target.cold_flow, abs=1e-9)
    assert height == pytest.approx(target.height, abs=1e-7)
    assert temp == pytest.approx(target.temperature, abs=1e-7)
    assert abs(run.states[0, 3] - temperature) > 0.01  # it started away from it
    # and the unchanged rig would need other commands to hold it: the shift is what counts
    assert abs(operating_point(params, 0.47, temperature).hot_flow - target.hot_flow) > 0.01


def test_hot_supply_that_reaches_the_cold_supply_is_refused() -> None:
    params = RigParams(hot_supply_temp=0.5, cold_supply_temp=0.1)  # room for -0.4 (exclusive)
    TankSimulator(params, TS, faults=[Fault("hot_supply", 0.0, -0.39)])
    with pytest.raises(ModelError, match=r"hot supply to 0\.1.*choose a smaller cooling"):
        TankSimulator(params, TS, faults=[Fault("hot_supply", 0.0, -0.4)])
    sim = TankSimulator(params, TS, faults=[Fault("hot_supply", 0.0, -0.2)])
    sim.add_fault(Fault("hot_supply", 10.0, 0.3))  # warming does not count against it
    with pytest.raises(ModelError, match="cold_supply_temp"):
        sim.add_fault(Fault("hot_supply", 5.0, -0.25, end_s=20.0))  # -0.45 in all


# --- valve_saturation -------------------------------------------------------------------------


@settings(max_examples=10)
@given(
    channel=st.sampled_from(["hot", "cold"]),
    limit=st.floats(0.3, 0.6),
    seed=st.integers(0, 2**16),
)
def test_valve_saturation_equals_commands_clipped_by_hand(
    channel: str, limit: float, seed: int
) -> None:
    u = np.clip(excitation(seed, 3000), 0.0, 1.0)
    col = ("hot", "cold").index(channel)
    clipped = u.copy()
    clipped[:, col] = np.minimum(u[:, col], limit)
    assert np.any(clipped != u)  # the limit does clip some commands
    fault = Fault("valve_saturation", 0.0, limit, channel)
    faulty = simulate(BASE, u, TS, seed=seed, faults=[fault])
    reference = simulate(BASE, clipped, TS, seed=seed)
    assert_same_run(faulty, reference, exact=False)
    np.testing.assert_array_equal(faulty.commands, u)  # the record keeps the requested ones
    # clipped before a weak valve scales it: delivered g min(u, limit)
    weak = Fault("valve_weak", 0.0, 0.8, channel)
    both = simulate(BASE, u, TS, seed=seed, faults=[weak, fault])
    scaled = clipped.copy()
    scaled[:, col] *= 0.8
    assert_same_run(both, simulate(BASE, scaled, TS, seed=seed), exact=False)
    # of two limits on one valve the lower applies
    looser = Fault("valve_saturation", 0.0, min(1.0, limit + 0.1), channel)
    assert_same_run(simulate(BASE, u, TS, seed=seed, faults=[looser, fault]), reference, exact=True)


@pytest.mark.parametrize("channel", ["hot", "cold"])
def test_valve_saturation_above_every_command_changes_nothing(channel: str) -> None:
    u = excitation(3, 3000, rms=(0.1, 0.1))
    top = float(u[:, ("hot", "cold").index(channel)].max())
    assert 0.45 < top < 0.9  # well inside the valve range: a limit there is a real limit
    nominal = simulate(BASE, u, TS, seed=3)
    for limit in (1.0, top):  # min(u, top) is u itself
        faulty = simulate(
            BASE, u, TS, seed=3, faults=[Fault("valve_saturation", 0, limit, channel)]
        )
        assert_same_run(faulty, nominal, exact=True)


# --- onset mid-run ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "spec", ["hot_supply=-0.1@50", "hot_supply=0.05@50.03", "valve_saturation:cold=0.45@50"]
)
def test_onset_mid_run(spec: str) -> None:
    fault = parse_fault(spec)
    u = np.clip(excitation(7, 2000), 0.0, 1.0)
    nominal = simulate(BASE, u, TS, seed=7)
    faulty = simulate(BASE, u, TS, seed=7, faults=[fault])
    onset = math.ceil(fault.onset_s / TS - 1e-9)  # first sample instant at or after onset_s
    if fault.kind == "valve_saturation":  # it acts from the first clipped command on
        onset += int(np.argmax(u[onset:, 1] > fault.magnitude))
    # the state after command k differs first: sample onset + 1
    for name in ("states", "clean", "measured"):
        np.testing.assert_array_equal(
            getattr(faulty, name)[: onset + 1], getattr(nominal, name)[: onset + 1], name
        )
    assert np.any(faulty.states[onset + 1] != nominal.states[onset + 1])


# --- text form and bad values -----------------------------------------------------------------


def test_examples_parse() -> None:
    assert parse_fault("valve_saturation:hot=0.55@1500") == Fault(
        "valve_saturation", 1500.0, 0.55, "hot"
    )
    assert parse_fault("hot_supply=-0.1@1500") == Fault("hot_supply", 1500.0, -0.1)
    assert parse_fault("hot_supply=+0.2@10-20") == Fault("hot_supply", 10.0, 0.2, end_s=20.0)


@given(
    kind_channel=st.sampled_from(
        [("valve_saturation", "hot"), ("valve_saturation", "cold"), ("hot_supply", "")]
    ),
    magnitude=st.floats(0.001, 1.0),
    negative=st.booleans(),
    onset=st.floats(0.0, 1e5),
    extra=st.one_of(st.just(math.inf), st.floats(1.0, 1e5)),
)
def test_round_trip(
    kind_channel: tuple[str, str], magnitude: float, negative: bool, onset: float, extra: float
) -> None:
    kind, channel = kind_channel
    if kind == "hot_supply":
        magnitude = (-0.5 if negative else 0.5) * magnitude
    fault = Fault(kind, onset, magnitude, channel, onset + extra)
    back = parse_fault(format_fault(fault))
    assert (back.kind, back.channel) == (kind, channel)
    assert back.magnitude == pytest.approx(magnitude, rel=1e-5)
    assert back.onset_s == pytest.approx(onset, rel=1e-5, abs=1e-9)
    assert math.isinf(back.end_s) == math.isinf(fault.end_s)
    assert parse_fault(format_fault(back)) == back  # formatting is then a fixed point


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("valve_saturation:hot=0@5", r"magnitude=0\.0 is outside \(0, 1\].*inside that range"),
        ("valve_saturation:cold=1.01@5", r"magnitude=1\.01 is outside \(0, 1\]"),
        ("valve_saturation:cold=-0.2@5", r"outside \(0, 1\]"),
        ("valve_saturation=0.5@5", r"needs channel in \('hot', 'cold'\)"),
        ("valve_saturation:height=0.5@5", r"channel='height' is invalid.*\('hot', 'cold'\)"),
        ("hot_supply=0.51@5", r"magnitude=0\.51 is outside \[-0\.5, 0\.5\].*inside that range"),
        ("hot_supply=-0.6@5", r"outside \[-0\.5, 0\.5\]"),
        ("hot_supply:hot=-0.1@5", r"whole tank: leave channel=\"\""),
        ("hot_supply@5", None),  # no magnitude: 0, accepted (no change)
    ],
)
def test_bad_values_name_the_fix(spec: str, match: str | None) -> None:
    if match is None:
        assert parse_fault(spec).magnitude == 0.0
        return
    with pytest.raises(ModelError, match=match):
        parse_fault(spec)
