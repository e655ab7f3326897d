"""Tables: CSV and Parquet logs of a PLC or historian, read through an interface map.

Many rigs log to a table, not to a bag: a time column and one column per signal, in the
rig's units. :func:`read_table` reads such a file through an interface map whose sources
name columns (:mod:`twotank_validation.online.interface`: ``{name: hot, column:
valve_hot_pct, scale: 100}``, the time column in the map's ``time``) and returns the rows in
time order: stamps in integer nanoseconds and the mapped columns in model units, converted
with the same float operations as a bag's values (``(raw - offset) / scale``,
:func:`~twotank_validation.online.interface.convert`). Replay feeds them to the online
validator row by row (:func:`twotank_validation.replay.replay_table`).

CSV goes through pandas' C parser (``pd.read_csv``; a float written with ``repr`` reads back
as the same float, which ``test/test_tables.py`` checks); Parquet through pyarrow
(``pd.read_parquet``), whose float64 columns are the floats written. A cell that is empty
or not a number is kept as NaN: the aligner flags its sample, which the validator recovers
from the other periods when there are few, else the windows holding it are not judged, with
the reason. A time stamp that cannot be read is an error (a row without a
time has no place on the grid).
pandas is imported on first use. Nothing here imports ROS.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from twotank_validation.defaults import NS_PER_S
from twotank_validation.errors import TwotankError
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.online.sources import TIME_COLUMNS, Source, TimeColumn, convert

__all__ = [
    "CSV_SUFFIXES",
    "PARQUET_SUFFIXES",
    "TABLE_SUFFIXES",
    "Table",
    "TableError",
    "is_table",
    "read_table",
    "table_columns",
]

CSV_SUFFIXES: Final = (".csv",)
"""File suffixes read as CSV (case-insensitive)."""
PARQUET_SUFFIXES: Final = (".parquet", ".pq")
"""File suffixes read as Parquet (case-insensitive)."""
TABLE_SUFFIXES: Final = CSV_SUFFIXES + PARQUET_SUFFIXES
"""Every suffix of a table; anything else is read as a bag."""

_NS_PER_UNIT: Final = {"s": NS_PER_S, "ms": 1_000_000, "us": 1_000, "ns": 1}
_INT64_MAX: Final = float(np.iinfo(np.int64).max)
_DELIMITERS: Final = ";\t|"
"""Tried, in order, when a CSV header holds no comma."""


class TableError(TwotankError, ValueError):
    """A table cannot be read through the map: the file, a column or the time column.

    The message names the file, what was found (the columns present, the bad cell) and the fix.
    """


@dataclasses.dataclass(frozen=True)
class Table:
    """A table read through an interface map, in time order.

    Attributes:
        path: The file.
        stamps_ns: (n,) int64, each row's time in nanoseconds (UTC since 1970 for ISO
            times, else the time column's own origin), non-decreasing.
        inputs: (n, nu) float64, the input columns in model units, in the order of ``u``.
        outputs: (n, ny) float64, the output columns in model units, in the order of ``y``.
        time_column: The time column used ("" for rows stamped by the map's ``step_s``).
        time_unit: Its unit as read: ``s``, ``ms``, ``us``, ``ns`` or ``iso`` (``row``: rows
            stamped ``k step_s``).
        columns: Every column of the file, in file order.
        bad_cells: Column -> (cells that are empty or not numbers, first such row, 1-based
            after the header), for the mapped columns that have any.
    """

    path: Path
    stamps_ns: np.ndarray
    inputs: np.ndarray
    outputs: np.ndarray
    time_column: str
    time_unit: str
    columns: tuple[str, ...]
    bad_cells: dict[str, tuple[int, int]] = dataclasses.field(default_factory=dict)

    @property
    def rows(self) -> int:
        """Number of rows."""
        return len(self.stamps_ns)


def is_table(path: str | Path) -> bool:
    """The path names a table by its suffix (:data:`TABLE_SUFFIXES`), whether it exists or not."""
    return Path(path).suffix.lower() in TABLE_SUFFIXES


def _kind(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in CSV_SUFFIXES:
        return "csv"
    if suffix in PARQUET_SUFFIXES:
        return "parquet"
    raise TableError(
        f"{path}: the suffix {repr(path.suffix) if path.suffix else '(none)'} is not a "
        "table's; a table is a CSV "
        f"({', '.join(CSV_SUFFIXES)}) or Parquet ({', '.join(PARQUET_SUFFIXES)}) file: rename "
        "it, or give a bag with a map of topics"
    )


def _checked_file(path: Path) -> str:
    kind = _kind(path)
    if not path.exists():
        raise TableError(f"cannot read the table {path}: no such file; give a CSV or Parquet file")
    if not path.is_file():
        raise TableError(
            f"cannot read the table {path}: it is not a file; give a CSV or Parquet file"
        )
    return kind


def _csv_delimiter(path: Path) -> str:
    """``,`` unless the header line has none and has ``;``, a tab or ``|``."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            header = f.readline()
    except (OSError, UnicodeDecodeError) as err:
        raise TableError(f"cannot read the table {path}: {err}") from err
    if "," in header:
        return ","
    return next((d for d in _DELIMITERS if d in header), ",")


def table_columns(path: str | Path) -> tuple[str, ...]:
    """The column names of a table, in file order, without reading its rows.

    Raises:
        TableError: Unknown suffix, missing file, or a file that is not a readable table.
    """
    path = Path(path)
    kind = _checked_file(path)
    if kind == "parquet":
        import pyarrow.parquet as pq  # noqa: PLC0415 (pyarrow on first use)

        try:
            return tuple(pq.read_schema(path).names)
        except Exception as err:  # pyarrow raises ArrowInvalid, OSError, ...
            raise TableError(f"{path} is not a readable Parquet file: {err}") from err
    import pandas as pd  # noqa: PLC0415 (pandas on first use)

    try:
        header = pd.read_csv(path, nrows=0, sep=_csv_delimiter(path), encoding="utf-8-sig")
    except pd.errors.EmptyDataError as err:
        raise TableError(f"{path} is empty: a table needs a header line of column names") from err
    except (ValueError, OSError, UnicodeDecodeError) as err:
        raise TableError(f"{path} is not a readable CSV file: {err}") from err
    return tuple(str(c) for c in header.columns)


def _near(name: str, columns: Sequence[str]) -> str:
    """``; did you mean 'X'?`` for a column equal up to case and spaces, else ``""``."""
    key = name.strip().lower()
    hits = [c for c in columns if c.strip().lower() == key]
    return f"; did you mean {hits[0]!r}?" if hits else ""


def _time_column(path: Path, time: TimeColumn, columns: Sequence[str]) -> str:
    if time.column:
        if time.column not in columns:
            raise TableError(
                f"{path}: no time column {time.column!r}{_near(time.column, columns)}; the "
                f"table's columns: {list(columns)}; name one in the map (time: {{column: NAME}})"
            )
        return time.column
    found = [c for c in columns if c.strip().lower() in TIME_COLUMNS]
    if len(found) == 1:
        return found[0]
    if found:
        raise TableError(
            f"{path}: the columns {found} could each be the time; name one in the map "
            f"(time: {{column: {found[0]}, unit: s}})"
        )
    raise TableError(
        f"{path}: no time column: none of the columns {list(columns)} is named "
        f"{', '.join(TIME_COLUMNS)}; name it in the map, e.g. time: {{column: NAME, unit: s}} "
        "(units s, ms, us, ns, iso), or, if the rows are evenly spaced samples without a time "
        "column, give their spacing: time: {step_s: SECONDS}"
    )


def read_table(path: str | Path, imap: InterfaceMap) -> Table:
    """Read a CSV or Parquet table through a map of columns, sorted by time.

    Args:
        path: A ``.csv`` or ``.parquet`` (``.pq``) file with a header of column names.
        imap: A map whose sources are columns (:attr:`InterfaceMap.is_table`), with its time
            column (:class:`~twotank_validation.online.interface.TimeColumn`).

    Returns:
        The rows in time order (stable: rows with equal times keep file order); values in
        model units ``(raw - offset) / scale``; a cell that is empty or not a number is NaN.

    Raises:
        TableError: An unknown suffix, a missing or unreadable file, a map of topics, a
            mapped or time column that the table lacks (the message lists the columns
            present), a time cell that cannot be read in the time unit, or no rows.
    """
    path = Path(path)
    if not imap.is_table:
        raise TableError(
            f"{path}: the interface map reads topics, not columns; a table's map names a "
            "column per source (e.g. {name: hot, column: valve_hot_pct, scale: 100}, "
            "docs/interface.md)"
        )
    kind = _checked_file(path)
    columns = table_columns(path)
    time = imap.time if imap.time is not None else TimeColumn()
    time_col = "" if time.step_s is not None else _time_column(path, time, columns)
    sources = imap.sources()
    missing = [s for s in sources if s.column not in columns]
    if missing:
        src = missing[0]
        raise TableError(
            f"{path}: no column {src.column!r} (source {src.name!r}){_near(src.column, columns)}; "
            f"the table's columns: {list(columns)}; set 'column:' of that source to one of them"
        )
    wanted = list(dict.fromkeys([*([time_col] if time_col else []), *(s.column for s in sources)]))
    frame = _read_frame(path, kind, wanted)
    if len(frame) == 0:
        raise TableError(f"{path} holds no rows (only the header); nothing to validate")
    if time.step_s is not None:  # no time column: row k at k step_s (file order)
        stamps, unit = np.arange(len(frame), dtype=np.int64) * round(time.step_s * NS_PER_S), "row"
    else:
        stamps, unit = _stamps_ns(path, frame[time_col], time.unit, time_col)
    order = np.argsort(stamps, kind="stable")
    bad: dict[str, tuple[int, int]] = {}

    def model(src: Source) -> np.ndarray:
        raw = _numbers(frame[src.column])
        nan = np.flatnonzero(np.isnan(raw))
        if len(nan):
            bad[src.column] = (len(nan), int(nan[0]) + 1)
        return convert(raw, src)[order]

    inputs = np.column_stack([model(s) for s in imap.inputs])
    outputs = np.column_stack([model(s) for s in imap.outputs])
    return Table(
        path=path,
        stamps_ns=stamps[order],
        inputs=inputs,
        outputs=outputs,
        time_column=time_col,
        time_unit=unit,
        columns=columns,
        bad_cells=bad,
    )


def _read_frame(path: Path, kind: str, wanted: list[str]) -> Any:
    import pandas as pd  # noqa: PLC0415

    try:
        if kind == "parquet":
            return pd.read_parquet(path, columns=wanted)
        return pd.read_csv(
            path,
            usecols=wanted,
            sep=_csv_delimiter(path),
            encoding="utf-8-sig",
        )
    except pd.errors.ParserError as err:
        raise TableError(f"{path} is not a readable CSV file: {err}") from err
    except (ValueError, OSError, UnicodeDecodeError) as err:
        raise TableError(f"{path}: cannot read the columns {wanted}: {err}") from err
    except Exception as err:  # pyarrow's own errors (ArrowInvalid, ...)
        raise TableError(f"{path} is not a readable {kind} file: {err}") from err


def _is_numeric(series: Any) -> bool:
    import pandas as pd  # noqa: PLC0415

    return bool(pd.api.types.is_numeric_dtype(series.dtype))


def _numbers(series: Any) -> np.ndarray:
    """(n,) float64 of a column: numbers as they are, anything else NaN."""
    if _is_numeric(series):
        return series.to_numpy(dtype=np.float64, na_value=np.nan)
    # a column with text cells: each cell as Python's float() reads it (correctly rounded)
    out = np.full(len(series), np.nan)
    for i, cell in enumerate(series.tolist()):
        if isinstance(cell, str | int | float | np.number):  # bool is an int
            with contextlib.suppress(ValueError):  # text that is not a number stays NaN
                out[i] = float(cell)
    return out


def _stamps_ns(path: Path, series: Any, unit: str, name: str) -> tuple[np.ndarray, str]:
    """(n,) int64 ns of the time column, and the unit it was read in."""
    import pandas as pd  # noqa: PLC0415

    is_datetime = bool(pd.api.types.is_datetime64_any_dtype(series.dtype))
    if unit == "auto":
        unit = "s" if _is_numeric(series) and not is_datetime else "iso"
    if unit == "iso":
        return _iso_ns(path, series, name, is_datetime), unit
    if is_datetime:
        raise TableError(
            f"{path}: time column {name!r} holds datetimes, not numbers of {unit}; set its unit "
            f"to iso (time: {{column: {name}, unit: iso}})"
        )
    factor = _NS_PER_UNIT[unit]
    if pd.api.types.is_integer_dtype(series.dtype) and not series.isna().any():
        ints = series.to_numpy(dtype=np.int64)
        if len(ints) and int(np.abs(ints).max()) > _INT64_MAX // factor:
            _bad_time(path, name, unit, series, np.abs(ints) > _INT64_MAX // factor)
        return ints * factor, unit
    values = _numbers(series)
    with np.errstate(over="ignore", invalid="ignore"):
        scaled = values * float(factor)
    bad = ~np.isfinite(scaled) | (np.abs(scaled) >= _INT64_MAX)
    if bad.any():
        _bad_time(path, name, unit, series, bad)
    return np.rint(scaled).astype(np.int64), unit


def _iso_ns(path: Path, series: Any, name: str, is_datetime: bool) -> np.ndarray:
    import pandas as pd  # noqa: PLC0415

    if is_datetime:
        times = series if series.dt.tz is None else series.dt.tz_convert("UTC").dt.tz_localize(None)
    elif _is_numeric(series):
        raise TableError(
            f"{path}: time column {name!r} holds numbers, not ISO-8601 times; give its unit "
            f"(time: {{column: {name}, unit: s}}, or ms, us, ns)"
        )
    else:
        text = series.astype(object)
        parsed = pd.to_datetime(text, format="ISO8601", utc=True, errors="coerce")
        bad = parsed.isna().to_numpy()
        if bad.any():
            _bad_time(path, name, "iso", series, bad)
        times = parsed.dt.tz_localize(None)
    bad = times.isna().to_numpy()
    if bad.any():
        _bad_time(path, name, "iso", series, bad)
    return times.dt.as_unit("ns").to_numpy(dtype="datetime64[ns]").view(np.int64)


_UNIT_WORDS: Final = {
    "s": "a number of seconds",
    "ms": "a number of milliseconds",
    "us": "a number of microseconds",
    "ns": "a number of nanoseconds",
    "iso": "an ISO-8601 time (e.g. 2024-05-01T12:00:00.8Z)",
}


def _bad_time(path: Path, name: str, unit: str, series: Any, bad: np.ndarray) -> None:
    rows = np.flatnonzero(bad)
    first = int(rows[0])
    cell = series.iloc[first]
    if isinstance(cell, np.generic):
        cell = cell.item()
    empty = cell is None or (isinstance(cell, float) and np.isnan(cell))
    shown = "an empty cell" if empty else repr(cell)
    other = (
        "; if the column holds ISO-8601 times, set unit: iso"
        if unit != "iso"
        else "; if it holds numbers, set unit: s (or ms, us, ns)"
    )
    raise TableError(
        f"{path}: time column {name!r}, row {first + 1} (after the header): {shown} is not "
        f"{_UNIT_WORDS[unit]} ({len(rows)} such row(s)); every row needs a time: fix or drop "
        f"those rows{other}"
    )
