"""Column sums, means and maxima of records: numpy's own results, bit for bit, faster.

A record is a tall array of few columns, ``(n_samples, n_channels)``. numpy reduces its axis 0
row after row (one sequential sum per column, the order ``((x0 + x1) + x2) + ...``), calling
its inner loop once per row on ``n_channels`` numbers: about 10 ns a row however few the
columns. The functions here give the same numbers in fewer calls:

* sums and means: two float columns are one complex column (the real and imaginary parts are
  added separately, by the same IEEE additions), accumulated in one call along the samples:
  the same sequential sum per column, so the same bits (numpy's starts from +0, which
  changes only a sum of -0s; ``x.mean(axis=0)`` is that sum over ``n``);
* maxima of absolute values: a maximum does not depend on the order (the values are never
  ``-0``, and a NaN wins either way), so it is taken on the transposed copy;
* a row subtracted from every row (``x - mean``): the same IEEE subtractions, one complex
  number per pair of columns, in one call;
* Euclidean norms of rows of one or two entries: their squares summed in one call.

Anything else (an odd number of columns, another dtype, no rows) goes to numpy itself.
``test/core/test_columns.py`` holds them to numpy's results.
"""

from __future__ import annotations

import numpy as np


def _pairs(x: np.ndarray) -> bool:
    """Whether numpy reduces ``x`` row after row and its columns pair up.

    An even number of float64 columns, adjacent in memory (the last axis is the innermost:
    numpy sums a record stored column after column pairwise instead), and some rows.
    """
    return (
        x.dtype == np.float64
        and x.shape[-1] % 2 == 0
        and x.size > 0
        and x.strides[-1] == x.itemsize
        and all(s >= x.shape[-1] * x.itemsize for s in x.strides[:-1])
    )


def column_sum(x: np.ndarray) -> np.ndarray:
    """``x.sum(axis=0)`` of a record, bit for bit.

    Args:
        x: (n, k) float.

    Returns:
        (k,) float.
    """
    if x.ndim != 2 or not _pairs(x):
        return np.sum(x, axis=0)
    c = np.ascontiguousarray(x).view(np.complex128)  # (n, k/2): columns 2i, 2i+1 as one
    total = np.add.accumulate(c, axis=0)[-1]
    return total.view(np.float64) + 0.0  # numpy starts from +0: a sum of -0s is +0


def column_mean(x: np.ndarray) -> np.ndarray:
    """``x.mean(axis=0)`` of a record, bit for bit.

    Args:
        x: (n, k) float.

    Returns:
        (k,) float.
    """
    if x.ndim != 2 or not _pairs(x):
        return np.mean(x, axis=0)
    out: np.ndarray = column_sum(x) / x.shape[0]
    return out


def centred(x: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """``x - mean`` of a record and a row, bit for bit.

    Args:
        x: (n, k) float.
        mean: (k,) float.

    Returns:
        (n, k) float, a new array.
    """
    mean = np.asarray(mean)
    if x.ndim != 2 or not _pairs(x) or mean.shape != x.shape[1:] or mean.dtype != np.float64:
        out: np.ndarray = x - mean
        return out
    c = np.ascontiguousarray(x).view(np.complex128)  # (n, k/2)
    return (c - np.ascontiguousarray(mean).view(np.complex128)).view(np.float64)


def period_mean(x: np.ndarray) -> np.ndarray:
    """``x.mean(axis=1)`` of a record cut into periods, bit for bit.

    Args:
        x: (p, L, k) float, ``p`` periods of ``L`` samples.

    Returns:
        (p, k) float.
    """
    if x.ndim != 3 or not _pairs(x):
        return np.mean(x, axis=1)
    c = np.ascontiguousarray(x).view(np.complex128)  # (p, L, k/2)
    total = np.add.accumulate(c, axis=1)[:, -1, :]
    out: np.ndarray = (np.ascontiguousarray(total).view(np.float64) + 0.0) / x.shape[1]
    return out


def column_max_abs(x: np.ndarray) -> np.ndarray:
    """``np.max(np.abs(x), axis=0)`` of a record, bit for bit.

    Args:
        x: (n, k) float, n >= 1.

    Returns:
        (k,) float.
    """
    if x.ndim != 2 or x.dtype != np.float64 or x.shape[0] == 0:
        return np.max(np.abs(x), axis=0)
    out: np.ndarray = np.abs(np.ascontiguousarray(x.T)).max(axis=1)
    return out


def row_norm(w: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(w, axis=1)``, bit for bit.

    numpy sums the squared magnitudes of each row in its own inner-loop call; of one or two
    columns (never ``-0``) that sum is the plain sum, taken here for all rows at once.

    Args:
        w: (n, k) complex or float.

    Returns:
        (n,) float.
    """
    if w.ndim != 2 or w.shape[1] > 2 or w.shape[1] == 0:
        out: np.ndarray = np.linalg.norm(w, axis=1)
        return out
    s = (w.conj() * w).real  # as numpy's norm: |w|^2 >= +0
    return np.sqrt(s[:, 0] + s[:, 1]) if w.shape[1] == 2 else np.sqrt(s[:, 0])
