"""How a recording is replayed (:class:`ReplayConfig`) and what it found (:class:`ReplayResult`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from twotank_validation.core.model import LFTModel, load_model_document
from twotank_validation.defaults import JITTER_FRACTION
from twotank_validation.diagnose.live_jobs import catalogue_diagnosis
from twotank_validation.errors import Interrupted, ModelError, TwotankError
from twotank_validation.online import MonitorConfig, OnlineValidator, WindowReport
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.online.livediag import LiveDiagConfig, LiveDiagnoser
from twotank_validation.online.streams import two_tank_map


@dataclass(frozen=True)
class ReplayConfig:
    """How to read a recording.

    Attributes:
        monitor: validator settings (as the node's parameters).
        interface: the interface map (:mod:`twotank_validation.online.interface`): each input
            and output channel read from its own topic, type, field and stamp (a bag; the
            messages are decoded from the definitions stored in the bag) or from a table's
            column, with its unit conversion; the channels are matched to the models' by
            name. Default: the two-tank preset
            (:func:`~twotank_validation.online.streams.two_tank_map`; None gives it too). A
            table (:func:`replay_table`) needs a map of columns.
        jitter_fraction: accepted stamp distance from the sample grid (fraction of ts).
        oversampling: messages per sample of topics (a table: channels) published faster
            than ``monitor.ts_s`` (name -> whole number; :attr:`Timing.oversampling`): they
            are decimated to the sample grid.
        diagnosis: run the live diagnosis (:mod:`~twotank_validation.online.livediag`):
            once a model's alarm rises, each report carries the most likely effect in force
            (``WindowReport.diagnosis``), computed synchronously, as the node's answers.
        documents: model name -> model document for the diagnosis; a model not named is
            loaded by its name (the built-in models); a model with neither is an error
            (:func:`model_documents`).
        diagnosis_config: the live diagnosis's settings.
    """

    monitor: MonitorConfig = field(default_factory=MonitorConfig)
    interface: InterfaceMap = field(default_factory=two_tank_map)
    jitter_fraction: float = JITTER_FRACTION
    oversampling: Mapping[str, int] = field(default_factory=dict)
    diagnosis: bool = False
    documents: Mapping[str, Any] = field(default_factory=dict)
    diagnosis_config: LiveDiagConfig = field(default_factory=LiveDiagConfig)

    def __post_init__(self) -> None:
        given: object = self.interface
        if given is None:  # None: the preset
            object.__setattr__(self, "interface", two_tank_map())
        elif not isinstance(given, InterfaceMap):
            raise ReplayConfigError(
                f"interface: expected an InterfaceMap, found {type(given).__name__}"
            )

    def validator(self, models: Sequence[LFTModel]) -> OnlineValidator:
        """The online validator these settings describe (the one path of every replay)."""
        return OnlineValidator(
            self.monitor,
            models,
            interface=self.interface,
            jitter_fraction=self.jitter_fraction,
            oversampling=self.oversampling,
            diagnoser=self.diagnoser(models) if self.diagnosis else None,
        )

    def diagnoser(self, models: Sequence[LFTModel]) -> LiveDiagnoser:
        """The synchronous live diagnoser of these models (their documents, see ``documents``)."""
        docs = model_documents(models, self.documents)
        cfg = dataclasses.replace(self.diagnosis_config, models=tuple(docs))
        return LiveDiagnoser(catalogue_diagnosis(docs, convention=self.monitor.convention), cfg)


def model_documents(
    models: Sequence[LFTModel], given: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Model name -> document: the given ones, else the built-in model of that name.

    Raises:
        ModelError: a model whose document was not given and that is no built-in model (the
            message names it and how to give its file).
    """
    out: dict[str, Any] = {}
    for m in models:
        if given and m.name in given:
            out[m.name] = given[m.name]
            continue
        try:
            out[m.name] = load_model_document(m.name)[0]
        except (TwotankError, OSError) as err:
            raise ModelError(
                f"model {m.name!r}: the live diagnosis needs the model's document, which was "
                "not given, and it is no built-in model; give its YAML file (--model FILE, the "
                "node's models parameter) or its document (ReplayConfig.documents, "
                "ValidatorNode(documents=...)), or turn the diagnosis off (--no-diagnosis)"
            ) from err
    return out


class TimeBase(StrEnum):
    """The clock a recording's windows are timed by; the value is how outputs name it.

    Chosen by :func:`~twotank_validation.replay.timebase.stamp_base` for a bag.
    """

    HEADER = "header stamps"
    """Every source is stamped by its message's ``header.stamp``."""
    LOG = "log times"
    """Every source is stamped by the time the recorder logged its message."""
    HEADER_AND_LOG = "header stamps and log times"
    """The map mixes the two, and in this bag they agree (within the grid's jitter band)."""
    TIME_COLUMN = "time column"
    """A table: its time column."""


class ReplayConfigError(TwotankError, ValueError):
    """A replay setting cannot be used as given (the message says what to change)."""


@dataclass(frozen=True)
class WindowSnapshot:
    """Samples of one window kept for figures: stamps (n,), u (n, nu), y (n, ny).

    ``measured``: (nu,) bool, the inputs the interface map marks measured (None: every input
    commanded), for a datum built as the validator built it.
    """

    report: WindowReport
    stamps_ns: np.ndarray
    u: np.ndarray
    y: np.ndarray
    measured: np.ndarray | None = None


@dataclass
class ReplayResult:
    """Everything a replay found.

    Attributes:
        path: the bag or the table.
        reports: window reports in order (all models).
        complete: the whole bag was read and every expected topic was present.
        problems: what made the run incomplete or what was refused, in words (the input
            faults in the live node's words).
        counters: aligner counters (duplicates, out of order, gaps, ...).
        messages: messages read (a table: rows read).
        decode_s: wall time spent reading and decoding.
        validate_s: wall time spent aligning and validating.
        bag_start_ns: the first stamp in the recording's time base (``time_base``): a bag's
            first header stamp or first log time, a table's first time (reports' times are
            relative to it in JSON).
        snapshots: windows of interest per model.
        source: ``"bag"`` or ``"table"``.
        end_ns: the last stamp in the time base, or a table's last time (0: not known).
        time_base: the clock the windows are timed by.
        interrupted: the replay was stopped by a signal (:class:`ReplayInterrupted`); the
            reports are those judged before it (``complete`` is then False).
    """

    path: Path
    reports: list[WindowReport] = field(default_factory=list)
    complete: bool = True
    problems: list[str] = field(default_factory=list)
    counters: dict[str, int] = field(default_factory=dict)
    messages: int = 0
    decode_s: float = 0.0
    validate_s: float = 0.0
    bag_start_ns: int = 0
    snapshots: dict[str, dict[str, WindowSnapshot]] = field(default_factory=dict)
    source: str = "bag"
    end_ns: int = 0
    interrupted: bool = False
    time_base: TimeBase = TimeBase.HEADER


class ReplayInterrupted(Interrupted):
    """A replay stopped by SIGINT or SIGTERM: ``result`` holds what was judged before it.

    A ``KeyboardInterrupt`` (an :class:`~twotank_validation.errors.Interrupted`), so that an
    interrupt still stops whoever does not look at the partial result.

    Attributes:
        result: the replay up to the interrupt (``interrupted`` True, ``complete`` False).
    """

    def __init__(self, result: ReplayResult, signum: int) -> None:
        super().__init__(signum)
        self.result = result
