"""The tracker's kernels loaded with the pipeline's: :func:`service.perception.warm_up` calls
:func:`warm_up_tracking` (the tracker itself builds on the pipeline, so the pipeline cannot
call it)."""

from __future__ import annotations

import numpy as np

from service.perception import _tracking_kernels


def warm_up_tracking() -> None:
    """Call every tracking kernel once on tiny inputs of the tracker's argument types,
    so that :func:`service.perception.warm_up` compiles (or loads) them all."""
    line = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])
    other = np.array([[15.0, -10.0], [15.0, 0.0], [15.0, 10.0]])
    both = np.ascontiguousarray(np.vstack((line, other)))
    starts = np.array([0, 4], np.int64)
    counts = np.array([4, 3], np.int64)
    directions = np.tile(np.array([1.0, 0.0]), (4, 1))
    distance, arc, cosine = _tracking_kernels.nearest_on_polylines(
        line, directions, both, starts, counts, np.full(2, 5.0)
    )
    _tracking_kernels.fit_statistics(
        distance,
        arc * 10.0,
        cosine,
        line[:, 0].copy(),
        starts[:1],
        counts[:1],
        np.full(2, 5.0),
        0.5,
    )
    arcs = line[:, 0].copy()
    _tracking_kernels.refine_offset(line, line, arcs, 1, 0.0, 10.0, 2)
    _tracking_kernels.chord_walk(line, arcs, 5.0, -1, 10.0, 3)
    _tracking_kernels.crowded_segments(
        both, starts, counts, np.full(2, 2.0), np.full(2, 3, np.int64)
    )
    _tracking_kernels.near_any_segment(line, np.full(4, 2.0), line[:-1].copy(), line[1:].copy())
    _tracking_kernels.constrain_chain(line, np.ones(4), 10.0, np.zeros(4), 2, 1)
