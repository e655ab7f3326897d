"""Extraction: a source's value and stamp read from a decoded message.

:func:`raw_value` walks a field path through a message, reading attributes by field name and
indexing arrays (numpy arrays, lists, tuples, ``array.array``), so it works on rosbags'
decoded dataclasses, rclpy messages and mcap_ros2's decoded objects alike; :func:`extract`
converts to model units, :func:`check_message` checks a topic's first message against its
source, :func:`source_stamp_ns` stamps a sample. Nothing here imports ROS.
"""

from __future__ import annotations

import array
import dataclasses
import numbers
from typing import Any

import numpy as np

from twotank_validation.defaults import NS_PER_S
from twotank_validation.online.sources import (
    STAMP_HEADER,
    FieldPath,
    InterfaceMapError,
    Source,
    format_field_path,
    parse_field_path,
)

__all__ = [
    "check_message",
    "extract",
    "message_fields",
    "message_type_name",
    "raw_value",
    "source_stamp_ns",
    "stamp_ns",
]

_ARRAYS = (list, tuple, array.array, np.ndarray)


_FIELDS_OF_TYPE: dict[type, tuple[str, ...] | None] = {}


def _type_fields(cls: type) -> tuple[str, ...] | None:
    """Field names of a message class (cached per class), None if it is not one."""
    if cls not in _FIELDS_OF_TYPE:
        _FIELDS_OF_TYPE[cls] = _declared_fields(cls)
    return _FIELDS_OF_TYPE[cls]


def _declared_fields(cls: type) -> tuple[str, ...] | None:
    if dataclasses.is_dataclass(cls):  # rosbags (its __msgtype__ is a field too)
        return tuple(f.name for f in dataclasses.fields(cls) if not f.name.startswith("_"))
    getter = getattr(cls, "get_fields_and_field_types", None)
    if callable(getter):  # rclpy
        return tuple(getter())
    slots = getattr(cls, "__slots__", None)  # mcap_ros2 and other plain classes
    if isinstance(slots, str):
        slots = (slots,)
    if slots and not issubclass(cls, _ARRAYS):
        return tuple(s for s in slots if not s.startswith("_"))
    return None


def message_fields(obj: Any) -> tuple[str, ...] | None:
    """Field names of a message object, or None if it is not a message.

    rosbags dataclasses: :func:`dataclasses.fields`; rclpy messages:
    ``get_fields_and_field_types()``; otherwise ``__slots__``, then the instance's attributes.
    Names starting with ``_`` are left out.
    """
    fields = _type_fields(type(obj))
    if fields is None and hasattr(obj, "__dict__") and not isinstance(obj, type):
        fields = tuple(k for k in vars(obj) if not k.startswith("_")) or None
    return fields


def message_type_name(msg: Any) -> str:
    """ROS 2 type name ``pkg/msg/Type`` of a message object (else its Python class name)."""
    name = getattr(msg, "__msgtype__", None)  # rosbags
    if isinstance(name, str):
        return name
    cls = type(msg)
    module = cls.__module__.split(".")
    if len(module) >= 2 and module[1] == "msg":  # rclpy: pkg.msg._module.Type
        return f"{module[0]}/msg/{cls.__name__}"
    return cls.__qualname__


def _kind(obj: Any) -> str:
    if isinstance(obj, _ARRAYS):
        return f"an array ({type(obj).__name__}) of length {len(obj)}"
    if message_fields(obj) is not None:
        return f"a {message_type_name(obj)} message"
    text = repr(obj)
    return f"a {type(obj).__name__} ({text if len(text) <= 40 else text[:37] + '...'})"


def _path_error(
    path: FieldPath, msg: Any, topic: str | None, msgtype: str | None, detail: str
) -> InterfaceMapError:
    where = f"topic {topic!r}" if topic is not None else "message"
    found = msgtype if msgtype is not None else message_type_name(msg)
    return InterfaceMapError(
        f"{where} ({found}): field path {format_field_path(path)!r} does not fit the "
        f"message: {detail}"
    )


def raw_value(
    msg: Any, path: FieldPath | str, *, topic: str | None = None, msgtype: str | None = None
) -> float:
    """The raw number a field path reaches in a decoded message, as a float.

    Args:
        msg: rosbags decoded message, rclpy message, or any object with the fields as
            attributes (arrays: numpy arrays, lists, tuples, ``array.array``).
        path: Parsed (:data:`FieldPath`) or text field path.
        topic: Topic, named in errors.
        msgtype: Message type, named in errors (default: found from ``msg``).

    Raises:
        InterfaceMapError: If the path does not fit: a field that is not there (the message
            lists the fields present at that level), an index past the end (names the length),
            an index into a non-array, or a leaf that is not a number.
    """
    steps = parse_field_path(path) if isinstance(path, str) else path
    obj = msg
    for depth, step in enumerate(steps):
        here = format_field_path(steps[:depth]) or "the message"
        if isinstance(step, int):
            if not isinstance(obj, _ARRAYS) or (isinstance(obj, np.ndarray) and obj.ndim != 1):
                raise _path_error(
                    steps,
                    msg,
                    topic,
                    msgtype,
                    f"{here} is {_kind(obj)}, not an array: [{step}] cannot index it",
                )
            if step >= len(obj):
                raise _path_error(
                    steps,
                    msg,
                    topic,
                    msgtype,
                    f"index {step} is out of range: {here} has length {len(obj)}",
                )
            obj = obj[step]
        else:
            fields = message_fields(obj)
            if fields is None or step not in fields:
                if fields is None:
                    detail = f"{here} is {_kind(obj)}, which has no fields; no field {step!r}"
                else:
                    detail = (
                        f"{here} ({message_type_name(obj)}) has no field {step!r}; its fields: "
                        f"{', '.join(fields) or '(none)'}"
                    )
                raise _path_error(steps, msg, topic, msgtype, detail)
            obj = getattr(obj, step)
    if isinstance(obj, bool | numbers.Real):
        return float(obj)
    text = format_field_path(steps)
    if isinstance(obj, _ARRAYS):
        hint = f"; add an index, e.g. {text}[0]" if len(obj) else ""
    elif (fields := message_fields(obj)) is not None:
        hint = f"; its fields: {', '.join(fields)}; continue the path, e.g. {text}.{fields[0]}"
    else:
        hint = ""
    raise _path_error(steps, msg, topic, msgtype, f"{text} is {_kind(obj)}, not a number{hint}")


def extract(msg: Any, source: Source) -> float:
    """Model-unit value of a source in a decoded message: ``(raw - offset) / scale``.

    Raises:
        InterfaceMapError: As :func:`raw_value` (naming the source's topic).
    """
    return source.to_model(raw_value(msg, source.path, topic=source.topic))


def check_message(source: Source, msg: Any, msgtype_found: str) -> None:
    """Check that a topic's message fits a source: its type, field path and stamp.

    For the first message of each topic (replay, live): type equality, then the path as
    :func:`raw_value` walks it, then ``header.stamp`` if the source's stamp is ``header``.

    Args:
        source: The source read from the message.
        msg: A decoded message of ``source.topic``.
        msgtype_found: The topic's message type as the bag or the graph reports it.

    Raises:
        InterfaceMapError: Naming the topic, the type found and what the map asks for.
    """
    if msgtype_found != source.msgtype:
        raise InterfaceMapError(
            f"topic {source.topic!r} carries {msgtype_found}, but the interface map asks for "
            f"{source.msgtype} (source {source.name!r}); set 'type: {msgtype_found}' for it in "
            "the map, with a field path that fits that type"
        )
    raw_value(msg, source.path, topic=source.topic, msgtype=msgtype_found)
    if source.stamp == STAMP_HEADER:
        header = getattr(msg, "header", None) if "header" in (message_fields(msg) or ()) else None
        st = getattr(header, "stamp", None)
        if st is None or not (hasattr(st, "sec") and hasattr(st, "nanosec")):
            raise InterfaceMapError(
                f"topic {source.topic!r} ({msgtype_found}) has no header.stamp to stamp source "
                f"{source.name!r}; set 'stamp: receive' for it (the receive or log time is used)"
            )


def stamp_ns(msg: Any) -> int:
    """Header stamp of a message in integer nanoseconds."""
    st = msg.header.stamp
    return int(st.sec) * NS_PER_S + int(st.nanosec)


def source_stamp_ns(msg: Any, source: Source, receive_ns: int) -> int:
    """Stamp of a source's sample (integer ns): ``header.stamp`` or ``receive_ns``.

    Args:
        msg: The decoded message.
        source: Its source (``stamp`` chooses).
        receive_ns: Receive time (live) or log time (bag), integer nanoseconds.
    """
    return stamp_ns(msg) if source.stamp == STAMP_HEADER else int(receive_ns)
