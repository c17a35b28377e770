"""Plain per-segment "inferred" flags of a resampled chain, widths across a chain, and the
chain's radius from them."""

import numpy as np


def inferred_segments(source_edge, edge_lengths, hidden_edge):
    inferred = np.zeros(len(source_edge) - 1, bool)
    for k in range(len(source_edge) - 1):
        span_edges = slice(source_edge[k], source_edge[k + 1] + 1)
        weights = edge_lengths[span_edges]
        if weights.sum() > 0:
            inferred[k] = (weights * hidden_edge[span_edges]).sum() > 0.5 * weights.sum()
        else:
            inferred[k] = bool(hidden_edge[source_edge[k]])
    return inferred


def sides_across(joints, mask, limit):
    """How far the mask reaches each side of the chain at each joint, then at each
    segment's middle."""
    n = len(joints)
    widths = []
    for k in range(n):
        tangent = joints[min(k + 1, n - 1)] - joints[max(k - 1, 0)]
        widths.append(_sides(mask, joints[k], tangent, limit))
    for k in range(n - 1):
        middle = 0.5 * (joints[k] + joints[k + 1])
        widths.append(_sides(mask, middle, joints[k + 1] - joints[k], limit))
    return np.array(widths, float).reshape(-1, 2)


def _sides(mask, point, tangent, limit):
    length = np.hypot(*tangent)
    if length == 0:
        return (np.nan, np.nan)
    normal = np.array([-tangent[1], tangent[0]]) / length
    return (
        _edge_distance(mask, point, normal, limit),
        _edge_distance(mask, point, -normal, limit),
    )


def _edge_distance(mask, point, direction, limit):
    """Where the ray enters the first background pixel (the square of side 1 round its
    centre): every pixel border the ray crosses, in order along it."""
    height, width = mask.shape
    cell = [int(np.floor(point[0] + 0.5)), int(np.floor(point[1] + 0.5))]
    if not (0 <= cell[0] < width and 0 <= cell[1] < height) or not mask[cell[1], cell[0]]:
        return np.nan
    crossings = []
    for axis, size in ((0, width), (1, height)):
        if direction[axis] != 0:
            along = (np.arange(size + 1) - 0.5 - point[axis]) / direction[axis]
            crossings += [(t, axis) for t in along[along > 0]]
    for t, axis in sorted(crossings):
        cell[axis] += 1 if direction[axis] > 0 else -1
        if t > limit or not (0 <= cell[0] < width and 0 <= cell[1] < height):
            return np.nan
        if not mask[cell[1], cell[0]]:
            return t
    return np.nan


def radius_from_sides(sides, radius, centred_share, quantisation):
    """The code ``_pipeline_kernels.radius_from_sides`` replaced in pipeline.chain_radius."""
    widths = sides.sum(axis=1)
    centred = sides.min(axis=1) >= centred_share * widths
    widths = widths[np.isfinite(widths) & centred]
    if widths.size == 0:
        return radius
    median = float(np.median(widths))
    near = widths[np.abs(widths - median) <= quantisation]
    return max(0.5 * (float(np.mean(near)) if near.size else median), 0.5)
