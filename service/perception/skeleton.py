"""Step 2: skeletonization, a one-pixel-wide, 8-connected centreline of the mask.

Morphological thinning keeps every component connected. Thinning also leaves short
spurs where the border of the mask is ragged; those are removed so that the skeleton
has one branch per real branch of the cable.
"""

from __future__ import annotations

import cv2
import numpy as np
from skimage.morphology import skeletonize

# Offsets of the 8 neighbours in circular order (clockwise from east), as (row, col).
NEIGHBOUR_OFFSETS = ((0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1))


def _branch_count_table() -> np.ndarray:
    """Number of separate runs of skeleton pixels around a pixel, per 8-bit pattern.

    Counting runs rather than neighbours keeps staircase steps of a diagonal line
    (two neighbours that touch each other) from looking like a junction.
    """
    table = np.zeros(256, np.uint8)
    for pattern in range(256):
        bits = [(pattern >> k) & 1 for k in range(8)]
        runs = sum(1 for k in range(8) if bits[k] and not bits[k - 1])
        if runs == 0 and all(bits):
            runs = 1
        # Where branches meet, thinning leaves small clumps in which two branches
        # touch in the ring and count as one run; four or more neighbours never
        # happen along a thin line, so they mark a junction too.
        if sum(bits) >= 4:
            runs = max(runs, 3)
        table[pattern] = runs
    return table


_BRANCH_COUNT = _branch_count_table()


def neighbour_pattern(skeleton: np.ndarray) -> np.ndarray:
    """8-bit pattern of the set neighbours of every pixel (bit k: NEIGHBOUR_OFFSETS[k])."""
    # One correlation with powers of two sums the neighbour bits; float32 holds the
    # sums (at most 255) exactly.
    kernel = np.zeros((3, 3), np.float32)
    for bit, (dr, dc) in enumerate(NEIGHBOUR_OFFSETS):
        kernel[1 + dr, 1 + dc] = 1 << bit
    pattern = cv2.filter2D(
        skeleton.astype(np.uint8), cv2.CV_32F, kernel, borderType=cv2.BORDER_CONSTANT
    )
    return pattern.astype(np.uint8)


def branch_counts(skeleton: np.ndarray) -> np.ndarray:
    """Branches leaving each skeleton pixel: 1 at a tip, 2 along a line, 3+ at a junction.

    Zero off the skeleton.
    """
    counts = _BRANCH_COUNT[neighbour_pattern(skeleton)]
    counts[~skeleton] = 0
    return counts


def _next_pixels(skeleton, row, col, visited):
    """Unvisited skeleton neighbours, orthogonal ones first (so staircases are not skipped)."""
    height, width = skeleton.shape
    found = []
    for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, -1), (-1, 1)):
        r, c = row + dr, col + dc
        if 0 <= r < height and 0 <= c < width and skeleton[r, c] and (r, c) not in visited:
            found.append((r, c))
    return found


def remove_spurs(skeleton: np.ndarray, spur_length: float, passes: int = 2) -> np.ndarray:
    """Remove branches that run from a tip to a junction in fewer than ``spur_length`` px.

    Branches from a tip to another tip (a whole short component) are left alone: they
    are removed, if at all, by the size filter of the segmentation.
    """
    skeleton = skeleton.copy()
    for _ in range(passes):
        counts = branch_counts(skeleton)
        tips = np.argwhere(counts == 1)
        removed_any = False
        for row, col in tips:
            if not skeleton[row, col]:
                continue
            path = [(row, col)]
            visited = {(row, col)}
            length = 0.0
            reached_junction = False
            while length <= spur_length:
                row_c, col_c = path[-1]
                candidates = _next_pixels(skeleton, row_c, col_c, visited)
                if not candidates:
                    break
                nxt = candidates[0]
                if counts[nxt] >= 3 or len(candidates) > 2:
                    reached_junction = True
                    break
                length += 1.0 if (nxt[0] == row_c or nxt[1] == col_c) else 1.4142
                path.append(nxt)
                visited.add(nxt)
                # A staircase step leaves the skipped diagonal as a visited neighbour.
                for extra in candidates[1:]:
                    if abs(extra[0] - nxt[0]) <= 1 and abs(extra[1] - nxt[1]) <= 1:
                        visited.add(extra)
            if reached_junction and length < spur_length:
                for r, c in path:
                    skeleton[r, c] = False
                removed_any = True
        if not removed_any:
            break
        # Removing a spur can leave a stub pixel at the junction; thin again.
        skeleton = skeletonize(skeleton)
    return skeleton


def skeletonize_mask(mask: np.ndarray, spur_length: float) -> np.ndarray:
    """Step 2 of the pipeline: thin the mask to a spur-free 8-connected skeleton.

    Parameters
    ----------
    mask : ndarray of bool
        Foreground mask.
    spur_length : float
        Tip-to-junction branches shorter than this (px) are removed.

    Returns
    -------
    ndarray of bool
        The skeleton, same shape as ``mask``.
    """
    skeleton = skeletonize(mask)
    if spur_length > 0:
        skeleton = remove_spurs(skeleton, spur_length)
    return skeleton


def estimate_radius(mask: np.ndarray, skeleton: np.ndarray) -> float:
    """Typical half width of the cables: the median distance from skeleton to border."""
    if not skeleton.any():
        return 0.0
    distance = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    # The distance is to the nearest background pixel centre, half a pixel beyond
    # the border.
    return max(float(np.median(distance[skeleton])) - 0.5, 0.5)
