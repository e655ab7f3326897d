"""Time the validation of one 4096-sample window for Models A and B: closed form vs SDP.

Usage: scripts/run bench bench_window.py [--repeats-closed 50] [--repeats-sdp 3]

Prints the median wall time per window (both models together, P(e^{j theta}) evaluated once
beforehand, as the live validator does) for the exact closed form and the general SDP path
(cvxpy + Clarabel, one SDP per bin), and their ratio. Also checks that both give the same beta.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from twotank_validation import experiment
from twotank_validation.datum import make_datum
from twotank_validation.model import load_model
from twotank_validation.validate import validate


def timed(fn, repeats: int) -> tuple[float, list[float], object]:
    times = []
    out = None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), times, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats-closed", type=int, default=50)
    parser.add_argument("--repeats-sdp", type=int, default=3)
    args = parser.parse_args()

    cfg = experiment.ExperimentConfig()
    _, u, y, _ = experiment.simulate_datum(cfg)
    datum = make_datum(u, y, ts_s=cfg.excitation.ts_s, period_samples=cfg.excitation.period_samples)
    models = [load_model(n) for n in ("A", "B")]
    responses = [m.response(datum.theta, datum.ts_s) for m in models]
    print(
        f"window: N = {datum.n_samples} samples, {datum.theta.size} one-sided bins, models A and B"
    )

    def closed():
        return [validate(datum, m, response=r) for m, r in zip(models, responses, strict=True)]

    def sdp():
        return [
            validate(datum, m, response=r, method="sdp")
            for m, r in zip(models, responses, strict=True)
        ]

    closed()  # warm-up (imports, caches)
    t_cf, _, res_cf = timed(closed, args.repeats_closed)
    t_sdp, runs, res_sdp = timed(sdp, args.repeats_sdp)
    for a, b in zip(res_cf, res_sdp, strict=True):
        rel = abs(a.beta - b.beta) / a.beta
        print(
            f"  model {a.model_name}: beta closed form {a.beta:.9f}, "
            f"SDP [{b.beta:.9f}, {b.beta_upper:.9f}] (rel diff {rel:.1e})"
        )
    print(f"closed form: median {t_cf * 1e3:.3f} ms per window ({args.repeats_closed} runs)")
    all_runs = ", ".join(f"{t:.2f}" for t in runs)
    print(f"SDP (cvxpy/Clarabel, per bin): median {t_sdp:.2f} s per window (runs: {all_runs} s)")
    print(f"ratio SDP / closed form: {t_sdp / t_cf:,.0f}x")
    print(f"SDP per bin: {t_sdp / (2 * datum.theta.size) * 1e3:.2f} ms")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
