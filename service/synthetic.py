"""Synthetic cable scenes with exact ground truth, for tests, benchmarks and demos.

:func:`make_scene` draws smooth, shaded cables (some with a loop that crosses itself) on a
dark, low-saturation background, optionally hides short stretches of them under
background-like occluders, adds sensor noise, and returns the image together with
everything a perfect detector would report: the visible-cable mask, a per-cable label
image, every cable's whole centreline (hidden stretches included) and every crossing with
the cable on top.

Coordinates are pixels as ``[x, y]`` with pixel centres at integer positions (the OpenCV
convention): ``image[row, col]`` is centred on ``x = col, y = row``. The same arguments
and seed always give the same scene.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from functools import cached_property
from itertools import pairwise
from statistics import NormalDist
from typing import Literal

import cv2
import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "Occluder",
    "SyntheticCable",
    "SyntheticCrossing",
    "SyntheticScene",
    "make_scene",
]

# Centreline samples are this far apart (px): fine enough that the distance to the sampled
# polyline is the distance to the smooth curve, to a few thousandths of a pixel.
SAMPLE_SPACING = 0.5

MIN_IMAGE_SIDE = 64
MAX_CABLES = 10
MIN_CABLE_RADIUS = 1.0

# Detectors cannot be expected to untangle shallower crossings, so scenes never have them.
MIN_CROSSING_ANGLE = math.radians(30.0)

# Saturated colours plus white and light grey, all with value >= 185 so that either
# colourfulness or brightness separates every cable from the dark grey background.
_PALETTE_BGR = (
    (45, 45, 215),  # red
    (35, 130, 240),  # orange
    (50, 215, 225),  # yellow
    (70, 195, 70),  # green
    (185, 175, 40),  # teal
    (225, 120, 40),  # blue
    (200, 80, 150),  # violet
    (170, 105, 240),  # pink
    (235, 235, 232),  # white
    (205, 203, 200),  # light grey
)

# Light from the upper left and above the table; y points down in the image.
_LIGHT = np.array([-0.35, -0.45, 0.82]) / np.linalg.norm([-0.35, -0.45, 0.82])
_HALF_VECTOR = (_LIGHT + np.array([0.0, 0.0, 1.0])) / np.linalg.norm(
    _LIGHT + np.array([0.0, 0.0, 1.0])
)

# Sensor noise is looked up from random bytes: 256 equally likely levels of a unit normal
# distribution (tails cut at about 2.9 sigma), several times faster than drawing normals.
_NOISE_LEVELS = np.array(
    [NormalDist().inv_cdf((level + 0.5) / 256) for level in range(256)], dtype=np.float32
)
_NOISE_LEVELS /= _NOISE_LEVELS.std()

_CABLE_ATTEMPTS = 150
_INTERSECTION_CHUNK = 8  # segments per bounding box when searching for crossings
_OCCLUDER_ATTEMPTS = 300


@dataclass(frozen=True, eq=False)
class SyntheticCable:
    """Ground truth for one cable.

    Attributes
    ----------
    centreline : ndarray, shape (N, 2), float64
        ``[x, y]`` samples at most 1 px apart along the whole in-image cable, hidden
        stretches included, from one end to the other.
    radius : float
        Half the cable width in px.
    colour : tuple of int
        Base BGR colour (the drawn cable is shaded around it).
    hidden : ndarray, shape (N,), bool
        True for centreline samples covered by an occluder. Being under another cable at a
        crossing does not count as hidden.
    depth : int
        Drawing order: cables are drawn in increasing depth, so higher is on top.
    """

    centreline: np.ndarray
    radius: float
    colour: tuple[int, int, int]
    hidden: np.ndarray
    depth: int


@dataclass(frozen=True, eq=False)
class SyntheticCrossing:
    """A place where two centrelines cross, or where a loop crosses its own cable.

    Attributes
    ----------
    x, y : float
        Where the centrelines intersect (px).
    over, under : int
        Indices into :attr:`SyntheticScene.cables` of the cable on top and the one below.
        They are equal for a self-crossing loop, where the part further along the
        centreline (larger arc length) lies on top.
    over_arc, under_arc : float
        Arc length (px from the first centreline sample) of the crossing along the ``over``
        and the ``under`` cable. For a self-crossing ``over_arc > under_arc``.
    """

    x: float
    y: float
    over: int
    under: int
    over_arc: float = math.nan
    under_arc: float = math.nan


@dataclass(frozen=True, eq=False)
class Occluder:
    """An object lying on top of the cables, coloured like the background.

    Attributes
    ----------
    polygon : ndarray, shape (K, 2), float64
        ``[x, y]`` vertices in order. A pixel is covered when its centre lies inside.
    """

    polygon: np.ndarray


@dataclass(frozen=True, eq=False)
class SyntheticScene:
    """A synthetic image and its exact ground truth.

    Attributes
    ----------
    image : ndarray, shape (H, W, 3), uint8
        The BGR image.
    mask : ndarray, shape (H, W), bool
        Visible cable pixels: what a perfect segmentation returns.
    labels : ndarray, shape (H, W), uint16
        0 for background, ``i + 1`` where cable ``i`` is visible; at a crossing, the cable on
        top.
    cables : list of SyntheticCable
    crossings : list of SyntheticCrossing
    occluders : list of Occluder
    """

    image: np.ndarray
    mask: np.ndarray
    labels: np.ndarray
    cables: list[SyntheticCable]
    crossings: list[SyntheticCrossing]
    occluders: list[Occluder]


def make_scene(
    width: int = 1280,
    height: int = 720,
    n_cables: int = 3,
    *,
    seed: int | None = 0,
    radius_range: tuple[float, float] = (4.0, 9.0),
    loops: bool = True,
    occluders: int = 0,
    background: Literal["textured", "plain"] = "textured",
    noise_sigma: float = 4.0,
    margin: float | None = None,
) -> SyntheticScene:
    """Draw a random cable scene and return it with its exact ground truth.

    Parameters
    ----------
    width, height : int
        Image size in px, each at least 64.
    n_cables : int
        Number of cables, 0 to 10.
    seed : int or None
        Seed for :func:`numpy.random.default_rng`; the same seed gives the same scene.
    radius_range : (float, float)
        Cable radii (half widths, px) are drawn uniformly from ``[low, high]``;
        ``1 <= low <= high``.
    loops : bool
        Let about half of the cables make a loop that crosses itself at a clear angle.
    occluders : int
        Number of rotated rectangles laid across cables, each hiding a 20-80 px stretch
        well inside one cable (never over a crossing or near a cable end). Needs at least
        one cable.
    background : {"textured", "plain"}
        Dark, low-saturation background: smoothed noise with a faint wood grain or grid,
        or a uniform grey with a slight gradient.
    noise_sigma : float
        Standard deviation of the Gaussian sensor noise added last (grey levels).
    margin : float or None
        None lets cables run off the image; their centrelines are then cut at the image
        border. A number keeps every cable wholly inside, at least ``margin`` px from each
        border, so both of its ends are visible.

    Returns
    -------
    SyntheticScene

    Raises
    ------
    ValueError
        If an argument is out of range.
    RuntimeError
        If the cables or occluders cannot be placed under the layout rules (too many or
        too wide cables for the image).

    Notes
    -----
    Layout rules, so that the ground truth is unambiguous: cables curve no tighter than
    4 radii and loops have a radius of at least 5 cable radii, so loop holes stay open;
    crossings are at least 30 degrees; two cables (or two parts of one) come within
    2.5 times their summed radii only briefly, at a crossing; cable ends keep 3 radii
    away from other cables. A self-crossing loop is drawn with its later part (larger
    arc length) on top.
    """
    _validate_arguments(
        width, height, n_cables, seed, radius_range, occluders, background, noise_sigma, margin
    )
    rng = np.random.default_rng(seed)

    grey, tint, background_level = _draw_background(rng, width, height, background)
    curves, raw_crossings = _place_cables(rng, width, height, n_cables, radius_range, loops, margin)
    colours = _pick_colours(rng, n_cables)
    depths = rng.permutation(n_cables)
    rects = _place_occluders(rng, occluders, curves, raw_crossings, width, height)

    # Cables and occluders are painted as lists of pixels and their colours, and only
    # laid over the background band by band in _compose: a whole float canvas and its
    # noise would take 24 bytes a pixel, 200 MB at 3840x2160.
    labels = np.zeros((height, width), dtype=np.uint16)
    paints: list[_Paint] = []
    for index in np.argsort(depths):
        loop_splits = [
            (crossing.first_arc + crossing.second_arc) / 2.0
            for crossing in raw_crossings
            if crossing.first == crossing.second == index
        ]
        paints += _draw_cable(labels, curves[index], colours[index], index + 1, loop_splits)
    for rect in rects:
        paints.append(_draw_occluder(rng, labels, rect, background_level))
    image = _compose(rng, grey, tint, paints, noise_sigma)
    del grey  # 4 bytes a pixel: free it before the mask is made

    cables = [
        SyntheticCable(
            centreline=curve.points,
            radius=curve.radius,
            colour=colours[index],
            hidden=_hidden_samples(curve.points, rects),
            depth=int(depths[index]),
        )
        for index, curve in enumerate(curves)
    ]
    crossings = [_public_crossing(crossing, depths) for crossing in raw_crossings]
    return SyntheticScene(
        image=image,
        mask=labels > 0,
        labels=labels,
        cables=cables,
        crossings=crossings,
        occluders=[Occluder(polygon=rect.corners()) for rect in rects],
    )


# --------------------------------------------------------------------------- validation


def _validate_arguments(
    width, height, n_cables, seed, radius_range, occluders, background, noise_sigma, margin
) -> None:
    for name, value in (("width", width), ("height", height)):
        if not _is_int(value) or value < MIN_IMAGE_SIDE:
            raise ValueError(f"{name} must be an integer >= {MIN_IMAGE_SIDE}, got {value!r}")
    if not _is_int(n_cables) or not 0 <= n_cables <= MAX_CABLES:
        raise ValueError(f"n_cables must be an integer from 0 to {MAX_CABLES}, got {n_cables!r}")
    if seed is not None and (not _is_int(seed) or seed < 0):
        raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
    try:
        low, high = (float(value) for value in radius_range)
    except (TypeError, ValueError):
        raise ValueError(
            f"radius_range must be two numbers (low, high), got {radius_range!r}"
        ) from None
    if not (math.isfinite(low) and math.isfinite(high) and MIN_CABLE_RADIUS <= low <= high):
        raise ValueError(
            f"radius_range must be sorted (low <= high) with low >= {MIN_CABLE_RADIUS} px, "
            f"got {radius_range!r}"
        )
    if not _is_int(occluders) or occluders < 0:
        raise ValueError(f"occluders must be a non-negative integer, got {occluders!r}")
    if occluders > 0 and n_cables == 0:
        raise ValueError("occluders are laid across cables, so they need n_cables >= 1")
    if background not in ("textured", "plain"):
        raise ValueError(f"background must be 'textured' or 'plain', got {background!r}")
    if not _is_real(noise_sigma) or not 0 <= noise_sigma < math.inf:
        raise ValueError(f"noise_sigma must be a finite number >= 0, got {noise_sigma!r}")
    if margin is not None:
        if not _is_real(margin) or not 0 <= margin < math.inf:
            raise ValueError(f"margin must be None or a finite number >= 0, got {margin!r}")
        if min(width, height) - 2 * margin < 32:
            raise ValueError(
                f"margin {margin!r} leaves less than 32 px between the borders of a "
                f"{width}x{height} image"
            )


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)


def _is_real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


# --------------------------------------------------------------------------- curves


@dataclass(frozen=True, eq=False)
class _Curve:
    """A cable centreline with its arc lengths and a nearest-sample index."""

    points: np.ndarray
    arc: np.ndarray
    radius: float
    tree: cKDTree

    @classmethod
    def from_points(cls, points: np.ndarray, radius: float) -> _Curve:
        steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(steps)])
        return cls(points=points, arc=arc, radius=radius, tree=cKDTree(points))

    @property
    def length(self) -> float:
        return float(self.arc[-1])

    @cached_property
    def chunk_boxes(self) -> np.ndarray:
        return _chunk_boxes(self.points, _INTERSECTION_CHUNK)


@dataclass(frozen=True)
class _Crossing:
    """Two centrelines crossing, before depths decide which one is on top."""

    x: float
    y: float
    first: int
    second: int
    first_arc: float
    second_arc: float
    angle: float  # between the two tangents, 0 to pi/2
    reach: float  # largest radius of the two cables: sets how far apart crossings stay


def _place_cables(rng, width, height, n_cables, radius_range, loops, margin):
    """Draw cables one at a time, resampling each until it obeys the layout rules."""
    if margin is None:
        box = (0.0, 0.0, width - 1.0, height - 1.0)
    else:
        box = (margin, margin, width - 1.0 - margin, height - 1.0 - margin)
    box_width, box_height = box[2] - box[0], box[3] - box[1]
    # Cables that may run off the image are grown around a point in the middle, so that
    # most of each stays in view.
    anchor_box = (
        box[0] + 0.2 * box_width,
        box[1] + 0.2 * box_height,
        box[2] - 0.2 * box_width,
        box[3] - 0.2 * box_height,
    )
    diagonal = math.hypot(width, height)

    curves: list[_Curve] = []
    crossings: list[_Crossing] = []
    for index in range(n_cables):
        for attempt in range(_CABLE_ATTEMPTS):
            radius = float(rng.uniform(*radius_range))
            # Shorter cables fit more easily; shrink them if the first tries keep failing.
            shrink = 1.0 - 0.5 * attempt / _CABLE_ATTEMPTS
            if margin is None:
                length = rng.uniform(0.6, 1.2) * diagonal * shrink
            else:
                length = rng.uniform(0.6, 1.2) * math.hypot(box_width, box_height) * shrink
            with_loop = loops and rng.random() < 0.5
            points, anchor_index = _random_centreline(rng, radius, length, diagonal, with_loop)
            if margin is None:
                points = points + rng.uniform(anchor_box[:2], anchor_box[2:])
                points = _clip_to_box(points, anchor_index, box)
            else:
                points = _fit_inside_box(rng, points, box)
            if points is None:
                continue
            curve = _Curve.from_points(points, radius)
            if curve.length < max(0.25 * min(box_width, box_height), 8.0 * radius):
                continue
            new_crossings = _crossings_if_well_placed(curve, index, curves, crossings)
            if new_crossings is not None:
                curves.append(curve)
                crossings.extend(new_crossings)
                break
        else:
            raise RuntimeError(
                f"could not place cable {index + 1} of {n_cables} in a {width}x{height} image "
                f"with radius_range={radius_range!r}; use fewer or thinner cables or a "
                "larger image"
            )
    return curves, crossings


def _random_centreline(rng, radius, length, diagonal, with_loop):
    """Integrate a smoothly varying curvature into a centreline, optionally with a loop.

    Returns the ``(N, 2)`` samples and the index of the anchor sample, which sits at the
    origin: a point near the middle, or the far side of the loop if there is one.
    """
    n_segments = max(2, math.ceil(length / SAMPLE_SPACING))
    total = n_segments * SAMPLE_SPACING
    # Bending tighter than 4 radii would pinch the drawn tube into a kink.
    max_curvature = 1.0 / (4.0 * radius)
    curvature = _smooth_random_curvature(rng, n_segments, diagonal, max_curvature)
    segment_mid_arc = (np.arange(n_segments) + 0.5) * SAMPLE_SPACING

    anchor_arc = rng.uniform(0.35, 0.65) * total
    if with_loop:
        # A loop is a straight arm, a circular arc turning by pi + beta, and a straight arm
        # back: the arms are tangent to the circle and meet where they started, so the
        # cable crosses itself there at angle beta. Its radius of >= 5 cable radii keeps the
        # hole open.
        loop_radius = rng.uniform(5.0 * radius, max(7.0 * radius, 0.04 * diagonal))
        beta = rng.uniform(math.radians(45.0), math.radians(100.0))
        arm = loop_radius / math.tan(beta / 2.0)
        turn_length = loop_radius * (math.pi + beta)
        loop_length = 2.0 * arm + turn_length
        if loop_length <= 0.5 * total:
            start = rng.uniform(0.25 * total, 0.75 * total - loop_length)
            turn_start, turn_end = start + arm, start + arm + turn_length
            in_loop = (segment_mid_arc >= start) & (segment_mid_arc < start + loop_length)
            curvature[in_loop] = 0.0
            turning = (segment_mid_arc >= turn_start) & (segment_mid_arc < turn_end)
            curvature[turning] = rng.choice([-1.0, 1.0]) / loop_radius
            anchor_arc = (turn_start + turn_end) / 2.0

    # Each step follows the heading at its middle, which is exact for circular arcs.
    headings = rng.uniform(0.0, 2.0 * math.pi) + (np.cumsum(curvature) - curvature / 2.0) * (
        SAMPLE_SPACING
    )
    steps = SAMPLE_SPACING * np.column_stack([np.cos(headings), np.sin(headings)])
    points = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    anchor_index = min(round(anchor_arc / SAMPLE_SPACING), n_segments)
    return points - points[anchor_index], anchor_index


def _smooth_random_curvature(rng, n_segments, diagonal, max_curvature):
    """Curvature per segment: random knots, linearly joined, then box-smoothed."""
    knot_spacing = diagonal * rng.uniform(0.05, 0.12)
    typical_curvature = 1.0 / (diagonal * rng.uniform(0.08, 0.2))
    n_knots = int(n_segments * SAMPLE_SPACING / knot_spacing) + 3
    knots = rng.normal(0.0, typical_curvature, n_knots)
    knot_arcs = (np.arange(n_knots) - 1.0) * knot_spacing
    segment_mid_arc = (np.arange(n_segments) + 0.5) * SAMPLE_SPACING
    curvature = np.interp(segment_mid_arc, knot_arcs, knots)
    # Smoothing over one knot spacing rounds off the corners of the linear joins, so the
    # curvature changes gradually and the cable has no visible bends at the knots.
    window = max(1, int(knot_spacing / SAMPLE_SPACING))
    padded = np.pad(curvature, (window // 2, window - 1 - window // 2), mode="edge")
    curvature = np.convolve(padded, np.full(window, 1.0 / window), mode="valid")
    return np.clip(curvature, -0.8 * max_curvature, 0.8 * max_curvature)


def _fit_inside_box(rng, points, box, tries=8):
    """Turn and shift the whole curve to a random place inside ``box``, or return None.

    Turning the curve keeps its shape; for each random turn the shifts that fit form a
    rectangle, so one can be drawn directly instead of by trial and error.
    """
    for _ in range(tries):
        angle = rng.uniform(0.0, 2.0 * math.pi)
        rotation = np.array(
            [[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]]
        )
        turned = points @ rotation.T
        low = np.array(box[:2]) - turned.min(axis=0)
        high = np.array(box[2:]) - turned.max(axis=0)
        if np.all(low <= high):
            return turned + rng.uniform(low, high)
    return None


def _clip_to_box(points, anchor_index, box):
    """Keep the contiguous piece inside ``box`` around the anchor, ends cut at the border."""
    x_min, y_min, x_max, y_max = box
    inside = (
        (points[:, 0] >= x_min)
        & (points[:, 0] <= x_max)
        & (points[:, 1] >= y_min)
        & (points[:, 1] <= y_max)
    )
    outside_before = np.flatnonzero(~inside[:anchor_index])
    outside_after = np.flatnonzero(~inside[anchor_index:])
    first = outside_before[-1] + 1 if outside_before.size else 0
    last = anchor_index + outside_after[0] - 1 if outside_after.size else len(points) - 1
    if last - first < 1:
        return None
    pieces = [points[first : last + 1]]
    if first > 0:
        pieces.insert(0, _border_point(points[first], points[first - 1], box))
    if last < len(points) - 1:
        pieces.append(_border_point(points[last], points[last + 1], box))
    return np.vstack(pieces)


def _border_point(inside, outside, box):
    """Where the step from ``inside`` to ``outside`` leaves ``box``, as a (0 or 1, 2) array."""
    step = outside - inside
    fraction = 1.0
    for axis, (low, high) in enumerate(((box[0], box[2]), (box[1], box[3]))):
        if outside[axis] < low:
            fraction = min(fraction, (low - inside[axis]) / step[axis])
        elif outside[axis] > high:
            fraction = min(fraction, (high - inside[axis]) / step[axis])
    # A border point on top of the last inside sample would make a zero-length segment.
    if fraction * np.linalg.norm(step) < 1e-6:
        return np.empty((0, 2))
    # Clipping removes rounding error that would leave the point a hair outside the box.
    point = np.clip(inside + fraction * step, [box[0], box[1]], [box[2], box[3]])
    return point[None, :]


# --------------------------------------------------------------------------- layout rules


def _crossings_if_well_placed(curve, index, placed, existing_crossings):
    """Crossings the new curve adds, or None if it breaks a layout rule.

    The cheap rules (crossing angles and spacing, cable ends) are checked before the
    costlier search for stretches where two cables run close together.
    """
    radius = curve.radius
    # Beyond this arc distance two parts of one curve can only be near each other by coming
    # back (the curve bends no tighter than 4 radii).
    same_curve_window = 8.0 * radius

    self_crossings = [
        _Crossing(*hit[:2], index, index, *hit[2:], reach=radius)
        for hit in _intersections(curve, curve, same=True)
    ]
    pair_crossings = [
        [
            _Crossing(*hit[:2], index, other_index, *hit[2:], reach=max(radius, other.radius))
            for hit in _intersections(curve, other, same=False)
        ]
        for other_index, other in enumerate(placed)
    ]
    found = self_crossings + [crossing for pair in pair_crossings for crossing in pair]
    if any(crossing.angle < MIN_CROSSING_ANGLE for crossing in found):
        return None
    if not _crossings_spread_out(found, existing_crossings):
        return None

    # A cable end lying on a cable would look like a junction.
    for end_arc, end in ((0.0, curve.points[0]), (curve.length, curve.points[-1])):
        nearby = curve.tree.query_ball_point(end, 3.0 * radius)
        if np.any(np.abs(curve.arc[nearby] - end_arc) > same_curve_window):
            return None
    for other in placed:
        end_clearance = 3.0 * max(radius, other.radius)
        if np.min(other.tree.query(curve.points[[0, -1]])[0]) < end_clearance:
            return None
        if np.min(curve.tree.query(other.points[[0, -1]])[0]) < end_clearance:
            return None

    coarse = slice(None, None, 4)  # 2 px apart: plenty for measuring close stretches
    coarse_arc = curve.arc[coarse]
    clearance = 5.0 * radius
    pairs = cKDTree(curve.points[coarse]).query_pairs(clearance, output_type="ndarray")
    if len(pairs):
        pairs = pairs[np.abs(coarse_arc[pairs[:, 0]] - coarse_arc[pairs[:, 1]]) > same_curve_window]
    close = np.zeros(len(coarse_arc), dtype=bool)
    close[pairs.ravel()] = True
    events = [c.first_arc for c in self_crossings] + [c.second_arc for c in self_crossings]
    angles = [c.angle for c in self_crossings] * 2
    if not _close_stretches_ok(close, coarse_arc, events, angles, clearance, 6 * radius):
        return None
    for other, crossings in zip(placed, pair_crossings, strict=True):
        radius_sum = radius + other.radius
        clearance = 2.5 * radius_sum
        angles = [c.angle for c in crossings]
        close = other.tree.query(curve.points[coarse], distance_upper_bound=clearance)[0]
        events = [c.first_arc for c in crossings]
        if not _close_stretches_ok(
            close < clearance, coarse_arc, events, angles, clearance, 3 * radius_sum
        ):
            return None
        close = curve.tree.query(other.points[coarse], distance_upper_bound=clearance)[0]
        events = [c.second_arc for c in crossings]
        if not _close_stretches_ok(
            close < clearance, other.arc[coarse], events, angles, clearance, 3 * radius_sum
        ):
            return None
    return found


def _crossings_spread_out(new_crossings, existing_crossings):
    """Crossings closer than a few cable widths would merge into one tangle."""
    every = list(existing_crossings) + list(new_crossings)
    for position, crossing in enumerate(new_crossings, start=len(existing_crossings)):
        for other_position, other in enumerate(every):
            if other_position == position:
                continue
            distance = math.hypot(crossing.x - other.x, crossing.y - other.y)
            if distance < 6.0 * max(crossing.reach, other.reach):
                return False
    return True


def _close_stretches_ok(close, arc, event_arcs, event_angles, clearance, free_length):
    """Check every stretch of ``close`` samples against the length a crossing explains.

    A stretch with no crossing may be ``free_length`` long; one with a crossing at angle
    ``a`` may also span the ``2 * clearance / sin(a)`` that crossing lines stay close for;
    a stretch holding two crossings means the cables wind round each other.
    """
    event_arcs = np.asarray(event_arcs, dtype=float)
    event_angles = np.asarray(event_angles, dtype=float)
    step = arc[1] - arc[0] if len(arc) > 1 else 0.0
    for start, stop in zip(*_true_runs(close), strict=True):
        low, high = arc[start] - step, arc[stop - 1] + step
        inside = (event_arcs >= low) & (event_arcs <= high)
        stretch = arc[stop - 1] - arc[start]
        if np.count_nonzero(inside) > 1:
            return False
        allowed = free_length
        if np.any(inside):
            angle = max(float(event_angles[inside][0]), MIN_CROSSING_ANGLE)
            allowed += 2.0 * clearance / math.sin(angle)
        if stretch > allowed:
            return False
    return True


def _true_runs(flags):
    """Start and stop (exclusive) indices of the runs of True in a 1-D bool array."""
    padded = np.concatenate([[False], flags, [False]]).astype(np.int8)
    edges = np.diff(padded)
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _intersections(a, b, *, same):
    """Every crossing of two polylines (or of one with itself) as tuples.

    Each tuple is ``(x, y, arc_a, arc_b, angle)``. Segments are grouped into short chunks
    whose bounding boxes are compared first, so only segments near each other are tested
    exactly. Parameters run over ``[0, 1)`` so a crossing through a sample counts once.
    """
    chunk = _INTERSECTION_CHUNK
    # Only chunks inside the other curve's bounding box can meet it: usually a few.
    chunks_a = _chunks_overlapping(a.chunk_boxes, _bounding_box(b.points))
    chunks_b = _chunks_overlapping(b.chunk_boxes, _bounding_box(a.points))
    boxes_a, boxes_b = a.chunk_boxes[chunks_a], b.chunk_boxes[chunks_b]
    overlap = (
        (boxes_a[:, None, 0] <= boxes_b[None, :, 2])
        & (boxes_b[None, :, 0] <= boxes_a[:, None, 2])
        & (boxes_a[:, None, 1] <= boxes_b[None, :, 3])
        & (boxes_b[None, :, 1] <= boxes_a[:, None, 3])
    )
    if same:
        # Neighbouring chunks share a sample; a smooth curve cannot cross itself that soon.
        overlap &= chunks_b[None, :] >= chunks_a[:, None] + 2
    pair_a, pair_b = np.nonzero(overlap)
    chunks_a, chunks_b = chunks_a[pair_a], chunks_b[pair_b]
    if chunks_a.size == 0:
        return []
    offsets = np.arange(chunk)
    seg_a = (chunks_a[:, None, None] * chunk + offsets[None, :, None]).repeat(chunk, axis=2)
    seg_b = (chunks_b[:, None, None] * chunk + offsets[None, None, :]).repeat(chunk, axis=1)
    seg_a, seg_b = seg_a.ravel(), seg_b.ravel()
    valid = (seg_a < len(a.points) - 1) & (seg_b < len(b.points) - 1)
    seg_a, seg_b = seg_a[valid], seg_b[valid]

    start_a, start_b = a.points[seg_a], b.points[seg_b]
    dir_a, dir_b = a.points[seg_a + 1] - start_a, b.points[seg_b + 1] - start_b
    gap = start_b - start_a
    denominator = dir_a[:, 0] * dir_b[:, 1] - dir_a[:, 1] * dir_b[:, 0]
    parallel = np.abs(denominator) < 1e-12
    denominator = np.where(parallel, 1.0, denominator)
    t = (gap[:, 0] * dir_b[:, 1] - gap[:, 1] * dir_b[:, 0]) / denominator
    u = (gap[:, 0] * dir_a[:, 1] - gap[:, 1] * dir_a[:, 0]) / denominator
    hit = ~parallel & (t >= 0) & (t < 1) & (u >= 0) & (u < 1)

    length_a = np.linalg.norm(dir_a[hit], axis=1)
    length_b = np.linalg.norm(dir_b[hit], axis=1)
    where = start_a[hit] + t[hit, None] * dir_a[hit]
    arc_a = a.arc[seg_a[hit]] + t[hit] * length_a
    arc_b = b.arc[seg_b[hit]] + u[hit] * length_b
    sine = np.clip(np.abs(denominator[hit]) / (length_a * length_b), 0.0, 1.0)
    angle = np.arcsin(sine)
    order = np.argsort(arc_a)
    return [
        (float(where[i, 0]), float(where[i, 1]), float(arc_a[i]), float(arc_b[i]), float(angle[i]))
        for i in order
    ]


def _bounding_box(points):
    return np.concatenate([points.min(axis=0), points.max(axis=0)])


def _chunks_overlapping(chunk_boxes, box):
    """Indices of the chunk boxes that overlap ``box`` (both ``[x0, y0, x1, y1]``)."""
    return np.flatnonzero(
        (chunk_boxes[:, 0] <= box[2])
        & (chunk_boxes[:, 2] >= box[0])
        & (chunk_boxes[:, 1] <= box[3])
        & (chunk_boxes[:, 3] >= box[1])
    )


def _chunk_boxes(points, chunk):
    """Bounding boxes ``[x_min, y_min, x_max, y_max]`` of consecutive ``chunk`` segments."""
    low = np.minimum(points[:-1], points[1:])
    high = np.maximum(points[:-1], points[1:])
    n_chunks = -(-len(low) // chunk)
    pad = n_chunks * chunk - len(low)
    low = np.pad(low, ((0, pad), (0, 0)), mode="edge").reshape(n_chunks, chunk, 2).min(axis=1)
    high = np.pad(high, ((0, pad), (0, 0)), mode="edge").reshape(n_chunks, chunk, 2).max(axis=1)
    return np.hstack([low, high])


def _public_crossing(crossing, depths):
    """Name the cable on top: higher depth, or the later part of a self-crossing loop."""
    first_on_top = (
        crossing.first_arc > crossing.second_arc
        if crossing.first == crossing.second
        else depths[crossing.first] > depths[crossing.second]
    )
    if first_on_top:
        over, under = crossing.first, crossing.second
        over_arc, under_arc = crossing.first_arc, crossing.second_arc
    else:
        over, under = crossing.second, crossing.first
        over_arc, under_arc = crossing.second_arc, crossing.first_arc
    return SyntheticCrossing(
        x=crossing.x,
        y=crossing.y,
        over=int(over),
        under=int(under),
        over_arc=over_arc,
        under_arc=under_arc,
    )


# --------------------------------------------------------------------------- occluders


@dataclass(frozen=True)
class _Rect:
    """A rotated rectangle: centre, direction of its length, and half sizes."""

    centre: np.ndarray
    angle: float
    half_length: float
    half_width: float

    def local(self, points):
        """Coordinates along the length (u) and across it (v)."""
        along = np.array([math.cos(self.angle), math.sin(self.angle)])
        across = np.array([-along[1], along[0]])
        offset = np.asarray(points, dtype=float) - self.centre
        return offset @ along, offset @ across

    def contains(self, points, pad=0.0):
        u, v = self.local(points)
        return (np.abs(u) <= self.half_length + pad) & (np.abs(v) <= self.half_width + pad)

    def corners(self):
        signs = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        along = np.array([math.cos(self.angle), math.sin(self.angle)])
        across = np.array([-along[1], along[0]])
        return (
            self.centre
            + (signs[:, :1] * self.half_length) * along
            + (signs[:, 1:] * self.half_width) * across
        )


def _place_occluders(rng, count, curves, crossings, width, height):
    rects: list[_Rect] = []
    for number in range(count):
        for _ in range(_OCCLUDER_ATTEMPTS):
            target = int(rng.integers(len(curves)))
            rect = _propose_occluder(rng, curves[target])
            if rect is not None and _occluder_fits(
                rect, target, curves, crossings, rects, width, height
            ):
                rects.append(rect)
                break
        else:
            raise RuntimeError(
                f"could not place occluder {number + 1} of {count} across a cable without "
                "covering a crossing or a cable end; use fewer occluders or more cables"
            )
    return rects


def _propose_occluder(rng, curve):
    """A rectangle laid across ``curve``, hiding a 20-80 px stretch of it."""
    radius = curve.radius
    half_length = rng.uniform(20.0, 80.0) / 2.0
    half_width = rng.uniform(3.0, 10.0) * radius / 2.0
    # The hidden stretch, its padding and 3 radii on both sides must fit inside the cable.
    reach = half_length + 2.0 * radius + 2.0 + 3.0 * radius
    if curve.length <= 2.0 * reach:
        return None
    centre_arc = rng.uniform(reach, curve.length - reach)
    index = int(np.searchsorted(curve.arc, centre_arc))
    behind, ahead = max(index - 4, 0), min(index + 4, len(curve.points) - 1)
    tangent = curve.points[ahead] - curve.points[behind]
    # Tilt and shift only as far as the rectangle still covers the cable's whole width.
    slack = half_width - radius
    max_tilt = 0.8 * math.atan2(slack, half_length + radius)
    angle = math.atan2(tangent[1], tangent[0]) + rng.uniform(-max_tilt, max_tilt)
    normal = np.array([-tangent[1], tangent[0]]) / np.linalg.norm(tangent)
    centre = curve.points[index] + rng.uniform(-0.3, 0.3) * slack * normal
    return _Rect(centre=centre, angle=angle, half_length=half_length, half_width=half_width)


def _occluder_fits(rect, target, curves, crossings, rects, width, height):
    corners = rect.corners()
    if corners.min() < 0 or np.any(corners.max(axis=0) > [width - 1, height - 1]):
        return False
    size = math.hypot(rect.half_length, rect.half_width)
    for other in rects:
        other_size = math.hypot(other.half_length, other.half_width)
        if np.linalg.norm(rect.centre - other.centre) < size + other_size + 4.0:
            return False
    for crossing in crossings:
        if rect.contains([crossing.x, crossing.y], pad=3.0 * crossing.reach):
            return False
    for index, curve in enumerate(curves):
        radius = curve.radius
        near = rect.contains(curve.points, pad=radius + 2.0)
        if index != target:
            # Covering a second cable would cut it arbitrarily; keep occluders to one.
            if np.any(near):
                return False
            continue
        starts, stops = _true_runs(near)
        if len(starts) != 1:
            return False
        first_arc, last_arc = curve.arc[starts[0]], curve.arc[stops[0] - 1]
        if first_arc < 3.0 * radius or last_arc > curve.length - 3.0 * radius:
            return False
        # Wherever the cable is level with the rectangle it must be covered across its whole
        # width, so it disappears at the short sides instead of peeking out along the long.
        u, v = rect.local(curve.points)
        level = near & (np.abs(u) <= rect.half_length + radius)
        if np.any(np.abs(v[level]) > rect.half_width - radius):
            return False
        if not np.any(rect.contains(curve.points)):
            return False
    return True


def _hidden_samples(points, rects):
    hidden = np.zeros(len(points), dtype=bool)
    for rect in rects:
        hidden |= rect.contains(points)
    return hidden


# --------------------------------------------------------------------------- drawing

# Pixels per band when the image is composed (_compose): about 3 MB of float32 BGR.
_BAND_PIXELS = 1 << 18


@dataclass(frozen=True, eq=False)
class _Paint:
    """Pixels to set, ``image[rows, cols] = bgr``, over what lies below."""

    rows: np.ndarray
    cols: np.ndarray
    bgr: np.ndarray  # shape (N, 3), float32


def _draw_background(rng, width, height, kind):
    """A dark, low-saturation background: grey levels and a BGR tint, and the mean level.

    Returns
    -------
    grey : ndarray, shape (H, W), float32
    tint : ndarray, shape (3,), float32
        The background's BGR values are ``grey[:, :, None] * tint``.
    level : float
    """
    direction = rng.uniform(0.0, 2.0 * math.pi)
    if kind == "plain":
        level = rng.uniform(45.0, 70.0)
        x = np.arange(width, dtype=np.float32)[None, :]
        y = np.arange(height, dtype=np.float32)[:, None]
        grey = x * np.float32(math.cos(direction)) + y * np.float32(math.sin(direction))
        slope = rng.uniform(4.0, 10.0) * 2.0 / math.hypot(width, height)
        # level + slope * along, in place: no whole-image temporaries.
        grey *= np.float32(slope)
        grey += np.float32(level)
    else:
        level = rng.uniform(40.0, 70.0)
        # The texture has no detail finer than a few pixels, so it is made at half size
        # and enlarged: a quarter of the work, which matters at 4K.
        small_width, small_height = -(-width // 2), -(-height // 2)
        grey = np.float32(level) + 7.0 * _smooth_noise(
            rng, small_width, small_height, max(small_width, small_height) / 6
        )
        grey += 3.0 * _smooth_noise(rng, small_width, small_height, 12.0)
        with_grid = rng.random() >= 0.6
        if not with_grid:
            # Wood-like grain: stripes across ``direction``, warped by slow noise.
            period = rng.uniform(10.0, 28.0) / 2.0
            x = np.arange(small_width, dtype=np.float32)[None, :]
            y = np.arange(small_height, dtype=np.float32)[:, None]
            along = x * np.float32(math.cos(direction)) + y * np.float32(math.sin(direction))
            warp = (2.0 * math.pi * 0.8) * _smooth_noise(rng, small_width, small_height, 80.0)
            phase = along * np.float32(2.0 * math.pi / period) + warp
            grey += 3.0 * np.sin(phase) + 1.5 * np.sin(2.7 * phase + 1.3 * warp)
        grey = cv2.resize(grey, (width, height), interpolation=cv2.INTER_LINEAR)
        if with_grid:
            # A faint cutting-mat grid, drawn at full size to keep its lines crisp.
            spacing = rng.uniform(40.0, 90.0)
            column_on_line = np.mod(np.arange(width), spacing) < 1.5
            row_on_line = np.mod(np.arange(height), spacing) < 1.5
            on_line = column_on_line[None, :] | row_on_line[:, None]
            # Adding the line strength only where on_line is the same as adding
            # ``strength * on_line`` everywhere, without a whole-image float temporary.
            np.add(grey, np.float32(rng.uniform(4.0, 7.0)), out=grey, where=on_line)
    tint = (1.0 + rng.uniform(-0.04, 0.04, 3)).astype(np.float32)
    return np.ascontiguousarray(grey, dtype=np.float32), tint, float(level)


def _compose(rng, grey, tint, paints, noise_sigma):
    """The uint8 BGR image: background, paints in order, sensor noise, rounded.

    Made in bands of rows, so that only one band is ever held in float32; every pixel
    goes through the same float32 operations in the same order as if the whole image
    were made at once, and the noise bytes are drawn in the same order.
    """
    height, width = grey.shape
    image = np.empty((height, width, 3), dtype=np.uint8)
    # A multiple of 4 rows makes every band's noise a whole number of the 4-byte words
    # rng.bytes draws, so the bands together draw exactly the bytes of one big call.
    band_rows = max(4, _BAND_PIXELS // width // 4 * 4)
    noise_levels = _NOISE_LEVELS * np.float32(noise_sigma)
    for top in range(0, height, band_rows):
        bottom = min(top + band_rows, height)
        band = grey[top:bottom, :, None] * tint[None, None, :]
        for paint in paints:
            inside = (paint.rows >= top) & (paint.rows < bottom)
            band[paint.rows[inside] - top, paint.cols[inside]] = paint.bgr[inside]
        if noise_sigma > 0:
            band += _gaussian_noise(rng, band.shape, noise_levels)
        band += 0.5  # so that truncating to uint8 rounds to nearest
        image[top:bottom] = np.clip(band, 0.0, 255.0, out=band).astype(np.uint8)
    return image


def _gaussian_noise(rng, shape, noise_levels):
    """Zero-mean float32 noise: ``noise_levels`` (scaled ``_NOISE_LEVELS``) looked up."""
    random_bytes = np.frombuffer(rng.bytes(math.prod(shape)), dtype=np.uint8).reshape(shape)
    return cv2.LUT(random_bytes, noise_levels)


def _smooth_noise(rng, width, height, feature_size):
    """Unit-variance-ish noise with blobs about ``feature_size`` px across, float32."""
    small_width = max(2, round(width / feature_size) + 1)
    small_height = max(2, round(height / feature_size) + 1)
    small = rng.standard_normal((small_height, small_width), dtype=np.float32)
    return cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)


def _pick_colours(rng, n_cables):
    order = rng.permutation(len(_PALETTE_BGR))
    colours = []
    for index in range(n_cables):
        base = np.array(_PALETTE_BGR[order[index % len(order)]])
        jittered = np.clip(base + rng.integers(-10, 11, 3), 0, 255)
        colours.append(tuple(int(channel) for channel in jittered))
    return colours


def _draw_cable(labels, curve, colour, label, loop_splits):
    """Label the pixels of a tube of ``curve.radius`` around the centreline; shade them.

    Returns the shaded pixels as one paint per layer, to lay on the background in order.
    A cable that crosses itself is drawn in layers split half-way round each loop, later
    layers on top, so the later part lies over the earlier one at the crossing. Each layer
    is measured against its stretch plus a little overlap, but paints only the pixels whose
    nearest centreline point is its own, so the layers join without a seam.
    """
    radius = curve.radius
    overlap = radius + 2.0
    colour = np.array(colour, dtype=np.float32)
    bounds = [-math.inf, *sorted(loop_splits), math.inf]
    paints = []
    for low, high in pairwise(bounds):
        if len(bounds) == 2:
            points, arc, tree = curve.points, curve.arc, curve.tree
        else:
            first = max(int(np.searchsorted(curve.arc, low - overlap)) - 1, 0)
            last = min(
                int(np.searchsorted(curve.arc, high + overlap, side="right")) + 1, len(curve.arc)
            )
            points, arc = curve.points[first:last], curve.arc[first:last]
            tree = cKDTree(points)
        rows, cols = _band_pixels(points, radius, labels.shape)
        centres = np.column_stack([cols, rows]).astype(float)
        distance, foot, foot_arc = _nearest_on_polyline(points, arc, tree, centres, radius + 1.5)
        keep = (distance <= radius) & (foot_arc >= low) & (foot_arc <= high)
        rows, cols = rows[keep], cols[keep]
        paints.append(_Paint(rows, cols, _shade(colour, (centres[keep] - foot[keep]) / radius)))
        labels[rows, cols] = label
    return paints


def _band_pixels(points, radius, shape):
    """Row and column indices of a band around the polyline, wider than the tube."""
    height, width = shape
    reach = radius + 3.0
    x0 = max(math.floor(points[:, 0].min() - reach), 0)
    y0 = max(math.floor(points[:, 1].min() - reach), 0)
    x1 = min(math.ceil(points[:, 0].max() + reach), width - 1)
    y1 = min(math.ceil(points[:, 1].max() + reach), height - 1)
    if x0 > x1 or y0 > y1:
        return np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
    band = np.zeros((y1 - y0 + 1, x1 - x0 + 1), dtype=np.uint8)
    # Every 4th sample (2 px chords) strays from the curve by far less than the band margin.
    outline = points[::4] if (len(points) - 1) % 4 == 0 else np.vstack([points[::4], points[-1:]])
    fixed_point = np.rint((outline - [x0, y0]) * 8.0).astype(np.int32)  # shift=3: 1/8 px
    thickness = 2 * math.ceil(radius) + 3
    cv2.polylines(band, [fixed_point.reshape(-1, 1, 2)], False, 255, thickness, cv2.LINE_8, 3)
    rows, cols = np.nonzero(band)
    return rows + y0, cols + x0


def _nearest_on_polyline(points, arc, tree, queries, max_distance):
    """Distance, nearest point and its arc length on the polyline, for each query point.

    Queries further than ``max_distance`` from every sample get an infinite distance.
    """
    n_queries = len(queries)
    distance = np.full(n_queries, np.inf)
    foot = np.zeros((n_queries, 2))
    foot_arc = np.full(n_queries, np.nan)
    _, nearest = tree.query(queries, distance_upper_bound=max_distance, workers=-1)
    found = nearest < len(points)
    if not np.any(found):
        return distance, foot, foot_arc
    query, nearest = queries[found], nearest[found]
    best = np.full(len(query), np.inf)
    best_foot = np.zeros_like(query)
    best_arc = np.zeros(len(query))
    # The nearest point of the polyline lies on a segment next to the nearest sample.
    for segment in (np.clip(nearest - 1, 0, len(points) - 2), np.clip(nearest, 0, len(points) - 2)):
        start = points[segment]
        step = points[segment + 1] - start
        step_squared = np.maximum(np.einsum("ij,ij->i", step, step), 1e-18)
        t = np.clip(np.einsum("ij,ij->i", query - start, step) / step_squared, 0.0, 1.0)
        candidate = start + t[:, None] * step
        candidate_distance = np.linalg.norm(query - candidate, axis=1)
        better = candidate_distance < best
        best = np.where(better, candidate_distance, best)
        best_foot[better] = candidate[better]
        best_arc[better] = arc[segment[better]] + t[better] * np.sqrt(step_squared[better])
    distance[found], foot[found], foot_arc[found] = best, best_foot, best_arc
    return distance, foot, foot_arc


def _shade(colour, outward):
    """BGR values of a lit cylinder (or hemispherical end) from the in-plane normal.

    ``outward`` is the pixel's offset from the centreline in radii, which is the in-plane
    part of the surface normal; the rest points at the camera.
    """
    facing = np.sqrt(np.clip(1.0 - np.einsum("ij,ij->i", outward, outward), 0.0, 1.0))
    normals = np.column_stack([outward, facing])
    diffuse = np.clip(normals @ _LIGHT, 0.0, 1.0)
    highlight = 0.45 * np.clip(normals @ _HALF_VECTOR, 0.0, 1.0) ** 24
    # The shadowed edge keeps 62% of the colour, still well clear of the dark background.
    brightness = 0.62 + 0.38 * diffuse
    shaded = colour[None, :] * (brightness * (1.0 - highlight))[:, None]
    return (shaded + 255.0 * highlight[:, None]).astype(np.float32)


def _draw_occluder(rng, labels, rect, background_level):
    """Clear the labels under the rectangle and return it painted dull, textured grey."""
    height, width = labels.shape
    corners = rect.corners()
    x0, y0 = np.maximum(np.floor(corners.min(axis=0)).astype(int), 0)
    x1 = min(math.ceil(corners[:, 0].max()), width - 1)
    y1 = min(math.ceil(corners[:, 1].max()), height - 1)
    rows, cols = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
    u, v = rect.local(np.column_stack([cols.ravel(), rows.ravel()]))
    inside = (np.abs(u) <= rect.half_length) & (np.abs(v) <= rect.half_width)
    rows, cols, u, v = rows.ravel()[inside], cols.ravel()[inside], u[inside], v[inside]

    grey = np.clip(background_level + rng.uniform(-8.0, 12.0), 35.0, 90.0)
    texture = _smooth_noise(rng, x1 - x0 + 1, y1 - y0 + 1, 6.0)[rows - y0, cols - x0]
    # A slightly darker rim makes it read as an object rather than a hole in the image.
    rim = np.minimum(rect.half_length - np.abs(u), rect.half_width - np.abs(v))
    value = (grey + 4.0 * texture) * (0.8 + 0.2 * np.clip(rim / 2.0, 0.0, 1.0))
    tint = 1.0 + rng.uniform(-0.05, 0.05, 3)
    labels[rows, cols] = 0
    return _Paint(rows, cols, (value[:, None] * tint[None, :]).astype(np.float32))
