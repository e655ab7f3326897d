"""Time calibrating a one-hour recording against validating it once (issue: < 20 validations).

Usage: scripts/run bench bench_calibrate.py [--hours 1.0] [--model A] [--repeats 3] [--keep DIR]

Writes the nominal scenario (the rig with its mixing delay) for the given duration into a
temporary rosbag2 MCAP bag, then times, in the same run:

* one validation of the bag for the model: ``replay.replay_recording`` (what
  ``twotank-validation validate --model M --no-diagnosis`` runs: decoding, alignment and every
  window judged at the default hop of a quarter period);
* the calibration of every block of the model: ``calibrate_recording`` (what
  ``twotank-validation calibrate BAG --model M`` runs: the same replay to cut the judged,
  non-overlapping windows, then the uniform scaling per block and window, the per-bin
  requirement, the weight fits and the judgement of the calibrated model).

Prints the medians over the repeats and their ratio against the goal (20 validations).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
import time
from pathlib import Path

from twotank_validation import bags, replay
from twotank_validation.calibrate import calibrate_recording
from twotank_validation.core.model import load_model_document, model_from_dict
from twotank_validation.sim import scenario as sc

GOAL = 20.0  # calibration in validations' worth of time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--model", default="A")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--keep", help="write the bag here instead of a temporary folder")
    args = parser.parse_args()

    duration = round(args.hours * 3600 / 204.8) * 204.8  # whole periods
    scen = dataclasses.replace(sc.load_scenario("nominal"), duration_s=duration)
    doc, source = load_model_document(args.model)
    model = model_from_dict(doc, source)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.keep) if args.keep else Path(tmp) / "bag"
        if not out.exists():
            bags.write_scenario_bag(scen, out)
        print(f"bag: {duration:.0f} s of 10 Hz data in {out}")
        val_walls, cal_walls = [], []
        cal = None
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = replay.replay_recording(out, [model])
            val_walls.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            cal, _ = calibrate_recording(out, doc, source=source)
            cal_walls.append(time.perf_counter() - t0)
        assert cal is not None
        val, calib = statistics.median(val_walls), statistics.median(cal_walls)
        judged = sum(r.judged for r in res.reports)
        print(
            f"validation of model {model.name}: {len(res.reports)} windows ({judged} judged); "
            f"median {val:.3f} s over {args.repeats} runs: "
            f"{', '.join(f'{w:.3f}' for w in val_walls)} s"
        )
        print(
            f"calibration of every block ({', '.join(b.name for b in cal.blocks)}) on "
            f"{cal.window_starts_s.size} judged non-overlapping windows: median {calib:.3f} s: "
            f"{', '.join(f'{w:.3f}' for w in cal_walls)} s"
        )
        ratio = calib / val
        print(
            f"calibration = {ratio:.1f} validations; goal < {GOAL:g}: ratio {ratio / GOAL:.2f} "
            f"({'met' if ratio < GOAL else 'NOT met'})"
        )
        for b in cal.blocks:
            print(f"  {b.used_text()}")


if __name__ == "__main__":
    main()
