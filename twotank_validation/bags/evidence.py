"""Evidence on an alarm: the messages around a rising alarm written to a rosbag2 MCAP bag.

:class:`EvidenceRecorder` keeps the messages the validator was fed (serialised, as received,
on their own topics and types, logged at the stamp the validator used) in a ring buffer
bounded to :attr:`~twotank_validation.online.validator_settings.EvidenceConfig.periods_before`
excitation periods. When a model's alarm rises (its report's level turns ERROR), the ring
buffer and the messages after it go to a new bag in ``EvidenceConfig.dir``, until a report
of that model carries the live diagnosis's last answer to the alarm (its
``diagnosis_max_updates``-th), or ``periods_after`` periods of data have followed the rise.
``twotank-validation diagnose BAG --model M`` reads the bag as it is: the same topics and
types as the live system, the sample and excitation periods in its metadata
(``custom_data``: ``ts_s``, ``period_samples``, and the alarm under :data:`CUSTOM_DATA_KEY`).

Never blocking: :meth:`~EvidenceRecorder.note` and :meth:`~EvidenceRecorder.on_report` only
append to a bounded deque or put to a bounded queue without waiting; a writer thread writes
the bag. When the writer falls behind by more than ``queue`` messages, messages are dropped
and counted (:attr:`EvidenceStatus.dropped`: the node says so on ``/diagnostics``).

Crash-safe: the writer flushes the bag every :data:`FLUSH_BYTES` of data and when the queue
runs dry (:meth:`~twotank_validation.bags.writer.BagWriter.flush`: the MCAP chunk closed, the
file flushed, ``metadata.yaml`` rewritten), so a bag killed at any point is a rosbag2
directory holding every flushed message; the reader scans a file without its summary.

Disk use bounded: a bag is closed at ``max_bag_mb``; before a bag is made, the oldest
evidence bags in the directory are removed so that at most ``max_bags`` remain.

This module imports rosbags (through the writer), never rclpy.
"""

from __future__ import annotations

import contextlib
import json
import queue
import re
import shutil
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from twotank_validation.bags.writer import BagWriter
from twotank_validation.defaults import NS_PER_S
from twotank_validation.errors import DatumError
from twotank_validation.online.alarm import Alarm
from twotank_validation.online.interface_map import InterfaceMap
from twotank_validation.online.validator_settings import EvidenceConfig
from twotank_validation.sim.model_record import write_interface_map

__all__ = [
    "CUSTOM_DATA_KEY",
    "FLUSH_BYTES",
    "MAP_FILE",
    "EvidenceRecorder",
    "EvidenceStatus",
    "evidence_bags",
]

CUSTOM_DATA_KEY: Final = "twotank_validation.evidence"
"""Key of the alarm's description (JSON) in an evidence bag's custom_data."""

MAP_FILE: Final = "interface_map.yaml"
"""The validator's interface map, written inside each evidence bag's directory."""

FLUSH_BYTES: Final = 64 * 1024
"""Message bytes after which the writer flushes the bag (an MCAP chunk each)."""

_NAME: Final = re.compile(r"^evidence-\d{8}T\d{6}-\d{4}-")
_OVERHEAD: Final = 64  # bytes per message besides its data (record, index): the size estimate


def evidence_bags(directory: str | Path) -> list[Path]:
    """The evidence bags in ``directory``, oldest first (their names sort by creation time)."""
    d = Path(directory)
    if not d.is_dir():
        return []
    return sorted(p for p in d.iterdir() if p.is_dir() and _NAME.match(p.name))


@dataclass
class EvidenceStatus:
    """What the recorder did (a copy: :meth:`EvidenceRecorder.status`).

    Attributes:
        bags: the bags made, oldest first (removed ones included).
        writing: the bag being written ("" when none).
        state: ``off``, ``armed`` (buffering), ``writing`` or ``error``.
        dropped: messages dropped because the writer fell behind (whole run).
        over_size: messages not written because a bag reached ``max_bag_mb``.
        removed: old bags removed to keep ``max_bags``.
        error: the last writer error ("" when none).
        by_model: per model, the bag of its latest alarm.
    """

    bags: list[str] = field(default_factory=list)
    writing: str = ""
    state: str = "armed"
    dropped: int = 0
    over_size: int = 0
    removed: int = 0
    error: str = ""
    by_model: dict[str, str] = field(default_factory=dict)


@dataclass
class _Episode:
    path: Path
    models: list[str]
    rise_ns: int
    end_ns: int


_Message = tuple[str, int, bytes]  # topic, log time (ns), CDR bytes


class EvidenceRecorder:
    """Ring buffer of the fed messages and a writer thread for the evidence bags.

    Args:
        config: the evidence settings (``config.dir`` non-empty).
        topics: topic -> message type of every topic the validator reads.
        ts_s: sample period (s).
        period_samples: excitation period (samples).
        messages_per_sample: messages of all topics per sample (the ring buffer's bound is
            ``periods_before * period_samples * messages_per_sample``).
        needed_periods: periods one judged window needs (settling + window): the ring
            buffer must hold at least this many.
        models: the models validated.
        interface: the validator's interface map, written into each bag as
            :data:`MAP_FILE` (``diagnose BAG --map BAG/interface_map.yaml`` for a map other
            than the two-tank preset in its default units); None: none written.

    Raises:
        DatumError: ``periods_before`` below ``needed_periods``, or the directory cannot be
            made.
    """

    def __init__(
        self,
        config: EvidenceConfig,
        *,
        topics: Mapping[str, str],
        ts_s: float,
        period_samples: int,
        messages_per_sample: int,
        needed_periods: int,
        models: Sequence[str] = (),
        interface: InterfaceMap | None = None,
    ) -> None:
        if config.periods_before < needed_periods:
            raise DatumError(
                f"evidence_periods_before = {config.periods_before} holds no judged window: "
                f"diagnose needs settle_periods + periods_per_window = {needed_periods} "
                "periods before the alarm; raise it"
            )
        self.config = config
        self.directory = Path(config.dir)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise DatumError(f"evidence_dir {config.dir!r} cannot be made: {err}") from err
        self.topics = dict(topics)
        self.ts_s = ts_s
        self.period_samples = period_samples
        self.models = tuple(models)
        self.interface = interface
        self.period_ns = round(period_samples * ts_s * NS_PER_S)
        self.span_ns = config.periods_before * self.period_ns
        self.max_ring = config.periods_before * period_samples * max(messages_per_sample, 1)
        self.ring: deque[_Message] = deque(maxlen=self.max_ring)
        self.max_bytes = int(config.max_bag_mb * 1e6)
        self._queue: queue.Queue[tuple[str, object]] = queue.Queue(maxsize=config.queue)
        self._lock = threading.Lock()
        self._status = EvidenceStatus()
        self._levels: dict[str, Alarm] = {}
        self._episode: _Episode | None = None
        self._seq = 0
        self._close_pending = threading.Event()  # a close the full queue did not take
        self._thread = threading.Thread(
            target=self._run, name="twotank_evidence_writer", daemon=True
        )
        self._thread.start()

    # ------------------------------------------------------------- the feeding side (never waits)

    def note(self, topic: str, stamp_ns: int, data: bytes) -> None:
        """One message as fed to the validator (before it is fed): buffered or written."""
        item = (topic, int(stamp_ns), data)
        ep = self._episode
        if ep is not None:
            if stamp_ns > ep.end_ns:
                self._finish("periods_after reached")
            else:
                self._put("msg", item)
        self.ring.append(item)
        cut = stamp_ns - self.span_ns
        ring = self.ring
        while ring and ring[0][1] < cut:
            ring.popleft()

    def on_report(self, model: str, alarm: Alarm, end_ns: int, *, diagnosed: bool = False) -> str:
        """A model's report, after its window's messages were noted; the bag's path or "".

        A rising alarm (the level turns ERROR) starts a bag with the ring buffer; a report
        that carries the live diagnosis's answer (``diagnosed``) closes the bag of its
        model's alarm (the windows the answer used are in it).
        """
        path = self._report(model, alarm, end_ns)
        ep = self._episode
        if diagnosed and ep is not None and model in ep.models:
            self._finish("the live diagnosis is in")
        return path

    def _report(self, model: str, alarm: Alarm, end_ns: int) -> str:
        before = self._levels.get(model, Alarm.OK)
        self._levels[model] = alarm
        if alarm is not Alarm.ERROR or before is Alarm.ERROR:
            return ""
        ep = self._episode
        if ep is not None:  # another model's alarm while writing: the same bag holds it
            ep.models.append(model)
            with self._lock:
                self._status.by_model[model] = str(ep.path)
            return str(ep.path)
        path = self._new_path(model)
        ep = self._episode = _Episode(
            path, [model], int(end_ns), int(end_ns) + self.config.periods_after * self.period_ns
        )
        custom = {
            "ts_s": repr(self.ts_s),
            "period_samples": str(self.period_samples),
            CUSTOM_DATA_KEY: json.dumps(
                {
                    "model": model,
                    "alarm_rise_s": end_ns / NS_PER_S,
                    "periods_before": self.config.periods_before,
                    "periods_after": self.config.periods_after,
                    "models": list(self.models),
                }
            ),
        }
        with self._lock:
            self._status.bags.append(str(path))
            self._status.writing = str(path)
            self._status.state = "writing"
            self._status.by_model[model] = str(path)
        self._put("open", (path, custom, list(self.ring)))
        return str(path)

    def _finish(self, _why: str) -> None:
        self._episode = None
        self._put("close", None)

    def _put(self, kind: str, payload: object) -> None:
        try:
            self._queue.put_nowait((kind, payload))
        except queue.Full:
            with self._lock:
                if kind == "open":
                    self._status.dropped += len(payload[2])  # type: ignore[index]
                    self._status.error = "the writer fell behind: a bag was not started"
                elif kind == "close":
                    self._close_pending.set()
                else:
                    self._status.dropped += 1

    def status(self) -> EvidenceStatus:
        """A copy of what the recorder did."""
        with self._lock:
            s = self._status
            return EvidenceStatus(
                list(s.bags),
                s.writing,
                s.state,
                s.dropped,
                s.over_size,
                s.removed,
                s.error,
                dict(s.by_model),
            )

    def wait_idle(self, timeout_s: float = 30.0) -> bool:
        """Block until the writer has written everything queued (tests, the end of a run)."""
        deadline = time.monotonic() + timeout_s
        while self._queue.unfinished_tasks:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.005)
        return True

    def close(self, timeout_s: float = 30.0) -> None:
        """Close the bag being written (what came so far is in it) and stop the writer."""
        if self._episode is not None:
            self._finish("shutdown")
        self._close_pending.set()
        with contextlib.suppress(queue.Full):
            self._queue.put(("exit", None), timeout=timeout_s)
        self._thread.join(timeout_s)

    # ------------------------------------------------------------- naming and rotation

    def _new_path(self, model: str) -> Path:
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        safe = re.sub(r"[^A-Za-z0-9_.-]", "_", model)
        while True:
            self._seq = (self._seq + 1) % 10000
            path = self.directory / f"evidence-{stamp}-{self._seq:04d}-{safe}"
            if not path.exists():
                return path

    def _rotate(self) -> None:
        """Remove the oldest evidence bags so that one more keeps at most ``max_bags``."""
        old = evidence_bags(self.directory)
        for p in old[: max(len(old) - self.config.max_bags + 1, 0)]:
            shutil.rmtree(p, ignore_errors=True)
            with self._lock:
                self._status.removed += 1

    # ------------------------------------------------------------- the writer thread

    def _run(self) -> None:
        bag: BagWriter | None = None
        size = unflushed = 0
        full = False
        while True:
            try:
                kind, payload = self._queue.get(timeout=0.2)
            except queue.Empty:
                if bag is not None:
                    if self._close_pending.is_set():
                        self._close(bag)
                        bag = None
                    elif unflushed:
                        self._flush(bag)
                        unflushed = 0
                continue
            try:
                if kind == "exit":
                    if bag is not None:
                        self._close(bag)
                        bag = None
                    return
                if kind == "open":
                    if bag is not None:
                        self._close(bag)
                        bag = None
                    path: Path
                    custom: dict[str, str]
                    ring: list[_Message]
                    path, custom, ring = payload  # type: ignore[misc]
                    bag, size, full = self._open(path, custom), 0, False
                    if bag is None:
                        continue
                    messages = ring
                elif kind == "close":
                    if bag is not None:
                        self._close(bag)
                        bag = None
                    continue
                else:
                    messages = [payload]  # type: ignore[list-item]
                if bag is None:
                    continue
                for topic, t, data in messages:
                    if full or size + len(data) + _OVERHEAD > self.max_bytes:
                        full = True
                        with self._lock:
                            self._status.over_size += 1
                        continue
                    bag.write_raw(topic, t, data)
                    size += len(data) + _OVERHEAD
                    unflushed += len(data)
                if full:  # max_bag_mb reached: the bag is closed, the rest is not written
                    self._close(bag)
                    bag = None
                elif unflushed >= FLUSH_BYTES:
                    self._flush(bag)
                    unflushed = 0
            except Exception as err:  # a writer error is reported, never raised into the node
                with self._lock:
                    self._status.error = f"{type(err).__name__}: {err}"
                    self._status.state = "error"
                if bag is not None:
                    with contextlib.suppress(Exception):
                        bag.close()
                    bag = None
            finally:
                self._queue.task_done()

    def _open(self, path: Path, custom: Mapping[str, str]) -> BagWriter | None:
        self._rotate()
        bag = BagWriter(path, "mcap")
        for key, value in custom.items():
            bag.set_custom_data(key, value)
        for topic, msgtype in self.topics.items():
            bag.add_topic(topic, msgtype)
        bag.flush()  # a readable (empty) bag from the start
        if self.interface is not None:
            write_interface_map(self.interface, path / MAP_FILE)
        self._close_pending.clear()
        return bag

    def _flush(self, bag: BagWriter) -> None:
        try:
            bag.flush()
        except Exception as err:
            with self._lock:
                self._status.error = f"{type(err).__name__}: {err}"

    def _close(self, bag: BagWriter) -> None:
        with contextlib.suppress(Exception):
            bag.flush()
        bag.close()
        self._close_pending.clear()
        with self._lock:
            if self._status.writing == str(bag.path):
                self._status.writing = ""
            if self._status.state == "writing":
                self._status.state = "armed"
