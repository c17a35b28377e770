"""Step 4: fitting, chains of ``l_s``-long segments along each contour.

The walk follows a contour and emits a joint each time it is ``l_s`` pixels from the
previous joint. A chain ends at every branch tip (where the contour turns back) and
wherever the walk enters a junction zone: near a crossing or a branch the skeleton
bends towards the junction and says nothing reliable about the strands, so those
pixels are left for the merging step to bridge with its gap curve.
"""

from __future__ import annotations

import cv2
import numpy as np

from service.perception import _fitting_kernels, _shared_kernels
from service.perception.skeleton import _BRANCH_COUNT, as_uint8

# Skeleton branches between two junction zones shorter than this many cable radii
# are the bridge the thinning draws through one crossing.
BRIDGE_RADII = 4.0


def junction_zones(
    skeleton: np.ndarray, radius: float, pixels: np.ndarray | None = None
) -> np.ndarray:
    """Pixels near skeleton junctions, where strands meet or cross.

    A zone is a disc of ``1.5 * radius`` around each junction pixel, plus every short
    skeleton branch that joins two zones (the bridge the thinning draws through the
    middle of an X crossing).

    Parameters
    ----------
    skeleton : ndarray of bool
    radius : float
        Typical cable half width in pixels.
    pixels : ndarray of int64, optional
        ``np.flatnonzero(skeleton)`` when the caller has it (the skeleton step lists
        them): the image is not scanned for them.

    Returns
    -------
    ndarray of bool
    """
    zone_radius = max(2, round(1.5 * radius))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * zone_radius + 1,) * 2)
    skeleton = as_uint8(skeleton)
    if pixels is None:
        pixels = _shared_kernels.nonzero_flat(skeleton.reshape(-1))
    zones, _ = _fitting_kernels.junction_zones_kernel(
        skeleton, pixels, disc, BRIDGE_RADII * radius, _BRANCH_COUNT
    )
    return zones.view(np.bool_)


def fit_chains(
    contours: list[np.ndarray],
    skeleton: np.ndarray,
    zones: np.ndarray,
    segment_length: float,
) -> list[np.ndarray]:
    """Step 4 of the pipeline: chains of joints along every contour.

    Parameters
    ----------
    contours : list of ndarray
        From :func:`service.perception.contours.extract_contours`.
    skeleton : ndarray of bool
    zones : ndarray of bool
        Junction zones from :func:`junction_zones`.
    segment_length : float
        ``l_s`` in pixels.

    Returns
    -------
    list of ndarray
        ``(K, 2)`` joint arrays. Each skeleton branch appears about twice (once per
        side of the contour); :func:`service.perception.pruning.prune_overlaps`
        removes the repeats.

    Notes
    -----
    Each contour is cut into runs at branch tips (where a run ends and the next
    begins) and at junction zones (whose pixels belong to no run); a closed contour
    with neither is one run. Each run gets a joint at its first pixel, then at every
    pixel at least ``segment_length`` from the previous joint, and at its last pixel.
    All contours are walked in one compiled loop (``_fitting_kernels.fit_kernel``);
    the plain version is the reference in ``tests/perception/references/fitting.py``.
    """
    if not contours:
        return []
    points = np.concatenate([np.asarray(c).reshape(-1, 2) for c in contours])
    points = np.ascontiguousarray(points, dtype=np.int32)
    starts = np.zeros(len(contours) + 1, np.int64)
    np.cumsum([len(c) for c in contours], out=starts[1:])
    joints, ends = _fitting_kernels.fit_kernel(
        points,
        starts,
        as_uint8(skeleton),
        as_uint8(zones),
        float(segment_length),
        _BRANCH_COUNT,
    )
    starts = [0, *ends[:-1].tolist()]
    return [joints[a:b] for a, b in zip(starts, ends.tolist(), strict=True)]
