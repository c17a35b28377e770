"""The seeds' lines of the cable contrast (:mod:`.cable_segmentation`):
one per pixel of its own pyramid level, with its cable's colour and the colours round it,
and the weaker lines of a seed's colour that join the seeds (hysteresis).

A seed is a pixel of the finest grid whose line ratio is a sure line; its *line* is the
segment through it at its best angle and level (:class:`Level`), and the colours of that
line, of the parallel segments to either side and of the local background are what the
later steps judge every other pixel against (:func:`seed_lines`). A weaker line on a
seed's run joins the seeds where it is of the seed's cable by colour
(:func:`weaker_lines_of_a_seeds_colour`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from service.perception import _cable_segmentation_kernels

N_ORIENTATIONS = 8
"""Angles of the line segments, 22.5 degrees apart: a segment at most 11.25 degrees off a
cable stays within a 2.5 px cable over its length."""
HALF_LENGTH = 4.0
"""Each segment reaches this far (level px) either way: about three widths of a 2.5-3.5 px
cable, short enough to stay on a cable bending to a radius of four of its widths."""
OFFSET = 4
"""The side segments lie this far (level px) from the centre: beyond a 3.5 px cable's rim
from anywhere on its centre line."""

REACH = 2.0
"""A pixel is judged against its nearest seed when that seed lies within this many level
px: half the widest cable a level is made for (3.5 px), rounded up."""

MIN_RATIO = 3.0
"""A seed's line differs from its sides and from the background by at least three times
the spread of colours along it. A table without cables (plain or textured) has no line
near that, and gives an empty mask."""

NEAREST_SEEDS = 16
"""A weaker line is judged against the nearest seed on its own run among this many
nearest seeds (:func:`weaker_lines_of_a_seeds_colour`): a few level pixels' worth of a
cable's seeds, enough to reach past a crossing cable's."""


@dataclass(frozen=True)
class Level:
    """One pyramid level: its sampling step, Lab image, background and line ratios."""

    step: float
    lab8: np.ndarray
    background8: np.ndarray
    wide8: np.ndarray
    ratio: np.ndarray
    orientation: np.ndarray


@dataclass(frozen=True)
class SeedLines:
    """The seeds, one per pixel of its own level, and the colours of their lines.

    Attributes
    ----------
    centres_y, centres_x : ndarray of float64
        The centre of the seed's level pixel, image px.
    angles : ndarray of float64
        The direction of the seed's line (``(cos, sin)`` in ``(x, y)``), radians.
    steps : ndarray of float64
        The seed's level step (image px per level px).
    colours : ndarray of float32
        ``(N, 4, 3)`` CIELAB: the line's colour, its two sides and the background.
    of_grid : ndarray of int64
        For every seed of the finest grid (in ``np.nonzero`` order), its index here.
    """

    centres_y: np.ndarray
    centres_x: np.ndarray
    angles: np.ndarray
    steps: np.ndarray
    colours: np.ndarray
    of_grid: np.ndarray

    def take(self, keep: np.ndarray) -> SeedLines:
        """The seeds where ``keep``; ``of_grid`` is -1 for the grid seeds of the others.

        A grid seed dropped before (-1) stays dropped: -1 is not an index here (as an
        index it would be the last line's, and bring the seed back as that line's).
        """
        renumber = np.cumsum(keep) - 1
        if keep.size == 0:
            of_grid = np.full_like(self.of_grid, -1)
        else:
            line = np.maximum(self.of_grid, 0)
            of_grid = np.where((self.of_grid >= 0) & keep[line], renumber[line], -1)
        return SeedLines(
            self.centres_y[keep],
            self.centres_x[keep],
            self.angles[keep],
            self.steps[keep],
            self.colours[keep],
            of_grid,
        )


def seed_lines(
    shape: tuple[int, int], levels: list[Level], best_level: np.ndarray, seeds: np.ndarray
) -> SeedLines:
    """The seeds of the finest grid gathered per pixel of their own level, with colours."""
    height, width = shape
    grid_h, grid_w = seeds.shape
    rows, cols = np.nonzero(seeds)
    seed_level = best_level[rows, cols]
    of_grid = np.empty(rows.size, np.int64)
    parts = []
    count = 0
    for index, level in enumerate(levels):
        pick = np.flatnonzero(seed_level == index)
        if pick.size == 0:
            continue
        # One seed per pixel of its own level: the finer grid's seeds repeat its colours.
        level_h, level_w = level.ratio.shape
        level_rows = np.minimum(
            ((rows[pick] + 0.5) * level_h / grid_h).astype(np.int64), level_h - 1
        )
        level_cols = np.minimum(
            ((cols[pick] + 0.5) * level_w / grid_w).astype(np.int64), level_w - 1
        )
        cells, inverse = np.unique(level_rows * level_w + level_cols, return_inverse=True)
        of_grid[pick] = count + inverse.ravel()
        count += cells.size
        level_rows, level_cols = cells // level_w, cells % level_w
        colours = _cable_segmentation_kernels.seed_colours(
            level.lab8,
            level.background8,
            level_rows,
            level_cols,
            level.orientation,
            N_ORIENTATIONS,
            HALF_LENGTH,
            float(OFFSET),
        )
        parts.append(
            (
                # The centre of the level pixel, in image pixel coordinates.
                (level_rows + 0.5) * (height / level_h) - 0.5,
                (level_cols + 0.5) * (width / level_w) - 0.5,
                np.pi * level.orientation[level_rows, level_cols] / N_ORIENTATIONS,
                np.full(cells.size, level.step),
                colours,
            )
        )
    if not parts:
        empty = np.empty(0)
        return SeedLines(empty, empty, empty, empty, np.empty((0, 4, 3), np.float32), of_grid)
    return SeedLines(*(np.concatenate(column) for column in zip(*parts, strict=True)), of_grid)


def weaker_lines_of_a_seeds_colour(
    shape: tuple[int, int],
    levels: list[Level],
    best_level: np.ndarray,
    ratio: np.ndarray,
    seeds: np.ndarray,
    runs: np.ndarray,
) -> tuple[np.ndarray, SeedLines]:
    """The grid pixels of weaker line on a seed's run that are of that seed's cable,
    with the seeds, and the lines of them all.

    Otsu's threshold splits the ratios of the whole picture: where the cables on white
    paper are strong lines, it is raised above a stretch of the same cable over a darker
    table strip, past a crossing or along its highlight, whose ratio is still a
    three-sigma line (:data:`MIN_RATIO`) but under the threshold; the seeds ended there
    and the mask with them (segmentation pass 8: `bright` 330030, 330052, 330036).
    Hysteresis, as in an edge detector: a pixel of a seed's run
    (:func:`.cable_segmentation._long_seed_runs`) whose ratio is at least
    :data:`MIN_RATIO` is taken, where

    - no seed has it within reach (:data:`REACH` px of its level), or, within a seed's
      reach, it runs along that seed's line between the same sides
      (:func:`along_the_seeds_line`: the cable's highlight, not its shadow or a ground
      of its colour beside it);
    - its line is the seed's cable by colour: nearer the colour of the nearest seed's
      line on the same run than half way to each colour round it (its two sides and its
      background), the half-way border of :func:`.cable_segmentation._extent` and
      :func:`.cable_segmentation.of_a_side_surface`. A stroke of a table's print or an
      edge that touches a cable's run has the colours round it.

    Their lines judge no cable's end ahead of them (:func:`.cable_segmentation._extent`).

    Parameters
    ----------
    shape : tuple of int
        The image's ``(H, W)``.
    levels : list of Level
    best_level, ratio : ndarray
        Per grid pixel, its best level and ratio (:func:`.cable_segmentation._seeds`).
    seeds : ndarray of bool
        The seeds on long runs.
    runs : ndarray of int64
        Their runs' labels (:func:`.cable_segmentation._long_seed_runs`).

    Returns
    -------
    grown : ndarray of bool
        ``seeds`` and the grid pixels taken.
    lines : SeedLines
        :func:`seed_lines` of ``grown`` (the lines the weaker pixels were judged on,
        less those not taken: not read twice).
    """
    weaker = (runs > 0) & ~seeds & (ratio >= MIN_RATIO)
    grid_step = shape[0] / seeds.shape[0]
    steps = np.array([level.step for level in levels])[best_level]
    off_seeds = cv2.distanceTransform((~seeds).view(np.uint8), cv2.DIST_L2, 3)
    beside_a_seed = weaker & (off_seeds * grid_step <= REACH * steps)
    if not weaker.any():
        return seeds, seed_lines(shape, levels, best_level, seeds)
    both = seeds | weaker
    lines = seed_lines(shape, levels, best_level, both)
    rows, cols = np.nonzero(both)
    # A line is a seed's when any seed of the grid falls in its level pixel.
    strong = np.zeros(lines.steps.size, bool)
    strong[lines.of_grid[seeds[rows, cols]]] = True
    run_of_line = np.zeros(lines.steps.size, np.int64)
    run_of_line[lines.of_grid] = runs[rows, cols]
    weak = np.flatnonzero(~strong)
    if weak.size == 0:
        return seeds, lines_of_kept(lines, seeds[rows, cols])
    # Imported here, as in tinted_by_a_neighbour: only the contrast path pays for scipy.
    from scipy.spatial import cKDTree

    centres = np.stack([lines.centres_x, lines.centres_y], axis=1)
    strong_index = np.flatnonzero(strong)
    near = min(NEAREST_SEEDS, strong_index.size)
    _, found = cKDTree(centres[strong_index]).query(centres[weak], k=near)
    found = strong_index[np.asarray(found).reshape(weak.size, near)]
    # The nearest of those on the weak line's own run (none: not taken).
    same_run = run_of_line[found] == run_of_line[weak][:, None]
    first = np.argmax(same_run, axis=1)
    has_seed = same_run[np.arange(weak.size), first]
    seed_colour = lines.colours[found[np.arange(weak.size), first], 0].astype(np.float64)
    colour = lines.colours[weak].astype(np.float64)
    from_seed = np.linalg.norm(colour[:, 0] - seed_colour, axis=1)
    seed_contrast = np.linalg.norm(colour[:, 1:] - seed_colour[:, None], axis=2).min(axis=1)
    nearest = found[np.arange(weak.size), first]
    beside = np.zeros(lines.steps.size, bool)
    beside[lines.of_grid[beside_a_seed[rows, cols]]] = True
    along = along_the_seeds_line(lines, weak, nearest, seed_colour)
    of_the_cable = np.zeros(lines.steps.size, bool)
    of_the_cable[weak[has_seed & (from_seed < 0.5 * seed_contrast) & (~beside[weak] | along)]] = (
        True
    )
    taken = weaker[rows, cols] & of_the_cable[lines.of_grid]
    kept = seeds[rows, cols] | taken
    grown = np.zeros(seeds.shape, bool)
    grown[rows[kept], cols[kept]] = True
    return grown, lines_of_kept(lines, kept)


def lines_of_kept(lines: SeedLines, kept: np.ndarray) -> SeedLines:
    """:func:`seed_lines` of a subset of the grid seeds ``lines`` was made from, taken
    from ``lines``: ``kept`` per grid seed (in ``np.nonzero`` order). A line's colours are
    its level pixel's, whichever of its grid seeds remain; a line none remains on goes."""
    cells = np.zeros(lines.steps.size, bool)
    cells[lines.of_grid[kept]] = True
    taken = lines.take(cells)
    return SeedLines(
        taken.centres_y,
        taken.centres_x,
        taken.angles,
        taken.steps,
        taken.colours,
        taken.of_grid[kept],
    )


def along_the_seeds_line(
    lines: SeedLines, weak: np.ndarray, nearest: np.ndarray, seed_colour: np.ndarray
) -> np.ndarray:
    """Which weaker lines run along their nearest seed's line, between the same sides.

    A weaker line within a seed's reach is either the same cable seen on another track
    of its profile (its highlight, lighter than the seed's line, where the segment angle
    falls between two of :data:`N_ORIENTATIONS`: segmentation pass 7) or something beside
    the cable (its shadow, a ground of its colour). Along the cable its direction is the
    seed's, within one angle step, and the colours :data:`OFFSET` px to either side of it
    are the seed's sides: each nearer the seed's side than half way from that side to the
    seed's line (the half-way border of :func:`.cable_segmentation._extent`). Beside the
    cable, the cable itself is one of its sides.

    Parameters
    ----------
    lines : SeedLines
    weak, nearest : ndarray of int64
        ``(M,)``: the weaker lines and, for each, its nearest seed's line.
    seed_colour : ndarray
        ``(M, 3)``: the colour of that seed's line.

    Returns
    -------
    ndarray of bool
        ``(M,)``.
    """
    turn = np.abs(np.angle(np.exp(2j * (lines.angles[weak] - lines.angles[nearest])))) / 2.0
    seed_sides = lines.colours[nearest, 1:3].astype(np.float64)
    own_sides = lines.colours[weak, 1:3].astype(np.float64)
    side_contrast = np.linalg.norm(seed_sides - seed_colour[:, None], axis=2)
    same_sides = (np.linalg.norm(own_sides - seed_sides, axis=2) < 0.5 * side_contrast).all(axis=1)
    return (turn <= np.pi / N_ORIENTATIONS + 1e-6) & same_sides
