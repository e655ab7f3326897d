"""A long periodic record of the 1 x 3 test plant, for the benches that time on it.

``test/data/models/one_by_three.yaml``'s nominal with its output gains off (the true plant's
``C`` rows scaled by 1.1, 0.9 and a changed flow row), driven by a multisine on 1498 lines of
an 8192-sample period at 0.01 s, ``n_periods`` periods from rest, sensor noise of 0.005.
Used by ``bench/bench_calibrate.py --case full-block`` and ``bench/bench_identify.py --case
1x3`` (the same record, so their figures refer to the same data).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import scipy.signal
import yaml

from twotank_validation.core import lti
from twotank_validation.core.model import model_from_dict

PERIOD = 8192
TS_S = 0.01


def model_document() -> dict[str, Any]:
    """The 1 x 3 test plant's model file, as loaded from YAML."""
    root = Path(__file__).resolve().parent.parent
    doc: dict[str, Any] = yaml.safe_load((root / "test/data/models/one_by_three.yaml").read_text())
    return doc


def record(n_periods: int = 10, input_noise: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``(u, y)``: (n_periods PERIOD, 1) and (n_periods PERIOD, 3) float, model units.

    ``input_noise``: RMS of noise on the input as recorded (the input's RMS is 1), so that
    every bin is driven, as with a measured input.
    """
    doc = model_document()
    rng = np.random.default_rng(0)
    lines = np.arange(2, 1500)
    phase = rng.uniform(0.0, 2 * np.pi, lines.size)
    k = np.arange(PERIOD)
    one = np.cos(2 * np.pi * np.outer(k, lines) / PERIOD + phase).sum(axis=1)
    u = np.tile(one / one.std(), n_periods)[:, None]
    true = copy.deepcopy(doc)
    true["nominal"]["ss"]["C"] = [[1.1, 0.0], [0.0, 0.9], [0.35, 0.6]]
    nominal = model_from_dict(true, "true").nominal
    assert nominal is not None  # a structured model: its nominal is stated
    sys = lti.discretise(nominal, TS_S)
    _, y, _ = scipy.signal.dlsim((sys.a, sys.b, sys.c, sys.d, TS_S), u)
    y = y + 0.005 * rng.standard_normal(y.shape)
    u = u + input_noise * rng.standard_normal(u.shape)
    return u, np.asarray(y)
