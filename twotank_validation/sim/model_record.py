"""A simulated model run as a table the validator reads, and the interface maps of its formats.

:func:`write_model_table` writes a :class:`~twotank_validation.sim.model_plant.ModelSimResult`
as a CSV table (pandas): a time column ``t`` in seconds and one column per channel, named as
the model names it, in model units; and beside it the interface map of that table
(:func:`table_interface_map`, written to :func:`interface_map_path`). The map of the same
channels as topics of a bag (``std_msgs/msg/Float64`` each) is :func:`bag_interface_map`;
the bag itself is written by :mod:`twotank_validation.bags.model_bag`.

Channel names become the map's source names, the columns and the topics, so they must be
valid source names (a letter, then letters, digits or ``_``) and no input may share its name
with an output.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Final

import numpy as np
import yaml

from twotank_validation.defaults import NS_PER_S
from twotank_validation.errors import DatumError
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.online.sources import STAMP_RECEIVE, InterfaceMapError, Source, TimeColumn
from twotank_validation.sim.excitation import design_document, write_design
from twotank_validation.sim.model_plant import ModelSimError, ModelSimResult

__all__ = [
    "CHANNEL_TYPE",
    "CHANNEL_TYPE_FIELD",
    "MAP_SUFFIX",
    "TIME_COLUMN",
    "bag_interface_map",
    "channel_topic",
    "check_channel_names",
    "interface_map_path",
    "table_interface_map",
    "write_interface_map",
    "write_model_table",
    "write_result_design",
]

CHANNEL_TYPE: Final = "std_msgs/msg/Float64"
"""Message type of every channel's topic (no header: stamped by the log or receive time)."""
CHANNEL_TYPE_FIELD: Final = "data"
"""Its field holding the value."""
TIME_COLUMN: Final = "t"
"""The table's time column, seconds since the start of the run."""
MAP_SUFFIX: Final = ".map.yaml"
"""Suffix of the interface map written beside a table or a bag."""


def check_channel_names(inputs: Sequence[str], outputs: Sequence[str]) -> None:
    """Check that the channel names can be a map's source names, columns and topics.

    Raises:
        ModelSimError: A name that is not a valid source name, or an input and an output of
            the same name (the message names it and the fix).
    """
    both = sorted(set(inputs) & set(outputs))
    if both:
        raise ModelSimError(
            f"the model names {both} both an input and an output; a recording needs one "
            "column or topic per channel: rename one of them in the model file"
        )
    if TIME_COLUMN in outputs or TIME_COLUMN in inputs:
        raise ModelSimError(
            f"a channel is named {TIME_COLUMN!r}, the name of the table's time column: rename it "
            "in the model file"
        )
    for name in (*inputs, *outputs):
        try:
            Source(name, column=name)
        except InterfaceMapError as err:
            raise ModelSimError(
                f"channel {name!r} cannot name a column or topic ({err}); rename it in the "
                "model file (a letter, then letters, digits or _)"
            ) from err


def channel_topic(name: str, prefix: str = "") -> str:
    """The topic of channel ``name``: ``prefix + name`` (e.g. ``plant/`` + ``y1``)."""
    return f"{prefix}{name}"


def table_interface_map(inputs: Sequence[str], outputs: Sequence[str]) -> InterfaceMap:
    """The map of a table written by :func:`write_model_table`: one column per channel.

    Args:
        inputs: The model's input names (order of u).
        outputs: The model's output names (order of y).

    Returns:
        Sources ``Source(name, column=name)`` (model units: offset 0, scale 1), time column
        :data:`TIME_COLUMN` in seconds.
    """
    check_channel_names(inputs, outputs)
    return InterfaceMap(
        tuple(Source(n, column=n) for n in inputs),
        tuple(Source(n, column=n) for n in outputs),
        TimeColumn(TIME_COLUMN, "s"),
    )


def bag_interface_map(
    inputs: Sequence[str], outputs: Sequence[str], prefix: str = ""
) -> InterfaceMap:
    """The map of a bag (or a live node) with one ``std_msgs/msg/Float64`` topic per channel.

    Args:
        inputs: The model's input names (order of u).
        outputs: The model's output names (order of y).
        prefix: Prepended to each name to make its topic (:func:`channel_topic`).

    Returns:
        Sources on topic ``prefix + name``, type :data:`CHANNEL_TYPE`, field ``data``,
        stamped by the receive (live) or log (bag) time, model units.
    """
    check_channel_names(inputs, outputs)

    def source(name: str) -> Source:
        return Source(
            name, channel_topic(name, prefix), CHANNEL_TYPE, CHANNEL_TYPE_FIELD, STAMP_RECEIVE
        )

    return InterfaceMap(tuple(source(n) for n in inputs), tuple(source(n) for n in outputs))


def interface_map_path(out: str | os.PathLike[str]) -> Path:
    """Where the map of a recording at ``out`` is written: beside it, ``<stem>.map.yaml``.

    ``run.csv`` -> ``run.map.yaml``; a bag directory ``run`` -> ``run.map.yaml``.
    """
    path = Path(out)
    stem = path.stem if path.suffix.lower() == ".csv" else path.name
    return path.with_name(stem + MAP_SUFFIX)


def write_interface_map(imap: InterfaceMap, path: str | os.PathLike[str]) -> Path:
    """Write ``imap.to_dict()`` as YAML to a new file ``path`` (never overwritten).

    Raises:
        ModelSimError: ``path`` exists.
    """
    path = Path(path)
    try:
        with path.open("x") as fh:
            yaml.safe_dump(imap.to_dict(), fh, sort_keys=False)
    except FileExistsError as err:
        raise ModelSimError(f"{path} exists already; choose another output name") from err
    return path


def write_model_table(result: ModelSimResult, out: str | os.PathLike[str]) -> Path:
    """Write a run as a CSV table and its interface map beside it.

    Columns: ``t`` (seconds, ``stamp_ns / 1e9``), then the inputs and the outputs by name,
    model units, each float as the shortest text that reads back to the same float.

    Args:
        result: The run.
        out: The ``.csv`` file to create; neither it nor its map
            (:func:`interface_map_path`) may exist.

    Returns:
        The CSV file.

    Raises:
        ModelSimError: ``out`` is not a ``.csv`` name, it or its map exists, or the channel
            names cannot be columns.
    """
    import pandas as pd  # noqa: PLC0415 (pandas only for writing tables)

    path = Path(out)
    if path.suffix.lower() != ".csv":
        raise ModelSimError(f"{path}: a table is written as CSV; give a name ending in .csv")
    map_path = interface_map_path(path)
    for p in (path, map_path):
        if p.exists() or p.is_symlink():
            raise ModelSimError(f"{p} exists already; recordings are never overwritten")
    imap = table_interface_map(result.input_names, result.output_names)
    columns: dict[str, np.ndarray] = {TIME_COLUMN: result.stamps_ns / NS_PER_S}
    columns |= {n: result.u[:, i] for i, n in enumerate(result.input_names)}
    columns |= {n: result.y[:, i] for i, n in enumerate(result.output_names)}
    frame = pd.DataFrame(columns)
    with path.open("x", newline="") as fh:
        frame.to_csv(fh, index=False)  # shortest text that reads back to the same float
    try:
        write_interface_map(imap, map_path)
        write_result_design(result, path)
    except BaseException:
        path.unlink(missing_ok=True)
        map_path.unlink(missing_ok=True)
        raise
    return path


def write_result_design(result: ModelSimResult, recording: str | os.PathLike[str]) -> Path:
    """Write the run's excitation design beside its recording (``<stem>.excitation.yaml``).

    The design, its lines (excited, detection, even), the crest factors and each
    realisation's settling and recorded periods
    (:func:`~twotank_validation.sim.excitation.design_document`): what ``validate`` and
    ``identify`` read back (:func:`~twotank_validation.sim.excitation.read_design`).

    Raises:
        ModelSimError: the file exists.
    """
    doc = design_document(
        result.config.excitation.the_design,
        result.ts_s,
        len(result.input_names),
        result.settle_periods,
        result.periods,
    )
    try:
        return write_design(doc, recording)
    except DatumError as err:
        raise ModelSimError(str(err)) from err
