"""rosbag2 SQLite3 files read row by row with the sqlite3 module, up to the damage.

Used when rosbags cannot read a SQLite3 bag through its index (a truncated file fails the
index queries; counts or time ranges contradict each other), and for a SQLite3 file without
the ``.db3`` suffix. Every row SQLite still returns is read, in time order through the
timestamp index, or in insertion order through the table if that reaches further
(``writable_schema`` lets SQLite use the pages a truncated file has). A query that produces
no row for ``_SQLITE_STALL_S`` seconds is aborted.

Why hand-written: rosbags' SQLite3 reader (tried first) gives up on such a file, and the
sqlite3 shell's ``.recover`` is a command, not a library call.
"""

from __future__ import annotations

import sqlite3
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Final
from urllib.parse import quote

from rosbags.typesys.store import Typestore

from twotank_validation.bags.backend import _Backend, _Damage, _Raw, _unzstd
from twotank_validation.bags.bag_errors import BagFormatError
from twotank_validation.bags.decode import _Codec, _typestore_from, _unknown_type
from twotank_validation.bags.records import STORAGE_SQLITE3, _norm_type

_SQLITE_STALL_S: Final = 60.0  # a query producing no row for this long is aborted


class _SqliteScanBackend(_Backend):
    """rosbag2 SQLite3 files read with the sqlite3 module row by row, up to the damage.

    The connection is read-only and immutable, with ``writable_schema`` on so that SQLite
    takes the pages the file really has instead of refusing a file shorter than its header
    says. Rows come in log-time order through the timestamp index; if the index is damaged
    and the table scan reaches further, rows come in insertion (rowid) order instead, which
    is the recorder's write order.
    """

    indexed = False
    storage = STORAGE_SQLITE3

    def __init__(
        self, files: Sequence[Path], shown: Path, *, reason: str, message_compression: bool
    ) -> None:
        super().__init__()
        self.shown = shown
        self._files = list(files)
        self._message_compression = message_compression
        self._topic_of: dict[tuple[int, int], tuple[str, str]] = {}
        self._definitions: list[tuple[str, str, str]] = []
        self._store: Typestore | None = None
        self._tick = [time.monotonic()]
        self._order = "timestamp"
        counts, damage, n, span = self._prescan()
        if damage is not None:
            self._order = "rowid"  # the table scan may reach rows the time index cannot
            counts2, damage2, n2, span2 = self._prescan()
            if n2 > n:
                counts, damage, span = counts2, damage2, span2
                self.ordered = False
            else:
                self._order = "timestamp"
        self.start_ns, self.end_ns = span
        self._damage = damage
        types: dict[str, set[str]] = {}
        for topic, msgtype in self._topic_of.values():
            types.setdefault(topic, set()).add(_norm_type(msgtype))
        self.topics = {t: tuple(sorted(v)) for t, v in types.items()}
        self.counts = {t: counts.get(t, 0) for t in self.topics}
        how = (
            "read row by row: all of it was readable"
            if damage is None
            else f"{damage.where()}; read row by row up to there"
            + (" (in insertion order: the time index is damaged)" if self._order == "rowid" else "")
        )
        self.damage = f"{reason}; {how}"

    def _prescan(self) -> tuple[Counter[str], _Damage | None, int, tuple[int | None, int | None]]:
        counts: Counter[str] = Counter()
        start: int | None = None
        end: int | None = None
        try:
            for key, log_ns, _ in self._rows(None):
                counts[self._topic_of[key][0]] += 1
                start = log_ns if start is None else min(start, log_ns)
                end = log_ns if end is None else max(end, log_ns)
        except _Damage as err:
            return counts, err, sum(counts.values()), (start, end)
        return counts, None, sum(counts.values()), (start, end)

    def _connect(self, path: Path) -> sqlite3.Connection:
        uri = f"file:{quote(str(path.resolve()))}?mode=ro&immutable=1"
        conn = sqlite3.connect(uri, uri=True)
        tick = self._tick

        def stalled() -> int:
            return int(time.monotonic() - tick[0] > _SQLITE_STALL_S)

        conn.set_progress_handler(stalled, 10_000)
        conn.execute("PRAGMA writable_schema = ON")  # use the pages the file has (read-only)
        return conn

    def _rows(self, topics: frozenset[str] | None) -> Iterator[tuple[tuple[int, int], int, bytes]]:
        for idx, path in enumerate(self._files):
            yield from self._file_rows(idx, path, topics)

    def _file_rows(
        self, idx: int, path: Path, topics: frozenset[str] | None
    ) -> Iterator[tuple[tuple[int, int], int, bytes]]:
        self._tick[0] = time.monotonic()
        try:
            conn = self._connect(path)
        except sqlite3.Error as err:
            raise _Damage(path, None, f"SQLite: {err}", truncated=False) from err
        try:
            kinds = dict(
                conn.execute(
                    "SELECT name, type FROM sqlite_master WHERE name IN ('messages', 'topics')"
                ).fetchall()
            )
            if kinds.get("messages") != "table" or kinds.get("topics") != "table":
                raise _Damage(
                    path, None, "no rosbag2 'messages' and 'topics' tables", truncated=False
                )
            for tid, name, msgtype in conn.execute("SELECT id, name, type FROM topics"):
                if not (
                    isinstance(tid, int) and isinstance(name, str) and isinstance(msgtype, str)
                ):
                    raise _Damage(path, None, "the topics table is damaged", truncated=False)
                self._topic_of.setdefault((idx, tid), (name, msgtype))
            has_defs = conn.execute(
                "SELECT count(*) FROM sqlite_master "
                "WHERE type = 'table' AND name = 'message_definitions'"
            ).fetchone()[0]
            if has_defs and not self._definitions:
                for row in conn.execute(
                    "SELECT topic_type, encoding, encoded_message_definition "
                    "FROM message_definitions"
                ):
                    self._definitions.append((str(row[0]), str(row[1]), str(row[2])))
            ids = [
                k[1]
                for k, v in self._topic_of.items()
                if k[0] == idx and (topics is None or v[0] in topics)
            ]
            if not ids:
                return
            marks = ",".join("?" * len(ids))
            order = "timestamp" if self._order == "timestamp" else "rowid"
            # Only '?' marks and a fixed ORDER BY are formatted into the query.
            cursor = conn.execute(
                f"SELECT topic_id, timestamp, data FROM messages "
                f"WHERE topic_id IN ({marks}) ORDER BY {order}",
                ids,
            )
            while True:
                self._tick[0] = time.monotonic()
                row = cursor.fetchone()
                if row is None:
                    break
                tid, log_ns, data = row
                key = (idx, tid)
                if key not in self._topic_of or not isinstance(log_ns, int):
                    raise _Damage(
                        path, None, "a row does not fit the rosbag2 schema", truncated=False
                    )
                if not isinstance(data, bytes):
                    raise _Damage(path, None, "a message row holds no data blob", truncated=False)
                yield key, log_ns, data
        except sqlite3.Error as err:
            raise _Damage(path, None, f"SQLite: {err}", truncated=False) from err
        finally:
            conn.close()

    def _decode(self, msgtype: str) -> _Codec | None:
        if self._store is None or msgtype not in self._store.fielddefs:
            wanted = {t for _, t in self._topic_of.values()}
            self._store = _typestore_from(self._definitions, wanted)
        store = self._store
        if msgtype not in store.fielddefs:
            return None
        return _Codec(
            lambda data: store.deserialize_cdr(data, msgtype), msgtype, lambda: store.fielddefs
        )

    def problem(self, topic: str) -> str | None:
        for t, msgtype in self._topic_of.values():
            if t == topic and self._decode(msgtype) is None:
                return _unknown_type(msgtype)
        return None

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:
        decoders: dict[str, _Codec | None] = {}
        for key, log_ns, data in self._rows(topics):
            topic, msgtype = self._topic_of[key]
            if msgtype not in decoders:
                decoders[msgtype] = self._decode(msgtype)
            dec = decoders[msgtype]
            if dec is None:  # pragma: no cover - problem() ran before
                raise BagFormatError(_unknown_type(msgtype))
            raw = _unzstd(data) if self._message_compression else data
            yield topic, _norm_type(msgtype), log_ns, raw, dec
        if self._damage is not None:
            raise self._damage

    def close(self) -> None:
        """Connections are closed after each read."""
