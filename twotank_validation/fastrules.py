"""The rules the fast path's two implementations share.

No numba here: importing the batched numpy path, or anything that validates, must not load
the compiler. Used by :mod:`twotank_validation.fast` (batched numpy) and
:mod:`twotank_validation.fastkernel` (compiled per-bin kernel); see docs/theory.md, Sec. 6.
"""

from __future__ import annotations

from twotank_validation.model import BlockStructure

TINY = 1e-300
PIVOT_RTOL = 1e-13
"""A Cholesky pivot below this times its scale counts as singular."""
NOISE_COND = 1e2
"""Noise elimination through ``P22^-1`` only below this Frobenius condition number."""
NOISE_GAIN = 1e3
"""... and only where ``||P22^-1 P21||_F`` stays below this."""
NEGLIGIBLE_Z = 1e-10
"""A block input below this times the least-norm unknowns is negligible (forced)."""
UNEXCITED = 1e-12
"""A block input below this times ``||P13_i||_F u_scale`` is unexcited (forced)."""
GRAM_COND = 1e8
"""Least-norm size by the output Gram matrix's inverse only below this condition number."""
PHI_RUNAWAY = 1e40
FLAT_ITERATIONS = 4
BACKTRACKS = 16
STARTS_NATURAL = (1.0, 1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e2)
STARTS_SCALED = (1.0, 0.1, 10.0, 0.01, 100.0, 1e-3)


def kernel_applies(blocks: BlockStructure, nw: int, ny: int, *, coupled: bool) -> bool:
    """Whether the compiled kernel takes a window: ``z = P13 U`` at every bin, ``P22`` square."""
    return not coupled and nw == ny <= 3 and 1 <= blocks.n_blocks <= 3 and blocks.nv >= 1
