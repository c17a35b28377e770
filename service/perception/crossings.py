"""Crossings: where strands cross, and which one is on top.

A strand on top is continuous across the crossing: sampled along its centreline the
image barely changes. A strand underneath disappears beneath the other cable, so its
centreline profile runs over the top cable's edges and shading (and, for cables of
different colours, its colour). The strand whose profile varies least is on top.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import cv2
import numpy as np

from service.perception import _crossings_kernels


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
    # Sweep along x: only segments whose x ranges overlap can intersect. The sweep
    # itself is compiled (_crossings_kernels.segment_intersections).
    order = np.argsort(lo[:, 0])
    lo_sorted_x = lo[order, 0]
    stops = np.searchsorted(lo_sorted_x, hi[order, 0], side="right")
    pairs, params = _crossings_kernels.segment_intersections(
        np.ascontiguousarray(starts, np.float64),
        np.ascontiguousarray(ends, np.float64),
        chain_ids.astype(np.int64),
        indices.astype(np.int64),
        order.astype(np.int64),
        stops.astype(np.int64),
    )
    found = []
    for (a, b), t_hit in zip(pairs.tolist(), params, strict=True):
        first, second = (
            (a, b) if (chain_ids[a], indices[a]) <= (chain_ids[b], indices[b]) else (b, a)
        )
        found.append(
            (
                int(chain_ids[first]),
                int(indices[first]),
                int(chain_ids[second]),
                int(indices[second]),
                starts[a] + t_hit * (ends[a] - starts[a]),
            )
        )
    return found


def _profile_maps(lines: list[tuple[np.ndarray, np.ndarray, float]]):
    """The ``float32`` sampling maps of all the lines, one after the other in one row
    (each line's samples 1 px apart), and where each line's samples start and stop."""
    # Each line's points as the centre plus each step along the direction, line by line.
    points = [
        centre + np.arange(-half, half + 0.5, 1.0)[:, None] * direction
        for centre, direction, half in lines
    ]
    bounds = np.cumsum([0, *(len(line) for line in points)])
    maps = np.concatenate(points).T.astype(np.float32, order="C")
    return maps[:1], maps[1:], bounds


def _variations(image_lab: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, bounds) -> list[float]:
    """Mean absolute change per pixel of each line's samples, ``bounds`` apart in the maps.

    One remap for all the lines (a bilinear sample depends on its own coordinates
    alone); the change from one line's last sample to the next line's first is left out.
    """
    samples = cv2.remap(image_lab, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    changes = np.abs(np.diff(samples.reshape(-1, image_lab.shape[2]), axis=0)).sum(axis=1)
    return [float(changes[start : stop - 1].mean()) for start, stop in pairwise(bounds.tolist())]


def _lab(image_bgr: np.ndarray) -> np.ndarray:
    """The image as ``float32`` Lab after a 3x3 Gaussian blur."""
    blurred = cv2.GaussianBlur(image_bgr, (3, 3), 0)
    return cv2.cvtColor(blurred, cv2.COLOR_BGR2LAB).astype(np.float32)


# Pixels round the samples' box that the bilinear samples and the blur may read.
_SAMPLE_MARGIN = 2
_BLUR_MARGIN = 1


def profile_variations(
    image_bgr: np.ndarray, lines: list[tuple[np.ndarray, np.ndarray, float]], full_lab=None
) -> tuple[list[float], np.ndarray | None]:
    """Mean absolute change of ``_lab(image_bgr)`` per pixel along each line.

    A line is ``(centre, direction, half_length)``: samples 1 px apart (bilinear) from
    ``-half_length`` to ``half_length`` along the unit ``direction`` through ``centre``.

    Blurs and converts only the patch round the lines when they stay clear of the
    image border, which gives the very same samples: the blur and the colour
    conversion of a pixel depend on its 3x3 neighbourhood alone, every bilinear
    sample reads pixels inside the patch, and the sample coordinates move by whole
    pixels (exact in ``float32``). Near the border (where the reflection would differ)
    the whole image is converted, once, and returned for the next call.
    """
    map_x, map_y, bounds = _profile_maps(lines)
    height, width = image_bgr.shape[:2]
    x0 = int(np.floor(map_x.min())) - _SAMPLE_MARGIN
    y0 = int(np.floor(map_y.min())) - _SAMPLE_MARGIN
    x1 = int(np.floor(map_x.max())) + _SAMPLE_MARGIN + 1
    y1 = int(np.floor(map_y.max())) + _SAMPLE_MARGIN + 1
    m = _BLUR_MARGIN
    if x0 - m >= 0 and y0 - m >= 0 and x1 + m <= width and y1 + m <= height:
        patch = _lab(image_bgr[y0 - m : y1 + m, x0 - m : x1 + m])[m:-m, m:-m]
        shift_x, shift_y = np.float32(x0), np.float32(y0)
        return _variations(patch, map_x - shift_x, map_y - shift_y, bounds), full_lab
    if full_lab is None:
        full_lab = _lab(image_bgr)
    return _variations(full_lab, map_x, map_y, bounds), full_lab


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
    # The Lab image is converted only round each crossing (or whole, once, when a
    # crossing is near the border): see profile_variations.
    full_lab = None
    crossings = []
    for chain_a, seg_a, chain_b, seg_b, point in intersections:
        if image_bgr is None:
            over_first, confidence = True, 0.0
        else:
            half = 2.0 * max(radii[chain_a], radii[chain_b]) + 2.0
            lines = []
            for chain, seg in ((chain_a, seg_a), (chain_b, seg_b)):
                direction = chains[chain][seg + 1] - chains[chain][seg]
                direction = direction / max(float(np.hypot(*direction)), 1e-12)
                lines.append((point, direction, half))
            variation, full_lab = profile_variations(image_bgr, lines, full_lab)
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
