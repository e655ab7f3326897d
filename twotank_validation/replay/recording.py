"""A recording opened once: a bag or a table, with its span and its metadata.

The timing (:func:`~twotank_validation.replay.timing.resolve_timing`) and the replay
(:func:`~twotank_validation.replay.feed.replay_recording`) both read the one
:class:`Recording`: a bag's reader stays open between them, a table is read once.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Self

import twotank_validation.bags as bag_reader
from twotank_validation import tables
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.replay.config import ReplayConfig, ReplayConfigError


@dataclass
class Recording:
    """A bag (its open reader) or a table (read), as :func:`open_recording` opened it.

    Attributes:
        given: the path as given (messages name it so).
        bag: the bag's reader (None: a table).
        table: the table, read through the map of its columns (None: a bag).
        read_s: wall time spent reading the table (s; 0 for a bag, read as it is replayed).
    """

    given: str | Path
    bag: bag_reader.BagReader | None = None
    table: tables.Table | None = None
    read_s: float = 0.0

    @property
    def path(self) -> Path:
        """The path."""
        return Path(self.given)

    @property
    def is_table(self) -> bool:
        """The recording is a table."""
        return self.table is not None

    @property
    def custom_data(self) -> dict[str, str]:
        """A bag's metadata strings (``custom_data``); a table has none."""
        return dict(self.bag.info.custom_data) if self.bag is not None else {}

    def close(self) -> None:
        """Release the bag's files (idempotent; nothing for a table)."""
        if self.bag is not None:
            self.bag.close()

    def __enter__(self) -> Self:
        """Return the recording itself."""
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Close the recording."""
        self.close()


def table_map(config: ReplayConfig | None, path: str | Path) -> InterfaceMap:
    """The map of columns a table is read through; else a ReplayConfigError with the fix."""
    imap = config.interface if config is not None else None
    if imap is None or not imap.is_table:
        given = "no interface map was given" if imap is None else f"{imap.label} reads topics"
        raise ReplayConfigError(
            f"{path} is a table (CSV/Parquet) but {given}; a table is read through a "
            "map of its columns: --map FILE with a 'column' per source and the time column "
            "(e.g. inputs: [{name: hot, column: valve_hot_pct, scale: 100}, ...], time: "
            "{column: t, unit: s}; docs/interface.md, Tables)"
        )
    return imap


def is_table_input(path: str | Path | Recording, config: ReplayConfig | None = None) -> bool:
    """The recording is read as a table: a table's suffix, or a map of columns."""
    if isinstance(path, Recording):
        return path.is_table
    return tables.is_table(path) or (config is not None and config.interface.is_table)


def open_recording(path: str | Path, config: ReplayConfig | None = None) -> Recording:
    """Open a bag or read a table (:func:`is_table_input`), once for timing and replay.

    Raises:
        BagNotFoundError, BagFormatError: the path is not a readable bag.
        TableError, ReplayConfigError: a table that cannot be read through the map (or there
            is no map of columns).
    """
    if is_table_input(path, config):
        start = time.perf_counter()
        table = tables.read_table(path, table_map(config, path))
        return Recording(path, table=table, read_s=time.perf_counter() - start)
    return Recording(path, bag=bag_reader.open_bag(path))
