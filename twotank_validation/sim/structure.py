"""A lightly damped chain of masses whose first spring stiffens with amplitude (cubic term).

The plant of issue 28's "Shown on" structure: 1 force input, 3 displacement outputs, three
modes in a 2–15 Hz band, and a cubic spring that moves the first mode up as the excitation
grows. ROS-free: pure functions over numpy arrays and frozen dataclasses.

**Units.** Force in N, displacement in m inside the simulation and in mm as outputs, time
in s, masses in kg, springs in N/m, the cubic coefficient in N/m³.

**The chain.** Masses ``m_0 .. m_{n-1}``; spring ``i`` (stiffness ``k_i``) with a dashpot
``c_i = damping_s k_i`` in parallel joins mass ``i - 1`` to mass ``i`` (spring 0 joins mass 0
to the ground). Spring 0 adds a cubic force: its tension is ``k_0 x_0 + k_c x_0³``. The force
acts on mass ``force_mass`` (the tip by default). ``M x'' + C x' + K x + k_c x_0³ e_0 = f e_F``,
``M = diag(m)``; ``C = damping_s K`` (stiffness-proportional damping: the modal damping ratio
of mode ``j`` is ``damping_s ω_j / 2``). The defaults (three 1 kg masses, three 1800 N/m
springs, ``damping_s`` 1e-3 s) have modes at 3.01, 8.42 and 12.17 Hz, damped 0.94 %, 2.6 %
and 3.8 %.

**The experiment** (:class:`StructureConfig`). A random-phase multisine over ``f_min_hz ..
f_max_hz`` (:func:`~twotank_validation.sim.excitation.multisine_period`) of RMS
``force_rms_n``, repeated from rest for ``settle_periods`` and then ``periods`` periods. The
force is **held over each sample** (zero-order hold, as a force actuator fed by a DAC at the
sample rate): the validator's zero-order-hold discretisation of the linear model is then the
exact response of the linear chain, and what a recording shows is the noise and the cubic
spring, not the hold. The chain is integrated by fixed-step RK4, ``substeps`` steps per
sample (hand-written and compiled with numba: scipy's ``solve_ivp`` would restart at every
sample of a held input, tens of thousands of restarts per run; at the default 4 substeps of
400 Hz, ``ω h`` is below 0.05 at the highest mode, a local error of order ``(ω h)⁵/120``;
``test/sim/test_structure.py`` checks the linear chain at 200 Hz against the closed form to
1e-4, which the transient left after settling dominates). The displacements are
sampled at each sample instant before that sample's force acts. The measured force carries
white Gaussian noise of ``force_noise`` times ``force_rms_n`` (a force cell: the input is
*measured*, ``kind: measured`` in the recording's map), each displacement sensor white
Gaussian noise of ``displacement_noise_mm``.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, TypeVar, cast

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from twotank_validation.defaults import NS_PER_S
from twotank_validation.online.interface_map import InputKind
from twotank_validation.sim.excitation import multisine_harmonics, multisine_period
from twotank_validation.sim.model_faults import ModelSimError
from twotank_validation.sim.model_record import (
    TIME_COLUMN,
    interface_map_path,
    table_interface_map,
    write_interface_map,
)

__all__ = [
    "FORCE",
    "MM_PER_M",
    "MODEL_SUFFIX",
    "StructureConfig",
    "StructureParams",
    "StructureRun",
    "excited_bins",
    "output_names",
    "simulate_structure",
    "state_space",
    "structure_model",
    "write_structure_recording",
    "zoh_response",
]

FloatArray = NDArray[np.float64]

FORCE: Final = "force"
"""The input's name (N)."""
MM_PER_M: Final = 1000.0
"""Outputs are displacements in mm."""
SETTLE_DECAY: Final = 1e-6
"""Automatic settling: the slowest mode's free decay ``exp(-σ t)`` reaches this first."""


def output_names(n_masses: int) -> tuple[str, ...]:
    """``("x1", "x2", ...)``: the displacement of each mass, mm (mass 0 is ``x1``)."""
    return tuple(f"x{i + 1}" for i in range(n_masses))


def _positive(where: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ModelSimError(f"{where}={value!r} must be a finite number")
    if value <= 0.0:
        raise ModelSimError(f"{where}={value!r} must be > 0")
    return float(value)


def _non_negative(where: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ModelSimError(f"{where}={value!r} must be a finite number")
    if value < 0.0:
        raise ModelSimError(f"{where}={value!r} must be >= 0")
    return float(value)


@dataclass(frozen=True, kw_only=True)
class StructureParams:
    """The chain's physical parameters (SI units; validated on construction).

    Attributes:
        masses_kg: Mass of each of the n >= 1 masses, kg, > 0.
        stiffness_n_per_m: Linear stiffness of each of the n springs, N/m, > 0; spring i
            joins mass i - 1 (the ground for i = 0) to mass i.
        damping_s: Stiffness-proportional damping, s, >= 0: dashpot ``c_i = damping_s k_i``.
        cubic_n_per_m3: Cubic coefficient of spring 0, N/m³, >= 0 (0: a linear chain). The
            default 3e5 leaves the chain linear within its noise up to a force of about 1 N
            RMS and stiffens the first mode beyond (docs/simulate.md).
        force_mass: Index of the mass the force acts on (default: the last, the tip).

    Raises:
        ModelSimError: naming the parameter.
    """

    masses_kg: tuple[float, ...] = (1.0, 1.0, 1.0)
    stiffness_n_per_m: tuple[float, ...] = (1800.0, 1800.0, 1800.0)
    damping_s: float = 1.0e-3
    cubic_n_per_m3: float = 3.0e5
    force_mass: int = -1

    def __post_init__(self) -> None:
        put = object.__setattr__
        m = tuple(_positive(f"masses_kg[{i}]", v) for i, v in enumerate(self.masses_kg))
        k = tuple(
            _positive(f"stiffness_n_per_m[{i}]", v) for i, v in enumerate(self.stiffness_n_per_m)
        )
        if not m or len(k) != len(m):
            raise ModelSimError(
                f"masses_kg has {len(m)} entries and stiffness_n_per_m {len(k)}: give one spring "
                "per mass (at least one)"
            )
        put(self, "masses_kg", m)
        put(self, "stiffness_n_per_m", k)
        put(self, "damping_s", _non_negative("damping_s", self.damping_s))
        put(self, "cubic_n_per_m3", _non_negative("cubic_n_per_m3", self.cubic_n_per_m3))
        fm = self.force_mass
        if isinstance(fm, bool) or not isinstance(fm, int) or not -len(m) <= fm < len(m):
            raise ModelSimError(f"force_mass={fm!r} must index one of the {len(m)} masses")
        put(self, "force_mass", fm % len(m))

    @property
    def n_masses(self) -> int:
        """Number of masses n."""
        return len(self.masses_kg)

    def matrices(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(M, C, K)``, each (n, n): mass (kg), damping (N s/m), stiffness (N/m)."""
        n = self.n_masses
        k = np.array(self.stiffness_n_per_m)
        stiff = np.zeros((n, n))
        for i in range(n):
            stiff[i, i] += k[i]
            if i > 0:  # spring i between mass i - 1 and mass i
                stiff[i - 1, i - 1] += k[i]
                stiff[i - 1, i] -= k[i]
                stiff[i, i - 1] -= k[i]
        return np.diag(self.masses_kg), self.damping_s * stiff, stiff

    def modes(self) -> tuple[FloatArray, FloatArray]:
        """``(f_hz, zeta)``, each (n,): natural frequencies and damping ratios, increasing."""
        a, _, _, _ = state_space(self)
        lam = np.linalg.eigvals(a)
        lam = lam[lam.imag > 0]
        wn = np.abs(lam)
        order = np.argsort(wn)
        return wn[order] / (2.0 * np.pi), -lam.real[order] / wn[order]


def state_space(params: StructureParams) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The linear chain (``k_c`` = 0) as a continuous state space from its matrices.

    State ``[x (m); x' (m/s)]`` (2n,), input the force (N), outputs the displacements (mm):
    ``A = [[0, I], [-M⁻¹K, -M⁻¹C]]``, ``B = [0; M⁻¹ e_F]``, ``C = 1000 [I, 0]``, ``D = 0``.

    Returns:
        ``(A (2n, 2n), B (2n, 1), C (n, 2n), D (n, 1))``.
    """
    mass, damp, stiff = params.matrices()
    n = params.n_masses
    minv = np.linalg.inv(mass)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ stiff, -minv @ damp]])
    b = np.zeros((2 * n, 1))
    b[n + params.force_mass, 0] = 1.0 / params.masses_kg[params.force_mass]
    c = np.hstack([MM_PER_M * np.eye(n), np.zeros((n, n))])
    return a, b, c, np.zeros((n, 1))


@dataclass(frozen=True, kw_only=True)
class StructureConfig:
    """One run of the structure at one excitation level.

    Attributes:
        params: The chain.
        ts_s: Sample period, s (default 1/400 s), a whole number of nanoseconds.
        period_samples: Excitation period, samples, >= 4.
        periods: Periods recorded after settling, >= 1.
        settle_periods: Periods from rest before the record; None: until the slowest mode's
            free decay reaches :data:`SETTLE_DECAY`.
        f_min_hz: Lowest frequency of the multisine, Hz.
        f_max_hz: Highest frequency of the multisine, Hz, below Nyquist.
        force_rms_n: RMS of the force, N, > 0 (the excitation level).
        seed: Seed of the multisine's phases.
        noise_seed: Seed of the sensor noise.
        displacement_noise_mm: Standard deviation of each displacement sensor's noise, mm.
        force_noise: Standard deviation of the force cell's noise relative to
            ``force_rms_n``.
        substeps: RK4 steps per sample, >= 1.
    """

    params: StructureParams = field(default_factory=StructureParams)
    ts_s: float = 0.0025
    period_samples: int = 1024
    periods: int = 8
    settle_periods: int | None = None
    f_min_hz: float = 2.0
    f_max_hz: float = 15.0
    force_rms_n: float = 1.0
    seed: int = 0
    noise_seed: int = 0
    displacement_noise_mm: float = 0.002
    force_noise: float = 3.0e-3
    substeps: int = 4

    def __post_init__(self) -> None:
        put = object.__setattr__
        put(self, "ts_s", _positive("ts_s", self.ts_s))
        ts_ns = self.ts_s * NS_PER_S
        if abs(ts_ns - round(ts_ns)) > 1e-3:
            raise ModelSimError(f"ts_s={self.ts_s!r} must be a whole number of nanoseconds")
        for key, lo in (
            ("period_samples", 4),
            ("periods", 1),
            ("substeps", 1),
            ("seed", 0),
            ("noise_seed", 0),
        ):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise ModelSimError(f"{key}={value!r} must be an integer >= {lo}")
        s = self.settle_periods
        if s is not None and (isinstance(s, bool) or not isinstance(s, int) or s < 0):
            raise ModelSimError(
                f"settle_periods={s!r} must be an integer >= 0 (or None: automatic)"
            )
        put(self, "force_rms_n", _positive("force_rms_n", self.force_rms_n))
        for key in ("displacement_noise_mm", "force_noise"):
            put(self, key, _non_negative(key, getattr(self, key)))
        put(self, "f_min_hz", _positive("f_min_hz", self.f_min_hz))
        put(self, "f_max_hz", _positive("f_max_hz", self.f_max_hz))
        if not self.f_min_hz <= self.f_max_hz < 0.5 / self.ts_s:
            raise ModelSimError(
                f"f_min_hz={self.f_min_hz!r} .. f_max_hz={self.f_max_hz!r} must be an increasing "
                f"band below the Nyquist frequency {0.5 / self.ts_s:g} Hz"
            )
        if excited_bins(self).size == 0:
            raise ModelSimError(
                f"no harmonic of the period ({1 / (self.period_samples * self.ts_s):g} Hz) lies in "
                f"{self.f_min_hz:g} .. {self.f_max_hz:g} Hz: lengthen period_samples"
            )

    @property
    def ts_ns(self) -> int:
        """Sample period in integer nanoseconds."""
        return round(self.ts_s * NS_PER_S)

    def settle(self) -> int:
        """The settling periods (given, or automatic: see ``settle_periods``)."""
        if self.settle_periods is not None:
            return self.settle_periods
        a, _, _, _ = state_space(self.params)
        sigma = float(np.min(-np.linalg.eigvals(a).real))
        if sigma <= 0.0:  # undamped: no settling time; one period
            return 1
        return math.ceil(math.log(1.0 / SETTLE_DECAY) / sigma / (self.period_samples * self.ts_s))


def excited_bins(cfg: StructureConfig) -> NDArray[np.int64]:
    """The DFT bins of one period the multisine excites (frequency ``k / (N ts_s)``)."""
    return multisine_harmonics(cfg.period_samples, cfg.ts_s, cfg.f_min_hz, cfg.f_max_hz, False)


@dataclass(frozen=True)
class StructureRun:
    """A run: the record after settling.

    Attributes:
        config: The run's settings.
        stamps_ns: (n,) int64, ``k ts_ns`` from the start of the run (settling included, so
            the first is ``settle * period_samples * ts_ns``).
        force: (n,) the force applied (held over each sample), N.
        force_measured: (n,) the force cell's reading, N.
        y_clean: (n, n_masses) the displacements, mm, without sensor noise.
        y: (n, n_masses) the measured displacements, mm.
    """

    config: StructureConfig
    stamps_ns: NDArray[np.int64]
    force: FloatArray
    force_measured: FloatArray
    y_clean: FloatArray
    y: FloatArray

    @property
    def output_names(self) -> tuple[str, ...]:
        """The outputs' names, ``x1 ..``."""
        return output_names(self.config.params.n_masses)


_F = TypeVar("_F", bound=Callable[..., Any])


def _jit(fn: _F) -> _F:
    """``numba.njit`` with an on-disk cache, compiled on first use (typed for mypy)."""
    import numba  # noqa: PLC0415 (imported by a process that simulates a structure only)

    return cast(_F, numba.njit(cache=True, nogil=True)(fn))


_KERNEL: list[Callable[..., FloatArray]] = []


def _rk4_held(  # noqa: PLR0917 - the compiled kernel's flat signature
    a: FloatArray, b: FloatArray, g: FloatArray, force: FloatArray, ts_s: float, substeps: int
) -> FloatArray:
    """States at each sample instant of ``s' = A s + B f + g x_0³`` under a held ``f``.

    Args:
        a: (2n, 2n) the linear chain's A.
        b: (2n,) its B column.
        g: (2n,) the cubic term's column (``-k_c/m_0`` on ``x_0''``).
        force: (m,) the force of each sample, held from its instant to the next.
        ts_s: Sample period, s.
        substeps: RK4 steps per sample.

    Returns:
        (m, 2n): the state at each sample instant before its force acts (from rest).
    """
    ns = a.shape[0]
    out = np.empty((force.shape[0], ns))
    s = np.zeros(ns)
    st = np.empty(ns)
    ks = np.empty((4, ns))
    h = ts_s / substeps
    frac = (0.0, 0.5, 0.5, 1.0)
    for k in range(force.shape[0]):
        out[k] = s
        f = force[k]
        for _ in range(substeps):
            for stage in range(4):
                for i in range(ns):  # the stage's state
                    st[i] = s[i] if stage == 0 else s[i] + frac[stage] * h * ks[stage - 1, i]
                cube = st[0] ** 3
                for i in range(ns):  # its derivative A st + b f + g x_0^3
                    acc = b[i] * f + g[i] * cube
                    for j in range(ns):
                        acc += a[i, j] * st[j]
                    ks[stage, i] = acc
            for i in range(ns):
                s[i] += (h / 6.0) * (ks[0, i] + 2.0 * ks[1, i] + 2.0 * ks[2, i] + ks[3, i])
    return out


def _kernel() -> Callable[..., FloatArray]:
    if not _KERNEL:
        _KERNEL.append(_jit(_rk4_held))
    return _KERNEL[0]


def simulate_structure(cfg: StructureConfig) -> StructureRun:
    """Run the chain from rest through ``settle + periods`` periods; return the record.

    Returns:
        The :class:`StructureRun` of the ``periods`` periods after settling.
    """
    p = cfg.params
    n = p.n_masses
    a, b, _, _ = state_space(p)
    g = np.zeros(2 * n)
    g[n] = -p.cubic_n_per_m3 / p.masses_kg[0]  # spring 0's cubic tension acts on mass 0
    period = cfg.force_rms_n * multisine_period(
        cfg.period_samples,
        cfg.ts_s,
        cfg.f_min_hz,
        cfg.f_max_hz,
        False,
        np.random.default_rng(cfg.seed),
    )
    settle = cfg.settle()
    force = np.tile(period, settle + cfg.periods)
    states = _kernel()(np.ascontiguousarray(a), b[:, 0].copy(), g, force, cfg.ts_s, cfg.substeps)
    if not np.all(np.isfinite(states)):
        raise ModelSimError(
            "the structure's simulation diverged: lower force_rms_n or cubic_n_per_m3, or raise "
            "substeps"
        )
    first = settle * cfg.period_samples
    y_clean = MM_PER_M * states[first:, :n]
    rng = np.random.default_rng(cfg.noise_seed)
    noise = rng.standard_normal((len(y_clean), n + 1))
    rec = force[first:]
    return StructureRun(
        config=cfg,
        stamps_ns=(np.arange(first, len(force), dtype=np.int64) * cfg.ts_ns),
        force=rec,
        force_measured=rec + cfg.force_noise * cfg.force_rms_n * noise[:, 0],
        y_clean=y_clean,
        y=y_clean + cfg.displacement_noise_mm * noise[:, 1:],
    )


def structure_model(
    params: StructureParams,
    *,
    name: str = "structure_1x3",
    uncertainty: float = 0.05,
    noise_weight_mm: float = 0.007,
) -> dict[str, Any]:
    """The linear chain's model document (``load_model`` reads it; YAML-safe plain types).

    Nominal: :func:`state_space` (continuous; force in N, displacements in mm). Perturbations:
    one output-multiplicative block per output of constant weight ``uncertainty`` (a fit to
    within 5 % of the FRF by default). Noise: one channel per output, constant weight
    ``noise_weight_mm``: about 3.5 times the simulator's default sensor noise (0.002 mm), so
    that the three channels sharing the unit-norm ``w`` spend about
    ``sqrt(3) 0.002 / 0.007 = 0.5`` of β over every bin.
    """
    a, b, c, d = state_space(params)
    outs = list(output_names(params.n_masses))
    n = params.n_masses
    return {
        "name": name,
        "description": (
            f"Linear {n}-mass chain (simulator sim.structure, cubic spring left out): force (N) "
            f"in, displacements (mm) out; {uncertainty:g} output-multiplicative uncertainty per "
            f"output, sensor noise weight {noise_weight_mm:g} mm."
        ),
        "inputs": [FORCE],
        "outputs": list(outs),
        "nominal": {
            "ss": {
                "A": a.tolist(),
                "B": b.tolist(),
                "C": c.tolist(),
                "D": d.tolist(),
                "states": [f"x{i + 1}_m" for i in range(n)]
                + [f"v{i + 1}_m_per_s" for i in range(n)],
            }
        },
        "perturbations": [
            {
                "name": f"{o}_fit",
                "kind": "output_multiplicative",
                "outputs": [o],
                "weight": {"gain": uncertainty},
            }
            for o in outs
        ],
        "noise": [
            {
                "name": "sensors",
                "outputs": list(outs),
                "weight": [{"gain": noise_weight_mm} for _ in outs],
            }
        ],
    }


def zoh_response(params: StructureParams, ts_s: float, f_hz: FloatArray) -> FloatArray:
    """The linear chain's response to a held force at ``f_hz``, closed form from expm.

    ``H(z) = C (z I − Φ)⁻¹ Γ``, ``Φ = exp(A ts)``, ``Γ = ∫₀^ts exp(A t) dt B`` (the block
    exponential of ``[[A, B], [0, 0]]``), ``z = exp(j 2π f ts)``.

    Returns:
        (n_f, n_masses) complex, mm/N.
    """
    a, b, c, _ = state_space(params)
    ns = a.shape[0]
    big = np.zeros((ns + 1, ns + 1))
    big[:ns, :ns] = a
    big[:ns, ns:] = b
    e = scipy.linalg.expm(big * ts_s)
    phi, gam = e[:ns, :ns], e[:ns, ns:]
    z = np.exp(2j * np.pi * np.asarray(f_hz) * ts_s)
    return np.array([(c @ np.linalg.solve(zk * np.eye(ns) - phi, gam))[:, 0] for zk in z])


MODEL_SUFFIX: Final = ".model.yaml"
"""Suffix of the linear model written beside a structure's recording."""


def write_structure_recording(
    run: StructureRun, out: str | os.PathLike[str]
) -> tuple[Path, Path, Path]:
    """Write a run as a CSV table, its interface map and the linear model beside it.

    * ``out`` (``.csv``): columns ``t`` (s, ``stamps_ns / 1e9``), ``force`` (the force cell's
      reading, N), ``x1 ..`` (the measured displacements, mm), each float as the shortest text
      that reads back to the same float;
    * ``<stem>.map.yaml``: ``Source(name, column=name)`` for each, time column ``t`` in s,
      the force ``kind: measured``;
    * ``<stem>.model.yaml``: :func:`structure_model` of the run's chain (the cubic term left
      out: the linear nominal a user would have fitted).

    Nothing is overwritten.

    Returns:
        ``(csv, map, model)`` paths.

    Raises:
        ModelSimError: ``out`` is not a ``.csv`` name, or one of the three exists.
    """
    import pandas as pd  # noqa: PLC0415 (pandas only for writing tables)
    import yaml  # noqa: PLC0415

    path = Path(out)
    if path.suffix.lower() != ".csv":
        raise ModelSimError(f"{path}: a recording is written as CSV; give a name ending in .csv")
    map_path = interface_map_path(path)
    model_path = path.with_name(path.stem + MODEL_SUFFIX)
    for p in (path, map_path, model_path):
        if p.exists() or p.is_symlink():
            raise ModelSimError(f"{p} exists already; recordings are never overwritten")
    outs = run.output_names
    plain = table_interface_map((FORCE,), outs)
    imap = dataclasses.replace(plain, input_kinds=(InputKind.MEASURED,))
    columns: dict[str, np.ndarray] = {
        TIME_COLUMN: run.stamps_ns / NS_PER_S,
        FORCE: run.force_measured,
    }
    columns |= {n: run.y[:, i] for i, n in enumerate(outs)}
    written: list[Path] = []
    try:
        with path.open("x", newline="") as fh:
            written.append(path)
            pd.DataFrame(columns).to_csv(fh, index=False)
        written.append(write_interface_map(imap, map_path))
        with model_path.open("x") as fh:
            written.append(model_path)
            yaml.safe_dump(structure_model(run.config.params), fh, sort_keys=False)
    except BaseException:
        for p in written:
            p.unlink(missing_ok=True)
        raise
    return path, map_path, model_path
