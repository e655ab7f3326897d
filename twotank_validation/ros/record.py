"""``twotank-validation record``: raw subscriptions to the interface topics into a rosbag2 bag.

There is no ``ros2 bag`` here (no rosbag2_py wheel): each topic gets a raw subscription
(serialised CDR bytes, not decoded) whose callback hands the bytes to the rosbags writer with
the receive time as log time. The writer is closed in a ``finally`` (Ctrl-C and SIGTERM
included), so everything received before the stop is in the bag.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Mapping
from pathlib import Path
from types import FrameType
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from twotank_validation.bags.writer import BagWriter
from twotank_validation.defaults import NS_PER_S
from twotank_validation.online.streams import STREAM_TYPES, STREAMS
from twotank_validation.ros import messages


class RecorderNode(Node):
    """Raw subscriptions writing every message of ``topics`` into ``writer``.

    Args:
        writer: an open bag writer.
        topics: topic name (as recorded) -> message type.
        **kwargs: passed to :class:`rclpy.node.Node`.
    """

    def __init__(self, writer: BagWriter, topics: Mapping[str, str], **kwargs: Any) -> None:
        super().__init__("twotank_recorder", **kwargs)
        self.writer = writer
        self.counts: dict[str, int] = dict.fromkeys(topics, 0)
        for topic, msgtype in topics.items():
            writer.add_topic(topic, msgtype)
            self.create_subscription(
                messages.message_class(msgtype), topic, self._callback(topic), 1000, raw=True
            )

    def _callback(self, topic: str) -> Any:
        def on_message(data: bytes) -> None:
            self.writer.write_raw(topic, int(self.get_clock().now().nanoseconds), bytes(data))
            self.counts[topic] += 1

        return on_message


def record(
    out: str | Path,
    *,
    duration_s: float | None = None,
    storage: str = "mcap",
    topics: Mapping[str, str] | None = None,
) -> dict[str, int]:
    """Record the interface topics until ``duration_s`` (ROS time) passes or Ctrl-C/SIGTERM.

    Args:
        out: bag path (must not exist).
        duration_s: seconds to record; ``None`` records until interrupted.
        storage: ``"mcap"`` or ``"sqlite3"``.
        topics: stream -> topic name remapping (default: the stream names).

    Returns:
        messages written per topic.
    """
    names = dict(topics or {s: s for s in STREAMS})
    wanted = {names[s]: STREAM_TYPES[s] for s in STREAMS}
    ctx = Context()
    rclpy.init(context=ctx)
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM) if main_thread else None

    def on_term(_sig: int, _frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    if main_thread:  # SIGTERM ends a recording like Ctrl-C (signals reach the main thread only)
        signal.signal(signal.SIGTERM, on_term)
    node = None
    try:
        with BagWriter(out, storage=storage) as writer:
            node = RecorderNode(writer, wanted, context=ctx)
            executor = SingleThreadedExecutor(context=ctx)
            executor.add_node(node)
            start = node.get_clock().now().nanoseconds
            end = None if duration_s is None else start + int(duration_s * NS_PER_S)
            try:
                while end is None or node.get_clock().now().nanoseconds < end:
                    executor.spin_once(timeout_sec=0.1)
            except KeyboardInterrupt:
                pass
            return dict(node.counts)
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=ctx)
