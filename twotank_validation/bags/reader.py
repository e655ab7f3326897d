"""One streaming iterator over recorded data, whatever the storage.

Reads rosbag2 bags in MCAP and SQLite3 storage (a bag directory with ``metadata.yaml``, or
the ``.mcap``/``.db3`` file inside one) through :class:`rosbags.highlevel.AnyReader`, and
plain MCAP files written by other ROS 2 tools (no ``metadata.yaml``) through
:func:`mcap.reader.make_reader`'s seeking reader with :class:`mcap_ros2.decoder.DecoderFactory`.
Messages come out decoded, in log-time order, one at a time (memory stays bounded by about
one MCAP chunk, whatever the length of the bag), with the attribute access of rclpy messages
(``msg.header.stamp.sec``, ``msg.fluid_pressure``, ``msg.hot``, ...).

Custom types are rebuilt from the definitions stored in the bag. Where a bag carries none
(SQLite3 bags of ROS 2 Humble and older), the ROS 2 Kilted types and this package's
``twotank_validation_msgs`` (from ``<sys.prefix>/share/twotank_validation_msgs/msg``, a colcon
prefix in ``AMENT_PREFIX_PATH``, or the repository's ``msg/``) are used instead.

Damage. When the index of a bag cannot be used (an MCAP file cut short by a killed recorder
has no summary and no footer; a truncated SQLite3 file fails the index queries; counts or
time ranges contradict each other), the reader falls back to a scan that recovers everything
before the damage. MCAP: every complete record up to the first bad one, including the
complete messages at the head of an uncompressed chunk the file cuts short; the scan at open
notes each chunk's byte and time range (an index rebuilt from the data) and the messages are
then merged in log-time order, chunk by chunk. SQLite3: every row SQLite still returns, in
time order through the timestamp index, or in insertion order through the table if that
reaches further (``writable_schema`` lets SQLite use the pages a truncated file has).
``info.damage`` says what was found. :meth:`BagReader.messages` yields the readable messages
first and raises :class:`BagCorruptError` (``messages_read``, ``last_good_ns``) where the
damage starts; through an index, reading fewer messages than it lists or going back in time
is damage too. Every error of this module is a :class:`BagError`; errors of the underlying
libraries (rosbags, mcap, sqlite3, yaml, struct, decompressors) are wrapped ``from`` the
original. The reader never loops on garbage: every loop advances through a file of known
size, record lengths are checked against it, and decompression stops at the declared size.

Layout (as rosbags splits its own): this module is the facade (:func:`open_bag`,
:class:`BagReader`, the choice of backend); the backends are
:mod:`~twotank_validation.bags.storage_rosbags` (rosbag2 through rosbags' index),
:mod:`~twotank_validation.bags.storage_mcap` (plain MCAP through its summary),
:mod:`~twotank_validation.bags.scan` (MCAP without its index) and
:mod:`~twotank_validation.bags.salvage_sqlite` (SQLite3 row by row), behind
:mod:`~twotank_validation.bags.backend`; decoding is :mod:`~twotank_validation.bags.decode`;
:meth:`BagReader.field_batches` moves the messages as arrays
(:mod:`~twotank_validation.bags.columnar`: indexed MCAP chunks whole); the errors are in
:mod:`~twotank_validation.bags.bag_errors`, what comes out in
:mod:`~twotank_validation.bags.records`.

This module (through those) imports rosbags, mcap and mcap-ros2-support, never rclpy.
"""

from __future__ import annotations

import contextlib
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path, PurePath
from types import TracebackType
from typing import Any, Final, Self

import numpy as np
import yaml

from twotank_validation.bags.backend import _Backend, _Damage, _NeedScan
from twotank_validation.bags.bag_errors import (
    BagCorruptError,
    BagEmptyError,
    BagError,
    BagFormatError,
    BagNotFoundError,
    TopicMissingError,
    TopicTypeError,
)
from twotank_validation.bags.columnar import _Channel, _Columns
from twotank_validation.bags.decode import _decode_columns, _decode_fields, _RawBatch
from twotank_validation.bags.records import (
    STORAGE_MCAP,
    STORAGE_MCAP_PLAIN,
    STORAGE_SQLITE3,
    BagInfo,
    BagMessage,
    FieldBatch,
    _fmt_ns,
    _norm_type,
    _short,
)
from twotank_validation.bags.salvage_sqlite import _SqliteScanBackend
from twotank_validation.bags.scan import _MCAP_MAGIC, _McapScanBackend
from twotank_validation.bags.storage_mcap import _PlainMcapBackend
from twotank_validation.bags.storage_rosbags import _RosbagsBackend

__all__ = ["BagReader", "expected_types", "open_bag"]

_SQLITE_MAGIC: Final = b"SQLite format 3\x00"
_YAML_LOADER: Final = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's, if built


_REPAIR_HINT: Final = (
    "re-copy the recording, or repair it (`mcap recover` for MCAP, the sqlite3 shell's "
    "`.recover` for SQLite3)"
)


def expected_types() -> dict[str, tuple[str, ...]]:
    """Accepted message types of the validator's default topics (names may be remapped)."""
    from twotank_validation.online.streams import STREAM_TYPES  # noqa: PLC0415 - keeps the reader light

    return {stream: (msgtype,) for stream, msgtype in STREAM_TYPES.items()}


def open_bag(path: str | Path) -> BagReader:
    """Open a bag for reading; use it as a context manager.

    Args:
        path: a rosbag2 directory (MCAP or SQLite3 storage), its ``metadata.yaml``, the
            ``.mcap``/``.db3`` file inside one, or a plain MCAP file.

    Raises:
        BagNotFoundError: The path does not exist.
        BagFormatError: The path is not a bag, or its metadata cannot be read.
    """
    return BagReader(path)


# --------------------------------------------------------------------------- opening


def _load_metadata(bagdir: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping of a bag's metadata.yaml, checked."""
    meta = bagdir / "metadata.yaml"
    hint = (
        f"restore {meta} (`ros2 bag reindex {bagdir}` regenerates it), or open the storage "
        "file inside the directory directly"
    )
    try:
        doc = yaml.load(meta.read_text(encoding="utf-8"), Loader=_YAML_LOADER)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise BagFormatError(
            f"bag {bagdir}: cannot read {meta.name} ({_short(err)}); {hint}"
        ) from err
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    problem = None
    if not isinstance(info, dict):
        problem = "it has no 'rosbag2_bagfile_information' mapping"
    elif info.get("storage_identifier") not in (STORAGE_MCAP, STORAGE_SQLITE3):
        problem = (
            f"storage {info.get('storage_identifier')!r} is not supported "
            f"(only {STORAGE_MCAP!r} and {STORAGE_SQLITE3!r})"
        )
    elif not isinstance(files := info.get("relative_file_paths"), list) or not all(
        isinstance(x, str) and x for x in files
    ):
        problem = "'relative_file_paths' is not a list of file names"
    if problem is not None:
        raise BagFormatError(
            f"bag {bagdir}: {meta.name} is not rosbag2 metadata: {problem}; {hint}"
        )
    assert isinstance(info, dict)
    return info


def _custom_data(shown: Path) -> dict[str, str]:
    """The ``custom_data`` strings of the metadata.yaml beside or in ``shown`` ({} if none)."""
    bagdir = shown if shown.is_dir() else shown.parent
    if not (bagdir / "metadata.yaml").is_file():
        return {}
    try:
        info = _load_metadata(bagdir)
    except BagFormatError:
        return {}  # a broken metadata.yaml: the bag is read without it (see info.damage)
    data = info.get("custom_data")
    if not isinstance(data, Mapping):
        return {}
    return {str(k): v for k, v in data.items() if isinstance(v, str)}


def _bag_files(bagdir: Path, info: Mapping[str, Any]) -> list[Path]:
    return [bagdir / PurePath(x).name for x in info["relative_file_paths"]]


def _open_rosbag2(bagdir: Path, info: Mapping[str, Any] | None = None) -> _Backend:
    info = _load_metadata(bagdir) if info is None else info
    storage = str(info["storage_identifier"])
    files = _bag_files(bagdir, info)
    if missing := [f.name for f in files if not f.is_file()]:
        raise BagFormatError(
            f"bag {bagdir}: metadata.yaml lists {', '.join(missing)}, which "
            f"{'is' if len(missing) == 1 else 'are'} not in the directory: the bag is incomplete; "
            "copy the missing files, or open a storage file on its own"
        )
    mode = str(info.get("compression_mode") or "").lower()
    try:
        return _RosbagsBackend(bagdir, storage, bagdir)
    except Exception as err:  # any failure of the index path: scan instead
        reason = _why(err)
        if mode == "file":
            raise BagCorruptError(
                f"bag {bagdir} cannot be read: {reason}; its files are compressed whole, so "
                f"nothing can be recovered by a scan: {_REPAIR_HINT}"
            ) from err
        if storage == STORAGE_MCAP:
            if any(not _is_mcap(_head(f), f) for f in files):
                raise BagFormatError(
                    f"bag {bagdir}: metadata.yaml says MCAP storage but its files are not MCAP "
                    f"({reason})"
                ) from err
            return _McapScanBackend(
                files, STORAGE_MCAP, bagdir, reason=reason, message_compression=mode == "message"
            )
        return _SqliteScanBackend(
            files, bagdir, reason=reason, message_compression=mode == "message"
        )


def _why(err: Exception) -> str:
    """Why the index path failed, for ``info.damage``."""
    if isinstance(err, _NeedScan):
        return str(err)
    return f"its index could not be read ({_short(err)})"


def _head(path: Path) -> bytes:
    try:
        with path.open("rb") as f:
            return f.read(16)
    except OSError as err:
        raise BagFormatError(
            f"{path} cannot be read ({_short(err)}): check its permissions"
        ) from err


def _is_mcap(head: bytes, path: Path) -> bool:
    if head.startswith(_MCAP_MAGIC):
        return True
    return path.suffix == ".mcap" and _MCAP_MAGIC.startswith(head)


def _is_sqlite(head: bytes, path: Path) -> bool:
    if head.startswith(_SQLITE_MAGIC):
        return True
    return path.suffix == ".db3" and _SQLITE_MAGIC.startswith(head)


def _open_file(path: Path) -> _Backend:  # noqa: PLR0911 - one return per kind of file
    head = _head(path)
    meta = path.parent / "metadata.yaml"
    in_bag = meta.is_file()
    if in_bag:
        try:
            info = _load_metadata(path.parent)
        except BagFormatError:
            info = None  # a broken metadata.yaml: read the file on its own
        if info is not None and [f.name for f in _bag_files(path.parent, info)] == [path.name]:
            return _open_rosbag2(path.parent, info)
    if _is_mcap(head, path):
        if in_bag:
            try:
                return _RosbagsBackend(path, STORAGE_MCAP, path)
            except Exception as err:  # scan instead
                return _McapScanBackend(
                    [path],
                    STORAGE_MCAP,
                    path,
                    reason=_why(err),
                )
        try:
            return _PlainMcapBackend(path)
        except _NeedScan as err:  # no usable summary: scan instead
            return _McapScanBackend(
                [path], STORAGE_MCAP_PLAIN, path, reason=str(err), benign=err.benign
            )
        except Exception as err:  # an unreadable summary: scan instead
            why = _why(err)
            return _McapScanBackend([path], STORAGE_MCAP_PLAIN, path, reason=why)
    if _is_sqlite(head, path):
        if path.suffix == ".db3":
            try:
                return _RosbagsBackend(path, STORAGE_SQLITE3, path)
            except Exception as err:  # scan instead
                reason = _why(err)
        else:
            reason = "a SQLite3 file without the .db3 suffix"
        return _SqliteScanBackend([path], path, reason=reason, message_compression=False)
    raise BagFormatError(
        f"{path} is not a bag: it is neither MCAP nor SQLite3 (it starts with {head[:8]!r}); "
        "pass a rosbag2 directory (with metadata.yaml), an .mcap file or a .db3 file"
    )


def _open_backend(path: Path) -> _Backend:
    try:
        exists = path.exists()
        is_dir = path.is_dir()
    except OSError as err:  # e.g. a name too long
        raise BagFormatError(f"{path} cannot be accessed ({_short(err)})") from err
    if not exists:
        raise BagNotFoundError(
            f"bag {path} does not exist: pass a rosbag2 directory (with metadata.yaml), the "
            ".mcap/.db3 file inside one, or a plain .mcap file"
        )
    if is_dir:
        if not (path / "metadata.yaml").is_file():
            storage_files = sorted(
                p.name for p in path.iterdir() if p.suffix in (".mcap", ".db3") and p.is_file()
            )
            hint = (
                f"; it holds {', '.join(storage_files[:5])}: open such a file directly, or "
                f"regenerate the metadata with `ros2 bag reindex {path}`"
                if storage_files
                else ""
            )
            raise BagFormatError(
                f"{path} is a directory but not a rosbag2 bag: no metadata.yaml{hint}"
            )
        return _open_rosbag2(path)
    if path.name == "metadata.yaml":
        return _open_rosbag2(path.parent)
    return _open_file(path)


# --------------------------------------------------------------------------- the reader


class BagReader:
    """An open bag: :attr:`info`, :meth:`check_topics` and the :meth:`messages` stream.

    Topic names are matched exactly, and a relative name also matches its absolute form in
    the root namespace (``height`` finds ``/height``, as rosbag2 records it);
    :meth:`resolve_topic` tells which. Create with :func:`open_bag`.

    Attributes:
        info: what the bag holds (see :class:`BagInfo`).
    """

    def __init__(self, path: str | Path) -> None:
        """Open ``path`` (see :func:`open_bag`)."""
        self._closed = True
        bag = Path(path)
        try:
            self._backend = _open_backend(bag)
        except BagError:
            raise
        except OSError as err:
            raise BagFormatError(
                f"{bag} cannot be read ({_short(err)}): check that it is readable"
            ) from err
        except Exception as err:  # whatever a library raises on garbage
            raise BagCorruptError(
                f"bag {bag} cannot be read ({_short(err)}): {_REPAIR_HINT}"
            ) from err
        self._closed = False
        b = self._backend
        self.info = BagInfo(
            path=b.shown,
            storage=b.storage,
            topics={t: " | ".join(v) for t, v in sorted(b.topics.items())},
            message_counts={t: b.counts.get(t, 0) for t in sorted(b.topics)},
            start_ns=b.start_ns,
            end_ns=b.end_ns,
            damage=b.damage,
            custom_data=_custom_data(Path(b.shown)),
        )

    # -- context manager
    def __enter__(self) -> Self:
        """Return the reader itself."""
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Close the bag."""
        self.close()

    def close(self) -> None:
        """Release the bag's files (idempotent)."""
        if not self._closed:
            self._closed = True
            with contextlib.suppress(Exception):  # closing a damaged file must not raise
                self._backend.close()

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f"bag {self.info.path} is closed: use it inside `with open_bag(...)`")

    # -- topics
    def resolve_topic(self, name: str) -> str | None:
        """The bag's name for a requested topic (``x`` also finds ``/x``), or None."""
        topics = self._backend.topics
        if name in topics:
            return name
        if not name.startswith("/") and f"/{name}" in topics:
            return f"/{name}"
        return None

    def float_fields(self, topic: str) -> tuple[str, ...] | None:
        """The float64 fields of ``topic``'s type if it is ``Header header`` + float64 fields.

        Those are the types :meth:`field_batches` decodes in bulk (the validator's three
        interface types among them), as the bag's own definitions describe them; None for
        any other type, a topic of several types or definitions, or one not in the bag.
        """
        self._check_open()
        name = self.resolve_topic(topic)
        if name is None:
            return None
        try:
            codecs = self._backend.topic_codecs(name)
        except Exception:  # a broken definition: not a fixed layout
            return None
        if not codecs:
            return None
        layouts = {c.layout() for c in codecs}
        return layouts.pop() if len(layouts) == 1 else None

    def _listing(self) -> str:
        if not self.info.topics:
            return "no topics"
        return ", ".join(
            f"{t} ({ty}, {self.info.message_counts.get(t, 0)} messages)"
            for t, ty in self.info.topics.items()
        )

    def _damage_note(self) -> str:
        return f" (the bag is damaged: {self.info.damage})" if self.info.damage else ""

    def _total(self) -> int:
        return sum(self.info.message_counts.values())

    def _raise_if_empty(self) -> None:
        if self._total() == 0 and self.info.damage is None:
            raise BagEmptyError(
                f"bag {self.info.path} holds no messages ({self._listing()}): nothing to read; "
                "check that the recorder received data on the topics before it stopped"
            )

    def _missing_error(
        self, missing: Sequence[str], *, empty: Sequence[str] = ()
    ) -> TopicMissingError:
        parts = []
        for name in missing:
            if name in empty:
                parts.append(f"{name!r} (recorded, but it holds no readable message)")
            else:
                parts.append(repr(name))
        return TopicMissingError(
            f"bag {self.info.path} lacks topic(s) {', '.join(parts)}; it has: {self._listing()}"
            f"{self._damage_note()}. Map the streams to the bag's topic names, or record the "
            "missing topics",
            missing,
            self.info.topics,
        )

    def check_topics(self, expected: Mapping[str, str | tuple[str, ...]]) -> None:
        """Check that the bag has the expected topics with an accepted type.

        Args:
            expected: topic name -> accepted message type(s).

        Raises:
            BagEmptyError: The bag (undamaged) holds no message at all.
            TopicMissingError: Some topics are absent or hold no message (all are named).
            TopicTypeError: A topic carries another type (the first such topic).
        """
        self._check_open()
        self._raise_if_empty()
        missing: list[str] = []
        empty: list[str] = []
        for name in expected:
            found = self.resolve_topic(name)
            if found is None:
                missing.append(name)
            elif self._backend.counts.get(found, 0) == 0:
                missing.append(name)
                empty.append(name)
        if missing:
            raise self._missing_error(missing, empty=empty)
        for name, accepted in expected.items():
            ok = tuple(
                _norm_type(t) for t in ((accepted,) if isinstance(accepted, str) else accepted)
            )
            bag_name = self.resolve_topic(name)
            assert bag_name is not None
            found_types = self._backend.topics[bag_name]
            if any(t not in ok for t in found_types):
                found = " | ".join(found_types)
                raise TopicTypeError(
                    f"bag {self.info.path}: topic {bag_name!r} carries {found}, expected "
                    f"{' or '.join(ok)}; map the stream to a topic of that type",
                    name,
                    found,
                    ok,
                )

    # -- messages
    def _wanted(self, topics: Sequence[str]) -> dict[str, str]:
        """Bag topic -> requested name, after the checks :meth:`messages` documents."""
        self._check_open()
        names = [topics] if isinstance(topics, str) else list(dict.fromkeys(topics))
        self._raise_if_empty()
        wanted: dict[str, str] = {}
        missing = []
        for name in names:
            found = self.resolve_topic(name)
            if found is None:
                missing.append(name)
            else:
                wanted.setdefault(found, name)
        if missing:
            raise self._missing_error(missing)
        for bag_name in wanted:
            try:
                problem = self._backend.problem(bag_name)
            except Exception as err:  # a broken stored definition
                problem = f"its definition cannot be used ({_short(err)})"
            if problem is not None:
                raise BagFormatError(
                    f"bag {self.info.path}: topic {bag_name!r} cannot be decoded: {problem}"
                )
        return wanted

    def messages(self, topics: Sequence[str]) -> Iterator[BagMessage]:
        """Stream the decoded messages of ``topics`` in log-time order.

        Memory stays bounded whatever the bag's length. On a damaged bag every message
        readable before the damage is yielded first, then :class:`BagCorruptError` is raised.
        (One exception: a SQLite3 file whose time index is damaged is read in insertion
        order, the recorder's write order; ``info.damage`` says so.)

        Args:
            topics: topic names (a single string is one topic).

        Raises:
            BagEmptyError: The bag (undamaged) holds no message at all.
            TopicMissingError: A topic is not in the bag (checked at the call).
            BagFormatError: A topic's messages cannot be decoded (unknown type, not CDR).
            BagCorruptError: While iterating, at the first unreadable data.
        """
        return self._stream(self._wanted(topics))

    def field_batches(
        self,
        topics: Sequence[str],
        fields: Mapping[str, Sequence[str]],
        *,
        size: int = 4096,
        columnar: bool = True,
    ) -> Iterator[FieldBatch]:
        """Stream the header stamps and float fields of ``topics``, many messages at a time.

        The same messages, in the same order, with the same errors as :meth:`messages`,
        reduced to ``header.stamp`` (ns) and the requested fields (``float(msg.<field>)``).
        Messages of a type whose definition is ``std_msgs/Header header`` followed by
        float64 fields (e.g. sensor_msgs/FluidPressure and Temperature) are decoded in bulk
        with numpy; any message that does not fit that layout goes through the generic
        deserialiser, as in :meth:`messages`. The messages themselves are read as arrays
        too: the chunks of an indexed rosbag2 MCAP bag whole, through their message index
        (any other storage message by message, then packed).

        Args:
            topics: topic names.
            fields: requested topic name -> names of float fields to read (a topic not
                listed reads none).
            size: messages per batch, at most.
            columnar: False reads and decodes row by row (the messages of :meth:`messages`,
                packed into lists, each group of equal layout decoded in bulk): the same
                batches, slower; kept as a reference.

        Raises:
            BagEmptyError, TopicMissingError, BagFormatError, BagCorruptError: as
                :meth:`messages`.
        """
        wanted = self._wanted(topics)
        if columnar:
            return self._column_stream(wanted, fields, max(1, size))
        return self._field_stream(wanted, fields, max(1, size))

    def _corrupt(
        self, what: str, read: int, last: int | None, offset: int | None
    ) -> BagCorruptError:
        got = f"{read} message(s) read" + (
            f", the last at t={_fmt_ns(last)}" if last is not None else ""
        )
        used = (
            "the messages before it were delivered"
            if read
            else "no message of the requested topics could be read"
        )
        return BagCorruptError(
            f"bag {self.info.path}: {what} ({got}): the recording was interrupted or the file "
            f"was damaged; {used}. To get more: {_REPAIR_HINT}",
            messages_read=read,
            last_good_ns=last,
            offset=offset,
        )

    def _undecodable(self, err: Exception, read: int, last: int | None) -> BagCorruptError:
        return self._corrupt(
            f"the data cannot be read past this point ({_short(err)})", read, last, None
        )

    def _raw_batches(self, wanted: dict[str, str], size: int) -> Iterator[_RawBatch]:
        """The undecoded messages in batches; the checks and errors of :meth:`messages`.

        An error is raised after the batch of the messages read before it.
        """
        backend = self._backend
        it = backend.iter(frozenset(wanted))
        read = 0
        last: int | None = None
        per_topic: Counter[str] = Counter()
        failure: BagError | None = None
        cause: BaseException | None = None
        ordered = backend.ordered
        try:
            while failure is None:
                self._check_open()
                batch = _RawBatch([], [], [], [], [])
                add_topic, add_type = batch.topic.append, batch.msgtype.append
                add_time, add_data = batch.log_time_ns.append, batch.data.append
                add_codec = batch.codec.append
                prev = last
                try:
                    for topic, msgtype, t, data, codec in it:
                        if ordered and prev is not None and t < prev:
                            failure = self._corrupt(
                                f"its index is inconsistent: log time goes back from "
                                f"{_fmt_ns(prev)} to {_fmt_ns(t)}",
                                read + len(batch.topic),
                                prev,
                                None,
                            )
                            break
                        add_topic(topic)
                        add_type(msgtype)
                        add_time(t)
                        add_data(data)
                        add_codec(codec)
                        prev = t
                        if len(batch.topic) >= size:
                            break
                except _Damage as err:
                    failure, cause = (
                        self._corrupt(err.where(), read + len(batch), prev, err.offset),
                        err,
                    )
                except BagError:
                    raise
                except Exception as err:  # any library error is damage here
                    failure, cause = self._undecodable(err, read + len(batch), prev), err
                n = len(batch)
                if n:
                    read += n
                    last = prev
                    per_topic.update(batch.topic)
                    yield batch
                if n < size:
                    break
            if failure is not None:
                raise failure from cause
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                with contextlib.suppress(Exception):  # the stream is being abandoned
                    close()
        self._check_index_counts(wanted, per_topic, read, last)

    def _check_index_counts(
        self, wanted: Mapping[str, str], per_topic: Counter[str], read: int, last: int | None
    ) -> None:
        """Raise :class:`BagCorruptError` where an indexed bag gave fewer messages than listed.

        Raised after the messages read; a bag without an index is not checked.
        """
        if not self._backend.indexed:
            return
        short = {t: (per_topic[t], self._backend.counts.get(t, 0)) for t in wanted}
        short = {t: v for t, v in short.items() if v[0] < v[1]}
        if short:
            detail = ", ".join(f"{t}: {got} of {want}" for t, (got, want) in short.items())
            raise self._corrupt(
                f"fewer messages could be read than its index lists ({detail})", read, last, None
            )

    def _stream(self, wanted: dict[str, str]) -> Iterator[BagMessage]:
        read = 0
        last: int | None = None
        for batch in self._raw_batches(wanted, 256):
            for topic, msgtype, t, data, codec in zip(
                batch.topic, batch.msgtype, batch.log_time_ns, batch.data, batch.codec, strict=True
            ):
                self._check_open()
                try:
                    msg = codec.decode(data)
                except BagError:
                    raise
                except Exception as err:  # an undecodable message is damage here
                    raise self._undecodable(err, read, last) from err
                yield BagMessage(wanted[topic], msgtype, t, msg)
                read += 1
                last = t

    def _field_stream(
        self, wanted: dict[str, str], fields: Mapping[str, Sequence[str]], size: int
    ) -> Iterator[FieldBatch]:
        return self._decoded(self._raw_batches(wanted, size), _decode_fields, wanted, fields)

    def _decoded(
        self,
        batches: Iterator[Any],
        decode: Callable[..., tuple[FieldBatch, Exception | None]],
        wanted: dict[str, str],
        fields: Mapping[str, Sequence[str]],
    ) -> Iterator[FieldBatch]:
        """Undecoded batches (rows or columns) decoded into field batches.

        An undecodable message ends the stream with :class:`BagCorruptError`, after the
        messages before it.
        """
        names = tuple(dict.fromkeys(wanted.values()))
        index = {bag: names.index(name) for bag, name in wanted.items()}
        spec = {bag: tuple(fields.get(name, ())) for bag, name in wanted.items()}
        width = max((len(v) for v in spec.values()), default=0)
        read = 0
        last: int | None = None
        for batch in batches:
            self._check_open()
            out, failure = decode(batch, index, spec, width, names)
            if len(out):
                yield out
                read += len(out)
                last = int(out.log_time_ns[-1])
            if failure is not None:
                raise self._undecodable(failure, read, last) from failure

    def _column_batches(self, wanted: dict[str, str], size: int) -> Iterator[_Columns]:
        """The undecoded messages as columns: the checks and errors of :meth:`_raw_batches`."""
        backend = self._backend
        channels: list[_Channel] = []
        it = backend.iter_columns(frozenset(wanted), channels)
        read = 0
        last: int | None = None
        per_topic: Counter[str] = Counter()
        failure: BagError | None = None
        cause: BaseException | None = None
        ordered = backend.ordered
        try:
            while failure is None:
                self._check_open()
                try:
                    cols = next(it, None)
                except _Damage as err:
                    failure, cause = self._corrupt(err.where(), read, last, err.offset), err
                    break
                except BagError:
                    raise
                except Exception as err:  # any library error is damage here
                    failure, cause = self._undecodable(err, read, last), err
                    break
                if cols is None:
                    break
                t = cols.log_time_ns
                if ordered and len(t):
                    prev = np.empty(len(t), dtype=np.int64)
                    prev[0] = t[0] if last is None else last
                    prev[1:] = t[:-1]
                    back = np.flatnonzero(t < prev)
                    if len(back):
                        k = int(back[0])
                        was = int(prev[k])
                        cols = cols.take(slice(0, k))
                        failure = self._corrupt(
                            f"its index is inconsistent: log time goes back from "
                            f"{_fmt_ns(was)} to {_fmt_ns(int(t[k]))}",
                            read + k,
                            was,
                            None,
                        )
                for lo in range(0, len(cols), size):
                    part = cols.take(slice(lo, lo + size))
                    read += len(part)
                    last = int(part.log_time_ns[-1])
                    counts = np.bincount(part.chan, minlength=len(channels))
                    for c in np.flatnonzero(counts).tolist():
                        per_topic[channels[c][0]] += int(counts[c])
                    yield part
            if failure is not None:
                raise failure from cause
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                with contextlib.suppress(Exception):  # the stream is being abandoned
                    close()
        self._check_index_counts(wanted, per_topic, read, last)

    def _column_stream(
        self, wanted: dict[str, str], fields: Mapping[str, Sequence[str]], size: int
    ) -> Iterator[FieldBatch]:
        return self._decoded(self._column_batches(wanted, size), _decode_columns, wanted, fields)
