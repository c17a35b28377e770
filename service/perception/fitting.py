"""Step 4: fitting, chains of ``l_s``-long segments along each contour.

The walk follows a contour and emits a joint each time it is ``l_s`` pixels from the
previous joint. A chain ends at every branch tip (where the contour turns back) and
wherever the walk enters a junction zone: near a crossing or a branch the skeleton
bends towards the junction and says nothing reliable about the strands, so those
pixels are left for the merging step to bridge with a natural curve.
"""

from __future__ import annotations

import cv2
import numpy as np

from service.perception import _kernels
from service.perception.skeleton import _BRANCH_COUNT, as_uint8

# Skeleton branches between two junction zones shorter than this many cable radii
# are the bridge the thinning draws through one crossing.
BRIDGE_RADII = 4.0


def junction_zones(skeleton: np.ndarray, radius: float) -> np.ndarray:
    """Pixels near skeleton junctions, where strands meet or cross.

    A zone is a disc of ``1.5 * radius`` around each junction pixel, plus every short
    skeleton branch that joins two zones (the bridge the thinning draws through the
    middle of an X crossing).

    Parameters
    ----------
    skeleton : ndarray of bool
    radius : float
        Typical cable half width in pixels.

    Returns
    -------
    ndarray of bool
    """
    zone_radius = max(2, round(1.5 * radius))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * zone_radius + 1,) * 2)
    zones, _ = _kernels.junction_zones_kernel(
        as_uint8(skeleton), disc, BRIDGE_RADII * radius, _BRANCH_COUNT
    )
    return zones.view(np.bool_)


def walk_joints(pixels: np.ndarray, segment_length: float) -> np.ndarray:
    """Joints along an ordered pixel run, each ``segment_length`` from the previous one.

    The first and last pixels are always joints, so the last segment may be shorter.

    Parameters
    ----------
    pixels : ndarray
        ``(N, 2)`` ordered ``[x, y]`` pixels.
    segment_length : float

    Returns
    -------
    ndarray
        ``(K, 2)`` ``float64`` joints, ``K >= 2`` when ``N >= 2``.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    joints = [pixels[0]]
    start = pixels[0]
    limit_sq = segment_length * segment_length
    for point in pixels[1:]:
        delta = point - start
        if delta[0] * delta[0] + delta[1] * delta[1] >= limit_sq:
            joints.append(point)
            start = point
    if len(pixels) > 1 and not np.array_equal(joints[-1], pixels[-1]):
        joints.append(pixels[-1])
    return np.array(joints)


def split_contour(contour: np.ndarray, is_tip: np.ndarray, in_zone: np.ndarray):
    """Cut a closed contour into runs that end at tips and stop short of junction zones.

    Parameters
    ----------
    contour : ndarray
        ``(N, 2)`` ``[x, y]`` pixels of one closed border.
    is_tip, in_zone : ndarray of bool
        Per contour pixel.

    Returns
    -------
    list of ndarray
        Runs of pixels, each in walking order.
    """
    n = len(contour)
    breaks = np.flatnonzero(is_tip | in_zone)
    if len(breaks) == 0:
        # A closed loop with no tip or junction: one run around it.
        return [contour]
    # Start the cyclic walk at a break so that no run wraps around the array end.
    order = np.roll(np.arange(n), -int(breaks[0]))
    runs: list[np.ndarray] = []
    current: list[int] = []
    for index in order:
        if in_zone[index]:
            if len(current) > 1:
                runs.append(contour[current])
            current = []
        elif is_tip[index]:
            current.append(index)
            if len(current) > 1:
                runs.append(contour[current])
            current = [index]
        else:
            current.append(index)
    if len(current) > 1:
        first_break = order[0]
        if is_tip[first_break] and not in_zone[first_break]:
            current.append(first_break)
        runs.append(contour[current])
    return runs


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
    Runs :func:`split_contour` and :func:`walk_joints` over all contours in one
    compiled loop (``_kernels.fit_kernel``), with the same result.
    """
    if not contours:
        return []
    points = np.concatenate([np.asarray(c).reshape(-1, 2) for c in contours])
    points = np.ascontiguousarray(points, dtype=np.int32)
    starts = np.zeros(len(contours) + 1, np.int64)
    np.cumsum([len(c) for c in contours], out=starts[1:])
    joints, ends = _kernels.fit_kernel(
        points,
        starts,
        as_uint8(skeleton),
        as_uint8(zones),
        float(segment_length),
        _BRANCH_COUNT,
    )
    starts = [0, *ends[:-1].tolist()]
    return [joints[a:b] for a, b in zip(starts, ends.tolist(), strict=True)]
