"""The 1 x 3 test structure built from its masses and springs, and records simulated from it.

Used by ``test/diagnose/test_diagnose_mode.py`` and ``bench/mode_shift.py``. The structure
is ``test/data/models/mode_structure.yaml``'s: three masses in a chain,
ground-k1-m1-k2-m2-k3-m3, the third also on a support spring to ground, a force on the third
(m = 0.5, 0.2, 2.0 kg; k = 800, 200, 800 N/m; support 100 N/m; Rayleigh damping C = 0.5 M +
0.001 K). States: displacements (m) and velocities (m/s); outputs: the displacements in mm.
The changed plants are built here by physics (a spring stiffened), independently of the
diagnosis's mode effect.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from twotank_validation.core.model import load_model_document, model_from_dict
from twotank_validation.diagnose import Window
from twotank_validation.sim.model_plant import ModelExcitation, ModelSimConfig, simulate_model

MODEL = Path(__file__).parents[1] / "test" / "data" / "models" / "mode_structure.yaml"
MASSES = np.array([0.5, 0.2, 2.0])
"""kg."""
SUPPORT = 100.0
"""The nominal support spring under the third mass, N/m."""
TS_S = 0.01
PERIOD = 1024
"""Samples per period (10.24 s: bins 0.098 Hz apart, about the first mode's half-power width)."""


def structure(support: float = SUPPORT, k_extra: np.ndarray | None = None) -> np.ndarray:
    """The state matrix (6, 6) from the masses and springs.

    Args:
        support: the support spring under the third mass, N/m.
        k_extra: (3, 3) N/m added to the stiffness matrix after the damping matrix is formed
            (a change of stiffness alone); ``None``: nothing.
    """
    k1, k2, k3 = 800.0, 200.0, 800.0
    k = np.array([[k1 + k2, -k2, 0], [-k2, k2 + k3, -k3], [0, -k3, k3 + support]])
    c = 0.5 * np.diag(MASSES) + 0.001 * k
    k = k if k_extra is None else k + k_extra
    m = MASSES[:, None]
    return np.block([[np.zeros((3, 3)), np.eye(3)], [-k / m, -c / m]])


def windows(
    support: float = SUPPORT, seed: int = 0, gain_x2: float = 0.0, n_windows: int = 2
) -> list[Window]:
    """Windows of two periods of the structure, simulated with ``simulate_model``.

    A multisine force of 1 N RMS over 1-14 Hz (seed ``seed``), the model file's noise at its
    edge (noise seed ``seed + 1``), settled automatically.

    Args:
        support: the support spring of the simulated structure, N/m.
        seed: the excitation's seed.
        gain_x2: an output gain injected on ``x2`` by hand (its deviation scaled by
            ``1 + gain_x2``; the operating point is 0).
        n_windows: windows to return.
    """
    doc, _ = load_model_document(str(MODEL))
    true = copy.deepcopy(doc)
    true["nominal"]["ss"]["A"] = structure(support).tolist()
    config = ModelSimConfig(
        model=model_from_dict(true),
        ts_s=TS_S,
        excitation=ModelExcitation(
            period_samples=PERIOD, rms=1.0, f_min_hz=1.0, f_max_hz=14.0, seed=seed
        ),
        periods=2 * n_windows,
        noise_seed=seed + 1,
    )
    u, y = simulate_model(config).recorded()
    y = y.copy()
    y[:, 1] *= 1.0 + gain_x2
    n = 2 * PERIOD
    return [
        Window(u[i * n : (i + 1) * n], y[i * n : (i + 1) * n], TS_S, PERIOD, i * n * TS_S)
        for i in range(n_windows)
    ]
