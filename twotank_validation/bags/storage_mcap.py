"""Plain MCAP files (no ``metadata.yaml``; other ROS 2 tools) with a summary: mcap's reader.

:class:`mcap.reader.SeekingReader` reads them through the summary's chunk index in log-time
order; messages decode with mcap-ros2-support's DecoderFactory (rosbags' type store where it
has no decoder). A file without a summary or with an inconsistent one raises ``_NeedScan``
and the reader scans it (:mod:`~twotank_validation.bags.scan`).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from mcap.reader import SeekingReader

from twotank_validation.bags.backend import (
    _MAX_CHUNK_BYTES,
    _Backend,
    _check_index,
    _NeedScan,
    _Raw,
)
from twotank_validation.bags.bag_errors import BagFormatError
from twotank_validation.bags.decode import _Codec, _Decoders
from twotank_validation.bags.records import STORAGE_MCAP_PLAIN, _norm_type


class _PlainMcapBackend(_Backend):
    """A healthy plain MCAP file with a summary: mcap's seeking reader, log-time order."""

    indexed = True
    storage = STORAGE_MCAP_PLAIN

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.shown = path
        self._file = path.open("rb")
        try:
            self._setup(path)
        except BaseException:
            self._file.close()
            raise

    def _setup(self, path: Path) -> None:
        size = path.stat().st_size
        self._reader = SeekingReader(self._file, validate_crcs=True, record_size_limit=size)
        summary = self._reader.get_summary()
        if summary is None or summary.statistics is None:
            raise _NeedScan("the file has no summary section (index)", benign=True)
        stats = summary.statistics
        if not summary.chunk_indexes and stats.message_count:
            raise _NeedScan("the file has no chunk index", benign=True)
        for ci in summary.chunk_indexes:
            if (
                ci.chunk_start_offset + ci.chunk_length > size
                or ci.compressed_size > ci.chunk_length
                or ci.uncompressed_size > _MAX_CHUNK_BYTES
                or ci.compression not in ("", "zstd", "lz4")
                or any(cid not in summary.channels for cid in ci.message_index_offsets)
            ):
                raise _NeedScan(
                    f"its chunk index is inconsistent (chunk at byte {ci.chunk_start_offset})"
                )
        self._channels = summary.channels
        self._schemas = summary.schemas
        self._decoders = _Decoders(prefer_rosbags=False)
        for schema in summary.schemas.values():
            self._decoders.add_schema(schema)
        types: dict[str, set[str]] = {}
        for ch in summary.channels.values():
            if ch.schema_id and ch.schema_id not in summary.schemas:
                raise _NeedScan(f"channel {ch.id} refers to a missing schema {ch.schema_id}")
            types.setdefault(ch.topic, set()).add(self._msgtype(ch.schema_id))
            n = stats.channel_message_counts.get(ch.id, 0)
            self.counts[ch.topic] = self.counts.get(ch.topic, 0) + n
        self.topics = {t: tuple(sorted(v)) for t, v in types.items()}
        if stats.message_count:
            self.start_ns = int(stats.message_start_time)
            self.end_ns = int(stats.message_end_time)
        _check_index(self.counts, int(stats.message_count), self.start_ns, self.end_ns)
        if not stats.message_count and summary.chunk_indexes:
            raise _NeedScan("its statistics count no message but it has chunks")

    def _msgtype(self, schema_id: int) -> str:
        schema = self._schemas.get(schema_id)
        return _norm_type(schema.name) if schema is not None else "(no schema)"

    def _decoder(self, channel_id: int) -> _Codec | str:
        ch = self._channels[channel_id]
        schema = self._schemas.get(ch.schema_id)
        return self._decoders.get(
            (0, ch.id), ch.message_encoding, schema, self._msgtype(ch.schema_id)
        )

    def topic_codecs(self, topic: str) -> list[_Codec] | None:
        keys = [ch.id for ch in self._channels.values() if ch.topic == topic]
        codecs = [c for c in map(self._decoder, keys) if not isinstance(c, str)]
        return codecs if len(codecs) == len(keys) else None

    def problem(self, topic: str) -> str | None:
        for ch in self._channels.values():
            if ch.topic == topic and isinstance(found := self._decoder(ch.id), str):
                return found
        return None

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:
        for _, channel, message in self._reader.iter_messages(topics=sorted(topics)):
            dec = self._decoder(channel.id)
            if isinstance(dec, str):  # pragma: no cover - problem() ran before
                raise BagFormatError(dec)
            msgtype = self._msgtype(channel.schema_id)
            yield channel.topic, msgtype, int(message.log_time), message.data, dec

    def close(self) -> None:
        self._file.close()
