"""Errors of the bag layer: every failure of the reader and the writer is a :class:`BagError`.

Each subclass also inherits the builtin exception a caller would expect (``FileNotFoundError``,
``ValueError``, ``KeyError``, ``TypeError``, ``FileExistsError``); :class:`BagError` is a
:class:`~twotank_validation.errors.TwotankError`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from twotank_validation.errors import TwotankError

__all__ = [
    "BagCorruptError",
    "BagEmptyError",
    "BagError",
    "BagExistsError",
    "BagFormatError",
    "BagNotFoundError",
    "BagWriteError",
    "TopicMissingError",
    "TopicTypeError",
]


class BagError(TwotankError):
    """Root of every error of the bag reader (each subclass also inherits a builtin)."""


class BagNotFoundError(BagError, FileNotFoundError):
    """The path does not exist."""


class BagFormatError(BagError, ValueError):
    """The path is not a bag, its metadata is unreadable, or a topic cannot be decoded."""


class BagEmptyError(BagError, ValueError):
    """The bag holds no message at all."""


class BagCorruptError(BagError, ValueError):
    """The bag's data is truncated or corrupt from some point on.

    Attributes:
        messages_read: messages of the requested topics delivered before the damage.
        last_good_ns: log time (ns) of the last of them, None if none was read.
        offset: byte offset of the damage in its file, None where unknown (SQLite3).
    """

    def __init__(
        self,
        message: str,
        *,
        messages_read: int = 0,
        last_good_ns: int | None = None,
        offset: int | None = None,
    ) -> None:
        super().__init__(message)
        self.messages_read = messages_read
        self.last_good_ns = last_good_ns
        self.offset = offset


class TopicMissingError(BagError, KeyError):
    """Topics asked for are not in the bag (or hold no message).

    Attributes:
        missing: the requested names that were not found or are empty.
        available: topic -> message type of everything the bag has.
    """

    def __init__(self, message: str, missing: Sequence[str], available: Mapping[str, str]) -> None:
        super().__init__(message)
        self.missing = tuple(missing)
        self.available = dict(available)

    def __str__(self) -> str:
        """The message itself (KeyError would show its repr)."""
        return str(self.args[0])


class TopicTypeError(BagError, TypeError):
    """A topic carries another message type than the one expected.

    Attributes:
        topic: the topic as requested.
        found: its type(s) in the bag (``" | "``-joined if several).
        expected: the accepted types.
    """

    def __init__(self, message: str, topic: str, found: str, expected: Sequence[str]) -> None:
        super().__init__(message)
        self.topic = topic
        self.found = found
        self.expected = tuple(expected)


class BagWriteError(BagError, ValueError):
    """A bag cannot be written as asked (storage, topic, type, time, or a closed bag)."""


class BagExistsError(BagWriteError, FileExistsError):
    """The bag's path exists already; bags are never overwritten."""
