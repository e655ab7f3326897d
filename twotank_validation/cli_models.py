"""``simulate --model`` and ``live --plant-model``: any model's plant, from the command line.

The two-tank rig's ``simulate --scenario`` and ``live`` stay in :mod:`twotank_validation.cli`,
which hands them in as the fallbacks of these commands.
"""

from __future__ import annotations

import argparse
import functools
from collections.abc import Callable

from twotank_validation.cli_common import Interrupts, LiveOutput, live_end, loopback_only
from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.errors import UsageError

__all__ = [
    "SIM_NOISE_SCALE",
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
        help="--model: a rosbag2 bag (one std_msgs/Float64 topic per channel) or a CSV table "
        "(--out ends in .csv); the interface map is written beside it (<out>.map.yaml, "
        "<stem>.map.yaml for a table); default: mcap",
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
    sim.set_defaults(func=functools.partial(cmd_simulate_model, scenario=scenario))


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
        return _simulate_structure(args)
    if args.storage != "mcap":
        raise UsageError("--storage is for --scenario; with --model give --format")
    from twotank_validation.bags.model_bag import simulate_model_command  # noqa: PLC0415
    from twotank_validation.sim.model_record import interface_map_path  # noqa: PLC0415

    path = simulate_model_command(
        args.model,
        args.out,
        args.format or "mcap",
        ts_s=TS_S if args.ts is None else args.ts,
        period_samples=PERIOD_SAMPLES if args.period is None else args.period,
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
