"""Systems of the python-control package (``control``) to and from :class:`~.lti.StateSpace`.

``control`` is imported on first use only: a model that names no python-control object never
loads it. Continuous time is ``dt = 0`` there and ``dt_s = None`` here; a discrete system
carries its sample period in seconds (python-control's ``dt=True``, a discrete system without
a period, is refused: the period is needed to evaluate it at the data's bins).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from twotank_validation.core.lti import StateSpace
from twotank_validation.errors import ModelError


def is_control_system(obj: object) -> bool:
    """Whether ``obj`` is a python-control LTI system (checked without importing control)."""
    module = type(obj).__module__ or ""
    return (module == "control" or module.startswith("control.")) and hasattr(obj, "dt")


def from_control(sys: Any, where: str = "system") -> StateSpace:
    """A python-control ``StateSpace`` or ``TransferFunction`` as a :class:`StateSpace`.

    Raises:
        ModelError: not a python-control state space or transfer function, or a discrete
            system without a sample period (``dt=True``).
    """
    import control  # noqa: PLC0415 (loaded only when a model names python-control systems)

    if isinstance(sys, control.TransferFunction):
        try:
            sys = control.ss(sys)
        except (ValueError, TypeError, ImportError, control.ControlMIMONotImplemented) as err:
            raise ModelError(
                f"{where}: the python-control transfer function cannot be realised as a "
                f"state space ({err}): pass a control.StateSpace"
            ) from err
    if not isinstance(sys, control.StateSpace):
        raise ModelError(
            f"{where}: expected a control.StateSpace or control.TransferFunction, found "
            f"{type(sys).__name__}"
        )
    dt = sys.dt
    if dt is True:
        raise ModelError(
            f"{where}: a discrete python-control system without a sample period (dt=True): "
            "give dt in seconds"
        )
    dt_s = None if dt is None or dt == 0 else float(dt)
    n = sys.nstates
    return StateSpace(
        np.asarray(sys.A, dtype=float).reshape(n, n),
        np.asarray(sys.B, dtype=float).reshape(n, sys.ninputs),
        np.asarray(sys.C, dtype=float).reshape(sys.noutputs, n),
        np.asarray(sys.D, dtype=float).reshape(sys.noutputs, sys.ninputs),
        dt_s,
    )


def to_control(
    sys: StateSpace,
    name: str | None = None,
    inputs: list[str] | None = None,
    outputs: list[str] | None = None,
) -> Any:
    """A :class:`StateSpace` as a python-control ``StateSpace`` (continuous: ``dt = 0``).

    Raises:
        ModelError: the system has transport delays (python-control's state space has none).
    """
    import control  # noqa: PLC0415

    if sys.output_delays_s:
        raise ModelError(
            f"{name or 'system'} has output delays {list(sys.output_delays_s)} s, which a "
            "python-control state space cannot hold: approximate them (control.pade) in the "
            "model, or export the rational part only"
        )
    kwargs: dict[str, Any] = {"name": name} if name else {}
    if inputs is not None:
        kwargs["inputs"] = inputs
    if outputs is not None:
        kwargs["outputs"] = outputs
    return control.StateSpace(
        sys.a, sys.b, sys.c, sys.d, 0 if sys.dt_s is None else sys.dt_s, **kwargs
    )
