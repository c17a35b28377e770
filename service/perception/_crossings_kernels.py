"""Compiled sweep of :mod:`service.perception.crossings`: segment intersections.

Plain version: ``tests/perception/references/crossings.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def segment_intersections(starts, ends, chain_ids, indices, order, stops):
    """The sweep of crossings.find_intersections over all segments, in its order.

    ``order`` sorts the segments by their smallest x and ``stops[k]`` is where the
    segments of ``order`` that may overlap ``order[k]`` along x end. Returns the
    pairs ``(a, b)`` of proper intersections (``a`` the segment of the sweep) and
    the parameter ``t`` of the point along ``a``, with the same float64 arithmetic.
    """
    n = order.size
    capacity = 16
    pairs = np.empty((capacity, 2), np.int64)
    params = np.empty(capacity, np.float64)
    count = 0
    for position in range(n):
        a = order[position]
        ax0 = starts[a, 0]
        ay0 = starts[a, 1]
        rx = ends[a, 0] - ax0
        ry = ends[a, 1] - ay0
        a_lo_y = min(ay0, ends[a, 1])
        a_hi_y = max(ay0, ends[a, 1])
        for k in range(position + 1, stops[position]):
            b = order[k]
            bx0 = starts[b, 0]
            by0 = starts[b, 1]
            bx1 = ends[b, 0]
            by1 = ends[b, 1]
            if not (min(by0, by1) <= a_hi_y and max(by0, by1) >= a_lo_y):
                continue
            if chain_ids[b] == chain_ids[a] and abs(indices[b] - indices[a]) <= 2:
                continue
            sx = bx1 - bx0
            sy = by1 - by0
            denom = rx * sy - ry * sx
            if not abs(denom) > 1e-12:
                continue
            qpx = bx0 - ax0
            qpy = by0 - ay0
            t = (qpx * sy - qpy * sx) / denom
            u = (qpx * ry - qpy * rx) / denom
            if t >= 0 and t < 1 and u >= 0 and u < 1:
                if count == capacity:
                    capacity *= 2
                    grown = np.empty((capacity, 2), np.int64)
                    grown[:count] = pairs[:count]
                    pairs = grown
                    grown_params = np.empty(capacity, np.float64)
                    grown_params[:count] = params[:count]
                    params = grown_params
                pairs[count, 0] = a
                pairs[count, 1] = b
                params[count] = t
                count += 1
    return pairs[:count], params[:count]
