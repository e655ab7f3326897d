"""``simulate --model`` and ``live --plant-model``: any model's plant, from the command line.

The two-tank rig's ``simulate --scenario`` and ``live`` stay in :mod:`twotank_validation.cli`,
which hands them in as the fallbacks of these commands.
"""

from __future__ import annotations

import argparse
import functools
import os
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from twotank_validation.cli_common import Interrupts, LiveOutput, live_end, loopback_only
from twotank_validation.cli_options import option_dest
from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.errors import UsageError
from twotank_validation.settings import FlatSetting

if TYPE_CHECKING:
    from twotank_validation.sim.excitation import ExcitationDesign

__all__ = [
    "SIM_NOISE_SCALE",
    "add_design_options",
    "add_live_model_options",
    "add_simulate_model_options",
    "cmd_live_model",
    "cmd_simulate_model",
]

STRUCTURE_TS_S = 0.0025
"""``simulate --structure``'s default sample period (400 Hz; as ``StructureConfig``)."""
STRUCTURE_PERIOD = 1024
"""``simulate --structure``'s default excitation period (samples; as ``StructureConfig``)."""

SIM_NOISE_SCALE = 0.5
"""Default noise of a simulated model (``simulate --model``, ``live --plant-model``), as a
fraction of what its noise weights admit: at 1 the noise alone uses the whole unit budget of
``w`` (the realised ``||w||`` scatters around 1), so the nominal's beta would sit at the
limit and a run of nominal data would raise alarms by chance."""


# --------------------------------------------------------------------------- live --plant-model


def add_live_model_options(
    live: argparse.ArgumentParser, two_tank: Callable[[argparse.Namespace], int]
) -> None:
    """``live --plant-model FILE``'s options; the command then runs :func:`cmd_live_model`.

    Without ``--plant-model`` that runs ``two_tank`` (the rig's composition).
    """
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
    live.set_defaults(func=functools.partial(cmd_live_model, two_tank=two_tank))


def cmd_live_model(args: argparse.Namespace, two_tank: Callable[[argparse.Namespace], int]) -> int:
    """``live``: the two-tank rig, or any model's plant with ``--plant-model``."""
    if args.plant_model is None:
        if args.member != "nominal" or args.noise_scale != SIM_NOISE_SCALE:
            raise UsageError("--member and --noise-scale are for --plant-model")
        return two_tank(args)
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
    loopback_only()
    from twotank_validation.cli_options import evidence_params  # noqa: PLC0415
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
        validator=evidence_params(args),
    )

    import contextlib  # noqa: PLC0415 (here: the module's imports are shared by other commands)

    from twotank_validation.cli_view import live_view  # noqa: PLC0415

    output = LiveOutput(args.json)
    view, report = live_view(args, cfg.models or (args.plant_model,), output.report)
    with view or contextlib.nullcontext():
        with Interrupts() as interrupts:
            result = run_model_live(cfg, on_report=report, stop=interrupts)
        code = live_end(output, result, result.steps * cfg.ts_s, interrupts)
        if view is not None:
            view.hold(f"live run ended (exit code {code})")
    return code


# --------------------------------------------------------------------------- simulate --model


def add_simulate_model_options(
    sim: argparse.ArgumentParser, scenario: Callable[[argparse.Namespace], int]
) -> None:
    """``simulate --model FILE``'s options; the command then runs :func:`cmd_simulate_model`.

    With ``--scenario`` that runs ``scenario`` (the rig's scenario bag).
    """
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
        help="--model: a rosbag2 bag (one std_msgs/Float64 topic per channel) or a CSV table; "
        "the interface map is written beside it (<out>.map.yaml, <stem>.map.yaml for a "
        "table); default: csv when --out ends in .csv, else mcap",
    )
    group.add_argument(
        "--ts",
        type=float,
        default=None,
        help=f"--model, --structure: sample period (s); default {TS_S:g} (--model), "
        f"{STRUCTURE_TS_S:g} (--structure)",
    )
    group.add_argument(
        "--period",
        type=int,
        default=None,
        help=f"--model, --structure: excitation period (samples); default {PERIOD_SAMPLES} "
        f"(--model), {STRUCTURE_PERIOD} (--structure)",
    )
    group.add_argument(
        "--periods",
        type=int,
        default=2,
        help="--model, --structure: periods recorded after settling",
    )
    group.add_argument(
        "--settle-periods",
        type=int,
        default=None,
        help="--model, --structure: periods to let the transient die out first; default: as "
        "many as the plant needs (a structure's are not written)",
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
    group.add_argument("--seed", type=int, default=0, help="--model, --structure: excitation seed")
    group.add_argument(
        "--noise-scale",
        type=float,
        default=SIM_NOISE_SCALE,
        help="--model: noise as a fraction of what the model's noise weights admit "
        f"(default {SIM_NOISE_SCALE}: at 1 the noise alone uses the whole unit budget of w)",
    )
    group.add_argument("--noise-seed", type=int, default=0, help="--model, --structure: noise seed")
    group.add_argument(
        "--structure",
        type=float,
        metavar="FORCE_RMS_N",
        help="simulate the 3-mass chain with a cubic spring (docs/simulate.md) at this force "
        "RMS (N) instead of a scenario or a model; --out ends in .csv: the table, its map "
        "(the force kind: measured) and the linear model (<stem>.model.yaml) are written",
    )
    add_design_options(sim)
    sim.set_defaults(func=functools.partial(cmd_simulate_model, scenario=scenario))


DESIGN_BAND_OPTION = "--band"
"""``simulate``'s option for the multisine's band, ``F1..F2`` Hz: the design's ``f_min_hz``
and ``f_max_hz`` at once."""


def design_option_settings() -> tuple[FlatSetting, ...]:
    """The excitation design's settings that are ``simulate`` options (``--excitation`` ...)."""
    from twotank_validation.sim.excitation import ExcitationDesign  # noqa: PLC0415

    return tuple(s for s in ExcitationDesign.settings() if s.meta.option)


def add_design_options(sim: argparse.ArgumentParser) -> None:
    """``simulate``'s excitation design options, generated from ``ExcitationDesign``.

    Each defaults to None: the scenario's own setting, or ``--model``'s multisine over its
    first line .. ``0.2 / ts``; ``--period`` and ``--seed`` are the design's period and seed.
    """
    group = sim.add_argument_group(
        "excitation design (--scenario, --model; docs/identify.md, designing an experiment)"
    )
    for s in design_option_settings():
        kwargs: dict[str, Any] = {"default": None}
        if s.kind is bool:
            kwargs["action"] = "store_true"
        elif s.meta.choices:
            kwargs["choices"] = s.meta.choices
        else:
            kwargs["type"] = s.kind
        group.add_argument(s.meta.option, help=s.meta.description, **kwargs)
    group.add_argument(
        DESIGN_BAND_OPTION,
        metavar="F1..F2",
        help="multisine: the band of excited lines (Hz), its f_min_hz and f_max_hz",
    )


def design_values(args: argparse.Namespace) -> dict[str, Any]:
    """The design settings given on the command line, by their flat names.

    Raises:
        UsageError: a band not of the form ``F1..F2``.
    """
    values = {
        s.name: getattr(args, option_dest(s.meta.option))
        for s in design_option_settings()
        if getattr(args, option_dest(s.meta.option)) is not None
    }
    if args.band is not None:
        lo, sep, hi = str(args.band).partition("..")
        try:
            values["f_min_hz"], values["f_max_hz"] = float(lo), float(hi)
        except ValueError:
            sep = ""
        if not sep:
            raise UsageError(f"--band {args.band!r}: give F1..F2 in Hz, e.g. 0.002..0.05")
    return values


def model_design(args: argparse.Namespace, period_samples: int) -> ExcitationDesign | None:
    """``simulate --model``'s design: the options given over its default multisine.

    The default: a multisine over the first line .. 0.2 / ts. None when no design option is
    given (the short form, the same samples).

    Raises:
        UsageError: an invalid design (the message names the setting).
    """
    from twotank_validation.settings import from_flat  # noqa: PLC0415
    from twotank_validation.sim.excitation import ExcitationDesign  # noqa: PLC0415

    given = design_values(args)
    if not given:
        return None
    base = ExcitationDesign(
        kind="multisine",
        period_samples=period_samples,
        f_min_hz=0.0,
        f_max_hz=0.0,
        cutoff_hz=0.0,
        seed=args.seed,
    )
    try:
        return from_flat(ExcitationDesign, base.to_flat() | given)
    except ValueError as err:
        raise UsageError(f"excitation design: {err}") from err


def design_text(path: str | os.PathLike[str]) -> str | None:
    """One line on the design written beside a recording (lines, realisations, crest)."""
    from twotank_validation.sim.excitation import design_path, read_design  # noqa: PLC0415

    rec = read_design(path)
    if rec is None:
        return None
    d = rec.design
    parts = [f"excitation {d.kind}"]
    if rec.lines is not None:
        parts.append(
            f"{rec.lines.excited.size} excited line(s), {rec.lines.detection.size} detection "
            f"line(s), {rec.lines.even.size} even line(s) unexcited"
        )
    if d.realisations > 1:
        parts.append(f"{d.realisations} realisations of {rec.realisation_periods} periods")
    doc = yaml.safe_load(design_path(path).read_text())
    crest = doc.get("crest_factor", {})
    before, after = np.max(crest.get("random_phase", [[0]])), np.max(crest.get("applied", [[0]]))
    parts.append(f"crest factor {before:.3g} (random phase) -> {after:.3g} (applied)")
    return f"{', '.join(parts)}; written to {design_path(path)}"


def cmd_simulate_model(
    args: argparse.Namespace, scenario: Callable[[argparse.Namespace], int]
) -> int:
    """``simulate``: a scenario, any model or the structure (exactly one of the three)."""
    chosen = (
        ("--scenario", args.scenario),
        ("--model", args.model),
        ("--structure", args.structure),
    )
    given = [o for o, v in chosen if v is not None]
    if len(given) != 1:
        raise UsageError(
            "simulate needs exactly one of --scenario NAME (the two-tank rig), --model FILE "
            "(any model) and --structure FORCE_RMS_N (the 3-mass chain), found "
            + (" and ".join(given) if given else "none")
        )
    if args.scenario is not None:
        if args.format is not None or args.ts is not None or args.period is not None:
            raise UsageError(
                "--format, --ts and --period are for --model and --structure; a scenario's bag "
                "takes --storage and its own settings"
            )
        return scenario(args)
    if args.structure is not None:
        if design_values(args):
            raise UsageError(
                "the excitation design options are for --scenario and --model; --structure "
                "drives its chain with its own multisine"
            )
        return _simulate_structure(args)
    if args.storage != "mcap":
        raise UsageError("--storage is for --scenario; with --model give --format")
    from twotank_validation.bags.model_bag import simulate_model_command  # noqa: PLC0415
    from twotank_validation.sim.model_record import interface_map_path  # noqa: PLC0415

    period = PERIOD_SAMPLES if args.period is None else args.period
    table = str(args.out).lower().endswith(".csv")
    if table and args.format not in (None, "csv"):
        raise UsageError(
            f"--out {args.out} names a CSV table but --format is {args.format}: drop --format "
            "or give --out a bag directory name"
        )
    path = simulate_model_command(
        args.model,
        args.out,
        args.format or ("csv" if table else "mcap"),
        ts_s=TS_S if args.ts is None else args.ts,
        period_samples=period,
        periods=args.periods,
        settle_periods=args.settle_periods,
        rms=args.rms,
        offset=args.offset,
        seed=args.seed,
        design=model_design(args, period),
        member=args.member,
        noise_scale=args.noise_scale,
        noise_seed=args.noise_seed,
        faults=tuple(args.fault or ()),
    )
    print(f"wrote {path} and its interface map {interface_map_path(path)}")
    if text := design_text(path):
        print(text)
    return 0


def _simulate_structure(args: argparse.Namespace) -> int:
    """``simulate --structure FORCE_RMS_N --out RUN.csv``: the chain's recording."""
    other = [
        o
        for o, bad in (
            ("--storage", args.storage != "mcap"),
            ("--format", args.format not in (None, "csv")),
            ("--member", args.member != "nominal"),
            ("--fault", bool(args.fault)),
            ("--rms", args.rms != 0.1),
            ("--offset", args.offset != 0.0),
            ("--noise-scale", args.noise_scale != SIM_NOISE_SCALE),
        )
        if bad
    ]
    if other:
        raise UsageError(
            f"{', '.join(other)}: not for --structure (its level is FORCE_RMS_N, its noise "
            "fixed; it writes a CSV table)"
        )
    from twotank_validation.sim import structure  # noqa: PLC0415

    cfg = structure.StructureConfig(
        ts_s=STRUCTURE_TS_S if args.ts is None else args.ts,
        period_samples=STRUCTURE_PERIOD if args.period is None else args.period,
        periods=args.periods,
        settle_periods=args.settle_periods,
        force_rms_n=args.structure,
        seed=args.seed,
        noise_seed=args.noise_seed,
    )
    paths = structure.write_structure_recording(structure.simulate_structure(cfg), args.out)
    print(f"wrote {paths[0]}, its interface map {paths[1]} and the linear model {paths[2]}")
    return 0
