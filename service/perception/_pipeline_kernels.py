"""Compiled loop of :mod:`service.perception.pipeline`: the "inferred" flags of a chain.

Plain version: ``tests/perception/references/pipeline.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._shared_kernels import pairwise_sum


@njit(cache=True, nogil=True)
def inferred_segments(source_edge, edge_lengths, hidden_edge):
    """The per-segment "inferred" flags of a resampled chain (pipeline._finalise_path).

    Segment ``k`` (joints ``k`` to ``k + 1``) spans the polyline edges
    ``source_edge[k]`` to ``source_edge[k + 1]``; it is inferred when more than half of
    their length is hidden (or, if they have no length, when the first one is). The
    sums are added in NumPy's order (:func:`pairwise_sum`), so the comparisons are
    those of the plain code.
    """
    n = max(source_edge.size - 1, 0)
    inferred = np.zeros(n, np.bool_)
    scratch = np.empty(max(edge_lengths.size, 1), np.float64)
    for k in range(n):
        lo = source_edge[k]
        hi = min(source_edge[k + 1] + 1, edge_lengths.size)
        total = pairwise_sum(edge_lengths, lo, hi) if hi > lo else 0.0
        if total > 0:
            for i in range(lo, hi):
                scratch[i - lo] = edge_lengths[i] if hidden_edge[i] else 0.0
            inferred[k] = pairwise_sum(scratch, 0, hi - lo) > 0.5 * total
        else:
            inferred[k] = hidden_edge[source_edge[k]]
    return inferred
