"""Plain crossing search (the sweep) and centreline profile of the whole image."""

import cv2
import numpy as np


def find_intersections(chains):
    starts = np.concatenate([c[:-1] for c in chains])
    ends = np.concatenate([c[1:] for c in chains])
    chain_ids = np.concatenate([np.full(len(c) - 1, i) for i, c in enumerate(chains)])
    indices = np.concatenate([np.arange(len(c) - 1) for c in chains])
    lo, hi = np.minimum(starts, ends), np.maximum(starts, ends)
    found = []
    order = np.argsort(lo[:, 0])
    lo_sorted_x = lo[order, 0]
    for position, a in enumerate(order):
        others = order[position + 1 : np.searchsorted(lo_sorted_x, hi[a, 0], side="right")]
        others = others[(lo[others, 1] <= hi[a, 1]) & (hi[others, 1] >= lo[a, 1])]
        near = np.abs(indices[others] - indices[a]) <= 2
        others = others[~((chain_ids[others] == chain_ids[a]) & near)]
        if len(others) == 0:
            continue
        p, r = starts[a], ends[a] - starts[a]
        q, s = starts[others], ends[others] - starts[others]
        denom = r[0] * s[:, 1] - r[1] * s[:, 0]
        qp = q - p
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (qp[:, 0] * s[:, 1] - qp[:, 1] * s[:, 0]) / denom
            u = (qp[:, 0] * r[1] - qp[:, 1] * r[0]) / denom
        hit = (np.abs(denom) > 1e-12) & (t >= 0) & (t < 1) & (u >= 0) & (u < 1)
        for b, t_hit in zip(others[hit], t[hit], strict=True):
            key_a, key_b = (chain_ids[a], indices[a]), (chain_ids[b], indices[b])
            first, second = (a, b) if key_a <= key_b else (b, a)
            found.append(
                (
                    int(chain_ids[first]),
                    int(indices[first]),
                    int(chain_ids[second]),
                    int(indices[second]),
                    p + t_hit * r,
                )
            )
    return found


def profile_variation(image_bgr, centre, direction, half_length) -> float:
    """Mean absolute change, per pixel, of the blurred Lab image along a line through
    ``centre``: bilinear samples 1 px apart, the whole image converted."""
    blurred = cv2.GaussianBlur(image_bgr, (3, 3), 0)
    lab = cv2.cvtColor(blurred, cv2.COLOR_BGR2LAB).astype(np.float32)
    offsets = np.arange(-half_length, half_length + 0.5, 1.0)
    points = centre[None, :] + offsets[:, None] * direction[None, :]
    map_x = points[:, 0].astype(np.float32).reshape(1, -1)
    map_y = points[:, 1].astype(np.float32).reshape(1, -1)
    samples = cv2.remap(lab, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    samples = samples.reshape(-1, 3)
    return float(np.abs(np.diff(samples, axis=0)).sum(axis=1).mean())
