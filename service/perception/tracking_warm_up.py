"""The tracker's kernels, a set of their own (``tracking`` in
:data:`service.console.KERNEL_SETS`): only the front ends that track load them (``dlo
track``, ``dlo eval --tracking``, ``dlo bench --tracking``, a service that tracks), so a
one-image ``dlo detect`` does not pay for them."""

from __future__ import annotations

import numpy as np

from service.perception import _tracking_kernels
from service.perception._kernel_cache import kernels_cached, write_stamp

TRACKING = "tracking"
"""The group (stamp) of the tracker's kernels (:func:`service.perception.kernels_cached`)."""


def warm_up_tracking() -> None:
    """Call every tracking kernel once on tiny inputs of the tracker's argument types,
    so that they are all compiled (on a machine's first run) or loaded; then write their
    group's stamp."""
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
        np.array([30.0, 20.0]),
    )
    arcs = line[:, 0].copy()
    _tracking_kernels.refine_offset(line, line, arcs, 1, 0.0, 10.0, 2)
    _tracking_kernels.chord_walk(line, arcs, 5.0, -1, 10.0, 3)
    _tracking_kernels.crowded_segments(
        both, starts, counts, np.full(2, 2.0), np.full(2, 3, np.int64)
    )
    _tracking_kernels.near_any_segment(line, np.full(4, 2.0), line[:-1].copy(), line[1:].copy())
    _tracking_kernels.constrain_chain(line, np.ones(4), 10.0, np.zeros(4), 2, 1)
    _tracking_kernels.window_medians(np.vstack((line, other)) * 1.0, 3)
    _tracking_kernels.rigid_sums(line, line + 1.0)
    _tracking_kernels.piece_samples(line)
    _tracking_kernels.unit_tangents(line)
    _tracking_kernels.farthest_from_polyline(other, line)
    flags = np.ones(4, bool)
    normal, across, turned, _, _, _ = _tracking_kernels.motion_design(
        line, line + 1.0, flags, directions
    )
    _tracking_kernels.motion_result(np.zeros(3), turned, across, normal, ~flags, np.ones(5) / 5.0)
    if not kernels_cached(TRACKING):
        # numba's cache directory, as the pipeline's warm-up finds it (one for the package).
        cache = getattr(_tracking_kernels.nearest_on_polylines, "_cache", None)
        write_stamp(str(getattr(cache, "_cache_path", "") or ""), TRACKING)
