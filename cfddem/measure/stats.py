"""Statistics shared by the measurements."""

from __future__ import annotations

import math
import numbers

import numpy as np


def mean_sd(values) -> tuple[float, float, int]:
    """Mean, standard deviation (ddof 1; NaN below two values) and count of the finite numbers
    among ``values`` (replicas of one measurement; NaN, text and None are left out)."""
    a = np.array([v for v in values if isinstance(v, numbers.Real) and math.isfinite(v)], float)
    if a.size == 0:
        return math.nan, math.nan, 0
    return float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else math.nan, int(a.size)


def block_error(samples, n_blocks: int = 10) -> np.ndarray:
    """Standard error of the mean of ``samples`` (n, ...) along axis 0 from ``n_blocks``
    contiguous block means (``np.array_split``: the first n mod n_blocks blocks one sample
    longer), the blocks' standard deviation (ddof 1) / sqrt(n_blocks); with fewer samples than
    blocks, one block per sample; NaN with fewer than 2 blocks.  Correlated samples inside a
    block do not make the error look smaller than it is, as long as a block is longer than the
    correlation time."""
    s = np.asarray(samples, float)
    nb = min(int(n_blocks), s.shape[0])
    if nb < 2:
        return np.full(s.shape[1:], np.nan)
    means = np.array([b.mean(axis=0) for b in np.array_split(s, nb)])
    return means.std(axis=0, ddof=1) / math.sqrt(nb)
