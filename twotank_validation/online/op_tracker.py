"""The reference operating point of one model: commissioned, checked, moved by a setpoint.

The window monitor keeps one :class:`OperatingPointTracker` per model. Judged windows in
steady state feed it their input and output means; it answers with the zero-frequency check
(:func:`~twotank_validation.core.oppoint.check_operating_point`) against its reference:

1. **Commissioning.** Without a reference given in the settings, the first
   ``commission_windows`` judged steady windows, a period apart, whose means agree (within the
   drift allowance on the outputs and the input tolerance on the inputs) become the
   reference: their mean.
   Until then the operating point is not judged.
2. **Checking.** Every later judged steady window is checked against the reference.
3. **A setpoint change** is told apart from a fault by the rule: the commanded input means
   moved (some ``|Δū_j|`` above ``input_tolerance``) *and* the model explains the move
   (``β_op ≤ 1``: the outputs moved as its steady-state gain, perturbations and noise
   allow). The reference then moves to the window's means. Outputs that moved while the
   inputs did not, or moved other than the model predicts, keep the reference: that is the
   fault the check exists for, and it stays visible for as long as it lasts.
4. **Transients.** A window whose outputs still drift (the datum's transient finding) is not
   in steady state: its means are not an operating point, so it is never used to commission
   or to move the reference. With the transient term on (the monitor passes the term at DC,
   :class:`~twotank_validation.core.oppoint.DcTransient`) it is checked against a settled
   reference (given, commissioned, or moved and refined) with the transient's share taken
   off its means (docs/theory.md §20); otherwise it is not checked.
5. **Suspended.** A judged window that invalidates the model (its dynamics: β > 1) while no
   reference exists ends the commissioning: the windows after it are not known to be
   healthy (a leak's transient invalidates the dynamics, the steady windows after it sit at
   the leak's operating point), so none of them becomes the reference. The operating point
   then goes unchecked until a reference is given (``reference_u``/``reference_y``) or
   :meth:`OperatingPointTracker.reset` (the ``reset_operating_point`` service) commissions
   again once the plant is healthy; meanwhile the alarm stays at least WARN
   (:func:`~twotank_validation.online.alarm.update_alarm`, ``unchecked``).

The tracker is reset (re-commissioned) by :meth:`OperatingPointTracker.reset`, as the alarm
latch is.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from twotank_validation.core.datum import NormConvention
from twotank_validation.core.model import LFTModel
from twotank_validation.core.oppoint import (
    DcTransient,
    OperatingPoint,
    OperatingPointCheck,
    check_operating_point,
)
from twotank_validation.settings import check_settings, setting


class OpState(enum.StrEnum):
    """Where the reference of a model's operating point stands."""

    OFF = "off"
    """The check is switched off."""
    COMMISSIONING = "commissioning"
    """No reference yet: steady windows are being collected."""
    GIVEN = "given"
    """The reference came from the settings."""
    COMMISSIONED = "commissioned"
    """The reference is the mean of the first steady windows."""
    MOVED = "moved by a setpoint change"
    """The inputs moved and the model explained the move: the reference followed."""
    SUSPENDED = "suspended"
    """Not commissioned: the model was invalidated before a reference was set, and the
    windows after that are not known to be healthy. Left by a given reference or a reset."""


SUSPENDED_NOTE = (
    "not commissioned: the model was invalidated before a reference was set; give the "
    "reference (op_reference_u, op_reference_y) or call reset_operating_point once the plant is "
    "healthy"
)
"""Why a suspended reference checks nothing, and what clears it (every window says so)."""


@dataclass(frozen=True)
class OpPointConfig:
    """Settings of the operating-point check (part of ``MonitorConfig``).

    Attributes:
        enabled: check the operating point at all.
        commission_windows: steady judged windows that commission the reference.
        drift_allowance: dead band on each output's mean deviation (model units): a slow
            drift of the operating point this large is accepted.
        input_tolerance: input mean change (model units) above which the inputs moved (a
            setpoint change candidate).
        reference_u: a given reference of the input means (model units); empty: commission.
        reference_y: a given reference of the output means; given together with reference_u.
    """

    enabled: bool = setting(
        True, "check the operating point (window means against a reference)", name="op_check"
    )
    commission_windows: int = setting(
        2,
        "steady judged windows whose means commission the reference operating point",
        low=1,
        high=1000,
    )
    drift_allowance: float = setting(
        0.002,
        "dead band on each output's mean deviation from the reference (model units)",
        unit="model units",
        low=0.0,
        high=1e6,
    )
    input_tolerance: float = setting(
        1e-3,
        "input mean change (model units) above which the inputs moved (a setpoint change)",
        unit="model units",
        low=0.0,
        high=1e6,
    )
    reference_u: tuple[float, ...] = setting(
        (),
        "given reference input means (model units), one per input; [0.0] alone or empty: "
        "commission from the first steady windows (reset_operating_point: commission again)",
        unit="model units",
    )
    reference_y: tuple[float, ...] = setting(
        (), "given reference output means, with op_reference_u", unit="model units"
    )

    def __post_init__(self) -> None:
        check_settings(self)
        if bool(self.reference_u) != bool(self.reference_y):
            raise ValueError(
                "give the operating point's reference_u and reference_y together (or neither, "
                "to commission it from the first steady windows)"
            )
        if not all(math.isfinite(x) for x in (*self.reference_u, *self.reference_y)):
            raise ValueError("the operating point's reference must be finite")


@dataclass(frozen=True)
class OpVerdict:
    """What the operating-point check says of one window.

    Attributes:
        state: where the reference stands after this window.
        check: the zero-frequency check, None where the window was not checked.
        note: why it was not checked, or what happened (commissioned, moved), in words.
    """

    state: OpState
    check: OperatingPointCheck | None
    note: str

    @property
    def beta(self) -> float:
        """β_op, NaN where the window was not checked."""
        return self.check.beta if self.check is not None else math.nan

    @property
    def unchecked(self) -> bool:
        """The operating point cannot be checked since the model was invalidated."""
        return self.state is OpState.SUSPENDED


@dataclass
class OperatingPointTracker:
    """One model's reference operating point and its check (see the module docstring)."""

    model: LFTModel
    config: OpPointConfig
    ts_s: float
    n_samples: int
    convention: NormConvention = NormConvention.POWER
    method: str = "auto"
    spacing_ns: int = 0
    """Windows collected to commission or refine the reference lie at least this far apart
    (the monitor passes one period: windows every hop overlap, and two that share most of
    their samples agree whether or not the plant has settled)."""
    reference: OperatingPoint | None = None
    state: OpState = OpState.COMMISSIONING
    _pending: list[OperatingPoint] = field(default_factory=list)
    _last_end: int | None = None

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the reference: the given one again, or commission anew."""
        self._pending, self._last_end = [], None
        cfg = self.config
        if not cfg.enabled:
            self.reference, self.state = None, OpState.OFF
        elif cfg.reference_u:
            u, y = np.array(cfg.reference_u, float), np.array(cfg.reference_y, float)
            if u.shape != (self.model.nu,) or y.shape != (self.model.ny,):
                raise ValueError(
                    f"the operating point's reference has {u.size} input and {y.size} output "
                    f"means; model {self.model.name!r} has {self.model.nu} inputs "
                    f"{list(self.model.input_names)} and {self.model.ny} outputs "
                    f"{list(self.model.output_names)}"
                )
            self.reference, self.state = OperatingPoint(u, y), OpState.GIVEN
        else:
            self.reference, self.state = None, OpState.COMMISSIONING

    def observe(
        self,
        means: OperatingPoint,
        *,
        steady: bool,
        end_ns: int | None = None,
        invalidated: bool = False,
        transient: DcTransient | None = None,
    ) -> OpVerdict:
        """One judged window's means in; the check of this window out.

        Args:
            means: the window's input and output means (model units).
            steady: the window is in steady state (no transient finding).
            end_ns: the window's last stamp (spaces the windows collected; None: no spacing).
            invalidated: the window's dynamics invalidate the model (β > 1): without a
                reference, its verdict; the commissioning is then suspended (module doc, 5).
            transient: the window's transient term at DC, None: the term is off (a window
                that is not steady is then not checked; module doc, 4).
        """
        if self.state is OpState.OFF:
            return OpVerdict(self.state, None, "operating-point check off")
        if self.reference is None and invalidated:
            self.state, self._pending, self._last_end = OpState.SUSPENDED, [], None
        if self.state is OpState.SUSPENDED:
            return OpVerdict(self.state, None, SUSPENDED_NOTE)
        if not steady:
            return self._unsteady(means, transient)
        if self.reference is None:
            return self._commission(means, end_ns)
        chk = self._check(means, None)
        moved = float(np.max(np.abs(chk.du), initial=0.0)) > self.config.input_tolerance
        if moved and chk.explained:
            self.reference, self.state = means, OpState.MOVED
            self._pending = [means]  # the next steady windows refine the new reference
            self._last_end = end_ns
            return OpVerdict(
                self.state,
                chk,
                f"inputs moved by {_fmt(chk.du)} and the outputs by {_fmt(chk.dy)}, as the "
                f"model predicts (beta_op {chk.beta:.3g}): setpoint change, reference moved",
            )
        return self._refine(means, chk, moved=moved, end_ns=end_ns)

    def _unsteady(self, means: OperatingPoint, transient: DcTransient | None) -> OpVerdict:
        """A window whose outputs drift: checked with the term at DC against a settled reference."""
        if transient is None or self.reference is None or self._pending:
            return OpVerdict(self.state, None, "not in steady state (outputs still drift)")
        chk = self._check(means, transient)
        return OpVerdict(
            self.state, chk, "outputs still drift: checked with the transient term at DC"
        )

    def _check(self, means: OperatingPoint, transient: DcTransient | None) -> OperatingPointCheck:
        assert self.reference is not None
        return check_operating_point(
            self.model,
            self.ts_s,
            self.reference,
            means,
            n_samples=self.n_samples,
            convention=self.convention,
            allowance=self.config.drift_allowance,
            method=self.method,
            transient=transient,
        )

    def _refine(
        self, means: OperatingPoint, chk: OperatingPointCheck, *, moved: bool, end_ns: int | None
    ) -> OpVerdict:
        """After a setpoint change: refine the new reference over the next steady windows."""
        if self._pending and not moved and chk.explained:
            # after a setpoint change the first window may still hold the end of the move:
            # the reference becomes the mean of the windows that follow it, once enough agree
            if not self._spaced(end_ns):
                return OpVerdict(self.state, chk, "")
            self._pending = [*self._agreeing(means), means][-self.config.commission_windows :]
            self._last_end = end_ns
            if len(self._pending) == self.config.commission_windows:
                self.reference = OperatingPoint(
                    np.mean([p.u for p in self._pending], axis=0),
                    np.mean([p.y for p in self._pending], axis=0),
                )
                self._pending = []
                return OpVerdict(self.state, chk, "reference refined after the setpoint change")
        elif self._pending:
            self._pending = []  # not a settled new point: keep the reference as it is
        return OpVerdict(self.state, chk, "")

    def _agreeing(self, means: OperatingPoint) -> list[OperatingPoint]:
        """The pending windows whose means agree with ``means``.

        Inputs within the input tolerance, outputs within the drift allowance: a window that
        disagrees with them (the plant still settling) starts the count again.
        """
        cfg = self.config
        return [
            p
            for p in self._pending
            if np.all(np.abs(p.u - means.u) <= cfg.input_tolerance)
            and np.all(np.abs(p.y - means.y) <= cfg.drift_allowance)
        ]

    def _spaced(self, end_ns: int | None) -> bool:
        """Whether a window ending at ``end_ns`` is far enough from the last one collected."""
        return (
            end_ns is None or self._last_end is None or end_ns - self._last_end >= self.spacing_ns
        )

    def _commission(self, means: OperatingPoint, end_ns: int | None) -> OpVerdict:
        cfg = self.config
        if self._pending and not self._spaced(end_ns):
            return OpVerdict(
                self.state,
                None,
                f"commissioning the operating point ({len(self._pending)} of "
                f"{cfg.commission_windows} steady windows, a period apart)",
            )
        self._pending = [*self._agreeing(means), means]
        self._last_end = end_ns
        if len(self._pending) < cfg.commission_windows:
            return OpVerdict(
                self.state,
                None,
                f"commissioning the operating point ({len(self._pending)} of "
                f"{cfg.commission_windows} steady windows)",
            )
        u = np.mean([p.u for p in self._pending], axis=0)
        y = np.mean([p.y for p in self._pending], axis=0)
        self.reference, self.state, self._pending = OperatingPoint(u, y), OpState.COMMISSIONED, []
        return OpVerdict(
            self.state, None, f"operating point commissioned: inputs {_fmt(u)}, outputs {_fmt(y)}"
        )


def _fmt(x: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in np.asarray(x, dtype=float)) + "]"
