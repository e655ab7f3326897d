"""What every storage backend gives the reader, and the signals between them.

:class:`_Backend` is what :class:`~twotank_validation.bags.reader.BagReader` reads through:
topics, counts and time range at open, then the undecoded messages of some topics
(:data:`_Raw`, each with its :class:`~twotank_validation.bags.decode._Codec`). A backend
reading through an index raises :class:`_NeedScan` when the index cannot be used
(``_check_index``: counts and time range that contradict each other), and the reader falls
back to a scanning backend; a scan raises :class:`_Damage` where it stops. ``_unzstd``
decompresses the messages of message-compressed bags, bounded.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, Final

import zstandard

from twotank_validation.bags.columnar import _Channel, _Columns, _rows_to_columns
from twotank_validation.bags.decode import _Codec

_MAX_CHUNK_BYTES: Final = 1 << 31  # a chunk header claiming more is corrupt


class _Damage(Exception):  # noqa: N818 - internal signal, never leaves bags/
    """Where a linear scan stopped: file, byte offset (None if unknown), what was wrong."""

    def __init__(self, path: Path, offset: int | None, detail: str, *, truncated: bool) -> None:
        super().__init__(detail)
        self.path = path
        self.offset = offset
        self.detail = detail
        self.truncated = truncated

    def where(self) -> str:
        at = f" at byte {self.offset}" if self.offset is not None else ""
        what = "truncated" if self.truncated else "corrupt"
        return f"{self.path.name} is {what}{at} ({self.detail})"


_Raw = tuple[str, str, int, Any, _Codec]
"""What a backend yields: bag topic, message type, log time (ns), CDR bytes, codec."""


class _Backend:
    """What every storage reader provides to :class:`~twotank_validation.bags.reader.BagReader`."""

    storage: str
    shown: Path
    indexed: bool  # the counts are promised by an index: reading fewer is damage
    ordered = True  # messages come in log-time order: going back is damage
    damage: str | None = None

    def __init__(self) -> None:
        self.topics: dict[str, tuple[str, ...]] = {}
        self.counts: dict[str, int] = {}
        self.start_ns: int | None = None
        self.end_ns: int | None = None

    def problem(self, topic: str) -> str | None:  # pragma: no cover - overridden
        """Why ``topic`` cannot be decoded, or None."""
        raise NotImplementedError

    def iter(self, topics: frozenset[str]) -> Iterator[_Raw]:  # pragma: no cover - overridden
        """Decoded messages of ``topics``; may raise anything, or _Damage."""
        raise NotImplementedError

    def iter_columns(self, topics: frozenset[str], channels: list[_Channel]) -> Iterator[_Columns]:
        """The messages of :meth:`iter`, many at a time as arrays (``channels`` fills up).

        The same messages in the same order, and the same errors at the same place: an
        error is raised after the columns of the messages before it.
        """
        return _rows_to_columns(self.iter(topics), channels)

    def topic_codecs(self, topic: str) -> list[_Codec] | None:
        """The codecs ``topic``'s messages are decoded with (None: not known before reading)."""
        return None

    def close(self) -> None:  # pragma: no cover - overridden
        """Release files."""
        raise NotImplementedError


class _NeedScan(Exception):  # noqa: N818 - internal signal
    """The index cannot be used; read the file by a linear scan.

    ``benign``: the file simply has no index (valid MCAP), as opposed to an inconsistent one.
    """

    def __init__(self, reason: str, *, benign: bool = False) -> None:
        super().__init__(reason)
        self.benign = benign


def _check_index(
    counts: Mapping[str, int], total: int, start_ns: int | None, end_ns: int | None
) -> None:
    """Raise _NeedScan if an index's counts and time range contradict each other."""
    if sum(counts.values()) != total or any(n < 0 for n in counts.values()):
        raise _NeedScan(
            f"its index is inconsistent: {total} messages in all, "
            f"{sum(counts.values())} counted per topic"
        )
    if start_ns is not None and end_ns is not None and start_ns > end_ns:
        raise _NeedScan("its index is inconsistent: its time range ends before it starts")


def _unzstd(data: bytes | memoryview) -> bytes:
    parts: list[bytes] = []
    total = 0
    with zstandard.ZstdDecompressor().stream_reader(bytes(data)) as src:
        while piece := src.read(1 << 20):
            parts.append(piece)
            total += len(piece)
            if total > _MAX_CHUNK_BYTES:
                raise ValueError("a compressed message expands beyond 2 GiB")
    return b"".join(parts)
