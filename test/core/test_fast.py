"""The batched fast path against independent references: the cvxpy SDP path and the closed form.

Every check compares with a reference computed in the test (the per-bin cvxpy path, the exact
closed form, or an explicit closed-loop evaluation of the witness), never a stored number.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twotank_validation import experiment
from twotank_validation.core import fast, solvers
from twotank_validation.core.datum import Datum, make_datum
from twotank_validation.core.model import BlockStructure, PlantResponse, load_model

RTOL = 1e-6  # agreement asked of the fast path with the cvxpy reference
# Relative agreement is meaningless at a zero minimum: below FLOOR times the bin's data scale
# (bin_scale) values are compared absolutely, to RTOL * FLOOR = 1e-9 of that scale.
FLOOR = 1e-3


def cplx(rng: np.random.Generator, *shape: int) -> np.ndarray:
    return rng.normal(size=shape) + 1j * rng.normal(size=shape)


def random_window(
    seed: int,
    shapes: tuple[tuple[int, int], ...],
    nw: int,
    ny: int,
    nu: int,
    *,
    coupled: bool,
    n_bins: int = 8,
) -> tuple[PlantResponse, np.ndarray, np.ndarray]:
    """A window of random bins with the awkward cases planted in fixed bins.

    ``coupled``: z depends on v and w (P11 with norm 0.5, P12 non-zero); otherwise z = P13 U
    (structured models). Bin 1 has no excitation (U = 0), bin 2 an ill-conditioned noise
    weight (one P22 column 1e-5 of the others), bin 3 is explained by the model alone
    (Y = P23 U: minimum 0), bin 4 a weak excitation (U scaled by 1e-7), bin 5 a block input
    with no drive (P13 = 0, so z = 0 unless P11 or P12 move it), bin 6 a large error.
    """
    rng = np.random.default_rng(seed)
    blocks = BlockStructure(shapes)
    nz, nv = blocks.nz, blocks.nv
    p = cplx(rng, n_bins, nz + ny, nv + nw + nu)
    if coupled:
        p11 = p[:, :nz, :nv]
        p[:, :nz, :nv] = 0.5 * p11 / np.linalg.norm(p11, 2, axis=(1, 2))[:, None, None]
    else:
        p[:, :nz, : nv + nw] = 0.0
    p[:, nz:, nv : nv + nw] *= 0.2  # noise weights smaller than the rest, as in practice
    u = cplx(rng, n_bins, nu)
    y = cplx(rng, n_bins, ny)
    u[1] = 0.0
    p[2, nz:, nv] *= 1e-5
    y[3] = p[3, nz:, nv + nw :] @ u[3]
    u[4] *= 1e-7
    p[5, :nz, nv + nw :] = 0.0
    y[6] *= 30.0
    return PlantResponse(p, blocks, nw, nu, ny), u, y


def unperturbed(resp: PlantResponse, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n_bins,) ||w|| of the least-norm w with Delta = 0."""
    rhs = y - np.einsum("kij,kj->ki", resp.p23, u)
    w = np.einsum("kij,kj->ki", np.linalg.pinv(resp.p22), rhs)
    return np.linalg.norm(w, axis=1)


def bin_scale(resp: PlantResponse, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n_bins,) the size of each bin's data in units of w: ``||P22^+|| (||Y|| + ||P23 U||)``."""
    gain = np.linalg.norm(np.linalg.pinv(resp.p22), 2, axis=(1, 2))
    nominal = np.linalg.norm(np.einsum("kij,kj->ki", resp.p23, u), axis=1)
    return gain * (np.linalg.norm(y, axis=1) + nominal)


def closed_loop_w_norm(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, delta: tuple[np.ndarray, ...]
) -> np.ndarray:
    """Independent check of a witness: close the loop with Delta and solve for w by lstsq."""
    out = np.empty(u.shape[0])
    blocks = resp.blocks
    for n in range(u.shape[0]):
        dm = np.zeros((blocks.nv, blocks.nz), dtype=complex)
        for d, vs, zs in zip(delta, blocks.v_slices, blocks.z_slices, strict=True):
            dm[vs, zs] = d[n]
        p11, p12, p13 = resp.p11[n], resp.p12[n], resp.p13[n]
        p21, p22, p23 = resp.p21[n], resp.p22[n], resp.p23[n]
        closed = dm @ np.linalg.inv(np.eye(blocks.nz) - p11 @ dm)
        lhs = p22 + p21 @ closed @ p12
        rhs = y[n] - p23 @ u[n] - p21 @ closed @ p13 @ u[n]
        w = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        ok = np.linalg.norm(lhs @ w - rhs) <= 1e-7 * (np.linalg.norm(rhs) + np.linalg.norm(y[n]))
        out[n] = np.linalg.norm(w) if ok else np.inf
    return out


def assert_close(got: np.ndarray, ref: np.ndarray, floor: np.ndarray, what: str) -> None:
    """``|got - ref| <= RTOL max(|ref|, floor)`` per bin, ``inf`` where the reference is."""
    inf = np.isinf(ref)
    np.testing.assert_array_equal(np.isinf(got), inf, err_msg=f"{what}: infeasible bins differ")
    err = np.abs(got[~inf] - ref[~inf])
    tol = RTOL * np.maximum(np.abs(ref[~inf]), floor[~inf])
    bad = np.flatnonzero(err > tol)
    assert bad.size == 0, f"{what}: bins {bad} differ: {got[~inf][bad]} vs {ref[~inf][bad]}"


def feasible_values(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, *sols: solvers.BinSolutions
) -> np.ndarray:
    """(n_bins,) the smallest ||w|| among points checked feasible by closing the loop here:
    Delta = 0 and the witnesses of ``sols`` (``inf`` where none explains the bin)."""
    zero = tuple(np.zeros((u.shape[0], r, c), dtype=complex) for r, c in resp.blocks.shapes)
    values = [closed_loop_w_norm(resp, u, y, zero)]
    values += [closed_loop_w_norm(resp, u, y, s.delta) for s in sols]
    return np.min(values, axis=0)


def compare_with_reference(
    resp: PlantResponse,
    u: np.ndarray,
    y: np.ndarray,
    res: fast.FastSolutions,
    ref: solvers.BinSolutions,
) -> np.ndarray:
    """The fast path against the cvxpy path and against independently checked feasible points.

    * Bins the batch left to the fallback carry the reference's answer.
    * Every other bin is sound: its lower bound never exceeds a feasible value, and it finds
      a witness wherever one is known.
    * Where the reference is trustworthy -- it certifies its bound, and that bound does not
      exceed a feasible value (its certificate's round-off can be amplified on a bin the
      nominal explains to 1e-16, and Clarabel can call an ill-conditioned bin infeasible) --
      the lower bounds agree to ``RTOL``, and the fast witness is never worse than the
      reference's nor below its bound (where the reference's bounds meet, they pin it).

    Returns:
        (n_bins,) bool, the bins compared with the reference.
    """
    sol = res.solutions
    floor = FLOOR * bin_scale(resp, u, y)
    back = res.fell_back
    assert_close(sol.lower[back], ref.lower[back], floor[back], "fallback lower")
    assert_close(sol.upper[back], ref.upper[back], floor[back], "fallback upper")
    own = ~back
    feas = feasible_values(resp, u, y, sol, ref)
    with np.errstate(invalid="ignore"):
        tol = RTOL * np.maximum(np.where(np.isfinite(feas), feas, 0.0), floor)
    assert np.all(sol.lower[own] <= feas[own] + tol[own]), (sol.lower, feas)
    assert not np.any(np.isinf(sol.upper[own]) & np.isfinite(feas[own])), (sol.upper, feas)
    trust = own & ref.certified & (ref.lower <= feas + tol)
    trust &= np.isfinite(ref.lower) | np.isinf(feas)
    assert_close(sol.lower[trust], ref.lower[trust], floor[trust], "lower")
    with np.errstate(invalid="ignore"):
        ref_tol = RTOL * np.maximum(np.where(np.isfinite(ref.upper), ref.upper, 0.0), floor)
    fin = own & np.isfinite(ref.upper)
    assert np.all(sol.upper[fin] <= ref.upper[fin] + ref_tol[fin]), (sol.upper, ref.upper)
    fin = trust & np.isfinite(ref.lower)
    assert np.all(sol.upper[fin] >= ref.lower[fin] - tol[fin]), (sol.upper, ref.lower)
    return trust


def check_solution(
    resp: PlantResponse, u: np.ndarray, y: np.ndarray, sol: solvers.BinSolutions
) -> None:
    """Bounds ordered; the witness is feasible and reproduces its own upper bound."""
    assert np.all(sol.lower <= sol.upper + 1e-12 * (1.0 + np.abs(sol.upper)))
    for d in sol.delta:
        assert np.all(np.linalg.norm(d, 2, axis=(1, 2)) <= 1.0 + 1e-9)
    fin = np.isfinite(sol.upper)
    ref = closed_loop_w_norm(resp, u, y, sol.delta)
    scale = unperturbed(resp, u, y)
    np.testing.assert_allclose(sol.upper[fin], ref[fin], rtol=1e-8, atol=1e-12 * scale.max())
    np.testing.assert_allclose(np.linalg.norm(sol.w, axis=1)[fin], sol.upper[fin], rtol=1e-9)


# ------------------------------------------------------------------ tank models


@cache
def tank_datum() -> Datum:
    cfg = experiment.ExperimentConfig()
    _, u, y, _ = experiment.simulate_datum(cfg)
    return make_datum(u, y, ts_s=cfg.excitation.ts_s, period_samples=cfg.excitation.period_samples)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("name", ["A", "B"])
def test_tank_models_match_closed_form_on_every_bin(name: str, compiled: bool) -> None:
    """The general fast path on the tank models equals the exact closed form (2049 bins),
    through the compiled kernel (every bin) and through the batched numpy code alone."""
    datum = tank_datum()
    resp = load_model(name).response(datum.theta, datum.ts_s)
    structure, _ = solvers.decoupled_structure(resp)
    assert structure is not None
    cf = solvers.solve_closed_form(resp, datum.u_bins, datum.y_bins, structure)
    res = fast.solve_fast(resp, datum.u_bins, datum.y_bins, compiled=compiled)
    sol = res.solutions
    assert sol.method == "fast"
    assert res.stats.n_fallback == 0
    assert res.stats.n_direct + res.stats.n_dual == datum.theta.size
    assert res.stats.n_compiled == (datum.theta.size if compiled else 0)
    assert sol.certified.all()
    # round-off bins (the de-biased DC bin) are judged against the window's scale
    floor = np.full(cf.lower.shape, 1e-6 * float(np.max(cf.lower)))
    assert_close(sol.lower, cf.lower, floor, "lower")
    assert_close(sol.upper, cf.lower, floor, "upper")
    beta_fast = np.sqrt(np.sum(datum.bin_weights * sol.lower**2))
    beta_cf = np.sqrt(np.sum(datum.bin_weights * cf.lower**2))
    assert beta_fast == pytest.approx(beta_cf, rel=1e-9)


def test_kernel_threads_share_the_bins_without_changing_a_bit() -> None:
    """The window cut among 1, 2 or 3 threads (chunks of >= 256 bins) gives the same bits."""
    datum = tank_datum()
    resp = load_model("B").response(datum.theta, datum.ts_s)
    runs = [fast.solve_fast(resp, datum.u_bins, datum.y_bins, threads=t) for t in (1, 2, 3)]
    for res in runs[1:]:
        for what in ("lower", "upper", "w", "v", "z", "certified"):
            np.testing.assert_array_equal(
                getattr(res.solutions, what), getattr(runs[0].solutions, what), err_msg=what
            )
        for a, b in zip(res.solutions.delta, runs[0].solutions.delta, strict=True):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(res.error, runs[0].error)
        assert res.stats == runs[0].stats


def _kernel_outputs(out: object) -> dict[str, np.ndarray]:
    """The kernel's outputs; the bounds of a deferred bin are not written (left to numpy)."""
    from twotank_validation.core.fast.kernel import DONE  # noqa: PLC0415

    names = ("w", "v", "z", "dmat", "r", "status", "kind")
    got = {name: getattr(out, name) for name in names}
    done = got["status"] == DONE
    for name in ("lower", "upper"):
        got[name] = np.where(done, getattr(out, name), np.nan)
    return got


def test_shipped_models_get_the_kernel_compiled_for_their_dimensions() -> None:
    """Both tank models' dimensions are in fastkernel.SIZED, so the default call runs the
    sized kernel, and it says so in the statistics."""
    from twotank_validation.core.fast import kernel as fastkernel  # noqa: PLC0415

    datum = tank_datum()
    for name in ("A", "B"):
        resp = load_model(name).response(datum.theta, datum.ts_s)
        blocks = resp.blocks
        dims = (blocks.nz, blocks.nv, resp.nw, resp.nu, blocks.n_blocks)
        assert dims in fastkernel.SIZED, (name, dims)
        assert fast.solve_fast(resp, datum.u_bins, datum.y_bins).stats.kernel_sized
    resp, u, y = random_window(3, ((1, 1),), 2, 2, 1, coupled=False)
    stats = fast.solve_fast(resp, u, y).stats
    assert stats.n_compiled > 0
    assert not stats.kernel_sized


def assert_sized_equals_general(resp: PlantResponse, u: np.ndarray, y: np.ndarray) -> None:
    """The kernel compiled for ``resp``'s dimensions and the general one (dimensions read at
    run time) on one window: every output equal to the bit (bounds where answered)."""
    from twotank_validation.core.fast import kernel as fastkernel  # noqa: PLC0415

    kw = {
        "u_scale": float(np.max(np.linalg.norm(u, axis=1))),
        "blocks": resp.blocks,
        "nw": resp.nw,
        "max_iter": 60,
        "threads": 1,
    }
    sized = fastkernel.solve_window(resp.p, u, y, sized=True, **kw)
    general = fastkernel.solve_window(resp.p, u, y, sized=False, **kw)
    want = _kernel_outputs(general)
    for what, got in _kernel_outputs(sized).items():
        np.testing.assert_array_equal(got, want[what], err_msg=what)
    assert sized.iterations == general.iterations
    assert sized.sized
    assert not general.sized


@pytest.mark.parametrize("name", ["A", "B"])
def test_sized_kernel_gives_the_general_kernels_bits_on_the_tank_window(name: str) -> None:
    """The same arithmetic in both kernels, so the same bits on the tank window."""
    datum = tank_datum()
    resp = load_model(name).response(datum.theta, datum.ts_s)
    assert_sized_equals_general(resp, datum.u_bins, datum.y_bins)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1.0, 1e-6, 1e6]))
def test_sized_kernel_gives_the_general_kernels_bits_on_random_bins(
    seed: int, scale: float
) -> None:
    """Random structured windows of the tank's dimensions (awkward bins planted): the sized
    and the general kernel agree to the bit, deferred bins included."""
    resp, u, y = random_window(seed, ((1, 1), (1, 1)), 2, 2, 2, coupled=False, n_bins=40)
    assert_sized_equals_general(resp, u * scale, y * scale)


def test_kernel_settings_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    """TWOTANK_FAST_SIZED adds structures to the shipped one, TWOTANK_FAST_THREADS sets the
    threads; a malformed value is an error naming the variable."""
    from twotank_validation.core.fast import kernel as fastkernel  # noqa: PLC0415

    monkeypatch.setenv("TWOTANK_FAST_SIZED", "1,1,2,1,1; 3,3,2,2,2")
    assert fastkernel._sized_default() == {(2, 2, 2, 2, 2), (1, 1, 2, 1, 1), (3, 3, 2, 2, 2)}
    monkeypatch.setenv("TWOTANK_FAST_SIZED", "1,1,2")
    with pytest.raises(ValueError, match="TWOTANK_FAST_SIZED"):
        fastkernel._sized_default()
    monkeypatch.setenv("TWOTANK_FAST_THREADS", "3")
    assert fastkernel._default_threads() == 3
    monkeypatch.setenv("TWOTANK_FAST_THREADS", "two")
    with pytest.raises(ValueError, match="TWOTANK_FAST_THREADS"):
        fastkernel._default_threads()


def test_validating_does_not_load_numba_until_the_kernel_runs() -> None:
    """The node and replay (closed form) never pay numba's import and memory."""
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    code = (
        "import sys\n"
        "from twotank_validation.core import validate\n"
        "from twotank_validation.core import fast\n"
        "from twotank_validation.online import validator\n"
        "from twotank_validation.ros import validator_node\n"
        "print('numba' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_kernel_threads_work_in_a_forked_child() -> None:
    """A child forked after the parent used the thread pool starts one of its own (no hang)."""
    import multiprocessing as mp  # noqa: PLC0415

    datum = tank_datum()
    resp = load_model("B").response(datum.theta, datum.ts_s)
    want = fast.solve_fast(resp, datum.u_bins, datum.y_bins, threads=2).solutions.lower
    with mp.get_context("fork").Pool(1) as pool:
        got = pool.apply_async(_child_lower, (resp, datum.u_bins, datum.y_bins)).get(timeout=120)
    np.testing.assert_array_equal(got, want)


def _child_lower(resp: PlantResponse, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    return fast.solve_fast(resp, u, y, threads=2).solutions.lower


@pytest.mark.parametrize("name", ["A", "B"])
def test_tank_models_match_cvxpy_on_a_spread_of_bins(name: str) -> None:
    """Against the cvxpy path on 40 bins: the strongest, the weakest excited, unexcited ones."""
    datum = tank_datum()
    resp = load_model(name).response(datum.theta, datum.ts_s)
    u_norm = np.linalg.norm(datum.u_bins, axis=1)
    order = np.argsort(u_norm)
    excited = order[u_norm[order] > 0]
    bins = np.unique(np.concatenate([excited[-15:], excited[:15], order[:10]]))
    sub = PlantResponse(resp.p[bins], resp.blocks, resp.nw, resp.nu, resp.ny)
    u, y = datum.u_bins[bins], datum.y_bins[bins]
    u_scale = float(u_norm.max())
    ref = solvers.solve_sdp(sub, u, y, u_scale=u_scale)
    sol = fast.solve_fast(resp, datum.u_bins, datum.y_bins).solutions
    floor = FLOOR * bin_scale(sub, u, y)
    assert_close(sol.lower[bins], ref.lower, floor, "lower")
    assert_close(sol.upper[bins], ref.upper, floor, "upper")


# ------------------------------------------------------------------ random problems


@settings(max_examples=20)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_blocks=st.integers(1, 2),
    full=st.booleans(),
    coupled=st.booleans(),
    nw=st.integers(1, 3),
    nu=st.integers(1, 2),
    compiled=st.booleans(),
)
def test_random_one_or_two_blocks_match_cvxpy(
    seed: int, n_blocks: int, full: bool, coupled: bool, nw: int, nu: int, compiled: bool
) -> None:
    """One or two blocks (the dual is exact): lower and upper bounds equal the cvxpy path's
    (with and without the compiled kernel, which takes the uncoupled windows with nw = ny)."""
    shapes = ((2, 1), (1, 2))[:n_blocks] if full else ((1, 1),) * n_blocks
    ny = min(nw, 2)
    resp, u, y = random_window(seed, shapes, nw, ny, nu, coupled=coupled)
    ref = solvers.solve_sdp(resp, u, y)
    res = fast.solve_fast(resp, u, y, compiled=compiled)
    assert (res.stats.n_compiled > 0) == (compiled and not coupled and nw == ny)
    compare_with_reference(resp, u, y, res, ref)
    check_solution(resp, u, y, res.solutions)
    # Fallback bins carry the reference's answer (checked above). They are mostly the hard
    # case (a zero minimum with many minimisers: H_tt singular at the dual optimum); a few
    # planted awkward bins of 8 may join them, never most of the window.
    assert res.stats.n_fallback == int(np.sum(res.fell_back)) <= 3, res.stats


@settings(max_examples=10)
@given(seed=st.integers(0, 2**32 - 1), coupled=st.booleans(), compiled=st.booleans())
def test_random_three_blocks_lower_bound_matches_cvxpy(
    seed: int, coupled: bool, compiled: bool
) -> None:
    """Three blocks, one non-square: the certified lower bound equals the SDP relaxation's;
    the upper bound is a feasible witness; the gap is reported, not hidden."""
    shapes = ((1, 1), (2, 1), (1, 1))
    resp, u, y = random_window(seed, shapes, 2, 2, 2, coupled=coupled)
    ref = solvers.solve_sdp(resp, u, y)
    res = fast.solve_fast(resp, u, y, compiled=compiled)
    compare_with_reference(resp, u, y, res, ref)
    check_solution(resp, u, y, res.solutions)


@settings(max_examples=12, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    shapes=st.sampled_from(
        [((1, 1),), ((2, 1),), ((1, 1), (1, 1)), ((1, 2), (2, 1)), ((1, 1), (2, 1), (1, 1))]
    ),
    ny=st.integers(1, 3),
    scale=st.sampled_from([1.0, 1e-6, 1e6]),
)
def test_compiled_kernel_agrees_with_the_batched_numpy_path(
    seed: int, shapes: tuple[tuple[int, int], ...], ny: int, scale: float
) -> None:
    """Two implementations of the same rules, bin by bin, on 40 random structured bins (the
    awkward ones planted) at three data scales: the kernel answers most bins, defers the
    ill-conditioned noise weight (bin 2) to the numpy code, and where both answer the bounds
    agree to 1e-9 and the kernel's witness closes the loop."""
    resp, u, y = random_window(seed, shapes, ny, ny, 2, coupled=False, n_bins=40)
    u, y = u * scale, y * scale
    res = fast.solve_fast(resp, u, y)
    ref = fast.solve_fast(resp, u, y, compiled=False)
    assert res.stats.n_compiled >= 30, res.stats
    assert res.stats.n_compiled < 40  # bin 2: P22 ill conditioned, deferred
    assert res.stats.n_bins == res.stats.n_direct + res.stats.n_dual + res.stats.n_fallback
    check_solution(resp, u, y, res.solutions)
    floor = 1e-3 * bin_scale(resp, u, y)
    both = ~res.fell_back & ~ref.fell_back
    for what in ("lower", "upper"):
        got, want = getattr(res.solutions, what), getattr(ref.solutions, what)
        err = np.abs(got[both] - want[both])
        assert np.all(err <= 1e-9 * np.maximum(np.abs(want[both]), floor[both])), what
    np.testing.assert_allclose(res.error, ref.error, rtol=0, atol=1e-14 * np.abs(y).max())


def test_unexcited_window_is_least_norm_noise() -> None:
    """U = 0 everywhere (z = 0, structured model): every bin is the least-norm w, no dual."""
    resp, _, y = random_window(7, ((1, 1), (1, 1)), 2, 2, 2, coupled=False)
    u = np.zeros((y.shape[0], 2), dtype=complex)
    res = fast.solve_fast(resp, u, y)
    assert res.stats.n_direct == y.shape[0]
    expected = unperturbed(resp, u, y)
    np.testing.assert_allclose(res.solutions.lower, expected, rtol=1e-12)
    np.testing.assert_allclose(res.solutions.upper, expected, rtol=1e-12)
    ref = solvers.solve_sdp(resp, u, y)
    np.testing.assert_allclose(res.solutions.lower, ref.lower, rtol=RTOL)


def test_fallback_bins_are_the_cvxpy_answer() -> None:
    """With no Newton iteration allowed, every dual bin falls back: the cvxpy answer, counted."""
    resp, u, y = random_window(11, ((1, 1), (1, 1)), 2, 2, 2, coupled=True)
    res = fast.solve_fast(resp, u, y, max_iter=0)
    ref = solvers.solve_sdp(resp, u, y)
    assert res.stats.n_fallback == y.shape[0] - res.stats.n_direct - res.stats.n_dual
    assert res.stats.n_fallback >= 5
    assert res.fell_back.sum() == res.stats.n_fallback
    compare_with_reference(resp, u, y, res, ref)


def test_output_without_noise_is_infeasible_when_unexplained() -> None:
    """An output with neither noise nor reach: inf, as the cvxpy path says."""
    blocks = BlockStructure(((1, 1),))
    p = np.zeros((2, 2, 3), dtype=complex)
    p[:, 0, 2] = 1.0
    p[:, 1, 0] = 0.1
    p[:, 1, 2] = 1.0
    resp = PlantResponse(p, blocks, 1, 1, 1)  # noise weight zero
    u = np.array([[1.0 + 0j], [1.0 + 0j]])
    y = np.array([[2.0 + 0j], [1.05 + 0j]])
    res = fast.solve_fast(resp, u, y)
    ref = solvers.solve_sdp(resp, u, y)
    assert np.isinf(res.solutions.lower[0])
    assert res.stats.n_infeasible >= 1
    np.testing.assert_array_equal(np.isinf(res.solutions.lower), np.isinf(ref.lower))
    assert res.solutions.lower[1] == pytest.approx(ref.lower[1], abs=1e-9)


def test_coverage() -> None:
    assert fast.coverage(BlockStructure(((1, 1),) * 3), 2)[0]
    covered, why = fast.coverage(BlockStructure(((1, 1),) * 4), 2)
    assert not covered
    assert "4 blocks" in why
    resp, u, y = random_window(0, ((1, 1),) * 4, 2, 2, 2, coupled=False)
    with pytest.raises(ValueError, match="does not cover"):
        fast.solve_fast(resp, u, y)


def test_warm_up_loads_the_kernel_only_for_structures_the_fast_path_takes() -> None:
    """warm_up on a structure the kernel and the fast path take says so; on one the kernel
    would take but the fast path does not cover (too many unknowns per bin) it declines,
    without raising: the monitor calls it at start-up for any model."""
    resp, _, _ = random_window(3, ((1, 1), (1, 1)), 2, 2, 2, coupled=False)
    assert fast.warm_up(resp)
    big = BlockStructure(((8, 1), (8, 1)))
    assert not fast.coverage(big, 2)[0]
    p = np.zeros((2, big.nz + 2, big.nv + 2 + 1), dtype=complex)
    p[:, : big.nz, -1] = 1.0
    p[:, big.nz :, :] = 1.0
    assert not fast.warm_up(PlantResponse(p, big, 2, 1, 2))
    coupled, _, _ = random_window(3, ((1, 1),), 2, 2, 2, coupled=True)
    assert not fast.warm_up(coupled)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("factor", [0.0, 1e-200])
def test_a_block_with_zero_or_tiny_weight_stays_on_the_fast_path(
    compiled: bool, factor: float
) -> None:
    """A full 3x3 block whose weight is 0 (or 1e-200): its v enters nothing, the bins are the
    least-norm w of the nominal (closed form here), none falls back to the per-bin SDP; with
    a second, live block, it meets the cvxpy reference (with the block's columns 0: cvxpy
    itself is unreliable on entries of 1e-200) as every fast answer must."""
    resp, u, y = random_window(23, ((3, 3),), 3, 3, 1, coupled=False, n_bins=12)
    p = resp.p.copy()
    p[:, :, :3] *= factor
    dead = PlantResponse(p, resp.blocks, 3, 1, 3)
    res = fast.solve_fast(dead, u, y, compiled=compiled)
    assert res.stats.n_fallback == 0
    ref0 = unperturbed(dead, u, y)
    assert np.all(np.abs(res.solutions.lower - ref0) <= 1e-9 * np.maximum(ref0, 1e-3))
    resp2, u2, y2 = random_window(29, ((3, 3), (1, 1)), 3, 3, 1, coupled=False)
    p2 = resp2.p.copy()
    p2[:, :, :3] *= factor
    two = PlantResponse(p2, resp2.blocks, 3, 1, 3)
    res2 = fast.solve_fast(two, u2, y2, compiled=compiled)
    assert res2.stats.n_fallback == 0
    p2[:, :, :3] = 0.0  # the reference: cvxpy on the plant without the block's effect
    ref = solvers.solve_sdp(PlantResponse(p2, resp2.blocks, 3, 1, 3), u2, y2)
    compared = compare_with_reference(PlantResponse(p2, resp2.blocks, 3, 1, 3), u2, y2, res2, ref)
    assert compared.sum() >= 6
