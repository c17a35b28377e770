"""Tracking, step 1: which stretch of which track each stretch of a detection shows.

A detection's chains are cut into *pieces* where the detection is sure of itself: away
from gaps it filled (inferred segments) and from places where the chain comes near
another chain or near itself (crossings, touching cables), where its merging step may
have joined the wrong strands. Each piece is then laid along the tracks, as predicted
for this frame: its points are projected on each track's polyline and, because a cable
does not stretch, the arc along the piece and the arc along the track differ by one
constant (and perhaps a sign), ``s = sign * u + offset``. The offset found this way is
the registration of the piece onto the track; its spread tells whether the piece fits
at all. Each piece goes to the track it fits best, or to none (a new cable, perhaps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from schemas import Detection
from service.perception import _tracking_kernels

EDGE_MARGIN = 3.0
"""A chain end within its radius plus this many px of the picture's edge is not a tip."""


@dataclass(frozen=True, eq=False)
class Piece:
    """A stretch of a detected chain that is surely one cable.

    Attributes
    ----------
    chain : int
        Index of the chain in the detection.
    first : int
        Index in that chain of the piece's first joint.
    joints : ndarray, shape (n, 2)
        Joints ``segment_length`` apart: the arc of joint ``i`` is ``i * segment_length``.
    tips : (bool, bool)
        Whether the first and the last joint are a cable's free end (the chain's end,
        clear of the picture's edge and of other chains).
    radius : float
    """

    chain: int
    first: int
    joints: np.ndarray
    tips: tuple[bool, bool]
    radius: float

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.joints, axis=0), axis=1).sum())


@dataclass(frozen=True)
class Fit:
    """How a piece lies along a track: track arc = ``sign * piece arc + offset``."""

    track: int
    sign: int
    offset: float
    cost: float
    inliers: float  # share of the piece's points near the track


def detection_pieces(detection: Detection) -> list[Piece]:
    """Cut the detection's chains into :class:`Piece` s (see the module's documentation)."""
    chains = [np.asarray(chain.points, dtype=np.float64) for chain in detection.chains]
    if not chains:
        return []
    step = detection.segment_length
    radii = np.array([chain.radius for chain in detection.chains], dtype=np.float64)
    reach = 1.5 * radii + 1.0
    self_gap = np.ceil(2.0 * math.pi * reach / step).astype(np.int64) + 2
    counts = np.array([len(c) for c in chains], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    crowded = _tracking_kernels.crowded_segments(
        np.ascontiguousarray(np.concatenate(chains)), starts, counts, reach, self_gap
    )
    pieces = []
    segment = 0
    width, height = detection.width, detection.height
    for index, (chain, joints) in enumerate(zip(detection.chains, chains, strict=True)):
        n_segments = len(joints) - 1
        usable = ~np.asarray(chain.inferred, dtype=bool) & ~crowded[segment : segment + n_segments]
        segment += n_segments
        for begin, end in _runs(usable):
            piece_joints = joints[begin : end + 1]
            tips = (
                begin == 0 and clear_of_edge(joints[0], chain.radius, width, height),
                end == n_segments and clear_of_edge(joints[-1], chain.radius, width, height),
            )
            pieces.append(Piece(index, begin, piece_joints, tips, chain.radius))
    return pieces


def fit_pieces(
    pieces: list[Piece],
    tracks: list[np.ndarray],
    gates: np.ndarray,
    step: float,
) -> list[Fit | None]:
    """The track each piece lies along, and how; None for a piece that fits none.

    Parameters
    ----------
    pieces : list of Piece
    tracks : list of (N, 2) ndarray
        The tracks' joints as predicted for this frame (``step`` apart).
    gates : (T,) ndarray
        Per track, how far (px) a point of a piece may lie from it and still count.
    step : float
        The segment length.
    """
    if not pieces or not tracks:
        return [None] * len(pieces)
    samples = [_samples(piece.joints) for piece in pieces]
    points = np.ascontiguousarray(np.concatenate([p for p, _, _ in samples]))
    directions = np.ascontiguousarray(np.concatenate([d for _, d, _ in samples]))
    counts = np.array([len(t) for t in tracks], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    distance, arc, cosine = _tracking_kernels.nearest_on_polylines(
        points,
        directions,
        np.ascontiguousarray(np.concatenate(tracks)),
        starts,
        counts,
        np.ascontiguousarray(gates, dtype=np.float64),
    )
    arc = arc * step  # joint units to px along the track
    fits: list[Fit | None] = []
    first = 0
    for piece_points, _, piece_arc in samples:
        rows = slice(first, first + len(piece_points))
        first += len(piece_points)
        best = None
        for track in range(len(tracks)):
            fit = _fit_one(
                distance[rows, track],
                arc[rows, track],
                cosine[rows, track],
                piece_arc,
                float(gates[track]),
            )
            if fit is None:
                continue
            sign, offset, cost, inliers = fit
            if best is None or cost < best.cost:
                best = Fit(track, sign, offset, cost, inliers)
        fits.append(best)
    return fits


def _fit_one(distance, arc, cosine, piece_arc, gate):
    """(sign, offset, cost, inlier share) of one piece on one track, or None."""
    near = np.isfinite(distance) & (np.abs(cosine) >= 0.5)
    n_near = int(np.count_nonzero(near))
    if n_near < 3 or n_near < 0.5 * len(distance):
        return None
    sign = 1 if float(cosine[near].sum()) >= 0 else -1
    offsets = arc[near] - sign * piece_arc[near]
    offset = float(np.median(offsets))
    spread = float(np.median(np.abs(offsets - offset)))
    if spread > 0.5 * max(float(piece_arc[-1]), 1.0):
        return None  # the piece does not lie along the track in order
    inliers = n_near / len(distance)
    cost = float(np.mean(distance[near])) + (1.0 - inliers) * gate + 0.25 * spread
    return sign, offset, cost, inliers


def _samples(joints: np.ndarray):
    """Joints and segment midpoints, their unit directions, and their arcs (joint units)."""
    n = len(joints)
    points = np.empty((2 * n - 1, 2))
    points[0::2] = joints
    points[1::2] = 0.5 * (joints[:-1] + joints[1:])
    steps = np.diff(joints, axis=0)
    lengths = np.linalg.norm(steps, axis=1)
    unit = steps / np.maximum(lengths, 1e-12)[:, None]
    directions = np.empty_like(points)
    directions[1::2] = unit
    directions[0] = unit[0]
    directions[-1] = unit[-1]
    if n > 2:
        inner = unit[:-1] + unit[1:]
        directions[2:-1:2] = inner / np.maximum(np.linalg.norm(inner, axis=1), 1e-12)[:, None]
    arc = np.concatenate([[0.0], np.cumsum(np.repeat(lengths / 2.0, 2))])
    return points, directions, arc


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first joint, last joint) of each run of True segments."""
    padded = np.concatenate([[False], flags, [False]]).astype(np.int8)
    edges = np.diff(padded)
    begins = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    return [(int(b), int(e)) for b, e in zip(begins, ends, strict=True)]


def clear_of_edge(point, radius: float, width: int, height: int) -> bool:
    """Whether a chain end lies clear of the picture's edge (so it can be a cable's tip)."""
    margin = radius + EDGE_MARGIN
    x, y = float(point[0]), float(point[1])
    return margin <= x <= width - 1 - margin and margin <= y <= height - 1 - margin
