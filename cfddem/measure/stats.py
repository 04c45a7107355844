"""Statistics shared by the measurements."""

from __future__ import annotations

import math

import numpy as np


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
