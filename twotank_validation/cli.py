"""Command line ``twotank-validation``: parse, call the core, print; errors without traceback."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

from twotank_validation.core.datum import NormConvention
from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.errors import TwotankError
from twotank_validation.online import WindowReport
from twotank_validation.online.window import verdict_text

if TYPE_CHECKING:
    from twotank_validation.online.interface import InterfaceMap
    from twotank_validation.settings import FlatSetting

EXIT_OK = 0
"""The command ran and judged what it was asked to judge."""
EXIT_ERROR = 2
"""Bad arguments or a file that cannot be used (the message says what to change)."""
EXIT_INCOMPLETE = 3
"""The recording could not be read completely (a topic missing or of the wrong type, damage)."""
EXIT_NOT_JUDGED = 4
"""The recording was read completely, but no window of a model could be judged (the message
says why)."""

EXIT_CODES = f"""exit codes: {EXIT_OK} done; {EXIT_ERROR} bad arguments or unusable input \
(ERROR: says what to change); {EXIT_INCOMPLETE} the recording was not read completely \
(WARNING: says what was missing; windows judged before it are kept); {EXIT_NOT_JUDGED} \
read completely, but no window of a model could be judged (ERROR: says why and the likely \
fix)."""


def _out(*parts: object) -> None:
    """Print to stdout; a reader that went away (``| head``) ends the printing quietly.

    The command goes on (its JSON and report files are still written); only what would have
    been printed is dropped.
    """
    try:
        print(*parts, flush=True)
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # later prints and the exit flush go nowhere
        os.close(devnull)


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
        closed_loop=args.closed_loop,
        controller={"excitation_entry": args.excitation_entry} if args.closed_loop else {},
        supervisor=args.supervisor is not None,
        supervisor_params={"models": args.supervisor} if args.supervisor else {},
    )
    if cfg.supervisor and not cfg.closed_loop:
        print(
            "error: --supervisor switches the controller's mode: add --closed-loop",
            file=sys.stderr,
        )
        return 2

    def show(rep: WindowReport) -> None:
        if args.json:
            print(json.dumps(report_dict(rep)), flush=True)
            return
        verdict = verdict_text(rep) if rep.judged else f"not judged: {rep.data_quality}"
        warned = "".join(f"  warning: {w}" for w in rep.warnings)
        print(
            f"[{rep.start_ns / 1e9:8.1f}, {rep.end_ns / 1e9:8.1f}] s  model {rep.model}: "
            f"{verdict}  alarm {rep.alarm.name}{warned}",
            flush=True,
        )

    result = run_live(cfg, on_report=show)
    for tr in result.transitions:
        if args.json:
            entry = {
                "time": tr.time_s,
                "from": tr.from_mode.value,
                "to": tr.to_mode.value,
                "reason": tr.reason,
            }
            print(json.dumps({"transition": entry}), flush=True)
        else:
            print(
                f"[{tr.time_s:8.1f} s] supervisor: {tr.from_mode.value} -> {tr.to_mode.value}: "
                f"{tr.reason}",
                flush=True,
            )
    print(
        f"simulated {cfg.duration_s:.0f} s in {result.wall_s:.1f} s wall "
        f"({cfg.duration_s / max(result.wall_s, 1e-9):.0f}x real time); "
        f"{len(result.reports)} reports; aligner: {result.counters}",
        file=sys.stderr,
    )
    return 0


def _finite(x: float) -> float | None:
    """``x``, or None (JSON null) where it is NaN or infinite."""
    return x if math.isfinite(x) else None


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
        "data_quality": rep.data_quality,
        "warnings": list(rep.warnings),
        "beta_op": _finite(rep.beta_op),
        "beta_total": _finite(rep.beta_total),
        "raised_by": rep.raised_by,
        "operating_point": rep.operating_point,
    }


def _cmd_simulate(args: argparse.Namespace) -> int:
    from twotank_validation.bags.scenario_bag import simulate_command  # noqa: PLC0415

    path = simulate_command(args.scenario, args.out, args.storage)
    print(f"wrote {path}")
    return 0


# --------------------------------------------------------------------------- live --plant-model


def _add_live_model_options(live: argparse.ArgumentParser) -> None:
    """``live --plant-model FILE``'s options; the command then runs :func:`_cmd_live_model`."""
    group = live.add_argument_group("any model's plant (--plant-model; docs/simulate.md)")
    group.add_argument(
        "--plant-model",
        help="run the plant of this model (YAML file or built-in name) instead of the "
        "two-tank rig; --model then names the validated models (default: this one), "
        "--fault takes KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S] on its channels",
    )
    group.add_argument(
        "--member",
        default="nominal",
        help="--plant-model: the member of its set: nominal, gains=G[,G...] or "
        "random[,seed=S][,scale=R]",
    )
    group.add_argument(
        "--noise-scale",
        type=float,
        default=SIM_NOISE_SCALE,
        help="--plant-model: noise as a fraction of what the model's noise weights admit "
        f"(default {SIM_NOISE_SCALE}: at 1 the noise alone uses the whole unit budget of w, so "
        "beta of the nominal sits at 1)",
    )
    live.set_defaults(func=_cmd_live_model)


def _cmd_live_model(args: argparse.Namespace) -> int:
    """``live``: the two-tank rig, or any model's plant with ``--plant-model``."""
    if args.plant_model is None:
        if args.member != "nominal" or args.noise_scale != SIM_NOISE_SCALE:
            raise UsageError("--member and --noise-scale are for --plant-model")
        return _cmd_live(args)
    if args.closed_loop or args.supervisor is not None:
        raise UsageError(
            "--closed-loop and --supervisor run the two-tank rig's controller; a "
            "--plant-model runs open loop"
        )
    if not (args.ts > 0 and args.duration >= args.ts):
        raise UsageError(
            f"--ts {args.ts:g} and --duration {args.duration:g}: give a sample period > 0 and "
            "a duration of at least one sample"
        )
    _loopback_only()
    from twotank_validation.ros.live_model import (  # noqa: PLC0415 (needs rclpy)
        ModelLiveConfig,
        run_model_live,
    )

    cfg = ModelLiveConfig(
        plant_model=args.plant_model,
        models=tuple(args.model or ()),
        n_steps=round(args.duration / args.ts),
        ts_s=args.ts,
        period_samples=args.period,
        faults=tuple(args.fault or ()),
        member=args.member,
        noise_scale=args.noise_scale,
        noise_seed=args.seed,
        record_samples=False,
    )

    def show(rep: WindowReport) -> None:
        if args.json:
            _out(json.dumps(report_dict(rep)))
            return
        verdict = verdict_text(rep) if rep.judged else f"not judged: {rep.data_quality}"
        warned = "".join(f"  warning: {w}" for w in rep.warnings)
        _out(
            f"[{rep.start_ns / 1e9:8.1f}, {rep.end_ns / 1e9:8.1f}] s  model {rep.model}: "
            f"{verdict}  alarm {rep.alarm.name}{warned}"
        )

    result = run_model_live(cfg, on_report=show)
    simulated = cfg.n_steps * cfg.ts_s
    print(
        f"simulated {simulated:.0f} s in {result.wall_s:.1f} s wall "
        f"({simulated / max(result.wall_s, 1e-9):.0f}x real time); "
        f"{len(result.reports)} reports; aligner: {result.counters}",
        file=sys.stderr,
    )
    return 0


# --------------------------------------------------------------------------- simulate --model


def _add_simulate_model_options(sim: argparse.ArgumentParser) -> None:
    """``simulate --model FILE``'s options; the command then runs :func:`_cmd_simulate_model`."""
    group = sim.add_argument_group("any model (--model; docs/simulate.md)")
    group.add_argument(
        "--model",
        help="simulate this model (YAML file or built-in name) instead of a scenario: its "
        "nominal or a member of its set, its noise, faults on its named channels",
    )
    group.add_argument(
        "--format",
        choices=["mcap", "sqlite3", "csv"],
        default=None,
        help="--model: a rosbag2 bag (one std_msgs/Float64 topic per channel) or a CSV table "
        "(--out ends in .csv); the interface map is written beside it (<out>.map.yaml, "
        "<stem>.map.yaml for a table); None: mcap",
    )
    group.add_argument("--ts", type=float, default=TS_S, help="--model: sample period (s)")
    group.add_argument(
        "--period", type=int, default=PERIOD_SAMPLES, help="--model: excitation period (samples)"
    )
    group.add_argument(
        "--periods", type=int, default=2, help="--model: periods recorded after settling"
    )
    group.add_argument(
        "--settle-periods",
        type=int,
        default=None,
        help="--model: periods to let the transient die out first; None: as many as the "
        "plant needs",
    )
    group.add_argument(
        "--member",
        default="nominal",
        help="--model: the member of the perturbation set: nominal, gains=G[,G...] or "
        "random[,seed=S][,scale=R]",
    )
    group.add_argument(
        "--fault",
        action="append",
        help="--model: KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S], KIND one of input_gain, "
        "stuck_input, sensor_bias, output_delay (repeat)",
    )
    group.add_argument("--rms", type=float, default=0.1, help="--model: RMS of every input")
    group.add_argument(
        "--offset", type=float, default=0.0, help="--model: operating point of every input"
    )
    group.add_argument("--seed", type=int, default=0, help="--model: excitation seed")
    group.add_argument(
        "--noise-scale",
        type=float,
        default=SIM_NOISE_SCALE,
        help="--model: noise as a fraction of what the model's noise weights admit "
        f"(default {SIM_NOISE_SCALE}: at 1 the noise alone uses the whole unit budget of w)",
    )
    group.add_argument("--noise-seed", type=int, default=0, help="--model: noise seed")
    sim.set_defaults(func=_cmd_simulate_model)


def _cmd_simulate_model(args: argparse.Namespace) -> int:
    """``simulate``: a scenario (``--scenario``) or any model (``--model``), exactly one."""
    if (args.scenario is None) == (args.model is None):
        raise UsageError(
            "simulate needs exactly one of --scenario NAME (the two-tank rig) and --model FILE "
            "(any model), found " + ("both" if args.scenario is not None else "neither")
        )
    if args.scenario is not None:
        if args.format is not None:
            raise UsageError("--format is for --model; a scenario's bag takes --storage")
        return _cmd_simulate(args)
    if args.storage != "mcap":
        raise UsageError("--storage is for --scenario; with --model give --format")
    from twotank_validation.bags.model_bag import simulate_model_command  # noqa: PLC0415
    from twotank_validation.sim.model_record import interface_map_path  # noqa: PLC0415

    path = simulate_model_command(
        args.model,
        args.out,
        args.format or "mcap",
        ts_s=args.ts,
        period_samples=args.period,
        periods=args.periods,
        settle_periods=args.settle_periods,
        rms=args.rms,
        offset=args.offset,
        seed=args.seed,
        member=args.member,
        noise_scale=args.noise_scale,
        noise_seed=args.noise_seed,
        faults=tuple(args.fault or ()),
    )
    print(f"wrote {path} and its interface map {interface_map_path(path)}")
    return 0


def _topic_map(pairs: Sequence[str] | None) -> dict[str, str]:
    from twotank_validation.online.streams import STREAMS  # noqa: PLC0415

    topics = {s: s for s in STREAMS}
    for pair in pairs or ():
        stream, sep, topic = pair.partition("=")
        if not sep or stream not in topics or not topic:
            raise UsageError(
                f"--topic expects STREAM=TOPIC with STREAM in {list(STREAMS)}, found {pair!r}"
            )
        topics[stream] = topic
    return topics


def _replay_config(
    args: argparse.Namespace,
    ts_s: float,
    period_samples: int,
    oversampling: dict[str, int] | None = None,
) -> object:
    """The ``replay.ReplayConfig`` of the shared bag options (validate, diagnose)."""
    from twotank_validation import replay  # noqa: PLC0415
    from twotank_validation.online import MonitorConfig  # noqa: PLC0415
    from twotank_validation.settings import from_flat  # noqa: PLC0415

    try:
        return replay.ReplayConfig(
            monitor=from_flat(
                MonitorConfig,
                {s.name: getattr(args, option_dest(s.meta.option)) for s in _option_settings()}
                | {
                    "ts_s": ts_s,
                    "period_samples": period_samples,
                    "input_periodic_rtol": _input_periodic_rtol(args),
                },
            ),
            interface=_interface_map(args),
            oversampling=oversampling or {},
        )
    except ValueError as err:
        raise UsageError(str(err)) from err


def _input_periodic_rtol(args: argparse.Namespace) -> float:
    """The input periodicity gate: closed-loop data's with ``--closed-loop`` (theory.md §10)."""
    from twotank_validation.online import MonitorConfig  # noqa: PLC0415
    from twotank_validation.sim.control import CLOSED_LOOP_INPUT_PERIODIC_RTOL  # noqa: PLC0415

    if getattr(args, "closed_loop", False):
        return CLOSED_LOOP_INPUT_PERIODIC_RTOL
    return MonitorConfig.input_periodic_rtol


def _interface_map(args: argparse.Namespace) -> InterfaceMap:
    """The interface map of ``--map`` or ``--input``/``--output``, else the two-tank preset.

    The preset takes ``--topic`` remaps and the unit options. ``--time`` gives a table's time
    column (it replaces the map file's ``time``).
    """
    from twotank_validation.online import interface  # noqa: PLC0415
    from twotank_validation.online.streams import RigUnits, two_tank_map  # noqa: PLC0415

    texts = bool(args.input or args.output)
    if not (args.map or texts):
        if args.time is not None:
            raise UsageError(
                "--time names a table's time column; give the table's columns with --map FILE "
                "or --input/--output NAME=column:COLUMN"
            )
        units = RigUnits(args.pascal_per_unit, args.temperature_offset_c, args.temperature_span_c)
        return two_tank_map(units, _topic_map(args.topic))
    if args.topic:
        raise UsageError(
            "--topic remaps the two-tank interface; with --map/--input/--output give the "
            "topics in the map instead"
        )
    if args.map and texts:
        raise UsageError("give the interface either as --map FILE or as --input/--output")
    if args.map:
        imap = interface.load_interface_map(args.map)
        if args.time is None:
            return imap
        return replace(imap, time=interface.time_column_from_text(args.time))
    if not (args.input and args.output):
        raise UsageError("--input and --output go together: give every input and every output")
    return interface.interface_map_from_text(args.input, args.output, args.time)


def _stderr(line: str) -> None:
    print(line, file=sys.stderr)


def _timed_config(
    args: argparse.Namespace, say: Callable[[str], None] = _stderr
) -> tuple[object, object]:
    """The replay config with the sample and excitation periods resolved, and the timing.

    ``--ts``/``--period`` win; else the bag's metadata, else what the data show
    (``replay.resolve_timing``). What was taken is said (``say``, default stderr),
    contradictions as warnings.
    """
    from twotank_validation import replay  # noqa: PLC0415

    base = _replay_config(args, args.ts or TS_S, args.period or PERIOD_SAMPLES)
    assert isinstance(base, replay.ReplayConfig)
    if replay.is_table_input(args.bag, base) and not base.interface.is_table:
        raise UsageError(
            f"{args.bag} is a table (CSV/Parquet): give the map of its columns with --map FILE "
            "(a 'column' per input and output, and the time column: docs/interface.md, "
            "Tables), or --input/--output NAME=column:COLUMN[,scale=S][,offset=O]"
        )
    timing = replay.resolve_timing(args.bag, base, ts_s=args.ts, period_samples=args.period)
    for note in timing.notes:
        say(f"note: {note}")
    for conflict in timing.conflicts:
        say(f"WARNING: {conflict}")
    return _replay_config(args, timing.ts_s, timing.period_samples, timing.oversampling), timing


def _validate_setup(
    args: argparse.Namespace, say: Callable[[str], None] = _stderr
) -> tuple[list[Any], Any, Any]:
    """``(models, replay config, timing)`` of ``validate`` on the recording ``args.bag``."""
    from twotank_validation import replay  # noqa: PLC0415
    from twotank_validation.core.model import load_model_document, model_from_dict  # noqa: PLC0415

    docs = [load_model_document(m) for m in (args.model or ["A", "B"])]
    models = [model_from_dict(doc, source) for doc, source in docs]
    cfg, timing = _timed_config(args, say)
    assert isinstance(cfg, replay.ReplayConfig)
    assert isinstance(timing, replay.Timing)
    if not args.no_diagnosis:
        cfg = replace(
            cfg,
            diagnosis=True,
            documents={m.name: doc for m, (doc, _) in zip(models, docs, strict=True)},
        )
    return models, cfg, timing


def _validate_summary(result: Any, models: Sequence[Any], timing: Any) -> dict[str, Any]:
    """The ``validate --json`` document of a replay."""
    from twotank_validation import replay  # noqa: PLC0415

    summary = replay.summary_json(result, [m.name for m in models])
    summary["timing"] = timing.to_json()
    return summary


def _cmd_validate(args: argparse.Namespace) -> int:
    from twotank_validation import replay, report  # noqa: PLC0415

    if not _single_recording(args):
        return _cmd_fleet(args, _validate_job)
    models, cfg, timing = _validate_setup(args)
    bar = None
    if not args.quiet:
        bar = tqdm(total=0, desc="replay", unit="msg", mininterval=0.5, disable=None)

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = max(total, done)
            bar.n = done
            bar.refresh()

    result = replay.replay_recording(args.bag, models, cfg, progress=progress)
    if bar is not None:
        bar.close()
    summary = _validate_summary(result, models, timing)
    _out(f"{'window (s)':>21}  {'model':<6} {'beta':>7} {'beta_op':>7}  {'verdict':<30} alarm")
    for name, entry in summary["models"].items():
        for w in entry["windows"]:
            verdict = (
                ("INVALIDATED" if w["invalidated"] else "valid")
                if w["beta"] is not None
                else "not judged"
            )
            beta = f"{w['beta']:7.3f}" if w["beta"] is not None else "      -"
            beta += f" {w['beta_op']:7.3f}" if w["beta_op"] is not None else "       -"
            if w["raised_by"]:
                verdict += f" ({w['raised_by']})"
            extra = f"  ({w['reason']})" if w["reason"] else ""
            extra += "".join(f"  (warning: {text})" for text in w["warnings"])
            if w["diagnosis"] is not None:
                extra += "  (diagnosis: {})".format(_diagnosis_text(w["diagnosis"]))
            _out(
                f"{w['start']:9.1f}-{w['end']:9.1f}  {name:<6} {beta}  {verdict:<30} "
                f"{w['alarm']}{extra}"
            )
    for name, entry in summary["models"].items():
        bmax = "-" if entry["beta_max"] is None else f"{entry['beta_max']:.3f}"
        first = "none" if entry["first_alarm"] is None else f"{entry['first_alarm']:.1f} s"
        _out(
            f"model {name}: {entry['judged']} of {entry['judged'] + entry['not_judged']} "
            f"window(s) judged, beta_max {bmax}, first alarm {first}"
        )
    for problem in result.problems:
        print(f"WARNING: {problem}", file=sys.stderr)
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2))
    if args.report:
        report.write_replay_report(result, {m.name: m for m in models}, summary, Path(args.report))
    print(
        f"{result.messages} {'rows' if result.source == 'table' else 'messages'}; "
        f"decoding {result.decode_s:.2f} s, "
        f"validation {result.validate_s:.2f} s; "
        + ("complete" if result.complete else "INCOMPLETE"),
        file=sys.stderr,
    )
    return _exit_code(result.complete, replay.unjudged_models(summary, timing, cfg), timing)


def _diagnosis_text(d: dict[str, Any]) -> str:
    """``"leak on height (outflow 0.058), confidence 0.17"`` of a window's diagnosis entry."""
    params = ", ".join(f"{k} {v:.3g}" for k, v in d["parameters"].items())
    where = f" on {d['channel']}" if d["channel"] else ""
    return (
        f"{d['kind']}{where}"
        + (f" ({params})" if params else "")
        + (f", confidence {d['confidence']:.2f}")
    )


def _exit_code(complete: bool, unjudged: Sequence[str], timing: object) -> int:
    """The exit code of a replay, with the reasons of models without a judged window.

    3 if the recording was not read completely (the cause of anything missing), else 4 if a
    model had no judged window, else 0.

    Args:
        complete: the whole recording was read.
        unjudged: one line per model without a judged window (``replay.unjudged_models``).
        timing: the ``replay.Timing`` used.
    """
    code, lines = _exit_status(complete, unjudged, timing)
    for line in lines:
        print(line, file=sys.stderr)
    return code


def _exit_status(complete: bool, unjudged: Sequence[str], timing: object) -> tuple[int, list[str]]:
    """:func:`_exit_code` without printing: the code and its ``ERROR:`` lines."""
    from twotank_validation import replay  # noqa: PLC0415

    lines = [f"ERROR: {line}" for line in unjudged]
    if unjudged:
        assert isinstance(timing, replay.Timing)
        lines.append(
            f"ERROR: judged with ts {timing.ts_s:.9g} s ({timing.ts_from}) and period "
            f"{timing.period_samples} samples ({timing.period_from})"
        )
    if not complete:
        return EXIT_INCOMPLETE, lines
    return (EXIT_NOT_JUDGED if unjudged else EXIT_OK), lines


@dataclass
class _DiagnoseReplay:
    """What ``diagnose`` read from one recording before diagnosing it."""

    doc: Any
    source: str
    model: Any
    cfg: Any
    timing: Any
    windows: list[Any]
    findings: list[Any]
    replayed: Any
    summary: dict[str, Any]
    unjudged: list[str]


def _diagnose_replay(
    args: argparse.Namespace, say: Callable[[str], None] = _stderr
) -> _DiagnoseReplay:
    """Replay ``args.bag`` for ``diagnose``: its judged windows, findings and summary."""
    from twotank_validation import replay  # noqa: PLC0415
    from twotank_validation.core.model import load_model_document, model_from_dict  # noqa: PLC0415

    doc, source = load_model_document(args.model)
    model = model_from_dict(doc, source)
    cfg, timing = _timed_config(args, say)
    assert isinstance(cfg, replay.ReplayConfig)
    assert isinstance(timing, replay.Timing)
    windows, findings, replayed = replay.windows_with_findings(
        args.bag, model, cfg, start=args.start, end=args.end
    )
    for problem in replayed.problems:
        say(f"WARNING: {problem}")
    summary = replay.summary_json(replayed, [model.name])
    unjudged = replay.unjudged_models(summary, timing, cfg)
    return _DiagnoseReplay(
        doc, source, model, cfg, timing, windows, findings, replayed, summary, unjudged
    )


def _diagnose_recording(args: argparse.Namespace, run: _DiagnoseReplay) -> tuple[Any, Any]:
    """``(recording diagnosis, diagnosis of its current stretch)`` of the replayed windows.

    Raises:
        DiagnosisError: no stretch could be diagnosed (the reasons per stretch).
    """
    from twotank_validation import diagnose as dg  # noqa: PLC0415
    from twotank_validation.diagnose import stretches  # noqa: PLC0415

    ranged = args.start is not None or args.end is not None
    recording = stretches.diagnose_stretches(
        run.windows,
        run.doc,
        run.findings,
        dg.DiagnosisConfig(max_effects=args.max_effects),
        split=args.segment or not ranged,
        source=run.source,
        convention=NormConvention(args.norm),
    )
    current = recording.current
    if current is None or current.relative_to_model is None:
        why = "; ".join(
            f"{s.stretch.start_s:.1f}-{s.stretch.end_s:.1f} s: {s.not_diagnosed}"
            for s in recording.stretches
        )
        raise dg.DiagnosisError(f"no stretch of the recording could be diagnosed ({why})")
    return recording, current.relative_to_model


def _diagnosis_document(
    recording: Any, diag: Any, timing: Any, model_file: str | None
) -> dict[str, Any]:
    """The ``diagnose --json`` document."""
    out: dict[str, Any] = diag.to_json(model_file)
    out.update(recording.to_json())
    out["stretch"] = recording.stretches.index(recording.current)
    out["timing"] = timing.to_json()
    return out


def _cmd_diagnose(args: argparse.Namespace) -> int:
    import yaml  # noqa: PLC0415

    from twotank_validation import report  # noqa: PLC0415

    if not _single_recording(args):
        return _cmd_fleet(args, _diagnose_job)
    run = _diagnose_replay(args)
    if run.unjudged:
        return _exit_code(run.replayed.complete, run.unjudged, run.timing)
    ranged = args.start is not None or args.end is not None
    windows, model = run.windows, run.model
    _out(
        f"{len(windows)} non-overlapping judged window(s) of model {model.name} in {args.bag}"
        + (f" ({windows[0].start_s:.1f} .. {windows[-1].start_s:.1f} s)" if ranged else "")
    )
    recording, diag = _diagnose_recording(args, run)
    replayed, timing = run.replayed, run.timing
    model_file = None
    if diag.document is not None and args.out_model:
        Path(args.out_model).write_text(
            "# Written by twotank-validation diagnose; validate with --model this file.\n"
            + yaml.safe_dump(diag.document, sort_keys=False, width=100)
        )
        model_file = str(args.out_model)
    out = _diagnosis_document(recording, diag, timing, model_file)
    _out(_stretches_text(recording))
    _out(report.diagnosis_text(diag, model_file))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    if args.report:
        report.write_diagnosis_report(diag, Path(args.report))
        _out(f"figures in {args.report}")
    return EXIT_OK if replayed.complete else EXIT_INCOMPLETE


# --------------------------------------------------------------------------- many recordings


def _single_recording(args: argparse.Namespace) -> bool:
    """One recording named directly and no ``--out``: the single-recording command.

    Sets ``args.bag`` to it. Several paths, a directory of recordings, a glob or ``--out``
    make a fleet run (:func:`_cmd_fleet`).
    """
    from twotank_validation import fleet  # noqa: PLC0415

    if args.out is None and fleet.is_single(args.bags):
        args.bag = args.bags[0]
        return True
    return False


def _absolute(value: str | None) -> str | None:
    """An existing file's absolute path (a task may run in another folder), else as given."""
    return os.path.abspath(value) if value is not None and os.path.exists(value) else value


def _fleet_args(args: argparse.Namespace) -> argparse.Namespace:
    """The options every task gets: files made absolute, single-recording outputs off."""
    one = argparse.Namespace(**vars(args))
    one.quiet = True
    one.json = one.report = None
    if hasattr(one, "out_model"):
        one.out_model = None
    if isinstance(one.model, list):
        one.model = [_absolute(m) for m in one.model]
    else:
        one.model = _absolute(one.model)
    one.map = _absolute(one.map)
    return one


def _validate_job(args: argparse.Namespace, path: str) -> Any:
    """One recording of ``validate`` in a fleet: a ``fleet.RecordingOutcome``.

    The document is the one ``validate --json`` writes for that recording alone.
    """
    from twotank_validation import fleet, replay  # noqa: PLC0415

    one = argparse.Namespace(**vars(args))
    one.bag = path
    said: list[str] = []
    try:
        models, cfg, timing = _validate_setup(one, said.append)
        result = replay.replay_recording(path, models, cfg)
    except TwotankError as err:
        return fleet.RecordingOutcome(
            path, fleet.STATUS_UNREADABLE, EXIT_ERROR, messages=(*said, f"ERROR: {err}")
        )
    summary = _validate_summary(result, models, timing)
    said += [f"WARNING: {problem}" for problem in result.problems]
    code, lines = _exit_status(
        result.complete, replay.unjudged_models(summary, timing, cfg), timing
    )
    return fleet.RecordingOutcome(path, _STATUS[code], code, summary, summary, (*said, *lines))


def _diagnose_job(args: argparse.Namespace, path: str) -> Any:
    """One recording of ``diagnose`` in a fleet: a ``fleet.RecordingOutcome``.

    The document is the one ``diagnose --json`` writes for that recording alone (None where
    it writes none: no window judged, nothing diagnosed).
    """
    from twotank_validation import fleet  # noqa: PLC0415

    one = argparse.Namespace(**vars(args))
    one.bag = path
    said: list[str] = []
    try:
        run = _diagnose_replay(one, said.append)
    except TwotankError as err:
        return fleet.RecordingOutcome(
            path, fleet.STATUS_UNREADABLE, EXIT_ERROR, messages=(*said, f"ERROR: {err}")
        )
    if run.unjudged:
        code, lines = _exit_status(run.replayed.complete, run.unjudged, run.timing)
        return fleet.RecordingOutcome(path, _STATUS[code], code, None, run.summary, (*said, *lines))
    try:
        recording, diag = _diagnose_recording(one, run)
    except TwotankError as err:
        return fleet.RecordingOutcome(
            path,
            fleet.STATUS_NOT_JUDGED,
            EXIT_ERROR,
            None,
            run.summary,
            (*said, f"ERROR: {err}"),
        )
    doc = _diagnosis_document(recording, diag, run.timing, None)
    code = EXIT_OK if run.replayed.complete else EXIT_INCOMPLETE
    return fleet.RecordingOutcome(path, _STATUS[code], code, doc, run.summary, tuple(said))


_STATUS = {
    EXIT_OK: "complete",
    EXIT_INCOMPLETE: "incomplete",
    EXIT_NOT_JUDGED: "not judged",
}
"""A recording's status in a fleet by its single-recording exit code (fleet.STATUS_*)."""


def _cmd_fleet(args: argparse.Namespace, job: Callable[[argparse.Namespace, str], Any]) -> int:
    """``validate``/``diagnose`` of several recordings: one task each, then the summary."""
    import functools  # noqa: PLC0415

    from twotank_validation import fleet  # noqa: PLC0415

    single_only = [
        opt
        for opt, value in (
            ("--json", args.json),
            ("--report", args.report),
            ("--out-model", getattr(args, "out_model", None)),
        )
        if value
    ]
    if single_only:
        raise UsageError(
            f"{', '.join(single_only)} write(s) one recording's results; with several "
            "recordings give --out DIR (one JSON per recording, summary.csv, fleet.png)"
        )
    if args.out is None:
        raise UsageError(
            "several recordings: give --out DIR for one JSON per recording, the summary "
            "table (summary.csv) and the figure (fleet.png)"
        )
    if args.scheduler and (args.serial or args.workers is not None):
        raise UsageError(
            "--scheduler runs on that cluster's workers: drop --workers/--serial, or drop "
            "--scheduler to run on this machine"
        )
    if args.workers is not None and args.workers < 0:
        raise UsageError(f"--workers must be 0 (in this process) or more, found {args.workers}")
    one = _fleet_args(args)
    # bad models and maps, and models whose channels the map does not carry, fail here,
    # before any task
    names = _model_names(one, check_channels=True)
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

    def arrived(outcome: Any) -> None:
        bar.update(1)
        bar.set_postfix_str(f"{Path(outcome.path).name}: {outcome.status}", refresh=False)

    try:
        res = fleet.run_fleet(
            functools.partial(job, one),
            expansion,
            Path(args.out),
            names,
            dask=settings,
            progress=arrived,
        )
    finally:
        bar.close()
    for o in res.outcomes:
        for line in o.messages:
            kind, sep, text = line.partition(": ")
            if kind in ("WARNING", "ERROR") and sep:
                print(f"{kind}: {o.path}: {text}", file=sys.stderr)
    for path, why in res.skipped:
        print(f"note: skipped {path}: {why}", file=sys.stderr)
    shown = res.table.drop(columns=["json"], errors="ignore")
    _out(shown.to_string(index=False, max_colwidth=48, float_format=lambda x: f"{x:.3f}"))
    counts: dict[str, int] = {}
    for o in res.outcomes:
        counts[o.status] = counts.get(o.status, 0) + 1
    told = ", ".join(f"{n} {status}" for status, n in counts.items())
    alarmed = sum(1 for o in res.outcomes if o.alarms())
    _out(
        f"{len(res.outcomes)} recording(s): {told}; {alarmed} with an alarm; "
        f"written to {Path(args.out).resolve()} (summary.csv, fleet.png, one JSON each)"
    )
    return res.code


def _model_names(args: argparse.Namespace, *, check_channels: bool = False) -> list[str]:
    """The names of the models of ``--model`` (loading them: bad ones fail here).

    ``check_channels``: also match their channels to the interface map's by name
    (:class:`~twotank_validation.online.channels.ChannelError` where they do not match).
    """
    from twotank_validation.core.model import load_model_document, model_from_dict  # noqa: PLC0415
    from twotank_validation.online.channels import match_channels  # noqa: PLC0415

    given = args.model if isinstance(args.model, list) else [args.model]
    models = [model_from_dict(*load_model_document(m)) for m in (given if given[0] else ["A", "B"])]
    if check_channels:
        cfg = _replay_config(args, TS_S, PERIOD_SAMPLES)
        imap = cfg.interface  # type: ignore[attr-defined]
        match_channels(imap.input_names, imap.output_names, models, source=imap.label)
    return [m.name for m in models]


def _stretches_text(recording: object) -> str:
    """One block per stretch: its span, the change that starts it, skipped windows, answers."""
    from twotank_validation.diagnose import stretches  # noqa: PLC0415

    assert isinstance(recording, stretches.RecordingDiagnosis)
    lines = []
    if not recording.segmented:
        lines.append("the range is taken as one stretch (no change search inside it)")
    elif len(recording.stretches) == 1 and not recording.changes:
        lines.append("no change found: the recording is one stationary stretch")
    for k, st in enumerate(recording.stretches):
        head = f"stretch {k + 1}: {st.stretch.start_s:.1f}-{st.stretch.end_s:.1f} s"
        if st.stretch.change_at_s is not None:
            head += (
                f", changed at {st.stretch.change_at_s:.1f} s (in the window starting "
                f"then): {st.stretch.evidence}"
            )
        lines.append(head)
        lines.append(f"  {len(st.window_starts_s)} window(s) diagnosed")
        lines += [f"  skipped {t:.1f} s: {why}" for t, why in st.skipped]
        if st.not_diagnosed:
            lines.append(f"  not diagnosed: {st.not_diagnosed}")
        if st.relative_to_model is not None:
            lines.append(f"  relative to the model: {st.relative_to_model.summary}")
        if st.relative_to_previous is not None:
            same = st.relative_to_previous is st.relative_to_model
            text = "the same (it needed nothing)" if same else st.relative_to_previous.summary
            lines.append(f"  relative to the stretch before: {text}")
    return "\n".join(lines)


def _cmd_record(args: argparse.Namespace) -> int:
    _loopback_only()
    from twotank_validation.ros.record import record  # noqa: PLC0415 (needs rclpy)

    counts = record(
        args.out, duration_s=args.duration, storage=args.storage, topics=_topic_map(args.topic)
    )
    print(f"wrote {args.out}: " + ", ".join(f"{t} {n}" for t, n in counts.items()))
    return 0


SIM_NOISE_SCALE = 0.5
"""Default noise of a simulated model (``simulate --model``, ``live --plant-model``), as a
fraction of what its noise weights admit: at 1 the noise alone uses the whole unit budget of
``w`` (the realised ``||w||`` scatters around 1), so the nominal's beta would sit at the
limit and a run of nominal data would raise alarms by chance."""


class UsageError(TwotankError, ValueError):
    """A command-line argument is not usable (the message says which)."""


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
    live.set_defaults(func=_cmd_live)
    _add_live_model_options(live)

    sim = command(
        "simulate",
        "simulate a scenario of the rig into a rosbag2 bag, or any model (--model) into a bag "
        "or a CSV table with its interface map",
    )
    sim.add_argument("--scenario", help="scenario YAML file or shipped name (e.g. nominal, leak)")
    sim.add_argument("--out", required=True, help="bag to write (must not exist)")
    sim.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap", help="bag storage")
    _add_simulate_model_options(sim)

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
    val.add_argument(
        "bags",
        nargs="+",
        metavar="BAG",
        help="rosbag2 directory (MCAP or SQLite3), a plain .mcap file, or a .csv/.parquet "
        "table (with --map of its columns); several, a directory of them or a glob: one "
        "task each, results in --out (docs/fleet.md)",
    )
    val.add_argument(
        "--model", action="append", help="model name or YAML path (repeat; default A and B)"
    )
    val.add_argument("--json", help="write the per-window results as JSON to this file")
    val.add_argument("--report", help="write figures (alarm timeline, windows of interest) here")
    val.add_argument(
        "--no-diagnosis",
        action="store_true",
        help="do not name the fault live once an alarm rises (the live diagnosis)",
    )
    _add_bag_options(val)
    val.set_defaults(func=_cmd_validate)

    dia = command(
        "diagnose", "trace a model's residual on a bag to the effect it lacks, add it, compare"
    )
    dia.add_argument(
        "bags",
        nargs="+",
        metavar="BAG",
        help="rosbag2 directory (MCAP or SQLite3), a plain .mcap file, or a .csv/.parquet "
        "table (with --map of its columns); several, a directory of them or a glob: one "
        "task each, results in --out (docs/fleet.md)",
    )
    dia.add_argument("--model", required=True, help="model name (A, B) or YAML path")
    dia.add_argument("--json", help="write the diagnosis as JSON to this file")
    dia.add_argument("--report", help="write the evidence figures to this folder")
    dia.add_argument("--out-model", help="write the changed model (YAML) to this file")
    dia.add_argument(
        "--max-effects", type=int, choices=[0, 1, 2], default=2, help="effects combined"
    )
    dia.add_argument(
        "--start",
        help="diagnose only the windows from this time: seconds from the recording start, or "
        "an ISO 8601 time (UTC unless it has a zone); None: from the start",
    )
    dia.add_argument(
        "--end", help="diagnose only the windows up to this time, as --start; None: to the end"
    )
    dia.add_argument(
        "--segment",
        action="store_true",
        help="search for changes inside the --start/--end range too (without a range the "
        "whole recording is always searched)",
    )
    _add_bag_options(dia)
    dia.set_defaults(func=_cmd_diagnose)
    _add_calibrate_parser(command)
    return parser


# --------------------------------------------------------------------------- calibrate


def _cmd_calibrate(args: argparse.Namespace) -> int:
    """``calibrate``: the smallest uncertainty the recording demands, and a fitted model."""
    import yaml  # noqa: PLC0415

    from twotank_validation import calibrate as cb  # noqa: PLC0415
    from twotank_validation import replay  # noqa: PLC0415
    from twotank_validation.core.model import load_model_document, model_from_dict  # noqa: PLC0415

    doc, source = load_model_document(args.model)
    model = model_from_dict(doc, source)
    cb.choose_blocks(model, args.block)  # an unknown block is an error before the replay
    config = cb.CalibrationConfig(margin=args.margin, max_order=args.max_order)
    cfg, timing = _timed_config(args)
    assert isinstance(cfg, replay.ReplayConfig)
    assert isinstance(timing, replay.Timing)
    windows, replayed = replay.windows_from_recording(args.bag, model, cfg)
    for problem in replayed.problems:
        print(f"WARNING: {problem}", file=sys.stderr)
    summary = replay.summary_json(replayed, [model.name])
    if unjudged := replay.unjudged_models(summary, timing, cfg):
        return _exit_code(replayed.complete, unjudged, timing)
    cal = cb.calibrate(
        windows, doc, config, blocks=args.block, source=source, convention=NormConvention(args.norm)
    )
    model_file = None
    if args.out_model:
        if cal.document is None:
            raise cb.CalibrationError(
                "no weight could be changed (see each block's note): no model file written"
            )
        Path(args.out_model).write_text(
            "# Written by twotank-validation calibrate; validate with --model this file.\n"
            + yaml.safe_dump(cal.document, sort_keys=False, width=100)
        )
        model_file = str(args.out_model)
    _out(cb.calibration_text(cal, model_file))
    if args.json:
        out = cal.to_json(model_file)
        out["timing"] = timing.to_json()
        Path(args.json).write_text(json.dumps(out, indent=2))
    if args.report:
        cb.write_calibration_report(cal, model, timing.ts_s, Path(args.report), model_file)
        _out(f"figures in {args.report}")
    return EXIT_OK if replayed.complete else EXIT_INCOMPLETE


def _add_calibrate_parser(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """The ``calibrate`` sub-command's arguments."""
    cal = command(
        "calibrate",
        "the smallest uncertainty weights a bag demands of a model, and a model file with "
        "fitted weights",
    )
    cal.add_argument(
        "bag",
        help="rosbag2 directory (MCAP or SQLite3), a plain .mcap file, or a .csv/.parquet "
        "table (with --map of its columns)",
    )
    cal.add_argument("--model", required=True, help="model name (A, B) or YAML path")
    cal.add_argument(
        "--block",
        action="append",
        help="a perturbation or noise block to calibrate, by its name (repeat, in order); "
        "None: every block",
    )
    cal.add_argument("--json", help="write the calibration as JSON to this file")
    cal.add_argument("--report", help="write the figures (beta, weights) to this folder")
    cal.add_argument("--out-model", help="write the calibrated model (YAML) to this file")
    cal.add_argument(
        "--margin", type=float, default=1.2, help="the new weights cover this x the requirement"
    )
    cal.add_argument("--max-order", type=int, default=2, help="largest order of a fitted weight")
    _add_bag_options(cal)
    cal.set_defaults(func=_cmd_calibrate)


def _option_settings() -> tuple[FlatSetting, ...]:
    """The settings that are options of the bag commands (the window and alarm options)."""
    from twotank_validation.online.validator_settings import VALIDATOR_SETTINGS  # noqa: PLC0415

    return tuple(s for s in VALIDATOR_SETTINGS if s.meta.option)


def option_dest(option: str) -> str:
    """The ``argparse`` destination of an option (``--settle-periods``: ``settle_periods``)."""
    return option.removeprefix("--").replace("-", "_")


def _add_setting_options(parser: argparse.ArgumentParser) -> None:
    """The window and alarm options, generated from the settings tree.

    One option per setting with an ``option`` name: default, choices, type and help are the
    setting's (``online/validator_settings.py``).
    """
    from twotank_validation.online.validator_settings import VALIDATOR_SETTINGS  # noqa: PLC0415

    defaults = {s.name: s.param_default for s in VALIDATOR_SETTINGS}
    for s in _option_settings():
        kwargs: dict[str, Any] = {"default": s.param_default}
        if s.meta.choices:
            kwargs["choices"] = s.meta.choices
        else:
            kwargs["type"] = s.kind
        parser.add_argument(
            s.meta.option, help=(s.meta.cli_help or s.meta.description).format(**defaults), **kwargs
        )


def _add_bag_options(val: argparse.ArgumentParser) -> None:
    """Topic, unit and window options shared by ``validate`` and ``diagnose``."""
    from twotank_validation.online.streams import RigUnits  # noqa: PLC0415

    units = RigUnits()
    val.add_argument(
        "--topic", action="append", help="remap: STREAM=TOPIC (flow_cmd, height, temperature)"
    )
    val.add_argument(
        "--map",
        help="interface map (YAML): each model input and output from its own topic, message "
        "type, field, stamp and unit conversion, or from a table's column (docs/interface.md); "
        "None: the two-tank topics",
    )
    val.add_argument(
        "--input",
        action="append",
        help="one input source instead of --map, in model input order (repeat): "
        "NAME=TOPIC:TYPE:FIELD[,scale=S][,offset=O][,stamp=receive], or for a table "
        "NAME=column:COLUMN[,scale=S][,offset=O]",
    )
    val.add_argument(
        "--output",
        action="append",
        help="one output source instead of --map, in model output order (repeat), as --input",
    )
    val.add_argument(
        "--time",
        help="a table's time column: COLUMN[,unit=auto|s|ms|us|ns|iso] (replaces the map's "
        "'time'); None: the map's, else the column named time, t or timestamp",
    )
    val.add_argument(
        "--ts",
        type=float,
        default=None,
        help="sample period of the recording (s); None: from the bag's metadata, else "
        "inferred from the command stamps (a table's time column) (said on stderr)",
    )
    val.add_argument(
        "--period",
        type=int,
        default=None,
        help="excitation period (samples); None: from the bag's metadata, else inferred "
        "from the commands' repetition (said on stderr)",
    )
    _add_setting_options(val)
    val.add_argument(
        "--closed-loop",
        action="store_true",
        help="the recording is of a plant under feedback control: its valve commands are not "
        "periodic, so the input periodicity gate is opened to 0.25 of their RMS (windows in "
        "which the loop moves the valves are left unjudged)",
    )
    val.add_argument(
        "--pascal-per-unit", type=float, default=units.pascal_per_unit, help="Pa per level unit"
    )
    val.add_argument(
        "--temperature-offset-c",
        type=float,
        default=units.temperature_offset_c,
        help="degC of model unit 0",
    )
    val.add_argument(
        "--temperature-span-c",
        type=float,
        default=units.temperature_span_c,
        help="degC per model unit",
    )
    val.add_argument("--quiet", action="store_true", help="no progress bar")
    fleet = val.add_argument_group("many recordings (docs/fleet.md)")
    fleet.add_argument(
        "--out",
        help="folder for one JSON per recording, summary.csv and fleet.png (needed with "
        "several recordings; with one, runs it as a fleet of one)",
    )
    fleet.add_argument(
        "--workers",
        type=int,
        default=None,
        help="processes of the local Dask cluster (one thread each); 0: in this process; "
        "None: one per core",
    )
    fleet.add_argument(
        "--serial", action="store_true", help="run in this process, without Dask (--workers 0)"
    )
    fleet.add_argument(
        "--scheduler",
        help="address of an existing Dask scheduler (tcp://HOST:PORT) to run the tasks on",
    )


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
