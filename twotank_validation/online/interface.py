"""The interface map: which topic, message type and field feeds each model input and output.

A real rig publishes its own topics and types. An :class:`InterfaceMap` binds each input and
output channel, by name, to a :class:`Source`: a topic, its message
type (``pkg/msg/Type``), a field path into the message (``data[1]``, ``position[0]``,
``a.b[2].c``), where the time stamp comes from (``header.stamp`` or the receive/log time) and
the conversion to model units, ``model = (raw - offset) / scale``.

A map of a table (a CSV or Parquet log of a PLC or historian) names a ``column`` per source
instead of topic, type and field, and the table's time column once for the map
(:class:`TimeColumn`); a map is all-topic (a bag) or all-column (a table). Reading tables is
:mod:`twotank_validation.tables`.

Maps come from YAML (:func:`load_interface_map`, :meth:`InterfaceMap.from_dict`), from the
text form of CLI options and node parameters (:func:`source_from_text`,
:func:`interface_map_from_text`), or a preset (the two-tank rig's:
:func:`twotank_validation.online.streams.two_tank_map`, the default). The validator matches
the map's channel names to each model's (:mod:`~twotank_validation.online.channels`).

Extraction (:func:`raw_value`, :func:`extract`, :func:`check_message`) reads attributes by
field name and indexes arrays (numpy arrays, lists, tuples, ``array.array``), so it works on
rosbags' decoded dataclasses, rclpy messages and mcap_ros2's decoded objects alike. Nothing
here imports ROS.

This module is the map's public face (the names ``docs/interface.md`` imports from here); they
are defined in :mod:`~twotank_validation.online.sources` (sources, field paths, time columns,
:class:`InterfaceMapError`), :mod:`~twotank_validation.online.interface_map` (the map, its
YAML form), :mod:`~twotank_validation.online.interface_text` (the text form) and
:mod:`~twotank_validation.online.extraction` (values and stamps from messages).
"""

from twotank_validation.online.extraction import (
    check_message,
    extract,
    raw_value,
    source_stamp_ns,
)
from twotank_validation.online.interface_map import InputKind, InterfaceMap, load_interface_map
from twotank_validation.online.interface_text import (
    input_texts,
    interface_map_from_text,
    source_from_text,
    source_to_text,
    time_column_from_text,
)
from twotank_validation.online.sources import InterfaceMapError, Source, TimeColumn, convert

__all__ = [
    "InputKind",
    "InterfaceMap",
    "InterfaceMapError",
    "Source",
    "TimeColumn",
    "check_message",
    "convert",
    "extract",
    "input_texts",
    "interface_map_from_text",
    "load_interface_map",
    "raw_value",
    "source_from_text",
    "source_stamp_ns",
    "source_to_text",
    "time_column_from_text",
]
