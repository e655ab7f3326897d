"""The fault named live: the live diagnosis against the faults injected into the simulated rig.

References: the fault each run injects (its kind, channel and size) through the documented
table ``expected_effect``; a second run of the same data (bag replay, a background executor)
for the parity checks; the nominal rig (no fault) for the negative control.
"""

from __future__ import annotations

import concurrent.futures
import math

import pytest

from tools.events import record_events, two_tank_value
from twotank_validation import replay
from twotank_validation.bags import open_bag, write_scenario_bag
from twotank_validation.core.model import load_model, load_model_document
from twotank_validation.diagnose.kinds import expected_effect, named
from twotank_validation.diagnose.live_jobs import catalogue_diagnosis
from twotank_validation.online import STREAMS, MonitorConfig, OnlineValidator, RigUnits
from twotank_validation.online.livediag import LiveDiagConfig, LiveDiagnoser
from twotank_validation.online.streams import stamp_ns
from twotank_validation.sim.faults import FAULT_KINDS, parse_fault
from twotank_validation.sim.scenario import Scenario, simulate_scenario

PERIOD_S = 204.8
WINDOW_S = 2 * PERIOD_S
ONSET_S = round(6.375 * PERIOD_S, 1)  # three non-overlapping nominal windows before it


def scenario(spec: str | None, windows_after: int = 3, seed: int = 0) -> Scenario:
    faults = (f"{spec}@{ONSET_S}",) if spec else ()
    return Scenario(
        name="livediag",
        duration_s=round(ONSET_S + windows_after * WINDOW_S, 1),
        seed=seed,
        faults=faults,
    )


def diagnoser(max_updates: int = 2, executor=None) -> LiveDiagnoser:
    doc, _ = load_model_document("B")
    return LiveDiagnoser(
        catalogue_diagnosis({"B": doc}),
        LiveDiagConfig(max_updates=max_updates),
        executor=executor,
    )


def run(spec: str | None, *, windows_after: int = 3, executor=None, seed: int = 0):
    sc = scenario(spec, windows_after, seed)
    stamps, u, y = simulate_scenario(sc)
    dg = diagnoser(executor=executor)
    v = OnlineValidator(MonitorConfig(), [load_model("B")], diagnoser=dg)
    reports = v.feed_many(*record_events(stamps, u, y))
    return reports, dg


# Each rig fault at twice its stated limit (docs/detection.md, "Stated limits", the default
# alarm), and the faults without a stated limit at a size of the detection matrix that the
# default alarm detects. The second item is the answer the diagnosis gives: the expected one,
# except where the live diagnosis cannot tell the fault from another (and says which).
CASES = [
    ("leak=0.06", None),
    ("sensor_bias:height=0.05", None),
    ("sensor_bias:temperature=0.16", None),
    ("valve_weak:hot=0.86", None),
    ("valve_weak:cold=0.86", None),
    ("sensor_delay:height=10", None),
    ("sensor_delay:temperature=30", None),
    ("mixing_delay=35", None),
    ("heat_loss=0.2", None),
    ("valve_stuck:hot=0", None),
    ("valve_saturation:hot=0.38", None),
    ("hot_supply=-0.15", None),
]

MOVES_OPERATING_POINT = ("leak", "sensor_bias", "valve_weak", "heat_loss", "hot_supply")
"""Faults whose steady means move: the answer dates the change from them."""


PARAMETERS = {
    "sensor_bias:height=0.05": ("offset", 0.05, 0.1),
    "sensor_bias:temperature=0.16": ("offset", 0.16, 0.1),
    "valve_weak:cold=0.86": ("gain_error", -0.14, 0.1),
    "valve_weak:hot=0.86": ("gain_error", -0.14, 0.1),
    "sensor_delay:height=10": ("delay_s", 10.0, 0.05),
    "sensor_delay:temperature=30": ("delay_s", 30.0, 0.05),
    "leak=0.06": ("outflow", 0.06, 0.1),
}
"""The fitted parameter of the answer against the injected size (name, size, rtol)."""


@pytest.mark.parametrize(("spec", "confused_with"), CASES, ids=[c[0] for c in CASES])
def test_live_diagnosis_names_the_injected_fault(spec, confused_with) -> None:
    reports, _dg = run(spec)
    fault = parse_fault(f"{spec}@{ONSET_S}")
    after_alarm = [r for r in reports if r.alarm.name == "ERROR"]
    assert after_alarm, f"{spec}: the alarm never rose"
    answers = [r.diagnosis for r in reports if r.diagnosis is not None]
    assert answers, f"{spec}: no diagnosis after the alarm"
    last = answers[-1]
    # every answer comes after the alarm and after the onset, stamped by its window
    first_error = after_alarm[0].end_ns
    assert all(a.window_end_ns >= first_error for a in answers)
    assert all(a.onset_ns < first_error for a in answers)
    if fault.kind in MOVES_OPERATING_POINT:  # dated within a period of the injected onset
        assert all(abs(a.onset_ns / 1e9 - ONSET_S) <= PERIOD_S for a in answers), [
            a.onset_ns / 1e9 - ONSET_S for a in answers
        ]
    assert 0.0 <= last.score <= 1.0
    assert last.probability is not None
    assert 0.0 <= last.probability <= 1.0
    if confused_with is None:
        assert named(last, fault), f"{spec}: named {last.kind} on {last.channel}: {last.summary}"
        if spec in PARAMETERS:  # the fitted size against the injected one
            name, true, rtol = PARAMETERS[spec]
            assert last.parameters[name] == pytest.approx(true, rel=rtol), last
    else:
        assert not named(last, fault)
        assert (last.kind, last.channel) == confused_with, last.summary


def test_nominal_data_gives_no_diagnosis() -> None:
    reports, dg = run(None, windows_after=2)
    assert sum(r.judged for r in reports) >= 8
    assert all(r.diagnosis is None for r in reports)
    assert dg.jobs_started == 0


def test_background_executor_gives_the_answers_of_the_synchronous_run() -> None:
    """The documented rule: the same answers in order, only the report they ride on may differ."""
    sync_reports, sync_dg = run("sensor_bias:temperature=0.16")
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        bg_reports, bg_dg = run("sensor_bias:temperature=0.16", executor=pool)
    got = {id(r.diagnosis): r.diagnosis for r in bg_reports if r.diagnosis is not None}
    want = {id(r.diagnosis): r.diagnosis for r in sync_reports if r.diagnosis is not None}
    assert sync_dg.jobs_started == bg_dg.jobs_started == 2
    sync_answers = sorted(want.values(), key=lambda d: d.update)
    bg_answers = sorted(got.values(), key=lambda d: d.update)
    # a background answer may come too late for the last report; what came is identical
    assert bg_answers == sync_answers[: len(bg_answers)]
    # synchronously, an answer rides on the report of the window that started it
    for r in sync_reports:
        if r.diagnosis is not None and r.diagnosis.window_end_ns == r.end_ns:
            break
    else:
        pytest.fail("no synchronous answer rode on its own window's report")


def test_replay_equals_the_event_fed_run_bit_for_bit(tmp_path) -> None:
    """Bag replay (bulk decoding, feed_many) == the bag's messages fed one by one (feed)."""
    sc = scenario("sensor_bias:height=0.05")
    bag = write_scenario_bag(sc, tmp_path / "bias", storage="mcap")
    cfg = replay.ReplayConfig(diagnosis=True, diagnosis_config=LiveDiagConfig(max_updates=2))
    res = replay.replay_bag(bag, [load_model("B")], cfg)
    v = OnlineValidator(MonitorConfig(), [load_model("B")], diagnoser=diagnoser())
    fed = []
    with open_bag(bag) as reader:
        for m in reader.messages(list(STREAMS)):
            stream = m.topic.lstrip("/")
            value = two_tank_value(stream, m.msg, RigUnits())
            fed += v.feed(stream, stamp_ns(m.msg), value)
    assert len(res.reports) == len(fed)
    for a, b in zip(res.reports, fed, strict=True):
        assert (a.end_ns, a.alarm, a.judged) == (b.end_ns, b.alarm, b.judged)
        assert a.beta == b.beta or (math.isnan(a.beta) and math.isnan(b.beta))
        assert a.diagnosis == b.diagnosis
    summary = replay.summary_json(res)
    windows = summary["models"]["B"]["windows"]
    entries = [w["diagnosis"] for w in windows if w["diagnosis"] is not None]
    assert entries
    assert entries[-1]["kind"] == "offset"
    assert entries[-1]["channel"] == "height"
    assert set(entries[-1]) == {
        "kind",
        "channel",
        "parameters",
        "probability",
        "score",
        "onset",
        "window_end",
        "windows",
        "update",
        "summary",
    }
    assert all(w["diagnosis"] is None for w in windows if w["alarm"] != "ERROR")


def test_expected_effect_table_covers_every_rig_fault() -> None:
    channels = {"valve_weak": "hot", "sensor_delay": "temperature", "sensor_bias": "height"}
    channels |= {"valve_stuck": "cold", "valve_saturation": "hot"}

    class F:
        def __init__(self, kind: str) -> None:
            self.kind, self.channel = kind, channels.get(kind, "")

    got = {k: expected_effect(F(k)) for k in FAULT_KINDS}
    assert got["leak"] == ("leak", "height")
    assert got["valve_weak"] == ("input_gain", "hot")
    assert got["sensor_delay"] == ("delay", "temperature")
    assert got["sensor_bias"] == ("offset", "height")
    assert got["mixing_delay"] == ("delay", "temperature")
    assert got["valve_stuck"] == ("stuck", "cold")
    with pytest.raises(Exception, match="no expected answer"):
        expected_effect(type("G", (), {"kind": "meteor", "channel": ""})())


def test_a_job_cancelled_at_shutdown_is_dropped_quietly() -> None:
    """A node that shuts down cancels the pending jobs: their callback records no failure and
    calls nothing (a cancelled future has no exception to ask for)."""
    from concurrent.futures import Future  # noqa: PLC0415

    seen = []
    dg = diagnoser()
    dg.on_result = seen.append
    future: Future = Future()
    assert future.cancel()
    dg._notify(future)
    assert seen == []
    assert dg.failures == []


# Closed loop (PI on level and temperature, excitation added to the valve commands): the
# loop hides the fault's move of the outputs in the inputs, so the fault shows in the
# deviation of the outputs from the nominal's response to the inputs. A sensor bias and a
# plant fault that move the same output are told apart by its time course.
CLOSED_ONSET_S = round(8.375 * PERIOD_S, 1)
CLOSED_CASES = ["leak=0.06", "sensor_bias:height=0.05", "sensor_bias:temperature=0.16"]


@pytest.mark.parametrize("spec", CLOSED_CASES)
def test_live_diagnosis_names_the_fault_in_closed_loop(spec) -> None:
    from twotank_validation.sim.control import CLOSED_LOOP_INPUT_PERIODIC_RTOL  # noqa: PLC0415
    from twotank_validation.sim.scenario import ClosedLoop  # noqa: PLC0415

    sc = Scenario(
        name="livediag-closed",
        duration_s=round(CLOSED_ONSET_S + 4 * WINDOW_S, 1),
        seed=0,
        faults=(f"{spec}@{CLOSED_ONSET_S}",),
        closed_loop=ClosedLoop(),
    )
    stamps, u, y = simulate_scenario(sc)
    config = MonitorConfig(input_periodic_rtol=CLOSED_LOOP_INPUT_PERIODIC_RTOL)
    v = OnlineValidator(config, [load_model("B")], diagnoser=diagnoser())
    reports = v.feed_many(*record_events(stamps, u, y))
    answers = [r.diagnosis for r in reports if r.diagnosis is not None]
    assert answers, f"{spec}: no diagnosis in closed loop"
    fault = parse_fault(f"{spec}@{CLOSED_ONSET_S}")
    last = answers[-1]
    assert named(last, fault), f"{spec}: named {last.kind} on {last.channel}: {last.summary}"
    assert abs(last.onset_ns / 1e9 - CLOSED_ONSET_S) <= PERIOD_S
    if spec in PARAMETERS:
        name, true, rtol = PARAMETERS[spec]
        assert last.parameters[name] == pytest.approx(true, rel=rtol), last


def test_mean_deviations_remove_the_response_to_the_input_means() -> None:
    """Output means = the nominal's response to input means that moved + a step of 0.03 on the
    level: the deviations are that step alone (the reference: the step injected), where the
    steady-state version also carries the response's settling."""
    import numpy as np  # noqa: PLC0415
    import scipy.linalg  # noqa: PLC0415

    from twotank_validation.diagnose.effects import Nominal  # noqa: PLC0415
    from twotank_validation.diagnose.live_jobs import mean_deviations  # noqa: PLC0415
    from twotank_validation.diagnose.steady import dc_gain  # noqa: PLC0415
    from twotank_validation.online.livediag import DiagnosisJob  # noqa: PLC0415

    doc, _ = load_model_document("B")
    nom = Nominal.from_document(doc)
    hop = PERIOD_S / 4
    t = np.arange(40) * hop
    # input means: a ramp of the hot valve over two hops from t = 10 hops (a loop's move)
    du = np.zeros((t.size, 2))
    du[:, 0] = 0.02 * np.clip((t - 10 * hop) / (2 * hop), 0.0, 1.0)
    # the nominal's response, by the matrix exponential on a fine grid (not lsim)
    fine = 64
    dt = hop / fine
    n = nom.a.shape[0]
    big = np.zeros((n + 2, n + 2))
    big[:n, :n], big[:n, n:] = nom.a * dt, nom.b * dt
    phi = scipy.linalg.expm(big)
    x = np.zeros(n)
    ys = [nom.c @ x + nom.d @ du[0]]
    for k in range(1, t.size):
        for j in range(fine):  # the input linear between the hops, held over each fine step
            uk = du[k - 1] + (du[k] - du[k - 1]) * (j + 0.5) / fine
            x = phi[:n, :n] @ x + phi[:n, n:] @ uk
        ys.append(nom.c @ x + nom.d @ du[k])
    y = np.array(ys)
    step = np.where(t >= 20 * hop, 0.03, 0.0)
    y[:, 0] += step
    job = DiagnosisJob(
        model="B", onset_ns=0, trigger_end_ns=0, pre=(), post=(),
        means_end_ns=np.round(t * 1e9).astype(np.int64),
        means_u=0.4 + du, means_y=np.array([0.47, 0.5]) + y,
        raised_by="operating point", ts_s=0.1, period_samples=2048, update=1,
    )  # fmt: skip
    got = mean_deviations(job, nom)
    assert np.max(np.abs(got[:, 0] - step)) < 1e-3
    assert np.max(np.abs(got[:, 1])) < 1e-3
    steady = y - du @ dc_gain(nom).T  # the steady-state version is off while the level settles
    assert np.max(np.abs(steady[:, 0] - step)) > 5e-3
