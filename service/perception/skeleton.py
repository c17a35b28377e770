"""Step 2: skeletonization, a one-pixel-wide, 8-connected centreline of the mask.

Morphological thinning keeps every component connected. Thinning also leaves short
spurs where the border of the mask is ragged; those are removed so that the skeleton
has one branch per real branch of the cable.

The pixel loops run in compiled kernels (:mod:`service.perception._kernels`) that
visit only the pixels that can change: the thinning is scikit-image's Zhang-Suen
thinning, pixel for pixel, and the distances are OpenCV's 5x5 chamfer distances.
"""

from __future__ import annotations

import numpy as np
from skimage.morphology import skeletonize as skimage_skeletonize

from service.perception import _kernels

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


def as_uint8(image: np.ndarray) -> np.ndarray:
    """A C-contiguous ``uint8`` 0/1 view (no copy when possible) of a boolean image."""
    image = np.asarray(image)
    if image.dtype != np.bool_:
        return np.ascontiguousarray(image != 0).view(np.uint8)
    image = np.ascontiguousarray(image)
    if not image.flags.writeable:
        # The kernels are compiled for writable arrays; a read-only one would make
        # numba compile (and cache) another version on the spot.
        image = image.copy()
    return image.view(np.uint8)


def branch_counts(skeleton: np.ndarray) -> np.ndarray:
    """Branches leaving each skeleton pixel: 1 at a tip, 2 along a line, 3+ at a junction.

    Zero off the skeleton.
    """
    return _kernels.branch_count_image(as_uint8(skeleton), _BRANCH_COUNT)


def skeletonize(mask: np.ndarray) -> np.ndarray:
    """Thin a 2D mask to a one-pixel-wide 8-connected skeleton.

    Zhang-Suen thinning by ``skimage.morphology.skeletonize``, run only on the
    bounding box of the foreground.

    Parameters
    ----------
    mask : ndarray
        2D foreground mask (nonzero = foreground).

    Returns
    -------
    ndarray of bool
    """
    mask = as_uint8(mask)
    if mask.ndim != 2:
        raise ValueError(f"skeletonize needs a 2D mask, not {mask.ndim}D")
    skeleton = np.zeros(mask.shape, bool)
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return skeleton
    cols = np.flatnonzero(mask.any(axis=0))
    # One pixel of margin: thinning treats the array border as background anyway.
    top, bottom = max(rows[0] - 1, 0), min(rows[-1] + 2, mask.shape[0])
    left, right = max(cols[0] - 1, 0), min(cols[-1] + 2, mask.shape[1])
    skeleton[top:bottom, left:right] = skimage_skeletonize(mask[top:bottom, left:right] > 0)
    return skeleton


def remove_spurs(skeleton: np.ndarray, spur_length: float, passes: int = 2) -> np.ndarray:
    """Remove branches that run from a tip to a junction in fewer than ``spur_length`` px.

    Branches from a tip to another tip (a whole short component) are left alone: they
    are removed, if at all, by the size filter of the segmentation.

    In each pass, every tip (in row-major order) starts a walk along its branch: the
    next pixel is the first unvisited neighbour in the order E, S, W, N, SE, SW, NW,
    NE (orthogonal first, so staircases are not skipped), and the walk ends at a
    junction (branch count 3 or more at the start of the pass, or more than two ways
    on). A walk that reaches a junction within ``spur_length`` is removed. After a
    pass that removed anything, the skeleton is thinned again, since a removed spur
    can leave a stub pixel at its junction.
    """
    skeleton = as_uint8(skeleton).copy()
    for _ in range(passes):
        if not _kernels.remove_spurs_inplace(skeleton, float(spur_length), _BRANCH_COUNT):
            break
        skeleton = as_uint8(skeletonize(skeleton))
    return skeleton.view(np.bool_)


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


def distance_transform(mask: np.ndarray) -> np.ndarray:
    """``cv2.distanceTransform(mask, cv2.DIST_L2, 5)``, bit for bit, in O(foreground).

    Float32 distance of each foreground pixel to the nearest background pixel centre
    (OpenCV's 5x5 chamfer approximation of the Euclidean distance); 0 on background.
    """
    return _kernels.distance_transform(as_uint8(mask))


def estimate_radius(
    mask: np.ndarray, skeleton: np.ndarray, distance: np.ndarray | None = None
) -> float:
    """Typical half width of the cables: the median distance from skeleton to border.

    Parameters
    ----------
    mask, skeleton : ndarray of bool
    distance : ndarray, optional
        ``distance_transform(mask)`` when the caller has it already; otherwise the
        distance is computed at the skeleton pixels only.
    """
    skeleton = as_uint8(skeleton)
    if distance is not None:
        values = distance[skeleton.view(np.bool_)]
    else:
        values = _kernels.distances_on_skeleton(as_uint8(mask), skeleton)
    if values.size == 0:
        return 0.0
    # The distance is to the nearest background pixel centre, half a pixel beyond
    # the border.
    return max(float(np.median(values)) - 0.5, 0.5)
