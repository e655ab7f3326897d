"""The validator's settings tree: every setting of the node and the CLI's window options, once.

:class:`ValidatorSettings` is the root. Its nodes are the configs the code takes:
:class:`~twotank_validation.online.window.MonitorConfig` (windows, gates, solver; with
:class:`~twotank_validation.online.alarm.AlarmConfig` and
:class:`~twotank_validation.online.op_tracker.OpPointConfig`),
:class:`~twotank_validation.online.livediag.LiveDiagConfig`, and the alignment and node
settings kept here (jitter, oversampling, the stale timeout, the models). Each field is a
:func:`~twotank_validation.settings.setting` (default, unit, description, range, choices, its
parameter and option names) or a :func:`~twotank_validation.settings.group`; the validator
node's parameters (``ros/validator_node.py``) and the ``validate``/``diagnose``/``calibrate``
window options (``cli.py``) are generated from it, and ``test/test_settings.py`` checks that
the front ends and the docs agree with it.

The interface settings (units, the interface map, topics) are not in the tree: they belong to
the interface (:mod:`~twotank_validation.online.interface`).
"""

from __future__ import annotations

from dataclasses import dataclass

from twotank_validation.defaults import JITTER_FRACTION
from twotank_validation.online.livediag import LiveDiagConfig
from twotank_validation.online.window import MonitorConfig
from twotank_validation.settings import FlatSetting, check_settings, flat, group, setting


@dataclass(frozen=True)
class EvidenceConfig:
    """Evidence on an alarm: the data around a rising alarm written to a bag (docs/ros.md).

    Attributes:
        dir: directory of the evidence bags; empty: off.
        periods_before: excitation periods kept before the rise (the ring buffer).
        periods_after: periods written after the rise at most (the bag closes sooner, once
            the live diagnosis's first answer is in).
        max_bags: bags kept in ``dir`` (the oldest removed first).
        max_bag_mb: largest bag (MB); beyond it the bag is closed.
        queue: messages the writer thread may fall behind by; beyond, they are dropped.
    """

    dir: str = setting(
        "",
        "directory of the evidence bags written when a model's alarm rises (the periods "
        "before the rise and the windows after it); empty: off",
        option="--evidence-dir",
    )
    periods_before: int = setting(
        16,
        "excitation periods kept before the alarm's rise (at least settle_periods + "
        "periods_per_window, what diagnose needs for one window)",
        unit="periods",
        low=1,
        high=1000,
        option="--evidence-periods-before",
    )
    periods_after: int = setting(
        8,
        "excitation periods written after the alarm's rise at most (the bag closes sooner "
        "once the live diagnosis's first answer is in)",
        unit="periods",
        low=1,
        high=1000,
        option="--evidence-periods-after",
    )
    max_bags: int = setting(
        10,
        "evidence bags kept in evidence_dir; the oldest are removed",
        low=1,
        high=100000,
        option="--evidence-max-bags",
    )
    max_bag_mb: float = setting(
        64.0,
        "largest evidence bag (MB); the bag is closed when it reaches it",
        unit="MB",
        low=0.01,
        high=1e6,
        option="--evidence-max-mb",
    )
    queue: int = setting(
        65536,
        "messages the evidence writer thread may fall behind by; beyond, messages are "
        "dropped (never waited for) and /diagnostics says how many",
        low=16,
        high=10000000,
    )

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class ValidatorSettings:
    """Every setting of the online validator (the node's parameters, by their flat names).

    Attributes:
        models: the models validated: built-in names or YAML paths.
        monitor: windows, gates, solver, alarm and operating point.
        stale_timeout_s: a stream silent this long (ROS time) makes the status STALE.
        jitter_fraction: accepted stamp distance from the sample grid, fraction of ``ts_s``.
        diagnosis: name the fault live once a model's alarm is ERROR.
        live_diagnosis: the live diagnosis's settings (flat names ``diagnosis_...``).
        oversampling: topics published faster than ``ts_s``, ``TOPIC=N`` each.
        evidence: evidence on an alarm (flat names ``evidence_...``).
    """

    models: tuple[str, ...] = setting(
        ("A", "B"), "models to validate: built-in names (A, B) or YAML file paths"
    )
    monitor: MonitorConfig = group(MonitorConfig)
    stale_timeout_s: float = setting(
        2.0,
        "a stream silent this long (ROS time) makes the status STALE",
        unit="s",
        low=0.01,
        high=3600.0,
    )
    jitter_fraction: float = setting(
        JITTER_FRACTION,
        "accepted stamp distance from the sample grid, fraction of ts_s",
        low=0.0,
        high=0.49,
    )
    diagnosis: bool = setting(
        True,
        "name the fault live: once a model's alarm is ERROR, diagnose the windows after the "
        "onset against those before it and publish validation/M/diagnosis",
    )
    live_diagnosis: LiveDiagConfig = group(LiveDiagConfig, prefix="diagnosis_")
    oversampling: tuple[str, ...] = setting(
        (),
        "topics of the interface map published faster than ts_s, one TOPIC=N per entry (N "
        "messages per sample, decimated to the grid; the input topics share one N): e.g. "
        "flow_cmd=2 and height=2 with ts_s 0.2 for commands and level at 10 Hz, temperature "
        "at 5 Hz; empty: every topic at ts_s",
    )
    evidence: EvidenceConfig = group(EvidenceConfig, prefix="evidence_")

    def __post_init__(self) -> None:
        check_settings(self)


VALIDATOR_SETTINGS: tuple[FlatSetting, ...] = flat(ValidatorSettings)
"""The tree's settings, flat, in declaration order (the node declares them in this order)."""
