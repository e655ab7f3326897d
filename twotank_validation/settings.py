"""Settings declared once: a field of a frozen config dataclass carries its whole description.

A setting is a dataclass field made by :func:`setting`: its default, unit, description,
inclusive range and choices, and the names it has in the front ends (the ROS parameter, the
command-line option). A config that holds another config marks the field with :func:`group`
(a prefix for the flat names of the group's settings). The config dataclasses of the package
(``MonitorConfig``, ``AlarmConfig``, ``OpPointConfig``, ``LiveDiagConfig``, the root
``ValidatorSettings``) are such trees; the front ends are derived from them:

* :func:`flat` lists a tree's settings with their flat names (``alarm_evidence`` for
  ``MonitorConfig.alarm.evidence``): the node parameters and the CLI options are made from it;
* :func:`from_flat` builds the typed config of flat values (parameter values, parsed
  options): the inverse;
* :func:`check_settings`, called by each config's ``__post_init__``, checks ranges and choices
  and names the setting, the value and what is allowed.

The flat (parameter) form of a value: enums by their value, tuples as lists, and an empty
tuple as ROS's one-element placeholder (``[0.0]`` for numbers, ``[""]`` for text: a ROS
parameter cannot be declared as an empty array of a type). This module imports nothing of the
package but :mod:`twotank_validation.errors`.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final, TypeVar

from twotank_validation.errors import TwotankError

T = TypeVar("T")

_KEY: Final = "twotank_setting"
_GROUP: Final = "twotank_group"


class SettingError(TwotankError, ValueError):
    """A setting is out of its range or not among its choices; the message names it."""


@dataclass(frozen=True)
class Setting:
    """What a settings field carries besides its default (the field's own).

    Attributes:
        description: one line, as the node parameter and the CLI help show it (units in
            parentheses where the name does not carry them).
        unit: the unit of the value (``"s"``, ``"samples"``, ``"model units"``; empty:
            dimensionless or text).
        low: smallest allowed value (inclusive); None: no lower bound.
        high: largest allowed value (inclusive); None: no upper bound.
        choices: the allowed values of a text setting; empty: any.
        name: the flat name (node parameter) where it is not the group's prefix followed by
            the field's name.
        option: the command-line option (``"--hop"``); empty: not an option.
        cli_help: the option's help where the description does not fit the command line;
            ``{name}`` fields are replaced by the default of the setting of that flat name.
        hidden: why the setting is no node parameter (empty: it is one).
    """

    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    name: str = ""
    option: str = ""
    cli_help: str = ""
    hidden: str = ""

    def range_text(self) -> str:
        """``"[1, 64]"``, ``"[0, inf)"`` or the choices; empty without either."""
        if self.choices:
            return "one of " + ", ".join(self.choices)
        if self.low is None and self.high is None:
            return ""
        low = "(-inf" if self.low is None else f"[{_num(self.low)}"
        high = "inf)" if self.high is None else f"{_num(self.high)}]"
        return f"{low}, {high}"


def _num(x: float) -> str:
    return f"{x:g}"


def setting(
    default: T,
    description: str,
    *,
    unit: str = "",
    low: float | None = None,
    high: float | None = None,
    choices: tuple[str, ...] = (),
    name: str = "",
    option: str = "",
    cli_help: str = "",
    hidden: str = "",
) -> T:
    """A dataclass field that is a setting (see :class:`Setting` for the arguments)."""
    meta = Setting(description, unit, low, high, choices, name, option, cli_help, hidden)
    return dataclasses.field(default=default, metadata={_KEY: meta})


def group(factory: type[T], *, prefix: str = "") -> T:
    """A dataclass field holding a nested settings tree (its flat names start with ``prefix``)."""
    return dataclasses.field(default_factory=factory, metadata={_GROUP: prefix})


@dataclass(frozen=True)
class FlatSetting:
    """One setting of a tree, located.

    Attributes:
        name: its flat name: the node parameter's, unique in the tree.
        path: the attribute path from the root (``("alarm", "evidence")``).
        owner: the dataclass that declares it.
        kind: its Python type (``int``, ``float``, ``bool``, ``str``, an enum class, or
            ``tuple[float, ...]``/``tuple[str, ...]``).
        default: the field's default (the typed value).
        meta: the rest of what it declares.
    """

    name: str
    path: tuple[str, ...]
    owner: type
    kind: Any
    default: Any
    meta: Setting

    @property
    def param_default(self) -> Any:
        """The default in flat (parameter) form."""
        return to_flat(self.kind, self.default)


def _fields(cls: type) -> tuple[dataclasses.Field[Any], ...]:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a settings dataclass")
    return dataclasses.fields(cls)


def flat(cls: type, prefix: str = "", path: tuple[str, ...] = ()) -> tuple[FlatSetting, ...]:
    """Every setting of the tree ``cls``, depth first in field order.

    Raises:
        TypeError: a field that is neither a setting nor a group (every field of a settings
            tree is one or the other), or a flat name used twice.
    """
    hints = typing.get_type_hints(cls)
    out: list[FlatSetting] = []
    for f in _fields(cls):
        if _GROUP in f.metadata:
            out.extend(flat(hints[f.name], prefix + f.metadata[_GROUP], (*path, f.name)))
            continue
        meta = f.metadata.get(_KEY)
        if not isinstance(meta, Setting):
            raise TypeError(
                f"{cls.__name__}.{f.name} is neither a setting nor a group: declare it with "
                "twotank_validation.settings.setting() or group()"
            )
        name = meta.name or prefix + f.name
        out.append(FlatSetting(name, (*path, f.name), cls, hints[f.name], f.default, meta))
    names = [s.name for s in out]
    if twice := sorted({n for n in names if names.count(n) > 1}):
        raise TypeError(f"settings of {cls.__name__} share the flat names {twice}")
    return tuple(out)


def to_flat(kind: Any, value: Any) -> Any:
    """A typed value of type ``kind`` in flat (parameter) form.

    Enums by their value, tuples as lists, an empty tuple as ROS's placeholder (``[0.0]`` or
    ``[""]``).
    """
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, tuple):
        item = typing.get_args(kind)[0] if typing.get_origin(kind) is tuple else str
        return [item(v) for v in value] if value else [item()]
    return value


def _from_flat_value(kind: Any, value: Any) -> Any:
    """The typed value of a flat one (the inverse of :func:`to_flat`)."""
    if typing.get_origin(kind) is tuple:
        item = typing.get_args(kind)[0]
        items = tuple(item(v) for v in (value or ()))
        if item is str:
            return tuple(v for v in items if v)  # "" entries (the placeholder) stand for none
        return () if items == (item(),) else items
    return kind(value)  # bool, int, float, str, an enum


def from_flat(cls: type[T], values: Mapping[str, Any], prefix: str = "") -> T:
    """The config ``cls`` of flat values; settings missing from ``values`` keep their defaults.

    Raises:
        SettingError: a value out of range or not among the choices (from the configs' own
            checks, which may raise other ``ValueError`` subclasses for inconsistencies).
    """
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    for f in _fields(cls):
        if _GROUP in f.metadata:
            kwargs[f.name] = from_flat(hints[f.name], values, prefix + f.metadata[_GROUP])
            continue
        meta: Setting = f.metadata[_KEY]
        name = meta.name or prefix + f.name
        if name in values:
            if meta.choices:  # named before an enum's own error could hide the setting
                _check(_label(cls, f.name, meta), meta, values[name], SettingError)
            kwargs[f.name] = _from_flat_value(hints[f.name], values[name])
    return cls(**kwargs)


def _label(cls: type, field: str, meta: Setting) -> str:
    """``"alarm_evidence (AlarmConfig.evidence)"``, or ``"MonitorConfig.ts_s"``."""
    label = f"{cls.__name__}.{field}"
    return f"{meta.name} ({label})" if meta.name else label


def _check(label: str, meta: Setting, value: Any, error: type[Exception]) -> None:
    """Raise ``error`` naming the setting if ``value`` is out of its range or choices."""
    if meta.choices:
        if to_flat(str, value) not in meta.choices:
            raise error(f"{label} = {value!r} is not one of {list(meta.choices)}")
        return
    if isinstance(value, bool) or not isinstance(value, int | float):
        return
    low = -math.inf if meta.low is None else meta.low
    high = math.inf if meta.high is None else meta.high
    if not low <= value <= high:  # NaN fails too
        raise error(f"{label} = {value!r} is outside its allowed range {meta.range_text()}")


def check_settings(config: object, error: type[Exception] = SettingError) -> None:
    """Check every setting of ``config`` (not its groups) against its range and choices.

    Args:
        config: a settings dataclass instance (called from its ``__post_init__``).
        error: the exception to raise (a config keeps the error type it always raised).

    Raises:
        error: the first setting out of range, naming it, the value and the allowed range.
    """
    for f in _fields(type(config)):
        meta = f.metadata.get(_KEY)
        if isinstance(meta, Setting):
            _check(_label(type(config), f.name, meta), meta, getattr(config, f.name), error)
