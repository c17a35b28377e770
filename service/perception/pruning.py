"""Step 5: pruning, so that no two chains cover the same pixels.

Fitting walks every skeleton branch once per side of its contour, so most branches
come out twice. Chains are visited longest first; a segment with at least two of its
points at 1/4, 1/2 and 3/4 of its length on pixels already covered by a kept segment
(a band ``2 * tolerance + 1`` px wide drawn by ``cv2.polylines``) is removed, and what
is left of a chain is split into its unbroken runs (runs under 1 px long are dropped).
The per-segment test runs in a compiled kernel (``_pruning_kernels.uncovered_runs``).
"""

from __future__ import annotations

import cv2
import numpy as np

from service.perception import _pruning_kernels


def prune_overlaps(
    chains: list[np.ndarray], shape: tuple[int, int], tolerance: float = 2.0
) -> list[np.ndarray]:
    """Step 5 of the pipeline: drop segments that repeat segments already kept.

    Parameters
    ----------
    chains : list of ndarray
        ``(K, 2)`` joint arrays from fitting.
    shape : tuple of int
        ``(H, W)`` of the image.
    tolerance : float
        Half width in pixels of the band a kept segment covers.

    Returns
    -------
    list of ndarray
        Non-overlapping chains, each with at least two joints.
    """
    coverage = np.zeros(shape, np.uint8)
    thickness = max(1, round(2 * tolerance + 1))
    if not chains:
        return []
    arrays = [np.asarray(joints, dtype=np.float64).reshape(-1, 2) for joints in chains]
    ends = np.cumsum([len(joints) for joints in arrays])
    everything = np.ascontiguousarray(np.concatenate(arrays))
    lengths = _pruning_kernels.chain_lengths(everything, ends)
    # The pixels cv2.polylines draws a kept run through, for all chains at once.
    rounded = np.rint(everything).astype(np.int32)
    starts = ends - [len(joints) for joints in arrays]
    kept: list[np.ndarray] = []
    # Longest first; chains of equal length keep their order.
    for index in np.argsort(-lengths, kind="stable").tolist():
        joints = arrays[index]
        if len(joints) < 2:
            continue
        offset = int(starts[index])
        runs = _pruning_kernels.uncovered_runs(everything[offset : offset + len(joints)], coverage)
        for start, stop in runs.tolist():
            kept.append(joints[start:stop])
            points = rounded[offset + start : offset + stop]
            cv2.polylines(coverage, [points], False, 1, thickness)
    return kept
