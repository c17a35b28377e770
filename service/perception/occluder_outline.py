"""The outline of an object of the ground's own colour over a cable's hidden turn.

A sheet of the same paper or a flap of the same cloth laid over a cable shows little of
itself: its colour is the ground's. What it does show is its border: a real sheet casts
a thin shadow or shows an edge, a rim a few pixels wide darker than the sheet inside it.
At one cut that rim is a step of a few lightness units over pixel noise of as much
(BENCHMARKS, "the occluder's border beside the cut"); averaged along a whole straight
side, tens of pixels long, the noise falls several times while the rim does not.

A cable that doubles back under such an object leaves two cut ends side by side on the
object's near side. Where the object is a rectangle, that side runs through both cuts,
its far side parallel to it, and its two other sides square to both, beyond the two
strands. :func:`rectangle_over_turn` reads the four from the image's brightness averaged
along lines in those directions, and gives the rectangle only when the rim of every side
stands clearly out of the brightness's own variation across the lines
(:data:`RIM_CONTRAST`): otherwise nothing (an object whose outline the image does not
show, a disc, or open ground).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import cv2
import numpy as np

from service.perception.appearance import off_mask, unlike_background
from service.perception.geometry import rotated
from service.perception.turn_joins import bends_as_a_cable

RIM_WIDTH = 2.0
"""How far (px) inside an object's border its rim darkens it: the edge, or the shadow
its thickness casts, a pixel or two wide."""
INTERIOR_WIDTH = 4.0
"""How far (px) past the rim the object's own brightness is read to compare the rim with."""
BIN = 0.5
"""Width (px) of the bins the brightness is averaged in across a line: the side's
position to half a pixel."""
RIM_CONTRAST = 6.0
"""How many times the typical variation of the rim statistic across the lines searched
(its median absolute deviation, scaled to a standard deviation) the darkening of a side
must reach to count as found: a side seen, not the best of many lines through noise."""
RIM_SHARE = 0.04
"""The least darkening of a rim against the object inside it, as a share of the
object's brightness: a shadow or an edge, not a ripple of the ground's texture."""
TILTS = np.radians(np.arange(-16.0, 16.1, 2.0))
"""Tilts (radians) of the near side tried about the line through the two cuts: the cut
points are the strands' skeleton tips, each a pixel or two off the border."""
NEAR_REACH_RADII = 2.5
"""How far (cable radii) from the cuts' line the near side is searched: a skeleton
stops up to about a radius short of a square cut."""
NEAR_SIDE_RADII = 5.0
"""How far (cable radii) past the outer cut the near side is read along: past the
strands (which cover the line between them), within the object's side."""
DEPTH_RADII = (2.5, 11.0)
"""How deep (cable radii past the near side) the far side is searched: room for the
turn's tube (a cable bends no tighter than two radii), up to a large sheet's depth."""
SIDE_REACH_RADII = 12.0
"""How far (cable radii) past the outer strand each other side is searched."""
CUT_CLEAR_RADII = 2.0
"""Samples of a turn's curve within this many cable radii of either cut, or within one
radius of the cuts' line, are not held to lie under the outline: there the strands
pass under the object's near side, their tubes straddling it whatever the turn."""


def turns_within_outlines(
    image: np.ndarray, mask: np.ndarray, ends: Sequence
) -> Callable[[int, int, np.ndarray, Callable[[], Sequence[np.ndarray]]], np.ndarray | None]:
    """For the turns seen on their cuts alone (:func:`.turn_joins.turn_joins`'
    ``within_outline``): a callable ``(i, j, compact, curves)`` giving, where the image
    shows the rectangle of an object of the ground's colour over the turn between ends
    ``i`` and ``j`` (:func:`rectangle_over_turn`), the curve of ``curves()`` (called
    only then: building every curve costs more than reading the outline) whose depth
    lies in the middle of what the object allows (:func:`middle_depth_within`); else
    None. The image's brightness is read once, on the first call."""
    brightness: list[np.ndarray] = []

    def within(i: int, j: int, compact: np.ndarray, curves: Callable[[], Sequence[np.ndarray]]):
        first, second = ends[i], ends[j]
        inward = np.asarray(first.direction, np.float64) + np.asarray(second.direction, np.float64)
        length = float(np.hypot(*inward))
        if length < 1e-6:
            return None
        inward = inward / length
        cable = 0.5 * (first.width + second.width)
        if cable <= 0:
            return None
        if not brightness:
            brightness.append(np.asarray(image, np.float64).mean(axis=2))
        outline = rectangle_over_turn(
            brightness[0], mask, first.position, second.position, inward, cable
        )
        if outline is None or _unlike_the_ground(image, mask, outline, (first, second), cable):
            return None
        return middle_depth_within(
            compact, curves(), first.position, second.position, inward, cable, outline
        )

    return within


INTERIOR_SPAN = np.linspace(0.2, 0.8, 7)
"""Where across and along a rectangle read over a turn its inside is sampled (shares of
its sides): clear of its rims and of the strands entering at its near side."""


def _unlike_the_ground(image, mask, outline, ends, cable_radius) -> bool:
    """Whether most of the inside of the rectangle ``outline`` (corners in order round it)
    off the foreground looks unlike the open ground beside the two ``ends``' cables
    (:func:`.appearance.unlike_background`): an object of another colour, whose border
    the rim reading finds as well. Such an object is read by the turn pass's own object
    test (its outline, ``turn_out_of_view``); where that test did not pass on the turn,
    the strands do not turn round under it as a sheet over a turn does (they pass out
    under its sides), and its depth does not bound the turn."""
    u, v = np.meshgrid(INTERIOR_SPAN, INTERIOR_SPAN)
    u, v = u.ravel()[:, None], v.ravel()[:, None]
    c0, c1, c2, c3 = outline
    points = (1 - u) * (1 - v) * c0 + u * (1 - v) * c1 + u * v * c2 + (1 - u) * v * c3
    points = off_mask(points, mask)
    if not len(points):
        return False
    return bool(np.mean(unlike_background(image, mask, points, ends, cable_radius)) > 0.5)


def middle_depth_within(
    compact: np.ndarray,
    curves: Sequence[np.ndarray],
    first_cut: np.ndarray,
    second_cut: np.ndarray,
    inward: np.ndarray,
    cable_radius: float,
    outline: np.ndarray,
) -> np.ndarray | None:
    """Of ``curves``, the one whose depth lies nearest the middle of what the outline
    allows: between ``compact``'s (the most compact curve the cuts' evidence passes on)
    and the deepest whose whole tube stays under the outline.

    Nothing in the image says where under the object the turn lies; the object only
    bounds it. The middle of the depths it allows halves the worst error either bound
    would make (the most compact curve alone, the turn pass's choice where no object
    is seen, falls short of the true apex by 1-4 radii in most of the turns it misses).

    Parameters
    ----------
    compact : ndarray (N, 2)
        The most compact curve the evidence passes on.
    curves : sequence of ndarray (M, 2)
        Every curve built for the turn (:func:`.turn_joins.hidden_turn_curves`, led in).
    first_cut, second_cut, inward : array_like (2,)
        The two ends' tips and the direction (unit) into the object.
    cable_radius : float
        The cable's half width (px).
    outline : ndarray (K, 2)
        The object's convex outline (:func:`rectangle_over_turn`).

    Returns
    -------
    ndarray or None
        The curve; None when no curve that bends as a cable lies under the outline,
        or none deeper than ``compact``.
    """
    first_cut = np.asarray(first_cut, np.float64)
    second_cut = np.asarray(second_cut, np.float64)
    inward = np.asarray(inward, np.float64)
    middle = 0.5 * (first_cut + second_cut)

    def depth(curve):
        return float(((curve - middle) @ inward).max())

    def under_outline(curve):
        clear = CUT_CLEAR_RADII * cable_radius
        held = (
            (np.hypot(*(curve - first_cut).T) > clear)
            & (np.hypot(*(curve - second_cut).T) > clear)
            & ((curve - middle) @ inward > cable_radius)
        )
        inside = -_signed_distance(outline, curve[held])
        return bool((inside >= cable_radius).all()) and bends_as_a_cable(curve, cable_radius)

    shallowest = depth(compact)
    allowed = [(depth(curve), curve) for curve in curves if under_outline(curve)]
    if not allowed:
        return None
    deepest = max(value for value, _ in allowed)
    if deepest <= shallowest:
        return None
    target = 0.5 * (shallowest + deepest)
    return min(allowed, key=lambda item: abs(item[0] - target))[1]


def _signed_distance(outline: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The largest signed distance (px) of each point to the convex outline's sides'
    lines: <= 0 inside, minus the distance to the border."""
    edges = np.roll(outline, -1, axis=0) - outline
    normals = np.column_stack([edges[:, 1], -edges[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    # Outward, whichever way round the corners run.
    normals *= np.sign(np.einsum("ij,ij->i", outline - outline.mean(axis=0), normals))[:, None]
    offsets = np.einsum("ij,ij->i", normals, outline)
    return (np.asarray(points, np.float64).reshape(-1, 2) @ normals.T - offsets).max(axis=1)


def rectangle_over_turn(
    brightness: np.ndarray,
    foreground: np.ndarray,
    first_cut: np.ndarray,
    second_cut: np.ndarray,
    inward: np.ndarray,
    cable_radius: float,
) -> np.ndarray | None:
    """The rectangle of an object of the ground's colour hiding a cable's turn between
    two cut ends, read from its rim, or None where the image does not clearly show one.

    Parameters
    ----------
    brightness : ndarray (H, W) float
        The image's brightness (a linear mean of its channels: a rim darkens it by a
        share, whatever the ground's brightness).
    foreground : ndarray (H, W) bool
        The cables' mask: their pixels (and a pixel round them, for their shading)
        are left out.
    first_cut, second_cut : array_like (2,)
        The two ends' tips (x, y), where the two strands pass under the object.
    inward : array_like (2,)
        The direction (unit) from the cuts into the object: the mean of the two ends'
        outward directions.
    cable_radius : float
        The cable's half width (px): the scale of every search.

    Returns
    -------
    ndarray (4, 2) or None
        The rectangle's corners (x, y), in order round it; None unless the rims of all
        four sides stand out (:data:`RIM_CONTRAST`, :data:`RIM_SHARE`).
    """
    first_cut = np.asarray(first_cut, np.float64)
    second_cut = np.asarray(second_cut, np.float64)
    chord = second_cut - first_cut
    span = float(np.hypot(*chord))
    if span < 1e-6 or cable_radius <= 0:
        return None
    along0 = chord / span
    normal0 = np.array([-along0[1], along0[0]])
    if normal0 @ np.asarray(inward, np.float64) < 0:
        normal0 = -normal0
    origin = 0.5 * (first_cut + second_cut)
    reach_along = 0.5 * span + SIDE_REACH_RADII * cable_radius + RIM_WIDTH + INTERIOR_WIDTH
    near_reach = NEAR_REACH_RADII * cable_radius
    deepest = DEPTH_RADII[1] * cable_radius + RIM_WIDTH + INTERIOR_WIDTH
    samples = _window(brightness, foreground, origin, reach_along, near_reach, deepest)
    if samples is None:
        return None
    points, values = samples

    # The near side: the tilt and offset whose rim (the object inside, on the far side
    # of the line from the cuts' ground) stands out most.
    best = None
    for tilt in TILTS:
        normal = rotated(normal0, tilt)
        along = np.array([normal[1], -normal[0]])
        depth, lateral = points @ normal, points @ along
        level = np.abs(lateral) <= 0.5 * span + NEAR_SIDE_RADII * cable_radius
        found = _rim(depth[level], values[level], -near_reach, near_reach, +1)
        if found is not None and (best is None or found[1] > best[1]):
            best = (found[0], found[1], normal, along)
    if best is None:
        return None
    near, _, normal, along = best
    depth, lateral = points @ normal, points @ along
    cuts = np.sort([(first_cut - origin) @ along, (second_cut - origin) @ along])

    lo, hi = near + DEPTH_RADII[0] * cable_radius, near + DEPTH_RADII[1] * cable_radius
    inside_along = (lateral >= cuts[0] - cable_radius) & (lateral <= cuts[1] + cable_radius)
    far = _rim(depth[inside_along], values[inside_along], lo, hi, -1)
    if far is None:
        return None
    far_side = far[0]
    between = (depth > near + RIM_WIDTH) & (depth < far_side - RIM_WIDTH)
    outer = SIDE_REACH_RADII * cable_radius
    left = _rim(lateral[between], values[between], cuts[0] - outer, cuts[0] - cable_radius, +1)
    right = _rim(lateral[between], values[between], cuts[1] + cable_radius, cuts[1] + outer, -1)
    if left is None or right is None:
        return None
    corners = [(left[0], near), (right[0], near), (right[0], far_side), (left[0], far_side)]
    return np.array([origin + s * along + d * normal for s, d in corners])


def _window(brightness, foreground, origin, reach_along, near_reach, deepest):
    """The pixels (offsets from ``origin``) and brightness within reach of the cuts,
    off the cables and the pixel round them; None when too few."""
    height, width = brightness.shape
    reach = float(np.hypot(reach_along, max(near_reach, deepest)))
    x0, y0 = (int(max(np.floor(c - reach), 0)) for c in origin)
    x1 = int(min(np.ceil(origin[0] + reach), width - 1))
    y1 = int(min(np.ceil(origin[1] + reach), height - 1))
    if x1 - x0 < 4 or y1 - y0 < 4:
        return None
    near_cable = cv2.dilate(
        foreground[y0 : y1 + 1, x0 : x1 + 1].astype(np.uint8), np.ones((3, 3), np.uint8)
    )
    rows, cols = np.nonzero(near_cable == 0)
    if len(rows) < 100:
        return None
    points = np.column_stack([cols + x0 - origin[0], rows + y0 - origin[1]])
    return points, brightness[rows + y0, cols + x0].astype(np.float64)


def _rim(position, values, lo, hi, inside):
    """The border position in [lo, hi] whose rim (darker over :data:`RIM_WIDTH` on
    the ``inside`` side, +1 towards larger positions, than the :data:`INTERIOR_WIDTH`
    past it) stands out most, and how many typical deviations it does; None unless
    it stands out clearly (:data:`RIM_CONTRAST`, :data:`RIM_SHARE`)."""
    pad = RIM_WIDTH + INTERIOR_WIDTH
    start = lo - pad
    count = int(np.ceil((hi - lo + 2 * pad) / BIN)) + 1
    index = np.floor((position - start) / BIN).astype(np.int64)
    keep = (index >= 0) & (index < count)
    sums = np.bincount(index[keep], values[keep], count)
    counts = np.bincount(index[keep], minlength=count).astype(np.float64)
    rim_bins, interior_bins = round(RIM_WIDTH / BIN), round(INTERIOR_WIDTH / BIN)
    cumulative_sums = np.concatenate([[0.0], np.cumsum(sums)])
    cumulative_counts = np.concatenate([[0.0], np.cumsum(counts)])

    def band_mean(first, length):
        total = cumulative_sums[first + length] - cumulative_sums[first]
        number = cumulative_counts[first + length] - cumulative_counts[first]
        with np.errstate(invalid="ignore", divide="ignore"):
            return total / number, number

    borders = np.arange(rim_bins + interior_bins, count - rim_bins - interior_bins)
    if inside > 0:
        rim, rim_count = band_mean(borders, rim_bins)
        interior, interior_count = band_mean(borders + rim_bins, interior_bins)
    else:
        rim, rim_count = band_mean(borders - rim_bins, rim_bins)
        interior, interior_count = band_mean(borders - rim_bins - interior_bins, interior_bins)
    darkening = interior - rim
    valid = (rim_count >= 4 * rim_bins) & (interior_count >= 4 * interior_bins)
    positions = start + borders * BIN
    searched = valid & (positions >= lo) & (positions <= hi)
    if searched.sum() < 4 or valid.sum() < 8:
        return None
    spread = 1.4826 * np.median(np.abs(darkening[valid] - np.median(darkening[valid])))
    if spread <= 1e-9:
        return None
    scores = np.where(searched, (darkening - np.median(darkening[valid])) / spread, -np.inf)
    best = int(np.argmax(scores))
    if scores[best] < RIM_CONTRAST or darkening[best] < RIM_SHARE * interior[best]:
        return None
    return float(positions[best]), float(scores[best])
