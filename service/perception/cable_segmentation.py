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
   :data:`MIN_RATIO` whatever Otsu says) are seeds, on runs of line long for their
   width (measured mirrored at the picture's border: :func:`mirrored_at_border`);
   weaker pixels of such a run, still three-sigma lines, out of reach of its seeds and
   of their colour, join them (:func:`weaker_lines_of_a_seeds_colour`: a cable over a
   darker table strip). Each gets its cable's colour and the
   colours round it (both sides, the background). Seeds on shadows cables cast (the
   surface's tint at a lower lightness, or that tint moved part of the way towards the
   cable beside it: :func:`tinted_by_a_neighbour`), on
   transitions between their sides, and on strips whose two sides differ from each other
   more than from the strip (:func:`between_unlike_sides`: the paper's edge between
   paper and table), and on strips of the colour of the surface on one of their sides
   (:func:`of_a_side_surface`: the paper between a cable and the sheet's edge) are
   dropped.
5. **Extent.** Every pixel near a seed is cable when its colour is nearer the seed's
   cable colour than each colour round it: the border falls half way between cable and
   background, whatever the two are, and a shadow or a blurred rim that looks more
   like the paper than like the cable stays out.
6. **Shape.** Slits the mask encloses (:func:`fill_slits`: the highlight along a round
   cable, lighter than its colour) are filled; components that are not cable-like are
   dropped (:func:`keep_cable_like`): compact blobs, and strokes much thinner than the
   typical cable of the picture.

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
from service.perception.deadline import Deadline, check
from service.perception.seed_lines import (
    HALF_LENGTH,
    MIN_RATIO,
    N_ORIENTATIONS,
    OFFSET,
    REACH,
    Level,
    SeedLines,
    weaker_lines_of_a_seeds_colour,
)

STAGE = "segmentation"
"""The stage a :class:`~service.perception.deadline.DeadlineExceeded` names."""

MEDIAN_SIZE = 5
"""Backgrounds are medians over ``MEDIAN_SIZE`` x ``MEDIAN_SIZE`` samples of a level."""
BACKGROUND_FACTOR = 4
"""The local background of a level is the median over 5 x 5 of its pixels 4 px apart: a
window 20 level px wide, of which a cable covers under a fifth and two cables side by side
under half."""
WIDE_FACTOR = 8
"""A line must also differ from the median over a window twice as wide (samples 8 px
apart), where two cables crossing cover under a quarter: the paper in the angle between
them (whose narrow window two thick cables may fill half) is not taken for a line."""
BACKGROUND_WINDOW = MEDIAN_SIZE * BACKGROUND_FACTOR
WIDE_WINDOW = MEDIAN_SIZE * WIDE_FACTOR
SIDE_SURFACE_DISTANCE = WIDE_WINDOW // 2
"""The surface on either side of a line is the wide background this far (level px) to
that side: the window lies beside the line, its edge on it."""
FINEST_STEP = 2.0
"""The finest level takes every other pixel: cables from 5 px wide are 2.5 px there."""
COARSEST_STEP = 16.0
"""The coarsest level brings cables 40 px wide down to 2.5 px."""
LEVEL_RATIO = float(np.sqrt(2.0))
END_PROBE = 2.0
"""A seed ends a line when no seed lies near the point this far ahead on its line (level
px): half its segment's length. Only seeds at least half this far ahead of it count
(:func:`line_goes_on`)."""
END_WIDTH = REACH
"""Ahead of a line's end the cable is judged as wide as beside its seeds (level px): a
cable keeps its width up to its end, where the line's ratio fell because its segment ran
past the end, not because the cable narrowed. (Judged within half the narrowest cable's
width, 1 px, the end's cap was left out at its sides and the chain ended short of the
cable: segmentation pass 7.)"""
MIN_LEVEL_SIDE = 2 * BACKGROUND_WINDOW
"""A level must hold two background windows across its shorter side."""
JND = 2.3
"""A just noticeable colour difference in CIELAB (Delta E 2.3, Sharma 2003): the spread
along a segment is never taken as smaller, so that colours nobody can tell apart give
no line."""
RATIO_BINS = 20.0
"""Ratios are binned in steps of 1/20 for Otsu's threshold (ratios above 12.75, certainly
lines, share the top bin)."""
SCALE_BAND = 2.0
"""Cables of one picture are within this factor of the typical width: the levels, and the
components' widths, outside the band are dropped."""
SHADOW_TINT = 2.0 * JND
"""A shadow keeps the background's chromaticity to within two just noticeable differences
(the light left in a shadow, from the room and the sky, may be of another tint)."""
SHADOW_BLEED = 0.5
"""A shadow beside a coloured cable takes up some of the cable's chromaticity (a JPEG's
chroma, sampled over 2 x 2 pixels and blurred, spreads over the narrow shadow; the cable
reflects its own colour into it): up to half the way from the shadowed background's to the
cable's, past which it is nearer the cable's colour (the half-way rule of the extent)."""
SHADOW_LIGHT = 0.25
"""A shadow keeps at least a quarter of the background's luminance: it is cast by part of
the light only (the soft shadow of a thin cable under a lamp and the room's light)."""
SHADOW_REACH = 2.0
"""A cast shadow lies beside its cable: within twice the side segments' offset."""
RAMP_WIDTH = 0.25
"""A transition's colour lies within a quarter of its sides' difference of the path
between them (:func:`transitions`)."""
RAMP_END = 0.1
"""... and more than a tenth of the way from either side's colour."""
RUN_RATIO = 0.5
"""Runs of line are traced down to half the seeds' lowest ratio (:func:`_long_seed_runs`),
the usual two to one of hysteresis."""
LINE_WIDTH = 3.0
"""A line found at a level is about this wide there (level px): the levels are made for
cables 2.5 to 3.5 px wide."""
MIN_ELONGATION = 3.0
"""A component is at least this many of its widths long (by the measure of
:func:`keep_cable_like`, a disc or a square is 2.3 widths long)."""
SLIT_HALF_WIDTH = 1.5
"""An enclosed gap none of whose pixels lies farther than this (px) from the mask, at most
2 px wide, is a slit in a cable (:func:`fill_slits`)."""


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
    image_bgr: np.ndarray,
    min_component_area: int = 0,
    max_hole_area: int = 0,
    *,
    deadline: Deadline | None = None,
) -> np.ndarray:
    """Foreground mask of the cables in a BGR image, by their contrast with their sides.

    Parameters
    ----------
    image_bgr : ndarray
        ``(H, W, 3)`` BGR ``uint8``.
    min_component_area, max_hole_area : int
        The clean-up of :func:`service.perception.segmentation.clean_mask`.
    deadline : Deadline, optional
        Checked after each pyramid level and each later step
        (:class:`~service.perception.deadline.DeadlineExceeded` past it).

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
    return cable_contrast(image_bgr, min_component_area, max_hole_area, deadline=deadline).mask


def cable_contrast(
    image_bgr: np.ndarray,
    min_component_area: int = 0,
    max_hole_area: int = 0,
    *,
    deadline: Deadline | None = None,
) -> CableContrast:
    """:func:`segment_cables`, with the line ratios, seeds and levels it used."""
    height, width = image_bgr.shape[:2]
    lab8 = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2Lab)
    levels = _levels(lab8, level_steps(height, width), deadline)
    used = list(range(len(levels)))
    on_grid = [_on_grid(level.ratio, levels[0].ratio.shape) for level in levels]
    ratio, best_level, seeds = _seeds(on_grid, used)
    if seeds.any():
        used = _within_scale_band(levels, best_level, seeds)
        if len(used) < len(levels):
            ratio, best_level, seeds = _seeds(on_grid, used)
    check(deadline, STAGE)
    mask = np.zeros((height, width), bool)
    if seeds.any():
        widest_line = LINE_WIDTH * max(levels[index].step for index in used) / levels[0].step
        seeds, runs = _long_seed_runs(ratio, seeds, widest_line)
    if seeds.any():
        strong = seeds
        seeds, lines = weaker_lines_of_a_seeds_colour(
            (height, width), levels, best_level, ratio, seeds, runs
        )
        lines = _without_shadows(lines, seeds, height / seeds.shape[0])
        lines = lines.take(~transitions(lines.colours))
        lines = lines.take(~between_unlike_sides(lines.colours))
        lines = lines.take(
            ~of_a_side_surface(lines.colours, side_surfaces((height, width), levels, lines))
        )
        of_a_seed = lines_of_grid_pixels(lines, seeds, strong)
        seeds = seeds.copy()
        seeds[np.nonzero(seeds)] = lines.of_grid >= 0
        check(deadline, STAGE)
        candidates = _extent(lab8, lines, seeds, of_a_seed)
        check(deadline, STAGE)
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
        mask = keep_cable_like(fill_slits(mask), widest_line * levels[0].step)
    return CableContrast(mask, ratio, best_level, seeds, levels, used)


def _levels(lab8: np.ndarray, steps: list[float], deadline: Deadline | None) -> list[Level]:
    """The pyramid's levels, each with its line ratios (the deadline checked after each)."""
    images = _pyramid(lab8, steps)
    levels = []
    for step, small in zip(steps, images, strict=False):
        background, wide = (
            _sparse_median(small, factor) for factor in (BACKGROUND_FACTOR, WIDE_FACTOR)
        )
        ratio, orientation = _cable_segmentation_kernels.level_contrast(
            small, background, wide, N_ORIENTATIONS, HALF_LENGTH, float(OFFSET), JND * JND
        )
        levels.append(Level(step, small, background, wide, ratio, orientation))
        check(deadline, STAGE)
    return levels


def _pyramid(lab8: np.ndarray, steps: list[float]) -> list[np.ndarray]:
    """The level images: each is the one two below it halved (the mean of 2 x 2 px), so
    only the first two are resized from the image itself."""
    height, width = lab8.shape[:2]
    images = []
    for index, step in enumerate(steps):
        if step == 1.0:
            images.append(lab8)
            continue
        size = (max(1, round(width / step)), max(1, round(height / step)))
        source = images[index - 2] if index >= 2 else lab8
        images.append(cv2.resize(source, size, interpolation=cv2.INTER_AREA))
    return images


def _sparse_median(lab8: np.ndarray, factor: int) -> np.ndarray:
    """Median colour over a window ``MEDIAN_SIZE * factor`` px wide centred on each pixel,
    from the pixels of the window on the pixel's own rows and columns every ``factor``
    px (``MEDIAN_SIZE`` x ``MEDIAN_SIZE`` samples).

    The samples are pixels of the level, not block means: a block across a cable's rim
    would give a colour between cable and background, and between two close cables the
    median of such blends is neither (the paper between them would look like a line).
    Every pixel gets the median of its own window, not one interpolated from its
    neighbours' windows: at the border of two surfaces (a sheet of paper on a dark
    table) an interpolated background is a blend of the two, the colour of neither, and
    the paper left between a cable and the sheet's edge would differ from it. The
    ``factor`` x ``factor`` phases of the grid (each a ``factor`` times smaller image) are
    laid side by side (:func:`~._cable_segmentation_kernels.phase_mosaic`) and filtered at
    once: the whole costs one median filter of the level. A level with too
    few samples gets its overall median.
    """
    height, width = lab8.shape[:2]
    if min(height, width) // factor < MEDIAN_SIZE:
        median = np.median(lab8.reshape(-1, 3), axis=0).round().astype(np.uint8)
        return np.broadcast_to(median, lab8.shape).copy()
    mosaic = _cable_segmentation_kernels.phase_mosaic(lab8, factor, MEDIAN_SIZE // 2)
    return _cable_segmentation_kernels.from_phase_mosaic(
        cv2.medianBlur(mosaic, MEDIAN_SIZE), factor, MEDIAN_SIZE // 2, height, width
    )


def _on_grid(ratio: np.ndarray, grid_shape: tuple[int, int]) -> np.ndarray:
    """A level's ratios on the finest grid: each grid pixel takes the level pixel its
    centre falls in."""
    grid_h, grid_w = grid_shape
    return cv2.resize(ratio, (grid_w, grid_h), interpolation=cv2.INTER_NEAREST_EXACT)


def _seeds(on_grid: list[np.ndarray], used: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best ratio and level per pixel of the finest grid, and the seeds among them.

    ``on_grid`` holds every level's ratios on the grid (:func:`_on_grid`); of the
    ``used`` levels, a pixel keeps the first with the largest ratio.
    """
    # Ratios are never negative: from zeros, a pixel whose ratios are all 0 keeps the first.
    best = np.zeros(on_grid[used[0]].shape, np.float32)
    best_level = np.full(best.shape, used[0], np.int64)
    for index in used:
        _cable_segmentation_kernels.keep_larger(best, best_level, on_grid[index], index)
    cue = np.minimum(best * RATIO_BINS, 255.0).astype(np.uint8)
    hist = cv2.calcHist([cue], [0], None, [256], [0, 256]).ravel().astype(np.float64)
    threshold, _ = _segmentation_kernels.otsu_kernel(hist)
    threshold = max(threshold, MIN_RATIO * RATIO_BINS)
    return best, best_level, cue > threshold


def _long_seed_runs(
    ratio: np.ndarray, seeds: np.ndarray, widest_line: float
) -> tuple[np.ndarray, np.ndarray]:
    """The seeds on runs of line at least :data:`MIN_ELONGATION` of their widths long,
    and the runs they lie on (a label per grid pixel, 0 off those runs).

    A cable is a line over its whole length; a fleck of paint, a blob of texture or a
    short stroke is a line over a few widths at most. A run is a connected stretch of the
    finest grid where the ratio is at least :data:`RUN_RATIO` of the seeds' lowest (a
    faint cable whose ratio wavers about the seeds' threshold, or a tight loop whose ratio
    is high only where the segments fit the curve, is one run, not many); its width and
    length are measured as :func:`keep_cable_like` measures a component's, on the grid
    mirrored at the picture's border (:func:`mirrored_at_border`): a run the border cuts
    goes on beyond it unseen, and the picture shows only part of its length. (Measured
    as seen, a cable leaving the picture a few widths past an object or a crossing lost
    that whole stretch: segmentation pass 8.) ``widest_line`` is the widest line the
    used levels find, in grid px (:func:`mirror_margin`).
    """
    line = ((ratio >= RUN_RATIO * ratio[seeds].min()) | seeds).view(np.uint8)
    pad = mirror_margin(line.shape, widest_line)
    line_seen, seeds_seen = (mirrored_at_border(grid, pad) for grid in (line, seeds))
    distance = _shared_kernels.distance_transform(line_seen)
    labels, area, width = _cable_segmentation_kernels.component_widths(line_seen, distance)
    # A band w px wide has pixel distances 1 .. w / 2 to the background: four times their
    # mean is w + 2 on a grid this coarse.
    width = np.maximum(width - 2.0, 1.0)
    # The seeds are the evidence, the weaker pixels only join them: a run's seeds must
    # cover that length themselves.
    seed_area = np.bincount(labels[seeds_seen], minlength=area.size)
    keep = seed_area >= MIN_ELONGATION * width**2
    keep[0] = False
    height, width_px = line.shape
    labels = labels[pad : pad + height, pad : pad + width_px]
    runs = np.where(keep[labels], labels, 0)
    return seeds & (runs > 0), runs


def mirror_margin(shape: tuple[int, int], widest_line: float) -> int:
    """How far (grid px) to mirror a grid at its border for :func:`_long_seed_runs`.

    A run of a line ``w`` wide that the border cuts after a visible length of at least
    half :data:`MIN_ELONGATION` widths passes when mirrored; one seen over
    :data:`MIN_ELONGATION` widths passes as it is. So the mirror need reach no farther
    than half that length of the widest line, and never past the grid's own size.
    """
    margin = int(np.ceil(0.5 * MIN_ELONGATION * widest_line))
    return max(0, min(margin, min(shape) - 1))


def mirrored_at_border(grid: np.ndarray, margin: int) -> np.ndarray:
    """``grid`` with ``margin`` px of its own mirror image added beyond each side.

    The picture's border is taken as a mirror (the edge pixel repeated, as
    ``cv2.BORDER_REFLECT``): a line cut by the border runs on beyond it as far again as
    it is seen, while a fleck the border cuts in half is made whole again, no longer, and
    a fleck clear of the border is unchanged.

    Parameters
    ----------
    grid : ndarray of bool or uint8
        ``(H, W)``.
    margin : int
        At most ``min(H, W)``.

    Returns
    -------
    ndarray
        ``(H + 2 margin, W + 2 margin)``, of ``grid``'s dtype; ``grid`` itself at rows
        and columns ``margin`` on.
    """
    if margin == 0:
        return grid
    return np.pad(grid, margin, mode="symmetric")


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


def shadow_tint(colours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How each line's colour differs from its background's in shadow.

    As light dims, CIELAB's a and b scale with L + 16: the background in a shadow as
    dark as the line has the background's a and b times ``(L_line + 16) / (L_bg + 16)``.

    Returns
    -------
    tint : ndarray
        ``(N, 2)``: the line's a and b less those of its background dimmed to it.
    luminance : ndarray
        ``(N,)``: the line's luminance over its background's.
    """
    line = colours[:, 0].astype(np.float64)
    background = colours[:, 3].astype(np.float64)
    scale = (line[:, 0] + 16.0) / (background[:, 0] + 16.0)
    return line[:, 1:] - background[:, 1:] * scale[:, None], scale**3


def shadow_coloured(colours: np.ndarray) -> np.ndarray:
    """Which lines have the colour of their background in shadow.

    A shadow is the background with less light: the same chromaticity within
    :data:`SHADOW_TINT` (:func:`shadow_tint`), darker, and keeping at least
    :data:`SHADOW_LIGHT` of the background's luminance.
    """
    tint, luminance = shadow_tint(colours)
    return (np.hypot(tint[:, 0], tint[:, 1]) <= SHADOW_TINT) & dimmed(luminance)


def dimmed(luminance: np.ndarray) -> np.ndarray:
    """Luminances a shadow may have: under the background's, over :data:`SHADOW_LIGHT` of it."""
    return (luminance >= SHADOW_LIGHT) & (luminance < 1.0)


def transitions(colours: np.ndarray) -> np.ndarray:
    """Which lines are transitions between their sides rather than lines of their own.

    A cable differs from both its sides alike: darker than both, brighter than both, or
    of another colour. A band whose colour lies on the way from one side's colour to the
    other's (within :data:`RAMP_WIDTH` of their difference from that path, and not at
    either end of it) is the soft rim of something beside it: a shadow between a cable
    and the paper, the strip of wood between white paper and a dark table.
    """
    line, one, two = (colours[:, k].astype(np.float64) for k in range(3))
    path = two - one
    length2 = np.maximum((path * path).sum(axis=1), 1e-12)
    along = ((line - one) * path).sum(axis=1) / length2
    off = line - (one + np.clip(along, 0.0, 1.0)[:, None] * path)
    return (
        (along > RAMP_END)
        & (along < 1.0 - RAMP_END)
        & ((off * off).sum(axis=1) < RAMP_WIDTH**2 * length2)
    )


def between_unlike_sides(colours: np.ndarray) -> np.ndarray:
    """Which lines lie between two sides more unlike each other than the line is unlike them.

    A cable lies on one surface: what is beside it on the left is what is beside it on the
    right (the same paper, the same table), and the cable differs from both. A strip along
    the border of two surfaces (the paper's edge between white paper and a dark table, a
    margin between a print and the board under it) has a different surface on each side:
    when its two sides differ from each other by more than the line differs from the
    nearer of them, the line is a step from one surface to the other with a strip in it,
    not a ridge. (A cable crossing such a border runs across it, where its two sides
    each straddle the border alike; only a line along the border is judged so.)
    """
    line, one, two = (colours[:, k].astype(np.float64) for k in range(3))
    contrast = np.minimum(np.linalg.norm(line - one, axis=1), np.linalg.norm(line - two, axis=1))
    return np.linalg.norm(one - two, axis=1) > contrast


def side_surfaces(shape: tuple[int, int], levels: list[Level], lines: SeedLines) -> np.ndarray:
    """The colour of the surface on either side of each seed's line.

    The wide background (the median over :data:`WIDE_WINDOW` level px) at
    :data:`SIDE_SURFACE_DISTANCE` level px from the seed across its line, to the side of
    its side one and of its side two (:func:`seed_lines`; taken at the picture's edge
    beyond it). Its window lies beside the line, not across it: at the border of two
    surfaces each side gets its own, where the window centred on the line may hold
    either.

    Returns
    -------
    ndarray of float32
        ``(N, 2, 3)`` CIELAB.
    """
    height, width = shape
    surfaces = np.zeros((lines.steps.size, 2, 3), np.float32)
    cos_t, sin_t = np.cos(lines.angles), np.sin(lines.angles)
    for level in levels:
        pick = np.flatnonzero(lines.steps == level.step)
        if pick.size == 0:
            continue
        level_h, level_w = level.wide8.shape[:2]
        # The seed's own level pixel (seed_lines put the seed at its centre).
        rows = np.round((lines.centres_y[pick] + 0.5) * level_h / height - 0.5)
        cols = np.round((lines.centres_x[pick] + 0.5) * level_w / width - 0.5)
        for side, sign in enumerate((1.0, -1.0)):
            # Side one lies at (round(d cos t), round(-d sin t)) rows and columns, as in
            # the kernels' line sides.
            y = np.clip(rows + sign * np.round(SIDE_SURFACE_DISTANCE * cos_t[pick]), 0, level_h - 1)
            x = np.clip(cols - sign * np.round(SIDE_SURFACE_DISTANCE * sin_t[pick]), 0, level_w - 1)
            found = level.wide8[y.astype(np.int64), x.astype(np.int64)]
            surfaces[pick, side] = cielab_from_lab8(found)
    return surfaces


def cielab_from_lab8(lab8: np.ndarray) -> np.ndarray:
    """CIELAB (L 0-100, a and b signed) from OpenCV's 8-bit Lab (all three 0-255).

    Parameters
    ----------
    lab8 : ndarray of uint8
        ``(..., 3)`` as ``cv2.cvtColor(bgr_uint8, cv2.COLOR_BGR2Lab)`` gives it.

    Returns
    -------
    ndarray of float32
        ``(..., 3)``.
    """
    lab = lab8.astype(np.float32)
    lab[..., 0] *= 100.0 / 255.0
    lab[..., 1:] -= 128.0
    return lab


def of_a_side_surface(colours: np.ndarray, surfaces: np.ndarray) -> np.ndarray:
    """Which lines have the colour of the surface on one of their sides.

    A cable differs from the surface it lies on, on both its sides. A strip of that
    surface left between a cable and the border of another surface (the paper between a
    cable and the sheet's edge, the paper between two cables lying side by side) differs
    from its sides (the cable, the table) and from a background the window of which
    straddles the border, but it is the surface on one side. A line counts as of that
    surface when its colour is nearer the surface's colour than half its contrast with
    the colours round it: the half-way border of :func:`_extent`, applied to the line.

    Parameters
    ----------
    colours : ndarray
        ``(N, 4, 3)`` CIELAB: line, side one, side two, background (:class:`SeedLines`).
    surfaces : ndarray
        ``(N, 2, 3)`` CIELAB: the surface on each side (:func:`side_surfaces`).
    """
    line = colours[:, :1].astype(np.float64)
    contrast = np.linalg.norm(colours[:, 1:] - line, axis=2).min(axis=1)
    nearest_surface = np.linalg.norm(surfaces - line, axis=2).min(axis=1)
    return nearest_surface < 0.5 * contrast


def _without_shadows(lines: SeedLines, seeds: np.ndarray, grid_step: float) -> SeedLines:
    """The seeds less the shadows cables cast: shadow-coloured lines (:func:`shadow_coloured`)
    within :data:`SHADOW_REACH` of their own widths of a line that is not, and dimmed lines
    tinted towards a line that near (:func:`tinted_by_a_neighbour`).

    A grey cable on white paper is shadow-coloured too; away from other cables it stays.
    """
    shadow = shadow_coloured(lines.colours)
    reach = SHADOW_REACH * OFFSET * lines.steps
    tinted = tinted_by_a_neighbour(lines, reach)
    if not shadow.any() or shadow.all():
        return lines.take(~tinted) if tinted.any() and not shadow.all() else lines
    grid_h, grid_w = seeds.shape
    caster = np.ones(seeds.shape, np.uint8)
    rows, cols = np.nonzero(seeds)
    casting = ~shadow[lines.of_grid]
    caster[rows[casting], cols[casting]] = 0
    distance = cv2.distanceTransform(caster, cv2.DIST_L2, 3)
    # A shadow seed's distance to the nearest casting seed, in image px (from the grid).
    ys = np.clip(
        np.round((lines.centres_y + 0.5) / grid_step - 0.5).astype(np.int64), 0, grid_h - 1
    )
    xs = np.clip(
        np.round((lines.centres_x + 0.5) / grid_step - 0.5).astype(np.int64), 0, grid_w - 1
    )
    near_caster = distance[ys, xs] * grid_step <= reach
    return lines.take(~((shadow & near_caster) | tinted))


def tinted_by_a_neighbour(lines: SeedLines, reach: np.ndarray) -> np.ndarray:
    """Which dimmed lines are the background in shadow tinted towards a line near them.

    A line as dark as a shadow (:func:`dimmed`) whose tint (:func:`shadow_tint`) lies on
    the way from none towards another line's within ``reach`` (image px, per line), no
    farther than :data:`SHADOW_BLEED` of it and within :data:`SHADOW_TINT` of the way, is
    the shadow of that line with its colour bled in. Lines along one cable share their
    tint (all the way, not half) and do not count as each other's shadow; a line within
    :data:`SHADOW_TINT` of the shadow's tint-free colour shows no way to go.
    """
    tint, luminance = shadow_tint(lines.colours)
    candidate = np.flatnonzero(dimmed(luminance) & (np.hypot(tint[:, 0], tint[:, 1]) > SHADOW_TINT))
    found = np.zeros(tint.shape[0], bool)
    if candidate.size == 0:
        return found
    # Imported here, not at the top: scipy.spatial loads scipy.linalg, which a process
    # that never takes the contrast path should not pay for at start-up (issue 15).
    from scipy.spatial import cKDTree

    centres = np.stack([lines.centres_x, lines.centres_y], axis=1)
    everyone = cKDTree(centres)
    # a and b apart: the pairs are many, and whole-array arithmetic on columns is fastest.
    a, b = (lines.colours[:, 0, k].astype(np.float32) for k in (1, 2))
    tint_a, tint_b = tint[:, 0].astype(np.float32), tint[:, 1].astype(np.float32)
    tint2 = tint_a * tint_a + tint_b * tint_b
    for step in np.unique(lines.steps[candidate]):
        # One level at a time: its own reach, so the search stays small.
        own = candidate[lines.steps[candidate] == step]
        pairs = cKDTree(centres[own]).sparse_distance_matrix(
            everyone, float(reach[own[0]]), output_type="ndarray"
        )
        pairs_i, pairs_j = own[pairs["i"]], pairs["j"]
        # From the line's background dimmed to it (its colour less its tint) towards the
        # other line's colour; the tint's part along that way and across it.
        t_a, t_b = tint_a[pairs_i], tint_b[pairs_i]
        toward_a = a[pairs_j] - a[pairs_i] + t_a
        toward_b = b[pairs_j] - b[pairs_i] + t_b
        dot = t_a * toward_a + t_b * toward_b
        length2 = toward_a * toward_a + toward_b * toward_b
        across2 = tint2[pairs_i] * length2 - dot * dot
        bled = (
            (length2 > SHADOW_TINT**2)
            & (dot >= 0.0)
            & (dot <= SHADOW_BLEED * length2)
            & (across2 <= SHADOW_TINT**2 * length2)
        )
        found[pairs_i[bled]] = True
    return found


def _extent(
    lab8: np.ndarray, lines: SeedLines, seeds: np.ndarray, ends: np.ndarray | None = None
) -> np.ndarray:
    """Image pixels near a seed whose colour is near the seed's cable colour.

    A pixel counts when any seed within reach says so, not only the nearest: where two
    cables of different colours cross, the lower one's pixels beside the upper one's seeds
    are still judged by the lower one's own seeds. Where a line of seeds ends, its last
    seeds also judge the line ahead of them at its full width (:data:`END_WIDTH`), out to
    the length of their segment: there the segment ran past the cable's end and its ratio
    fell. Only the lines where ``ends`` (default: all) are judged ahead, and where they
    end among those alone: the ratio of a weaker line taken by
    :func:`weaker_lines_of_a_seeds_colour` did not fall because a segment ran past the
    cable's end, and its end is no cable's end (past it lie a cable's bare wires, a
    ferrule, the shadow beside it).
    """
    if ends is None:
        ends = np.ones(lines.steps.size, bool)
    judged = lines.take(ends)
    ahead = []
    for sign in (1.0, -1.0):
        reach_ahead = np.zeros(lines.steps.size)
        reach_ahead[ends] = np.where(
            line_goes_on(judged, seeds & _grid_of(lines, seeds, ends), sign, lab8.shape[0]),
            0.0,
            HALF_LENGTH * judged.steps,
        )
        ahead.append(reach_ahead)
    return _cable_segmentation_kernels.colour_class_within_reach(
        lab8,
        lines.centres_y,
        lines.centres_x,
        lines.angles,
        lines.steps,
        ahead[0],
        ahead[1],
        REACH,
        END_WIDTH,
        float(OFFSET),
        lines.colours,
    )


def lines_of_grid_pixels(lines: SeedLines, grid: np.ndarray, pick: np.ndarray) -> np.ndarray:
    """Which of ``lines`` hold a pixel of ``grid`` where ``pick`` (both ``(H, W)`` bool,
    ``grid`` the seeds ``lines`` were gathered from, ``pick`` within it)."""
    rows, cols = np.nonzero(grid)
    held = np.zeros(lines.steps.size, bool)
    line = lines.of_grid[pick[rows, cols]]
    held[line[line >= 0]] = True
    return held


def _grid_of(lines: SeedLines, seeds: np.ndarray, which: np.ndarray) -> np.ndarray:
    """The grid seeds (``seeds``, those of ``lines``) that belong to the lines ``which``."""
    rows, cols = np.nonzero(seeds)
    grid = np.zeros(seeds.shape, bool)
    line = lines.of_grid
    # ``seeds`` holds exactly the grid seeds ``lines`` keeps, in the order of its of_grid
    # entries that are not -1.
    kept = line[line >= 0]
    grid[rows, cols] = which[kept]
    return grid


def line_goes_on(lines: SeedLines, seeds: np.ndarray, sign: float, height: int) -> np.ndarray:
    """Which seeds' lines go on past them, forward (``sign`` 1) or back (-1).

    A line goes on when a seed of the finest grid lies within one grid pixel of the point
    :data:`END_PROBE` level px ahead on it, and that seed is itself at least half that
    far ahead. Without the second condition, the seed's own grid pixel (or the one beside
    it across the line) is within a grid pixel of the point on the finest level whenever
    the line runs diagonally (the point is only sqrt(2) grid px off each way), so such a
    line never ended: the lower cable at a crossing, its last seeds short of the upper
    one, was not followed up to it, and its mask stopped a few px short, cut in two.

    Parameters
    ----------
    lines : SeedLines
    seeds : ndarray of bool
        The finest grid's seeds, those of ``lines`` only.
    sign : float
        1.0 along the line's angle, -1.0 against it.
    height : int
        The image's height (px), for the grid's step.

    Returns
    -------
    ndarray of bool
        ``(N,)``; True also where the point lies beyond the picture.
    """
    grid_h, grid_w = seeds.shape
    grid_step = height / grid_h
    along_x = sign * np.cos(lines.angles)
    along_y = sign * np.sin(lines.angles)
    probe = END_PROBE * lines.steps
    gx = np.floor((lines.centres_x + probe * along_x + 0.5) / grid_step).astype(np.int64)
    gy = np.floor((lines.centres_y + probe * along_y + 0.5) / grid_step).astype(np.int64)
    inside = (gx >= 0) & (gx < grid_w) & (gy >= 0) & (gy < grid_h)
    goes_on = ~inside
    padded = np.pad(seeds, 1)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near_x, near_y = gx + dx, gy + dy
            seed_there = padded[
                np.clip(near_y + 1, 0, grid_h + 1), np.clip(near_x + 1, 0, grid_w + 1)
            ]
            # How far ahead of the seed that grid pixel's centre lies, in image px.
            forward = ((near_x + 0.5) * grid_step - 0.5 - lines.centres_x) * along_x + (
                (near_y + 0.5) * grid_step - 0.5 - lines.centres_y
            ) * along_y
            goes_on |= inside & seed_there & (forward >= 0.5 * probe)
    return goes_on


def fill_slits(mask: np.ndarray) -> np.ndarray:
    """Fill the thin gaps the mask encloses: background components that do not touch the
    picture's border and that a closing by a 3 x 3 square fills whole (gaps at most 2 px
    wide, every pixel of them within :data:`SLIT_HALF_WIDTH` px of the mask).

    A round cable under a lamp has a highlight along its middle, lighter than its own
    colour: on white paper nearer the paper than the cable, so the colour test of
    :func:`_extent` leaves a slit between the cable's two halves, whatever its length.
    Background that the mask encloses (inside a loop, between two crossing or touching
    cables) widens away from where the cables meet, and holds pixels the closing leaves
    open; a gap that stays within a pixel and a half of the mask all along is the cable's
    own.
    """
    solid = mask.view(np.uint8)
    closed = cv2.morphologyEx(solid, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    gaps = cv2.subtract(closed, solid)
    points = cv2.findNonZero(gaps)
    if points is None:
        return mask
    count, labels = cv2.connectedComponents(gaps, connectivity=4)
    # A gap is part of a wider background component when it touches (4-connected)
    # background the closing left open, or the picture's border.
    open_background = np.pad(cv2.bitwise_or(solid, gaps) == 0, 1, constant_values=True)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    reached = cv2.dilate(open_background.view(np.uint8), cross)[1:-1, 1:-1]
    xs, ys = points.reshape(-1, 2).T
    gap_labels = labels[ys, xs]
    leaks = np.zeros(count, bool)
    leaks[gap_labels[reached[ys, xs] > 0]] = True
    slit = ~leaks[gap_labels]
    filled = mask.copy()
    filled[ys[slit], xs[slit]] = True
    return filled


def keep_cable_like(mask: np.ndarray, widest_line: float = 0.0) -> np.ndarray:
    """Drop the components of a mask that do not look like cables.

    A component's width is four times its mean distance to the background (a band of
    width w has distances spread evenly over 0..w/2), and its length its area over its
    width. Kept: components at least :data:`MIN_ELONGATION` widths long and no thinner
    than the typical width (the area-weighted median) over :data:`SCALE_BAND`. Measured
    on the mask mirrored at the picture's border (:func:`mirrored_at_border`, as far as
    :func:`mirror_margin` asks for lines up to ``widest_line`` px wide; 0: as seen): a
    cable the border cuts a few widths past an object is judged by more than the
    stretch the picture shows.
    """
    if not mask.any():
        return mask
    margin = mirror_margin(mask.shape, widest_line)
    seen = np.ascontiguousarray(mirrored_at_border(mask.view(np.uint8), margin))
    distance = _shared_kernels.distance_transform(seen)
    labels, area, width = _cable_segmentation_kernels.component_widths(seen, distance)
    height, width_px = mask.shape
    labels = labels[margin : margin + height, margin : margin + width_px]
    elongation = area / np.maximum(width, 1.0) ** 2
    order = np.argsort(width[1:]) + 1
    cumulative = np.cumsum(area[order])
    typical = width[order][np.searchsorted(cumulative, cumulative[-1] / 2.0)]
    keep = (elongation >= MIN_ELONGATION) & (width >= typical / SCALE_BAND)
    keep[0] = False
    return keep[labels]
