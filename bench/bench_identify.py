"""Time identifying a recording against validating it once (issue: <= 10 validations' worth).

Usage: scripts/run bench bench_identify.py [--case rig|1x3] [--hours 1.0] [--repeats 3]

``--case rig``: the nominal scenario (the two-tank rig, 10 Hz, with its mixing delay) for
``--hours`` written to a temporary rosbag2 MCAP bag; timed in the same run:

* one validation of the bag for Model B: ``replay.replay_recording`` (what ``twotank-validation
  validate --model B --no-diagnosis`` runs: decoding, alignment, every window judged at the
  default hop);
* its identification: ``IdentifyJob.run`` (what ``twotank-validation identify BAG`` runs: the
  same replay to cut the windows, the response, the fits of orders 1..8, the noise weights
  and the perturbation weights calibrated on fit windows and judged on held-out ones).

``--case 1x3``: a 1 x 3 plant (``test/data/models/one_by_three.yaml``'s nominal with its output
gains off, sensor noise) on 8 periods of 8192 samples (a multisine on 1498 lines), as one
window; timed: one validation of it against ``one_by_three`` (``validate``), and its
identification (``identify_windows`` and ``identified_model``, orders 1..8).

Prints the medians over the repeats and their ratio against the goal.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
import time
from pathlib import Path

from tools import one_by_three_record
from twotank_validation import bags, replay
from twotank_validation.core.datum import make_datum
from twotank_validation.core.model import load_model, model_from_dict
from twotank_validation.core.validate import validate
from twotank_validation.diagnose.inputs import Window
from twotank_validation.identify.pipeline import (
    IdentifyConfig,
    identified_model,
    identify_windows,
)
from twotank_validation.sim import scenario as sc
from twotank_validation.usecases import IdentifyJob, ReadSettings

GOAL = 10.0  # identification in validations' worth of time


def _ratio_line(what: str, walls: list[float], val: float) -> str:
    med = statistics.median(walls)
    ratio = med / val
    return (
        f"{what}: median {med:.3f} s ({', '.join(f'{w:.3f}' for w in walls)} s) = "
        f"{ratio:.1f} validations; goal <= {GOAL:g}: {'met' if ratio <= GOAL else 'NOT met'}"
    )


def rig(args: argparse.Namespace) -> None:
    """The one-hour two-tank recording (module doc)."""
    duration = round(args.hours * 3600 / 204.8) * 204.8  # whole periods
    scen = dataclasses.replace(sc.load_scenario("nominal"), duration_s=duration)
    model = load_model("B")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bag"
        bags.write_scenario_bag(scen, out)
        print(f"bag: {duration:.0f} s of 10 Hz data")
        val_walls, id_walls = [], []
        outcome = None
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = replay.replay_recording(out, [model])
            val_walls.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            outcome = IdentifyJob(str(out), ReadSettings(), json_path=None).run()
            id_walls.append(time.perf_counter() - t0)
        val = statistics.median(val_walls)
        print(
            f"validation of Model B: {len(res.reports)} windows; median {val:.3f} s "
            f"({', '.join(f'{w:.3f}' for w in val_walls)} s)"
        )
        print(_ratio_line("identification", id_walls, val))
        assert outcome is not None
        for line in outcome.text:
            print(f"  {line}")


def one_by_three(args: argparse.Namespace) -> None:
    """The 8-period 1 x 3 record (module doc)."""
    doc = one_by_three_record.model_document()
    period, ts = one_by_three_record.PERIOD, one_by_three_record.TS_S
    u, y = one_by_three_record.record(10)
    keep = slice(2 * period, 10 * period)  # 8 periods after 2 of settling
    window = Window(u[keep], y[keep], ts, period)
    model = model_from_dict(doc, "one_by_three")
    datum = make_datum(window.u, window.y, ts_s=ts, period_samples=period)
    validate(datum, model)  # load the compiled kernel first
    val_walls, id_walls = [], []
    made = None
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        validate(datum, model)
        val_walls.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ident = identify_windows([window], IdentifyConfig(orders=range(1, 9)))
        made = identified_model(ident, [window], "identified", ["pump"], ["p_in", "p_out", "flow"])
        id_walls.append(time.perf_counter() - t0)
    val = statistics.median(val_walls)
    print(
        f"validation of the 8-period window (65,536 samples): median {val:.3f} s "
        f"({', '.join(f'{w:.3f}' for w in val_walls)} s)"
    )
    print(_ratio_line("identification", id_walls, val))
    assert made is not None
    print(
        f"  {ident.estimator.value}, {ident.response.freqs_hz.size} lines, order "
        f"{ident.fit.order}, 2V/dof {ident.fit.cost_ratio:.2f}; β on held-out "
        f"{float(made.beta[made.held_out].max()):.3f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=("rig", "1x3"), default="rig")
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if args.case == "1x3":
        one_by_three(args)
    else:
        rig(args)


if __name__ == "__main__":
    main()
