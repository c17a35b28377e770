"""Plain :func:`service.perception.bridge_ends.ends_clear_of_crossing`: the NumPy code
``_bridge_ends_kernels.clear_of_crossing`` replaced."""

from dataclasses import replace

import numpy as np

from service.perception._geometry_kernels import END_FIT_MAX_TURNING
from service.perception.bridge_ends import (
    short_piece_clear_of_crossing,
    start_on_the_piece,
    widened_tip_length,
)
from service.perception.geometry import fit_where_skipped
from tests.perception.references.geometry import polyline_length


def ends_clear_of_crossing(points, end, far_skip, span, distance):
    length = polyline_length(points)
    if end.width <= 0:
        return None
    backwards = np.ascontiguousarray(points if end.at_start else points[::-1], np.float64)
    if length < span:  # no compiled code
        return short_piece_clear_of_crossing(points, backwards, end, span, distance)
    skip = max(float(end.skip), widened_tip_length(backwards, distance, end.width))
    reach = length - skip - far_skip
    fit_span = span
    if far_skip > end.skip and reach >= 0.5 * span:
        fit_span = min(span, reach)
    if skip <= 0:
        return None
    fit_span = bend_aware_span(backwards, skip, fit_span)
    inner = fit_where_skipped(points, end.at_start, fit_span, skip)
    if inner is None:
        return None
    # The bridge starts on the piece where the fit misses it (over half the full span).
    position, direction = start_on_the_piece(backwards, skip, span, *inner)
    return replace(end, position=position, direction=direction), skip


def bend_aware_span(backwards, skip, span):
    """Halved while the turns at the joints between ``skip`` and ``skip + span`` of arc
    length add up to more than ``END_FIT_MAX_TURNING``."""
    steps = np.diff(backwards, axis=0)
    inner = np.cumsum(np.hypot(steps[:, 0], steps[:, 1]))[:-1]  # arc length at joints 1..
    turns = np.arctan2(
        steps[:-1, 0] * steps[1:, 1] - steps[:-1, 1] * steps[1:, 0],
        steps[:-1, 0] * steps[1:, 0] + steps[:-1, 1] * steps[1:, 1],
    )
    while span > 1.0:
        within = (inner >= skip) & (inner <= skip + span)
        if abs(float(turns[within].sum())) <= END_FIT_MAX_TURNING:
            break
        span *= 0.5
    return span
