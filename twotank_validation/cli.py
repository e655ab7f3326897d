"""Command line ``twotank-validation``: parse, call the core, print; errors without traceback."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

from tqdm import tqdm

from twotank_validation.datum import NormConvention
from twotank_validation.errors import TwotankError
from twotank_validation.monitor import WindowReport


def _progress_factory(enabled: bool) -> Callable[[str, int], Callable[[int], None]] | None:
    if not enabled:
        return None

    def make(label: str, total: int) -> Callable[[int], None]:
        bar = tqdm(total=total, desc=label, unit="bin", leave=True, mininterval=0.5)

        def update(n: int) -> None:
            bar.update(n)
            if bar.n >= total:
                bar.close()

        return update

    return make


def _cmd_demo(args: argparse.Namespace) -> int:
    from twotank_validation import experiment, report  # noqa: PLC0415 (fast --help)

    cfg = experiment.ExperimentConfig(convention=NormConvention(args.norm))
    if args.seed is not None:
        cfg = replace(cfg, excitation=replace(cfg.excitation, seed=args.seed), seed=args.seed)
    steps = tqdm(total=3, desc="demo", unit="step", disable=args.quiet)
    steps.set_postfix_str("simulating rig and validating")
    res = experiment.run_experiment(
        cfg, sdp_check=not args.no_sdp, progress=_progress_factory(not args.quiet)
    )
    steps.update(1)
    steps.set_postfix_str("writing figures")
    numbers = report.write_report(res, Path(args.out))
    steps.update(2)
    steps.close()
    print(f"norm convention: {numbers['norm_convention']}")
    for name, m in numbers["models"].items():
        verdict = "INVALIDATED" if m["invalidated"] else "not invalidated"
        line = f"Model {name}: beta = {m['beta']:.3f} (paper {m['paper_beta']}) -> {verdict}"
        if "sdp_check" in m:
            line += f"; SDP agrees to {m['sdp_check']['beta_rel_diff']:.1e} relative"
        print(line)
    print(f"report written to {Path(args.out).resolve()}/summary.md")
    return 0


def _loopback_only() -> None:
    """DDS discovery on loopback only, in a domain of our own unless one was chosen."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", "77")


def _cmd_live(args: argparse.Namespace) -> int:
    _loopback_only()
    from twotank_validation.ros.live import LiveConfig, run_live  # noqa: PLC0415 (needs rclpy)

    cfg = LiveConfig(
        duration_s=args.duration,
        ts_s=args.ts,
        period_samples=args.period,
        models=tuple(args.model or ["A", "B"]),
        faults=tuple(args.fault or ()),
        seed=args.seed,
    )

    def show(rep: WindowReport) -> None:
        if args.json:
            print(json.dumps(report_dict(rep)), flush=True)
            return
        verdict = (
            f"beta {rep.beta:6.3f}  {'INVALIDATED' if rep.invalidated else 'valid      '}"
            if rep.judged
            else f"not judged: {rep.data_quality}"
        )
        print(
            f"[{rep.start_ns / 1e9:8.1f}, {rep.end_ns / 1e9:8.1f}] s  model {rep.model}: "
            f"{verdict}  alarm {rep.alarm.name}",
            flush=True,
        )

    result = run_live(cfg, on_report=show)
    print(
        f"simulated {cfg.duration_s:.0f} s in {result.wall_s:.1f} s wall "
        f"({cfg.duration_s / max(result.wall_s, 1e-9):.0f}x real time); "
        f"{len(result.reports)} reports; aligner: {result.counters}",
        file=sys.stderr,
    )
    return 0


def report_dict(rep: WindowReport) -> dict[str, object]:
    """JSON-friendly summary of a window report (spectrum left out)."""
    return {
        "model": rep.model,
        "start": rep.start_ns / 1e9,
        "end": rep.end_ns / 1e9,
        "judged": rep.judged,
        "beta": rep.beta if rep.judged else None,
        "invalidated": rep.invalidated,
        "alarm": rep.alarm.name,
        "reason": None if rep.judged else rep.data_quality,
    }


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (one sub-command per job)."""
    parser = argparse.ArgumentParser(
        prog="twotank-validation",
        description="Frequency-domain validation of robust-control models (Smith 1995).",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser(
        "demo", help="reproduce the paper's Model A / Model B experiment in simulation"
    )
    demo.add_argument("--out", default="report", help="report folder (default: ./report)")
    demo.add_argument("--norm", choices=[c.value for c in NormConvention], default="power")
    demo.add_argument("--seed", type=int, default=None, help="excitation and noise seed")
    demo.add_argument("--no-sdp", action="store_true", help="skip the general SDP cross-check")
    demo.add_argument("--quiet", action="store_true", help="no progress bars")
    demo.set_defaults(func=_cmd_demo)
    live = sub.add_parser(
        "live", help="plant, excitation and validator nodes in one process on a simulated clock"
    )
    live.add_argument(
        "--duration", type=float, default=3000.0, help="simulated seconds (default 3000)"
    )
    live.add_argument("--ts", type=float, default=0.1, help="sample period in s (default 0.1)")
    live.add_argument("--period", type=int, default=2048, help="excitation period in samples")
    live.add_argument(
        "--model", action="append", help="model name or YAML path (repeat; default A and B)"
    )
    live.add_argument("--fault", action="append", help="plant fault, e.g. leak=0.02@1000 (repeat)")
    live.add_argument("--seed", type=int, default=0, help="plant noise seed")
    live.add_argument("--json", action="store_true", help="one JSON object per report")
    live.set_defaults(func=_cmd_live)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``twotank-validation`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except TwotankError as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
