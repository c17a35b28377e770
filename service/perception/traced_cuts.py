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
other lopsided) read at the traced cuts, after the tests of the usual readings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from service.perception.appearance import cut_square
from service.perception.cut_ends import REACH_PAST_SKIP_RADII, end_at_the_cut
from service.perception.gap_evidence import TURN_CUT_ENDS, cut_ends_alike


def ends_at_the_cuts(ends: list, mask: np.ndarray, radius: float) -> Callable[[int], object]:
    """Per end index, the end read at its traced cut (a callable, each end traced once,
    when first asked): position where the middle line leaves the mask, the direction
    there, no hook to leave out (``skip`` 0); the end itself where its fit left out no
    tip or no cut lies ahead."""
    traced: dict[int, object] = {}

    def at_cut(index: int):
        if index not in traced:
            end = ends[index]
            found = None
            if end.skip > 0:
                half_width = (end.width or radius) + 0.5
                start = replace(end, position=end.position - end.skip * end.direction)
                limit = end.skip + REACH_PAST_SKIP_RADII * half_width + 2.0
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


def traced_cut_tests(ends, mask, colours, radius, image) -> tuple:
    """The tests of two cut ends (:func:`.gap_evidence.cut_ends_alike`, both cut, then
    one cut and the other lopsided: :data:`.gap_evidence.TURN_CUT_ENDS`) with each end
    read at its traced cut (:func:`ends_at_the_cuts`), as callables ``(i, j, curve)``;
    False where neither end reads otherwise than usual (the usual tests said so)."""
    at_cut = ends_at_the_cuts(ends, mask, radius)
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

    return (test(2), test(TURN_CUT_ENDS))
