"""An end whose fit went astray on a tight bend, refitted nearer its tip.

An end's quadratic is fitted over a few cable widths (:func:`.merging.chain_ends`),
leaving out the tip a cut's hook bends. On a short piece running round a loop's turn or
a doubled-back cable's bend up to an object, that stretch turns by a quarter turn or
more, and the quadratic, extrapolated over the tip, lands beside the cable, off the
foreground, pointing tens of degrees off. Read there, the end's join cost, the image's
evidence for a turn under the object (the background beside it, whether it is cut) and
its bridge are read off the cable: the turn is never joined. A fit over the stretch
nearest the tip, which the bend has not yet turned away from, lies on the cable (as
:func:`._geometry_kernels.bend_aware_fit` fits an end at a loop's own crossing). Only
an end whose fit left out no narrow tip: a cut's hook puts the tip in the cut's corner,
up to a half width off the middle, and a fit there is no better reading.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from service.perception.geometry import end_fit


def ends_off_the_mask(pieces: list[np.ndarray], ends: Sequence, mask: np.ndarray) -> np.ndarray:
    """Per end, whether its fitted position lies off the foreground (or the picture) and
    its fitted line passes further from its piece's tip than the piece's half width: the
    most thinning bends a tip off the cable's middle, into a cut's corner, is a half
    width, so a fit whose line misses the tip by more, beside the cable, has followed no
    cable there."""
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
        offset = np.asarray(end.position, np.float64) - tip
        # Across the fitted line: ahead along it, a fit extrapolated over a long hook
        # runs on past the tip into the object, as the cable does.
        if not abs(offset[0] * end.direction[1] - offset[1] * end.direction[0]) > end.width:
            off[k] = False
    return off


def ends_refitted_onto_the_mask(
    pieces: list[np.ndarray], ends: list, mask: np.ndarray, span: float, skip: float = 0.0
) -> list:
    """``ends`` with each end :func:`ends_off_the_mask` finds refitted over half the
    span, and half again, until it is no longer astray (left as it was where none
    does): the stretch of cable nearest the tip, which the bend has not yet turned away
    from, as :func:`._geometry_kernels.bend_aware_fit` fits an end at a loop's own
    crossing. With the skeleton's joints about 10 px apart, half the span holds too few
    joints for the quadratic, and the end is then its tip, pointing along the chord to
    the last joint within that span. Only ends whose fit left out no more than
    ``skip`` (the fit's own skip: no narrow tip, so the tip lies on the cable's
    middle)."""
    off = np.flatnonzero(ends_off_the_mask(pieces, ends, mask))
    if not len(off):
        return ends
    ends = list(ends)
    for k in off.tolist():
        end = ends[k]
        if end.skip > skip:
            # Its fit left out a narrow tip (a cut's hook): the tip lies in the cut's
            # corner, up to a half width off the middle, no reading to fall back on.
            continue
        points = pieces[end.piece]
        if len(points) < 2 or closed_on_itself(points):
            # A ring closed on itself (its two tips neighbouring pixels) has no free
            # end to read: its fit runs round the ring, and a refit would give it one.
            continue
        span_tried = 0.5 * span
        while span_tried > 1.0:
            # Through geometry.end_fit, the kernel every fit calls (and the one the
            # compiled module holds), not a kernel only other kernels call.
            position, direction, curvature = end_fit(
                points, end.at_start, span_tried, float(end.skip)
            )
            refitted = replace(end, position=position, direction=direction, curvature=curvature)
            if not ends_off_the_mask(pieces, [refitted], mask)[0]:
                ends[k] = refitted
                break
            span_tried *= 0.5
    return ends


def closed_on_itself(points: np.ndarray) -> bool:
    """Whether a piece's two tips are neighbouring pixels: a contour run closed on itself
    (:func:`.fitting.fit_chains` puts a joint at a closed run's first and last pixel)."""
    return bool(np.hypot(*(points[0] - points[-1])) <= 1.5)
