"""How a job reads a recording: the interface map, the window settings, the timing options.

:class:`ReadSettings` is what the command line's bag options (and a fleet's task) give; the
sample and excitation periods are resolved per recording (:func:`timed_config`: the option,
else the bag's metadata, else what the data show) from the recording opened once
(:func:`open_recording`), which the replay then reads.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from twotank_validation import replay
from twotank_validation.bags import BagEmptyError
from twotank_validation.core.band import parse_band
from twotank_validation.core.model import LFTModel, load_model_document, model_from_dict
from twotank_validation.errors import DatumError
from twotank_validation.online import MonitorConfig
from twotank_validation.online.channels import match_channels
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.online.streams import two_tank_map
from twotank_validation.replay import (
    Recording,
    ReplayConfig,
    Timing,
    is_table_input,
    resolve_timing,
)
from twotank_validation.sim.excitation import design_path, read_design
from twotank_validation.usecases.outcome import Level, Teller, UsageError


@dataclass(frozen=True)
class ReadSettings:
    """How to read a recording (picklable: a fleet ships it to its workers).

    Attributes:
        interface: the interface map of the recording's topics or columns.
        monitor: the window and alarm settings (``online/validator_settings.py``); its
            ``ts_s`` and ``period_samples`` are replaced by the resolved timing.
        ts_s: the sample period given by the user (s), None: resolved from the recording.
        period_samples: the excitation period given by the user (samples), None: resolved.
    """

    interface: InterfaceMap = field(default_factory=two_tank_map)
    monitor: MonitorConfig = field(default_factory=MonitorConfig)
    ts_s: float | None = None
    period_samples: int | None = None

    def replay_config(
        self, ts_s: float, period_samples: int, oversampling: Mapping[str, int] | None = None
    ) -> ReplayConfig:
        """The replay settings with these periods.

        Raises:
            UsageError: the settings do not hold with these periods (the message says which).
        """
        try:
            monitor = dataclasses.replace(self.monitor, ts_s=ts_s, period_samples=period_samples)
            return ReplayConfig(
                monitor=monitor, interface=self.interface, oversampling=dict(oversampling or {})
            )
        except ValueError as err:
            raise UsageError(str(err)) from err


def open_recording(read: ReadSettings, path: str) -> Recording:
    """The recording opened once (a bag's reader, a table read), for timing and replay.

    Raises:
        UsageError: a table without a map of its columns, or settings that do not hold.
        BagEmptyError: the file (a bag's every storage file) is empty.
        BagError subclasses, TableError: the recording cannot be read.
    """
    base = read.replay_config(read.monitor.ts_s, read.monitor.period_samples)
    if empty := empty_files(path):
        raise BagEmptyError(
            f"{empty[0]} is empty (0 bytes): there is nothing to read in it (a recorder stopped "
            "before writing anything?); give a recording that holds data"
        )
    if is_table_input(path, base) and not base.interface.is_table:
        raise UsageError(
            f"{path} is a table (CSV/Parquet): give the map of its columns with --map FILE "
            "(a 'column' per input and output, and the time column: docs/interface.md, "
            "Tables), or --input/--output NAME=column:COLUMN[,scale=S][,offset=O]"
        )
    return replay.open_recording(path, base)


def empty_files(path: str) -> list[Path]:
    """The recording's storage files if every one is empty (0 bytes), else ``[]``.

    A file given directly, or the ``.mcap``/``.db3`` files of a bag directory; an empty file
    holds nothing to read, whatever its suffix says.
    """
    p = Path(path)
    if p.is_file():
        files = [p]
    elif p.is_dir():
        files = sorted(f for f in p.iterdir() if f.suffix in (".mcap", ".db3") and f.is_file())
    else:
        return []
    return files if files and all(f.stat().st_size == 0 for f in files) else []


def timed_config(
    read: ReadSettings, recording: Recording, tell: Teller
) -> tuple[ReplayConfig, Timing]:
    """The replay settings with the sample and excitation periods resolved, and the timing.

    The options win; else the bag's metadata, else what the data show
    (``replay.resolve_timing``). What was taken is told as notes, contradictions as warnings.

    An excitation design written beside the recording (``simulate``'s
    ``<stem>.excitation.yaml``, :func:`with_recorded_design`) gives the periods where
    nothing else does and, for several realisations, the windows' realisation boundaries.

    Raises:
        UsageError: settings that do not hold with the periods resolved.
    """
    read = with_recorded_design(read, recording, tell)
    base = read.replay_config(read.monitor.ts_s, read.monitor.period_samples)
    timing = resolve_timing(recording, base, ts_s=read.ts_s, period_samples=read.period_samples)
    for note in timing.notes:
        tell(Level.NOTE, note)
    for conflict in timing.conflicts:
        tell(Level.WARNING, conflict)
    return read.replay_config(timing.ts_s, timing.period_samples, timing.oversampling), timing


def with_recorded_design(read: ReadSettings, recording: Recording, tell: Teller) -> ReadSettings:
    """``read`` with what the excitation design beside the recording says, where not given.

    The sample and excitation periods of a table (which has no metadata); with several
    realisations the monitor's ``realisation_periods`` and, where a window still fits after
    it, each realisation's settling as the windows' settling periods. Nothing that the user
    gave is replaced.

    Raises:
        UsageError: the design file is there but cannot be read.
    """
    try:
        rec = read_design(recording.given)
    except DatumError as err:
        raise UsageError(str(err)) from err
    if rec is None:
        return read
    changes: dict[str, object] = {}
    if recording.table is not None and (read.ts_s is None or read.period_samples is None):
        # a table has no metadata: the design's periods, unless given (a bag's metadata wins)
        if read.ts_s is None:
            changes["ts_s"] = rec.ts_s
        if read.period_samples is None:
            changes["period_samples"] = rec.design.period_samples
        tell(
            Level.NOTE,
            f"sample period {rec.ts_s:g} s and period {rec.design.period_samples} from the "
            f"excitation design {design_path(recording.given)} (--ts, --period override)",
        )
    monitor = read.monitor
    if rec.design.realisations > 1 and not monitor.realisation_periods:
        settle = monitor.settle_periods
        if rec.settle_periods + monitor.periods_per_window <= rec.realisation_periods:
            settle = min(max(settle, rec.settle_periods), 64)
        monitor = dataclasses.replace(
            monitor, realisation_periods=rec.realisation_periods, settle_periods=settle
        )
        changes["monitor"] = monitor
        tell(
            Level.NOTE,
            f"excitation design {design_path(recording.given)}: {rec.design.realisations} "
            f"realisations of {rec.realisation_periods} periods; windows lie within one, "
            f"after {settle} settling period(s) (--realisation-periods, --settle-periods "
            "override)",
        )
    return dataclasses.replace(read, **changes) if changes else read  # type: ignore[arg-type]


@dataclass(frozen=True)
class LoadedModel:
    """A model as every layer uses it: the model, its document and where it came from."""

    model: LFTModel
    document: Mapping[str, object]
    source: str


def load(source: str | Path) -> LoadedModel:
    """A model file or built-in model, with its document.

    Raises:
        ModelFileError, ModelError: the file cannot be read or is not a model.
    """
    doc, label = load_model_document(source)
    return LoadedModel(model_from_dict(doc, label), doc, label)


def banded(loaded: LoadedModel, band: str) -> LoadedModel:
    """``loaded`` with ``band`` (``--band``) in place of its file's band, model and document.

    ``band`` empty: ``loaded`` as it is. The document carries the band too, so that a model
    file written from it (``calibrate``) claims the band it was calibrated over.

    Raises:
        ModelError: a band that does not parse.
    """
    if not band:
        return loaded
    parsed = parse_band(band)
    doc = {k: v for k, v in loaded.document.items() if k != "band"}
    if parsed is not None:
        doc["band"] = parsed.to_dict()
    return LoadedModel(dataclasses.replace(loaded.model, band=parsed), doc, loaded.source)


def model_names(sources: Sequence[str], read: ReadSettings | None = None) -> list[str]:
    """The names of the models (loading them: bad ones fail here).

    ``read``: also match their channels to the interface map's by name
    (:class:`~twotank_validation.online.channels.ChannelError` where they do not match).
    """
    models = [load(s).model for s in sources]
    if read is not None:
        imap = read.interface
        match_channels(imap.input_names, imap.output_names, models, source=imap.label)
    return [m.name for m in models]
