"""Command line ``twotank-validation``: parse, call the core, print; errors without traceback."""

from __future__ import annotations

import argparse
import contextlib
import difflib
import json
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

import twotank_validation
from twotank_validation.cli_common import (
    Interrupts,
    LiveOutput,
    live_end,
    progress_wanted,
    report_dict,
    stdout_to_devnull,
)
from twotank_validation.cli_common import loopback_only as _loopback_only
from twotank_validation.cli_common import out as _out
from twotank_validation.cli_models import (
    add_live_model_options,
    add_simulate_model_options,
    design_text,
    design_values,
)
from twotank_validation.cli_options import (
    absolute,
    add_calibrate_arguments,
    add_diagnose_arguments,
    add_evidence_options,
    add_identify_arguments,
    add_recording_options,
    add_validate_arguments,
    check_fleet_options,
    evidence_params,
    option_dest,
    read_settings,
    replay_config,
    topic_map,
)
from twotank_validation.cli_view import (
    VIEW_STOP,
    ViewRun,
    add_view_options,
    live_view,
    model_bands,
    view_response,
)
from twotank_validation.core.datum import NormConvention
from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.errors import (
    ExitCode,
    TwotankError,
    UsageError,
    held_interrupts,
    interruption,
    raise_interrupted,
)

if TYPE_CHECKING:
    from twotank_validation.usecases import (
        CalibrateJob,
        DiagnoseJob,
        IdentifyJob,
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

EXIT_MEANINGS = {
    ExitCode.OK: "done",
    ExitCode.ERROR: "bad arguments or unusable input, e.g. an empty or unreadable file "
    "(ERROR: says what to change)",
    ExitCode.INCOMPLETE: "the recording was not read completely (WARNING: says what was "
    "missing; windows judged before it are kept)",
    ExitCode.NOT_JUDGED: "read completely, but no window of a model could be judged (ERROR: "
    "says why and the likely fix)",
    ExitCode.UNREADABLE: "several recordings: some could not be read at all or their task "
    "failed (the others were judged)",
    ExitCode.ALARM: "validate --fail-on-alarm: a model's alarm rose (ERROR) on a judged window",
    ExitCode.INTERRUPTED: "SIGINT (Ctrl-C): stopped; what was judged is printed and kept "
    '(JSON with "interrupted": true, figures, a fleet\'s summary.csv)',
    ExitCode.BROKEN_PIPE: "the reader of the output went away (| head): stopped quietly",
    ExitCode.TERMINATED: "SIGTERM: stopped as on SIGINT",
}
"""What each exit code means, as ``--help`` and docs/cli.md list them."""
EXIT_CODES = "exit codes: " + "; ".join(f"{int(c)} {t}" for c, t in EXIT_MEANINGS.items()) + "."


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Each option's default said once: appended unless its help says it or it has none."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if "default" in text or default is None or default is False:
            return text
        return super()._get_help_string(action)


class _CommandParser(argparse.ArgumentParser):
    """A sub-command's parser: an unknown option is its error, with the option it resembles.

    argparse hands a sub-command's unknown arguments back to the top-level parser, whose
    error shows the top-level usage; here the sub-command's usage is shown instead, with the
    closest of its options (Python 3.14's ``suggest_on_error`` does this for choices only).
    """

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        """Parse; unknown arguments are this parser's usage error."""
        parsed, extras = super().parse_known_args(args, namespace)
        if extras:
            hints = []
            for arg in extras:
                if arg.startswith("-"):
                    close = difflib.get_close_matches(
                        arg.partition("=")[0], list(self._option_string_actions), n=1
                    )
                    hints += [f"did you mean {close[0]}?"] if close else []
            hint = f" ({'; '.join(hints)})" if hints else ""
            self.error(f"unrecognized arguments: {' '.join(extras)}{hint}")
        return parsed, extras


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
    steps = tqdm(total=4, desc="demo", unit="step", disable=not progress_wanted(args.quiet))
    steps.set_postfix_str("simulating rig and validating")
    res = experiment.run_experiment(
        cfg, sdp_check=not args.no_sdp, progress=_progress_factory(progress_wanted(args.quiet))
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
        validator=evidence_params(args),
    )
    if cfg.supervisor and not cfg.closed_loop:
        print(
            "error: --supervisor switches the controller's mode: add --closed-loop",
            file=sys.stderr,
        )
        return 2
    output = LiveOutput(args.json)
    view, report = live_view(args, cfg.models, output.report)
    with view or contextlib.nullcontext():
        with Interrupts() as interrupts:
            on_transition = view.transition if view is not None else None
            result = run_live(cfg, on_report=report, on_transition=on_transition, stop=interrupts)
        if result.evidence is not None:
            for bag in result.evidence.bags:
                print(f"evidence bag: {bag}", file=sys.stderr)
        code = _live_tail(args, output, result, cfg, interrupts)
        if view is not None:
            view.hold(f"live run ended (exit code {code})")
    return code


def _cmd_view(args: argparse.Namespace) -> int:
    """``view``: the live view of a running system's reports (its topics)."""
    _loopback_only()
    from twotank_validation.ros.view_node import run_view  # noqa: PLC0415 (needs rclpy)

    models = tuple(args.model or ["A", "B"])
    view = ViewRun(
        args.view_port,
        title="attached",
        bands=model_bands(models),
        speed=1.0,
        replay=False,
        foxglove=args.foxglove_port if args.foxglove else None,
        response=view_response(args, models),
    )
    with view, Interrupts(VIEW_STOP) as interrupts:
        reports = run_view(view.sink, models, duration_s=args.duration, stop=interrupts)
    if reports == 0:
        topics = ", ".join(f"validation/{m}/report" for m in models)
        print(
            f"ERROR: no report came on {topics} (ROS_DOMAIN_ID "
            f"{os.environ.get('ROS_DOMAIN_ID')}, loopback): start the validator in the same "
            "domain, or name its models with --model",
            file=sys.stderr,
        )
        return int(ExitCode.NOT_JUDGED)
    print(f"view: {reports} report(s) shown", file=sys.stderr)
    return int(ExitCode.OK)


def _live_tail(
    args: argparse.Namespace, output: LiveOutput, result: Any, cfg: Any, interrupts: Interrupts
) -> int:
    """``live``'s closing lines: the supervisor's transitions, the summary; the code."""
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
    from twotank_validation.sim.model_record import interface_map_path  # noqa: PLC0415
    from twotank_validation.sim.scenario import load_scenario  # noqa: PLC0415

    wanted = progress_wanted(args.quiet)
    path = simulate_command(
        args.scenario,
        args.out,
        args.storage,
        progress=None if wanted else False,
        design=design_values(args),
    )
    if load_scenario(args.scenario).flow_meter_noise > 0.0:  # its map is beside the bag
        print(f"wrote {path} and its interface map {interface_map_path(path)}")
    else:
        print(f"wrote {path}")
    if text := design_text(path):
        print(text)
    return 0


def _validate_job(args: argparse.Namespace, *, fleet: bool = False) -> ValidateJob:
    """The ``validate`` job of the arguments (``fleet``: files absolute, nothing written)."""
    from twotank_validation.usecases import ValidateJob  # noqa: PLC0415

    return ValidateJob(
        args.bags[0],
        read_settings(args, fleet=fleet),
        tuple(absolute(m, fleet) for m in args.model) if args.model else None,
        diagnosis=not args.no_diagnosis,
        json_path=args.json,
        report_dir=args.report,
        fail_on_alarm=args.fail_on_alarm,
    )


def _say(message: Message) -> None:
    print(message, file=sys.stderr)


def _show(outcome: Outcome, shown: int = 0) -> int:
    """Print an outcome's text and closing lines; its exit code.

    The text on stdout from line ``shown`` on (those before were streamed), the closing
    lines on stderr.
    """
    for line in outcome.text[shown:]:
        _out(line)
    for message in outcome.closing:
        print(message, file=sys.stderr)
    return int(outcome.code)


class _ReplayBar:
    """A replay's progress bar on a terminal, and lines printed on stdout above it.

    The bar is made on the first report of progress; the lines are printed as they come.
    """

    def __init__(self, quiet: bool) -> None:
        self._wanted = progress_wanted(quiet)
        self._bar: tqdm[Any] | None = None
        self.shown = 0

    def progress(self, done: int, total: int) -> None:
        """Told (messages read, messages expected)."""
        if self._bar is None and self._wanted:
            self._bar = tqdm(total=0, desc="replay", unit="msg", mininterval=0.5)
        if self._bar is not None:
            self._bar.total = max(total, done)
            self._bar.n = done
            self._bar.refresh()

    def show(self, line: str) -> None:
        """Print a line of the text as it arises (the bar, if any, redrawn below it).

        A signal waits until the line is printed and counted, so that the lines left to
        print after an interrupt (``shown`` on) are exactly those not printed.
        """
        with held_interrupts():
            if self._bar is not None:
                self._bar.clear()
            _out(line)
            self.shown += 1
            if self._bar is not None:
                self._bar.refresh()

    def close(self) -> None:
        """Remove the bar."""
        if self._bar is not None:
            self._bar.close()


def _run_with_bar(
    job: ValidateJob | DiagnoseJob | CalibrateJob | IdentifyJob,
    quiet: bool,
    **listeners: Any,
) -> int:
    """Run one recording's job with the replay's progress bar; print its outcome; the code.

    ``listeners``: more keyword arguments of the job's ``run`` (``validate``'s
    ``on_report``).
    """
    bar = _ReplayBar(quiet)
    try:
        outcome = job.run(say=_say, progress=bar.progress, show=bar.show, **listeners)
    finally:
        bar.close()
    return _show(outcome, bar.shown)


def _cmd_validate(args: argparse.Namespace) -> int:
    if not _single_recording(args):
        if args.view or args.foxglove or args.view_response:
            shown = "--view" if args.view else "--foxglove" if args.foxglove else "--view-response"
            raise UsageError(f"{shown} shows one recording: name one bag or table, without --out")
        check_fleet_options(args)
        return _cmd_fleet(args, _validate_job(args, fleet=True))
    job = _validate_job(args)
    response = view_response(args, job.sources, page=args.view)
    if not (args.view or args.foxglove):
        if args.replay_speed is not None:
            raise UsageError("--replay-speed paces the view's replay: add --view or --foxglove")
        return _run_with_bar(job, args.quiet)
    bands = model_bands(job.sources, job.read.monitor)
    title = Path(job.recording).name
    with ViewRun(
        args.view_port,
        title=title,
        bands=bands,
        speed=args.replay_speed,
        replay=True,
        page=args.view,
        foxglove=args.foxglove_port if args.foxglove else None,
        response=response,
    ) as view:
        code = _run_with_bar(job, args.quiet, on_report=view.report)
        how = "interrupted" if code in (ExitCode.INTERRUPTED, ExitCode.TERMINATED) else "finished"
        view.hold(f"replay of {title} {how} (exit code {code})")
    return code


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
    return _run_with_bar(_diagnose_job(args), args.quiet)


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
        together=args.together,
        json_path=args.json,
        report_dir=args.report,
        out_model=args.out_model,
        noise_from_data=args.noise_from_data,
        noise_quantile=args.noise_quantile,
        noise_budget=args.noise_budget,
    )
    return _run_with_bar(job, args.quiet)


def _cmd_identify(args: argparse.Namespace) -> int:
    """``identify``: the measured response, a fitted nominal and a model set."""
    from twotank_validation.usecases import IdentifyJob  # noqa: PLC0415

    job = IdentifyJob(
        args.bag,
        read_settings(args),
        orders=args.orders,
        delays=args.delays,
        grey_box=args.grey_box,
        start=args.start,
        end=args.end,
        name=args.name,
        json_path=args.json,
        report_dir=args.report,
        out_model=args.out_model,
    )
    return _run_with_bar(job, args.quiet)


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
    from twotank_validation.usecases import ValidateJob  # noqa: PLC0415
    from twotank_validation.usecases.validate import default_models_note  # noqa: PLC0415

    # bad models and maps, and models whose channels the map does not carry, fail here,
    # before any task
    names = job.model_names(check_channels=True)
    expansion = fleet.expand_paths(args.bags)
    paths = [os.path.abspath(p) for p in expansion.recordings]
    expansion = fleet.Expansion(tuple(paths), expansion.skipped)
    settings = None
    if args.scheduler or not (args.serial or args.workers == 0):
        tls = None
        if args.tls_ca_file:  # checked: with --tls-cert and a tls:// scheduler
            tls = fleet.TlsFiles(args.tls_ca_file, args.tls_cert, args.tls_key)
        settings = fleet.DaskSettings(workers=args.workers or 0, scheduler=args.scheduler, tls=tls)
    where = (
        "in this process"
        if settings is None
        else f"on {args.scheduler}"
        if args.scheduler
        else f"on a local cluster of {settings.workers or os.cpu_count()} worker(s)"
    )
    print(f"{len(paths)} recording(s) {where}", file=sys.stderr)
    if isinstance(job, ValidateJob) and not job.models_named:  # once, not per recording
        print(f"note: {default_models_note(job.sources)}", file=sys.stderr)
    bar = tqdm(
        total=len(paths),
        desc=args.command,
        unit="recording",
        disable=not progress_wanted(args.quiet),
    )

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
    if res.interrupted is not None:
        done = sum(o.status != fleet.STATUS_INTERRUPTED for o in res.outcomes)
        print(
            f"interrupted by {res.interrupted.name}: {done} of {len(res.outcomes)} "
            f"recording(s) finished; summary.csv and fleet.png of them in {args.out}",
            file=sys.stderr,
        )
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
        allow_abbrev=False,
    )
    parser.add_argument(
        "--version", action="version", version=f"%(prog)s {twotank_validation.__version__}"
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_CommandParser)

    def command(name: str, help_: str) -> argparse.ArgumentParser:
        # every option's help shows its default once; every command's help ends with the
        # exit codes; an option is never matched by a prefix of its name
        return sub.add_parser(
            name,
            help=help_,
            formatter_class=_HelpFormatter,
            epilog=EXIT_CODES,
            allow_abbrev=False,
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
    add_view_options(live, replay=False)
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
    add_evidence_options(live)
    add_live_model_options(live, _cmd_live)

    att = command(
        "view",
        "serve the live view of a running system: its validation/M/report, "
        "validation/M/diagnosis and control/mode topics (docs/view.md)",
    )
    att.add_argument(
        "--model", action="append", help="model whose topics to follow (repeat; default A and B)"
    )
    att.add_argument(
        "--duration", type=float, default=None, help="wall seconds (default: until Ctrl-C)"
    )
    add_view_options(att, replay=False, port_only=True)
    att.set_defaults(func=_cmd_view)

    sim = command(
        "simulate",
        "simulate a scenario of the rig into a rosbag2 bag, or any model (--model) into a bag "
        "or a CSV table with its interface map",
    )
    sim.add_argument("--scenario", help="scenario YAML file or shipped name (e.g. nominal, leak)")
    sim.add_argument("--out", required=True, help="bag to write (must not exist)")
    sim.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap", help="bag storage")
    sim.add_argument("--quiet", action="store_true", help="no progress bar")
    add_simulate_model_options(sim, _cmd_simulate)

    rec = command("record", "record the interface topics of a live system into a bag")
    rec.add_argument("--out", required=True, help="bag to write (must not exist)")
    rec.add_argument(
        "--duration", type=float, default=None, help="seconds (ROS time); default: until Ctrl-C"
    )
    rec.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap", help="bag storage")
    rec.add_argument(
        "--topic", action="append", help="remap: STREAM=TOPIC (flow_cmd, height, temperature)"
    )
    rec.set_defaults(func=_cmd_record)

    val = command("validate", "validate recorded bags through the live validator's code")
    add_validate_arguments(val)
    add_view_options(val, replay=True)
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
    ide = command(
        "identify",
        "from a periodic experiment to a model set: the measured response ± σ, a fitted "
        "nominal, perturbation and noise weights (docs/identify.md)",
    )
    add_identify_arguments(ide)
    add_recording_options(ide)
    ide.set_defaults(func=_cmd_identify)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``twotank-validation`` console script."""
    args = build_parser().parse_args(argv)
    handlers = {}
    if threading.current_thread() is threading.main_thread():  # signals reach it only
        for sig in (signal.SIGINT, signal.SIGTERM):
            handlers[sig] = signal.signal(sig, raise_interrupted)
    try:
        return int(args.func(args))
    except TwotankError as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt as stop:  # before anything was judged, or a second signal
        interrupted = interruption(stop)
        print(f"interrupted by {interrupted.name}", file=sys.stderr)
        return interrupted.exit_code
    except BrokenPipeError:
        stdout_to_devnull()  # the reader of stdout went away (`live | head -3`): stop quietly
        return ExitCode.BROKEN_PIPE
    finally:
        for sig, previous in handlers.items():
            if previous is not None:  # None: not set from Python
                signal.signal(sig, previous)


if __name__ == "__main__":
    sys.exit(main())
