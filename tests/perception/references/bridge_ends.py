"""Plain :func:`service.perception.bridge_ends.ends_clear_of_crossing`: the NumPy code
``_bridge_ends_kernels.clear_of_crossing`` replaced."""

from dataclasses import replace

import numpy as np

from service.perception._geometry_kernels import END_FIT_MAX_TURNING
from service.perception.bridge_ends import WIDENED_MARGIN_PX, start_on_the_piece
from service.perception.geometry import fit_where_skipped
from tests.perception.references.geometry import polyline_length


def ends_clear_of_crossing(points, end, far_skip, span, distance):
    length = polyline_length(points)
    if end.width <= 0 or length < span:
        return None
    backwards = np.ascontiguousarray(points if end.at_start else points[::-1], np.float64)
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


def widened_tip_length(backwards, distance, width):
    """Arc length from the tip to the first joint where the mask is no wider than
    ``width + WIDENED_MARGIN_PX``."""
    rows = np.clip(np.rint(backwards[:, 1]).astype(int), 0, distance.shape[0] - 1)
    cols = np.clip(np.rint(backwards[:, 0]).astype(int), 0, distance.shape[1] - 1)
    narrow = np.flatnonzero(distance[rows, cols] <= width + WIDENED_MARGIN_PX)
    last = int(narrow[0]) if narrow.size else len(backwards) - 1
    return polyline_length(backwards[: last + 1])
