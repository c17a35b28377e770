"""Cable contrast: cables found by what a cable is, not by what the background is.

A cable is thin and elongated, of nearly constant width and of one colour along its
length, and differs in colour from what lies beside it: it is darker, brighter or more
colourful than its surroundings, whatever those are. ``segmentation="contrast"`` looks
for exactly that, at every width from 5 px to 40 px, on bright, dark and textured
backgrounds, for dark and bright cables together:

1. **Colour.** The image goes to CIELAB, where the distance between two colours is the
   perceived difference (Delta E), and into a pyramid of levels a factor sqrt(2) apart
   (:func:`level_steps`): at one level or another every cable is 2.5 to 3.5 px wide.
2. **Line ratio.** At every level and for :data:`N_ORIENTATIONS` angles, the mean colour
   along a short segment through each pixel (:data:`HALF_LENGTH` px each way, about
   three widths) is compared with the mean colours along the parallel segments
   :data:`OFFSET` px to either side and with the local background (the median colour
   over :data:`BACKGROUND_WINDOW` px). The smallest of the three differences over the
   spread of colours along the segment is the pixel's line ratio: high along a cable
   (one colour, unlike both sides and the background), low across a step edge (one
   side alike), in texture (a wide spread) and on the background between two cables
   (the background's own colour). Each pixel keeps its best angle and level.
3. **Scale.** Cables in one picture are of comparable width: levels more than a factor
   :data:`SCALE_BAND` from the one that holds most of the lines' length are dropped
   (a wooden board's edge, a strip of paper margin).
4. **Seeds.** Pixels whose ratio is above Otsu's threshold of the ratios (and above
   :data:`MIN_RATIO` whatever Otsu says) are seeds; each gets its cable's colour and the
   colours round it (both sides, the background).
5. **Extent.** Every pixel near a seed is cable when its colour is nearer the seed's
   cable colour than each colour round it: the border falls half way between cable and
   background, whatever the two are, and a shadow or a blurred rim that looks more
   like the paper than like the cable stays out.
6. **Shape.** Components that are not cable-like are dropped (:func:`keep_cable_like`):
   compact blobs, and strokes much thinner than the typical cable of the picture.

Every threshold comes from the cable model or from perception, not from a data set:
a just noticeable colour difference (:data:`JND`), a three-sigma line (:data:`MIN_RATIO`),
Otsu's split of the ratios, and the half-way colour boundary.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from service.perception import (
    _cable_segmentation_kernels,
    _segmentation_kernels,
    _shared_kernels,
)

N_ORIENTATIONS = 8
"""Angles of the line segments, 22.5 degrees apart: a segment at most 11.25 degrees off a
cable stays within a 2.5 px cable over its length."""
HALF_LENGTH = 4.0
"""Each segment reaches this far (level px) either way: about three widths of a 2.5-3.5 px
cable, short enough to stay on a cable bending to a radius of four of its widths."""
OFFSET = 4
"""The side segments lie this far (level px) from the centre: beyond a 3.5 px cable's rim
from anywhere on its centre line."""
BACKGROUND_WINDOW = 4 * OFFSET + 1
"""The local background is the median colour over a window this wide (level px): a cable
covers under a fifth of it, two cables side by side under half."""
WIDE_WINDOW = 8 * OFFSET + 1
"""A line must also differ from the median colour over a window twice as wide, where two
cables crossing cover under a quarter: the paper in the angle between them (whose narrow
window two thick cables may fill half) is not taken for a line."""
REACH = 2.0
"""A pixel is judged against its nearest seed when that seed lies within this many level
px: half the widest cable a level is made for (3.5 px), rounded up."""
FINEST_STEP = 2.0
"""The finest level takes every other pixel: cables from 5 px wide are 2.5 px there."""
COARSEST_STEP = 16.0
"""The coarsest level brings cables 40 px wide down to 2.5 px."""
LEVEL_RATIO = float(np.sqrt(2.0))
MIN_LEVEL_SIDE = 2 * BACKGROUND_WINDOW
"""A level must hold two background windows across its shorter side."""
JND = 2.3
"""A just noticeable colour difference in CIELAB (Delta E 2.3, Sharma 2003): the spread
along a segment is never taken as smaller, so that colours nobody can tell apart give
no line."""
RATIO_BINS = 20.0
"""Ratios are binned in steps of 1/20 for Otsu's threshold (ratios above 12.75, certainly
lines, share the top bin)."""
MIN_RATIO = 3.0
"""A seed's line differs from its sides and from the background by at least three times
the spread of colours along it. A table without cables (plain or textured) has no line
near that, and gives an empty mask."""
SCALE_BAND = 2.0
"""Cables of one picture are within this factor of the typical width: the levels, and the
components' widths, outside the band are dropped."""
MIN_ELONGATION = 3.0
"""A component is at least this many of its widths long (by the measure of
:func:`keep_cable_like`, a disc or a square is 2.3 widths long)."""


@dataclass(frozen=True)
class Level:
    """One pyramid level: its sampling step, Lab image, background and line ratios."""

    step: float
    lab8: np.ndarray
    background8: np.ndarray
    ratio: np.ndarray
    orientation: np.ndarray


@dataclass(frozen=True)
class CableContrast:
    """The mask and what it was made from (:func:`cable_contrast`).

    Attributes
    ----------
    mask : ndarray of bool
        ``(H, W)``, True on cable pixels.
    ratio : ndarray of float32
        The best line ratio of each pixel of the finest level's grid.
    level : ndarray of int64
        Which level gave it (an index into ``levels``).
    seeds : ndarray of bool
        The seeds on that grid.
    levels : list of Level
    used_levels : list of int
        The levels within the scale band.
    """

    mask: np.ndarray
    ratio: np.ndarray
    level: np.ndarray
    seeds: np.ndarray
    levels: list[Level]
    used_levels: list[int]


def level_steps(height: int, width: int) -> list[float]:
    """The pyramid's sampling steps (image px per level px), finest first.

    From :data:`FINEST_STEP` to :data:`COARSEST_STEP` by factors of sqrt(2), as long as a
    level keeps :data:`MIN_LEVEL_SIDE` px across; an image too small for the finest
    level is taken as it is (one level of step 1).
    """
    steps = []
    step = FINEST_STEP
    while step <= COARSEST_STEP * (1 + 1e-9) and min(height, width) / step >= MIN_LEVEL_SIDE:
        steps.append(step)
        step *= LEVEL_RATIO
    return steps or [1.0]


def segment_cables(
    image_bgr: np.ndarray, min_component_area: int = 0, max_hole_area: int = 0
) -> np.ndarray:
    """Foreground mask of the cables in a BGR image, by their contrast with their sides.

    Parameters
    ----------
    image_bgr : ndarray
        ``(H, W, 3)`` BGR ``uint8``.
    min_component_area, max_hole_area : int
        The clean-up of :func:`service.perception.segmentation.clean_mask`.

    Returns
    -------
    ndarray of bool
        ``(H, W)``; empty when nothing in the image looks like a cable.

    Examples
    --------
    >>> import cv2, numpy as np
    >>> paper = np.full((160, 240, 3), 215, np.uint8)
    >>> _ = cv2.line(paper, (20, 40), (220, 120), (30, 30, 30), 9)  # a black cable
    >>> mask = segment_cables(paper)
    >>> bool(mask[80, 120]), bool(mask[20, 200])
    (True, False)
    """
    return cable_contrast(image_bgr, min_component_area, max_hole_area).mask


def cable_contrast(
    image_bgr: np.ndarray, min_component_area: int = 0, max_hole_area: int = 0
) -> CableContrast:
    """:func:`segment_cables`, with the line ratios, seeds and levels it used."""
    height, width = image_bgr.shape[:2]
    lab8 = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2Lab)
    levels = [_level(lab8, step) for step in level_steps(height, width)]
    used = list(range(len(levels)))
    ratio, best_level, seeds = _seeds(levels, used)
    if seeds.any():
        used = _within_scale_band(levels, best_level, seeds)
        if len(used) < len(levels):
            ratio, best_level, seeds = _seeds(levels, used)
    mask = np.zeros((height, width), bool)
    if seeds.any():
        candidates = _extent(lab8, levels, best_level, seeds)
        # Seeds hold the mask together: a candidate counts when it touches a seed.
        seeds_full = cv2.resize(
            seeds.view(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST
        )
        cue = candidates + (candidates & seeds_full)
        mask = _segmentation_kernels.threshold_and_clean(
            cue,
            0.5,
            1.5,
            int(np.count_nonzero(candidates)),
            int(min_component_area),
            int(max_hole_area),
        ).view(np.bool_)
        mask = keep_cable_like(mask)
    return CableContrast(mask, ratio, best_level, seeds, levels, used)


def _level(lab8: np.ndarray, step: float) -> Level:
    height, width = lab8.shape[:2]
    if step == 1.0:
        small = lab8
    else:
        size = (max(1, round(width / step)), max(1, round(height / step)))
        small = cv2.resize(lab8, size, interpolation=cv2.INTER_AREA)
    background, wide = _backgrounds(small)
    ratio, orientation = _cable_segmentation_kernels.level_contrast(
        small, background, wide, N_ORIENTATIONS, HALF_LENGTH, float(OFFSET), JND * JND
    )
    return Level(step, small, background, ratio, orientation)


def _backgrounds(lab8: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The local background colours of a level: medians over the two windows.

    The background changes slowly next to the windows' size, so the medians are taken
    on the level halved (windows halved, odd) and enlarged again: a quarter of the work.
    """
    height, width = lab8.shape[:2]
    half = cv2.resize(lab8, ((width + 1) // 2, (height + 1) // 2), interpolation=cv2.INTER_AREA)
    return tuple(
        cv2.resize(
            _median(half, (window // 2) | 1), (width, height), interpolation=cv2.INTER_LINEAR
        )
        for window in (BACKGROUND_WINDOW, WIDE_WINDOW)
    )


def _median(lab8: np.ndarray, window: int) -> np.ndarray:
    """Median of each channel over a ``window`` px square (OpenCV's O(1) median for uint8)."""
    channels = [cv2.medianBlur(np.ascontiguousarray(lab8[:, :, c]), window) for c in range(3)]
    return cv2.merge(channels)


def _seeds(levels: list[Level], used: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best ratio and level per pixel of the finest grid, and the seeds among them."""
    grid_h, grid_w = levels[0].ratio.shape
    best = np.zeros((grid_h, grid_w), np.float32)
    best_level = np.zeros((grid_h, grid_w), np.int64)
    for index in used:
        _cable_segmentation_kernels.merge_level(best, best_level, levels[index].ratio, index)
    cue = np.minimum(best * RATIO_BINS, 255.0).astype(np.uint8)
    hist = cv2.calcHist([cue], [0], None, [256], [0, 256]).ravel().astype(np.float64)
    threshold, _ = _segmentation_kernels.otsu_kernel(hist)
    threshold = max(threshold, MIN_RATIO * RATIO_BINS)
    return best, best_level, cue > threshold


def _within_scale_band(levels: list[Level], best_level: np.ndarray, seeds: np.ndarray) -> list[int]:
    """The levels within :data:`SCALE_BAND` of the one holding most of the seeds' length.

    A seed pixel of the finest grid stands for ``step`` image px of line at its level
    (whose width there is about the same few px whatever the level): the length a level
    holds is its seed count over its step.
    """
    steps = np.array([level.step for level in levels])
    counts = np.bincount(best_level[seeds], minlength=len(levels)).astype(np.float64)
    typical = steps[int(np.argmax(counts / steps))]
    low, high = typical / SCALE_BAND * (1 - 1e-9), typical * SCALE_BAND * (1 + 1e-9)
    return [index for index, step in enumerate(steps) if low <= step <= high]


def _extent(
    lab8: np.ndarray, levels: list[Level], best_level: np.ndarray, seeds: np.ndarray
) -> np.ndarray:
    """Image pixels near a seed whose colour is nearer the seed's cable than its surroundings."""
    width = lab8.shape[1]
    grid_h, grid_w = seeds.shape
    rows, cols = np.nonzero(seeds)
    colours = np.empty((rows.size, 4, 3), np.float32)
    reach = np.empty(rows.size, np.float32)
    seed_level = best_level[rows, cols]
    for index, level in enumerate(levels):
        pick = np.flatnonzero(seed_level == index)
        if pick.size == 0:
            continue
        level_h, level_w = level.ratio.shape
        level_rows = np.minimum(
            ((rows[pick] + 0.5) * level_h / grid_h).astype(np.int64), level_h - 1
        )
        level_cols = np.minimum(
            ((cols[pick] + 0.5) * level_w / grid_w).astype(np.int64), level_w - 1
        )
        colours[pick] = _cable_segmentation_kernels.seed_colours(
            level.lab8,
            level.background8,
            level_rows,
            level_cols,
            level.orientation,
            N_ORIENTATIONS,
            HALF_LENGTH,
            float(OFFSET),
        )
        reach[pick] = REACH * level.step
    # The nearest seed of every grid pixel, and how far it is.
    distance, labels = cv2.distanceTransformWithLabels(
        (~seeds).view(np.uint8), cv2.DIST_L2, 3, labelType=cv2.DIST_LABEL_PIXEL
    )
    seed_of_label = np.full(int(labels.max()) + 1, -1, np.int64)
    seed_of_label[labels[rows, cols]] = np.arange(rows.size)
    nearest = seed_of_label[labels]
    return _cable_segmentation_kernels.nearest_colour_class(
        lab8, nearest, distance, width / grid_w, reach, colours
    )


def keep_cable_like(mask: np.ndarray) -> np.ndarray:
    """Drop the components of a mask that do not look like cables.

    A component's width is four times its mean distance to the background (a band of
    width w has distances spread evenly over 0..w/2), and its length its area over its
    width. Kept: components at least :data:`MIN_ELONGATION` widths long and no thinner
    than the typical width (the area-weighted median) over :data:`SCALE_BAND`.
    """
    if not mask.any():
        return mask
    distance = _shared_kernels.distance_transform(mask.view(np.uint8))
    labels, area, width = _cable_segmentation_kernels.component_widths(
        mask.view(np.uint8), distance
    )
    elongation = area / np.maximum(width, 1.0) ** 2
    order = np.argsort(width[1:]) + 1
    cumulative = np.cumsum(area[order])
    typical = width[order][np.searchsorted(cumulative, cumulative[-1] / 2.0)]
    keep = (elongation >= MIN_ELONGATION) & (width >= typical / SCALE_BAND)
    keep[0] = False
    return keep[labels]
