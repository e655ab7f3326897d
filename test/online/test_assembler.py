"""Inputs on separate topics assembled into commands, against a reference built by hand."""

from __future__ import annotations

import numpy as np
import pytest

from twotank_validation.errors import DatumError
from twotank_validation.online.assembler import CommandAssembler

TS_NS = 100_000_000


def feed(asm: CommandAssembler, events) -> list[tuple[int, list[float]]]:
    out = []
    for index, stamp, value in events:
        out += [(s, v.tolist()) for s, v in asm.push(index, stamp, value)]
    return out + [(s, v.tolist()) for s, v in asm.flush()]


def test_two_topics_in_step_give_one_command_per_instant() -> None:
    rng = np.random.default_rng(0)
    hot, cold = rng.random(50), rng.random(50)
    events = []
    for k in range(50):
        events += [(0, k * TS_NS + 3_000, hot[k]), (1, k * TS_NS + 7_000, cold[k])]
    got = feed(CommandAssembler(2, 0.1), events)
    assert got == [(k * TS_NS + 3_000, [hot[k], cold[k]]) for k in range(50)]


def test_loosely_interleaved_topics_and_a_lost_value() -> None:
    # cold of instant 1 arrives after hot of instant 2; cold of instant 3 is lost
    events = [
        (0, 0, 0.1), (1, 0, 0.5),
        (0, TS_NS, 0.2),
        (0, 2 * TS_NS, 0.3), (1, TS_NS + 5, 0.6), (1, 2 * TS_NS, 0.7),
        (0, 3 * TS_NS, 0.4),
        (0, 4 * TS_NS, 0.45), (1, 4 * TS_NS, 0.8),
        (0, 5 * TS_NS, 0.5), (1, 5 * TS_NS, 0.9),
    ]  # fmt: skip
    got = feed(CommandAssembler(2, 0.1), events)
    assert got == [
        (0, [0.1, 0.5]),
        (TS_NS, [0.2, 0.6]),
        (2 * TS_NS, [0.3, 0.7]),
        (3 * TS_NS, [0.4, 0.7]),  # cold held (lost message)
        (4 * TS_NS, [0.45, 0.8]),
        (5 * TS_NS, [0.5, 0.9]),
    ]


def test_an_input_never_seen_is_nan_and_late_values_are_dropped() -> None:
    asm = CommandAssembler(2, 0.1)
    out = feed(asm, [(0, 0, 0.1), (0, TS_NS, 0.2), (0, 2 * TS_NS, 0.3)])
    assert [s for s, _ in out] == [0, TS_NS, 2 * TS_NS]
    assert all(np.isnan(v[1]) for _, v in out)
    assert asm.push(1, 0, 0.5) == []  # instant 0 is gone


def test_a_single_input_passes_straight_through() -> None:
    asm = CommandAssembler(1, 0.1)
    assert [(s, v.tolist()) for s, v in asm.push(0, 5, 0.3)] == [(5, [0.3])]


def test_bad_arguments() -> None:
    with pytest.raises(DatumError, match="at least one input"):
        CommandAssembler(0, 0.1)
    with pytest.raises(DatumError, match="positive"):
        CommandAssembler(2, 0.0)
    with pytest.raises(DatumError, match="input index 2"):
        CommandAssembler(2, 0.1).push(2, 0, 1.0)
