"""Measured inputs: how far the noise left in a logged input may move β (docs/theory.md).

A measured input ``u_m = u + n`` (a flow meter, a force cell) is averaged over the periods
(:func:`~twotank_validation.core.datum.period_average`): its DFT keeps the harmonics of the
period, where the noise left is ``N(n)``, of standard deviation ``sigma(n)``
(``Datum.u_noise_std``). The datum then carries ``U(n) + N(n)`` in place of ``U(n)``; through
the nominal the output error moves by ``P23(n) N(n)``, which the noise channel explains at
the least cost ``||P22(n)^+ P23(n) N(n)||``. Summed over the bins this bounds the move of β
for a model without perturbations (the triangle inequality) and gives it to first order in
``N`` otherwise. Pure functions over numpy arrays.
"""

from __future__ import annotations

import numpy as np


def noise_gain(p22: np.ndarray, p23: np.ndarray) -> np.ndarray:
    """``|P22(n)^+ P23(n)|`` column by column: the least ``||w||`` per unit of input noise.

    Args:
        p22: (n_bins, n_outputs, nw) complex, the noise channels' response.
        p23: (n_bins, n_outputs, n_inputs) complex, the nominal plant's response.

    Returns:
        (n_bins, n_inputs) float, ``||P22(n)^+ P23(n) e_j||`` (unit of ``w`` per model unit
        of input ``j``).
    """
    return np.asarray(np.linalg.norm(np.linalg.pinv(p22) @ p23, axis=1))


def input_noise_shift(
    p22: np.ndarray, p23: np.ndarray, noise_bins: np.ndarray, bin_weights: np.ndarray
) -> float:
    """The move of β that a given input noise causes through the nominal, at most.

    ``sqrt(sum_n b_n ||P22(n)^+ P23(n) N(n)||^2)``: for a model without perturbations β
    of the noisy datum lies within this of the noise-free β (docs/theory.md).

    Args:
        p22: (n_bins, n_outputs, nw) complex.
        p23: (n_bins, n_outputs, n_inputs) complex.
        noise_bins: (n_bins, n_inputs) complex, the input noise's scaled DFT ``N(n)``.
        bin_weights: (n_bins,) float, multiplicity of each kept bin.

    Returns:
        The shift (units of ``||w||``).
    """
    w = np.linalg.pinv(p22) @ p23 @ noise_bins[:, :, None]  # (n_bins, nw, 1)
    return float(np.sqrt(np.sum(bin_weights * np.sum(np.abs(w[:, :, 0]) ** 2, axis=1))))


def input_noise_effect(
    p22: np.ndarray,
    p23: np.ndarray,
    noise_std: np.ndarray,
    bin_weights: np.ndarray,
    mask: np.ndarray | None = None,
) -> float:
    """The expected :func:`input_noise_shift` of the noise estimated in a measured input.

    With independent noise on the inputs, ``E ||P22^+ P23 N(n)||^2 = sum_j sigma_j(n)^2
    |P22^+ P23 e_j|^2`` (:func:`noise_gain`).

    Args:
        p22: (n_bins, n_outputs, nw) complex.
        p23: (n_bins, n_outputs, n_inputs) complex.
        noise_std: (n_bins, n_inputs) float, ``sigma_j(n)`` (``Datum.u_noise_std``; 0 for a
            commanded input); empty: every input commanded (the effect is 0).
        bin_weights: (n_bins,) float.
        mask: (n_bins,) bool, the bins β counts (the model's band); None: every bin.

    Returns:
        The expected shift (units of ``||w||``); NaN where the noise cannot be estimated (one
        period).
    """
    if noise_std.size == 0 or not np.any(noise_std != 0):
        return 0.0
    gain = noise_gain(p22, p23)
    b = bin_weights if mask is None else np.where(mask, bin_weights, 0.0)
    return float(np.sqrt(np.sum(b[:, None] * (gain * noise_std) ** 2)))
