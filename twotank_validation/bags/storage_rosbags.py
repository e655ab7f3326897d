"""rosbag2 bags, MCAP or SQLite3 storage, read through rosbags' AnyReader and the bag's index.

The reader's first choice for a rosbag2 directory and for a ``.mcap``/``.db3`` file inside
one (or a lone ``.db3`` file). If the index cannot be used the backend raises (``_NeedScan``,
or whatever rosbags raises) and the reader scans instead (:mod:`~twotank_validation.bags.scan`,
:mod:`~twotank_validation.bags.salvage_sqlite`).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.interfaces import ConnectionExtRosbag2
from rosbags.rosbag2.reader import DirectoryReader
from rosbags.rosbag2.storage_mcap import McapReader, decompress

from twotank_validation.bags.backend import _Backend, _check_index, _NeedScan, _Raw
from twotank_validation.bags.columnar import _Channel, _Columns, _McapColumns, _rows_to_columns
from twotank_validation.bags.decode import (
    _Codec,
    _default_typestore,
    _fill_defaults,
    _unknown_type,
)
from twotank_validation.bags.records import _norm_type


class _RosbagsBackend(_Backend):
    """rosbag2 (directory or lone storage file) through rosbags' AnyReader and its index."""

    indexed = True

    def __init__(self, path: Path, storage: str, shown: Path) -> None:
        super().__init__()
        self.storage = storage
        self.shown = shown
        self._reader = AnyReader([path], default_typestore=_default_typestore())
        self._reader.open()
        try:
            conns = self._reader.connections
            _fill_defaults(self._reader.typestore, {c.msgtype for c in conns})
            types: dict[str, set[str]] = {}
            for c in conns:
                types.setdefault(c.topic, set()).add(_norm_type(c.msgtype))
                self.counts[c.topic] = self.counts.get(c.topic, 0) + int(c.msgcount)
            self.topics = {t: tuple(sorted(v)) for t, v in types.items()}
            total = int(self._reader.message_count)
            if total:
                self.start_ns = int(self._reader.start_time)
                self.end_ns = int(self._reader.end_time) - 1  # rosbags: one past the last
            _check_index(self.counts, total, self.start_ns, self.end_ns)
            if not total and next(self._reader.messages(), None) is not None:
                raise _NeedScan("its metadata counts no message but the storage holds some")
        except BaseException:
            self._reader.close()
            raise

    def problem(self, topic: str) -> str | None:
        for c in self._reader.connections:
            if c.topic != topic:
                continue
            ext = c.ext
            if isinstance(ext, ConnectionExtRosbag2) and ext.serialization_format != "cdr":
                return f"it is serialised as {ext.serialization_format!r}, not ROS 2 CDR"
            if c.msgtype not in self._reader.typestore.fielddefs:
                return _unknown_type(c.msgtype)
        return None

    def _codecs(self, conns: list[Any]) -> dict[int, _Channel]:
        reader = self._reader
        store = reader.typestore
        codecs: dict[int, _Channel] = {}
        for c in conns:
            dec = functools.partial(_rosbags_decode, reader, c.msgtype)
            codecs[id(c)] = (
                c.topic,
                _norm_type(c.msgtype),
                _Codec(dec, c.msgtype, lambda: store.fielddefs),
            )
        return codecs

    def topic_codecs(self, topic: str) -> list[_Codec] | None:
        conns = [c for c in self._reader.connections if c.topic == topic]
        return [codec for _, _, codec in self._codecs(conns).values()]

    def _rows(self, conns: list[Any], codecs: dict[int, _Channel]) -> Iterator[_Raw]:
        for conn, log_ns, raw in self._reader.messages(connections=conns):
            topic, msgtype, codec = codecs[id(conn)]
            yield topic, msgtype, int(log_ns), raw, codec

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:
        conns = [c for c in self._reader.connections if c.topic in topics]
        if not conns:
            return iter(())
        return self._rows(conns, self._codecs(conns))

    def _mcap_storages(self) -> list[McapReader] | None:
        """Rosbags' readers of the bag's MCAP files, if the chunks can be read in bulk."""
        readers = self._reader.readers
        if len(readers) != 1:
            return None
        storage = getattr(readers[0], "storage", None)
        if isinstance(storage, McapReader):
            storages = [storage]
        elif isinstance(storage, DirectoryReader):
            if storage.metadata.compression_mode == "message":
                return None
            storages = [s for s in storage.storages if isinstance(s, McapReader)]
            if len(storages) != len(storage.storages):
                return None
        else:
            return None
        if not storages or not all(s.chunks and s.bio is not None for s in storages):
            return None
        return storages

    def iter_columns(self, topics: frozenset[str], channels: list[_Channel]) -> Iterator[_Columns]:
        conns = [c for c in self._reader.connections if c.topic in topics]
        if not conns:
            return iter(())
        codecs = self._codecs(conns)
        storages = self._mcap_storages()
        if storages is None:
            return _rows_to_columns(self._rows(conns, codecs), channels)
        channels.extend(codecs[id(c)] for c in conns)
        return iter(
            _McapColumns(storages, conns, channels, decompress, lambda: self._rows(conns, codecs))
        )

    def close(self) -> None:
        self._reader.close()


def _rosbags_decode(reader: AnyReader, msgtype: str, data: Any) -> Any:
    return reader.deserialize(data, msgtype)
