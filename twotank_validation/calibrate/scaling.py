"""How large a block's uncertainty the data demand: the uniform scaling and the per-bin picture.

A block of the model set is a perturbation ``Delta_i`` (its weight acts on ``v_i``) or a noise
channel (its weight acts on ``w``). Scaling the block's weight by ``s`` is scaling the columns
of the generalised plant ``P`` that the block feeds (``P[:, :, v_i]`` or ``P[:, :, w_j]``), so
every search here works on the plant response evaluated once per window, with the window
solver's lower bounds :func:`~twotank_validation.core.validate.lower_bins` (closed form, fast
path or SDP, as :func:`~twotank_validation.core.validate.validate` would take; the closed form
without its witness).

``beta`` never grows as a block's weight grows (the model set only gets larger), which makes
the searches below one-dimensional root finding.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.optimize

from twotank_validation.core import lti, solvers
from twotank_validation.core.datum import Datum
from twotank_validation.core.model import LFTModel, PlantResponse
from twotank_validation.core.solvers import DecoupledStructure
from twotank_validation.core.validate import (
    check_compatible,
    lower_bins,
    takes_closed_form,
    total_beta,
    validation_band,
)
from twotank_validation.diagnose.fit import excited_bins
from twotank_validation.errors import DatumError

S_MAX = 1e6
"""Largest scaling tried: a block that needs more cannot explain the data alone."""
S_MIN = 1e-9
"""Smallest scaling told apart from zero."""
_BISECTIONS = 24
"""Bisection steps of the per-bin search (in log scale, from a bracket of ratio 4: about
1e-7 relative)."""


class CalibrationError(DatumError):
    """The data or the request cannot be calibrated (no judged window, an unknown block)."""


@dataclass(frozen=True)
class Block:
    """One perturbation or noise block of a model, as the calibration scales it.

    Attributes:
        name: the block's name (a perturbation's or noise channel's ``name``).
        kind: ``"perturbation"`` or ``"noise"``.
        index: position among the model's perturbations or noise channels.
        columns: the columns of ``P`` (``[v; w; u]`` order) that the block's weight feeds.
        weight: the block's stated weight (continuous or discrete), or None for a block of a
            generalised plant (scaled as its columns of ``P``).
        intersample: the model's intersample assumption (how a continuous weight is
            evaluated at the bins).
    """

    name: str
    kind: str
    index: int
    columns: slice
    weight: lti.StateSpace | None
    intersample: lti.Intersample = lti.Intersample.ZOH

    @property
    def is_noise(self) -> bool:
        """Whether the block is a noise channel."""
        return self.kind == "noise"


def model_blocks(model: LFTModel) -> list[Block]:
    """Every perturbation block, then every noise channel, of ``model``.

    A generalised plant's noise inputs are one block each (``w0``, ``w1``, ...).
    """
    out = []
    for i, (name, cols) in enumerate(zip(model.block_names, model.blocks.v_slices, strict=True)):
        weight = model.perturbations[i].weight if model.perturbations else None
        out.append(Block(name, "perturbation", i, cols, weight, model.intersample))
    col = model.blocks.nv
    if model.generalized is not None:
        for j, name in enumerate(model.noise_names):
            out.append(
                Block(name, "noise", j, slice(col + j, col + j + 1), None, model.intersample)
            )
        return out
    for j, ch in enumerate(model.noise):
        k = len(ch.outputs)
        out.append(Block(ch.name, "noise", j, slice(col, col + k), ch.weight, model.intersample))
        col += k
    return out


def choose_blocks(model: LFTModel, names: Sequence[str] | None) -> list[Block]:
    """The blocks named (all of them for None or an empty list), in the order named.

    Raises:
        CalibrationError: a name that is not a block of the model (the message lists them).
    """
    blocks = model_blocks(model)
    if not blocks:
        raise CalibrationError(
            f"model {model.name!r} has no perturbation or noise block to calibrate"
        )
    if not names:
        return blocks
    by_name = {b.name: b for b in blocks}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise CalibrationError(
            f"model {model.name!r} has no block {', '.join(map(repr, unknown))}; its blocks are "
            f"{', '.join(by_name)}: give --block one of these"
        )
    if len(set(names)) != len(names):
        raise CalibrationError(f"a block is named twice in {list(names)}")
    return [by_name[n] for n in names]


@dataclass(frozen=True)
class WindowProblem:
    """One window's datum and the model's plant at its bins (evaluated once).

    Attributes:
        datum: the window's datum.
        response: ``P`` at ``datum.theta`` (the model as it stands).
        method: the solver route (``"auto"``, ...), as :func:`validate`.
        counted: (k,) int, the bins β counts: the model's validation band
            (:func:`~twotank_validation.core.validate.validation_band`, as :func:`validate`
            totals them); None: every bin (a model without a band).
    """

    datum: Datum
    response: PlantResponse
    method: str = "auto"
    counted: np.ndarray | None = None

    @classmethod
    def of(cls, datum: Datum, model: LFTModel, method: str = "auto") -> WindowProblem:
        """The problem of ``model`` on ``datum`` (raises as :func:`check_compatible`)."""
        check_compatible(datum, model)
        mask = validation_band(datum, model)
        counted = None if mask is None else np.flatnonzero(mask)
        return cls(datum, model.response(datum.theta, datum.ts_s), method, counted)

    def counted_bins(self) -> np.ndarray:
        """(k,) int, the bins β counts (every bin without a band)."""
        return np.arange(self.datum.theta.size) if self.counted is None else self.counted

    def bin_lower(
        self, block: Block, factor: float | np.ndarray, bins: np.ndarray | None = None
    ) -> np.ndarray:
        """(k,) lower bounds on min ||W(n)|| with the block's columns times ``factor``.

        Args:
            block: the block scaled.
            factor: a scalar, or (k,) one factor per bin of ``bins``.
            bins: (k,) bin indices; None: every bin.
        """
        d = self.datum
        # fancy indexing copies already; every bin: one copy, no index
        p = self.response.p.copy() if bins is None else self.response.p[bins]
        u, y = (d.u_bins, d.y_bins) if bins is None else (d.u_bins[bins], d.y_bins[bins])
        f = np.asarray(factor, dtype=float)
        p[:, :, block.columns] *= f[:, None, None] if f.ndim else f
        resp = PlantResponse(p, self.response.blocks, self.response.nw, self.response.nu,
                             self.response.ny)  # fmt: skip
        lower: np.ndarray = lower_bins(resp, u, y, method=self.method)
        return lower

    def beta(self, block: Block, factor: float) -> float:
        """The window's beta (over the band's bins) with the block's weight times ``factor``."""
        d, bins = self.datum, self.counted
        if bins is None:
            return total_beta(self.bin_lower(block, factor), d.bin_weights)
        if bins.size == 0:
            return 0.0
        return total_beta(self.bin_lower(block, factor, bins), d.bin_weights[bins])

    def beta_joint(self, blocks: Sequence[Block], factors: Sequence[float]) -> float:
        """The window's beta (over the band's bins), each block's weight times its factor."""
        d, bins = self.datum, self.counted
        if bins is not None and bins.size == 0:
            return 0.0
        # fancy indexing copies already; every bin: one copy, no index
        p = self.response.p.copy() if bins is None else self.response.p[bins]
        for block, f in zip(blocks, factors, strict=True):
            p[:, :, block.columns] *= f
        resp = PlantResponse(p, self.response.blocks, self.response.nw, self.response.nu,
                             self.response.ny)  # fmt: skip
        u, y, w = (
            (d.u_bins, d.y_bins, d.bin_weights)
            if bins is None
            else (d.u_bins[bins], d.y_bins[bins], d.bin_weights[bins])
        )
        structure = self._counted_structure
        if structure is not None and all(f != 0.0 and math.isfinite(f) for f in factors):
            # columns scaled by non-zero factors keep P's pattern, which alone decides the
            # route and the structure: lower_bins would find this one again at every call
            return total_beta(solvers.closed_form_bins(resp, u, y, structure)[0], w)
        return total_beta(lower_bins(resp, u, y, method=self.method), w)

    @cached_property
    def _counted_structure(self) -> DecoupledStructure | None:
        """The closed form's structure on the counted bins, where the route takes it."""
        p = self.response.p if self.counted is None else self.response.p[self.counted]
        resp = PlantResponse(p, self.response.blocks, self.response.nw, self.response.nu,
                             self.response.ny)  # fmt: skip
        if not takes_closed_form(resp, self.method):
            return None
        return solvers.decoupled_structure(resp)[0]


def window_scaling(problem: WindowProblem, block: Block, guess: float | None = None) -> float:
    """The smallest factor ``s`` on the block's weight for which the window's beta is <= 1.

    0 when the window needs none of the block (beta <= 1 without it, or below ``S_MIN``);
    ``inf`` when even ``S_MAX`` leaves beta > 1 (the block alone cannot explain the window).
    The root of ``log beta(s)`` is found by ``scipy.optimize.brentq`` in ``log s`` to a
    relative 1e-6 after bracketing by factors of 4 from ``s = 1``; with a ``guess`` (another
    window's factor), first in ``[guess / 1.05, guess * 1.05]`` if that brackets it (beta
    is monotone, so a root there is the root, and fewer evaluations).
    """

    def f(x: float) -> float:
        b = problem.beta(block, math.exp(x))
        return min(math.log(b), 50.0) if b > 0.0 else -50.0

    if guess is not None and S_MIN < guess < S_MAX:
        g_lo, g_hi = math.log(guess / 1.05), math.log(guess * 1.05)
        if f(g_lo) > 0.0 and f(g_hi) <= 0.0:
            return math.exp(float(scipy.optimize.brentq(f, g_lo, g_hi, xtol=1e-6)))
    if problem.beta(block, 0.0) <= 1.0:
        return 0.0
    hi = 1.0
    while f(math.log(hi)) > 0.0:
        hi *= 4.0
        if hi > S_MAX:
            return math.inf
    lo = hi / 4.0
    while f(math.log(lo)) <= 0.0:
        hi, lo = lo, lo / 4.0
        if lo < S_MIN:
            return 0.0
    x = scipy.optimize.brentq(f, math.log(lo), math.log(hi), xtol=1e-6)
    return math.exp(float(x))


def active_bins(problem: WindowProblem, block: Block, floor: float) -> np.ndarray:
    """Indices of the bins at which the block's weight is judged bin by bin.

    A noise block acts at every bin. A perturbation block acts through ``z``, which is
    ``P13 U`` for a structured model: at the excited harmonic bins of the period (input power
    at least ``floor`` times the largest harmonic's, 0 < n < N/2, as the diagnosis); where
    ``z`` depends on ``v`` or ``w`` (a generalised plant with ``P11`` or ``P12``), at every bin.
    Only the bins β counts (the model's band, :attr:`WindowProblem.counted`).
    """
    d = problem.datum
    if block.is_noise or problem.response.coupled:
        return problem.counted_bins()
    return np.intersect1d(excited_bins(d, floor), problem.counted_bins())


@dataclass(frozen=True)
class BinRequirement:
    """What one window demands of a block, bin by bin.

    Attributes:
        bins: (k,) int, the active bins (:func:`active_bins`).
        factor: (k,) float, the smallest factor on the block's stated weight at each bin
            (0: the bin needs none of it; inf: no factor explains the bin within its share).
        share: the share of ``beta^2`` each active bin may use, per unit bin weight (``b^2``).
        fixed: ``sum weight_n w_min(n)^2`` over the other bins β counts, with the block taken
            out there.
    """

    bins: np.ndarray
    factor: np.ndarray
    share: float
    fixed: float


def bin_requirement(problem: WindowProblem, block: Block, floor: float) -> BinRequirement:
    """The smallest factor on the block's weight that each active bin requires.

    The window is valid when ``beta^2 = sum_n c_n w_min(n)^2 <= 1`` (``c_n`` the one-sided bin
    weights, ``n`` over the bins β counts: the model's band). The bins where the block does
    not act keep what they need with the block taken out there (``fixed``: a weight changed
    only at the active bins can then not make them worse); the rest of the budget,
    ``1 - fixed``, is shared equally (per unit bin weight) among the active bins: each must
    reach ``w_min(n) <= b`` with ``b^2 = (1 - fixed) / sum_active c_n``. A weight at least
    ``factor(n)`` times the stated one at every active bin therefore leaves the window valid.
    (The equal share is a choice: it is the allocation a white unknown input would make;
    docs/calibrate.md.)

    ``w_min(n)`` does not grow with the factor, so each bin's factor is found by bisection in
    ``log factor``, all bins at once (one solver call per step: written here because
    ``scipy.optimize`` roots one scalar function at a time).
    """
    d = problem.datum
    bins = active_bins(problem, block, floor)
    others = np.setdiff1d(problem.counted_bins(), bins)
    fixed = (
        total_beta(problem.bin_lower(block, 0.0, others), d.bin_weights[others]) ** 2
        if others.size
        else 0.0
    )
    weights = d.bin_weights[bins]
    if bins.size == 0:
        return BinRequirement(bins, np.zeros(0), 0.0, fixed)
    if not fixed < 1.0:
        return BinRequirement(bins, np.full(bins.size, np.inf), 0.0, fixed)
    share = (1.0 - fixed) / float(np.sum(weights))
    b = math.sqrt(share)
    factor = np.zeros(bins.size)
    need = problem.bin_lower(block, 0.0, bins) > b
    hi = np.ones(bins.size)
    lo = np.zeros(bins.size)
    # bracket: grow the upper end by 4 until the bin is explained (or S_MAX)
    open_ = need.copy()
    while np.any(open_):
        ok = problem.bin_lower(block, hi[open_], bins[open_]) <= b
        idx = np.flatnonzero(open_)
        lo[idx[~ok]] = hi[idx[~ok]]
        hi[idx[~ok]] *= 4.0
        open_[idx[ok]] = False
        open_ &= hi <= S_MAX
    unreachable = need & (hi > S_MAX)
    todo = need & ~unreachable
    lo[todo & (lo == 0.0)] = hi[todo & (lo == 0.0)] / 4.0
    # the lower end must fail: shrink it by 4 until it does (or S_MIN)
    low_open = todo.copy()
    while np.any(low_open):
        idx = np.flatnonzero(low_open)
        ok = problem.bin_lower(block, lo[idx], bins[idx]) <= b
        hi[idx[ok]] = lo[idx[ok]]
        lo[idx[ok]] /= 4.0
        low_open[idx[~ok]] = False
        low_open &= lo >= S_MIN
    idx = np.flatnonzero(todo)
    for _ in range(_BISECTIONS):
        if idx.size == 0:
            break
        mid = np.sqrt(lo[idx] * hi[idx])
        ok = problem.bin_lower(block, mid, bins[idx]) <= b
        hi[idx[ok]] = mid[ok]
        lo[idx[~ok]] = mid[~ok]
    factor[todo] = hi[todo]
    factor[unreachable] = np.inf
    return BinRequirement(bins, factor, share, fixed)


def weight_gain(block: Block, theta: np.ndarray, ts_s: float) -> np.ndarray:
    """(k,) largest singular value of the block's stated weight at ``theta`` (1 without one)."""
    if block.weight is None:
        return np.ones(theta.size)
    resp = lti.bin_response(block.weight, theta, ts_s, block.intersample)
    gain: np.ndarray = np.linalg.norm(resp, ord=2, axis=(1, 2))
    return gain
