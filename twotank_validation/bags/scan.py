"""MCAP files read without their index: a hand-written linear scan up to the damage.

Used when the index of an MCAP file (rosbag2 storage or plain) cannot be used: a file cut
short by a killed recorder has no summary and no footer; counts or time ranges contradict
each other; a streaming writer wrote none. The scan recovers every complete record up to
the first bad one, including the complete messages at the head of an uncompressed chunk the
file cuts short; at open it notes each chunk's byte and time range (an index rebuilt from
the data) and the messages are then merged in log-time order, chunk by chunk. It never
loops on garbage: every loop advances through a file of known size, record lengths are
checked against it, and decompression stops at the declared size.

Why hand-written: the mcap library's reader for files without an index
(``NonSeekingReader``) sorts the whole file in memory to give log-time order, decompresses
lz4 chunks without a size bound, and loses a chunk the file cuts short (or one holding a bad
record) whole; ``mcap recover`` is a command-line tool, not a library call.
"""

from __future__ import annotations

import heapq
import os
import struct
import zlib
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import lz4.frame
import zstandard
from mcap.records import Schema as McapSchema

from twotank_validation.bags.backend import (
    _MAX_CHUNK_BYTES,
    _Backend,
    _Damage,
    _Raw,
    _unzstd,
)
from twotank_validation.bags.bag_errors import BagFormatError
from twotank_validation.bags.decode import _Codec, _Decoders
from twotank_validation.bags.records import STORAGE_MCAP_PLAIN, _norm_type, _short

_MCAP_MAGIC: Final = b"\x89MCAP0\r\n"


class _Cursor:
    """Bounds-checked little-endian reads from a record body."""

    __slots__ = ("buf", "pos")

    def __init__(self, buf: bytes | memoryview, pos: int = 0) -> None:
        self.buf = memoryview(buf)
        self.pos = pos

    def take(self, n: int) -> memoryview:
        if n < 0 or n > len(self.buf) - self.pos:
            raise ValueError(f"needs {n} bytes, {len(self.buf) - self.pos} left in the record")
        out = self.buf[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return int(struct.unpack("<H", self.take(2))[0])

    def u32(self) -> int:
        return int(struct.unpack("<I", self.take(4))[0])

    def u64(self) -> int:
        return int(struct.unpack("<Q", self.take(8))[0])

    def string(self) -> str:
        return bytes(self.take(self.u32())).decode("utf-8")


_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_DATA_END: Final = 0x0F


def _decompress(compression: str, data: bytes | memoryview, size: int) -> bytes:
    """Decompress a chunk, never producing more than its declared ``size`` (+1) bytes."""
    if size > _MAX_CHUNK_BYTES:
        raise ValueError(f"declares {size} uncompressed bytes")
    if compression == "":
        out = bytes(data)
    elif compression == "zstd":
        parts: list[bytes] = []
        total = 0
        with zstandard.ZstdDecompressor().stream_reader(bytes(data)) as src:
            while total <= size:
                piece = src.read(min(1 << 20, size + 1 - total))
                if not piece:
                    break
                parts.append(piece)
                total += len(piece)
        out = b"".join(parts)
    elif compression == "lz4":
        out = lz4.frame.LZ4FrameDecompressor().decompress(bytes(data), max_length=size + 1)
    else:
        raise ValueError(f"unsupported compression {compression!r}")
    if len(out) != size:
        raise ValueError(f"decompresses to {len(out)} bytes, its header says {size}")
    return out


_Msg = tuple[int, int, tuple[int, int], memoryview]  # log time, file order, channel key, data

_RUN_MAX_MESSAGES: Final = 10_000
_RUN_MAX_BYTES: Final = 4 << 20


@dataclass
class _Segment:
    """A piece of an MCAP file the scan can reload: a chunk, or a run of loose records.

    ``kind`` is "run" (top-level records in ``[offset, stop)``), "chunk" (the chunk record at
    ``offset``, its first ``limit`` messages if set) or "partial" (an uncompressed chunk the
    file cuts short, from ``offset`` to the end of the file).
    """

    file_idx: int
    kind: str
    offset: int
    stop: int
    start_ns: int
    end_ns: int
    topics: set[str]
    limit: int | None = None


class _McapScanBackend(_Backend):
    """An MCAP read without its index: scanned once at open into segments, then merged.

    The scan at open walks every record from the start, up to the data-end record or the
    first damage, and notes for each chunk (or run of loose messages, bounded in size) its
    byte range, its time range and its topics: an index rebuilt from the data, as
    ``mcap recover`` does. :meth:`iter` then merges the segments by log time, loading each
    one only when its first message is due, so memory stays bounded by a few segments.
    """

    indexed = False

    def __init__(
        self,
        files: Sequence[Path],
        storage: str,
        shown: Path,
        *,
        reason: str,
        message_compression: bool = False,
        benign: bool = False,
    ) -> None:
        super().__init__()
        self.storage = storage
        self.shown = shown
        self._files = list(files)
        self._message_compression = message_compression
        self._decoders = _Decoders(prefer_rosbags=storage != STORAGE_MCAP_PLAIN)
        self._schemas: dict[tuple[int, int], McapSchema] = {}
        self._channels: dict[tuple[int, int], tuple[str, str, int]] = {}  # topic, enc, schema
        self._segments: list[_Segment] = []
        self._counts: Counter[str] = Counter()
        self._damage: _Damage | None = None
        try:
            for idx, path in enumerate(self._files):
                self._index_file(idx, path)
        except _Damage as err:
            self._damage = err
        types: dict[str, set[str]] = {}
        for key, (topic, _, _) in self._channels.items():
            types.setdefault(topic, set()).add(self._msgtype(key))
        self.topics = {t: tuple(sorted(v)) for t, v in types.items()}
        self.counts = {t: self._counts.get(t, 0) for t in self.topics}
        if self._segments:
            self.start_ns = min(s.start_ns for s in self._segments)
            self.end_ns = max(s.end_ns for s in self._segments)
        how = (
            "read by a linear scan: all of it was readable"
            if self._damage is None
            else f"{self._damage.where()}; read by a linear scan up to there"
        )
        # A valid file written without a summary (streaming writers) is not damaged.
        self.damage = None if benign and self._damage is None else f"{reason}; {how}"

    def _msgtype(self, key: tuple[int, int]) -> str:
        schema = self._schemas.get((key[0], self._channels[key][2]))
        return _norm_type(schema.name) if schema is not None else "(no schema)"

    def _decoder(self, key: tuple[int, int]) -> _Codec | str:
        _, enc, schema_id = self._channels[key]
        schema = self._schemas.get((key[0], schema_id))
        return self._decoders.get(key, enc, schema, self._msgtype(key))

    def topic_codecs(self, topic: str) -> list[_Codec] | None:
        keys = [key for key, (t, _, _) in self._channels.items() if t == topic]
        codecs = [c for c in map(self._decoder, keys) if not isinstance(c, str)]
        return codecs if len(codecs) == len(keys) else None

    def problem(self, topic: str) -> str | None:
        for key, (t, _, _) in self._channels.items():
            if t == topic and isinstance(found := self._decoder(key), str):
                return found
        return None

    def close(self) -> None:
        """Files are opened per read."""

    # -- the scan at open
    def _add(self, seg: _Segment, msgs: Sequence[_Msg]) -> None:
        if not msgs:
            return
        times = [m[0] for m in msgs]
        seg.start_ns, seg.end_ns = min(times), max(times)
        for m in msgs:
            topic = self._channels[m[2]][0]
            seg.topics.add(topic)
            self._counts[topic] += 1
        self._segments.append(seg)

    def _index_file(self, idx: int, path: Path) -> None:
        run: list[_Msg] = []
        span = [0, 0]  # byte range of the current run of loose messages

        def flush() -> None:
            if run:
                self._add(_Segment(idx, "run", span[0], span[1], 0, 0, set()), run)
                run.clear()

        try:
            for pos, op, length, body in self._records(path):
                if op == _OP_CHUNK:
                    flush()
                    if body is None:  # cut short: keep its complete messages (then _Damage)
                        seg = _Segment(idx, "partial", pos, pos, 0, 0, set())
                        self._add(seg, self._partial_chunk(idx, path, pos, self._tail(path, pos)))
                        continue
                    msgs, problem = self._chunk(idx, path, pos, body)
                    limit = len(msgs) if problem is not None else None
                    self._add(
                        _Segment(idx, "chunk", pos, pos + 9 + length, 0, 0, set(), limit), msgs
                    )
                    if problem is not None:
                        raise _Damage(path, pos, f"bad chunk: {problem}", truncated=False)
                elif body is not None:
                    msg = self._record(idx, path, pos, op, body)
                    if msg is not None:
                        if not run:
                            span[0] = pos
                        span[1] = pos + 9 + length
                        run.append((msg[1], len(run), msg[0], msg[2]))
                        if len(run) >= _RUN_MAX_MESSAGES or span[1] - span[0] >= _RUN_MAX_BYTES:
                            flush()
        finally:
            flush()

    @staticmethod
    def _tail(path: Path, pos: int) -> bytes:
        with path.open("rb") as f:
            f.seek(pos + 9)
            return f.read()

    @staticmethod
    def _records(path: Path) -> Iterator[tuple[int, int, int, bytes | None]]:
        """Top-level records (byte offset, opcode, length, body) up to the data end.

        A chunk record the file cuts short comes with body None (and then _Damage follows);
        any other damage raises _Damage.
        """
        try:
            size = path.stat().st_size
            f = path.open("rb")
        except OSError as err:
            raise _Damage(path, None, f"cannot be read: {err}", truncated=False) from err
        with f:
            head = f.read(8)
            if head != _MCAP_MAGIC:
                if len(head) < 8 and _MCAP_MAGIC.startswith(head):
                    raise _Damage(
                        path, len(head), "the file ends inside the MCAP magic", truncated=True
                    )
                raise _Damage(path, 0, "it does not start with the MCAP magic", truncated=False)
            pos = 8
            while True:
                hdr = f.read(9)
                if len(hdr) < 9:
                    detail = (
                        "the file ends without the data-end record and footer"
                        if not hdr
                        else "the file ends inside a record header"
                    )
                    raise _Damage(path, pos, detail, truncated=True)
                op, length = struct.unpack("<BQ", hdr)
                if op == 0 or 0x10 <= op < 0x80:
                    raise _Damage(path, pos, f"unknown record opcode 0x{op:02x}", truncated=False)
                avail = max(size - pos - 9, 0)
                if length > avail:
                    if op == _OP_CHUNK:
                        yield pos, op, length, None
                    raise _Damage(
                        path,
                        pos,
                        f"the record at byte {pos} (opcode 0x{op:02x}) needs {length} bytes, "
                        f"the file ends after {avail}",
                        truncated=True,
                    )
                if op in (_OP_DATA_END, _OP_FOOTER):
                    return
                if op in (_OP_CHUNK, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE):
                    body = f.read(length)
                    if len(body) != length:  # the file shrank while being read
                        raise _Damage(path, pos, "the file ends early", truncated=True)
                    yield pos, op, length, body
                else:
                    f.seek(length, os.SEEK_CUR)
                pos += 9 + length

    def _record(
        self, idx: int, path: Path, pos: int, op: int, body: bytes | memoryview
    ) -> tuple[tuple[int, int], int, memoryview] | None:
        """Parse a schema, channel or message record; return a message as (key, t, data)."""
        try:
            cur = _Cursor(body)
            if op == _OP_SCHEMA:
                sid = cur.u16()
                name, encoding = cur.string(), cur.string()
                data = bytes(cur.take(cur.u32()))
                schema = McapSchema(id=sid, name=name, encoding=encoding, data=data)
                self._schemas.setdefault((idx, sid), schema)
                self._decoders.add_schema(schema)
            elif op == _OP_CHANNEL:
                cid, sid = cur.u16(), cur.u16()
                topic, encoding = cur.string(), cur.string()
                self._channels.setdefault((idx, cid), (topic, encoding, sid))
            elif op == _OP_MESSAGE:
                cid = cur.u16()
                cur.take(4)  # sequence
                log_ns = cur.u64()
                cur.take(8)  # publish time
                if (idx, cid) not in self._channels:
                    raise ValueError(f"a message refers to channel {cid}, never defined")
                return (idx, cid), log_ns, cur.take(len(cur.buf) - cur.pos)
        except (ValueError, struct.error) as err:  # UnicodeDecodeError is a ValueError
            raise _Damage(
                path, pos, f"bad record (opcode 0x{op:02x}): {err}", truncated=False
            ) from err
        return None

    def _inner(
        self, idx: int, path: Path, pos: int, data: bytes | memoryview, *, partial: bool
    ) -> tuple[list[_Msg], str | None]:
        """Records of a chunk's payload: (messages in file order, problem or None)."""
        view = memoryview(data)
        msgs: list[_Msg] = []
        at = 0
        while at < len(view):
            if len(view) - at < 9:
                return msgs, "the chunk ends inside a record header"
            op, length = struct.unpack_from("<BQ", view, at)
            if length > len(view) - at - 9:
                return (
                    msgs,
                    f"a record in the chunk needs {length} bytes, {len(view) - at - 9} left",
                )
            if not partial and (op == 0 or 0x10 <= op < 0x80):
                return msgs, f"unknown record opcode 0x{op:02x} in the chunk"
            if op in (_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE):
                try:
                    msg = self._record(idx, path, pos, op, view[at + 9 : at + 9 + length])
                except _Damage as err:
                    return msgs, err.detail
                if msg is not None:
                    msgs.append((msg[1], len(msgs), msg[0], msg[2]))
            at += 9 + length
        return msgs, None

    def _chunk(self, idx: int, path: Path, pos: int, body: bytes) -> tuple[list[_Msg], str | None]:
        """Messages of a complete chunk record (file order), and a problem found after them.

        Raises:
            _Damage: The chunk cannot be decompressed or fails its CRC (nothing usable).
        """
        try:
            cur = _Cursor(body)
            cur.take(16)  # message start and end time
            usize, crc = cur.u64(), cur.u32()
            compression = cur.string()
            payload = cur.take(cur.u64())
            data = _decompress(compression, payload, usize)
        except Exception as err:  # any decoder failure is damage here
            raise _Damage(path, pos, f"bad chunk: {_short(err)}", truncated=False) from err
        if crc and zlib.crc32(data) != crc:
            raise _Damage(path, pos, "the chunk's CRC does not match its content", truncated=False)
        return self._inner(idx, path, pos, data, partial=False)

    def _partial_chunk(self, idx: int, path: Path, pos: int, body: bytes) -> list[_Msg]:
        """Complete messages at the start of an uncompressed chunk the file cuts short."""
        try:
            cur = _Cursor(body)
            cur.take(28)  # times, uncompressed size and CRC
            if cur.string() != "":
                return []  # a compressed chunk cut short cannot be decoded
            cur.take(8)
        except ValueError:
            return []
        msgs, _ = self._inner(idx, path, pos, memoryview(body)[cur.pos :], partial=True)
        return msgs

    # -- reading
    def _load(self, seg: _Segment) -> list[_Msg]:
        """The messages of a segment, sorted by log time (ties in file order)."""
        path = self._files[seg.file_idx]
        with path.open("rb") as f:
            f.seek(seg.offset)
            data = f.read(seg.stop - seg.offset if seg.kind != "partial" else -1)
        if seg.kind == "partial":
            msgs = self._partial_chunk(seg.file_idx, path, seg.offset, data[9:])
        elif seg.kind == "chunk":
            msgs, _ = self._chunk(seg.file_idx, path, seg.offset, data[9:])
            msgs = msgs[: seg.limit] if seg.limit is not None else msgs
        else:
            msgs = []
            view = memoryview(data)
            at = 0
            while at < len(view):
                op, length = struct.unpack_from("<BQ", view, at)
                if op == _OP_MESSAGE:
                    msg = self._record(
                        seg.file_idx, path, seg.offset + at, op, view[at + 9 : at + 9 + length]
                    )
                    if msg is not None:
                        msgs.append((msg[1], len(msgs), msg[0], msg[2]))
                at += 9 + length
        msgs.sort(key=lambda m: (m[0], m[1]))
        return msgs

    def _source(
        self, seg: _Segment, order: int, topics: frozenset[str]
    ) -> Iterator[tuple[int, int, int, Any, Any]]:
        yield seg.start_ns, order, -1, None, None  # placeholder: loads nothing until due
        for i, (log_ns, _, key, data) in enumerate(self._load(seg)):
            if self._channels[key][0] in topics:
                yield log_ns, order, i, key, data

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:
        segs = sorted((s for s in self._segments if s.topics & topics), key=lambda s: s.start_ns)
        sources = [self._source(s, i, topics) for i, s in enumerate(segs)]
        for log_ns, _, _, key, data in heapq.merge(*sources):
            if key is None:
                continue
            dec = self._decoder(key)
            if isinstance(dec, str):  # pragma: no cover - problem() ran before
                raise BagFormatError(dec)
            raw = _unzstd(data) if self._message_compression else bytes(data)
            yield self._channels[key][0], self._msgtype(key), log_ns, raw, dec
        if self._damage is not None:
            raise self._damage
