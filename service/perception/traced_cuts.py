"""A turn under an object whose cut lies on the turn's own bend, read where it is cut.

Where an object hides a cable's sharp turn, its border may cut a strand already bending
into the turn. The end's fit, over the usual span, lags the bend by tens of degrees and
its tip (the skeleton's hook into the cut) lies off the cable's middle, so the front read
from there is neither square nor lopsided, and no test of the cut passes. The middle
line traced on the mask from where the fit begins to where it leaves the mask
(:func:`.cut_ends.end_at_the_cut`, the point and direction a gap's bridge already
starts from) is where the cable passes out of sight and which way: the cut read there,
along that direction, is the object's border across the cable.

:func:`traced_cut_tests` gives the turn pass (:mod:`.turn_joins`) the two tests of the
cuts (:func:`.gap_evidence.cut_ends_alike`: both ends cut square, or one square and the
other lopsided) read at the traced cuts, after the tests of the usual readings, and a
third: one end cut square at its traced cut, the other no cable's own tip. Where a
doubled-back cable's turn is round (a half circle across the two cuts) and an object's
border cuts both strands along their bends into it, the second strand's front, read along
its fit or its traced direction, bulges past a round cap's bulge (the border crosses the
bend, not the cable's straight run) and its sides differ by less than a lopsided cut's:
neither straight across, lopsided nor a tip. What tells a turn's cut from two cables
ending side by side is that neither end is a cable's own round tip
(:func:`.appearance.reads_own_tip`), and one end is cut square.

Where a strand bends into the turn right up to an object's corner, or into a short, steep
cut, the skeleton runs on into the narrow wedge the object leaves, and an end left at its
tip (too few joints to fit) or fitted over the bend points along a chord of the bend: the
line back from its tip to where its fit begins leaves the cable on the bend's inside.
Traced from there, nothing is read. Such an end's trace starts on its own piece instead,
at the first point back from the tip where the cable is seen whole
(:func:`_start_on_the_piece`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from service.perception.appearance import cut_square, reads_own_tip
from service.perception.cut_ends import REACH_PAST_SKIP_RADII, end_at_the_cut, on_mask
from service.perception.end_readings import closed_on_itself
from service.perception.gap_evidence import (
    TURN_CUT_ENDS,
    alike_and_short_enough_to_hide,
    cut_ends_alike,
)
from service.perception.one_border import one_border_test
from service.perception.turn_joins import PIXEL_ROUNDING

# Step (px) of the walk back along a piece from its tip (:func:`_start_on_the_piece`).
WALK_STEP_PX = 0.5


def _start_on_the_piece(end, piece: np.ndarray, distance: np.ndarray, half_width: float):
    """Where a trace to ``end``'s cut starts on its own ``piece`` (joints, px), and the
    heading there: the first point back along the piece from the end's tip, no nearer
    the tip than where the end's fit begins (``skip``), at which the mask's
    ``distance`` transform reaches the cable's ``half_width`` less a pixel's rounding
    (:data:`.turn_joins.PIXEL_ROUNDING`), heading along the piece towards the tip; with
    the arc from there to the tip. None where the piece nowhere shows the cable whole.

    The skeleton lies on the cable's middle, so the piece's point stays on the cable
    where a straight line back from a tip in a cut's corner leaves it; a cut only
    narrows a section, so where the section is whole the cut has not begun."""
    points = np.asarray(piece, np.float64)
    if not end.at_start:
        points = points[::-1]  # from the tip back
    steps = np.diff(points, axis=0)
    lengths = np.hypot(steps[:, 0], steps[:, 1])
    arcs = np.concatenate([[0.0], np.cumsum(lengths)])
    backs = np.arange(float(end.skip), float(arcs[-1]) + 1e-9, WALK_STEP_PX)
    if len(steps) == 0 or len(backs) == 0:
        return None
    # Every point of the walk at once (a ring's end walks its whole piece).
    segment = np.minimum(np.searchsorted(arcs, backs, side="right") - 1, len(steps) - 1)
    used = lengths[segment] > 0
    backs, segment = backs[used], segment[used]
    walked = (
        points[segment] + ((backs - arcs[segment]) / lengths[segment])[:, None] * steps[segment]
    )
    cols = np.rint(walked[:, 0]).astype(np.int64)
    rows = np.rint(walked[:, 1]).astype(np.int64)
    height, width = distance.shape[:2]
    inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    depth = np.zeros(len(walked))
    depth[inside] = distance[rows[inside], cols[inside]]
    whole = np.flatnonzero(depth >= half_width - PIXEL_ROUNDING)
    if len(whole) == 0:
        return None
    k = int(whole[0])
    return walked[k], -steps[segment[k]] / lengths[segment[k]], float(backs[k])


def ends_at_the_cuts(
    ends: list,
    mask: np.ndarray,
    radius: float,
    pieces: list | None = None,
    distance: np.ndarray | None = None,
) -> Callable[[int], object]:
    """Per end index, the end read at its traced cut (a callable, each end traced once,
    when first asked): position where the middle line leaves the mask, the direction
    there, no hook to leave out (``skip`` 0); the end itself where its fit left out no
    tip or no cut lies ahead. With ``pieces`` and the mask's ``distance`` transform, an
    end whose line back to where its fit begins leaves the mask is traced from its own
    piece (:func:`_start_on_the_piece`)."""
    traced: dict[int, object] = {}

    def at_cut(index: int):
        if index not in traced:
            end = ends[index]
            found = None
            if end.skip > 0:
                half_width = (end.width or radius) + 0.5
                start = replace(end, position=end.position - end.skip * end.direction)
                limit = end.skip + REACH_PAST_SKIP_RADII * half_width + 2.0
                if (
                    pieces is not None
                    and distance is not None
                    and not on_mask(mask, *start.position)
                    and not closed_on_itself(pieces[end.piece])
                ):
                    # The line back from the tip leaves the cable (a bend into a
                    # corner's wedge): start on the piece, where the cable is whole. (A
                    # ring closed on itself has no free end: its fit runs round it.)
                    on_piece = _start_on_the_piece(end, pieces[end.piece], distance, end.width)
                    if on_piece is not None:
                        point, heading, back = on_piece
                        start = replace(end, position=point, direction=heading, curvature=0.0)
                        limit = back + REACH_PAST_SKIP_RADII * half_width + 2.0
                # The cut's shape read at the border itself (where it crosses the
                # middle line), as the turn pass's tests were measured: on traces that
                # stop at the first narrowed section (a cut's test is evidence for a
                # join; its reading was not measured again, see BENCHMARKS, cutfb14).
                found = end_at_the_cut(
                    mask, start, half_width, limit, to_the_border=True, first_narrowing=True
                )
            traced[index] = (
                end
                if found is None
                else replace(end, position=found[1], direction=found[2], skip=0.0)
            )
        return traced[index]

    return at_cut


def traced_cut_tests(ends, mask, colours, radius, image, pieces=None, distance=None) -> tuple:
    """The tests of two cut ends (:func:`.gap_evidence.cut_ends_alike`, both cut, then
    one cut and the other lopsided: :data:`.gap_evidence.TURN_CUT_ENDS`) with each end
    read at its traced cut (:func:`ends_at_the_cuts`, given ``pieces`` and ``distance``),
    as callables ``(i, j, curve)``; False where neither end reads otherwise than usual
    (the usual tests said so). Then one end cut square at its traced cut (or at its fit,
    where none is traced) and the other's front, read at its fit and at its traced cut,
    no cable's own tip (:func:`.appearance.reads_own_tip`), the two ends alike and the
    curve no longer than an object of the background's own colour hides
    (:func:`.gap_evidence.alike_and_short_enough_to_hide`): a strand cut along its bend
    into a round turn (the module's docstring). A turn found on it alone is bridged as
    any gap is, from the cuts (:data:`.gap_evidence.TURN_EVIDENCE_ALONG_CURVE` has no
    entry for it), which across a round turn's two cuts draw its half circle."""
    at_cut = ends_at_the_cuts(ends, mask, radius, pieces, distance)
    square: dict[int, bool] = {}

    def cut_square_at(index: int) -> bool:
        # Whether the end reads square at its traced cut, once per end: the same for
        # every curve tried, and false on most of them (a cable's own tip).
        if index not in square:
            end = at_cut(index)
            square[index] = bool(cut_square(mask, end.position, end.direction, end.width, end.skip))
        return square[index]

    def test(cut_needed: int):
        def passes(i: int, j: int, curve: np.ndarray) -> bool:
            a, b = at_cut(i), at_cut(j)
            if a is ends[i] and b is ends[j]:
                return False
            cuts = [cut_square_at(i), cut_square_at(j)]
            if not any(cuts) or (cut_needed > 1 and not all(cuts)):
                return False  # cut_ends_alike would say no on these reads
            return cut_ends_alike(a, b, i, j, curve, mask, colours, radius, cut_needed, image)

        return passes

    tipless: dict[int, bool] = {}

    def no_tip_at(index: int) -> bool:
        # Whether the end's front, at its fit and at its traced cut, is no cable's own
        # tip: once per end, the same for every curve tried.
        if index not in tipless:
            fitted, traced = ends[index], at_cut(index)
            readings = (fitted,) if traced is fitted else (fitted, traced)
            tipless[index] = not any(
                reads_own_tip(mask, end.position, end.direction, end.width, end.skip)
                for end in readings
            )
        return tipless[index]

    def one_cut_the_other_no_tip(i: int, j: int, curve: np.ndarray) -> bool:
        # A strand cut along its bend into a round turn reads neither straight across
        # nor lopsided: the cut is told from a cable's own tip by not being one.
        cuts = [cut_square_at(i), cut_square_at(j)]
        if not any(cuts) or not no_tip_at(j if cuts[0] else i):
            return False
        return alike_and_short_enough_to_hide(
            at_cut(i), at_cut(j), i, j, curve, mask, colours, radius, image
        )

    def readings(index: int) -> tuple:
        fitted, traced = ends[index], at_cut(index)
        return (fitted,) if traced is fitted else (fitted, traced)

    return (
        test(2),
        test(TURN_CUT_ENDS),
        one_cut_the_other_no_tip,
        one_border_test(ends, readings, mask, colours, radius, image),
    )
