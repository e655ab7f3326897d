"""Time calibrating a one-hour recording against validating it once (issue: < 20 validations).

Usage: scripts/run bench bench_calibrate.py [--hours 1.0] [--model A] [--repeats 3] [--keep DIR]
       scripts/run bench bench_calibrate.py --case full-block [--repeats 3] [--before COMMIT]

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

``--case full-block``: a 1 x 3 plant (``test/data/models/one_by_three.yaml`` with one full
3 x 3 output-multiplicative block, weight 0.05 I, and its noise) on 4 windows of 16,384
samples (2 periods of 8192, a multisine on 1498 lines, the true plant's output gains off by
up to 10 %, sensor noise; ``--input-noise R`` adds noise of RMS R to the input as recorded, so that
every bin is driven, as with a measured input). Times, in the same run: validating the 4 windows (``validate``),
calibrating the block (``calibrate``), and the same calibration through the fast path's
previous bin classification (``--before COMMIT``'s ``core/fast/forms.py``, loaded from git),
where every bin with the block's weight at zero fell back to the per-bin SDP (run
``--before-repeats`` times, default 1: it takes minutes).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path
from unittest import mock

import numpy as np

from tools import one_by_three_record
from twotank_validation import bags, replay
from twotank_validation.calibrate import calibrate, calibrate_recording
from twotank_validation.core.datum import make_datum
from twotank_validation.core.fast import dispatch
from twotank_validation.core.model import load_model_document, model_from_dict
from twotank_validation.core.validate import validate
from twotank_validation.diagnose.inputs import Window
from twotank_validation.sim import scenario as sc

GOAL = 20.0  # calibration in validations' worth of time


def _full_block_case(input_noise: float = 0.0) -> tuple[dict, list[Window]]:
    """The 1 x 3 model with a full 3 x 3 block and 4 windows of 16,384 samples (module doc)."""
    doc = one_by_three_record.model_document()
    doc["perturbations"] = [
        {
            "name": "outputs_3x3",
            "kind": "output_multiplicative",
            "outputs": ["p_in", "p_out", "flow"],
            "weight": {"gain": 0.05},
        }
    ]
    period, ts = one_by_three_record.PERIOD, one_by_three_record.TS_S
    u, y = one_by_three_record.record(10, input_noise)
    n = 2 * period
    windows = [
        Window(u[(i + 1) * n : (i + 2) * n], y[(i + 1) * n : (i + 2) * n], ts, period,
               (i + 1) * n * ts)
        for i in range(4)
    ]  # fmt: skip
    return doc, windows


def _previous_classify(commit: str) -> object:
    """``core/fast/forms.py`` of ``commit`` (from git), as a module."""
    root = Path(__file__).resolve().parent.parent
    src = subprocess.run(
        ["git", "show", f"{commit}:twotank_validation/core/fast/forms.py"],
        cwd=root,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    module = types.ModuleType("forms_before")
    sys.modules[module.__name__] = module  # dataclasses look their module up
    exec(compile(src, f"{commit}:forms.py", "exec"), module.__dict__)
    return module


def full_block(args: argparse.Namespace) -> None:
    """The full 3 x 3 block case (module doc)."""
    doc, windows = _full_block_case(args.input_noise)
    model = model_from_dict(doc, "one_by_three_full")
    datums = [make_datum(w.u, w.y, ts_s=w.ts_s, period_samples=w.period_samples) for w in windows]
    [validate(d, model) for d in datums]  # load the compiled kernel first
    val_walls, cal_walls = [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        [validate(d, model) for d in datums]
        val_walls.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        cal = calibrate(windows, doc, blocks=["outputs_3x3"])
        cal_walls.append(time.perf_counter() - t0)
    before = _previous_classify(args.before)
    sdp_bins = [0]
    solve_sdp = dispatch.solvers.solve_sdp

    def counted(resp: object, u: np.ndarray, *a: object, **k: object) -> object:
        sdp_bins[0] += u.shape[0]
        return solve_sdp(resp, u, *a, **k)

    old_walls = []
    with (
        mock.patch.object(dispatch, "_classify", before._classify),  # type: ignore[attr-defined]
        mock.patch.object(dispatch.solvers, "solve_sdp", counted),
    ):
        for _ in range(args.before_repeats):
            t0 = time.perf_counter()
            old = calibrate(windows, doc, blocks=["outputs_3x3"])
            old_walls.append(time.perf_counter() - t0)
    val, calib = statistics.median(val_walls), statistics.median(cal_walls)
    old_t = statistics.median(old_walls)
    print(
        f"validation of the 4 windows (16,384 samples, 8193 bins each): median {val:.3f} s over "
        f"{args.repeats} runs: {', '.join(f'{w:.3f}' for w in val_walls)} s"
    )
    print(
        f"calibration of the full 3x3 block: median {calib:.3f} s: "
        f"{', '.join(f'{w:.3f}' for w in cal_walls)} s = {calib / val:.1f} validations "
        f"(goal < {GOAL:g}: {'met' if calib / val < GOAL else 'NOT met'})"
    )
    print(
        f"the same through the fast path's bin classification of {args.before}: median "
        f"{old_t:.1f} s over {args.before_repeats} run(s) = {old_t / val:.0f} validations; "
        f"{sdp_bins[0] // args.before_repeats} bins per run fell back to the per-bin SDP"
    )
    print(f"  now:    {cal.blocks[0].used_text()}")
    print(f"  before: {old.blocks[0].used_text()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=("rig", "full-block"), default="rig")
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--model", default="A")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--keep", help="write the bag here instead of a temporary folder")
    parser.add_argument("--before", default="3c53088", help="full-block: the commit compared")
    parser.add_argument("--before-repeats", type=int, default=1)
    parser.add_argument(
        "--input-noise",
        type=float,
        default=0.0,
        help="full-block: noise (RMS, the input's RMS is 1) on the input as measured",
    )
    args = parser.parse_args()
    if args.case == "full-block":
        full_block(args)
        return

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
