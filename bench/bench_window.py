"""Time the validation of one 4096-sample window for Models A and B: closed form, fast path, SDP.

Usage: scripts/run bench bench_window.py [--repeats-closed 50] [--repeats-fast 50]
                                         [--repeats-sdp 3]

Prints, in one run, the median wall time per window (both models together, P(e^{j theta})
evaluated once beforehand, as the live validator does) of

* the exact closed form (``validate``'s automatic choice for both tank models),
* the general batched fast path, forced (``method="fast"``: the Lagrangian dual of every bin
  solved together; it does not use the models' decoupled structure),
* the per-bin cvxpy SDP path (``method="sdp"``, one Clarabel SDP per bin: the reference),

their ratios, the goal checks (fast path at most 5 ms per window, at least 10,000 times
faster than the SDP path), the bins the fast path handed back to the per-bin SDP, and how
closely beta and the per-bin bounds agree between the three.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from twotank_validation import experiment, fast
from twotank_validation.datum import make_datum
from twotank_validation.model import load_model
from twotank_validation.validate import validate

GOAL_FAST_S = 5e-3
GOAL_RATIO = 10_000


def timed(fn, repeats: int) -> tuple[float, list[float], object]:
    times = []
    out = None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), times, out


def per_bin_rel(a: np.ndarray, b: np.ndarray) -> float:
    """Largest ``|a - b| / max(|b|, 1e-6 max|b|)`` over bins (relative, floored at round-off)."""
    fin = np.isfinite(b)
    floor = 1e-6 * float(np.max(np.abs(b[fin]))) if np.any(fin) else 0.0
    return float(np.max(np.abs(a[fin] - b[fin]) / np.maximum(np.abs(b[fin]), floor)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats-closed", type=int, default=50)
    parser.add_argument("--repeats-fast", type=int, default=50)
    parser.add_argument("--repeats-sdp", type=int, default=3)
    args = parser.parse_args()

    cfg = experiment.ExperimentConfig()
    _, u, y, _ = experiment.simulate_datum(cfg)
    datum = make_datum(u, y, ts_s=cfg.excitation.ts_s, period_samples=cfg.excitation.period_samples)
    models = [load_model(n) for n in ("A", "B")]
    responses = [m.response(datum.theta, datum.ts_s) for m in models]
    pairs = list(zip(models, responses, strict=True))
    print(
        f"window: N = {datum.n_samples} samples, {datum.theta.size} one-sided bins, models A and B"
    )

    def closed():
        return [validate(datum, m, response=r) for m, r in pairs]

    def fast_path():
        return [validate(datum, m, response=r, method="fast") for m, r in pairs]

    def fast_solver_only():
        return [fast.solve_fast(r, datum.u_bins, datum.y_bins) for _, r in pairs]

    def sdp():
        return [validate(datum, m, response=r, method="sdp") for m, r in pairs]

    closed()  # warm-up (imports, caches)
    fast_path()
    t_cf, _, res_cf = timed(closed, args.repeats_closed)
    t_fast, runs_fast, res_fast = timed(fast_path, args.repeats_fast)
    t_solver, _, _ = timed(fast_solver_only, args.repeats_fast)
    t_sdp, runs_sdp, res_sdp = timed(sdp, args.repeats_sdp)

    print("agreement (beta; per-bin lower and upper bounds, relative, floored at 1e-6 of max):")
    for cf, fa, sd in zip(res_cf, res_fast, res_sdp, strict=True):
        print(
            f"  model {cf.model_name}: beta closed form {cf.beta:.9f}, fast [{fa.beta:.9f}, "
            f"{fa.beta_upper:.9f}], SDP [{sd.beta:.9f}, {sd.beta_upper:.9f}]"
        )
        print(
            f"    fast vs SDP: beta rel diff {abs(fa.beta - sd.beta) / sd.beta:.1e}, per-bin "
            f"lower {per_bin_rel(fa.w_min, sd.w_min):.1e}, upper "
            f"{per_bin_rel(fa.w_upper, sd.w_upper):.1e}; fast vs closed form: beta rel diff "
            f"{abs(fa.beta - cf.beta) / cf.beta:.1e}, per-bin lower "
            f"{per_bin_rel(fa.w_min, cf.w_min):.1e}"
        )
        print(
            f"    fast path: {fa.fallback_bins} of {datum.theta.size} bins fell back to the "
            f"per-bin SDP; max gap {float(np.max(fa.solution.gap)):.1e}; "
            f"{fa.method_reason}"
        )
    runs = ", ".join(f"{t * 1e3:.2f}" for t in sorted(runs_fast)[:5])
    print(f"closed form: median {t_cf * 1e3:.3f} ms per window ({args.repeats_closed} runs)")
    print(
        f"fast path (method='fast'): median {t_fast * 1e3:.3f} ms per window "
        f"({args.repeats_fast} runs; fastest {runs} ms); solver alone "
        f"(fast.solve_fast, no validate() bookkeeping) {t_solver * 1e3:.3f} ms"
    )
    all_runs = ", ".join(f"{t:.2f}" for t in runs_sdp)
    print(f"SDP (cvxpy/Clarabel, per bin): median {t_sdp:.2f} s per window (runs: {all_runs} s)")
    print(f"SDP per bin: {t_sdp / (2 * datum.theta.size) * 1e3:.2f} ms")
    print(f"ratio SDP / fast path: {t_sdp / t_fast:,.0f}x")
    print(f"ratio SDP / closed form: {t_sdp / t_cf:,.0f}x")
    print(f"ratio fast path / closed form: {t_fast / t_cf:.2f}x")
    ok_time = t_fast <= GOAL_FAST_S
    ok_ratio = t_sdp / t_fast >= GOAL_RATIO
    print(
        f"goal: fast path <= {GOAL_FAST_S * 1e3:.0f} ms per window: "
        f"{'met' if ok_time else 'NOT met'} ({t_fast * 1e3:.3f} ms); "
        f">= {GOAL_RATIO:,}x faster than the SDP path: "
        f"{'met' if ok_ratio else 'NOT met'} ({t_sdp / t_fast:,.0f}x)"
    )


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
