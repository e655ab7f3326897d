"""Undecoded messages as arrays, and indexed MCAP chunks read into them without a Python loop.

:class:`_Columns` is what the reader's columnar path moves around: the channel, log time and
the place of the CDR bytes of many messages, as numpy arrays over a few byte buffers (an MCAP
chunk, or the joined bytes of messages read one by one). ``_rows_to_columns`` packs any
backend's per-message stream into it. ``_McapColumns`` reads the chunks of indexed rosbag2
MCAP files (what :class:`~twotank_validation.bags.storage_rosbags._RosbagsBackend` opens)
into it: each chunk is decompressed with rosbags' own ``decompress`` (the same size and
checksum checks) and its records are found through the chunk's message index, checked
against the records themselves (each record must end where the next one starts, the last at
the chunk's end), so the messages are exactly those rosbags' record-by-record walk finds,
in rosbags' order (a stable sort by log time within a chunk, chunks merged by log time and
then file offset). Anything else (an index that does not match the records, a checksum,
a chunk that cannot be read) hands over to rosbags' own iterator, which skips the messages
already delivered and goes on, errors included, as the per-message path does.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from twotank_validation.bags.decode import _Codec

_Channel = tuple[str, str, _Codec]
"""One source of messages: bag topic, message type, codec."""

_MESSAGE_OP: Final = 0x05
_INDEX_OP: Final = 0x07
_RECORD_HEAD: Final = 9  # opcode (1) + record length (8)
_MESSAGE_HEAD: Final = 22  # channel (2) + sequence (4) + log time (8) + publish time (8)
_MAX_NS: Final = 2**63


@dataclass
class _Columns:
    """Consecutive undecoded messages (in the order they are delivered), as arrays.

    Attributes:
        channels: every channel seen so far (shared, may grow); ``chan`` indexes it.
        chan: (n,) intp, channel of each message.
        log_time_ns: (n,) int64, log times.
        buf: (n,) intp, which of ``bufs`` holds the message's bytes.
        start: (n,) int64, offset of its CDR bytes in that buffer.
        size: (n,) int64, their length.
        bufs: uint8 buffers.
        beyond: (n,) bool, or None (none): log time past the int64 range (stored as its
            maximum); such a message cannot be delivered in a batch: decoding stops there.
    """

    channels: list[_Channel]
    chan: np.ndarray
    log_time_ns: np.ndarray
    buf: np.ndarray
    start: np.ndarray
    size: np.ndarray
    bufs: list[np.ndarray]
    beyond: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.chan)

    def take(self, rows: slice) -> _Columns:
        """A contiguous part (the same buffers)."""
        return _Columns(
            self.channels,
            self.chan[rows],
            self.log_time_ns[rows],
            self.buf[rows],
            self.start[rows],
            self.size[rows],
            self.bufs,
            None if self.beyond is None else self.beyond[rows],
        )

    def data(self, i: int) -> bytes:
        """The CDR bytes of message ``i``."""
        s = int(self.start[i])
        return self.bufs[int(self.buf[i])][s : s + int(self.size[i])].tobytes()


def _rows_to_columns(
    rows: Iterable[tuple[str, str, int, Any, _Codec]],
    channels: list[_Channel],
    piece: int = 1024,
) -> Iterator[_Columns]:
    """A backend's per-message stream as columns, ``piece`` messages at a time.

    An error of the stream is raised after the columns of the messages before it.
    """
    known: dict[tuple[str, str, int], int] = {}
    it = iter(rows)
    while True:
        chan: list[int] = []
        times: list[int] = []
        datas: list[bytes] = []
        failure: BaseException | None = None
        try:
            for topic, msgtype, t, data, codec in it:
                key = (topic, msgtype, id(codec))
                c = known.get(key)
                if c is None:
                    c = known[key] = len(channels)
                    channels.append((topic, msgtype, codec))
                chan.append(c)
                times.append(t)
                datas.append(bytes(data))
                if len(chan) >= piece:
                    break
        except BaseException as err:  # delivered after the messages before it
            failure = err
        if chan:
            sizes = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
            starts = np.zeros(len(datas), dtype=np.int64)
            np.cumsum(sizes[:-1], out=starts[1:])
            try:
                stamps = np.array(times, dtype=np.int64)
                beyond = None
            except OverflowError:  # an MCAP log time is unsigned
                beyond = np.array([t >= _MAX_NS for t in times], dtype=bool)
                stamps = np.array([min(t, _MAX_NS - 1) for t in times], dtype=np.int64)
            yield _Columns(
                channels,
                np.array(chan, dtype=np.intp),
                stamps,
                np.zeros(len(chan), dtype=np.intp),
                starts,
                sizes,
                [np.frombuffer(b"".join(datas), dtype=np.uint8)],
                beyond,
            )
        if failure is not None:
            raise failure
        if len(chan) < piece:
            return


class _Fallback(Exception):  # noqa: N818 - internal signal, never leaves bags/
    """The chunk cannot be read in bulk: rosbags' iterator takes over."""


def _u64(u: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Little-endian uint64 at byte offsets ``at`` of the uint8 array ``u``."""
    return np.lib.stride_tricks.sliding_window_view(u, 8)[at].view("<u8").ravel()


def _chain(u: np.ndarray, offs: np.ndarray) -> np.ndarray | None:
    """Record lengths if the records at ``offs`` (sorted) tile ``u`` from there to its end."""
    size = len(u)
    if len(offs) == 0 or offs[-1] + _RECORD_HEAD > size:
        return None
    lens = _u64(u, offs + 1)
    if (lens > size).any():
        return None
    ends = offs + _RECORD_HEAD + lens.astype(np.int64)
    if ends[-1] != size or (ends[:-1] != offs[1:]).any():
        return None
    return lens.astype(np.int64)


def _walk(raw: bytes, stop: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Message records, record by record (rosbags' walk), up to ``stop`` (the end if None).

    Returns the offsets and lengths of the message records and where the walk ended (a
    record boundary at or past ``stop``).
    """
    offs, lens = [], []
    pos, size = 0, len(raw)
    end = size if stop is None else min(stop, size)
    unpack = struct.Struct("<Q").unpack_from
    while pos < end:
        if pos + _RECORD_HEAD > size:
            raise _Fallback("truncated record head")
        (length,) = unpack(raw, pos + 1)
        if pos + _RECORD_HEAD + length > size:
            raise _Fallback("truncated record")
        if raw[pos] == _MESSAGE_OP:
            offs.append(pos)
            lens.append(length)
        pos += _RECORD_HEAD + length
    return np.array(offs, dtype=np.int64), np.array(lens, dtype=np.int64), pos


def _records(u: np.ndarray, raw: bytes, index: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Offsets and lengths of a chunk's message records.

    The records before the first one the message index lists (a writer may put schemas and
    channels there) are walked one by one; from there on, the index must list every record
    and they must tile the chunk to its end, else the whole chunk is walked.
    """
    offs = _index_offsets(index)
    if offs is not None and len(offs):
        head_offs, _, pos = _walk(raw, int(offs[0]))
        if pos == offs[0] and not len(head_offs):
            lens = _chain(u, offs)
            if lens is not None and (u[offs] == _MESSAGE_OP).all():
                return offs, lens
    offs, lens, _ = _walk(raw)
    return offs, lens


def _index_offsets(data: bytes) -> np.ndarray | None:
    """Record offsets listed by a chunk's MessageIndex records (all channels), or None."""
    pos, size = 0, len(data)
    parts = []
    while pos < size:
        if pos + _RECORD_HEAD > size or data[pos] != _INDEX_OP:
            return None
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        body = pos + _RECORD_HEAD
        if length < 6 or body + length > size:
            return None
        (nbytes,) = struct.unpack_from("<I", data, body + 2)
        if nbytes % 16 or 6 + nbytes != length:
            return None
        entries = np.frombuffer(data, dtype="<u8", count=nbytes // 8, offset=body + 6)
        parts.append(entries[1::2])
        pos = body + length
    if not parts:
        return None
    offs = np.concatenate(parts)
    if len(offs) and offs.max() >= _MAX_NS:
        return None
    return np.sort(offs.astype(np.int64))


def _same_connection(x: Any, y: Any) -> bool:
    """Rosbags' DirectoryReader match of a storage connection ``x`` to a bag connection ``y``."""
    return bool(
        y.topic == x.topic
        and y.msgtype == x.msgtype
        and y.ext == x.ext
        and (not x.digest or not y.digest or y.digest == x.digest)
    )


class _McapColumns:
    """The messages of some connections of indexed rosbag2 MCAP files, chunk by chunk.

    Args:
        storages: rosbags' ``McapReader`` of each file, in the bag's order (open).
        conns: the wanted connections (of the bag, as rosbags' AnyReader lists them).
        channels: the channel of each connection, in the order of ``conns``.
        decompress: rosbags' chunk decompressor ``(data, compression, size, crc) -> bytes``.
        fallback: rosbags' per-message iterator over the same connections, from the start.
    """

    def __init__(
        self,
        storages: Sequence[Any],
        conns: Sequence[Any],
        channels: list[_Channel],
        decompress: Callable[[bytes, str, int, int], bytes],
        fallback: Callable[[], Iterable[tuple[str, str, int, Any, _Codec]]],
    ) -> None:
        self._storages = storages
        self._conns = conns
        self._channels = channels
        self._decompress = decompress
        self._fallback = fallback
        self.chunks_read = 0
        self.fell_back: str | None = None
        self._gen = self._columns()

    def __iter__(self) -> _McapColumns:
        return self

    def __next__(self) -> _Columns:
        return next(self._gen)

    def close(self) -> None:
        """Abandon the stream."""
        self._gen.close()

    def _columns(self) -> Generator[_Columns, None, None]:
        delivered = 0
        try:
            for storage in self._storages:
                cmap = np.full(1 << 16, -1, dtype=np.intp)
                for x in storage.connections:
                    for j, y in enumerate(self._conns):
                        if x is y or _same_connection(x, y):
                            cmap[x.id] = j
                            break
                for cols in self._file(storage, cmap):
                    delivered += len(cols)
                    yield cols
        except _Fallback as why:
            self.fell_back = str(why)
            rows = iter(self._fallback())
            for _ in range(delivered):
                next(rows)
            yield from _rows_to_columns(rows, self._channels)

    def _file(self, storage: Any, cmap: np.ndarray) -> Iterator[_Columns]:
        chunks = [
            c
            for c in storage.chunks
            if any(cmap[cid] >= 0 for cid, n in c.channel_count.items() if n and 0 <= cid < 65536)
        ]
        if not storage.chunks:
            raise _Fallback("no chunk index")
        # heapq.merge order of rosbags: each chunk enters at its start time, in list order
        chunks.sort(key=lambda c: c.message_start_time)
        pending: list[tuple[np.ndarray, ...]] = []
        for chunk in chunks:
            if pending:
                out, pending = self._emit(pending, chunk.message_start_time)
                if out is not None:
                    yield out
            got = self._chunk(storage, chunk, cmap)
            if got is not None:
                pending.append(got)
        if pending:
            out, _ = self._emit(pending, None)
            if out is not None:
                yield out

    def _emit(
        self, pending: list[tuple[np.ndarray, ...]], before: int | None
    ) -> tuple[_Columns | None, list[tuple[np.ndarray, ...]]]:
        """Messages of ``pending`` logged before ``before`` (all if None), in rosbags' order."""
        bufs = [p[0] for p in pending]
        if len(pending) == 1:
            _, chan, t, start, size, off = pending[0]
            buf = np.zeros(len(t), dtype=np.intp)
        else:
            chan = np.concatenate([p[1] for p in pending])
            t = np.concatenate([p[2] for p in pending])
            start = np.concatenate([p[3] for p in pending])
            size = np.concatenate([p[4] for p in pending])
            off = np.concatenate([p[5] for p in pending])
            buf = np.concatenate(
                [np.full(len(p[2]), k, dtype=np.intp) for k, p in enumerate(pending)]
            )
            rank = np.arange(len(t))
            order = np.lexsort((rank, off, t))
            chan, t, start, size, off, buf = (a[order] for a in (chan, t, start, size, off, buf))
        n = len(t) if before is None else int(np.searchsorted(t, before, side="left"))
        rest: list[tuple[np.ndarray, ...]] = []
        if n < len(t):
            # what stays keeps its buffers: one pending entry per buffer still used
            for k, b in enumerate(bufs):
                sel = np.flatnonzero(buf[n:] == k) + n
                if len(sel):
                    rest.append((b, chan[sel], t[sel], start[sel], size[sel], off[sel]))
        if n == 0:
            return None, rest
        cols = _Columns(self._channels, chan[:n], t[:n], buf[:n], start[:n], size[:n], bufs)
        return cols, rest

    def _chunk(self, storage: Any, chunk: Any, cmap: np.ndarray) -> tuple[np.ndarray, ...] | None:
        """One chunk's wanted messages: (buffer, chan, t, start, size, chunk offset), sorted."""
        bio = storage.bio
        base = chunk.chunk_start_offset
        try:
            bio.seek(base + _RECORD_HEAD + 24)
            head = bio.read(4)
            bio.seek(base + _RECORD_HEAD + 40 + len(chunk.compression))
            compressed = bio.read(chunk.compressed_size)
            if len(head) != 4 or len(compressed) != chunk.compressed_size:
                raise _Fallback("truncated chunk")
            (crc,) = struct.unpack("<I", head)
            raw = self._decompress(compressed, chunk.compression, chunk.uncompressed_size, crc)
            bio.seek(base + chunk.chunk_length)
            index = bio.read(chunk.message_index_length)
        except _Fallback:
            raise
        except Exception as err:  # rosbags will raise it where it reads this chunk
            raise _Fallback(f"chunk at {base}: {err}") from err
        self.chunks_read += 1
        u = np.frombuffer(raw, dtype=np.uint8)
        offs, lens = _records(u, raw, index)
        if len(offs) == 0:
            return None
        if (lens < _MESSAGE_HEAD).any():
            raise _Fallback("a message record shorter than its header")
        cid = np.lib.stride_tricks.sliding_window_view(u, 2)[offs + _RECORD_HEAD]
        cid = cid.view("<u2").ravel()
        t = _u64(u, offs + _RECORD_HEAD + 6)
        if (t >= _MAX_NS).any():
            raise _Fallback("a log time beyond int64")
        t = t.astype(np.int64)
        chan = cmap[cid]
        keep = (chan >= 0) & (t >= chunk.message_start_time) & (t <= chunk.message_end_time)
        if not keep.all():
            offs, lens, chan, t = offs[keep], lens[keep], chan[keep], t[keep]
        if len(t) == 0:
            return None
        order = np.argsort(t, kind="stable")
        start = offs[order] + _RECORD_HEAD + _MESSAGE_HEAD
        size = lens[order] - _MESSAGE_HEAD
        chunk_off = np.full(len(t), base, dtype=np.int64)
        return u, chan[order], t[order], start, size, chunk_off
