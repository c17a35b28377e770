"""Crossings: where strands cross, and which one is on top.

A strand on top is continuous across the crossing: sampled along its centreline the
image barely changes. A strand underneath disappears beneath the other cable, so its
centreline profile runs over the top cable's edges and shading (and, for cables of
different colours, its colour). The strand whose profile varies least is on top.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class CrossingFound:
    x: float
    y: float
    over: int
    under: int
    over_segment: int
    under_segment: int
    confidence: float


def _segments(chains: list[np.ndarray]):
    starts = np.concatenate([c[:-1] for c in chains])
    ends = np.concatenate([c[1:] for c in chains])
    chain_ids = np.concatenate([np.full(len(c) - 1, i) for i, c in enumerate(chains)])
    indices = np.concatenate([np.arange(len(c) - 1) for c in chains])
    return starts, ends, chain_ids, indices


def find_intersections(chains: list[np.ndarray]) -> list[tuple[int, int, int, int, np.ndarray]]:
    """All proper intersections between segments of the chains.

    Returns
    -------
    list of (chain_a, segment_a, chain_b, segment_b, point)
        Segments of one chain that are neighbours (or next-but-one) are not tested.
    """
    if not chains:
        return []
    starts, ends, chain_ids, indices = _segments(chains)
    lo = np.minimum(starts, ends)
    hi = np.maximum(starts, ends)
    found = []
    # Sweep along x: only segments whose x ranges overlap can intersect.
    order = np.argsort(lo[:, 0])
    lo_sorted_x = lo[order, 0]
    for position, a in enumerate(order):
        stop = np.searchsorted(lo_sorted_x, hi[a, 0], side="right")
        others = order[position + 1 : stop]
        if len(others) == 0:
            continue
        others = others[(lo[others, 1] <= hi[a, 1]) & (hi[others, 1] >= lo[a, 1])]
        same = chain_ids[others] == chain_ids[a]
        near = np.abs(indices[others] - indices[a]) <= 2
        others = others[~(same & near)]
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
            first, second = (
                (a, b) if (chain_ids[a], indices[a]) <= (chain_ids[b], indices[b]) else (b, a)
            )
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


def profile_variation(
    image_lab: np.ndarray, centre: np.ndarray, direction: np.ndarray, half_length: float
) -> float:
    """Mean absolute change of the image per pixel along a line through ``centre``."""
    offsets = np.arange(-half_length, half_length + 0.5, 1.0)
    points = centre[None, :] + offsets[:, None] * direction[None, :]
    map_x = points[:, 0].astype(np.float32).reshape(1, -1)
    map_y = points[:, 1].astype(np.float32).reshape(1, -1)
    samples = cv2.remap(image_lab, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    samples = samples.reshape(-1, image_lab.shape[2])
    return float(np.abs(np.diff(samples, axis=0)).sum(axis=1).mean())


def detect_crossings(
    chains: list[np.ndarray], radii: list[float], image_bgr: np.ndarray | None
) -> list[CrossingFound]:
    """Crossings between (and within) chains, with the strand on top.

    Parameters
    ----------
    chains : list of ndarray
        Final ``(K, 2)`` joint arrays; list index is the chain id.
    radii : list of float
        Half width of each chain.
    image_bgr : ndarray or None
        The image; without it the order cannot be seen, the lower id is put on top
        and the confidence is 0.
    """
    intersections = find_intersections(chains)
    if not intersections:
        return []
    image_lab = None
    if image_bgr is not None:
        blurred = cv2.GaussianBlur(image_bgr, (3, 3), 0)
        image_lab = cv2.cvtColor(blurred, cv2.COLOR_BGR2LAB).astype(np.float32)
    crossings = []
    for chain_a, seg_a, chain_b, seg_b, point in intersections:
        if image_lab is None:
            over_first, confidence = True, 0.0
        else:
            half = 2.0 * max(radii[chain_a], radii[chain_b]) + 2.0
            variation = []
            for chain, seg in ((chain_a, seg_a), (chain_b, seg_b)):
                direction = chains[chain][seg + 1] - chains[chain][seg]
                direction = direction / max(float(np.hypot(*direction)), 1e-12)
                variation.append(profile_variation(image_lab, point, direction, half))
            over_first = variation[0] <= variation[1]
            total = variation[0] + variation[1]
            confidence = abs(variation[0] - variation[1]) / total if total > 0 else 0.0
        over = (chain_a, seg_a) if over_first else (chain_b, seg_b)
        under = (chain_b, seg_b) if over_first else (chain_a, seg_a)
        crossings.append(
            CrossingFound(
                float(point[0]),
                float(point[1]),
                over[0],
                under[0],
                over[1],
                under[1],
                float(confidence),
            )
        )
    return crossings
