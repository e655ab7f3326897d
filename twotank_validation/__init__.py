"""twotank_validation: frequency-domain model validation of LFT robust-control models.

The method is R. S. Smith, "Model validation for robust control: an experimental process
control application", Automatica 31(11), 1995.

The public surface is this module's names::

    from twotank_validation import make_datum, load_model, validate, OnlineValidator, replay_bag

(``diagnose`` is a subpackage; its entry point is ``twotank_validation.diagnose.diagnose``.)

Importing the package imports none of its layers: each name below loads its module on first
use, so ``import twotank_validation`` costs nothing and a script that only validates a datum
never loads the bag readers or ROS. The layers, lowest first, each importing only those
below it: ``errors``/``defaults``; ``core`` (datum, LTI systems, LFT models, per-bin solvers
and the fast path, validate, the probabilistic tests: numpy, scipy, cvxpy, numba);
``online`` (streams, alignment, whole-period windows, the alarm, :class:`OnlineValidator`);
``sim`` (the simulated rig, excitation, faults, scenarios); ``bags`` (rosbag2 reading and
writing: rosbags, mcap); ``diagnose``; ``replay``; ``experiment``; ``calibrate``;
``report`` (matplotlib); ``ros`` (the only layer that imports rclpy); ``cli``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# name -> module that defines it (the one place the public surface is written down)
_PUBLIC: dict[str, str] = {
    "TwotankError": "twotank_validation.errors",
    "Method": "twotank_validation.defaults",
    "NormConvention": "twotank_validation.core.datum",
    "Datum": "twotank_validation.core.datum",
    "make_datum": "twotank_validation.core.datum",
    "LFTModel": "twotank_validation.core.model",
    "load_model": "twotank_validation.core.model",
    "ValidationResult": "twotank_validation.core.validate",
    "validate": "twotank_validation.core.validate",
    "MonitorConfig": "twotank_validation.online.window",
    "WindowReport": "twotank_validation.online.window",
    "Alarm": "twotank_validation.online.alarm",
    "OnlineValidator": "twotank_validation.online.validator",
    "open_bag": "twotank_validation.bags.reader",
    "Diagnosis": "twotank_validation.diagnose",
    "ReplayConfig": "twotank_validation.replay",
    "ReplayResult": "twotank_validation.replay",
    "replay_bag": "twotank_validation.replay",
}

__all__ = [
    "Alarm",
    "Datum",
    "Diagnosis",
    "LFTModel",
    "Method",
    "MonitorConfig",
    "NormConvention",
    "OnlineValidator",
    "ReplayConfig",
    "ReplayResult",
    "TwotankError",
    "ValidationResult",
    "WindowReport",
    "load_model",
    "make_datum",
    "open_bag",
    "replay_bag",
    "validate",
]

if TYPE_CHECKING:
    from twotank_validation.bags.reader import open_bag
    from twotank_validation.core.datum import Datum, NormConvention, make_datum
    from twotank_validation.core.model import LFTModel, load_model
    from twotank_validation.core.validate import ValidationResult, validate
    from twotank_validation.defaults import Method
    from twotank_validation.diagnose import Diagnosis
    from twotank_validation.errors import TwotankError
    from twotank_validation.online.alarm import Alarm
    from twotank_validation.online.validator import OnlineValidator
    from twotank_validation.online.window import MonitorConfig, WindowReport
    from twotank_validation.replay import ReplayConfig, ReplayResult, replay_bag


def __getattr__(name: str) -> Any:
    """Load a public name's module on first use (PEP 562)."""
    try:
        module = _PUBLIC[name]
    except KeyError:
        raise AttributeError(f"module 'twotank_validation' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_PUBLIC])
