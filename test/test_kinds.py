"""Fault kinds, effect kinds and window states as records and enums, not strings parsed back.

References: the string tables and prose parsers they replaced, kept here verbatim (the old
``FAULT_KINDS`` tuple, ``expected_effect`` table, ``raised_by`` function, the ``" and "``
split of ``raised_by``, and ``reason_category`` with ``_FLAG_KINDS``); the shipped scenarios
fed through the validator, whole and damaged (gaps, non-finite values, off-grid stamps,
non-finite commands), for the summary's ``not_judged_reasons``.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from tools.events import record_events
from twotank_validation import replay
from twotank_validation.core.model import load_model, load_model_document
from twotank_validation.diagnose import catalogue
from twotank_validation.diagnose.effects import Nominal
from twotank_validation.diagnose.kinds import (
    EFFECT_KINDS,
    EFFECT_RECORDS,
    REPORTED_KINDS,
    EffectFamily,
    EffectKind,
    ModelNeed,
    expected_effect,
)
from twotank_validation.online import COMMAND, MonitorConfig, OnlineValidator
from twotank_validation.online.livediag import UNEXPLAINED, DiagnosisJob
from twotank_validation.online.states import RaisedBy, SampleFlag, WindowQuality, WindowState
from twotank_validation.online.window import raised_by
from twotank_validation.sim.faults import (
    FAULT_KINDS,
    FAULT_RECORDS,
    Fault,
    FaultKind,
    format_fault,
    parse_fault,
)
from twotank_validation.sim.scenario import load_scenario, shipped_scenarios, simulate_scenario

OLD_FAULT_KINDS = (
    "leak",
    "sensor_bias",
    "valve_stuck",
    "valve_weak",
    "sensor_delay",
    "mixing_delay",
    "heat_loss",
    "valve_saturation",
    "hot_supply",
)
OLD_EFFECT_KINDS = (
    "delay",
    "lag",
    "gain",
    "input_gain",
    "coupling",
    "leak",
    "heat_loss",
    "hot_supply",
)


def old_expected_effect(kind: str, channel: str) -> tuple[str, str]:
    """The sim -> catalogue table as it stood in online/livediag.py."""
    table = {
        "leak": ("leak", "height"),
        "valve_weak": ("input_gain", channel),
        "sensor_delay": ("delay", channel),
        "sensor_bias": ("offset", channel),
        "heat_loss": ("heat_loss", "temperature"),
        "mixing_delay": ("delay", "temperature"),
        "valve_stuck": ("stuck", channel),
        "valve_saturation": ("saturation", channel),
        "hot_supply": ("hot_supply", "hot"),
    }
    return table[kind]


def old_raised_by(beta: float, beta_op: float, beta_total: float) -> str:
    if not beta_total > 1.0:
        return ""
    if beta > 1.0:
        return "dynamics" if not beta_op > 1.0 else "dynamics and operating point"
    if beta_op > 1.0:
        return "operating point"
    return "dynamics and operating point"


_OLD_FLAG_KINDS = (
    ("gap", "gap"),
    ("off the sample grid", "off grid"),
    ("non-finite valve", "no command"),
    ("no valid valve command", "no command"),
    ("non-finite", "non-finite"),
    ("implausible", "non-finite"),
)


def old_reason_category(quality: str) -> str:
    """replay.reason_category as it parsed the data_quality text."""
    if "unusable sample" in quality:
        first = quality.partition("first: ")[2]
        kind = next((k for key, k in _OLD_FLAG_KINDS if key in first), "flagged")
        return f"unusable samples ({kind})"
    return quality.partition(":")[0].strip()


def some_fault(kind: FaultKind) -> Fault:
    rec = kind.record
    rng = rec.magnitude
    magnitude = 0.0 if rng is None else (rng.high if not rng.low_inclusive else rng.low)
    return Fault(kind, 10.0, magnitude, rec.channels[0] if rec.channels else "")


# --- fault kinds ------------------------------------------------------------------------------


def test_every_fault_kind_has_a_complete_record_with_a_catalogue_counterpart() -> None:
    assert tuple(FAULT_RECORDS) == tuple(FaultKind)
    assert FAULT_KINDS == OLD_FAULT_KINDS
    assert all(type(k) is str for k in FAULT_KINDS)
    for kind, rec in FAULT_RECORDS.items():
        assert rec.kind is kind
        assert kind.record is rec
        assert str(kind) == kind.value == f"{kind}"
        optional = {"magnitude", "effect_channel"}  # None: ignored; the fault's own channel
        fields = dataclasses.fields(rec)
        assert all(getattr(rec, f.name) is not None for f in fields if f.name not in optional)
        # the magnitude: a range with its unit, or ignored (the stuck valve only)
        if rec.magnitude is None:
            assert kind is FaultKind.VALVE_STUCK
        else:
            assert rec.magnitude.low < rec.magnitude.high
            assert rec.magnitude.unit.strip()
        assert set(rec.channels) in ({"hot", "cold"}, {"height", "temperature"}, set())
        # the counterpart is an effect of the registry; a fault on a channel names its own
        effect = EffectKind(rec.effect)
        assert effect in EFFECT_RECORDS
        assert (rec.effect_channel is None) == bool(rec.channels)
        if rec.stuck:
            assert rec.channels == ("hot", "cold")
        if rec.thermal:
            assert rec.moves_operating_point
            assert EffectKind(rec.effect).record.thermal
        # the text form round-trips and keeps its grammar
        f = some_fault(kind)
        assert f.kind is kind
        assert parse_fault(format_fault(f)) == f
        assert format_fault(f).startswith(f"{kind.value}")


def test_fault_kind_properties_are_those_the_tuples_held() -> None:
    by = {
        prop: {k.value for k in FaultKind if getattr(k.record, prop)}
        for prop in ("moves_operating_point", "thermal", "stuck")
    }
    # test_livediag.MOVES_OPERATING_POINT: faults whose steady means move
    assert by["moves_operating_point"] == {
        "leak",
        "sensor_bias",
        "valve_weak",
        "heat_loss",
        "hot_supply",
    }
    assert by["thermal"] == {"heat_loss", "hot_supply"}
    assert by["stuck"] == {"valve_stuck", "valve_saturation"}


def test_a_fault_kind_given_as_text_becomes_the_enum_and_prints_as_before() -> None:
    f = Fault("leak", 1000.0, 0.02)
    assert f.kind is FaultKind.LEAK
    assert f == Fault(FaultKind.LEAK, 1000.0, 0.02)
    assert repr(f) == "Fault(kind='leak', onset_s=1000.0, magnitude=0.02, channel='', end_s=inf)"
    assert json.dumps({"kind": f.kind}) == '{"kind": "leak"}'
    assert parse_fault("valve_weak:cold=0.7@300-900").kind is FaultKind.VALVE_WEAK


def test_expected_effect_reads_the_records_as_the_old_table() -> None:
    for kind in FaultKind:
        channels = kind.record.channels or ("",)
        for channel in channels:
            rec = kind.record
            rng = rec.magnitude
            mag = 0.0 if rng is None else (rng.high if not rng.low_inclusive else rng.low)
            got = expected_effect(Fault(kind, 1.0, mag, channel))
            assert got == old_expected_effect(kind.value, channel)
            assert isinstance(got[0], EffectKind)


# --- effect kinds -----------------------------------------------------------------------------


def test_every_effect_kind_has_a_complete_record() -> None:
    assert tuple(EFFECT_RECORDS) == tuple(EffectKind)
    # the old tuple, then the kinds added since (each once, in the order they are tried)
    assert (*OLD_EFFECT_KINDS, "mode") == EFFECT_KINDS
    assert REPORTED_KINDS == ("offset", "saturation")
    assert EffectKind.UNEXPLAINED == UNEXPLAINED
    for kind, rec in EFFECT_RECORDS.items():
        assert rec.kind is kind
        assert kind.record is rec
        assert rec.text.strip()
        assert rec.label.strip()
        assert len(set(rec.parameters)) == len(rec.parameters)
        if rec.family is not EffectFamily.ANSWER:
            assert rec.parameters
    moves = {k.value for k in EffectKind if k.record.moves_operating_point}
    assert moves == {"leak", "heat_loss", "hot_supply"}  # diagnosis.MOVES_OPERATING_POINT was
    thermal = {k.value for k in EffectKind if k.record.thermal}
    assert thermal == {"heat_loss", "hot_supply"}  # live.THERMAL was
    assert {k for k in EffectKind if k.record.family is EffectFamily.ANSWER} == {
        EffectKind.STUCK,
        EffectKind.UNEXPLAINED,
    }


def test_the_catalogue_takes_names_and_needs_from_the_records() -> None:
    doc, _ = load_model_document("B")
    nom = Nominal.from_document(doc)
    outputs, inputs = ("height", "temperature"), ("hot", "cold")
    op = {"height": 1.0, "temperature": 0.5}
    specs, skipped = catalogue(nom, outputs, period_s=204.8, operating_point=op, inputs=inputs)
    assert not skipped
    # Model B has no complex pole pair: no mode to shift, and nothing to say about it
    assert {s.kind for s in specs} == set(EFFECT_KINDS) - {EffectKind.MODE}
    for s in specs:
        assert isinstance(s.kind, EffectKind)
        assert s.names == s.kind.record.parameters
        assert s.label(outputs)
    unnamed = dataclasses.replace(nom, states=("", ""))
    specs, skipped = catalogue(unnamed, outputs, period_s=204.8, operating_point=op, inputs=inputs)
    needing = [k for k in EFFECT_KINDS if ModelNeed.TANK_STATES in k.record.needs]
    assert [k for k, _ in skipped] == needing
    assert all(type(k) is str for k, _ in skipped)
    assert not {s.kind for s in specs} & set(needing)
    assert "no states named 'height' and 'energy'/'temperature'" in skipped[0][1]
    doc, _ = load_model_document(str(Path(__file__).parent / "data/models/mode_structure.yaml"))
    specs, skipped = catalogue(
        Nominal.from_document(doc), ("x1", "x2", "x3"), period_s=10.24, operating_point={}
    )
    modes = [s for s in specs if s.kind is EffectKind.MODE]
    assert len(modes) == 3  # a structure: one mode shift per lightly damped pair
    assert all(s.names == EffectKind.MODE.record.parameters for s in modes)
    assert [k for k, _ in skipped] == needing  # no tank states


# --- raised_by --------------------------------------------------------------------------------


def test_raised_by_text_equals_the_old_strings() -> None:
    assert [r.value for r in RaisedBy] == [
        "",
        "dynamics",
        "operating point",
        "dynamics and operating point",
    ]
    values = (math.nan, 0.0, 0.5, 0.9, 1.0, 1.2, 3.0, math.inf)
    for beta, beta_op in itertools.product(values, values):
        total = math.hypot(beta, beta_op) if math.isfinite(beta_op) else beta
        got = raised_by(beta, beta_op, total)
        assert isinstance(got, RaisedBy)
        assert got == old_raised_by(beta, beta_op, total)
        assert str(got) == old_raised_by(beta, beta_op, total)
        assert f"INVALIDATED by the {got}" == f"INVALIDATED by the {got.value}"
        assert json.dumps(got) == json.dumps(old_raised_by(beta, beta_op, total))
        assert bool(got) == bool(old_raised_by(beta, beta_op, total))


def test_raised_by_joined_as_the_old_split_and_join() -> None:
    for combo in itertools.chain.from_iterable(
        itertools.combinations(list(RaisedBy), n) for n in range(4)
    ):
        old: set[str] = set()
        for r in combo:
            if r.value:
                old.update(r.value.replace(" and ", ",").split(","))
        assert RaisedBy.of(combo) == " and ".join(sorted(old))
        assert RaisedBy.of(combo).operating_point == ("operating point" in " and ".join(old))
    job = DiagnosisJob(
        model="B", onset_ns=0, trigger_end_ns=1, pre=(), post=(),
        means_end_ns=np.zeros(0), means_u=np.zeros((0, 2)), means_y=np.zeros((0, 2)),
        raised_by="operating point", ts_s=0.1, period_samples=2048, update=1,
    )  # fmt: skip
    assert job.raised_by is RaisedBy.OPERATING_POINT


# --- window states ----------------------------------------------------------------------------

FAST = MonitorConfig(ts_s=0.8, period_samples=256)


def damaged_events(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A shipped scenario at a fast rate, its messages with gaps, NaNs and off-grid stamps."""
    base = load_scenario(name)
    s = dataclasses.replace(base, ts_s=0.8, period_samples=256)
    stamps, u, y = simulate_scenario(s)
    kinds, st, values = record_events(stamps, u, y)
    keep = np.ones(len(st), bool)
    n = len(stamps)
    rng = np.random.default_rng(sum(map(ord, name)))
    t = stamps[np.sort(rng.choice(np.arange(300, n - 10), 6, replace=False))]
    keep &= ~((st >= t[0]) & (st < t[0] + 5 * 800_000_000))  # a gap of every stream
    values = values.copy()
    values[(st == t[1]) & (kinds == 0), 0] = np.nan  # a non-finite height
    values[(st == t[2]) & (kinds == 1), 0] = 1e9  # an implausible temperature
    values[(st == t[3]) & (kinds == COMMAND), :] = np.nan  # a non-finite command
    st = st.copy()
    st[(st == t[4]) & (kinds == 1)] += 300_000_000  # a temperature off the sample grid
    keep &= ~((st >= t[5]) & (st < t[5] + 2 * 800_000_000) & (kinds == COMMAND))  # no command
    return kinds[keep], st[keep], values[keep]


@pytest.mark.parametrize(
    ("damaged", "recover"),
    [(False, True), (True, True), (True, False)],
    ids=["whole", "damaged", "damaged-no-recovery"],
)
def test_summary_categories_from_the_typed_reasons_equal_the_prose_parsed_ones(
    damaged: bool, recover: bool
) -> None:
    models = [load_model("A"), load_model("B")] if not damaged else [load_model("B")]
    config = FAST if recover else dataclasses.replace(FAST, max_recovered_fraction=0.0)
    seen: set[str] = set()
    states: set[WindowState] = set()
    for name in shipped_scenarios():
        if damaged:
            events = damaged_events(name)
        else:
            s = load_scenario(name)
            s = dataclasses.replace(s, ts_s=0.8, period_samples=256)
            events = record_events(*simulate_scenario(s))
        reports = OnlineValidator(config, models).feed_many(*events)
        assert reports
        for rep in reports:
            assert isinstance(rep.quality, WindowQuality)
            states.add(rep.quality.state)
            assert rep.quality.state.judged == rep.judged
            assert rep.data_quality.startswith("ok") == rep.judged
            if rep.judged:
                want = WindowState.RECOVERED if "recovered" in rep.data_quality else WindowState.OK
                assert rep.quality.state is want
                continue
            assert replay.reason_category(rep.quality) == old_reason_category(rep.data_quality)
            assert rep.data_quality.startswith(rep.quality.state.value) or (
                rep.quality.state is WindowState.UNUSABLE_SAMPLES
            )
            seen.add(rep.quality.category)
        result = replay.ReplayResult(Path(name), reports=reports)
        summary = replay.summary_json(result)
        for entry in summary["models"].values():
            old: dict[str, int] = {}
            for w in entry["windows"]:
                if w["reason"] is not None:
                    why = old_reason_category(w["reason"])
                    old[why] = old.get(why, 0) + 1
            assert entry["not_judged_reasons"] == old
            assert all(type(w["raised_by"]) is str for w in entry["windows"])
    assert "settling" in seen
    if damaged and recover:  # the damage recovered from the other periods
        assert WindowState.RECOVERED in states
    if damaged and not recover:  # the damage reached the summary as the kind of sample it is
        assert {"unusable samples (gap)", "unusable samples (non-finite)"} <= seen


def test_sample_flag_kinds_are_the_old_flag_words() -> None:
    flags = [
        "gap: no height sample at t = 1.000 s",
        "temperature stamp 5 ns is off the sample grid by 3 ns",
        "non-finite valve command",
        "no valid valve command yet",
        "non-finite height (nan)",
        "implausible temperature (1e9)",
        "non-finite or implausible value",
        "something else",
        None,
    ]
    for flag in flags:
        text = f"3 unusable sample(s) in the window or its settling periods; first: {flag}"
        if flag is None:
            text = "3 unusable sample(s) in the window or its settling periods"
        quality = WindowQuality(WindowState.UNUSABLE_SAMPLES, SampleFlag.of(flag))
        assert quality.category == old_reason_category(text)
