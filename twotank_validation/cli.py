"""Command line ``twotank-validation``: parse, call the core, print; errors without traceback."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

from tqdm import tqdm

from twotank_validation.datum import NormConvention
from twotank_validation.errors import TwotankError


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
