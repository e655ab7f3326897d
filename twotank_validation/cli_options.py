"""The options of the recording commands (``validate``, ``diagnose``, ``calibrate``).

Declared once here, the window and alarm options generated from the settings tree
(``online/validator_settings.py``), and read back into the use cases' typed
:class:`~twotank_validation.usecases.ReadSettings` (the interface map, the window settings,
``--ts`` and ``--period``). The command line (:mod:`twotank_validation.cli`) adds them to its
sub-commands and turns the parsed arguments into jobs.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from twotank_validation.core.noise_budget import NOISE_BUDGET, NOISE_QUANTILE
from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.errors import UsageError
from twotank_validation.online import MonitorConfig, interface
from twotank_validation.online.interface import InterfaceMap
from twotank_validation.online.streams import STREAMS, RigUnits, two_tank_map
from twotank_validation.online.validator_settings import VALIDATOR_SETTINGS
from twotank_validation.settings import FlatSetting, from_flat

if TYPE_CHECKING:
    from twotank_validation.replay import ReplayConfig
    from twotank_validation.usecases import ReadSettings


def topic_map(pairs: Sequence[str] | None) -> dict[str, str]:
    """Stream -> topic of the two-tank interface with the ``--topic STREAM=TOPIC`` remaps."""
    topics = {s: s for s in STREAMS}
    for pair in pairs or ():
        stream, sep, topic = pair.partition("=")
        if not sep or stream not in topics or not topic:
            raise UsageError(
                f"--topic expects STREAM=TOPIC with STREAM in {list(STREAMS)}, found {pair!r}"
            )
        topics[stream] = topic
    return topics


def _interface_map(args: argparse.Namespace, *, fleet: bool = False) -> InterfaceMap:
    """The interface map of ``--map`` or ``--input``/``--output``, else the two-tank preset.

    The preset takes ``--topic`` remaps and the unit options. ``--time`` gives a table's time
    column (it replaces the map file's ``time``).
    """
    texts = bool(args.input or args.output)
    if not (args.map or texts):
        if args.time is not None:
            raise UsageError(
                "--time names a table's time column; give the table's columns with --map FILE "
                "or --input/--output NAME=column:COLUMN"
            )
        units = RigUnits(args.pascal_per_unit, args.temperature_offset_c, args.temperature_span_c)
        return two_tank_map(units, topic_map(args.topic))
    if args.topic:
        raise UsageError(
            "--topic remaps the two-tank interface; with --map/--input/--output give the "
            "topics in the map instead"
        )
    if args.map and texts:
        raise UsageError("give the interface either as --map FILE or as --input/--output")
    if args.map:
        imap = interface.load_interface_map(absolute(args.map, fleet))
        if args.time is None:
            return imap
        return replace(imap, time=interface.time_column_from_text(args.time))
    if not (args.input and args.output):
        raise UsageError("--input and --output go together: give every input and every output")
    return interface.interface_map_from_text(args.input, args.output, args.time)


def _monitor(args: argparse.Namespace) -> MonitorConfig:
    """The window and alarm settings of the options (``--ts``/``--period`` or the defaults)."""
    from twotank_validation.sim.control import (  # noqa: PLC0415
        CLOSED_LOOP_INPUT_PERIODIC_RTOL,
        CLOSED_LOOP_TRANSIENT,
    )

    # the input periodicity gate: closed-loop data's with --closed-loop (theory.md §10)
    closed = getattr(args, "closed_loop", False)
    rtol = CLOSED_LOOP_INPUT_PERIODIC_RTOL if closed else None
    values = {s.name: getattr(args, option_dest(s.meta.option)) for s in _option_settings()}
    dests = given_options(args)
    given = {s.name for s in _option_settings() if option_dest(s.meta.option) in dests}
    if closed and "transient" not in given:  # theory.md §20
        values["transient"] = CLOSED_LOOP_TRANSIENT
    values |= {"ts_s": args.ts or TS_S, "period_samples": args.period or PERIOD_SAMPLES}
    try:
        return from_flat(
            MonitorConfig,
            values | {"input_periodic_rtol": rtol or MonitorConfig.input_periodic_rtol},
        )
    except ValueError as err:
        raise UsageError(str(err)) from err


def read_settings(args: argparse.Namespace, *, fleet: bool = False) -> ReadSettings:
    """How to read the recording: the map, the window settings, ``--ts`` and ``--period``."""
    from twotank_validation.usecases import ReadSettings  # noqa: PLC0415

    monitor = _monitor(args)
    return ReadSettings(_interface_map(args, fleet=fleet), monitor, args.ts, args.period)


def replay_config(args: argparse.Namespace, ts_s: float, period_samples: int) -> ReplayConfig:
    """The replay settings of the bag options with these periods."""
    return read_settings(args).replay_config(ts_s, period_samples)


def absolute(value: str, fleet: bool) -> str:
    """A fleet's task may run in another folder: an existing file's absolute path."""
    return os.path.abspath(value) if fleet and os.path.exists(value) else value


def check_fleet_options(args: argparse.Namespace) -> None:
    """The options of a fleet run that cannot be used (UsageError saying the fix)."""
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
    _check_tls_options(args)


TLS_OPTIONS = ("tls_ca_file", "tls_cert", "tls_key")


def _check_tls_options(args: argparse.Namespace) -> None:
    """--tls-ca-file/--tls-cert/--tls-key: a tls:// scheduler, both of the first two, files."""
    given = {o: getattr(args, o) for o in TLS_OPTIONS if getattr(args, o)}
    if not given:
        return
    if not (args.scheduler or "").startswith("tls://"):
        raise UsageError(
            "--tls-ca-file/--tls-cert/--tls-key are for a scheduler that speaks TLS: give its "
            "address as --scheduler tls://HOST:PORT"
        )
    if not (args.tls_ca_file and args.tls_cert):
        raise UsageError(
            "TLS needs --tls-ca-file CA (the authority that signed the scheduler's certificate) "
            "and --tls-cert CERT (this client's certificate; --tls-key KEY unless CERT holds it)"
        )
    for option, path in given.items():
        if not os.path.isfile(path):
            raise UsageError(f"--{option.replace('_', '-')} {path}: no such file")


def _option_settings() -> tuple[FlatSetting, ...]:
    """The settings that are options of the bag commands (the window and alarm options)."""
    return tuple(s for s in VALIDATOR_SETTINGS if s.meta.option and s.path[0] == "monitor")


def _evidence_settings() -> tuple[FlatSetting, ...]:
    """The evidence settings that are ``live`` options (``--evidence-dir`` ...)."""
    return tuple(s for s in VALIDATOR_SETTINGS if s.meta.option and s.path[0] == "evidence")


def add_evidence_options(parser: argparse.ArgumentParser) -> None:
    """``live``'s evidence options, generated from the settings tree (docs/ros.md)."""
    for s in _evidence_settings():
        parser.add_argument(
            s.meta.option, type=s.kind, default=s.param_default, help=s.meta.description
        )


def evidence_params(args: argparse.Namespace) -> dict[str, Any]:
    """The validator parameters of ``live``'s evidence options (by their flat names)."""
    return {s.name: getattr(args, option_dest(s.meta.option)) for s in _evidence_settings()}


def option_dest(option: str) -> str:
    """The ``argparse`` destination of an option (``--settle-periods``: ``settle_periods``)."""
    return option.removeprefix("--").replace("-", "_")


GIVEN_SETTINGS = "given_settings"
"""The attribute of the parsed options holding the destinations of the setting options given
on the command line."""


def given_options(args: argparse.Namespace) -> frozenset[str]:
    """The destinations of the setting options given on the command line."""
    return frozenset(getattr(args, GIVEN_SETTINGS, frozenset()))


class _SettingOption(argparse.Action):
    """Stores a setting's value and notes it as given (a default may depend on other options)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        setattr(namespace, self.dest, values)
        given: frozenset[str] = getattr(namespace, GIVEN_SETTINGS, frozenset())
        setattr(namespace, GIVEN_SETTINGS, given | {self.dest})


def _add_setting_options(parser: argparse.ArgumentParser) -> None:
    """The window and alarm options, generated from the settings tree.

    One option per setting with an ``option`` name: default, choices, type and help are the
    setting's (``online/validator_settings.py``).
    """
    defaults = {s.name: s.param_default for s in VALIDATOR_SETTINGS}
    for s in _option_settings():
        kwargs: dict[str, Any] = {"default": s.param_default, "action": _SettingOption}
        if s.meta.choices:
            kwargs["choices"] = s.meta.choices
        else:
            kwargs["type"] = s.kind
        parser.add_argument(
            s.meta.option, help=(s.meta.cli_help or s.meta.description).format(**defaults), **kwargs
        )


def add_recording_options(val: argparse.ArgumentParser) -> None:
    """Topic, unit and window options shared by ``validate`` and ``diagnose``."""
    units = RigUnits()
    val.add_argument(
        "--topic", action="append", help="remap: STREAM=TOPIC (flow_cmd, height, temperature)"
    )
    val.add_argument(
        "--map",
        help="interface map (YAML): each model input and output from its own topic, message "
        "type, field, stamp and unit conversion, or from a table's column (docs/interface.md); "
        "default: the two-tank topics",
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
        "'time'); default: the map's, else the column named time, t or timestamp",
    )
    val.add_argument(
        "--ts",
        type=float,
        default=None,
        help="sample period of the recording (s); default: from the bag's metadata, else "
        "inferred from the command stamps (a table's time column) (said on stderr)",
    )
    val.add_argument(
        "--period",
        type=int,
        default=None,
        help="excitation period (samples); default: from the bag's metadata, else inferred "
        "from the commands' repetition (said on stderr)",
    )
    _add_setting_options(val)
    val.add_argument(
        "--closed-loop",
        action="store_true",
        help="the recording is of a plant under feedback control: its valve commands are not "
        "periodic, so the input periodicity gate is opened to 0.25 of their RMS, and the "
        "windows in which the loop moves the valves are judged with the transient term "
        "(--transient auto unless --transient is given)",
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
        "default: one per core",
    )
    fleet.add_argument(
        "--serial", action="store_true", help="run in this process, without Dask (--workers 0)"
    )
    fleet.add_argument(
        "--scheduler",
        help="address of an existing Dask scheduler (tcp://HOST:PORT, or tls://HOST:PORT with "
        "the --tls-* files or Dask's TLS configuration) to run the tasks on",
    )
    fleet.add_argument(
        "--tls-ca-file",
        metavar="PEM",
        help="with --scheduler tls://: the CA certificate the scheduler's is checked against",
    )
    fleet.add_argument(
        "--tls-cert", metavar="PEM", help="with --scheduler tls://: this client's certificate"
    )
    fleet.add_argument(
        "--tls-key",
        metavar="PEM",
        help="with --scheduler tls://: this client's private key (unless --tls-cert holds it)",
    )


def add_validate_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``validate`` (a :class:`~twotank_validation.usecases.ValidateJob`)."""
    parser.add_argument(
        "bags",
        nargs="+",
        metavar="BAG",
        help="rosbag2 directory (MCAP or SQLite3), a plain .mcap file, or a .csv/.parquet "
        "table (with --map of its columns); several, a directory of them or a glob: one "
        "task each, results in --out (docs/fleet.md)",
    )
    parser.add_argument(
        "--model",
        action="append",
        help="model name or YAML path (repeat); default: the validator node's models, A and B "
        "(said on stderr)",
    )
    parser.add_argument(
        "--fail-on-alarm",
        action="store_true",
        help="exit 6 when a model's alarm rose (ERROR) on a judged window, for a pipeline; "
        "needs --model",
    )
    parser.add_argument("--json", help="write the per-window results as JSON to this file")
    parser.add_argument("--report", help="write figures (alarm timeline, windows of interest) here")
    parser.add_argument(
        "--no-diagnosis",
        action="store_true",
        help="do not name the fault live once an alarm rises (the live diagnosis)",
    )


def add_diagnose_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``diagnose`` (a :class:`~twotank_validation.usecases.DiagnoseJob`)."""
    parser.add_argument(
        "bags",
        nargs="+",
        metavar="BAG",
        help="rosbag2 directory (MCAP or SQLite3), a plain .mcap file, or a .csv/.parquet "
        "table (with --map of its columns); several, a directory of them or a glob: one "
        "task each, results in --out (docs/fleet.md)",
    )
    parser.add_argument("--model", required=True, help="model name (A, B) or YAML path")
    parser.add_argument("--json", help="write the diagnosis as JSON to this file")
    parser.add_argument("--report", help="write the evidence figures to this folder")
    parser.add_argument("--out-model", help="write the changed model (YAML) to this file")
    parser.add_argument(
        "--max-effects", type=int, choices=[0, 1, 2], default=2, help="effects combined"
    )
    parser.add_argument(
        "--start",
        help="diagnose only the windows from this time: seconds from the recording start, or "
        "an ISO 8601 time (UTC unless it has a zone); default: from the start",
    )
    parser.add_argument(
        "--end", help="diagnose only the windows up to this time, as --start; default: to the end"
    )
    parser.add_argument(
        "--segment",
        action="store_true",
        help="search for changes inside the --start/--end range too (without a range the "
        "whole recording is always searched)",
    )


def add_calibrate_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``calibrate`` (a :class:`~twotank_validation.usecases.CalibrateJob`)."""
    parser.add_argument(
        "bag",
        help="rosbag2 directory (MCAP or SQLite3), a plain .mcap file, or a .csv/.parquet "
        "table (with --map of its columns)",
    )
    parser.add_argument("--model", required=True, help="model name (A, B) or YAML path")
    parser.add_argument(
        "--block",
        action="append",
        help="a perturbation or noise block to calibrate, by its name (repeat, in order); "
        "default: every block",
    )
    parser.add_argument(
        "--together",
        action="store_true",
        help="scale the chosen blocks (--block, default all) together: the common factor and "
        "the smallest per-block factors that explain every window (written uniformly)",
    )
    parser.add_argument("--json", help="write the calibration as JSON to this file")
    parser.add_argument("--report", help="write the figures (beta, weights) to this folder")
    parser.add_argument("--out-model", help="write the calibrated model (YAML) to this file")
    parser.add_argument(
        "--margin", type=float, default=1.2, help="the new weights cover this x the requirement"
    )
    parser.add_argument("--max-order", type=int, default=2, help="largest order of a fitted weight")
    parser.add_argument(
        "--noise-from-data",
        action="store_true",
        help="set every output's noise weight from the period-to-period spread instead "
        "(flat, the outputs sharing one unit-norm w: the noise alone costs beta <= "
        "--noise-budget on --noise-quantile of windows; docs/calibrate.md)",
    )
    parser.add_argument(
        "--noise-budget",
        type=float,
        default=NOISE_BUDGET,
        help=f"with --noise-from-data: the beta the noise alone may cost (default {NOISE_BUDGET})",
    )
    parser.add_argument(
        "--noise-quantile",
        type=float,
        default=NOISE_QUANTILE,
        help="with --noise-from-data: the share of windows on which the noise alone costs at "
        f"most --noise-budget (default {NOISE_QUANTILE})",
    )


def add_identify_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``identify`` (a :class:`~twotank_validation.usecases.IdentifyJob`)."""
    parser.add_argument(
        "bag",
        help="rosbag2 directory (MCAP or SQLite3), a plain .mcap file, or a .csv/.parquet "
        "table (with --map of its columns) of a periodic experiment",
    )
    parser.add_argument(
        "--orders",
        default="1..8",
        help="the orders (states per input) tried, N or A..B; the MDL picks one (default 1..8)",
    )
    parser.add_argument(
        "--delays",
        action="store_true",
        help="fit a transport delay per output with the nominal (a process plant's dead time)",
    )
    parser.add_argument(
        "--grey-box",
        metavar="MODEL",
        help="fit this first-principles model's physical parameters (two-tank) to the "
        "response and take "
        "its linearisation as the nominal (two-tank: inputs hot, cold valve; outputs height, "
        "temperature; docs/identify.md)",
    )
    parser.add_argument("--name", default="identified", help="the identified model's name")
    parser.add_argument(
        "--start",
        help="use only the windows from this time: seconds from the recording start, or an "
        "ISO 8601 time; default: from the start",
    )
    parser.add_argument("--end", help="use only the windows up to this time, as --start")
    parser.add_argument("--json", help="write the identification as JSON to this file")
    parser.add_argument("--report", help="write the figures (Bode ± σ, fit, orders) here")
    parser.add_argument("--out-model", help="write the identified model set (YAML) here")
