"""The mode shift on the 1 x 3 test structure: named, its parameters, their intervals.

Usage: scripts/run bench mode_shift.py [--seeds 20] [--first 10] [--support 130]

For each seed, simulates the structure of ``test/data/models/mode_structure.yaml`` with its
support spring raised from 100 N/m to ``--support`` (built from the masses and springs,
:mod:`tools.mode_structure`; two windows of two periods after automatic settling), runs
``diagnose`` against the model file and prints: the runs that added exactly the mode shift of
mode 1, the runs flagged unexplained, how often the 95 % intervals of the new frequency and
damping ratio hold the physical structure's (its eigenvalues), the median and largest
error of each in standard errors, the intervals' median half-width, and the seconds per
diagnosis. Then two controls on the
same seeds: the nominal structure (nothing must be added) and the nominal with a +10 %
output gain on x2 (the gain must be named, no mode shift).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from tools.mode_structure import MODEL, SUPPORT, structure, windows
from twotank_validation.core.model import load_model_document
from twotank_validation.diagnose import diagnose
from twotank_validation.diagnose.effects import modes
from twotank_validation.diagnose.kinds import EffectKind


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first", type=int, default=10)
    parser.add_argument("--support", type=float, default=130.0)
    args = parser.parse_args()
    doc, source = load_model_document(str(MODEL))
    before, truth = modes(structure())[0], modes(structure(args.support))[0]
    print(
        f"mode 1: {before.f_hz:.5g} Hz, damping {before.zeta:.4g} -> true {truth.f_hz:.5g} Hz "
        f"({truth.f_hz / before.f_hz - 1:+.2%}), damping {truth.zeta:.4g}"
    )
    seeds = range(args.first, args.first + args.seeds)
    named = unexplained = cover_f = cover_z = 0
    z_f, z_z, secs, half_f, half_z = [], [], [], [], []
    for seed in seeds:
        w = windows(args.support, seed)
        t0 = time.perf_counter()
        d = diagnose(w, doc, source=source)
        secs.append(time.perf_counter() - t0)
        unexplained += d.unexplained
        kinds = [(e.spec.kind, e.spec.fixed.get("mode")) for e in d.effects]
        if kinds != [(EffectKind.MODE, 1.0)]:
            print(f"seed {seed}: {[e.spec.label(d.outputs) for e in d.effects]}")
            continue
        named += 1
        e = d.effects[0]
        assert e.uncertainty is not None
        lo, hi, se = e.uncertainty.low, e.uncertainty.high, e.uncertainty.stderr
        cover_f += bool(lo[0] <= truth.f_hz <= hi[0])
        cover_z += bool(lo[1] <= truth.zeta <= hi[1])
        half_f.append((hi[0] - lo[0]) / 2)
        half_z.append((hi[1] - lo[1]) / 2)
        z_f.append((e.values[0] - truth.f_hz) / se[0])
        z_z.append((e.values[1] - truth.zeta) / se[1])
    n = len(seeds)

    def spread(z: list[float]) -> str:
        a = np.abs(z)
        return f"{statistics.median(a):.2f} / {np.max(a):.2f}" if z else "-"

    print(
        f"stiffened: named {named}/{n}, unexplained {unexplained}/{n}; 95 % interval holds the "
        f"frequency {cover_f}/{named}, the damping {cover_z}/{named}; |error| in standard "
        f"errors, median / largest: frequency {spread(z_f)}, damping {spread(z_z)}; median "
        f"half-width of the interval: frequency {statistics.median(half_f or [np.nan]):.2g} Hz, "
        f"damping {statistics.median(half_z or [np.nan]):.2g}; "
        f"{statistics.median(secs):.2f} s per diagnosis"
    )
    quiet = gain = 0
    for seed in seeds:
        d = diagnose(windows(SUPPORT, seed), doc, source=source)
        quiet += not d.effects
        d = diagnose(windows(SUPPORT, seed, gain_x2=0.1), doc, source=source)
        gain += [(e.spec.kind, d.outputs[e.spec.channel]) for e in d.effects] == [
            (EffectKind.GAIN, "x2")
        ]
    print(f"nominal: nothing added {quiet}/{n}; +10 % gain on x2: the gain alone {gain}/{n}")


if __name__ == "__main__":
    main()
