"""The probability of a live diagnosis's answer: the shipped map, its fit and its reliability.

References: the answers the isolation bench recorded (``bench/data/isolation_answers.csv``,
written by ``bench_isolation.py --calibrate`` with the map), counted here directly; a
synthetic bench whose true probability of a right answer is known (a closed form of the
score); and the 95 % Wilson interval of each observed frequency.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tools import answer_calibration as cal
from twotank_validation.diagnose.answer_probability import answer_probability, probability_map

Z99 = 2.5758  # two-sided 99 % normal quantile
ANSWERS = Path(__file__).resolve().parents[2] / "bench" / "data" / "isolation_answers.csv"


@pytest.fixture(scope="module")
def answers() -> list[cal.Answer]:
    return cal.read_answers(ANSWERS)


def test_the_shipped_map_is_the_fit_of_the_recorded_bench_answers(answers) -> None:
    pmap = probability_map()
    assert pmap.command.startswith("bash scripts/run bench bench_isolation.py")
    assert "--calibrate" in pmap.command
    assert pmap.date == "2026-11-27"
    assert cal.fit_map(answers) == pmap.document["kinds"]


def test_the_probability_is_non_decreasing_in_the_score_per_kind() -> None:
    pmap = probability_map()
    grid = np.linspace(0.0, 1.0, 201)
    for kind in pmap.kinds:
        p = [pmap.probability(kind, s) for s in grid]
        assert all(0.0 < x < 1.0 for x in p), kind  # shrunk: never a certainty
        assert np.all(np.diff(p) >= 0.0), kind
    assert answer_probability("unexplained", 0.9) is None  # names no fault
    assert answer_probability("lag", 0.9) is None  # never on the bench: not measured


def test_each_kind_matches_its_observed_frequency_on_the_bench(answers) -> None:
    """Per kind with its own entry: the answers' mean probability lies in the 95 % Wilson
    interval of the frequency of right answers, counted from the recorded answers."""
    pmap = probability_map()
    for kind, entry in pmap.document["kinds"].items():
        mine = [a for a in answers if a.kind == kind]
        assert len(mine) == entry["n"]
        k = sum(a.right for a in mine)
        assert k == entry["right"]
        low, high = cal.wilson(k, len(mine))
        mean_p = np.mean([pmap.probability(kind, a.score) for a in mine])
        assert low <= mean_p <= high, (kind, k, len(mine), mean_p)


def test_held_out_reliability_matches_the_observed_frequencies(answers) -> None:
    """Cross-validated over the bench's seeds (each answer's probability from the other
    seeds' answers): in every probability bin of 10 answers or more the mean probability
    lies in the 95 % Wilson interval of the observed frequency, and the Brier score beats
    the raw score read as a probability. The stored table is this one."""
    pmap = probability_map()
    pairs = cal.held_out(answers)
    table = cal.reliability(pairs)
    assert table == pmap.document["reliability"]
    for row in table:
        inside = [
            (a, p)
            for a, p in pairs
            if row["bin"][0] <= p < row["bin"][1] or (row["bin"][1] == 1.0 and p == 1.0)
        ]
        assert len(inside) == row["n"]
        k = sum(a.right for a, _ in inside)
        assert row["observed"] == pytest.approx(k / len(inside), abs=1e-4)
        if row["n"] >= 10:  # 99 % (several bins: a 95 % interval misses one in twenty)
            low, high = cal.wilson(k, len(inside), z=Z99)
            assert low <= row["mean_probability"] <= high, row
    brier = cal.scores(answers)
    assert brier == pmap.document["brier"]
    assert brier["calibrated"] < brier["raw_score"]
    assert brier["calibrated"] <= brier["constant"] + 0.01


def test_the_fit_recovers_a_known_probability() -> None:
    """A synthetic bench: answers of one kind right with probability 0.3 + 0.6 s (score s
    uniform); the fitted map (a step function over 8 bins of a linear truth) is within 0.1 of
    it, the held-out probabilities are within 0.04 of the truth on average, and the
    held-out Brier score is the true probability's within 0.01."""
    rng = np.random.default_rng(0)
    n = 3000
    s = rng.uniform(0.0, 1.0, n)
    right = rng.uniform(0.0, 1.0, n) < 0.3 + 0.6 * s
    synthetic = [
        cal.Answer("leak", float(x), bool(r), i % 3)
        for i, (x, r) in enumerate(zip(s, right, strict=True))
    ]
    table = cal.fit_map(synthetic)
    for x in np.linspace(0.1, 0.9, 9):
        p = cal.lookup(table, "leak", float(x))
        assert p == pytest.approx(0.3 + 0.6 * x, abs=0.1), x
    pairs = cal.held_out(synthetic)
    error = [abs(p - (0.3 + 0.6 * a.score)) for a, p in pairs]
    assert np.mean(error) < 0.04
    brier = cal.brier(pairs)
    truth = float(np.mean([(0.3 + 0.6 * a.score - a.right) ** 2 for a, _ in pairs]))
    assert brier == pytest.approx(truth, abs=0.01)  # as good as the true probability
