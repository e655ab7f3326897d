"""The live diagnosis of measured inputs (issue 28, item 2): its windows' datum is validate's.

The nominal rig's record, its inputs logged with noise at 1e-3 of their RMS and marked
measured in the interface map; Model A (invalidated on the rig by design) raises the alarm
and starts diagnosis jobs. Reference: each job window's β from its datum against the β the
validator reported for the same window (one datum: the input averaged over the periods).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tools.events import record_events
from tools.streamfuzz import clean_record
from twotank_validation.core.model import load_model
from twotank_validation.core.validate import validate_beta
from twotank_validation.diagnose.live_jobs import _windows
from twotank_validation.online import MonitorConfig, OnlineValidator
from twotank_validation.online.interface_map import InputKind
from twotank_validation.online.livediag import DiagnosisJob, LiveDiagnoser
from twotank_validation.online.streams import two_tank_map


def test_live_diagnosis_jobs_carry_the_measured_inputs() -> None:
    jobs: list[DiagnosisJob] = []

    def run(job: DiagnosisJob):
        jobs.append(job)
        raise RuntimeError("only the job is looked at")

    stamps, u, y = clean_record(8)
    rms = np.sqrt(np.mean((u - u.mean(0)) ** 2, axis=0))
    logged = u + np.random.default_rng(3).standard_normal(u.shape) * 1e-3 * rms
    imap = dataclasses.replace(two_tank_map(), input_kinds=(InputKind.MEASURED,) * 2)
    cfg = MonitorConfig(ts_s=0.8, period_samples=256, hop_samples=256)
    model = load_model("A")
    v = OnlineValidator(cfg, [model], interface=imap, diagnoser=LiveDiagnoser(run))
    reports = {r.end_ns: r for r in v.feed_many(*record_events(stamps, logged, y)) if r.judged}
    assert jobs
    for job in jobs:
        np.testing.assert_array_equal(job.measured, [True, True])
        for data, win in zip(job.post, _windows(job.post, job, 0), strict=True):
            datum = win.datum()
            assert np.all(datum.u_noise_std[datum.harmonic_bins][1:] > 0.0)  # averaged
            ref = reports[data.end_ns].beta
            assert validate_beta(datum, model).beta == pytest.approx(ref, rel=1e-9)
