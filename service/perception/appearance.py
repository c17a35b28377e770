"""What the image says about chain ends, for merging: each end's colour.

Two pieces of one cable look alike where they meet a gap or a crossing; two cables
of clearly different colour are not one cable, however well their ends line up. Each
end gets the colour of the cable just inside it (the median, in CIE Lab, of the 3x3
means at points 1 px apart along a stretch of the piece starting one radius in and
stopping a radius before the piece's other end, so cuts' rims and occluders' shadows
are left out) and how much its samples scatter
round that (shading, texture, a stripe). :func:`colour_penalty` turns the difference
of two ends' colours, beyond what their own scatter explains, into a join cost.

Only the samples between the end and the first place where the foreground is much
wider than one cable count, less the stretch over which it widens to that: there the
piece runs into something that is not one cable, most often an object segmented with
the cables (an occluder of a cable-like colour) whose skeleton carries the piece on
into the object. Its colour there is the object's, and an end that lies in such a blob
has no colour of its own (too few samples before it): it is judged on geometry alone,
as with the colour cost off. Nor has a piece shorter than three radii (a scrap where
the skeleton meets a blob or a junction): it has no radius of cable clear of the rims
at both its ends; unless neither of its tips is in a junction: then it is a stretch of
cable seen between two objects, whose skeleton stops about a radius short of each cut.
Nor has an end whose colour differs from that of its own piece further
in: an occluder segmented with the cable, not much wider than it, that the piece runs
into; unless the piece is long enough to be read twice further in and the two
readings agree: then that is its cable's body, and the end (a stripped tip, a
connector, an object over the end) takes the body's colour.

For gaps, :func:`gap_hidden` tells whether something the image shows lies over one;
:func:`cut_square` whether an end stops straight across the cable, as where an object's
border cuts it (rather than in a cable's own round tip); :func:`ends_alike` whether two
ends agree in colour and width.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, partial

import cv2
import numpy as np

from service.perception import _appearance_kernels
from service.perception.geometry import rotated

# The end stretch starts this many radii in from the end, is at most this many radii
# long and stops as far from the piece's other end (a cut, a junction, an occluder's rim).
STRETCH_SKIP_RADII = 1.0
STRETCH_RADII = 7.0
# Colours closer than this (Lab units, lightness counted at half weight, after the two
# ends' own scatter) are alike: a few times what shading along one cable gives. Each
# further COLOUR_TOLERANCE adds one colour_weight to the join cost, up to
# MAX_COLOUR_STEPS of them.
COLOUR_TOLERANCE = 10.0
MAX_COLOUR_STEPS = 2.0
# Lightness changes with the light along one cable far more than hue does.
LIGHTNESS_SHARE = 0.5
# A sample counts only where the foreground's half width (the distance transform) is at
# most this many times the cable's: a cable is up to about this much thicker than the
# typical one, and two touching strands are twice as wide but of the cables' colours.
WIDE_FACTOR = 2.0
# Fewer samples than this before the first wide one: the end's colour is unknown.
MIN_SAMPLES = 3
# A piece shorter than this many radii with a tip in a junction is a scrap (where the
# skeleton meets a blob or a junction): no radius of it is clear of the rims at both ends.
SCRAP_RADII = 3.0


@dataclass(frozen=True)
class EndColours:
    """Per chain end: the cable's Lab colour next to it and its samples' scatter."""

    colour: np.ndarray  # (E, 3) L (0-100), a, b; NaN where unknown
    spread: np.ndarray  # (E,) median Lab distance of the samples from ``colour``

    @property
    def known(self) -> np.ndarray:
        """(E,) bool: the end has samples on the cable itself."""
        return ~np.isnan(self.spread)


def end_colours(
    image_bgr: np.ndarray,
    pieces: list[np.ndarray],
    ends,
    radius: float,
    distance: np.ndarray | None = None,
    free: np.ndarray | None = None,
    widths: np.ndarray | None = None,
) -> EndColours:
    """The colour of the cable at every chain end (see the module's docstring).

    Parameters
    ----------
    image_bgr : ndarray (H, W, 3) uint8
    pieces : list of ndarray (N, 2)
        Chain pieces, (x, y) joints.
    ends : sequence of ChainEnd
        Each with ``piece`` and ``at_start``.
    radius : float
        Cable half width (px).
    distance : ndarray (H, W), optional
        The foreground mask's distance transform: an end's samples from the first
        where it exceeds ``limit``, :data:`WIDE_FACTOR` times the full half width
        (``radius + 0.5``), on are left out, and so are the ``limit`` px before it
        (the rim of the wide blob, where it widens from a cable's width). An end
        left with fewer than :data:`MIN_SAMPLES` has an unknown colour (NaN), as has
        every end of a piece shorter than three radii (unless ``free``), and an end
        whose colour differs (a :func:`colour_penalty` above 0) from its piece's
        further in (the next stretch as long, where the piece is long enough), unless
        a third stretch further in still agrees with the second: then the end takes
        the second's colour (its cable's body).
    free : ndarray of bool, optional
        Per piece, whether neither of its tips is in a junction zone: such a piece
        shorter than three radii is a stretch of cable seen between two objects, not a
        scrap where the skeleton meets a blob or a junction, and keeps the colour of
        its whole length.
    widths : ndarray, optional
        Per end, its piece's own full half width (px, the median distance transform at
        its joints; 0 when unknown): where wider than the typical ``radius + 0.5``, the
        end's wide samples are those past :data:`WIDE_FACTOR` times its own. A cable
        more than twice as thick as the picture's typical one is wider than that limit
        everywhere, and its ends would have no colour at all (loops 400119).
    """
    count = len(ends)
    if count == 0:
        return EndColours(np.zeros((0, 3)), np.zeros(0))
    starts = np.cumsum([0] + [len(points) for points in pieces]).astype(np.int64)
    joints = np.ascontiguousarray(np.concatenate(pieces), dtype=np.float64)
    end_piece = np.array([end.piece for end in ends], np.int64)
    end_at_start = np.array([end.at_start for end in ends], np.bool_)
    image = np.ascontiguousarray(image_bgr, dtype=np.uint8)

    own = np.full(count, radius + 0.5)
    if widths is not None:
        own = np.maximum(own, np.asarray(widths, np.float64))

    def stretch(skip, which=slice(None)):
        return _stretch_colours(
            image,
            joints,
            starts,
            end_piece[which],
            end_at_start[which],
            skip,
            radius,
            distance,
            own[which],
        )

    colour, spread, lengths = stretch(STRETCH_SKIP_RADII * radius)
    scraps = lengths < SCRAP_RADII * STRETCH_SKIP_RADII * radius
    if free is not None:
        # A short piece with neither tip in a junction is a stretch of cable seen
        # between two objects: thinning stops about a radius short of each cut, so its
        # whole length is clear of the rims, and it is the cable's own colour.
        scraps &= ~np.asarray(free, bool)[end_piece]
    colour[scraps], spread[scraps] = np.nan, np.nan
    # The same piece further in: where the end's colour is not the body's, the end
    # lies on something else segmented with the cable.
    body_skip = (STRETCH_SKIP_RADII + STRETCH_RADII) * radius
    body, body_spread, _ = stretch(body_skip)
    short = lengths - body_skip - STRETCH_SKIP_RADII * radius < 1.0
    body[short], body_spread[short] = np.nan, np.nan
    both = EndColours(np.concatenate([colour, body]), np.concatenate([spread, body_spread]))
    index = np.arange(count)
    changed = colour_penalty(both, index, index + count) > 0
    colour[changed], spread[changed] = np.nan, np.nan
    # The cable is still of its body's colour (a stripped tip's copper or a connector
    # read at the end would leave the end free to join a cable of any colour), but only
    # where a second reading further in agrees: a body that runs onto an object
    # segmented with the cable is the object's colour, not the cable's.
    deep_skip = body_skip + STRETCH_RADII * radius
    # A stretch stays as far from the piece's other end as it starts from this one
    # (else it is the whole piece): only a piece that long has a second reading.
    readable = changed & (lengths - 2.0 * deep_skip >= 1.0)
    readable &= ~np.isnan(body_spread)
    if readable.any():
        which = np.flatnonzero(readable)
        deep, deep_spread, _ = stretch(deep_skip, which)
        inner = EndColours(
            np.concatenate([body[which], deep]),
            np.concatenate([body_spread[which], deep_spread]),
        )
        pair = np.arange(len(which))
        agree = inner.known[len(which) :] & (colour_penalty(inner, pair, pair + len(which)) == 0)
        kept = which[agree]
        colour[kept], spread[kept] = body[kept], body_spread[kept]
    return EndColours(colour, spread)


def _stretch_colours(
    image, joints, starts, end_piece, end_at_start, skip, radius, distance, own=None
):
    """Median colour and scatter of every end's stretch from ``skip`` on, and the
    length of its piece (see :func:`end_colours`; ``own``: per end, the full half width
    its wide samples are judged by, at least ``radius + 0.5``)."""
    samples, bounds, pixels, lengths = _appearance_kernels.end_samples(
        image, joints, starts, end_piece, end_at_start, skip, STRETCH_RADII * radius
    )
    # Converted as one row: OpenCV converts a row's pixels in vector registers, and a
    # column of one-pixel rows one pixel at a time (4 times slower, the same values).
    lab = cv2.cvtColor(samples.reshape(1, -1, 3), cv2.COLOR_BGR2LAB).reshape(-1, 3)
    limit = WIDE_FACTOR * (radius + 0.5)
    wide = np.zeros(len(samples), np.bool_)
    margin = int(np.ceil(limit))
    if distance is not None and len(samples):
        at = distance[pixels[:, 0], pixels[:, 1]]
        if own is None or not (own > radius + 0.5).any():
            wide = at > limit
        else:
            wide = _first_wide_less_margin(at, bounds, WIDE_FACTOR * own)
            margin = 0
    colour, spread = _appearance_kernels.colour_medians(
        np.ascontiguousarray(lab), bounds, wide, MIN_SAMPLES, margin
    )
    return colour, spread, lengths


def _first_wide_less_margin(at: np.ndarray, bounds: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """Per end (samples ``bounds[e]:bounds[e + 1]``, distance transform ``at``), the
    sample its colour's samples stop at marked alone: the first past the end's own
    ``limits[e]``, less that limit (rounded up) more, the rim of the wide blob, as the
    compiled median reads one limit for all ends with its ``margin``."""
    wide = np.zeros(len(at), np.bool_)
    counts = np.diff(bounds)
    # Every end's samples at once (called for every end of a frame, twice): each
    # compared with its end's limit in the distance transform's own type, as NumPy
    # compares an array with a Python float.
    past = np.flatnonzero(at > np.repeat(np.asarray(limits).astype(at.dtype), counts))
    if not past.size:
        return wide
    end_of = np.searchsorted(bounds, past, side="right") - 1
    ends, first = np.unique(end_of, return_index=True)
    starts = bounds[ends]
    margins = np.ceil(np.asarray(limits, np.float64)[ends]).astype(np.int64)
    wide[np.maximum(past[first] - margins, starts)] = True
    return wide


def colour_penalty(colours: EndColours, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Join cost, in units of the colour weight, of pairing ends ``first[k]`` and ``second[k]``.

    0 while the colours differ by no more than :data:`COLOUR_TOLERANCE` plus both ends'
    scatter, then one unit per further :data:`COLOUR_TOLERANCE`, at most
    :data:`MAX_COLOUR_STEPS`; 0 when either end's colour is unknown.
    """
    first, second = np.asarray(first), np.asarray(second)
    # Compiled: merging prices the colours of every candidate join and junction pair.
    steps = _appearance_kernels.colour_steps(
        np.ascontiguousarray(colours.colour, np.float64),
        np.ascontiguousarray(colours.spread, np.float64),
        np.ascontiguousarray(first, np.int64).ravel(),
        np.ascontiguousarray(second, np.int64).ravel(),
        COLOUR_TOLERANCE,
        MAX_COLOUR_STEPS,
        LIGHTNESS_SHARE,
    )
    return steps.reshape(first.shape)


# A gap's hidden stretch is compared with the background beside the two ends' pieces:
# points this many radii behind each end (along its direction), this many radii to
# either side of it.
BESIDE_BEHIND_RADII = (2.0, 3.0, 4.0, 5.0, 6.0)
BESIDE_SIDE_RADII = 3.0
# Gap samples this close (radii) to either end are left out: the cut's rim.
GAP_END_CLEAR_RADII = 1.5
# Right past each end, this many radii of the gap's curve: where the cable disappears.
CUT_REACH_RADII = 2.0
# Fewer background or gap samples than this: nothing is known.
MIN_GAP_SAMPLES = 3


def _lab_means(image_bgr: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Lab colour of the 3x3 mean round each (x, y) point (rounded, clipped)."""
    height, width = image_bgr.shape[:2]
    cols = np.clip(np.rint(points[:, 0]).astype(np.int64), 1, width - 2)
    rows = np.clip(np.rint(points[:, 1]).astype(np.int64), 1, height - 2)
    patches = np.zeros((len(points), 3), np.float32)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            patches += image_bgr[rows + dy, cols + dx].astype(np.float32)
    patches /= 9.0 * 255.0
    return cv2.cvtColor(patches.reshape(-1, 1, 3), cv2.COLOR_BGR2LAB).reshape(-1, 3)


def _lab_distance(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """CIELAB distance with lightness weighted by :data:`LIGHTNESS_SHARE` (the light
    along one cable changes lightness far more than hue)."""
    difference = first - second
    return np.sqrt(
        (LIGHTNESS_SHARE * difference[..., 0]) ** 2
        + difference[..., 1] ** 2
        + difference[..., 2] ** 2
    )


def gap_hidden(
    image_bgr: np.ndarray,
    mask: np.ndarray,
    curve: np.ndarray,
    ends: tuple,
    radius: float,
) -> bool:
    """Whether something the image shows could hide a cable along a gap's curve.

    The background is what lies beside the two ends' cables just behind the ends
    (:data:`BESIDE_BEHIND_RADII`, :data:`BESIDE_SIDE_RADII`; points off the mask): its
    median Lab colour and its samples' scatter. The gap is hidden by something when
    more than half of the curve's samples off the mask (clear of both ends' rims)
    differ from that colour by more than :data:`COLOUR_TOLERANCE` plus twice the
    scatter, as two ends' colours do in :func:`colour_penalty`, and so do more than
    half of those right past each end (:data:`CUT_REACH_RADII`) and of the curve moved a
    radius to either side: an object at least as wide as the cable lies over the gap
    where the cable disappears at both ends (not a thin line of a pattern crossing it).
    A gap over open background, which looks as the background beside the cables, is
    not; nor is one whose ends lie on open background (a cable's own end, or a piece of
    a pattern), nor one with too few samples to tell.

    Parameters
    ----------
    image_bgr : ndarray (H, W, 3) uint8
    mask : ndarray (H, W) bool
        The foreground.
    curve : ndarray (M, 2)
        The gap curve, (x, y) samples about 1 px apart.
    ends : tuple of two ChainEnd
        The ends the curve joins (``position``, ``direction`` outwards).
    radius : float
        Cable half width (px).
    """
    return gap_hidden_beside(
        image_bgr, mask, curve, ends, radius, background_beside(image_bgr, mask, ends, radius)
    )


def gap_hidden_beside(
    image_bgr: np.ndarray,
    mask: np.ndarray,
    curve: np.ndarray,
    ends: tuple,
    radius: float,
    background: tuple[np.ndarray, float] | None,
) -> bool:
    """:func:`gap_hidden` with the background beside the two ends already read
    (:func:`background_beside`, None when it cannot be): the same for every curve tried
    between one pair of ends, so the turn pass reads it once per pair."""
    if background is None:
        return False

    def mostly_unlike(points):
        points = off_mask(points, mask)
        if len(points) < MIN_GAP_SAMPLES:
            return False
        return bool(np.mean(_unlike(image_bgr, points, background)) > 0.5)

    curve = np.asarray(curve, np.float64)
    clear = GAP_END_CLEAR_RADII * radius
    reach = [np.hypot(*(curve - end.position).T) for end in ends]
    # Something lies over the cable where it disappears, at both ends, and over the gap
    # along its middle and both its edges: an object at least as wide as the cable.
    steps = np.gradient(curve, axis=0) if len(curve) > 1 else np.zeros_like(curve)
    normals = np.column_stack([-steps[:, 1], steps[:, 0]])
    normals /= np.maximum(np.hypot(normals[:, 0], normals[:, 1]), 1e-9)[:, None]
    middle = (reach[0] > clear) & (reach[1] > clear)
    return all(
        mostly_unlike(curve[(near > clear) & (near <= clear + CUT_REACH_RADII * radius)])
        for near in reach
    ) and all(
        mostly_unlike(curve[middle] + side * radius * normals[middle]) for side in (-1.0, 0.0, 1.0)
    )


def unlike_background(
    image_bgr: np.ndarray, mask: np.ndarray, points: np.ndarray, ends: tuple, radius: float
) -> np.ndarray:
    """Per (x, y) point (off the foreground ``mask``), whether the image there differs
    from the open background beside the two ``ends``' cables as :func:`gap_hidden`
    reads it (something seen over it); all False when that background cannot be read."""
    points = np.asarray(points, np.float64).reshape(-1, 2)
    background = background_beside(image_bgr, mask, ends, radius)
    if background is None or not len(points):
        return np.zeros(len(points), bool)
    return _unlike(image_bgr, points, background)


def _unlike(image_bgr: np.ndarray, points: np.ndarray, background: tuple) -> np.ndarray:
    """Per (x, y) point, whether the image there differs from ``background`` (its
    median Lab colour and scatter, :func:`background_beside`) by more than
    :data:`COLOUR_TOLERANCE` plus twice the scatter, as two ends' colours do in
    :func:`colour_penalty`."""
    colour, spread = background
    return _lab_distance(_lab_means(image_bgr, points), colour) > COLOUR_TOLERANCE + 2 * spread


def off_mask(points: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The (x, y) ``points`` inside the picture that lie off the foreground ``mask``."""
    return points[_off_mask_flags(points, mask)]


def _off_mask_flags(points: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per (x, y) point, whether it lies inside the picture and off the ``mask``."""
    height, width = mask.shape
    inside = (
        (points[:, 0] >= 0)
        & (points[:, 1] >= 0)
        & (points[:, 0] <= width - 1)
        & (points[:, 1] <= height - 1)
    )
    cols, rows = np.rint(np.where(inside[:, None], points, 0.0)).astype(np.int64).T
    return inside & ~mask[rows, cols]


def background_beside(
    image_bgr: np.ndarray, mask: np.ndarray, ends: tuple, radius: float
) -> tuple[np.ndarray, float] | None:
    """The open background beside two ends' cables just behind the ends
    (:data:`BESIDE_BEHIND_RADII`, :data:`BESIDE_SIDE_RADII`; points off the mask): its
    median Lab colour and its samples' median distance from it; None with too few."""
    reference = []
    for end in ends:
        normal = np.array([-end.direction[1], end.direction[0]])
        for behind in BESIDE_BEHIND_RADII:
            centre = end.position - behind * radius * end.direction
            for side in (-1.0, 1.0):
                reference.append(centre + side * BESIDE_SIDE_RADII * radius * normal)
    reference = off_mask(np.array(reference), mask)
    if len(reference) < MIN_GAP_SAMPLES:
        return None
    background = _lab_means(image_bgr, reference)
    colour = np.median(background, axis=0)
    return colour, float(np.median(_lab_distance(background, colour)))


def out_of_view(
    image_bgr: np.ndarray,
    mask: np.ndarray,
    curve: np.ndarray,
    ends: tuple,
    radius: float,
    background: tuple[np.ndarray, float] | None = None,
    half_width: float = 0.0,
) -> bool:
    """Whether a cable along ``curve`` would be out of view all the way: every sample of
    the curve off the foreground differs from the open background beside the two
    ``ends``' cables (:func:`gap_hidden`'s colour and tolerance), so that something lies
    over each. A curve that runs out past the object that hides the turn onto open
    background, where the cable would be seen, is not; nor is one with too few samples
    off the foreground, or ends with too little background beside them, to tell.
    ``background``: :func:`background_beside` of the two ends, when already read (the
    same for every curve tried between them). With ``half_width`` (px), the cable's
    whole tube, not only its middle: the points that far to either side of each sample
    off the foreground (across the curve), those off it too, must differ as well."""
    if background is None:
        background = background_beside(image_bgr, mask, ends, radius)
    if background is None:
        return False
    colour, spread = background
    curve = np.asarray(curve, np.float64)
    hidden = _off_mask_flags(curve, mask)
    points = curve[hidden]
    if len(points) < MIN_GAP_SAMPLES:
        return False
    if half_width > 0:
        steps = np.gradient(curve, axis=0)
        normals = np.column_stack([-steps[:, 1], steps[:, 0]])[hidden]
        normals *= half_width / np.maximum(np.hypot(*normals.T), 1e-9)[:, None]
        sides = np.concatenate([points + normals, points - normals])
        points = np.concatenate([points, off_mask(sides, mask)])
    distance = _lab_distance(_lab_means(image_bgr, points), colour)
    return bool(np.all(distance > COLOUR_TOLERANCE + 2 * spread))


# An end is cut when the foreground stops within this many radii ahead of it (a
# cable's end, or the border of something lying over it), rather than running on.
CUT_AHEAD_RADII = 2.0
# A cut's front is read this share of the half width to either side of the centre; it is
# straight when the middle bulges past the sides by at most CUT_BULGE_SHARE half widths
# (a round tip bulges by 0.29 there, a straight cut by nothing, at any slant).
CUT_PROBE_SHARE = 0.7
CUT_BULGE_SHARE = 0.15
# A cut at a slant reaches further along the cable on one side than on the other, and the
# line on its far side, running longer, leaves through the cable's side before the cut
# where the end's direction is a little off or the cable bends (as where it enters a
# disc's rim at a shallow angle): the middle then seems to bulge. The bulge allowed grows
# by this share of the difference between the two sides' fronts. A round tip shows that
# difference only where its circle lies off the centre line, and then bulges more still
# (by 0.37 half widths for a difference of 0.58, 0.50 for 0.92; the limit there is 0.27
# and 0.33).
CUT_SLANT_BULGE_SHARE = 0.2
# Turns (degrees, either way) of the directions a cut's front is read again along
# where the end's fitted direction reads no straight cut (:func:`cut_square`).
CUT_READ_TURNS = (10.0, 20.0)
# A front is lopsided (no cable's own tip) when one side line runs on past the other by
# more than this share of the half width: a round tip read 15 degrees off its axis is
# lopsided by about 0.37 of it.
TIP_LOPSIDED_SHARE = 0.5
# A cable's own round tip (a half disc) bulges past lines CUT_PROBE_SHARE of its half
# width to either side of its axis by this share of the half width. Each front is read
# in 0.5 px steps on a pixel grid: two readings may differ by up to TIP_READING_PX for
# nothing. A bulge under TIP_MIN_BULGE_PX (a cap on a cable under about 3.5 px in half
# width) is not told from a cut's pixel steps.
CAP_BULGE_SHARE = 1.0 - float(np.sqrt(1.0 - CUT_PROBE_SHARE**2))
TIP_READING_PX = 1.5
TIP_MIN_BULGE_PX = 1.0
# The cross-section is read this many half widths behind the end; a cable's there is
# within this range of its piece's typical half width.
CUT_BEHIND_RADII = 1.5
CUT_WIDTH_RANGE = (0.6, 1.5)
# Where the cross-section just behind the front is narrower (a steeply slanted cut),
# it is read again this share of a half width further back each time.
CUT_STEP_BACK_SHARE = 0.5
# The cut's front is read along the cable's own axis between the two cross-sections
# when they lie at least this share of a half width apart and that axis turns from the
# end's fitted direction by less than the angle of CUT_AXIS_COS.
CUT_AXIS_SHARE = 1.0
CUT_AXIS_COS = float(np.cos(np.radians(45.0)))
# Where the cable bends at its end, the front is read again along that bend
# (:func:`_front_along_bend`), traced back from the first cross-section one cross-section
# per half width, BEND_TRACE_STEPS of them; a cable bends no tighter than BEND_MIN_RADII
# half widths (the turn joins' tightest hidden bend, :data:`.turn_joins.HIDDEN_BEND_RADII`).
# Only a bend whose lines part from straight ones by at least TIP_MIN_BULGE_PX over
# BEND_READ_REACH half widths (from a half width behind the front to a tip's bulge past
# it) is read: a gentler one reads the straight front again, in new pixel steps.
BEND_TRACE_STEPS = 3
BEND_MIN_RADII = 2.0
BEND_READ_REACH = 2.0
# Two ends are alike in width when the narrower piece is at least this share of the wider.
WIDTH_AGREEMENT = 0.8


def _front(mask: np.ndarray, start: np.ndarray, direction: np.ndarray, count: int) -> float:
    """Arc (px, 0.5 px steps) from ``start`` along ``direction`` to the first point off
    ``mask``; NaN when the start is off it, or the mask runs on past ``count`` steps or
    the picture's edge."""
    # Compiled (:func:`._appearance_kernels.front`, the points made as NumPy makes
    # them): the fronts and cross-sections of the end readings march thousands of times
    # a frame on a textured ground.
    return _appearance_kernels.front(
        np.ascontiguousarray(mask).view(np.uint8),
        float(start[0]),
        float(start[1]),
        float(direction[0]),
        float(direction[1]),
        int(count),
    )


def _front_on_bend(
    mask: np.ndarray,
    start: np.ndarray,
    tangent: np.ndarray,
    curvature: float,
    offset: float,
    count: int,
) -> float:
    """As :func:`_front`, along the line ``offset`` px to the left of a centreline that
    leaves ``start`` along unit ``tangent`` and bends at ``curvature`` (1/px, positive
    to the left, as :func:`.geometry.end_fit`'s): the arc length along the centreline
    (0.5 px steps) at which that line, parallel to it, first leaves ``mask``. A cut
    straight across the bent cable (along a radius of the bend) reads as far on every
    line."""
    steps = 0.5 * np.arange(count)
    heading = complex(tangent[0], tangent[1])
    left = 1j * heading
    origin = complex(start[0], start[1]) + offset * left
    centre = complex(start[0], start[1]) + left / curvature
    path = centre + (origin - centre) * np.exp(1j * curvature * steps)
    return _first_off(mask, np.stack([path.real, path.imag], axis=1))


def _first_off(mask: np.ndarray, points: np.ndarray) -> float:
    """Arc (px, ``points`` 0.5 px apart) to the first of them off ``mask``; NaN when the
    first is off it, or none is off before the picture's edge."""
    return _appearance_kernels.first_off(
        np.ascontiguousarray(mask).view(np.uint8), np.ascontiguousarray(points, np.float64)
    )


def end_front(
    mask: np.ndarray,
    position: np.ndarray,
    direction: np.ndarray,
    half_width: float,
    skip: float = 0.0,
) -> np.ndarray | None:
    """The front of a chain end (``position``, outward unit ``direction``) of a cable
    of ``half_width`` px, as :func:`cut_square` reads it: how far the foreground runs on
    along the cable's centre and lines :data:`CUT_PROBE_SHARE` of its half width to
    either side (``(3,)``, in the local half width: one side, centre, other side);
    None when it cannot be read: the march starts off the mask, runs on (the foreground
    must end within :data:`CUT_AHEAD_RADII` half widths ahead of the end) or leaves the
    picture first, or the cable's width there is not its own.

    The cable's cross-section is first read :data:`CUT_BEHIND_RADII` half widths
    behind the end, or ``skip`` px (the tip the end's fit left out, a cut's hook) where
    that is further: closer in, a cut at a slant has already taken one side off. The
    front is read along the cable's own axis between that cross-section and the one
    just behind the front (:data:`CUT_AXIS_SHARE`, :data:`CUT_AXIS_COS`) rather than the
    fitted direction, which a bend just before the cut turns off the cable."""
    reading = _front_reading(mask, position, direction, half_width, skip)
    return None if reading is None else _straight_front(mask, reading)


def end_fronts(
    mask: np.ndarray,
    position: np.ndarray,
    direction: np.ndarray,
    half_width: float,
    skip: float = 0.0,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The end's front read as :func:`end_front` does, and again along the cable's own
    bend just behind it (:func:`_front_along_bend`; None where it bends too gently to
    matter, or where either cannot be read)."""
    front, bent = _fronts_on_demand(mask, position, direction, half_width, skip)
    return front, bent()


def _fronts_on_demand(mask, position, direction, half_width, skip):
    """:func:`end_fronts`, the reading along the bend left until it is asked for (a
    callable of no arguments, read once): most ends are decided on the straight front,
    and tracing the bend reads four more cross-sections and three more lines."""
    reading = _front_reading(mask, position, direction, half_width, skip)
    if reading is None:
        return None, lambda: None
    return _straight_front(mask, reading), cache(
        partial(_front_along_bend, mask, reading, half_width)
    )


def _front_reading(mask, position, direction, half_width, skip):
    """:func:`end_front`'s march up to the front: the first cross-section's centre, the
    centre, direction and half width of the one just behind the front, the march's
    length in 0.5 px steps and the cross-section reader; None where the front cannot
    be read."""
    direction = np.asarray(direction, np.float64)
    count = int(np.ceil(2.0 * ((CUT_AHEAD_RADII + 2.0) * half_width + float(skip)))) + 1

    # The cable's own cross-section behind the end: its centre and half width there
    # (the end's fitted position may lie off the centreline on a bend).
    def cross_section(point, direction=direction):
        normal = np.array([-direction[1], direction[0]])
        sides = [_front(mask, point, side * normal, count) for side in (1.0, -1.0)]
        if np.isnan(sides).any():
            return None, 0.0
        local = 0.5 * (sides[0] + sides[1])
        return point + 0.5 * (sides[0] - sides[1]) * normal, local

    back_from_end = max(CUT_BEHIND_RADII * half_width, float(skip))
    behind = np.asarray(position, np.float64) - back_from_end * direction
    centre, local = cross_section(behind)
    if centre is None:
        return None
    ahead = _front(mask, centre, direction, count)
    if np.isnan(ahead) or ahead > CUT_AHEAD_RADII * half_width + back_from_end:
        return None
    # Read the front from a cross-section just behind it: on a bend, lines from further
    # back would leave through the cable's side before they reach the cut. A cut at a
    # steep slant (or along an object's round rim) takes one side of the cable off
    # up to a few half widths before the middle: where the cross-section there is
    # narrower than the cable, it is read further back, half a half width at a time,
    # up to where the march began.
    start, back = centre, local
    while True:
        centre, local = cross_section(start + max(ahead - back, 0.0) * direction)
        if centre is None:
            return None
        if local >= CUT_WIDTH_RANGE[0] * half_width or back >= ahead:
            break
        back += CUT_STEP_BACK_SHARE * half_width
    # The fitted direction is extrapolated over the tip; where the cable bends just
    # before the cut, the lines along it leave through the cable's side. The cable's own
    # axis there runs from the first cross-section's centre to this one's.
    axis = centre - start
    apart = float(np.hypot(*axis))
    if apart >= CUT_AXIS_SHARE * half_width and float(axis @ direction) > apart * CUT_AXIS_COS:
        direction = axis / apart
        centre, local = cross_section(centre, direction)
        if centre is None:
            return None
    if not _of_the_cable(local, half_width):
        return None
    return start, centre, direction, local, count, cross_section


def _straight_front(mask, reading) -> np.ndarray | None:
    """The front along straight lines from the cross-section just behind it
    (``reading``, :func:`_front_reading`)."""
    _, centre, direction, local, count, _ = reading
    normal = np.array([-direction[1], direction[0]])
    fronts = [
        _front(mask, centre + share * local * normal, direction, count)
        for share in (-CUT_PROBE_SHARE, 0.0, CUT_PROBE_SHARE)
    ]
    if np.isnan(fronts).any():
        return None
    return np.array(fronts) / local


def _front_along_bend(mask, reading, half_width) -> np.ndarray | None:
    """The front read along the cable's own bend (``reading``, :func:`_front_reading`).

    On a bend, lines parallel to one straight direction leave through the cable's
    sides: the outer one early, the middle one running on across the cable, so a cut
    straight across the bent cable reads as bulging like a tip (or, the outer line
    cut short, like a cable's own round tip). Lines parallel to the bent centreline
    reach the cut on every line, while a cable's own tip stays round read along any
    bend. The bend is the one the cable's centre shows behind the front
    (:func:`_bend_behind`), traced from the first cross-section back, clear of the cut
    (a slanted cut takes one side off the cross-section just behind the front and
    shifts its centre: a bend read on a straight cable), and carried on along that
    bend to the front's cross-section. None where the bend is too gentle to part the
    lines from straight ones (:data:`BEND_READ_REACH`), or the front cannot be read
    along it."""
    start, centre, direction, _, count, cross_section = reading
    bend = _bend_behind(start, direction, half_width, cross_section)
    if bend is None:
        return None
    behind_centre, behind_direction, curvature = bend
    if 0.5 * abs(curvature) * (BEND_READ_REACH * half_width) ** 2 < TIP_MIN_BULGE_PX:
        return None
    carried = np.exp(1j * curvature * float(np.hypot(*(centre - behind_centre))))
    tangent = complex(behind_direction[0], behind_direction[1]) * carried
    front_direction = np.array([tangent.real, tangent.imag])
    front_centre, local = cross_section(centre, front_direction)
    if front_centre is None or not _of_the_cable(local, half_width):
        return None
    fronts = [
        _front_on_bend(mask, front_centre, front_direction, curvature, share * local, count)
        for share in (-CUT_PROBE_SHARE, 0.0, CUT_PROBE_SHARE)
    ]
    if np.isnan(fronts).any():
        return None
    return np.array(fronts) / local


def _of_the_cable(local: float, half_width: float) -> bool:
    """Whether a cross-section's half width ``local`` is the cable's own
    (:data:`CUT_WIDTH_RANGE`)."""
    return CUT_WIDTH_RANGE[0] * half_width <= local <= CUT_WIDTH_RANGE[1] * half_width


def _bend_behind(centre, heading, half_width, cross_section):
    """The cable's own bend behind the cross-section at ``centre`` (the cable running
    along unit ``heading`` there, of ``half_width`` px; ``cross_section(point,
    direction)`` -> (centre, half width) or (None, 0)): a cross-section every half
    width back, :data:`BEND_TRACE_STEPS` of them, each across the heading the last two
    centres give. Returns the first centre, the unit tangent there and the signed
    curvature (1/px, positive to the left of that tangent, no tighter than
    :data:`BEND_MIN_RADII` half widths) of the circle through the first, middle and last
    centres (the first read again across that tangent); None where the trace leaves the
    cable (a cross-section off the mask or not of the cable's width: a crossing, another
    strand, the cable's own tip)."""
    centres = [complex(centre[0], centre[1])]
    for _ in range(BEND_TRACE_STEPS):
        point = centres[-1] - half_width * complex(heading[0], heading[1])
        found, width = cross_section(np.array([point.real, point.imag]), heading)
        if found is None or not _of_the_cable(width, half_width):
            return None
        centres.append(complex(found[0], found[1]))
        step = centres[-2] - centres[-1]
        if abs(step) < 1e-9:
            return None
        heading = np.array([step.real, step.imag]) / abs(step)
    front, middle, last = centres[0], centres[len(centres) // 2], centres[-1]
    # The signed curvature of the circle through the three (2 sin(angle) / chord).
    turn = ((middle - last).conjugate() * (front - middle)).imag
    sides = abs(middle - last) * abs(front - middle) * abs(front - last)
    if sides < 1e-9:
        return None
    tightest = 1.0 / (BEND_MIN_RADII * half_width)
    curvature = float(np.clip(2.0 * turn / sides, -tightest, tightest))
    # The tangent at the first centre: the chord from the middle one, turned by half the
    # arc's turn over it.
    chord = front - middle
    tangent = chord / abs(chord) * np.exp(0.5j * curvature * abs(chord))
    direction = np.array([tangent.real, tangent.imag])
    found, width = cross_section(np.array([front.real, front.imag]), direction)
    if found is None or not _of_the_cable(width, half_width):
        return None
    return found, direction, curvature


def cut_square(
    mask: np.ndarray,
    position: np.ndarray,
    direction: np.ndarray,
    half_width: float,
    skip: float = 0.0,
) -> bool:
    """Whether a chain end (``position``, outward unit ``direction``) of a cable of
    ``half_width`` px stops as a cut straight across its width (:func:`end_front`): the
    middle bulging past the sides by at most :data:`CUT_BULGE_SHARE` of the half width
    (plus :data:`CUT_SLANT_BULGE_SHARE` of the two sides' difference: a slanted cut),
    as where an object's border crosses the cable, and unlike a cable's own rounded or
    tapering tip. False when the front cannot be read.

    Where an object's corner or a disc's rim cuts the cable at a steep slant, the
    skeleton hooks into the sharp corner and the end's fitted direction points into it
    (a wedge, read along its bisector, bulges as a tip does). The front is then read
    again along directions turned by :data:`CUT_READ_TURNS` either way: a straight cut
    reads straight along any of them, a round tip bulges along all (its outline is a
    circle's), so there the middle may bulge by no more than :data:`CUT_BULGE_SHARE`.
    An end whose front reads as a cable's own tip (:func:`own_tip`) is not read again:
    turned, a tip's bulge of a pixel or two is lost in its reading's pixel steps.

    Where the cable bends just behind the front, its straight lines leave through the
    cable's side and a cut straight across the bent cable bulges, or reads as a round
    tip: a front that reads flat along the bend (:func:`end_fronts`; :func:`_flat`, the
    slant's allowance being for lines that leave through the side of a bend) is cut
    too. A cable's own tip is round whichever way the cable bends."""
    front, bent = _fronts_on_demand(mask, position, direction, half_width, skip)
    return _cut_square_from(front, bent, mask, position, direction, half_width, skip)


def _cut_square_from(front, bent, mask, position, direction, half_width, skip) -> bool:
    """:func:`cut_square` with the front along ``direction`` read and the one along the
    bend to be read on demand (``bent()``, :func:`_fronts_on_demand`)."""
    if _straight(front) or _flat(bent()):
        return True
    if own_tip(front, half_width):
        return False
    for turn in CUT_READ_TURNS:
        for sign in (-1.0, 1.0):
            turned = rotated(direction, np.radians(sign * turn))
            if _flat(end_front(mask, position, turned, half_width, skip)):
                return True
    return False


def cut_or_lopsided(
    mask: np.ndarray,
    position: np.ndarray,
    direction: np.ndarray,
    half_width: float,
    skip: float = 0.0,
) -> bool:
    """Whether a chain end's front (:func:`end_front`) is no cable's own tip: cut
    straight across (:func:`cut_square`), or lopsided, one side running on past the
    other by more than :data:`TIP_LOPSIDED_SHARE` of the half width, as where an
    object's border or corner cuts a cable at a slant along its bend. A cable's round
    or tapering tip is symmetric about its axis, read straight or along the cable's
    bend (:func:`end_fronts`); or a wedge read straight (:func:`_wedge`), bulging past
    any round cap. False when the front cannot be read."""
    front, bent = _fronts_on_demand(mask, position, direction, half_width, skip)
    # The straight front's own tests first: they need neither the bend nor turned readings.
    return (
        _lopsided(front)
        or _wedge(front, half_width)
        or _cut_square_from(front, bent, mask, position, direction, half_width, skip)
        or _lopsided(bent())
    )


def reads_own_tip(
    mask: np.ndarray,
    position: np.ndarray,
    direction: np.ndarray,
    half_width: float,
    skip: float = 0.0,
) -> bool:
    """:func:`own_tip_both_ways` of the end's fronts (:func:`end_fronts`), the front
    along the bend read only for an end whose straight front reads as its own tip."""
    front, bent = _fronts_on_demand(mask, position, direction, half_width, skip)
    return own_tip(front, half_width) and own_tip_both_ways((front, bent()), half_width)


def own_tip_both_ways(
    fronts: tuple[np.ndarray | None, np.ndarray | None], half_width: float
) -> bool:
    """Whether a chain end whose ``fronts`` (:func:`end_fronts`) were read on a cable of
    ``half_width`` px ends in the cable's own round tip (:func:`own_tip`) read straight,
    and, where the cable bends just behind it, neither flat nor lopsided read along that
    bend: a cut straight across a bent cable reads round only along straight lines,
    which leave through the cable's side, while a cable's own tip is round whichever
    way the cable bends. (Read along a bend, a tip's pixel
    steps may leave it a little lopsided, no cut's front.)"""
    front, bent = fronts
    return own_tip(front, half_width) and not (_flat(bent) or _lopsided(bent))


def own_tip(front: np.ndarray | None, half_width: float) -> bool:
    """Whether a chain end's front (:func:`end_front`, of a cable of ``half_width`` px)
    is a cable's own round tip: read, symmetric about the cable's axis and bulging past
    the two side lines as a half disc does (:data:`CAP_BULGE_SHARE`), within
    :data:`TIP_READING_PX` on each count, and by at least :data:`TIP_MIN_BULGE_PX`. Where an
    object lies over a cable, its border cuts the cable straight, concave (a disc's
    rim) or at a slant, and a cut read on a bend may bulge far more than a cap. False
    when the front cannot be read (the foreground runs on ahead: a crossing, a junction,
    the picture's edge)."""
    if front is None:
        return False
    bulge = (front[1] - 0.5 * (front[0] + front[2])) * half_width
    return bool(
        abs(front[0] - front[2]) * half_width <= TIP_READING_PX
        and TIP_MIN_BULGE_PX <= bulge <= CAP_BULGE_SHARE * half_width + TIP_READING_PX
    )


def _wedge(front: np.ndarray | None, half_width: float) -> bool:
    """The middle runs on past the sides by more than a round cap's bulge
    (:data:`CAP_BULGE_SHARE`) plus the pixel steps of the middle's reading and of the
    sides' (:data:`TIP_READING_PX` each): no half disc, but a wedge, as where an object's
    corner cuts a strand bending into a turn and the lines to its sides leave through the
    strand's flanks before the cut."""
    if front is None:
        return False
    bulge = (front[1] - 0.5 * (front[0] + front[2])) * half_width
    return bool(bulge > CAP_BULGE_SHARE * half_width + 2.0 * TIP_READING_PX)


def _lopsided(front: np.ndarray | None) -> bool:
    return front is not None and bool(abs(front[0] - front[2]) > TIP_LOPSIDED_SHARE)


def _flat(front: np.ndarray | None) -> bool:
    """The middle line runs on past the sides' mean by at most a cut's bulge."""
    return front is not None and bool(front[1] - 0.5 * (front[0] + front[2]) <= CUT_BULGE_SHARE)


def _straight(front: np.ndarray | None) -> bool:
    if front is None:
        return False
    allowed = CUT_BULGE_SHARE + CUT_SLANT_BULGE_SHARE * abs(front[2] - front[0])
    return bool(front[1] - 0.5 * (front[0] + front[2]) <= allowed)


def ends_alike(colours: EndColours, first: int, second: int, widths: tuple[float, float]) -> bool:
    """Whether chain ends ``first`` and ``second`` look like two ends of one cable: both
    have a colour of their own and those agree (no :func:`colour_penalty`), and their
    pieces' half widths (``widths``, px; 0 when unknown) agree within
    :data:`WIDTH_AGREEMENT`."""
    if not (colours.known[first] and colours.known[second]):
        return False
    if colour_penalty(colours, np.array([first]), np.array([second]))[0] > 0:
        return False
    narrow, wide = sorted(float(width) for width in widths)
    return narrow > 0 and narrow >= WIDTH_AGREEMENT * wide


def _lab_beside(image_bgr: np.ndarray, mask: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Lab colour of the mean of the pixels off the foreground ``mask`` in the 3x3 patch
    round each (x, y) point (a slanted border's pixels beside it read the cable's colour,
    not what lies beyond it); NaN where the point's own pixel is on the mask or the patch
    leaves the picture."""
    # Compiled (a cut's reading asks for one or a few points at a time, where NumPy's
    # two dozen array operations per call cost more than the patches).
    patches, readable = _appearance_kernels.patches_beside(
        np.ascontiguousarray(image_bgr),
        np.ascontiguousarray(mask).view(np.uint8),
        np.ascontiguousarray(points, np.float64),
    )
    lab = cv2.cvtColor(patches.reshape(-1, 1, 3), cv2.COLOR_BGR2LAB).reshape(-1, 3)
    lab[~readable] = np.nan
    return lab


def ground_beside(
    image_bgr: np.ndarray, mask: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, float] | None:
    """The colour of what lies just beyond a cable's borders at the (x, y) ``points``
    (:func:`_lab_beside`): its median Lab colour and its samples' median distance from
    it (as :func:`background_beside`); None with fewer than :data:`MIN_GAP_SAMPLES`
    points off the mask."""
    colours = _lab_beside(image_bgr, mask, np.asarray(points, np.float64).reshape(-1, 2))
    colours = colours[~np.isnan(colours[:, 0])]
    if len(colours) < MIN_GAP_SAMPLES:
        return None
    colour = np.median(colours, axis=0)
    return colour, float(np.median(_lab_distance(colours, colour)))


def unlike_ground_at(
    image_bgr: np.ndarray, mask: np.ndarray, points: np.ndarray, ground: tuple[np.ndarray, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Whether the image at each (x, y) of ``points`` (:func:`_lab_beside`) can be read
    (off the mask, not at the picture's edge) and, where it can, differs from ``ground``
    (:func:`ground_beside`) by more than :func:`gap_hidden`'s tolerance (something else
    lies there: an object over the cable): two boolean arrays, ``unlike`` False where
    nothing is read (a NaN distance compares False)."""
    colours = _lab_beside(image_bgr, mask, np.asarray(points, np.float64).reshape(-1, 2))
    reference, spread = ground
    unlike = _lab_distance(colours, reference) > COLOUR_TOLERANCE + 2 * spread
    return ~np.isnan(colours[:, 0]), unlike


def unlike_ground(
    image_bgr: np.ndarray, mask: np.ndarray, point: np.ndarray, ground: tuple[np.ndarray, float]
) -> bool | None:
    """Whether the image at the (x, y) ``point`` differs from ``ground``, as
    :func:`unlike_ground_at` reads many; None where the point is on the mask or at the
    picture's edge (nothing to read). One point's own path: a wedge's borders are read a
    step at a time (:func:`.cut_ends.along_the_wedge`), where the arrays' handling costs
    twice the reading."""
    colour = _lab_beside(image_bgr, mask, np.asarray(point, np.float64).reshape(1, 2))[0]
    if np.isnan(colour[0]):
        return None
    reference, spread = ground
    return bool(_lab_distance(colour, reference) > COLOUR_TOLERANCE + 2 * spread)
