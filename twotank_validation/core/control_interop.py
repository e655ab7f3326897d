"""A model set as python-control objects: nominal, weights and the generalised plant P.

:func:`to_control_set` gives what a robust design in python-control starts from: the nominal
plant, each perturbation and noise weight, and ``P`` (``[v; w; u] -> [z; y]``) as one
``control.StateSpace`` with its block partition (which rows and columns belong to which
``Delta_i``, to ``w``, ``u``, ``z`` and ``y``). Models built from python-control systems are
read by :func:`~twotank_validation.core.model.load_model` (a model document whose ``nominal``
or ``weight`` entries are ``control.StateSpace`` / ``control.TransferFunction`` objects).

``P`` is built by interconnecting the parts' state spaces (the structured forms of
:mod:`~twotank_validation.core.model`). With ``dt_s`` each part is first discretised by
the model's hold on its own (zero-order, or first-order under ``intersample: foh``), as the
validator does, so the discrete ``P`` has exactly the validator's ``P(e^{j theta})`` (under
``intersample: exact`` the parts are first-order-hold discretised, which the validator's
exact evaluation at the bins is not); the continuous ``P`` is exact too, except that an input
multiplicative block's series ``G W`` discretised as a whole differs slightly from the
product of the parts' holds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from twotank_validation.core import lti
from twotank_validation.core.control_lti import to_control
from twotank_validation.core.lti import StateSpace
from twotank_validation.core.model import LFTModel
from twotank_validation.errors import ModelError


@dataclass(frozen=True)
class ControlModelSet:
    """A model set as python-control objects.

    Attributes:
        name: the model's name.
        nominal: the nominal plant ``G`` (None for a generalised-plant model).
        weights: each perturbation's and noise channel's weight, by block name.
        plant: ``P`` as one ``control.StateSpace``, inputs ``[v; w; u]``, outputs ``[z; y]``.
        block_shapes: ``((rows_i, cols_i), ...)`` of the blocks ``Delta_i``
            (``v_i = Delta_i z_i``: ``rows_i`` entries of v, ``cols_i`` of z).
        block_names: one name per block.
        nw: entries of ``w``; nu: of ``u``; ny: of ``y``.
        input_slices: ``{"v": .., "w": .., "u": ..}`` column slices of ``P``.
        output_slices: ``{"z": .., "y": ..}`` row slices of ``P``.
    """

    name: str
    nominal: Any
    weights: dict[str, Any]
    plant: Any
    block_shapes: tuple[tuple[int, int], ...]
    block_names: tuple[str, ...]
    nw: int
    nu: int
    ny: int
    input_slices: dict[str, slice]
    output_slices: dict[str, slice]


def to_control_set(model: LFTModel, dt_s: float | None = None) -> ControlModelSet:
    """The model as python-control objects; discrete at ``dt_s`` (the model's hold per part).

    Raises:
        ModelError: a part with transport delays, or discrete parts without ``dt_s`` of
            their own period mixed with continuous ones.
    """
    disc: Callable[[StateSpace], StateSpace] = (
        (lambda s: lti.discretise(s, dt_s, model.intersample))
        if dt_s is not None
        else (lambda s: s)
    )
    nv, nz = model.blocks.nv, model.blocks.nz
    nw, nu, ny = model.nw, model.nu, model.ny
    ins = [f"v[{i}]" for i in range(nv)] + [f"w[{i}]" for i in range(nw)] + list(model.input_names)
    outs = [f"z[{i}]" for i in range(nz)] + list(model.output_names)
    if model.generalized is not None:
        p = disc(model.generalized)
        nominal = None
        weights: dict[str, Any] = {}
    else:
        assert model.nominal is not None
        p = _structured_plant(model, disc)
        nominal = to_control(
            disc(model.nominal), model.name, list(model.input_names), list(model.output_names)
        )
        weights = {
            pert.name: to_control(disc(pert.weight), pert.name) for pert in model.perturbations
        }
        weights.update({ch.name: to_control(disc(ch.weight), ch.name) for ch in model.noise})
    return ControlModelSet(
        name=model.name,
        nominal=nominal,
        weights=weights,
        plant=to_control(p, f"{model.name}_P", ins, outs),
        block_shapes=model.blocks.shapes,
        block_names=model.block_names,
        nw=nw,
        nu=nu,
        ny=ny,
        input_slices={
            "v": slice(0, nv),
            "w": slice(nv, nv + nw),
            "u": slice(nv + nw, nv + nw + nu),
        },
        output_slices={"z": slice(0, nz), "y": slice(nz, nz + ny)},
    )


def _structured_plant(model: LFTModel, disc: Callable[[StateSpace], StateSpace]) -> StateSpace:
    """``P`` of a structured model by interconnecting its parts' state spaces."""
    assert model.nominal is not None
    g = disc(model.nominal)
    parts = (
        [g] + [disc(p.weight) for p in model.perturbations] + [disc(c.weight) for c in model.noise]
    )
    periods = {s.dt_s for s in parts}
    if len(periods) != 1:
        raise ModelError(
            f"model {model.name!r} mixes continuous and discrete parts (sample periods "
            f"{sorted(map(str, periods))}): export it with dt_s"
        )
    if any(s.output_delays_s for s in parts):
        raise ModelError(
            f"model {model.name!r} has transport delays, which a python-control state space "
            "cannot hold: approximate them (control.pade) in the model"
        )
    nv, nz, nw, nu, ny = model.blocks.nv, model.blocks.nz, model.nw, model.nu, model.ny
    n_in, n_out = nv + nw + nu, nz + ny
    uc = slice(nv + nw, n_in)
    yr = np.arange(nz, n_out)
    # state layout: G, then per perturbation its weight (and a copy of G for an input
    # multiplicative block, which passes W v through the plant), then the noise weights
    sizes = [g.n_states]
    for pert in model.perturbations:
        sizes.append(pert.weight.n_states)
        sizes.append(g.n_states if pert.kind == "input_multiplicative" else 0)
    sizes += [c.weight.n_states for c in model.noise]
    edges = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    n = int(edges[-1])
    a, b = np.zeros((n, n)), np.zeros((n, n_in))
    c, d = np.zeros((n_out, n)), np.zeros((n_out, n_in))
    sg = slice(edges[0], edges[1])
    a[sg, sg], b[sg, uc], c[yr, sg], d[yr, uc] = g.a, g.b, g.c, g.d
    for i, (pert, vs, zs) in enumerate(
        zip(model.perturbations, model.blocks.v_slices, model.blocks.z_slices, strict=True)
    ):
        w = parts[1 + i]
        sw = slice(edges[1 + 2 * i], edges[2 + 2 * i])
        a[sw, sw], b[sw, vs] = w.a, w.b
        zr = np.arange(zs.start, zs.stop)
        if pert.kind == "output_multiplicative":
            outs = list(pert.outputs)
            c[zr, sg], d[zr, uc] = g.c[outs], g.d[outs]
            c[nz + np.array(outs)[:, None], np.arange(sw.start, sw.stop)[None, :]] = w.c
            d[nz + np.array(outs)[:, None], np.arange(vs.start, vs.stop)[None, :]] = w.d
        elif pert.kind == "input_multiplicative":
            cols = list(pert.inputs)
            d[zr, nv + nw + np.array(cols)] = 1.0
            s2 = slice(edges[2 + 2 * i], edges[3 + 2 * i])
            bg, dg = g.b[:, cols], g.d[:, cols]
            a[s2, s2] = g.a
            a[s2, sw] = bg @ w.c
            b[s2, vs] = bg @ w.d
            c[yr, s2] = g.c
            c[yr, sw] += dg @ w.c
            d[yr, vs] += dg @ w.d
        else:  # additive
            outs, cols = list(pert.outputs), list(pert.inputs)
            d[zr, nv + nw + np.array(cols)] = 1.0
            c[nz + np.array(outs)[:, None], np.arange(sw.start, sw.stop)[None, :]] = w.c
            d[nz + np.array(outs)[:, None], np.arange(vs.start, vs.stop)[None, :]] = w.d
    col = nv
    base = 1 + 2 * len(model.perturbations)
    for j, ch in enumerate(model.noise):
        w = parts[1 + len(model.perturbations) + j]
        sn = slice(edges[base + j], edges[base + j + 1])
        k = len(ch.outputs)
        rows = nz + np.array(ch.outputs)[:, None]
        a[sn, sn], b[sn, col : col + k] = w.a, w.b
        c[rows, np.arange(sn.start, sn.stop)[None, :]] = w.c
        d[rows, np.arange(col, col + k)[None, :]] = w.d
        col += k
    return StateSpace(a, b, c, d, g.dt_s)


def frequency_response(plant: Any, theta: np.ndarray) -> np.ndarray:
    """The response of a python-control system, evaluated by python-control itself.

    Args:
        plant: a python-control system.
        theta: (k,) rad/sample for a discrete system (at ``e^{j theta}``), rad/s for a
            continuous one (at ``j theta``).

    Returns:
        (k, outputs, inputs) complex.
    """
    dt = plant.dt
    points = np.exp(1j * theta) if dt else 1j * np.asarray(theta)
    resp = np.asarray(plant(points, squeeze=False))
    return np.moveaxis(resp, -1, 0)
