"""Fit and check the probability of the live diagnosis's answers (the isolation bench's data).

The live diagnosis names one effect behind an alarm with a *score* in [0, 1]
(:attr:`~twotank_validation.online.livediag.LiveDiagnosis.score`): its own ranking of how
clearly the effect stood out, whose meaning differs from one kind of answer to the next. The
probability an operator reads is that score mapped, per kind of answer, onto the frequency with
which answers of that kind and score named the injected fault on the isolation bench
(``bench/bench_isolation.py --calibrate``). This module fits that map from the bench's answer
records and measures its reliability on held-out cases; the package only loads the result
(:mod:`twotank_validation.diagnose.answer_probability`).

The map (per kind, a non-decreasing step function of the score):

1. the answers of the kind (``unexplained`` names no fault and gets no probability; nor does
   a kind with fewer than :data:`MIN_ANSWERS` answers on the bench, or none: its
   probability was not measured);
2. the answers binned by their score: bins of equal counts (score quantiles), at least
   :data:`MIN_BLOCK` answers each and at most :data:`MAX_BINS` bins, fixed before the
   outcomes are looked at (fitting the steps to the outcomes, as plain isotonic regression
   does, overfits the ends: its top step is the best run of right answers);
3. the bins' frequencies made non-decreasing in the score by isotonic regression weighted by
   their counts (``scipy.optimize.isotonic_regression``, the pool-adjacent-violators
   algorithm), which pools neighbouring bins into steps; each step's frequency ``k/n``
   shrunk to ``(k + 1/2) / (n + 1)`` (Jeffreys prior: 36 right answers out of 36 read 0.986,
   not a certainty), and isotonic again.

Reliability is measured by cross-validation over the bench's seeds: each answer's
probability comes from a map fitted on the other seeds' answers, then the answers are binned
by that probability (the reliability table: per bin the mean probability, the observed
frequency and its 95 % Wilson interval) and scored by the Brier score, against the raw score
read as a probability and against one constant (the overall frequency).
"""

from __future__ import annotations

import csv
import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.optimize
import scipy.stats

MIN_ANSWERS = 15
"""Kinds with fewer bench answers than this get no probability (not measured)."""

MIN_BLOCK = 30
"""Fewest answers in one bin of a kind's scores."""

MAX_BINS = 8
"""Most bins of one kind's scores."""

NO_PROBABILITY = "unexplained"
"""The answer that names no fault (no probability)."""

BIN_EDGES = (0.0, 0.5, 0.7, 0.8, 0.9, 0.95, 1.0)
"""Bins of the reliability table (probability)."""


@dataclass(frozen=True)
class Answer:
    """One answer of the bench.

    Attributes:
        kind: the answer's kind (``LiveDiagnosis.kind``).
        score: its score in [0, 1] (``LiveDiagnosis.score``).
        right: whether it named the injected fault (kind and channel).
        fold: the cross-validation fold (the run's noise seed).
    """

    kind: str
    score: float
    right: bool
    fold: int


def read_answers(path: str | Path) -> list[Answer]:
    """The answers of a bench CSV (columns ``kind``, ``score``, ``right``, ``seed``)."""
    with open(path, newline="") as f:
        return [
            Answer(r["kind"], float(r["score"]), r["right"] == "1", int(r["seed"]))
            for r in csv.DictReader(f)
        ]


def _step(scores: np.ndarray, right: np.ndarray) -> dict[str, Any]:
    """The step function of one group: ``{"score", "probability", "n", "right"}``.

    ``score`` (m,) are the steps' lowest scores (the first is 0), ``probability`` (m,) their
    probabilities, ``n`` and ``right`` the group's answer counts.
    """
    order = np.argsort(scores, kind="stable")
    s, r = scores[order], right[order].astype(float)
    n = len(s)
    # bins of at least MIN_BLOCK answers, cut at score quantiles (never between equal scores)
    m = max(1, min(MAX_BINS, n // MIN_BLOCK))
    cuts: list[int] = []
    for q in range(1, m):
        i = int(np.searchsorted(s, s[q * n // m], side="left"))
        if (not cuts or i - cuts[-1] >= MIN_BLOCK) and n - i >= MIN_BLOCK:
            cuts.append(i)
    start = np.array([0, *cuts])
    b_n = np.diff(np.append(start, n)).astype(float)
    b_k = np.add.reduceat(r, start)
    # isotonic over the bins, then each pooled step shrunk (Jeffreys), isotonic again (the
    # shrinking can break the order between steps of different size)
    fit = scipy.optimize.isotonic_regression(b_k / b_n, weights=b_n).x
    step = np.concatenate([[0], np.cumsum(np.diff(fit) != 0)])
    s_n = np.bincount(step, weights=b_n)
    s_k = np.bincount(step, weights=b_k)
    p = scipy.optimize.isotonic_regression((s_k + 0.5) / (s_n + 1.0), weights=s_n).x
    first = np.concatenate([[True], np.diff(step) != 0])
    lows = s[start[first]].astype(float)
    lows[0] = 0.0
    keep = np.concatenate([[True], np.diff(p) != 0])  # one step per distinct probability
    return {
        "score": [round(float(x), 6) for x in lows[keep]],
        "probability": [round(float(x), 6) for x in p[keep]],
        "n": int(n),
        "right": int(r.sum()),
    }


def fit_map(answers: Sequence[Answer]) -> dict[str, dict[str, Any]]:
    """The probability map of these answers: kind -> step function (module docstring)."""
    by_kind: dict[str, list[Answer]] = {}
    for a in answers:
        if a.kind != NO_PROBABILITY:
            by_kind.setdefault(a.kind, []).append(a)
    out = {
        kind: _step(
            np.array([a.score for a in group]), np.array([a.right for a in group], dtype=bool)
        )
        for kind, group in sorted(by_kind.items())
        if len(group) >= MIN_ANSWERS
    }
    if not out:
        raise ValueError(f"no kind of answer names a fault {MIN_ANSWERS} times: nothing to fit")
    return out


def lookup(table: Mapping[str, Mapping[str, Any]], kind: str, score: float) -> float | None:
    """The probability of an answer under a map (None: ``unexplained``, or not measured)."""
    step = table.get(kind)
    if step is None:
        return None
    lows = np.asarray(step["score"], dtype=float)
    i = max(int(np.searchsorted(lows, score, side="right")) - 1, 0)
    return float(step["probability"][i])


def held_out(answers: Sequence[Answer]) -> list[tuple[Answer, float]]:
    """Each answer with its probability from a map fitted on the other folds.

    Answers whose kind the other folds' map does not hold (no probability) are left out.
    """
    out: list[tuple[Answer, float]] = []
    for fold in sorted({a.fold for a in answers}):
        table = fit_map([a for a in answers if a.fold != fold])
        for a in answers:
            if a.fold == fold:
                p = lookup(table, a.kind, a.score)
                if p is not None:
                    out.append((a, p))
    return out


def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval of a frequency k/n."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(mid - half, 0.0), min(mid + half, 1.0))


def reliability(pairs: Iterable[tuple[Answer, float]]) -> list[dict[str, Any]]:
    """The reliability table: a row per non-empty probability bin (:data:`BIN_EDGES`).

    Each row ``{"bin", "n", "mean_probability", "observed", "low", "high"}``: the answers in
    the bin, their mean probability, the frequency of right ones and its 95 % Wilson interval.
    """
    items = list(pairs)
    rows = []
    for lo, hi in itertools.pairwise(BIN_EDGES):
        last = hi == BIN_EDGES[-1]
        inside = [(a, p) for a, p in items if lo <= p < hi or (last and p == hi)]
        if not inside:
            continue
        k = sum(a.right for a, _ in inside)
        n = len(inside)
        low, high = wilson(k, n)
        rows.append(
            {
                "bin": [lo, hi],
                "n": n,
                "mean_probability": round(float(np.mean([p for _, p in inside])), 4),
                "observed": round(k / n, 4),
                "low": round(low, 4),
                "high": round(high, 4),
            }
        )
    return rows


def brier(pairs: Iterable[tuple[Answer, float]]) -> float:
    """Mean squared difference between probability and outcome (0 right, 1 wrong)."""
    items = list(pairs)
    return float(np.mean([(p - float(a.right)) ** 2 for a, p in items]))


def scores(answers: Sequence[Answer]) -> dict[str, float]:
    """Held-out Brier score of the map, of the raw score, and of the overall frequency."""
    pairs = held_out(answers)
    named = [a for a, _ in pairs]
    base = float(np.mean([a.right for a in named]))
    return {
        "calibrated": round(brier(pairs), 4),
        "raw_score": round(brier((a, a.score) for a in named), 4),
        "constant": round(brier((a, base) for a in named), 4),
        "answers": len(named),
        "right": int(sum(a.right for a in named)),
    }


def binomial_p(k: int, n: int, p: float) -> float:
    """Two-sided exact binomial test p-value of k of n at probability p (tests)."""
    return float(scipy.stats.binomtest(k, n, p).pvalue)
