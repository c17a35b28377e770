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

import cv2
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
    return thin_listed(mask)[0]


def thin_listed(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`skeletonize`, and the flat indices of the skeleton's pixels in raster order.

    The thinning lists the skeleton's pixels as it makes them, so the steps after it
    (:func:`estimate_radius`, :func:`spurs_removed`) need not scan the image for them.

    Returns
    -------
    skeleton : ndarray of bool
    pixels : ndarray of int64
        ``np.flatnonzero(skeleton)``.
    """
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"skeletonize needs a 2D mask, not {mask.ndim}D")
    skeleton = np.zeros(mask.shape, bool)
    if mask.size == 0:
        return skeleton, np.zeros(0, np.int64)
    # The foreground's bounding box: OpenCV's, of an 8-bit image's nonzero pixels, takes
    # half the time of the two reductions over rows and columns.
    nonzero = mask.view(np.uint8) if mask.dtype == np.bool_ else (mask != 0).view(np.uint8)
    left, top, box_width, box_height = cv2.boundingRect(np.ascontiguousarray(nonzero))
    if box_width == 0:
        return skeleton, np.zeros(0, np.int64)
    bottom, right = top + box_height, left + box_width
    # One pixel of background round the box, so the kernel needs no bounds checks.
    padded = np.zeros((bottom - top + 2, right - left + 2), np.uint8)
    box = mask[top:bottom, left:right]
    # A boolean mask is copied as it is (True is 1): no comparison over the box.
    padded[1:-1, 1:-1] = box if mask.dtype == np.bool_ else box != 0
    listed = _skeleton_kernels.thin_padded(padded, _THIN_FIRST, _THIN_SECOND, _THIN_STAIRCASE)
    # From the padded box's flat indices to the image's (the order is kept).
    rows, cols = np.divmod(listed, padded.shape[1])
    pixels = (rows + (top - 1)) * mask.shape[1] + (cols + (left - 1))
    # Written at its pixels: a few thousand, not the box's hundreds of thousands.
    skeleton.reshape(-1)[pixels] = True
    return skeleton, pixels


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
    return spurs_removed(skeleton, spur_length, passes=passes)[0]


def spurs_removed(
    skeleton: np.ndarray,
    spur_length: float,
    pixels: np.ndarray | None = None,
    passes: int = 2,
) -> tuple[np.ndarray, bool, np.ndarray]:
    """:func:`remove_spurs`, whether it removed anything, and the pixels it left.

    Parameters
    ----------
    skeleton : ndarray of bool
    spur_length : float
    pixels : ndarray of int64, optional
        ``np.flatnonzero(skeleton)`` when the caller has it (:func:`thin_listed`).
    passes : int

    Returns
    -------
    pruned : ndarray of bool
        A new array; equal to ``skeleton`` when nothing was removed.
    removed : bool
    pruned_pixels : ndarray of int64
        ``np.flatnonzero(pruned)``.
    """
    skeleton = as_uint8(skeleton).copy()
    if pixels is None:
        pixels = _shared_kernels.nonzero_flat(skeleton.reshape(-1))
    removed = False
    for _ in range(passes):
        if not _skeleton_kernels.remove_spurs_inplace(
            skeleton, pixels, float(spur_length), _BRANCH_COUNT
        ):
            break
        removed = True
        # Thinned again as the boolean it is (0/1), which thin_listed copies as it is.
        thinned, pixels = thin_listed(skeleton.view(np.bool_))
        skeleton = as_uint8(thinned)
    return skeleton.view(np.bool_), removed, pixels


def distance_transform(mask: np.ndarray) -> np.ndarray:
    """``cv2.distanceTransform(mask, cv2.DIST_L2, 5)``, bit for bit, in O(foreground).

    Float32 distance of each foreground pixel to the nearest background pixel centre
    (OpenCV's 5x5 chamfer approximation of the Euclidean distance); 0 on background.
    """
    return _shared_kernels.distance_transform(as_uint8(mask))


def estimate_radius(
    skeleton: np.ndarray, *, distance: np.ndarray, pixels: np.ndarray | None = None
) -> float:
    """Typical half width of the cables: the median distance from skeleton to border.

    Parameters
    ----------
    skeleton : ndarray of bool
    distance : ndarray
        ``distance_transform(mask)`` of the mask the skeleton was thinned from.
    pixels : ndarray of int64, optional
        ``np.flatnonzero(skeleton)`` when the caller has it (:func:`thin_listed`).
    """
    if pixels is None:
        # Gathered at the skeleton's pixels (found 8 bytes at a time), not through a
        # boolean index over the whole image.
        pixels = _shared_kernels.nonzero_flat(as_uint8(skeleton).reshape(-1))
    values = np.ascontiguousarray(distance).reshape(-1)[pixels]
    if values.size == 0:
        return 0.0
    # The distance is to the nearest background pixel centre, half a pixel beyond
    # the border.
    return max(float(median(values)) - 0.5, 0.5)


def short_blobs_kept(skeleton: np.ndarray, pruned: np.ndarray, spur_length: float) -> np.ndarray:
    """``pruned`` (``skeleton`` after :func:`remove_spurs`) with the longest path back in
    every component of ``skeleton`` that spur removal left shorter than a spur.

    Spur removal cuts the branches that run from a tip to a junction in fewer than
    ``spur_length`` px, each as a side branch of a longer line. A blob no longer than a
    few cable widths (a stretch of cable seen between two objects, cut at both ends)
    thins to a star: a short middle line with a fork at each cut corner, every branch
    shorter than a spur. Removing them all leaves the blob a pixel or none, and the
    piece of cable it shows is lost: a star of spurs is no side branch of anything,
    but a short component in its own right, which the size filter of the segmentation
    has already let through. Its longest path (tip to tip) is its line; the direction
    of a piece that short is read from the blob's sides (:func:`.short_pieces.ends_of_stubs`).

    Each window looked at is the one round a removed pixel at twice a spur's length:
    a component of spurs fits in it, and one that reaches its border is longer (as is,
    conservatively, one reaching the picture's edge).
    """
    lost = skeleton & ~pruned
    points = cv2.findNonZero(lost.view(np.uint8))
    if points is None:
        return pruned
    height, width = skeleton.shape
    reach = int(np.ceil(2.0 * spur_length)) + 1
    done = np.zeros_like(lost)
    kept = pruned
    for x, y in points.reshape(-1, 2).tolist():
        if done[y, x]:
            continue
        x0, y0 = max(x - reach, 0), max(y - reach, 0)
        x1, y1 = min(x + reach + 1, width), min(y + reach + 1, height)
        window = skeleton[y0:y1, x0:x1]
        _, labels = cv2.connectedComponents(window.view(np.uint8), connectivity=8)
        component = labels == labels[y - y0, x - x0]
        done[y0:y1, x0:x1] |= component
        # Reaching the window's border (or the picture's: left as it is) is a longer line.
        edge = component[[0, -1]].any() or component[:, [0, -1]].any()
        if edge or np.count_nonzero(component & pruned[y0:y1, x0:x1]) >= spur_length:
            continue  # a longer line: its spurs stay cut
        path = _longest_path(np.argwhere(component))
        if kept is pruned:
            kept = pruned.copy()
        kept[path[:, 0] + y0, path[:, 1] + x0] = True
    return kept


def _longest_path(pixels: np.ndarray) -> np.ndarray:
    """The (row, col) pixels of the longest path, in 8-connected steps, through the
    8-connected set ``pixels`` ((N, 2) row, col): from the pixel farthest from any
    one to the pixel farthest from it (exact on a tree, as a thinned blob is)."""
    index = {(int(r), int(c)): k for k, (r, c) in enumerate(pixels.tolist())}
    steps = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]

    def walk(start: int) -> tuple[int, list[int]]:
        parent = {start: -1}
        queue, head = [start], 0
        while head < len(queue):
            r, c = pixels[queue[head]].tolist()
            head += 1
            for dr, dc in steps:
                k = index.get((r + dr, c + dc))
                if k is not None and k not in parent:
                    parent[k] = queue[head - 1]
                    queue.append(k)
        return queue[-1], parent

    far, _ = walk(0)
    other, parent = walk(far)
    path = [other]
    while parent[path[-1]] >= 0:
        path.append(parent[path[-1]])
    return pixels[path]
