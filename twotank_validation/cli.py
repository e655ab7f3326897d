"""Command line ``twotank-validation``: parse, call the core, print; errors without traceback."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

from twotank_validation.cli_common import Interrupts, LiveOutput, live_end, report_dict
from twotank_validation.cli_common import loopback_only as _loopback_only
from twotank_validation.cli_common import out as _out
from twotank_validation.cli_models import add_live_model_options, add_simulate_model_options
from twotank_validation.cli_options import (
    absolute,
    add_calibrate_arguments,
    add_diagnose_arguments,
    add_recording_options,
    add_validate_arguments,
    check_fleet_options,
    option_dest,
    read_settings,
    replay_config,
    topic_map,
)
from twotank_validation.core.datum import NormConvention
from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.errors import ExitCode, TwotankError, UsageError

if TYPE_CHECKING:
    from twotank_validation.usecases import (
        DiagnoseJob,
        Message,
        Outcome,
        ValidateJob,
    )

__all__ = ["EXIT_CODES", "UsageError", "build_parser", "main", "option_dest", "report_dict"]

_replay_config = replay_config  # the replay settings of parsed bag options (kept for tests)
EXIT_OK = ExitCode.OK
EXIT_ERROR = ExitCode.ERROR
EXIT_INCOMPLETE = ExitCode.INCOMPLETE
EXIT_NOT_JUDGED = ExitCode.NOT_JUDGED

EXIT_CODES = f"""exit codes: {EXIT_OK} done; {EXIT_ERROR} bad arguments or unusable input \
(ERROR: says what to change); {EXIT_INCOMPLETE} the recording was not read completely \
(WARNING: says what was missing; windows judged before it are kept); {EXIT_NOT_JUDGED} \
read completely, but no window of a model could be judged (ERROR: says why and the likely \
fix)."""


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
    steps = tqdm(total=4, desc="demo", unit="step", disable=args.quiet)
    steps.set_postfix_str("simulating rig and validating")
    res = experiment.run_experiment(
        cfg, sdp_check=not args.no_sdp, progress=_progress_factory(not args.quiet)
    )
    steps.update(1)
    steps.set_postfix_str("diagnosing Model B")
    diag = experiment.run_diagnosis(cfg, "B")
    steps.update(1)
    steps.set_postfix_str("writing figures")
    numbers = report.write_report(res, Path(args.out), diag)
    steps.update(2)
    steps.close()
    print(f"norm convention: {numbers['norm_convention']}")
    for name, m in numbers["models"].items():
        verdict = "INVALIDATED" if m["invalidated"] else "not invalidated"
        line = f"Model {name}: beta = {m['beta']:.3f} (paper {m['paper_beta']}) -> {verdict}"
        if "sdp_check" in m:
            line += f"; SDP agrees to {m['sdp_check']['beta_rel_diff']:.1e} relative"
        print(line)
    print(f"diagnosis: {diag.summary}")
    print(f"report written to {Path(args.out).resolve()}/summary.md")
    return 0


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
        closed_loop=args.closed_loop,
        controller={"excitation_entry": args.excitation_entry} if args.closed_loop else {},
        supervisor=args.supervisor is not None,
        supervisor_params={"models": args.supervisor} if args.supervisor else {},
        record_samples=False,
        keep_reports=False,
        node_info_log=False,  # the answers are printed on stdout, in simulated time
    )
    if cfg.supervisor and not cfg.closed_loop:
        print(
            "error: --supervisor switches the controller's mode: add --closed-loop",
            file=sys.stderr,
        )
        return 2
    output = LiveOutput(args.json)
    with Interrupts() as interrupts:
        result = run_live(cfg, on_report=output.report, stop=interrupts)
    for tr in result.transitions:
        if args.json:
            entry = {
                "time": tr.time_s,
                "from": tr.from_mode.value,
                "to": tr.to_mode.value,
                "reason": tr.reason,
            }
            _out(json.dumps({"transition": entry}))
        else:
            _out(
                f"[{tr.time_s:8.1f} s] supervisor: {tr.from_mode.value} -> {tr.to_mode.value}: "
                f"{tr.reason}"
            )
    return live_end(output, result, result.steps * cfg.ts_s, interrupts)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from twotank_validation.bags.scenario_bag import simulate_command  # noqa: PLC0415

    path = simulate_command(args.scenario, args.out, args.storage)
    print(f"wrote {path}")
    return 0


def _validate_job(args: argparse.Namespace, *, fleet: bool = False) -> ValidateJob:
    """The ``validate`` job of the arguments (``fleet``: files absolute, nothing written)."""
    from twotank_validation.usecases import ValidateJob  # noqa: PLC0415

    return ValidateJob(
        args.bags[0],
        read_settings(args, fleet=fleet),
        tuple(absolute(m, fleet) for m in args.model or ValidateJob.models),
        diagnosis=not args.no_diagnosis,
        json_path=args.json,
        report_dir=args.report,
    )


def _say(message: Message) -> None:
    print(message, file=sys.stderr)


def _show(outcome: Outcome) -> int:
    """Print an outcome's text (stdout) and closing lines (stderr); its exit code."""
    for line in outcome.text:
        _out(line)
    for message in outcome.closing:
        print(message, file=sys.stderr)
    return int(outcome.code)


def _cmd_validate(args: argparse.Namespace) -> int:
    if not _single_recording(args):
        check_fleet_options(args)
        return _cmd_fleet(args, _validate_job(args, fleet=True))
    bar: tqdm[Any] | None = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if bar is None and not args.quiet:
            bar = tqdm(total=0, desc="replay", unit="msg", mininterval=0.5, disable=None)
        if bar is not None:
            bar.total = max(total, done)
            bar.n = done
            bar.refresh()

    outcome = _validate_job(args).run(say=_say, progress=progress)
    if bar is not None:
        bar.close()
    return _show(outcome)


def _diagnose_job(args: argparse.Namespace, *, fleet: bool = False) -> DiagnoseJob:
    """The ``diagnose`` job of the arguments (``fleet``: files absolute, nothing written)."""
    from twotank_validation.usecases import DiagnoseJob  # noqa: PLC0415

    return DiagnoseJob(
        args.bags[0],
        absolute(args.model, fleet),
        read_settings(args, fleet=fleet),
        max_effects=args.max_effects,
        start=args.start,
        end=args.end,
        segment=args.segment,
        json_path=args.json,
        report_dir=args.report,
        out_model=args.out_model,
    )


def _cmd_diagnose(args: argparse.Namespace) -> int:
    if not _single_recording(args):
        check_fleet_options(args)
        return _cmd_fleet(args, _diagnose_job(args, fleet=True))
    return _show(_diagnose_job(args).run(say=_say))


def _cmd_calibrate(args: argparse.Namespace) -> int:
    """``calibrate``: the smallest uncertainty the recording demands, and a fitted model."""
    from twotank_validation.usecases import CalibrateJob  # noqa: PLC0415

    job = CalibrateJob(
        args.bag,
        args.model,
        read_settings(args),
        blocks=tuple(args.block) if args.block else None,
        margin=args.margin,
        max_order=args.max_order,
        json_path=args.json,
        report_dir=args.report,
        out_model=args.out_model,
    )
    return _show(job.run(say=_say))


# --------------------------------------------------------------------------- many recordings


def _single_recording(args: argparse.Namespace) -> bool:
    """One recording named directly and no ``--out``: the single-recording command.

    Several paths, a directory of recordings, a glob or ``--out`` make a fleet run
    (:func:`_cmd_fleet`).
    """
    from twotank_validation import fleet  # noqa: PLC0415

    return args.out is None and fleet.is_single(args.bags)


def _cmd_fleet(args: argparse.Namespace, job: ValidateJob | DiagnoseJob) -> int:
    """``validate``/``diagnose`` of several recordings: one task each, then the summary."""
    from twotank_validation import fleet  # noqa: PLC0415

    # bad models and maps, and models whose channels the map does not carry, fail here,
    # before any task
    names = job.model_names(check_channels=True)
    expansion = fleet.expand_paths(args.bags)
    paths = [os.path.abspath(p) for p in expansion.recordings]
    expansion = fleet.Expansion(tuple(paths), expansion.skipped)
    settings = None
    if args.scheduler or not (args.serial or args.workers == 0):
        settings = fleet.DaskSettings(workers=args.workers or 0, scheduler=args.scheduler)
    where = (
        "in this process"
        if settings is None
        else f"on {args.scheduler}"
        if args.scheduler
        else f"on a local cluster of {settings.workers or os.cpu_count()} worker(s)"
    )
    print(f"{len(paths)} recording(s) {where}", file=sys.stderr)
    bar = tqdm(total=len(paths), desc=args.command, unit="recording", disable=args.quiet or None)

    def arrived(outcome: fleet.RecordingOutcome) -> None:
        bar.update(1)
        bar.set_postfix_str(f"{Path(outcome.path).name}: {outcome.status}", refresh=False)

    try:
        res = fleet.run_fleet(
            job, expansion, Path(args.out), names, dask=settings, progress=arrived
        )
    finally:
        bar.close()
    for line in res.said():
        print(line, file=sys.stderr)
    for line in res.text(Path(args.out)):
        _out(line)
    return res.code


def _model_names(args: argparse.Namespace) -> list[str]:
    """The names of the models of ``validate --model`` (loading them: bad ones fail here)."""
    return _validate_job(args).model_names()


def _cmd_record(args: argparse.Namespace) -> int:
    _loopback_only()
    from twotank_validation.ros.record import record  # noqa: PLC0415 (needs rclpy)

    counts = record(
        args.out, duration_s=args.duration, storage=args.storage, topics=topic_map(args.topic)
    )
    print(f"wrote {args.out}: " + ", ".join(f"{t} {n}" for t, n in counts.items()))
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (one sub-command per job)."""
    parser = argparse.ArgumentParser(
        prog="twotank-validation",
        description="Frequency-domain validation of robust-control models (Smith 1995).",
        epilog=EXIT_CODES,
    )
    sub = parser.add_subparsers(dest="command", required=True)

    def command(name: str, help_: str) -> argparse.ArgumentParser:
        # every option's help shows its default; every command's help ends with the exit codes
        return sub.add_parser(
            name,
            help=help_,
            formatter_class=argparse.ArgumentDefaultsHelpFormatter,
            epilog=EXIT_CODES,
        )

    demo = command("demo", "reproduce the paper's Model A / Model B experiment in simulation")
    demo.add_argument("--out", default="report", help="report folder")
    demo.add_argument(
        "--norm", choices=[c.value for c in NormConvention], default="power", help="norm of w"
    )
    demo.add_argument(
        "--seed", type=int, default=None, help="excitation and noise seed (default: the paper's)"
    )
    demo.add_argument("--no-sdp", action="store_true", help="skip the general SDP cross-check")
    demo.add_argument("--quiet", action="store_true", help="no progress bars")
    demo.set_defaults(func=_cmd_demo)
    live = command(
        "live", "plant, excitation and validator nodes in one process on a simulated clock"
    )
    live.add_argument("--duration", type=float, default=3000.0, help="simulated seconds")
    live.add_argument("--ts", type=float, default=TS_S, help="sample period (s)")
    live.add_argument(
        "--period", type=int, default=PERIOD_SAMPLES, help="excitation period (samples)"
    )
    live.add_argument(
        "--model", action="append", help="model name or YAML path (repeat; default A and B)"
    )
    live.add_argument("--fault", action="append", help="plant fault, e.g. leak=0.02@1000 (repeat)")
    live.add_argument("--seed", type=int, default=0, help="plant noise seed")
    live.add_argument("--json", action="store_true", help="one JSON object per report")
    live.add_argument(
        "--closed-loop",
        action="store_true",
        help="PI controller on level and temperature drives the valves (excitation added)",
    )
    live.add_argument(
        "--excitation-entry",
        choices=["output", "setpoint"],
        default="output",
        help="closed loop: excitation added to the valve commands or to the setpoints",
    )
    live.add_argument(
        "--supervisor",
        nargs="*",
        metavar="MODEL",
        help="closed loop: run the supervisor, which switches the controller to its safe mode "
        "while these models' alarm is ERROR (default: the supervisor's own, B); its "
        "transitions are printed at the end",
    )
    add_live_model_options(live, _cmd_live)

    sim = command(
        "simulate",
        "simulate a scenario of the rig into a rosbag2 bag, or any model (--model) into a bag "
        "or a CSV table with its interface map",
    )
    sim.add_argument("--scenario", help="scenario YAML file or shipped name (e.g. nominal, leak)")
    sim.add_argument("--out", required=True, help="bag to write (must not exist)")
    sim.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap", help="bag storage")
    add_simulate_model_options(sim, _cmd_simulate)

    rec = command("record", "record the interface topics of a live system into a bag")
    rec.add_argument("--out", required=True, help="bag to write (must not exist)")
    rec.add_argument(
        "--duration", type=float, default=None, help="seconds (ROS time); None: until Ctrl-C"
    )
    rec.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap", help="bag storage")
    rec.add_argument(
        "--topic", action="append", help="remap: STREAM=TOPIC (flow_cmd, height, temperature)"
    )
    rec.set_defaults(func=_cmd_record)

    val = command("validate", "validate recorded bags through the live validator's code")
    add_validate_arguments(val)
    add_recording_options(val)
    val.set_defaults(func=_cmd_validate)

    dia = command(
        "diagnose", "trace a model's residual on a bag to the effect it lacks, add it, compare"
    )
    add_diagnose_arguments(dia)
    add_recording_options(dia)
    dia.set_defaults(func=_cmd_diagnose)
    cal = command(
        "calibrate",
        "the smallest uncertainty weights a bag demands of a model, and a model file with "
        "fitted weights",
    )
    add_calibrate_arguments(cal)
    add_recording_options(cal)
    cal.set_defaults(func=_cmd_calibrate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``twotank-validation`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except TwotankError as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":
    sys.exit(main())
