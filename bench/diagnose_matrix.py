"""How often the diagnosis names the right effect, and how well it recovers its parameters.

Usage: scripts/run bench diagnose_matrix.py [--seeds 10] [--rms 0.1,0.1] [--cutoff 0.01]
       [--windows 4] [--cases SUBSTRING ...]

For every case (an undeclared effect in the simulated rig, or none) and seed, simulates
`windows` windows of two periods after five periods of settling, runs `diagnose` and
prints, per case: the share of runs that added exactly the right effect(s) or findings
(offset, saturation; the negative control: nothing), the median and worst relative error of
each true parameter, the median beta before/after on the held-out windows, the median ratio
of the held-out RMS error (after / before) on the affected output, the runs reported
unexplained, the runs that named both a level offset and a leak (undecided: the data
could not tell them apart), and how often each parameter's 95 % interval covers the true
value. The true parameters come from the rig's physics: delay = the sensor delay; leak rate =
leak_per_level / A1 (a leak proportional to the level, inflows retuned); outflow = the rig's
constant extra outflow (the `leak` fault); heat-loss rate = q / (h0 A1); coupling = Model B's
level-to-temperature terms (k_inf = -t0/h0, k0 from the Jacobian).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np

from twotank_validation import experiment
from twotank_validation.core.model import load_model_document
from twotank_validation.diagnose import Window, diagnose
from twotank_validation.sim import rig
from twotank_validation.sim.faults import Fault

A1, H0, T0 = 91.4, 0.47, 0.5
ALPHA = 1.34  # the outlet law's slope: a constant extra outflow L lowers the level by ALPHA L
K_INF, K_DC = -T0 / H0, -0.4674  # Model B's level -> temperature coupling (see test_diagnose)


def sensor_delay(tau: float) -> Fault:
    return Fault("sensor_delay", 0.0, tau, "temperature")


CASES = [
    # name, model, rig extras, faults, truth {(kind, channel): {param: value}}
    ("delay 8 s", "B", {}, [sensor_delay(8.0)], {("delay", "temperature"): {"delay_s": 8.0}}),
    ("delay 25 s", "B", {}, [sensor_delay(25.0)], {("delay", "temperature"): {"delay_s": 25.0}}),
    ("heat loss 0.3", "B", {"heat_loss_coeff": 0.3}, [],
     {("heat_loss", "temperature"): {"rate_per_s": 0.3 / (H0 * A1)}}),
    ("heat loss 0.6", "B", {"heat_loss_coeff": 0.6}, [],
     {("heat_loss", "temperature"): {"rate_per_s": 0.6 / (H0 * A1)}}),
    ("leak 0.3", "B", {"leak_per_level": 0.3}, [], {("leak", "height"): {"rate_per_s": 0.3 / A1}}),
    ("leak 0.8", "B", {"leak_per_level": 0.8}, [], {("leak", "height"): {"rate_per_s": 0.8 / A1}}),
    ("A: coupling", "A", {}, [],
     {("coupling", "temperature"): {"hf_gain": K_INF, "dc_gain": K_DC}}),
    ("A: coupling + delay 12", "A", {}, [sensor_delay(12.0)],
     {("coupling", "temperature"): {"hf_gain": K_INF}, ("delay", "temperature"): {"delay_s": 12.0}}),
    ("leak 0.6 + delay 10", "B", {"leak_per_level": 0.6}, [sensor_delay(10.0)],
     {("leak", "height"): {"rate_per_s": 0.6 / A1}, ("delay", "temperature"): {"delay_s": 10.0}}),
    ("heat 0.6 + delay 15", "B", {"heat_loss_coeff": 0.6}, [sensor_delay(15.0)],
     {("heat_loss", "temperature"): {"rate_per_s": 0.6 / (H0 * A1)},
      ("delay", "temperature"): {"delay_s": 15.0}}),
    ("valve loss 15 % (hot)", "B", {}, [Fault("valve_weak", 0.0, 0.85, "hot")],
     {("input_gain", "hot"): {"gain_error": -0.15}}),
    ("hot supply -0.15", "B", {"hot_supply_temp": 0.85}, [],
     {("hot_supply", "hot"): {"delta_temperature": -0.15}}),
    ("level bias 0.05", "B", {}, [Fault("sensor_bias", 0.0, 0.05, "height")],
     {("offset", "height"): {"offset": 0.05}}),
    # the leak/offset pair, present from the first sample: a constant extra outflow of 0.04
    # lowers the level by ALPHA * 0.04 = 0.0536, as a level sensor reading 0.0536 low does
    ("leak 0.04 (outflow)", "B", {}, [Fault("leak", 0.0, 0.04)],
     {("leak", "height"): {"outflow": 0.04}}),
    ("level bias -0.0536", "B", {}, [Fault("sensor_bias", 0.0, -ALPHA * 0.04, "height")],
     {("offset", "height"): {"offset": -ALPHA * 0.04}}),
    ("leak 0.04 + delay 20", "B", {}, [Fault("leak", 0.0, 0.04), sensor_delay(20.0)],
     {("leak", "height"): {"outflow": 0.04}, ("delay", "temperature"): {"delay_s": 20.0}}),
    ("level bias -0.0536 + delay 20", "B", {},
     [Fault("sensor_bias", 0.0, -ALPHA * 0.04, "height"), sensor_delay(20.0)],
     {("offset", "height"): {"offset": -ALPHA * 0.04},
      ("delay", "temperature"): {"delay_s": 20.0}}),
    ("hot valve saturates 0.45", "B", {}, [Fault("valve_saturation", 0.0, 0.45, "hot")],
     {("saturation", "hot"): {"level": 0.45}}),
    ("none (B, clean rig)", "B", {}, [], {}),
]  # fmt: skip


def windows(  # noqa: PLR0917
    params: rig.RigParams, faults, seed: int, rms, n_windows: int, cutoff_hz: float
) -> list[Window]:
    cfg = experiment.ExperimentConfig(rig=params, seed=seed, faults=tuple(faults))
    exc = dataclasses.replace(cfg.excitation, seed=seed + 2, rms=rms, cutoff_hz=cutoff_hz)
    return experiment.diagnosis_windows(dataclasses.replace(cfg, excitation=exc), n_windows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--rms", default="0.1,0.1", help="excitation RMS hot,cold")
    parser.add_argument("--windows", type=int, default=4)
    parser.add_argument("--cutoff", type=float, default=0.01, help="excitation cutoff (Hz)")
    parser.add_argument("--cases", nargs="*", help="only cases whose name contains one of these")
    args = parser.parse_args()
    rms = tuple(float(x) for x in args.rms.split(","))
    noise = {"noise_std_height": 0.003, "noise_std_temperature": 0.01}
    print(
        f"{args.seeds} seeds per case, excitation RMS {rms}, cutoff {args.cutoff} Hz, "
        f"{args.windows} windows "
        "(half fit, half held out), sensor noise 0.003 / 0.01"
    )
    print(f"{'case':<30}{'right':>7}  {'parameter error: median / worst':<44}"
          f"{'beta before->after':>20}{'RMS after/before':>18}{'s/run':>7}"
          f"{'unexpl':>7}{'both':>5}   95 % interval covers the truth")  # fmt: skip
    for name, model, extra, faults, truth in CASES:
        if args.cases and not any(c in name for c in args.cases):
            continue
        doc, src = load_model_document(model)
        right, errs, b0, b1, ratio, secs = 0, {}, [], [], [], []
        unexplained, covered, both = 0, {}, 0
        for seed in range(args.seeds):
            params = rig.RigParams(**noise, **extra)
            ws = windows(params, faults, seed, rms, args.windows, args.cutoff)
            t0 = time.perf_counter()
            d = diagnose(ws, doc, source=src)
            secs.append(time.perf_counter() - t0)
            entries = [e.to_dict(d.outputs) for e in d.effects]
            got = {(e["kind"], e["channel"]): e["parameters"] for e in entries}
            got |= {(f.kind, f.target): dict(f.parameters) for f in d.findings}
            right += set(got) == set(truth)
            unexplained += d.unexplained
            both += d.level is not None and d.level.kind is None
            for key, params in truth.items():
                for p, v in params.items():
                    if key in got:
                        errs.setdefault(p, []).append(abs(got[key][p] / v - 1.0))
                ci = next(
                    (e.get("uncertainty", {}) for e in entries if (e["kind"], e["channel"]) == key),
                    {},
                )
                for p, v in params.items():
                    if p in ci and ci[p]["ci95"][0] is not None:
                        lo, hi = ci[p]["ci95"]
                        covered.setdefault(p, []).append(lo <= v <= hi)
            b0.append(d.before.beta)
            b1.append(d.after.beta)
            # the outputs the effect changes: a constant leak changes the temperature's
            # response (the tank holds less), not the level's
            chans = {
                "temperature" if "outflow" in p else k[1]
                for k, p in truth.items()
                if k[1] in d.outputs
            } or {"height", "temperature"}
            ratio.append(max(d.after.rms[c] / d.before.rms[c] for c in chans))
        perr = (
            "; ".join(f"{p} {statistics.median(v):.1%} / {max(v):.1%}" for p, v in errs.items())
            or "-"
        )
        cover = "; ".join(f"{p} {sum(v)}/{len(v)}" for p, v in covered.items()) or "-"
        print(
            f"{name:<30}{right:>4}/{args.seeds:<2}  {perr:<44}"
            f"{statistics.median(b0):>9.2f} -> {statistics.median(b1):.2f}"
            f"{statistics.median(ratio):>18.2f}{statistics.median(secs):>7.1f}"
            f"{unexplained:>6}{both:>5}   {cover}",
            flush=True,
        )


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
