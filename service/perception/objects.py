"""Objects lying on the cables that a brightness threshold keeps with them.

Thresholding brightness keeps everything brighter than the background: a box, a lid or a
roll of tape lying on a cable is kept whole, joined to the cable that runs under it. Its
skeleton then draws lines through the object (a star, a cross) that fitting and merging
take for cable. Such an object is not a line of one width: it is a compact blob, much wider
than the cables that run into it. Two cables lying side by side or crossing at a shallow
angle make a region at most twice one cable's half width across (the widest disc inside
two crossing strips of half width ``w`` has radius ``2 w / (1 + sin(angle / 2))``), so a
blob whose inscribed disc is clearly wider than that, and which is not itself a long band,
is an object. It is taken out of the mask, leaving the cable cut at its border, as an
object of the background's colour leaves it.
"""

from __future__ import annotations

import cv2
import numpy as np

from service.perception import _segmentation_kernels, _shared_kernels
from service.perception.skeleton import as_uint8

# An object's inscribed radius is at least this many half widths of the widest line that
# leaves it (and of the picture's typical line): two lines together make up to 2, and the
# pixel grid and the cables' soft rims add up to a quarter more.
WIDER_THAN_LINES = 2.5
# An object is compact: its area is at most this many squares of its inscribed radius (a
# disc is pi, a square 4, a rectangle six times as long as it is wide 24), and its
# length at most this many (that rectangle's 12). A long band that wide is a thick
# cable or a lit edge, not an object lying on a cable.
COMPACT_AREA = 24.0
COMPACT_LENGTH = 12.0
# A disc this many half widths of the widest line beside an object fits in no line.
LINE_MARGIN = 1.25
# Below this typical half width (px) the mask holds no line to compare with.
MIN_HALF_WIDTH = 1.0


def _distance(mask: np.ndarray) -> np.ndarray:
    """Distance of each mask pixel to the nearest pixel off the mask (OpenCV's 5 x 5
    chamfer, within 2 % of the Euclidean: plenty for widths compared 2.5 times over)."""
    return cv2.distanceTransform(mask.view(np.uint8), cv2.DIST_L2, 5)


def distance_and_ridges(mask: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, float]]:
    """``distance_transform(mask)``, and its ridges as :func:`typical_half_width` reads them.

    One pass over the image for the mask's pixels serves both (the chamfer pass's
    row buffers hold the distances the ridge test compares).

    Returns
    -------
    distance : ndarray of float32
        ``(H, W)``, :func:`service.perception.skeleton.distance_transform` of ``mask``.
    ridges : (ndarray of float32, float)
        The distances at the middle lines' pixels (in raster order) and the largest
        distance on the mask, for :func:`without_objects`.
    """
    distance, values, largest = _shared_kernels.distance_and_ridges(as_uint8(mask))
    return distance, (values, float(largest))


def typical_half_width(ridges: tuple[np.ndarray, float]) -> tuple[float, float]:
    """The median distance to the border along the mask's middle lines (0 when none),
    and the largest distance on the mask.

    Cables are long and objects few, so their middle lines are mostly the cables'. A
    middle line's pixel is one no farther from the border than any of its eight
    neighbours; they are found with the distances (:func:`distance_and_ridges`), at
    the mask's own pixels only (a few per cent of a photograph), not over the whole
    picture (it runs on every photograph the brightness path segments).

    Parameters
    ----------
    ridges : (ndarray of float32, float)
        The middle lines' distances and the largest distance on the mask, from
        :func:`distance_and_ridges`.
    """
    values, largest = ridges
    values = values[values >= MIN_HALF_WIDTH]
    return (float(np.median(values)) if values.size else 0.0), float(largest)


def object_blobs(
    mask: np.ndarray,
    distance: np.ndarray | None = None,
    ridges: tuple[np.ndarray, float] | None = None,
) -> np.ndarray:
    """The parts of a foreground mask that are objects, not lines.

    A candidate is the union of every disc inside the mask of radius
    :data:`WIDER_THAN_LINES` typical half widths (the mask's opening by such a disc:
    nothing of a line of cables, crossing or lying together, survives it). Each
    connected candidate is an object when its own inscribed radius is also
    :data:`WIDER_THAN_LINES` times the half width of the widest line next to it (a
    thicker cable than the picture's typical one is compared with itself), it is
    compact (:data:`COMPACT_AREA`, :data:`COMPACT_LENGTH`) and it does not run on
    beyond what its disc centres reach. Its corners, which the disc does not reach,
    are added (:func:`_with_corners`).

    Parameters
    ----------
    mask : ndarray of bool
        ``(H, W)`` foreground mask.
    distance, ridges : optional
        ``distance_and_ridges(mask)`` when the caller has them (both, or they are
        found here).

    Returns
    -------
    ndarray of bool
        ``(H, W)``, True on the pixels of the objects found.

    Examples
    --------
    >>> import numpy as np
    >>> mask = np.zeros((80, 160), bool)
    >>> mask[37:43, :] = True            # a cable 6 px wide ...
    >>> mask[20:60, 60:100] = True       # ... under a box 40 px square
    >>> blobs = object_blobs(mask)
    >>> bool(blobs[40, 80]), bool(blobs[40, 10]), bool(blobs[40, 150])
    (True, False, False)
    """
    found = _objects_found(mask, distance, ridges)
    return np.zeros(np.shape(mask), bool) if found is None else found


def _objects_found(
    mask: np.ndarray, distance: np.ndarray | None, ridges: tuple[np.ndarray, float] | None
) -> np.ndarray | None:
    """:func:`object_blobs`, or None when it finds no object (the common case, told
    without an image-sized array to make and scan)."""
    mask = np.ascontiguousarray(mask, dtype=bool)
    found = None
    if distance is None or ridges is None:
        # The same values, compiled, over the foreground only.
        distance, ridges = distance_and_ridges(mask)
    typical, largest = typical_half_width(ridges)
    reach = WIDER_THAN_LINES * typical
    # No disc of the opening fits anywhere: the common case, decided without a pass
    # over the whole picture.
    if typical < MIN_HALF_WIDTH or largest < reach:
        return found
    core = distance >= reach
    # Each disc centre's region is worked on in a window around it: the opening's
    # discs, the lines beside them within the blob's radius, and room for the
    # distances there to see the mask beyond.
    count, core_labels, stats, _ = cv2.connectedComponentsWithStats(
        core.view(np.uint8), connectivity=8
    )
    height, width = mask.shape
    for label in range(1, count):
        left, top, box_width, box_height, _ = (int(v) for v in stats[label])
        centres = core_labels[top : top + box_height, left : left + box_width] == label
        radius = float(distance[top : top + box_height, left : left + box_width][centres].max())
        margin = int(np.ceil(2.0 * reach + radius)) + 2
        y0, y1 = max(top - margin, 0), min(top + box_height + margin, height)
        x0, x1 = max(left - margin, 0), min(left + box_width + margin, width)
        window = mask[y0:y1, x0:x1]
        # The opening: every mask pixel within ``reach`` of a centre of such a disc.
        candidates = window & (_distance(~core[y0:y1, x0:x1]) < reach)
        _, blob_labels = cv2.connectedComponents(candidates.view(np.uint8), connectivity=8)
        mine = core_labels[y0:y1, x0:x1] == label
        blob = blob_labels == blob_labels[mine][0]
        # An object's blob lies within ``reach`` of its disc centres; one that runs on
        # out of the window, further than the centres' own blob could reach, is a band
        # (a thick cable whose middle, hovering about ``reach``, breaks into pieces).
        if _leaves_window(blob, (y0, y1, x0, x1), (height, width)):
            continue
        area = int(np.count_nonzero(blob))
        if area > COMPACT_AREA * radius * radius:
            continue
        # Nor longer: a thick cable that a round object lies on is a long band with
        # a wide place in it.
        (_, _), sides, _ = cv2.minAreaRect(cv2.findNonZero(blob.view(np.uint8)))
        if max(sides) > COMPACT_LENGTH * radius:
            continue
        # The lines beside it: the mask's half width (its distance to the border, as
        # before anything was cut out) on what is left once every candidate is out,
        # within the blob's radius of it. A cable running in is its own half width
        # right up to the blob; a thick band going on, cut into blobs where its middle
        # hovers about ``reach``, is as wide as the blob.
        beside = (_distance(~blob) <= radius) & window & ~candidates
        widths = distance[y0:y1, x0:x1][beside]
        widest = float(widths.max()) if widths.size else 0.0
        if radius < WIDER_THAN_LINES * widest:
            continue
        line = max(widest, typical)
        if found is None:
            found = np.zeros(mask.shape, bool)
        found[y0:y1, x0:x1] |= _with_corners(blob, window, reach, line)
    return found


def _leaves_window(
    blob: np.ndarray, window: tuple[int, int, int, int], shape: tuple[int, int]
) -> bool:
    """Does ``blob`` reach a side of its window that is not the picture's border?"""
    y0, y1, x0, x1 = window
    height, width = shape
    return bool(
        (y0 > 0 and blob[0].any())
        or (y1 < height and blob[-1].any())
        or (x0 > 0 and blob[:, 0].any())
        or (x1 < width and blob[:, -1].any())
    )


def _with_corners(blob: np.ndarray, mask: np.ndarray, reach: float, widest: float) -> np.ndarray:
    """An object's outline: its blob, with the corners the opening's disc rounded off.

    The disc of radius ``reach`` rolling inside a right-angled corner stays up to
    ``(sqrt(2) - 1) * reach`` short of it, a wedge left on the mask, hung on the side of
    a cable that runs in close to the corner. A smaller disc, a quarter wider than the
    widest line beside the object (which no line can hold), rolls further into the
    corners; what it reaches within that distance of the blob is the object's too.

    Parameters
    ----------
    blob : ndarray of bool
        ``(H, W)`` the object's part the opening's disc reached.
    mask : ndarray of bool
        ``(H, W)`` the foreground mask around it.
    reach : float
        The opening disc's radius (px).
    widest : float
        The half width of the widest line beside the object (px).

    Returns
    -------
    ndarray of bool
        ``(H, W)``, the blob and its corners.
    """
    radius = LINE_MARGIN * widest
    side = 2 * int(np.ceil(radius)) + 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))
    rolled = cv2.morphologyEx(mask.view(np.uint8), cv2.MORPH_OPEN, disc).view(np.bool_)
    near = _distance(~blob) <= (np.sqrt(2.0) - 1.0) * reach + 1.0
    return blob | (rolled & near)


def without_objects(
    mask: np.ndarray,
    min_component_area: int,
    distance: np.ndarray | None = None,
    ridges: tuple[np.ndarray, float] | None = None,
) -> np.ndarray:
    """The mask less the objects lying on the cables (:func:`object_blobs`).

    What an object leaves behind that is no cable (its corners, which the disc of the
    opening does not reach) is removed with the specks: components under
    ``min_component_area`` px.

    Parameters
    ----------
    mask : ndarray of bool
        ``(H, W)`` foreground mask.
    min_component_area : int
        As :func:`service.perception.segmentation.clean_mask`.
    distance, ridges : optional
        ``distance_and_ridges(mask)`` when the caller has them (the skeleton step needs
        the distances too: computed once, they serve both when no object is found).

    Returns
    -------
    ndarray of bool
        A new mask; ``mask`` is returned itself when it holds no object.
    """
    blobs = _objects_found(mask, distance, ridges)
    # A blob found is never empty (it holds its disc centres).
    if blobs is None:
        return mask
    cleaned = np.ascontiguousarray(mask & ~blobs).view(np.uint8)
    if min_component_area > 0:
        _segmentation_kernels.remove_small_components(cleaned, int(min_component_area))
    return cleaned.view(np.bool_)
