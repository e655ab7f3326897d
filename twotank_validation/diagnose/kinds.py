"""The kinds of effect a diagnosis names, one record each, and the rig faults they explain.

Every kind the diagnosis can name is an :class:`EffectKind`; its properties (the family it
belongs to, what it acts on, its parameters, what it needs from the model, whether it moves
the operating point or the temperature alone, its words) are one :class:`EffectRecord`
(:data:`EFFECT_RECORDS`). The catalogue's tuples are views of the records:
:data:`EFFECT_KINDS` (the state-space effects, in the order they are tried) and
:data:`REPORTED_KINDS` (judged outside the fit and reported).

:func:`expected_effect` is the table from a simulated rig fault to the answer that names it
(each :class:`~twotank_validation.sim.faults.FaultKindRecord` names its effect kind and
channel; the table reads them).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType

from twotank_validation.errors import DatumError
from twotank_validation.online import livediag
from twotank_validation.online.livediag import LiveDiagnosis
from twotank_validation.sim.faults import FAULT_KINDS, Fault, FaultKind


class EffectKind(StrEnum):
    """A kind of effect the diagnosis names; its text is its value (``"input_gain"``)."""

    DELAY = "delay"
    LAG = "lag"
    GAIN = "gain"
    INPUT_GAIN = "input_gain"
    COUPLING = "coupling"
    LEAK = "leak"
    HEAT_LOSS = "heat_loss"
    HOT_SUPPLY = "hot_supply"
    MODE = "mode"
    OFFSET = "offset"
    SATURATION = "saturation"
    STUCK = "stuck"
    UNEXPLAINED = livediag.UNEXPLAINED

    @property
    def record(self) -> EffectRecord:
        """This kind's properties."""
        return EFFECT_RECORDS[self]


class EffectFamily(StrEnum):
    """Where a kind of effect is judged and what becomes of it."""

    STATE_SPACE = "state space"
    """A structured change of the nominal state space: fitted, judged on held-out windows,
    written into the changed model file (the catalogue, :data:`EFFECT_KINDS`)."""
    REPORTED = "reported"
    """Judged outside the state-space fit and reported with a recommendation (it cannot be
    written into an LTI model file, :data:`REPORTED_KINDS`)."""
    ANSWER = "answer"
    """Only a live answer (:mod:`twotank_validation.diagnose.live_jobs`): a saturation that clips
    almost everything, or no effect at all."""


class ActsOn(StrEnum):
    """What an effect changes."""

    OUTPUT = "output"
    INPUT = "input"
    OUTPUT_FROM_OUTPUT = "output from another output"
    TANK = "the tank's balances"
    MODE = "a resonant mode of the plant"
    NOTHING = "nothing"


class ModelNeed(StrEnum):
    """What an effect needs of a model besides its nominal (the catalogue skips it without)."""

    TANK_STATES = "states named 'height' and 'energy'/'temperature'"
    """The mass and energy balances: the nominal ``ss`` names its states."""
    HOT_INPUT = "an input named 'hot'"
    OPERATING_POINT = "the operating temperature (energy state) or height (temperature state)"
    """A heat loss on an energy state needs the operating temperature; a hot-supply change on
    a temperature state the operating height."""
    RESONANT_MODE = "a lightly damped complex pole pair in the excited band"
    """A mode shift acts on one of the nominal's lightly damped pole pairs
    (:data:`~twotank_validation.diagnose.effects.MODE_MAX_DAMPING`) that the data excite."""


@dataclass(frozen=True)
class EffectRecord:
    """Everything about one kind of effect, in one place.

    Attributes:
        kind: the kind.
        family: where it is judged (:class:`EffectFamily`).
        acts_on: what it changes.
        parameters: its fitted parameters' names (SI units in the suffix; model units for
            levels and offsets).
        needs: what it needs of the model besides a nominal (:class:`ModelNeed`).
        moves_operating_point: it shifts the plant's equilibrium by itself (a term on an
            absolute level, temperature or supply the deviation model does not hold): beside
            it a constant output offset cannot be judged on the operating point.
        thermal: it moves the temperature alone at steady state.
        text: the effect in words (``"heat loss"``).
        label: its label, a template of ``{output}``, ``{input}``, ``{source}``, ``{via}`` and
            ``{mode}`` (a mode's number and nominal frequency, ``3 at 10.7 Hz``)
            (:meth:`~twotank_validation.diagnose.effects.EffectSpec.label`).
    """

    kind: EffectKind
    family: EffectFamily
    acts_on: ActsOn
    parameters: tuple[str, ...]
    needs: tuple[ModelNeed, ...]
    moves_operating_point: bool
    thermal: bool
    text: str
    label: str


def _records(*records: EffectRecord) -> Mapping[EffectKind, EffectRecord]:
    return MappingProxyType({r.kind: r for r in records})


_K, _F, _A, _N = EffectKind, EffectFamily, ActsOn, ModelNeed
_TANK = (_N.TANK_STATES,)

EFFECT_RECORDS: Mapping[EffectKind, EffectRecord] = _records(
    EffectRecord(
        _K.DELAY, _F.STATE_SPACE, _A.OUTPUT, ("delay_s",), (), False, False,
        "delay", "delay on {output}",
    ),
    EffectRecord(
        _K.LAG, _F.STATE_SPACE, _A.OUTPUT, ("time_constant_s",), (), False, False,
        "lag", "lag on {output}",
    ),
    EffectRecord(
        _K.GAIN, _F.STATE_SPACE, _A.OUTPUT, ("gain_error",), (), False, False,
        "gain", "gain on {output}",
    ),
    EffectRecord(
        _K.INPUT_GAIN, _F.STATE_SPACE, _A.INPUT, ("gain_error",), (), False, False,
        "input gain", "input gain on {input}",
    ),
    EffectRecord(
        _K.COUPLING, _F.STATE_SPACE, _A.OUTPUT_FROM_OUTPUT, ("dc_gain", "hf_gain"), (), False,
        False, "coupling", "coupling {source} -> {output}{via}",
    ),
    EffectRecord(
        _K.LEAK, _F.STATE_SPACE, _A.TANK, ("rate_per_s",), _TANK, True, False,
        "leak", "leak",
    ),
    EffectRecord(
        _K.HEAT_LOSS, _F.STATE_SPACE, _A.TANK, ("rate_per_s",), (*_TANK, _N.OPERATING_POINT),
        True, True, "heat loss", "heat loss",
    ),
    EffectRecord(
        _K.HOT_SUPPLY, _F.STATE_SPACE, _A.INPUT, ("delta_temperature",),
        (*_TANK, _N.HOT_INPUT, _N.OPERATING_POINT), True, True,
        "hot-supply change", "hot supply temperature",
    ),
    EffectRecord(
        _K.MODE, _F.STATE_SPACE, _A.MODE, ("frequency_hz", "damping_ratio"),
        (_N.RESONANT_MODE,), False, False, "mode shift", "mode {mode}",
    ),
    EffectRecord(
        _K.OFFSET, _F.REPORTED, _A.OUTPUT, ("offset",), (), False, False,
        "offset", "offset on {output}",
    ),
    EffectRecord(
        _K.SATURATION, _F.REPORTED, _A.INPUT, ("level",), (), False, False,
        "saturation", "saturation on {input}",
    ),
    EffectRecord(
        _K.STUCK, _F.ANSWER, _A.INPUT, ("level",), (), False, False,
        "stuck valve", "stuck {input} valve",
    ),
    EffectRecord(
        _K.UNEXPLAINED, _F.ANSWER, _A.NOTHING, (), (), False, False,
        "unexplained", "unexplained",
    ),
)  # fmt: skip
"""Each :class:`EffectKind`'s record (the one table a new kind is added to)."""

EFFECT_KINDS: tuple[EffectKind, ...] = tuple(
    k for k in EffectKind if k.record.family is EffectFamily.STATE_SPACE
)
"""Kinds of state-space effect in the catalogue, in the order they are tried."""

REPORTED_KINDS: tuple[EffectKind, ...] = tuple(
    k for k in EffectKind if k.record.family is EffectFamily.REPORTED
)
"""Kinds of effect judged outside the state-space fit and reported, not written to a model."""


def expected_effect(fault: Fault) -> tuple[EffectKind, str]:
    """The answer that names a simulated fault: ``(kind, channel)``.

    The fault kind's record names it (``effect``, ``effect_channel``; its own channel where
    that is None). The table (docs/diagnosis.md, "The fault named live"):

    ============================  ==========================================================
    rig fault                     answer
    ============================  ==========================================================
    ``leak``                      ``leak`` on ``height``
    ``valve_weak:V``              ``input_gain`` on ``V``
    ``sensor_delay:C``            ``delay`` on ``C``
    ``sensor_bias:C``             ``offset`` on ``C``
    ``heat_loss``                 ``heat_loss`` on ``temperature``
    ``mixing_delay``              ``delay`` on ``temperature``
    ``valve_stuck:V``             ``stuck`` on ``V``
    ``valve_saturation:V``        ``saturation`` on ``V``
    ``hot_supply``                ``hot_supply`` on ``hot``
    ============================  ==========================================================

    Raises:
        DatumError: a fault kind the table does not hold.
    """
    kind = str(fault.kind)  # a Fault's kind, or the text of one (anything with kind, channel)
    if kind not in FAULT_KINDS:
        raise DatumError(
            f"no expected answer for the fault kind {kind!r}; known: {sorted(FAULT_KINDS)}"
        )
    record = FaultKind(kind).record
    own = str(getattr(fault, "channel", ""))
    return EffectKind(
        record.effect
    ), own if record.effect_channel is None else record.effect_channel


def named(answer: LiveDiagnosis | None, fault: Fault) -> bool:
    """Whether ``answer`` names ``fault`` (kind and channel as :func:`expected_effect`)."""
    return answer is not None and (answer.kind, answer.channel) == expected_effect(fault)
