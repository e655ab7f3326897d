"""Scenario recordings: a simulated scenario streamed into a rosbag2 bag.

``write_scenario_bag`` runs a :class:`~twotank_validation.sim.scenario.Scenario` sample by
sample into a bag with the topics the validator subscribes to (``flow_cmd``, ``height``,
``temperature``), so that replaying the bag is the same experiment as running the nodes
live; ``simulate_command`` is the ``simulate`` command line on top of it.

A scenario with flow meters (``flow_meter_noise`` > 0) adds the topic ``flow_meter``
(FlowCommand: the meters' readings of the flows) and writes beside the bag the interface map
that reads the inputs from it as measured (``<out>.map.yaml``, :func:`metered_interface_map`).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

from tqdm import tqdm

from twotank_validation.bags.bag_errors import BagExistsError, BagWriteError
from twotank_validation.bags.writer import (
    STORAGES,
    BagWriter,
    flow_command,
    fluid_pressure,
    temperature_msg,
)
from twotank_validation.online.interface_map import InputKind, InterfaceMap
from twotank_validation.online.sources import Source
from twotank_validation.online.streams import (
    FLOW_CMD,
    FLOW_CMD_TYPE,
    HEIGHT,
    STREAM_TYPES,
    TEMPERATURE,
    two_tank_map,
)
from twotank_validation.sim.excitation import design_document, write_design
from twotank_validation.sim.model_record import interface_map_path, write_interface_map
from twotank_validation.sim.scenario import Scenario, ScenarioError, iter_metered, load_scenario

__all__ = [
    "CUSTOM_DATA_KEY",
    "FLOW_METER",
    "PROGRESS_MIN_SAMPLES",
    "TOPICS",
    "metered_interface_map",
    "simulate_command",
    "write_scenario_bag",
]

TOPICS: Final = dict(STREAM_TYPES)
"""Topics of a scenario bag and their message types (the validator's subscriptions)."""

PROGRESS_MIN_SAMPLES: Final = 20_000
"""``write_scenario_bag`` shows a progress bar above this many samples (stderr a TTY)."""

FLOW_METER: Final = "flow_meter"
"""Topic of the flow meters' readings (FlowCommand) in the bag of a scenario with meters."""

CUSTOM_DATA_KEY: Final = "twotank_validation.scenario"
"""Key of the scenario (JSON of ``Scenario.to_dict()``) in a scenario bag's custom_data."""


def metered_interface_map(scenario: Scenario, kind: InputKind = InputKind.MEASURED) -> InterfaceMap:
    """The map of a metered scenario's bag: the inputs from :data:`FLOW_METER`, of ``kind``.

    The outputs are the two-tank preset's (``two_tank_map(scenario.units)``); the inputs
    ``hot`` and ``cold`` read the meters' FlowCommand fields of the same names, marked
    ``kind`` (measured by default; commanded applies the strict periodicity gate).
    """
    preset = two_tank_map(scenario.units)
    return InterfaceMap(
        inputs=(
            Source("hot", FLOW_METER, FLOW_CMD_TYPE, "hot"),
            Source("cold", FLOW_METER, FLOW_CMD_TYPE, "cold"),
        ),
        outputs=preset.outputs,
        input_kinds=(kind, kind),
    )


def write_scenario_bag(
    scenario: Scenario,
    out: str | os.PathLike[str],
    storage: str = "mcap",
    *,
    progress: bool | None = None,
) -> Path:
    """Simulate the scenario into a new bag, streaming sample by sample.

    Topics (:data:`TOPICS`): ``flow_cmd`` (FlowCommand, model units), ``height``
    (FluidPressure, Pa), ``temperature`` (Temperature, °C), one message each per sample, all
    three of sample k with header stamp and log time k ts_s (the validator holds commands and
    matches measurements to the grid). With flow meters (``scenario.flow_meter_noise`` > 0)
    also :data:`FLOW_METER` (FlowCommand, the meters' readings, :func:`iter_metered`) and the
    map :func:`metered_interface_map` beside the bag (``<out>.map.yaml``). The scenario is
    stored as JSON under :data:`CUSTOM_DATA_KEY` in the bag's custom_data. If the run fails
    or is interrupted, the bag directory (created here) and its map are removed: a scenario
    bag is whole or absent.

    Args:
        scenario: The scenario.
        out: Bag directory to create; must not exist.
        storage: ``"mcap"`` or ``"sqlite3"``.
        progress: Show a progress bar; default: above PROGRESS_MIN_SAMPLES samples when
            stderr (where the bar goes) is a terminal.

    Returns:
        The bag directory.

    Raises:
        BagExistsError: If ``out`` exists.
        BagError: Unknown storage.
        ModelError: If the tank empties.
    """
    if not isinstance(scenario, Scenario):
        raise ScenarioError(f"scenario must be a Scenario, got {type(scenario).__name__}")
    n = scenario.n_samples
    if progress is None:
        progress = n > PROGRESS_MIN_SAMPLES and sys.stderr.isatty()
    units = scenario.units
    metered = scenario.flow_meter_noise > 0.0
    map_path = interface_map_path(out)
    if metered and (map_path.exists() or map_path.is_symlink()):
        raise BagExistsError(f"{map_path} exists already; choose another --out")
    bag = BagWriter(out, storage)  # raises before anything is created
    try:
        with bag:
            bag.set_custom_data(CUSTOM_DATA_KEY, json.dumps(scenario.to_dict()))
            for topic, msgtype in TOPICS.items():
                bag.add_topic(topic, msgtype)
            if metered:
                bag.add_topic(FLOW_METER, FLOW_CMD_TYPE)
            with tqdm(
                total=n,
                desc=f"bag {scenario.name}",
                unit="sample",
                disable=not progress,
                mininterval=0.5,
            ) as bar:
                for k, (stamp, hot, cold, height, temperature, hot_m, cold_m) in enumerate(
                    iter_metered(scenario)
                ):
                    bag.write(FLOW_CMD, stamp, flow_command(stamp, hot, cold))
                    if metered:
                        bag.write(FLOW_METER, stamp, flow_command(stamp, hot_m, cold_m))
                    bag.write(HEIGHT, stamp, fluid_pressure(stamp, height, units))
                    bag.write(TEMPERATURE, stamp, temperature_msg(stamp, temperature, units))
                    if k % 1000 == 999:
                        bar.update(1000)
                bar.update(n - bar.n)
        if metered:
            write_interface_map(metered_interface_map(scenario), map_path)
        design = scenario.design()
        if design.kind == "multisine" or design.realisations > 1:
            write_design(
                design_document(design, scenario.ts_s, 2, 0, max(design.realisation_periods, 1)),
                bag.path,
            )
    except BaseException:
        shutil.rmtree(bag.path, ignore_errors=True)
        if metered:
            map_path.unlink(missing_ok=True)
        raise
    return bag.path


def simulate_command(
    scenario: str,
    out: str,
    storage: str = "mcap",
    *,
    progress: bool | None = None,
    design: Mapping[str, Any] | None = None,
) -> Path:
    """``twotank-validation simulate --scenario FILE|NAME --out BAG [--storage ...]``.

    Loads the scenario (file or shipped name) and writes its bag (``progress`` as
    :func:`write_scenario_bag`'s). ``design``: excitation design settings by their flat names
    (``simulate``'s design options) in place of the scenario's (:meth:`Scenario.with_design`).

    Returns:
        The bag directory.

    Raises:
        TwotankError: ScenarioError / DatumError for a bad scenario, BagError for a bad
            storage, BagExistsError if ``out`` exists, ModelError if the tank empties.
    """
    if storage not in STORAGES:
        raise BagWriteError(f"--storage {storage!r} is not a bag storage; use one of {STORAGES}")
    if Path(out).exists() or Path(out).is_symlink():
        raise BagExistsError(
            f"{out} exists already; bags are never overwritten: choose another --out"
        )
    loaded = load_scenario(scenario)
    if design:
        loaded = loaded.with_design(design)
    return write_scenario_bag(loaded, out, storage, progress=progress)
