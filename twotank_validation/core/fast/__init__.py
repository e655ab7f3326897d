"""The fast path: the per-bin problem solved by dual ascent over small matrices.

Modules, each importing only those listed before it:

* ``rules``: the rules and tolerances both implementations share (no numba);
* ``linalg``: batched small-matrix algebra, the bin axis last (Cholesky, pivoted
  Gram-Schmidt, Cramer's rule, least-norm solutions, inverses);
* ``forms``: a window's per-bin classification (forced blocks) and homogenised forms;
* ``dual``: the batched dual ascent (secular and projected Newton steps), on the forms or
  in ``v`` itself;
* ``witness``: the exactly feasible rank-one witness and the Lagrangian consistency check;
* ``kernel``: the compiled (numba) per-bin kernel for structured models, loaded on first use;
* ``dispatch``: the entry points -- coverage, the bins' routes (compiled kernel, batched
  dual, per-bin cvxpy fallback), warm-up.

Names with a leading underscore are internal to this package (shared among its modules);
the rest of the code uses the names exported here.
"""

from twotank_validation.core.fast.dispatch import (
    MAX_BLOCKS,
    MAX_UNKNOWNS,
    FastSolutions,
    FastStats,
    coverage,
    solve_fast,
    warm_up,
)

__all__ = [
    "MAX_BLOCKS",
    "MAX_UNKNOWNS",
    "FastSolutions",
    "FastStats",
    "coverage",
    "solve_fast",
    "warm_up",
]
