"""Step 2: skeletonization, a one-pixel-wide, 8-connected centreline of the mask.

Morphological thinning keeps every component connected. Thinning also leaves short
spurs where the border of the mask is ragged; those are removed so that the skeleton
has one branch per real branch of the cable.

The pixel loops run in compiled kernels (``_skeleton_kernels.py``, and the distance
transform in ``_shared_kernels.py``) that visit only the pixels that can change. The
thinning is Zhang and Suen's parallel thinning followed by one pass that removes the
corners of staircases (see :func:`skeletonize`); the distances are OpenCV's 5x5 chamfer
distances.
"""

from __future__ import annotations

import numpy as np

from service.perception import _shared_kernels, _skeleton_kernels
from service.perception.geometry import median


def _branch_count_table() -> np.ndarray:
    """Number of separate runs of skeleton pixels around a pixel, per 8-bit pattern.

    Bit k of a pattern is the neighbour k in circular order, clockwise from east
    (``_shared_kernels.RING_DR``, ``RING_DC``).

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


def _thinning_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Removal tables of :func:`skeletonize`, indexed by the pattern of the ring P2..P9.

    Bit k of a pattern is neighbour P(k+2) in Zhang and Suen's order: N, NE, E, SE,
    S, SW, W, NW.
    """
    offsets = ((-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))
    first = np.zeros(256, np.uint8)
    second = np.zeros(256, np.uint8)
    staircase = np.zeros(256, np.uint8)
    for pattern in range(256):
        ring = [(pattern >> k) & 1 for k in range(8)]
        count = sum(ring)
        # A(P1): the 0 -> 1 steps round the ring; exactly one means that removing the
        # pixel splits nothing and it is not inside a line.
        steps = sum(1 for k in range(8) if not ring[k] and ring[(k + 1) % 8])
        north, east, south, west = ring[0], ring[2], ring[4], ring[6]
        border = 2 <= count <= 6 and steps == 1
        # The first rule spares the north-west side, the second the south-east side.
        first[pattern] = border and not (east and south and (north or west))
        second[pattern] = border and not (north and west and (east or south))
        # A staircase corner: two set orthogonal neighbours that touch each other, all
        # set neighbours one 8-connected group (nothing is cut off), and an unset
        # orthogonal neighbour (no hole is opened).
        cells = [offsets[k] for k in range(8) if ring[k]]
        if count < 2 or (north and east and south and west):
            continue
        group, frontier = {cells[0]}, [cells[0]]
        while frontier:
            row, col = frontier.pop()
            for other in cells:
                if other not in group and max(abs(other[0] - row), abs(other[1] - col)) == 1:
                    group.add(other)
                    frontier.append(other)
        corner = (north and east) or (east and south) or (south and west) or (west and north)
        staircase[pattern] = corner and len(group) == count
    return first, second, staircase


_THIN_FIRST, _THIN_SECOND, _THIN_STAIRCASE = _thinning_tables()


def skeletonize(mask: np.ndarray) -> np.ndarray:
    """Step 2's thinning: a 2D mask to a one-pixel-wide, 8-connected skeleton.

    Zhang and Suen's parallel thinning [1]_: sub-iterations alternate between two
    rules until neither removes a pixel. A foreground pixel P1 with ring P2..P9 (N,
    NE, E, SE, S, SW, W, NW) is removed when it has 2 to 6 set neighbours, exactly one
    0 -> 1 step round the ring, and, in the first rule, not all of P2, P4, P6 nor all
    of P4, P6, P8 set (in the second, P2, P4, P8 and P2, P6, P8). Their result can
    still be two pixels thick where a line steps diagonally, so one raster pass then
    removes staircase corners: pixels with two set orthogonal neighbours that touch,
    whose set neighbours are one 8-connected group, and with an unset orthogonal
    neighbour. Both steps keep every component and every hole; outside the image is
    background.

    Parameters
    ----------
    mask : ndarray
        2D foreground mask (nonzero = foreground).

    Returns
    -------
    ndarray of bool

    References
    ----------
    .. [1] T. Y. Zhang and C. Y. Suen, "A fast parallel algorithm for thinning digital
       patterns", Communications of the ACM 27(3), 236-239, 1984.
    """
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"skeletonize needs a 2D mask, not {mask.ndim}D")
    skeleton = np.zeros(mask.shape, bool)
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return skeleton
    cols = np.flatnonzero(mask.any(axis=0))
    top, bottom, left, right = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    # One pixel of background round the box, so the kernel needs no bounds checks.
    padded = np.zeros((bottom - top + 2, right - left + 2), np.uint8)
    box = mask[top:bottom, left:right]
    # A boolean mask is copied as it is (True is 1): no comparison over the box.
    padded[1:-1, 1:-1] = box if mask.dtype == np.bool_ else box != 0
    _skeleton_kernels.thin_padded(padded, _THIN_FIRST, _THIN_SECOND, _THIN_STAIRCASE)
    skeleton[top:bottom, left:right] = padded[1:-1, 1:-1].view(np.bool_)
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
        if not _skeleton_kernels.remove_spurs_inplace(skeleton, float(spur_length), _BRANCH_COUNT):
            break
        # Thinned again as the boolean it is (0/1), which skeletonize copies as it is.
        skeleton = as_uint8(skeletonize(skeleton.view(np.bool_)))
    return skeleton.view(np.bool_)


def distance_transform(mask: np.ndarray) -> np.ndarray:
    """``cv2.distanceTransform(mask, cv2.DIST_L2, 5)``, bit for bit, in O(foreground).

    Float32 distance of each foreground pixel to the nearest background pixel centre
    (OpenCV's 5x5 chamfer approximation of the Euclidean distance); 0 on background.
    """
    return _shared_kernels.distance_transform(as_uint8(mask))


def estimate_radius(skeleton: np.ndarray, *, distance: np.ndarray) -> float:
    """Typical half width of the cables: the median distance from skeleton to border.

    Parameters
    ----------
    skeleton : ndarray of bool
    distance : ndarray
        ``distance_transform(mask)`` of the mask the skeleton was thinned from.
    """
    skeleton = as_uint8(skeleton)
    # Gathered at the skeleton's pixels (found 8 bytes at a time), not through a
    # boolean index over the whole image.
    indices = _shared_kernels.nonzero_flat(skeleton.reshape(-1))
    values = np.ascontiguousarray(distance).reshape(-1)[indices]
    if values.size == 0:
        return 0.0
    # The distance is to the nearest background pixel centre, half a pixel beyond
    # the border.
    return max(float(median(values)) - 0.5, 0.5)
