"""Where an end's own reading is no reading of its cable, a better one.

Two ends the merging step reads at a piece's tip can stand off the cable it ends:

- a fit over a tight bend: an end's quadratic is fitted over a few cable widths
  (:func:`.merging.chain_ends`); on a short piece running round a loop's turn or a
  doubled-back cable's bend that stretch turns by a quarter turn or more, and the
  quadratic, extrapolated over the tip it leaves out, lands beside the cable, off the
  foreground and further from the piece's tip than the cable's half width, pointing
  tens of degrees off (:func:`ends_refitted_onto_the_mask`);
- a tip left unfitted in a cut's corner: a piece too short to fit past the hook a
  cut leaves is read at its tip, up to a half width off the middle, along the chord
  through the hook; from there no cut is read (the section is already narrowed), so
  the tests of the image's evidence see no cut (:func:`ends_read_at_cuts`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from service.perception._geometry_kernels import outward_fit
from service.perception.bridge_ends import FIT_JOINTS
from service.perception.crossing_stubs import LazyEnds
from service.perception.cut_ends import (
    CUT_NARROWING_PX,
    REACH_PAST_SKIP_RADII,
    end_at_the_cut,
    unfitted_end_cut,
)
from service.perception.geometry import arc_lengths


def ends_off_the_mask(pieces: list[np.ndarray], ends: Sequence, mask: np.ndarray) -> np.ndarray:
    """Per end, whether its fitted position lies off the foreground (or the picture) and
    further from its piece's tip than the piece's half width: the most thinning bends a
    tip off the cable's middle, into a cut's corner, is a half width, so a fit that
    lands further off and beside the cable has followed no cable."""
    if not len(ends):
        return np.zeros(0, bool)
    xy = np.rint(np.array([end.position for end in ends], np.float64)).astype(np.int64)
    height, width = mask.shape[:2]
    inside = (xy[:, 0] >= 0) & (xy[:, 1] >= 0) & (xy[:, 0] < width) & (xy[:, 1] < height)
    on = np.zeros(len(ends), bool)
    on[inside] = mask[xy[inside, 1], xy[inside, 0]]
    off = ~on
    for k in np.flatnonzero(off).tolist():
        end = ends[k]
        points = pieces[end.piece]
        tip = np.asarray(points[0] if end.at_start else points[-1], np.float64)
        if not np.hypot(*(np.asarray(end.position, np.float64) - tip)) > end.width:
            off[k] = False
    return off


def ends_refitted_onto_the_mask(
    pieces: list[np.ndarray], ends: list, mask: np.ndarray, span: float
) -> list:
    """``ends`` with each end :func:`ends_off_the_mask` finds refitted over half the
    span, and half again, until its fitted position lies on the foreground (left as it
    was where none does): the stretch of cable nearest the tip, which the bend has not
    yet turned away from (as :func:`._geometry_kernels.bend_aware_fit` fits an end at a
    loop's own crossing). The same skip, so a cut's hook stays left out."""
    off = np.flatnonzero(ends_off_the_mask(pieces, ends, mask))
    if not len(off):
        return ends
    ends = list(ends)
    for k in off.tolist():
        end = ends[k]
        points = np.ascontiguousarray(pieces[end.piece], np.float64)
        backwards = np.ascontiguousarray(points if end.at_start else points[::-1])
        span_tried = 0.5 * span
        while span_tried > 1.0:
            x, y, dx, dy, curvature = outward_fit(backwards, float(end.skip), span_tried)
            refitted = replace(
                end,
                position=np.array([x, y]),
                direction=np.array([dx, dy]),
                curvature=curvature,
            )
            if not ends_off_the_mask(pieces, [refitted], mask)[0]:
                ends[k] = refitted
                break
            span_tried *= 0.5
    return ends


def ends_read_at_cuts(
    pieces: list[np.ndarray], ends: Sequence, seen_from: Sequence, mask: np.ndarray, radius: float
) -> LazyEnds:
    """``seen_from`` (the ends as the image's evidence reads them,
    :func:`.crossing_stubs.ends_past_crossings`) with each end left at its tip for want
    of joints to fit (a fit that left a tip out, with fewer than
    :data:`.bridge_ends.FIT_JOINTS` joints past it) and whose own trace finds no cut
    moved to the cut read from its piece's middle (:func:`.cut_ends.unfitted_end_cut`,
    as its bridge is drawn from), its ``skip`` 0; each read when first asked for."""

    def read(index: int):
        end = seen_from[index]
        if end is not ends[index] or end.skip <= 0:
            return end
        points = pieces[end.piece]
        along = arc_lengths(points[::-1] if end.at_start else points)
        if np.count_nonzero(along[-1] - along > end.skip) >= FIT_JOINTS:
            return end
        half_width = (end.width or radius) + 0.5
        if half_width < CUT_NARROWING_PX:
            return end
        limit = end.skip + REACH_PAST_SKIP_RADII * half_width + 2.0
        if end_at_the_cut(mask, end, half_width, limit) is not None:
            return end
        cut = unfitted_end_cut(mask, points, end, half_width)
        if cut is None:
            return end
        return replace(
            end,
            position=np.asarray(cut[0], np.float64),
            direction=np.asarray(cut[1], np.float64),
            skip=0.0,
        )

    return LazyEnds(len(ends), read)
