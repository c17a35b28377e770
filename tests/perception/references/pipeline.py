"""Plain per-segment "inferred" flags of a resampled chain."""

import numpy as np


def inferred_segments(source_edge, edge_lengths, hidden_edge):
    inferred = np.zeros(len(source_edge) - 1, bool)
    for k in range(len(source_edge) - 1):
        span_edges = slice(source_edge[k], source_edge[k + 1] + 1)
        weights = edge_lengths[span_edges]
        if weights.sum() > 0:
            inferred[k] = (weights * hidden_edge[span_edges]).sum() > 0.5 * weights.sum()
        else:
            inferred[k] = bool(hidden_edge[source_edge[k]])
    return inferred
