"""Plain resampling of a polyline to joints exactly one step apart."""

import numpy as np


def resample(points, step):
    joints, edges = [points[0]], [0]
    current, edge, n, step_sq = points[0], 0, len(points), step * step
    while edge < n - 1:
        a, b = points[edge], points[edge + 1]
        if (b[0] - current[0]) ** 2 + (b[1] - current[1]) ** 2 < step_sq:
            edge += 1
            continue
        d, f = b - a, a - current
        qa = d[0] * d[0] + d[1] * d[1]
        qb = 2.0 * (f[0] * d[0] + f[1] * d[1])
        qc = f[0] * f[0] + f[1] * f[1] - step_sq
        disc = max(qb * qb - 4.0 * qa * qc, 0.0)
        t = (-qb + np.sqrt(disc)) / (2.0 * qa) if qa > 0 else 1.0
        current = a + min(max(t, 0.0), 1.0) * d
        joints.append(current)
        edges.append(edge)
    return np.array(joints), np.array(edges)


def polyline_length(points):
    """Arc length of a polyline: the steps' Euclidean lengths added up (by NumPy)."""
    if len(points) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(np.asarray(points, np.float64), axis=0), axis=1).sum())


def arc_lengths(points):
    """Arc length of each vertex from the first."""
    steps = np.linalg.norm(np.diff(np.asarray(points, np.float64), axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])
