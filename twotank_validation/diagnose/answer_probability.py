"""The probability that a live diagnosis's answer names the fault behind the alarm.

The live diagnosis ranks its answer with a *score* in [0, 1] whose meaning differs from one
kind of answer to the next (an explained fraction, a contrast of direction matches, ...). The
probability is that score mapped, per kind of answer, onto the frequency with which answers
of the kind and score named the injected fault on the isolation bench: a non-decreasing step
function of the score per kind (a kind the bench produced fewer than 15 times has none: its
probability was not measured). The map
is data (``answer_probability.json`` beside this module), fitted by
``bash scripts/run bench bench_isolation.py --calibrate`` (``tools/answer_calibration.py``),
which also records how reliable it was on held-out seeds (docs/diagnosis.md, "The probability
of an answer").
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np

__all__ = ["ProbabilityMap", "answer_probability", "probability_map"]

_FILE = "answer_probability.json"


@dataclass(frozen=True)
class ProbabilityMap:
    """The stored map and where it came from.

    Attributes:
        kinds: kind -> ``(lows, probabilities)``: the step function's score thresholds (m,)
            (the first is 0) and the probability from each threshold on (m,).
        command: the command that fitted it.
        date: when.
        document: the whole stored document (its ``brier`` and ``reliability`` entries).
    """

    kinds: dict[str, tuple[np.ndarray, np.ndarray]]
    command: str
    date: str
    document: dict[str, Any]

    def probability(self, kind: str, score: float) -> float | None:
        """The probability of an answer of this kind and score.

        None for ``unexplained`` (it names no fault) and for a kind without an entry (not
        measured: the bench produced it too rarely or never).
        """
        if kind not in self.kinds:
            return None
        lows, probs = self.kinds[kind]
        i = max(int(np.searchsorted(lows, score, side="right")) - 1, 0)
        return float(probs[i])


@functools.cache
def probability_map() -> ProbabilityMap:
    """The map shipped with the package (read once)."""
    text = resources.files(__package__).joinpath(_FILE).read_text()
    doc = json.loads(text)
    kinds = {
        k: (np.asarray(v["score"], dtype=float), np.asarray(v["probability"], dtype=float))
        for k, v in doc["kinds"].items()
    }
    return ProbabilityMap(kinds, str(doc["command"]), str(doc["date"]), doc)


def answer_probability(kind: str, score: float) -> float | None:
    """The probability that an answer of this kind and score names the fault.

    None for ``unexplained``, for a kind the bench did not measure, and where the package
    ships no map (a checkout in which
    ``bench_isolation.py --calibrate`` has not run yet; ``test_answer_probability.py`` checks
    the installed package has one).
    """
    try:
        pmap = probability_map()
    except FileNotFoundError:
        return None
    return pmap.probability(kind, score)
