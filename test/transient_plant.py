"""The small plant the transient-term tests share: a SISO model set and its excitation.

``3/(2s^2 + 3s + 1)`` sampled at 0.25 s (time constants 4 and 8 samples) with an
output-multiplicative perturbation and output noise; windows of two periods of 256 samples.
Used by ``test/core/test_transient.py``, ``test/online/test_op_transient.py`` and
``test/core/test_closed_loop_formulation.py``.
"""

from __future__ import annotations

import numpy as np

from twotank_validation.core.model import model_from_dict

SISO = {
    "name": "siso",
    "inputs": ["valve"],
    "outputs": ["flow"],
    "nominal": {"tf": {"num": [3.0], "den": [2.0, 3.0, 1.0]}},
    "perturbations": [
        {
            "name": "mult",
            "kind": "output_multiplicative",
            "outputs": ["flow"],
            "weight": {"tf": {"num": [0.5, 0.05], "den": [1.0, 1.0]}},
        }
    ],
    "noise": [{"name": "n", "outputs": ["flow"], "weight": {"gain": 0.02}}],
}
TS, PERIOD, PERIODS = 0.25, 256, 2  # time constants 4 and 8 samples; windows of 512
N = PERIOD * PERIODS
MODEL = model_from_dict(SISO)


def multisine(seed: int, rms: float = 1.0) -> np.ndarray:
    """A random-phase multisine of RMS ``rms`` over the period's lines 1..60, two periods.

    Returns:
        (N,) float.
    """
    rng = np.random.default_rng(seed)
    spec = np.zeros(PERIOD // 2 + 1, complex)
    spec[1:61] = np.exp(2j * np.pi * rng.random(60))
    one = np.fft.irfft(spec, PERIOD)
    return np.tile(rms * one / one.std(), PERIODS)
