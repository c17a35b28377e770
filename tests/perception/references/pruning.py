"""Plain pruning (step 5): segments on already-kept segments dropped, longest chain first."""

import cv2
import numpy as np


def chain_length(joints):
    return float(np.linalg.norm(np.diff(joints, axis=0), axis=1).sum()) if len(joints) > 1 else 0.0


def prune_overlaps(chains, shape, tolerance=2.0):
    fractions = np.array([0.25, 0.5, 0.75])
    coverage = np.zeros(shape, np.uint8)
    thickness = max(1, round(2 * tolerance + 1))
    kept = []
    for joints in sorted(chains, key=chain_length, reverse=True):
        if len(joints) < 2:
            continue
        starts, ends = joints[:-1], joints[1:]
        samples = starts[:, None, :] + fractions[None, :, None] * (ends - starts)[:, None, :]
        cols = np.clip(np.rint(samples[..., 0]).astype(int), 0, shape[1] - 1)
        rows = np.clip(np.rint(samples[..., 1]).astype(int), 0, shape[0] - 1)
        covered = coverage[rows, cols].sum(axis=1) >= 2
        runs, start = [], None
        for k, is_covered in enumerate(covered):
            if not is_covered and start is None:
                start = k
            if is_covered and start is not None:
                runs.append(joints[start : k + 1])
                start = None
        if start is not None:
            runs.append(joints[start:])
        for run in runs:
            if chain_length(run) < 1.0:
                continue
            kept.append(run)
            cv2.polylines(coverage, [np.rint(run).astype(np.int32)], False, 1, thickness)
    return kept
