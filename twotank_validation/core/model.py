"""LFT robust-control models: nominal plant, perturbation blocks, noise weights -> P(e^{j theta}).

The generalised plant ``P`` maps ``[v; w; u]`` to ``[z; y]`` (Smith 1995, Sec. 2)::

    z = P11 v + P12 w + P13 u
    y = P21 v + P22 w + P23 u,      v_i = Delta_i z_i,  ||Delta_i|| <= 1,

with ``Delta = diag(Delta_1 .. Delta_m)`` full complex blocks (``Delta_i`` of shape
``(rows_i, cols_i)``: ``v_i`` has ``rows_i`` entries, ``z_i`` has ``cols_i``).

A model is either *structured* (a nominal ``G`` plus perturbations and noise channels, each
with an LTI weight; the perturbations act in parallel) or a user-supplied *generalised*
state-space ``P`` (closed-loop experiments, any interconnection). Structured kinds:

* ``output_multiplicative`` on outputs S:  ``y += E_S^T W v``,  ``z = E_S G u``.
* ``input_multiplicative`` on inputs S:    ``y += G E_S^T W v``, ``z = E_S u``.
* ``additive`` from inputs S_in to outputs S_out: ``y += E_out^T W v``, ``z = E_in u``.
* noise on outputs S: ``y += E_S^T W_n w``.

Continuous parts meet the sampled data as the model's ``intersample`` key says (docs/theory.md
§14): discretised by zero-order hold (the default, as in the paper: a held input), by
first-order hold, or evaluated exactly at the bins (a band-limited input), each part on its
own, at the sample period of the datum. Discrete parts are evaluated as they are.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from twotank_validation.core import lti
from twotank_validation.core.band import Band, parse_band
from twotank_validation.core.control_lti import from_control, is_control_system
from twotank_validation.core.lti import Intersample, StateSpace
from twotank_validation.errors import DimensionError, ModelError, ModelFileError

PERTURBATION_KINDS = ("output_multiplicative", "input_multiplicative", "additive")
BUILTIN_MODELS = {"A": "model_a.yaml", "B": "model_b.yaml"}


@dataclass(frozen=True)
class BlockStructure:
    """Shapes of the full complex blocks ``Delta_i`` (a scalar block is ``(1, 1)``).

    Attributes:
        shapes: ``((rows_1, cols_1), ...)``; ``v_i = Delta_i z_i`` has ``rows_i`` entries.
    """

    shapes: tuple[tuple[int, int], ...]

    def __post_init__(self) -> None:
        for r, c in self.shapes:
            if r < 1 or c < 1:
                raise ModelError(f"block shapes must be positive, found {self.shapes}")

    @property
    def n_blocks(self) -> int:
        """Number of blocks m."""
        return len(self.shapes)

    @property
    def nv(self) -> int:
        """Total dimension of v."""
        return sum(r for r, _ in self.shapes)

    @property
    def nz(self) -> int:
        """Total dimension of z."""
        return sum(c for _, c in self.shapes)

    @cached_property
    def v_slices(self) -> tuple[slice, ...]:
        """Slices of v belonging to each block."""
        return _slices([r for r, _ in self.shapes])

    @cached_property
    def z_slices(self) -> tuple[slice, ...]:
        """Slices of z belonging to each block."""
        return _slices([c for _, c in self.shapes])

    @property
    def all_scalar(self) -> bool:
        """True when every block is 1x1."""
        return all(s == (1, 1) for s in self.shapes)


def _slices(sizes: Sequence[int]) -> tuple[slice, ...]:
    edges = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    return tuple(slice(int(a), int(b)) for a, b in itertools.pairwise(edges))


@dataclass(frozen=True)
class PlantResponse:
    """The generalised plant evaluated at the DFT bins.

    Attributes:
        p: (n_bins, nz + ny, nv + nw + nu) complex.
        blocks: block structure (gives nv, nz).
        nw: noise dimension.
        nu: number of inputs.
        ny: number of outputs.
    """

    p: np.ndarray
    blocks: BlockStructure
    nw: int
    nu: int
    ny: int
    memo: dict[object, Any] = field(default_factory=dict, init=False, compare=False, repr=False)
    """What the solvers derive from ``p`` alone (the route, the closed form's gains), kept
    for the next datum at the same bins (``p`` is not to be changed in place; a response
    made by ``dataclasses.replace`` starts with an empty memo)."""

    def _part(self, row: int, col: int) -> np.ndarray:
        nz, nv = self.blocks.nz, self.blocks.nv
        rows = (slice(0, nz), slice(nz, nz + self.ny))[row]
        cols = (slice(0, nv), slice(nv, nv + self.nw), slice(nv + self.nw, nv + self.nw + self.nu))[
            col
        ]
        return self.p[:, rows, cols]

    @property
    def p11(self) -> np.ndarray:
        """(n_bins, nz, nv)."""
        return self._part(0, 0)

    @property
    def p12(self) -> np.ndarray:
        """(n_bins, nz, nw)."""
        return self._part(0, 1)

    @property
    def p13(self) -> np.ndarray:
        """(n_bins, nz, nu)."""
        return self._part(0, 2)

    @property
    def p21(self) -> np.ndarray:
        """(n_bins, ny, nv)."""
        return self._part(1, 0)

    @property
    def p22(self) -> np.ndarray:
        """(n_bins, ny, nw)."""
        return self._part(1, 1)

    @property
    def p23(self) -> np.ndarray:
        """(n_bins, ny, nu): the nominal plant."""
        return self._part(1, 2)

    @cached_property
    def coupled(self) -> bool:
        """Whether ``P11`` or ``P12`` is non-zero at some bin (``z`` depends on ``v`` or ``w``).

        Computed once per response (``p`` is not to be changed in place).
        """
        nz, nx = self.blocks.nz, self.blocks.nv + self.nw
        return bool(np.any(self.p[:, :nz, :nx]))


@dataclass(frozen=True)
class Perturbation:
    """One structured perturbation block.

    Attributes:
        kind: one of ``PERTURBATION_KINDS``.
        inputs: input indices (input-multiplicative and additive).
        outputs: output indices (output-multiplicative and additive).
        weight: continuous or discrete LTI weight, square, on the v side
            (``len(outputs)`` square for output-multiplicative and additive,
            ``len(inputs)`` square for input-multiplicative).
        name: label for reports.
    """

    kind: str
    inputs: tuple[int, ...]
    outputs: tuple[int, ...]
    weight: StateSpace
    name: str

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of Delta: dim v, dim z."""
        if self.kind == "output_multiplicative":
            return (len(self.outputs), len(self.outputs))
        if self.kind == "input_multiplicative":
            return (len(self.inputs), len(self.inputs))
        return (len(self.outputs), len(self.inputs))


@dataclass(frozen=True)
class NoiseChannel:
    """Weighted unknown input ``y[outputs] += W_n w``.

    Attributes:
        outputs: output indices.
        weight: LTI weight, square of size ``len(outputs)``.
        name: label.
    """

    outputs: tuple[int, ...]
    weight: StateSpace
    name: str


@dataclass(frozen=True)
class LFTModel:
    """A robust-control model set ``F_u(P, Delta)`` with unit-norm w.

    Exactly one of ``nominal`` (structured model) or ``generalized`` is the source of P.

    Attributes:
        name: model name (used in topics and reports).
        input_names: names of u entries.
        output_names: names of y entries.
        blocks: perturbation block structure.
        block_names: one label per block.
        noise_names: one label per noise entry (length nw).
        nominal: the nominal plant G (continuous or discrete), structured models.
        perturbations: structured perturbations, one per block.
        noise: noise channels.
        generalized: user-supplied P as a state space ``[v; w; u] -> [z; y]``.
        description: free text.
        operating_point: output values around which the model holds (model units).
        band: the frequencies the model set is claimed over (:class:`~twotank_validation.
            core.band.Band`); ``None``: every bin up to Nyquist.
        intersample: how the input behaves between samples, i.e. how every continuous part
            is evaluated at the bins (:class:`~twotank_validation.core.lti.Intersample`).
    """

    name: str
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    blocks: BlockStructure
    block_names: tuple[str, ...]
    noise_names: tuple[str, ...]
    nominal: StateSpace | None = None
    perturbations: tuple[Perturbation, ...] = ()
    noise: tuple[NoiseChannel, ...] = ()
    generalized: StateSpace | None = None
    description: str = ""
    operating_point: Mapping[str, float] = field(default_factory=dict)
    band: Band | None = None
    intersample: Intersample = Intersample.ZOH
    cache: dict[object, Any] = field(default_factory=dict, compare=False, repr=False)
    """Memo of derived quantities (e.g. pulse-response moments per sample period)."""

    def __post_init__(self) -> None:
        if (self.nominal is None) == (self.generalized is None):
            raise ModelError(
                f"model {self.name!r}: give either a nominal plant or a generalized plant"
            )
        if self.generalized is not None:
            rows = self.blocks.nz + self.ny
            cols = self.blocks.nv + self.nw + self.nu
            if self.generalized.shape != (rows, cols):
                raise DimensionError(
                    f"model {self.name!r}: generalized plant is {self.generalized.shape} but "
                    "blocks, "
                    f"noise, inputs and outputs need ({rows}, {cols}) = (nz+ny, nv+nw+nu)"
                )
            lti.check_stable(self.generalized, f"generalized plant of model {self.name!r}")
            return
        assert self.nominal is not None
        if self.nominal.shape != (self.ny, self.nu):
            raise DimensionError(
                f"model {self.name!r}: nominal plant is {self.nominal.shape} (outputs, inputs) but "
                f"the model names {self.ny} outputs and {self.nu} inputs"
            )
        lti.check_stable(self.nominal, f"nominal plant of model {self.name!r}")
        for pert in self.perturbations:
            lti.check_stable(pert.weight, f"weight of perturbation {pert.name!r}")
        for ch in self.noise:
            lti.check_stable(ch.weight, f"weight of noise {ch.name!r}")

    @property
    def nu(self) -> int:
        """Number of inputs."""
        return len(self.input_names)

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return len(self.output_names)

    @property
    def nw(self) -> int:
        """Dimension of the unknown input w."""
        return len(self.noise_names)

    def nominal_discrete(self, dt_s: float) -> StateSpace:
        """The nominal plant ``P23`` discretised at ``dt_s`` seconds by the model's hold.

        Zero-order hold, or first-order hold under ``foh`` and ``exact`` (the time-domain
        stand-in of the exact evaluation, :attr:`Intersample.simulation_method`).
        """
        if self.nominal is not None:
            return lti.discretise(self.nominal, dt_s, self.intersample)
        assert self.generalized is not None
        g = lti.discretise(self.generalized, dt_s, self.intersample)
        nz, c0 = self.blocks.nz, self.blocks.nv + self.nw
        delays = g.output_delays_s[nz:] if g.output_delays_s else ()
        return StateSpace(g.a, g.b[:, c0:], g.c[nz:], g.d[nz:, c0:], g.dt_s, delays)

    def response(self, theta: np.ndarray, dt_s: float) -> PlantResponse:
        """Evaluate P at ``z = exp(j theta)``.

        Args:
            theta: (n_bins,) float, rad/sample.
            dt_s: sample period (s) of the data.

        Returns:
            The plant response, ``p`` of shape (n_bins, nz+ny, nv+nw+nu).
        """
        theta = np.asarray(theta, dtype=float)
        if self.generalized is not None:
            p = lti.bin_response(self.generalized, theta, dt_s, self.intersample)
            return PlantResponse(p, self.blocks, self.nw, self.nu, self.ny)
        return PlantResponse(
            self._structured_response(theta, dt_s), self.blocks, self.nw, self.nu, self.ny
        )

    def _structured_response(self, theta: np.ndarray, dt_s: float) -> np.ndarray:
        assert self.nominal is not None
        nb = theta.size
        nz, nv, nw, nu, ny = self.blocks.nz, self.blocks.nv, self.nw, self.nu, self.ny
        g = lti.bin_response(self.nominal, theta, dt_s, self.intersample)  # (nb, ny, nu)
        p = np.zeros((nb, nz + ny, nv + nw + nu), dtype=complex)
        y_rows = slice(nz, nz + ny)
        p[:, y_rows, nv + nw :] = g
        for pert, vs, zs in zip(
            self.perturbations, self.blocks.v_slices, self.blocks.z_slices, strict=True
        ):
            wgt = lti.bin_response(pert.weight, theta, dt_s, self.intersample)
            if pert.kind == "output_multiplicative":
                outs = list(pert.outputs)
                p[:, zs, nv + nw :] = g[:, outs, :]
                p[:, nz + np.array(outs)[:, None], np.arange(vs.start, vs.stop)[None, :]] = wgt
            elif pert.kind == "input_multiplicative":
                ins = list(pert.inputs)
                p[:, zs.start + np.arange(len(ins)), nv + nw + np.array(ins)] = 1.0
                p[:, y_rows, vs] = g[:, :, ins] @ wgt
            else:  # additive
                outs, ins = list(pert.outputs), list(pert.inputs)
                p[:, zs.start + np.arange(len(ins)), nv + nw + np.array(ins)] = 1.0
                p[:, nz + np.array(outs)[:, None], np.arange(vs.start, vs.stop)[None, :]] = wgt
        col = nv
        for ch in self.noise:
            wgt = lti.bin_response(ch.weight, theta, dt_s, self.intersample)
            k = len(ch.outputs)
            p[:, nz + np.array(ch.outputs)[:, None], np.arange(col, col + k)[None, :]] = wgt
            col += k
        return p


# --------------------------------------------------------------------------- YAML loading


def _err(source: str, where: str, msg: str) -> ModelFileError:
    return ModelFileError(f"{source}: {where}: {msg}")


def _matrix(value: Any, source: str, where: str) -> np.ndarray:
    try:
        arr = np.atleast_2d(np.asarray(value, dtype=float))
    except (TypeError, ValueError) as err:
        raise _err(
            source, where, f"expected a number or a list of lists of numbers, found {value!r}"
        ) from err
    if arr.ndim != 2:
        raise _err(source, where, f"expected a matrix, found shape {arr.shape}")
    return arr


def _check_keys(node: Mapping[str, Any], allowed: set[str], source: str, where: str) -> None:
    unknown = set(node) - allowed
    if unknown:
        raise _err(source, where, f"unknown keys {sorted(unknown)}; allowed: {sorted(allowed)}")


def parse_lti(node: Any, source: str, where: str) -> StateSpace:
    """Parse an LTI description: ``{gain: K}``, ``{tf: {num, den}}`` or ``{ss: {A, B, C, D}}``.

    A number alone is a static gain; ``ss`` may carry ``dt_s`` for a discrete system. A
    python-control ``StateSpace`` or ``TransferFunction`` (continuous, or discrete with its
    ``dt`` in seconds) is taken as it is.
    """
    if is_control_system(node):
        try:
            return from_control(node, where)
        except ModelError as err:
            raise _err(source, where, str(err)) from err
    if isinstance(node, bool):
        raise _err(source, where, f"expected a number or an LTI mapping, found {node!r}")
    if isinstance(node, int | float):
        return lti.static_gain(float(node))
    if not isinstance(node, Mapping) or len(node) != 1:
        raise _err(
            source, where, f"expected one of {{gain: ..}}, {{tf: ..}}, {{ss: ..}}, found {node!r}"
        )
    ((key, body),) = node.items()
    if key == "gain":
        return lti.static_gain(_matrix(body, source, f"{where}.gain"))
    if key == "tf":
        if not isinstance(body, Mapping) or set(body) != {"num", "den"}:
            raise _err(
                source, f"{where}.tf", "expected {num: [...], den: [...]} (descending powers of s)"
            )
        try:
            return lti.from_transfer_function(body["num"], body["den"])
        except (TypeError, ValueError) as err:
            raise _err(source, f"{where}.tf", str(err)) from err
    if key == "ss":
        if not isinstance(body, Mapping):
            raise _err(source, f"{where}.ss", "expected a mapping with A, B, C, D")
        _check_keys(
            body, {"A", "B", "C", "D", "dt_s", "output_delays_s", "states"}, source, f"{where}.ss"
        )
        missing = {"A", "B", "C", "D"} - set(body)
        if missing:
            raise _err(source, f"{where}.ss", f"missing {sorted(missing)}")
        mats = [_matrix(body[k], source, f"{where}.ss.{k}") for k in "ABCD"]
        try:
            dt = body.get("dt_s")
            dt_s = None if dt is None else float(dt)
        except (TypeError, ValueError) as err:
            raise _err(
                source, f"{where}.ss.dt_s", f"expected a sample period in s, found {dt!r}"
            ) from err
        delays = body.get("output_delays_s") or []
        states = body.get("states")
        if not isinstance(delays, list):
            raise _err(
                source, f"{where}.ss.output_delays_s", "expected a list, one delay (s) per output"
            )
        if states is not None and (
            not isinstance(states, list) or len(states) != np.atleast_2d(mats[0]).shape[0]
        ):
            raise _err(source, f"{where}.ss.states", "expected a list of names, one per state")
        try:
            delay_values = tuple(float(t) for t in delays)
        except (TypeError, ValueError) as err:
            raise _err(source, f"{where}.ss.output_delays_s", f"expected numbers: {err}") from err
        try:
            return StateSpace(mats[0], mats[1], mats[2], mats[3], dt_s, delay_values)
        except ModelError as err:
            raise _err(source, f"{where}.ss", str(err)) from err
    raise _err(source, where, f"unknown LTI kind {key!r}; use gain, tf or ss")


def _diag_weight(node: Any, size: int, source: str, where: str) -> StateSpace:
    """A weight: one LTI (scalar -> times identity, or size x size) or a list (diagonal)."""
    if isinstance(node, list):
        if len(node) != size:
            raise _err(source, where, f"a list of weights needs {size} entries, found {len(node)}")
        parts = [parse_lti(n, source, f"{where}[{i}]") for i, n in enumerate(node)]
        return _block_diag(parts, source, where)
    sys = parse_lti(node, source, where)
    if sys.shape == (size, size):
        return sys
    if sys.shape == (1, 1):
        return _block_diag([sys] * size, source, where)
    raise _err(source, where, f"weight is {sys.shape}, expected scalar or ({size}, {size})")


def _block_diag(parts: Sequence[StateSpace], source: str, where: str) -> StateSpace:
    from scipy.linalg import block_diag  # noqa: PLC0415 (only needed when parsing)

    if any(p.shape != (1, 1) for p in parts):
        raise _err(source, where, "each entry of a diagonal weight must be scalar (1x1)")
    dts = {p.dt_s for p in parts}
    if len(dts) != 1:
        raise _err(
            source,
            where,
            f"diagonal weight mixes sample periods {sorted(map(str, dts))}: "
            "give every entry in continuous time or all with the same dt_s",
        )
    return StateSpace(
        block_diag(*[p.a for p in parts]) if any(p.n_states for p in parts) else np.zeros((0, 0)),
        block_diag(*[p.b for p in parts]),
        block_diag(*[p.c for p in parts]),
        block_diag(*[p.d for p in parts]),
        dts.pop(),
    )


def _indices(names: Any, known: Sequence[str], source: str, where: str) -> tuple[int, ...]:
    if isinstance(names, str):
        names = [names]
    if not isinstance(names, list) or not names:
        raise _err(source, where, f"expected a non-empty list of channel names, found {names!r}")
    out = []
    for n in names:
        if n not in known:
            raise _err(source, where, f"unknown channel {n!r}; the model has {list(known)}")
        out.append(list(known).index(n))
    if len(set(out)) != len(out):
        raise _err(source, where, f"channel listed twice in {names}")
    return tuple(out)


def _names(node: Any, source: str, key: str) -> tuple[str, ...]:
    if not isinstance(node, list) or not node or not all(isinstance(n, str) for n in node):
        raise _err(source, key, f"expected a non-empty list of names, found {node!r}")
    if len(set(node)) != len(node):
        raise _err(source, key, f"duplicate names in {node}")
    return tuple(node)


def _band(node: Any, source: str) -> Band | None:
    try:
        return parse_band(node)
    except ModelError as err:
        raise _err(source, "band", str(err)) from err


def _intersample(node: Any, source: str) -> Intersample:
    if node is None:
        return Intersample.ZOH
    try:
        return Intersample(node)
    except ValueError as err:
        raise _err(
            source,
            "intersample",
            f"expected one of {[m.value for m in Intersample]} (the input held between samples, "
            f"or band-limited: first-order hold or exact), found {node!r}",
        ) from err


def model_from_dict(doc: Any, source: str = "<dict>") -> LFTModel:
    """Build a model from a parsed YAML document (schema in docs/models.md).

    Raises:
        ModelFileError: schema violations, naming the offending key.
        ModelError: an unstable or dimensionally inconsistent model.
    """
    if not isinstance(doc, Mapping):
        raise _err(source, "top level", f"expected a mapping, found {type(doc).__name__}")
    allowed = {"name", "description", "inputs", "outputs", "operating_point", "nominal",
               "perturbations", "noise", "generalized_plant", "derivation", "band",
               "intersample"}  # fmt: skip
    _check_keys(doc, allowed, source, "top level")
    for key in ("name", "inputs", "outputs"):
        if key not in doc:
            raise _err(source, "top level", f"missing required key {key!r}")
    name = str(doc["name"])
    inputs = _names(doc["inputs"], source, "inputs")
    outputs = _names(doc["outputs"], source, "outputs")
    op = doc.get("operating_point", {}) or {}
    if not isinstance(op, Mapping):
        raise _err(source, "operating_point", "expected a mapping of output name to value")
    op_values: dict[str, float] = {}
    for key, value in op.items():
        if key not in outputs:
            raise _err(
                source, "operating_point", f"unknown output {key!r}; the model has {list(outputs)}"
            )
        try:
            op_values[str(key)] = float(value)
        except (TypeError, ValueError) as err:
            raise _err(
                source, f"operating_point.{key}", f"expected a number, found {value!r}"
            ) from err
    for key in ("perturbations", "noise"):
        if doc.get(key) is not None and not isinstance(doc[key], list):
            raise _err(source, key, f"expected a list, found {doc[key]!r}")
    common: dict[str, Any] = {
        "name": name,
        "input_names": inputs,
        "output_names": outputs,
        "description": str(doc.get("description", "")),
        "operating_point": op_values,
        "band": _band(doc.get("band"), source),
        "intersample": _intersample(doc.get("intersample"), source),
    }
    if "generalized_plant" in doc:
        if "nominal" in doc or "perturbations" in doc or "noise" in doc:
            raise _err(
                source, "top level", "generalized_plant excludes nominal/perturbations/noise"
            )
        gp = doc["generalized_plant"]
        if not isinstance(gp, Mapping):
            raise _err(source, "generalized_plant", "expected a mapping")
        _check_keys(gp, {"ss", "blocks", "noise_inputs"}, source, "generalized_plant")
        try:
            shapes = tuple((int(r), int(c)) for r, c in gp["blocks"])
            nw = int(gp["noise_inputs"])
        except (KeyError, TypeError, ValueError) as err:
            raise _err(
                source, "generalized_plant", "needs blocks: [[rows, cols], ...] and noise_inputs: n"
            ) from err
        if nw < 0:
            raise _err(source, "generalized_plant.noise_inputs", f"must be >= 0, found {nw}")
        return LFTModel(
            blocks=BlockStructure(shapes),
            block_names=tuple(f"block{i}" for i in range(len(shapes))),
            noise_names=tuple(f"w{i}" for i in range(nw)),
            generalized=parse_lti({"ss": gp.get("ss")}, source, "generalized_plant"),
            **common,
        )
    if "nominal" not in doc:
        raise _err(source, "top level", "missing 'nominal' (or give 'generalized_plant')")
    nominal = parse_lti(doc["nominal"], source, "nominal")
    perts: list[Perturbation] = []
    for i, node in enumerate(doc.get("perturbations", []) or []):
        where = f"perturbations[{i}]"
        if not isinstance(node, Mapping):
            raise _err(source, where, "expected a mapping with kind, channels and weight")
        _check_keys(node, {"kind", "inputs", "outputs", "weight", "name"}, source, where)
        kind = node.get("kind")
        if kind not in PERTURBATION_KINDS:
            raise _err(source, where, f"kind must be one of {PERTURBATION_KINDS}, found {kind!r}")
        ins = (
            _indices(node["inputs"], inputs, source, f"{where}.inputs") if "inputs" in node else ()
        )
        outs = (
            _indices(node["outputs"], outputs, source, f"{where}.outputs")
            if "outputs" in node
            else ()
        )
        need_in = kind in ("input_multiplicative", "additive")
        need_out = kind in ("output_multiplicative", "additive")
        if need_in != bool(ins) or need_out != bool(outs):
            raise _err(
                source,
                where,
                f"{kind} needs {'inputs ' if need_in else ''}{'outputs' if need_out else ''} only",
            )
        size = len(ins) if kind == "input_multiplicative" else len(outs)
        if "weight" not in node:
            raise _err(source, where, "missing weight")
        weight = _diag_weight(node["weight"], size, source, f"{where}.weight")
        label = str(
            node.get(
                "name",
                f"{kind}:{','.join(outputs[o] for o in outs) or ','.join(inputs[j] for j in ins)}",
            )
        )
        perts.append(Perturbation(kind, ins, outs, weight, label))
    noise: list[NoiseChannel] = []
    for i, node in enumerate(doc.get("noise", []) or []):
        where = f"noise[{i}]"
        if not isinstance(node, Mapping):
            raise _err(source, where, "expected a mapping with outputs and weight")
        _check_keys(node, {"outputs", "weight", "name"}, source, where)
        if "outputs" not in node or "weight" not in node:
            raise _err(source, where, "needs outputs and weight")
        outs = _indices(node["outputs"], outputs, source, f"{where}.outputs")
        weight = _diag_weight(node["weight"], len(outs), source, f"{where}.weight")
        noise.append(
            NoiseChannel(outs, weight, str(node.get("name", ",".join(outputs[o] for o in outs))))
        )
    noise_names = tuple(
        f"{ch.name}[{k}]" if len(ch.outputs) > 1 else ch.name
        for ch in noise
        for k in range(len(ch.outputs))
    )
    return LFTModel(
        blocks=BlockStructure(tuple(p.shape for p in perts)),
        block_names=tuple(p.name for p in perts),
        noise_names=noise_names,
        nominal=nominal,
        perturbations=tuple(perts),
        noise=tuple(noise),
        **common,
    )


def load_model(path_or_name: str | Path | Mapping[str, Any]) -> LFTModel:
    """Load a model from a YAML file, a built-in model by name (``"A"``, ``"B"``), or a document.

    A document is a mapping of the YAML schema; its ``nominal`` and ``weight`` entries may be
    python-control ``StateSpace`` / ``TransferFunction`` objects.

    Raises:
        ModelFileError: missing file, YAML syntax error, schema violation.
    """
    if isinstance(path_or_name, Mapping):
        return model_from_dict(path_or_name, "<document>")
    doc, source = load_model_document(path_or_name)
    return model_from_dict(doc, source)


def load_model_document(path_or_name: str | Path) -> tuple[Any, str]:
    """The parsed YAML document of a model file or built-in model, and its source label.

    Raises:
        ModelFileError: missing file or YAML syntax error (the schema is not checked here).
    """
    key = str(path_or_name)
    if key in BUILTIN_MODELS:
        text = (
            resources.files("twotank_validation")
            .joinpath("models", BUILTIN_MODELS[key])
            .read_text()
        )
        source = f"built-in model {key}"
    else:
        path = Path(path_or_name)
        if not path.is_file():
            raise ModelFileError(
                f"model file {path} not found: give a YAML file or one of {sorted(BUILTIN_MODELS)}"
            )
        text = path.read_text()
        source = str(path)
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ModelFileError(f"{source}: not valid YAML: {err}") from err
    return doc, source
