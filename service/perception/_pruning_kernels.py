"""Compiled loops of step 5 (:mod:`service.perception.pruning`): lengths and coverage.

Plain version: ``tests/perception/references/pruning.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._shared_kernels import pairwise_sum


@njit(cache=True, nogil=True)
def _polyline_length(joints, start, stop, scratch):
    """Arc length of ``joints[start:stop]``, rounded as NumPy's ``norm(diff).sum()`` rounds it."""
    if stop - start < 2:
        return 0.0
    for i in range(start, stop - 1):
        dx = joints[i + 1, 0] - joints[i, 0]
        dy = joints[i + 1, 1] - joints[i, 1]
        scratch[i - start] = np.sqrt(dx * dx + dy * dy)
    return 0.0 + pairwise_sum(scratch, 0, stop - start - 1)


@njit(cache=True, nogil=True)
def chain_lengths(joints, ends):
    """Arc length of each chain of ``joints`` (chain ``i`` ends at ``ends[i]``)."""
    lengths = np.empty(ends.size, np.float64)
    scratch = np.empty(max(joints.shape[0], 1), np.float64)
    start = 0
    for i in range(ends.size):
        lengths[i] = _polyline_length(joints, start, ends[i], scratch)
        start = ends[i]
    return lengths


@njit(cache=True, nogil=True)
def uncovered_runs(joints, coverage):
    """Runs of a chain whose segments are not already covered; see pruning.prune_overlaps.

    A segment is covered when at least two of its points at 1/4, 1/2 and 3/4 of its
    length (rounded to the nearest pixel, half to even, and clipped to the image)
    are set in ``coverage``. Returns ``(start, stop)`` joint index pairs of the
    maximal runs of uncovered segments at least 1 px long.
    """
    height, width = coverage.shape
    n = joints.shape[0]
    runs = np.empty((n, 2), np.int64)
    scratch = np.empty(max(n, 1), np.float64)
    n_runs = 0
    start = -1
    for k in range(n):
        covered = False
        if k < n - 1:
            sx = joints[k, 0]
            sy = joints[k, 1]
            dx = joints[k + 1, 0] - sx
            dy = joints[k + 1, 1] - sy
            hits = 0
            for f in (0.25, 0.5, 0.75):
                col = min(max(np.int64(np.rint(sx + f * dx)), 0), width - 1)
                row = min(max(np.int64(np.rint(sy + f * dy)), 0), height - 1)
                hits += coverage[row, col]
            covered = hits >= 2
        if k < n - 1 and not covered:
            if start < 0:
                start = k
        elif start >= 0:
            # Segments start .. k-1 are uncovered: joints start .. k.
            if _polyline_length(joints, start, k + 1, scratch) >= 1.0:
                runs[n_runs, 0] = start
                runs[n_runs, 1] = k + 1
                n_runs += 1
            start = -1
    return runs[:n_runs]
