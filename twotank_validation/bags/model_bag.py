"""A simulated model run written into a rosbag2 bag, and the ``simulate --model`` command.

:func:`write_model_bag` writes a :class:`~twotank_validation.sim.model_plant.ModelSimResult`
into a bag (MCAP by default) with one ``std_msgs/msg/Float64`` topic per channel (inputs and
outputs, named as the model names them), each message logged at its sample's stamp, and the
interface map of the bag beside it
(:func:`~twotank_validation.sim.model_record.bag_interface_map`, the sources stamped by the log
time). :func:`simulate_model_command` is what the command line calls: a model file in, a bag or
a CSV table (:func:`~twotank_validation.sim.model_record.write_model_table`) and its map out.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

from twotank_validation.bags.bag_errors import BagExistsError, BagWriteError
from twotank_validation.bags.writer import STORAGES, BagWriter
from twotank_validation.core.model import LFTModel, load_model
from twotank_validation.defaults import PERIOD_SAMPLES, TS_S
from twotank_validation.sim.excitation import ExcitationDesign
from twotank_validation.sim.model_plant import (
    ModelExcitation,
    ModelFault,
    ModelSimConfig,
    ModelSimError,
    ModelSimResult,
    format_member,
    format_model_fault,
    parse_member,
    parse_model_fault,
    simulate_model,
)
from twotank_validation.sim.model_record import (
    CHANNEL_TYPE,
    bag_interface_map,
    channel_topic,
    interface_map_path,
    write_interface_map,
    write_model_table,
    write_result_design,
)

__all__ = ["CUSTOM_DATA_KEY", "FORMATS", "simulate_model_command", "write_model_bag"]

FORMATS: Final = (*STORAGES, "csv")
"""Output formats of :func:`simulate_model_command`: a rosbag2 bag (two storages) or a CSV."""

CUSTOM_DATA_KEY: Final = "twotank_validation.model_sim"
"""Key of the run's settings (JSON) in a model bag's custom_data."""


def run_settings(result: ModelSimResult) -> dict[str, Any]:
    """The settings of a run as plain data (for a bag's custom_data)."""
    cfg = result.config
    exc = cfg.excitation
    return {
        "model": cfg.model.name,
        "inputs": list(result.input_names),
        "outputs": list(result.output_names),
        "ts_s": cfg.ts_s,
        "period_samples": cfg.period_samples,
        "settle_periods": result.settle_periods,
        "periods": result.periods,
        "excitation": {
            "kind": exc.kind,
            "rms": list(cfg.rms),
            "offset": list(cfg.offset),
            "band_hz": list(exc.band(cfg.ts_s)),
            "odd_only": exc.odd_only,
            "order": exc.order,
            "seed": exc.seed,
            "design": exc.the_design.to_flat(),
        },
        "member": format_member(cfg.member),
        "noise_scale": cfg.noise_scale,
        "noise_seed": cfg.noise_seed,
        "faults": [format_model_fault(f) for f in cfg.faults],
    }


def write_model_bag(
    result: ModelSimResult,
    out: str | os.PathLike[str],
    storage: str = "mcap",
    *,
    prefix: str = "",
) -> Path:
    """Write a run into a new bag, and its interface map beside it.

    Topics ``prefix + name`` of type ``std_msgs/msg/Float64``, one per input then output;
    sample k's messages are logged at ``stamps_ns[k]`` (the map's sources use
    ``stamp: receive``, the log time). The settings are stored as JSON under
    :data:`CUSTOM_DATA_KEY`. If writing fails, the bag directory and the map are removed.

    Args:
        result: The run.
        out: Bag directory to create; neither it nor its map
            (:func:`~twotank_validation.sim.model_record.interface_map_path`) may exist.
        storage: ``"mcap"`` or ``"sqlite3"``.
        prefix: Topic prefix, e.g. ``"plant/"``.

    Returns:
        The bag directory.

    Raises:
        BagExistsError: ``out`` exists.
        ModelSimError: The map exists, or the channel names cannot be topics.
        BagError: Unknown storage.
    """
    imap = bag_interface_map(result.input_names, result.output_names, prefix)
    map_path = interface_map_path(out)
    if map_path.exists() or map_path.is_symlink():
        raise ModelSimError(f"{map_path} exists already; recordings are never overwritten")
    bag = BagWriter(out, storage)
    try:
        with bag:
            bag.set_custom_data(CUSTOM_DATA_KEY, json.dumps(run_settings(result)))
            names = (*result.input_names, *result.output_names)
            topics = [channel_topic(n, prefix) for n in names]
            for topic in topics:
                bag.add_topic(topic, CHANNEL_TYPE)
            msg_cls = bag.typestore.types[CHANNEL_TYPE]
            for k, stamp in enumerate(result.stamps_ns.tolist()):
                row = (*result.u[k].tolist(), *result.y[k].tolist())
                for j, topic in enumerate(topics):
                    bag.write(topic, stamp, msg_cls(data=row[j]))
        write_interface_map(imap, map_path)
        write_result_design(result, bag.path)
    except BaseException:
        shutil.rmtree(bag.path, ignore_errors=True)
        map_path.unlink(missing_ok=True)
        raise
    return bag.path


def simulate_model_command(
    model_path: str | os.PathLike[str] | LFTModel,
    out: str | os.PathLike[str],
    fmt: str = "mcap",
    *,
    ts_s: float = TS_S,
    period_samples: int = PERIOD_SAMPLES,
    periods: int = 2,
    settle_periods: int | None = None,
    kind: str = "multisine",
    rms: float | Sequence[float] | Mapping[str, float] = 0.1,
    offset: float | Sequence[float] | Mapping[str, float] = 0.0,
    f_min_hz: float | None = None,
    f_max_hz: float | None = None,
    cutoff_hz: float | None = None,
    odd_only: bool = False,
    seed: int = 0,
    design: ExcitationDesign | None = None,
    member: str = "nominal",
    noise_scale: float = 1.0,
    noise_seed: int = 0,
    faults: Sequence[str | ModelFault] = (),
    prefix: str = "",
) -> Path:
    """``twotank-validation simulate --model FILE --out PATH [--format mcap|sqlite3|csv] ...``.

    Loads the model (a YAML file or a built-in name), simulates it
    (:func:`~twotank_validation.sim.model_plant.simulate_model`) and writes a bag or a CSV
    table with its interface map beside it
    (:func:`~twotank_validation.sim.model_record.interface_map_path`).

    Args:
        model_path: Model file, built-in name, or a loaded model.
        out: Bag directory (``mcap``, ``sqlite3``) or ``.csv`` file (``csv``) to create.
        fmt: One of :data:`FORMATS`.
        ts_s: Sample period, s.
        period_samples: Excitation period, samples.
        periods: Periods after settling.
        settle_periods: Settling periods (None: automatic).
        kind: ``multisine`` or ``filtered_noise``.
        rms: RMS per input (one for all, a list, or name -> RMS).
        offset: Operating point per input (same forms).
        f_min_hz: Multisine band's low edge (None: the first harmonic).
        f_max_hz: Multisine band's high edge (None: 0.2 / ts_s).
        cutoff_hz: Filtered noise cutoff (None: 0.2 / ts_s).
        odd_only: Multisine on odd harmonics only.
        seed: Excitation seed.
        design: The whole excitation design (replaces ``kind`` .. ``seed`` and
            ``period_samples``); written beside the recording
            (:func:`~twotank_validation.sim.excitation.design_path`) with its lines.
        member: Member text (:func:`~twotank_validation.sim.model_plant.parse_member`).
        noise_scale: Noise as a fraction of what the model's weights admit.
        noise_seed: Noise seed.
        faults: Fault specs ``KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S]``.
        prefix: Topic prefix (bags).

    Returns:
        The bag directory or the CSV file.

    Raises:
        TwotankError: ModelFileError for a bad model file, ModelSimError for bad settings
            (unknown channel, NaN, a period that is not a whole number of samples, an
            existing map), UnstableModelError, BagExistsError if ``out`` exists, BagError.
    """
    if fmt not in FORMATS:
        raise BagWriteError(f"--format {fmt!r} is not an output format; use one of {FORMATS}")
    if Path(out).exists() or Path(out).is_symlink():
        raise BagExistsError(
            f"{out} exists already; recordings are never overwritten: choose another --out"
        )
    if isinstance(model_path, LFTModel):
        model = model_path
    else:
        model = load_model(model_path if isinstance(model_path, str) else Path(model_path))
    config = ModelSimConfig(
        model=model,
        ts_s=ts_s,
        excitation=ModelExcitation(
            kind=kind,
            period_samples=period_samples,
            rms=rms,
            offset=offset,
            f_min_hz=f_min_hz,
            f_max_hz=f_max_hz,
            cutoff_hz=cutoff_hz,
            odd_only=odd_only,
            seed=seed,
        )
        if design is None
        else ModelExcitation(rms=rms, offset=offset, design=design),
        periods=periods,
        settle_periods=settle_periods,
        member=parse_member(member),
        noise_scale=noise_scale,
        noise_seed=noise_seed,
        faults=tuple(f if isinstance(f, ModelFault) else parse_model_fault(f) for f in faults),
    )
    result = simulate_model(config)
    if fmt == "csv":
        return write_model_table(result, out)
    return write_model_bag(result, out, fmt, prefix=prefix)
