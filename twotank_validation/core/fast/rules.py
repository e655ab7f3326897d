"""The rules the fast path's two implementations share.

No numba here: importing the batched numpy path, or anything that validates, must not load
the compiler. Used by the batched numpy path (``linalg``, ``forms``, ``dual``, ``witness``,
``dispatch`` of :mod:`twotank_validation.core.fast`) and :mod:`twotank_validation.core.fast.kernel`
(compiled per-bin kernel); see docs/theory.md, Sec. 6.
"""

from __future__ import annotations

from twotank_validation.core.model import BlockStructure

TINY = 1e-300
PIVOT_RTOL = 1e-13
"""A Cholesky pivot of ``H_tt`` below this times its scale counts as singular (as
``solvers.lagrangian_point``)."""
NOISE_COND = 1e2
"""Noise elimination (``w = P22^-1 (...)``) only below this Frobenius condition number of
``P22``: it squares into the objective's forms, whose Schur complement then cancels that
many digits more."""
NOISE_GAIN = 1e3
"""... and only where ``||P22^-1 P21 D||_F`` (``D``: balancing of v) stays below this."""
NEGLIGIBLE_Z = 1e-10
"""A block input below this times the least-norm unknowns is negligible (forced; as
``solvers._NEGLIGIBLE_Z``)."""
UNEXCITED = 1e-12
"""A block input below this times ``||P13_i||_F u_scale`` is unexcited (forced)."""
GRAM_COND = 1e8
"""Least-norm size by the output Gram matrix's inverse only below this condition number."""
PHI_RUNAWAY = 1e40
"""Dual value (in the objective's unit) beyond which a bin counts as unbounded (deferred)."""
FLAT_ITERATIONS = 4
"""Iterations in a row without ascent after which a bin stops."""
BACKTRACKS = 16
"""Step lengths tried per iteration before a bin counts as stalled."""
STARTS_NATURAL = (1.0, 1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e2)
"""Starting multipliers (objective's units) tried until ``H_tt`` is positive definite."""
STARTS_SCALED = (1.0, 0.1, 10.0, 0.01, 100.0, 1e-3)
"""... then these, uniform in the normalised units (see ``dual._starts``)."""


def kernel_applies(blocks: BlockStructure, nw: int, ny: int, *, coupled: bool) -> bool:
    """Whether the compiled kernel takes a window: ``z = P13 U`` at every bin, ``P22`` square."""
    return not coupled and nw == ny <= 3 and 1 <= blocks.n_blocks <= 3 and blocks.nv >= 1
