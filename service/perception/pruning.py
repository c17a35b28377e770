"""Step 5: pruning, so that no two chains cover the same pixels.

Fitting walks every skeleton branch once per side of its contour, so most branches
come out twice. Chains are visited longest first; a segment whose samples lie on
pixels already covered by a kept segment is removed, and what is left of a chain is
split into its unbroken runs.
"""

from __future__ import annotations

import cv2
import numpy as np

# Fractions along a segment at which coverage is tested.
_SAMPLE_FRACTIONS = np.array([0.25, 0.5, 0.75])


def _covered_segments(joints: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """Per segment: are most of its sample points already covered?"""
    starts, ends = joints[:-1], joints[1:]
    samples = starts[:, None, :] + _SAMPLE_FRACTIONS[None, :, None] * (ends - starts)[:, None, :]
    cols = np.clip(np.rint(samples[..., 0]).astype(int), 0, coverage.shape[1] - 1)
    rows = np.clip(np.rint(samples[..., 1]).astype(int), 0, coverage.shape[0] - 1)
    return coverage[rows, cols].sum(axis=1) >= 2


def _runs_of_uncovered(joints: np.ndarray, covered: np.ndarray) -> list[np.ndarray]:
    runs, start = [], None
    for k, is_covered in enumerate(covered):
        if not is_covered and start is None:
            start = k
        if is_covered and start is not None:
            runs.append(joints[start : k + 1])
            start = None
    if start is not None:
        runs.append(joints[start:])
    return runs


def chain_length(joints: np.ndarray) -> float:
    """Arc length of a polyline in pixels."""
    return float(np.linalg.norm(np.diff(joints, axis=0), axis=1).sum()) if len(joints) > 1 else 0.0


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
    kept: list[np.ndarray] = []
    for joints in sorted(chains, key=chain_length, reverse=True):
        if len(joints) < 2:
            continue
        covered = _covered_segments(joints, coverage)
        for run in _runs_of_uncovered(joints, covered):
            if chain_length(run) < 1.0:
                continue
            kept.append(run)
            cv2.polylines(coverage, [np.rint(run).astype(np.int32)], False, 1, thickness)
    return kept
