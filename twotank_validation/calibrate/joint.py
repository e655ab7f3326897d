"""Several blocks scaled together: a common factor, and the smallest set of per-block factors.

Scaling one block at a time (the others as stated) cannot answer when the error lies on
several channels: each block alone may need an unbounded factor although scaling them
together explains every window. This module scales the chosen blocks *together*.

Monotonicity (what makes the searches one-dimensional). Scaling block ``i``'s weight by
``s_i`` scales the columns of ``P`` it feeds, which is the same as allowing ``||Delta_i|| <=
s_i`` (a perturbation) or the noise ``s_i w_i`` (a noise channel). Any explanation of a bin at
factors ``s`` is therefore an explanation at factors ``s' >= s`` (elementwise) with a
perturbation of norm ``<= 1`` and a noise ``w`` of norm no larger: each window's ``beta`` is
non-increasing in every factor, hence in a common scale ``c`` of all of them. So

* the **common factor** (every chosen weight times the same ``c``) is the root of
  ``max_windows log beta(c) = 0`` (``scipy.optimize.brentq`` in ``log c``);
* the set of factors that explain every window is an *upper set* (if ``s`` is feasible, so is
  every ``s' >= s``). The smallest ``max_i s_i`` over it is the common factor. The **joint
  factors** are the feasible point closest to zero, the smallest ``sum_i s_i^2`` (factors are
  multiples of the stated weights, so they are comparable across blocks). ``sum_i log s_i``
  (a geometric mean) is no use here: as soon as one block can be dropped (``s_i -> 0``) it runs
  to minus infinity whatever the others cost, so it always puts the whole error on as few
  blocks as possible. Every point ``x = log s`` is ``t * 1 + d`` with a direction ``d``
  (``d_n = 0``); along ``1`` feasibility is monotone, so ``t*(d)``, the smallest feasible
  ``t``, is one root (as the common factor, which is ``d = 0``), and ``x(d) = t*(d) + d`` lies
  on the frontier. The objective ``sum_i exp(2 x_i(d))`` is minimised over ``d`` in ``n - 1``
  dimensions by Nelder-Mead (``scipy.optimize.minimize``; derivative-free: ``beta`` comes from
  a per-bin solver and has no usable gradient in the factors), from the best of a few starts.
  Every point tried is feasible and on the frontier, so the answer needs no repair (a
  constrained method such as COBYLA ends slightly outside the feasible set and would still
  need this projection). A last coordinate pass lowers each factor alone to its own root, so
  no single factor of the answer can be lowered (it is Pareto-minimal).

Factors are kept in ``[FLOOR, S_MAX]``; a factor at ``FLOOR`` is reported as 0 (the block is
not needed once the others are scaled). Nelder-Mead finds a local minimum of a frontier that
need not be convex; the starts (the common factor and each block favoured in turn) are the
guard, and the tests compare the answer with a brute-force grid on two blocks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from twotank_validation.calibrate.scaling import S_MAX, Block, WindowProblem

FLOOR = 1e-6
"""Smallest factor of a joint search; a block at it is reported as not needed (0)."""
_LO, _HI = math.log(FLOOR), math.log(S_MAX)
_XTOL = 1e-6
"""Tolerance of the roots in log factor."""
_START_SPREAD = math.log(100.0)
"""How far (in log factor) a start favours one block over the others."""


@dataclass(frozen=True)
class JointScaling:
    """Factors on several blocks' stated weights that together explain every window.

    Attributes:
        names: the blocks, in the order given.
        common: the smallest common factor on all of them for which no window is
            invalidated (inf: none up to ``S_MAX``; 0: the windows need none of them).
        window_common: (n_windows,) the same per window.
        factors: the joint factors (smallest ``sum s_i^2``; 0: the block is not needed; all
            inf when no factors up to ``S_MAX`` explain every window).
        evaluations: beta evaluations of one window the search took.
    """

    names: tuple[str, ...]
    common: float
    window_common: tuple[float, ...]
    factors: tuple[float, ...]
    evaluations: int

    @property
    def objective(self) -> float:
        """The objective ``sum_i s_i^2`` of the joint factors."""
        return float(sum(f * f for f in self.factors))


class _Windows:
    """``max over windows of log beta`` at given log factors (counting evaluations)."""

    def __init__(self, problems: Sequence[WindowProblem], blocks: Sequence[Block]) -> None:
        self.problems = problems
        self.blocks = blocks
        self.evaluations = 0

    def log_beta(self, x: np.ndarray, problems: Sequence[WindowProblem] | None = None) -> float:
        f = np.exp(np.clip(x, _LO, _HI))
        worst = -50.0
        for p in problems if problems is not None else self.problems:
            self.evaluations += 1
            b = p.beta_joint(self.blocks, f.tolist())
            worst = max(worst, min(math.log(b), 50.0) if b > 0.0 else -50.0)
            if worst > 0.0:  # infeasible already: the other windows cannot change that
                break
        return worst


def _root(g: Callable[[float], float], lo: float, hi: float) -> float:
    """Smallest ``t`` in ``[lo, hi]`` with ``g(t) <= 0`` for non-increasing ``g``.

    ``lo`` when ``g(lo) <= 0``; inf when ``g(hi) > 0``; else ``brentq`` to 1e-6 in ``t``
    (``g`` is continuous: beta is continuous in the factors), moved up by that tolerance
    until ``g(t) <= 0`` (brentq's answer may lie just on the infeasible side).
    """
    if g(lo) <= 0.0:
        return lo
    if g(hi) > 0.0:
        return math.inf
    t = float(scipy.optimize.brentq(g, lo, hi, xtol=_XTOL))
    while t < hi and g(t) > 0.0:
        t = min(t + _XTOL, hi)
    return t


def common_scaling(
    problems: Sequence[WindowProblem], blocks: Sequence[Block]
) -> tuple[float, tuple[float, ...]]:
    """The smallest common factor on every chosen block for which no window is invalidated.

    Returns:
        The factor over all windows (the largest per window) and the per-window factors;
        0 where a window needs none of them (valid at ``FLOOR``), inf where ``S_MAX`` is not
        enough.
    """
    ev = _Windows(problems, blocks)
    ones = np.ones(len(blocks))
    per = []
    for p in problems:

        def g(t: float, p: WindowProblem = p) -> float:
            return ev.log_beta(t * ones, [p])

        t = _root(g, _LO, _HI)
        per.append(0.0 if t <= _LO else math.exp(t))
    return (max(per) if per else 0.0), tuple(per)


def joint_scaling(
    problems: Sequence[WindowProblem], blocks: Sequence[Block], *, xatol: float = 1e-3
) -> JointScaling:
    """The common factor and the joint per-block factors (module docstring) on the windows.

    Args:
        problems: the windows (each one's plant evaluated once).
        blocks: the blocks scaled together (at least one).
        xatol: the Nelder-Mead tolerance in log factor (1e-3: 0.1 %).
    """
    names = tuple(b.name for b in blocks)
    n = len(blocks)
    common, per_window = common_scaling(problems, blocks)
    ev = _Windows(problems, blocks)
    if math.isinf(common):
        return JointScaling(names, common, per_window, (math.inf,) * n, ev.evaluations)
    if common == 0.0:
        return JointScaling(names, common, per_window, (0.0,) * n, ev.evaluations)

    def point(d: np.ndarray) -> np.ndarray:
        full = np.append(np.clip(d, _LO - _HI, _HI - _LO), 0.0)
        t = _root(lambda t: ev.log_beta(t + full), _LO - float(full.max()), _HI - float(full.min()))
        return np.clip(t + full, _LO, _HI)

    def objective(d: np.ndarray) -> float:
        return float(np.sum(np.exp(2.0 * point(d))))

    x: np.ndarray
    if n == 1:
        x = np.array([math.log(common)])
    else:
        starts = [np.zeros(n - 1)]
        for i in range(n):  # favour block i: the others lowered by _START_SPREAD
            d = np.full(n - 1, -_START_SPREAD if i == n - 1 else 0.0)
            if i < n - 1:
                d[i] = _START_SPREAD
            starts.append(d)
        best = min(starts, key=objective)
        simplex = np.vstack([best, best + 0.5 * np.eye(n - 1)])
        res = scipy.optimize.minimize(
            objective,
            best,
            method="Nelder-Mead",
            # fatol relative to the common factor's objective (factors may be far from 1)
            options={"xatol": xatol, "fatol": xatol * n * common**2, "initial_simplex": simplex},
        )
        x = point(np.asarray(res.x, dtype=float))
        # coordinate pass: lower each factor alone to its own root (Pareto-minimal)
        for i in range(n):

            def g(t: float, i: int = i) -> float:
                y = x.copy()
                y[i] = t
                return ev.log_beta(y)

            x[i] = min(x[i], _root(g, _LO, float(x[i])))
    factors = tuple(0.0 if xi <= _LO + 1e-9 else float(math.exp(xi)) for xi in x)
    return JointScaling(names, common, per_window, factors, ev.evaluations)


__all__ = ["FLOOR", "JointScaling", "common_scaling", "joint_scaling"]
