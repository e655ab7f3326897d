"""What the validator memoises (discretised parts, P at the bins, the solver's route and gains)
never leaks between models or sample periods: every run equals a fresh validator's, bit for bit.

The reference of each run is the same monitor built from models loaded anew (empty memo) in a
process state with the discretisation memo cleared: what a fresh interpreter would compute.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest

from tools import streamfuzz
from twotank_validation.core import lti
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model, load_model_document, model_from_dict
from twotank_validation.core.validate import bin_response, validate, validate_beta
from twotank_validation.online import MonitorConfig
from twotank_validation.online.window import WindowReport, monitor_record

N_PERIODS = 6
CFG = MonitorConfig(ts_s=0.8, period_samples=256)


@pytest.fixture(scope="module")
def record():
    return streamfuzz.clean_record(N_PERIODS, 0)


def fields(rep: WindowReport) -> tuple:
    """Every field of a report but its compute time, floats by their bits."""
    out = []
    for f in dataclasses.fields(rep):
        if f.name == "compute_time_s":
            continue
        v = getattr(rep, f.name)
        if isinstance(v, np.ndarray):
            v = (v.dtype.str, v.shape, v.tobytes())
        elif isinstance(v, float):
            v = "nan" if math.isnan(v) else v.hex()
        out.append((f.name, v))
    return tuple(out)


def other_a():
    """Model A under its own name with other numbers: the height sensor's noise weight halved
    and the height perturbation weight's pole moved (another continuous part to discretise)."""
    doc, source = load_model_document("A")
    doc = copy.deepcopy(doc)
    for ch in doc["noise"]:
        ch["weight"] = {"gain": 0.5 * float(ch["weight"]["gain"])}
    doc["perturbations"][0]["weight"]["tf"]["den"] = [0.5, 1.0]
    return model_from_dict(doc, source)


def fresh(cfg, stamps, u, y, make_models):
    """The reference: a monitor of models loaded anew, the discretisation memo empty."""
    lti._hold.cache_clear()
    return [fields(r) for r in monitor_record(stamps, u, y, cfg, make_models())]


def test_two_models_and_two_sample_periods_in_one_process_equal_fresh_runs(record) -> None:
    stamps, u, y = record
    other_ts = dataclasses.replace(CFG, ts_s=0.4)
    stamps_half = stamps // 2  # the same samples on the 0.4 s grid
    models = [load_model("A"), load_model("B")]
    weak = [other_a()]
    runs = [  # interleaved, all on the same model objects and the process's memos
        (CFG, stamps, models),
        (other_ts, stamps_half, models),
        (CFG, stamps, weak),
        (other_ts, stamps_half, weak),
        (CFG, stamps, models),
    ]
    got = [[fields(r) for r in monitor_record(s, u, y, cfg, ms)] for cfg, s, ms in runs]
    want = [
        fresh(CFG, stamps, u, y, lambda: [load_model("A"), load_model("B")]),
        fresh(other_ts, stamps_half, u, y, lambda: [load_model("A"), load_model("B")]),
        fresh(CFG, stamps, u, y, lambda: [other_a()]),
        fresh(other_ts, stamps_half, u, y, lambda: [other_a()]),
    ]
    want.append(want[0])
    for g, w in zip(got, want, strict=True):
        assert any(dict(r)["judged"] for r in w)
        assert g == w
    # and the runs did differ: each model and sample period got its own numbers
    beta = {i: [dict(r)["beta"] for r in got[i]][-1] for i in range(4)}
    assert len(set(beta.values())) == 4


def test_validate_beta_is_validate_and_the_response_memo_is_per_object(record) -> None:
    _stamps, u, y = record
    model = load_model("B")
    n = CFG.window_samples
    resp = bin_response(model, n, CFG.ts_s)
    assert bin_response(model, n, CFG.ts_s) is resp
    assert bin_response(model, n, 0.4) is not resp
    assert bin_response(model, n // 2, CFG.ts_s) is not resp
    for start in (0, n, 2 * n):  # several windows on the one memoised response
        d = make_datum(
            u[start : start + n], y[start : start + n], ts_s=CFG.ts_s, period_samples=256
        )
        lean = validate_beta(d, model, response=resp)
        full = validate(d, load_model("B"))  # fresh model, response and memo
        assert lean.beta == full.beta
        assert lean.beta_upper == full.beta_upper
        np.testing.assert_array_equal(lean.w_min, full.w_min)
        assert lean.warnings == full.warnings
        assert lean.method == full.method
    assert resp.memo  # the route and the gains were kept on it
    copied = dataclasses.replace(resp, p=resp.p * 2.0)
    assert not copied.memo  # a changed response starts without them
