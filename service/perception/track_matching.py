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

import cv2
import numpy as np

from schemas import Detection
from service.perception import _tracking_kernels
from service.perception.geometry import arc_lengths

MIN_COSINE = 0.5
"""A piece's point counts as on a track only where their directions are within 60
degrees of each other (either way round)."""
COLOUR_SPAN = 3
"""Joints either side compared for a change of colour along a chain ..."""
COLOUR_JUMP = 30.0
"""... and how much they must differ (Lab, 8-bit scaling, lightness weighted by half)."""
COLOUR_WEIGHTS = np.array([0.5, 1.0, 1.0])
EDGE_MARGIN = 3.0
"""A chain end within its radius plus this many px of the picture's edge is not a tip."""


@dataclass(frozen=True, eq=False)
class Chains:
    """A detection's chains as arrays, read once per frame.

    Attributes
    ----------
    joints, arcs : list of ndarray
        Per chain, its ``(n, 2)`` joints and their arcs from its first joint (px).
    radii : list of float
    inferred : list of (n - 1,) bool ndarray
    width, height : int
    step : float
        The segment length.
    colour_breaks : list of (n - 1,) bool ndarray
        Per chain, the segments where its colour changes (the detection joined two
        cables of different colours there); all False without an image.
    lab : list of (n, 3) ndarray, or None
        Per chain, the Lab colour under each joint, NaN outside the picture (None
        without an image).
    """

    joints: list[np.ndarray]
    arcs: list[np.ndarray]
    radii: list[float]
    inferred: list[np.ndarray]
    width: int
    height: int
    step: float
    colour_breaks: list[np.ndarray]
    lab: list[np.ndarray] | None = None

    @classmethod
    def of(cls, detection: Detection, image: np.ndarray | None = None) -> Chains:
        joints = [np.asarray(chain.points, dtype=np.float64) for chain in detection.chains]
        inferred = [np.asarray(chain.inferred, dtype=bool) for chain in detection.chains]
        lab = None
        if image is not None and joints:
            # Every chain's joints converted at once: the pieces' and the candidates'
            # colours are read from here.
            values, inside = lab_under(image, np.concatenate(joints))
            values[~inside] = np.nan
            lab = np.split(values, np.cumsum([len(points) for points in joints])[:-1])
        return cls(
            joints=joints,
            arcs=[arc_lengths(points) for points in joints],
            radii=[chain.radius for chain in detection.chains],
            inferred=inferred,
            width=detection.width,
            height=detection.height,
            step=detection.segment_length,
            colour_breaks=_colour_breaks(image, lab, inferred),
            lab=lab,
        )

    def colour(self, chain: int, first: int, last: int) -> np.ndarray | None:
        """Median Lab colour under joints ``first`` to ``last`` of a chain that lie in
        the picture (None without an image or without such joints)."""
        if self.lab is None:
            return None
        values = self.lab[chain][first : last + 1]
        return column_median(values[~np.isnan(values[:, 0])])

    def colour_of(self, pieces: list[Piece]) -> np.ndarray | None:
        """Median Lab colour under the pieces' joints that lie in the picture (a track's
        colour where this frame shows it)."""
        if self.lab is None or not pieces:
            return None
        values = np.concatenate([self.lab[p.chain][p.first : p.last + 1] for p in pieces])
        return column_median(values[~np.isnan(values[:, 0])])


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
    arcs : ndarray, shape (n,)
        Arc of each joint from the piece's first (px).
    """

    chain: int
    first: int
    joints: np.ndarray
    tips: tuple[bool, bool]
    radius: float
    arcs: np.ndarray

    @property
    def length(self) -> float:
        return float(self.arcs[-1])

    @property
    def last(self) -> int:
        """Index in the chain of the piece's last joint."""
        return self.first + len(self.joints) - 1


@dataclass(frozen=True)
class Fit:
    """How a piece lies along a track: track arc = ``sign * piece arc + offset``."""

    track: int
    sign: int
    offset: float
    cost: float
    inliers: float  # share of the piece's points near the track


def detection_pieces(chains: Chains) -> list[Piece]:
    """Cut the detection's chains into :class:`Piece` s (see the module's documentation)."""
    if not chains.joints:
        return []
    step = chains.step
    radii = np.array(chains.radii, dtype=np.float64)
    reach = 1.5 * radii + 1.0
    self_gap = np.ceil(2.0 * math.pi * reach / step).astype(np.int64) + 2
    counts = np.array([len(c) for c in chains.joints], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    crowded = _tracking_kernels.crowded_segments(
        np.ascontiguousarray(np.concatenate(chains.joints)), starts, counts, reach, self_gap
    )
    pieces = []
    segment = 0
    width, height = chains.width, chains.height
    for index, joints in enumerate(chains.joints):
        radius = chains.radii[index]
        arcs = chains.arcs[index]
        n_segments = len(joints) - 1
        usable = ~chains.inferred[index] & ~crowded[segment : segment + n_segments]
        usable &= ~chains.colour_breaks[index]
        segment += n_segments
        for begin, end in _runs(usable):
            tips = (
                begin == 0 and clear_of_edge(joints[0], radius, width, height),
                end == n_segments and clear_of_edge(joints[-1], radius, width, height),
            )
            pieces.append(
                Piece(
                    index,
                    begin,
                    joints[begin : end + 1],
                    tips,
                    radius,
                    arcs[begin : end + 1] - arcs[begin],
                )
            )
    return pieces


def fit_pieces(
    pieces: list[Piece],
    tracks: list[np.ndarray],
    gates: np.ndarray,
    step: float,
    compatible: np.ndarray | None = None,
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
    compatible : (P, T) bool ndarray, optional
        Which pieces may fit which tracks at all (their colours agree).
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
    counts_per_piece = np.array([len(p) for p, _, _ in samples], dtype=np.int64)
    starts_per_piece = np.concatenate([[0], np.cumsum(counts_per_piece)[:-1]]).astype(np.int64)
    ok, sign, offset, cost, share = _tracking_kernels.fit_statistics(
        distance,
        arc,
        cosine,
        np.ascontiguousarray(np.concatenate([a for _, _, a in samples])),
        starts_per_piece,
        counts_per_piece,
        np.ascontiguousarray(gates, dtype=np.float64),
        MIN_COSINE,
        (counts - 1).astype(np.float64) * step,
    )
    if compatible is not None:
        ok &= compatible
    fits: list[Fit | None] = []
    for p in range(len(pieces)):
        if not ok[p].any():
            fits.append(None)
            continue
        t = int(np.argmin(np.where(ok[p], cost[p], np.inf)))
        fits.append(
            Fit(t, int(sign[p, t]), float(offset[p, t]), float(cost[p, t]), float(share[p, t]))
        )
    return fits


def _samples(joints: np.ndarray):
    """Joints and segment midpoints, their unit directions, and their arcs (joint units)."""
    return _tracking_kernels.piece_samples(np.ascontiguousarray(joints, dtype=np.float64))


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first joint, last joint) of each run of True segments."""
    padded = np.concatenate([[False], flags, [False]]).astype(np.int8)
    edges = padded[1:] - padded[:-1]
    begins = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    return [(int(b), int(e)) for b, e in zip(begins, ends, strict=True)]


def column_median(values: np.ndarray) -> np.ndarray | None:
    """Per column, the median of the rows (as ``np.median(values, axis=0)``, without its
    per-call cost on a few rows); None for no rows."""
    count = len(values)
    if count == 0:
        return None
    ordered = np.sort(values, axis=0)
    return 0.5 * (ordered[(count - 1) // 2] + ordered[count // 2])


def _colour_breaks(
    image: np.ndarray | None, chain_lab: list[np.ndarray] | None, inferred: list[np.ndarray]
) -> list[np.ndarray]:
    """Per chain, the segments across which its colour changes: the median Lab colour of
    the :data:`COLOUR_SPAN` joints before differs from that of the ones after by more
    than :data:`COLOUR_JUMP` (lightness weighted by half). Joints on an inferred
    stretch (under an occluder, across a gap) show something else's colour and are left
    out of the medians; a side with none of its joints seen makes no break."""
    breaks = [np.zeros(len(flags), dtype=bool) for flags in inferred]
    if image is None or chain_lab is None or image.ndim < 3:
        return breaks  # no image, or a grey one: no colour to go by
    span = COLOUR_SPAN
    for values, hidden_segments, flags in zip(chain_lab, inferred, breaks, strict=True):
        if len(values) < 2 * span + 1:
            continue
        colours = values * COLOUR_WEIGHTS  # NaN outside the picture: no colour there
        hidden = np.zeros(len(values), dtype=bool)
        hidden[:-1] |= hidden_segments
        hidden[1:] |= hidden_segments
        colours[hidden] = np.nan
        # Window k covers joints k .. k + span; break k compares joints k - span .. k
        # with joints k + 1 .. k + span.
        before_median = _window_medians(colours, span + 1)
        after_median = _window_medians(colours[1:], span)
        ks = np.arange(span, len(values) - span)
        jump = np.linalg.norm(before_median[ks - span] - after_median[ks], axis=1)
        flags[ks] = np.nan_to_num(jump, nan=0.0) > COLOUR_JUMP
    return breaks


def _window_medians(values: np.ndarray, width: int) -> np.ndarray:
    """Per window of ``width`` consecutive rows, the median of each column over the rows
    that are not NaN (NaN where none is): ``np.nanmedian`` over small windows, without
    its per-call cost (a compiled loop)."""
    return _tracking_kernels.window_medians(np.ascontiguousarray(values, dtype=np.float64), width)


def lab_under(image: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lab colour (OpenCV's 8-bit scaling, float) of the pixel under each of ``points``
    (clamped to the picture; a grey image counts as grey colour), and which points lie
    in the picture."""
    height, width = image.shape[:2]
    inside = (
        (points[:, 0] >= 0)
        & (points[:, 0] <= width - 1)
        & (points[:, 1] >= 0)
        & (points[:, 1] <= height - 1)
    )
    cols = np.clip(np.rint(points[:, 0]).astype(np.intp), 0, width - 1)
    rows = np.clip(np.rint(points[:, 1]).astype(np.intp), 0, height - 1)
    pixels = image[rows, cols]
    if pixels.ndim == 1:  # a grey image
        pixels = np.repeat(pixels[:, None], 3, axis=1)
    pixels = np.ascontiguousarray(pixels[:, :3], dtype=np.uint8).reshape(-1, 1, 3)
    lab = cv2.cvtColor(pixels, cv2.COLOR_BGR2LAB).reshape(-1, 3).astype(np.float64)
    return lab, inside


def clear_of_edge(point, radius: float, width: int, height: int) -> bool:
    """Whether a chain end lies clear of the picture's edge (so it can be a cable's tip)."""
    margin = radius + EDGE_MARGIN
    x, y = float(point[0]), float(point[1])
    return margin <= x <= width - 1 - margin and margin <= y <= height - 1 - margin


MET_ENDS_JOINTS = 3
"""Joints a piece must lie along each of two tracks before it is cut between them."""
MET_ENDS_REACH = 2.0
"""How near (joints along the track) a piece's last joint on a track lies to its free end."""
MET_ENDS_NEAR = 10.0
"""Segments between two tracks' free ends under which pieces are looked at (what a track
sees of its cable may stop short of its end near another cable: a crowded stretch)."""


def cut_at_met_ends(
    pieces: list[Piece],
    tracks: list[np.ndarray],
    tips: list[tuple[bool, bool]],
    gates: np.ndarray,
    step: float,
) -> list[Piece]:
    """Pieces cut where they run from one track's free end on along another's free end.

    Two cables whose free ends touch can come out of the detection as one chain, with no
    gap or crossing to cut it at. A cable does not go on beyond its free end: a piece
    that lies along one track up to that track's free end and then along another track
    from that one's free end is two cables, and is cut there (each half fits its own
    track; neither track grows onto the other's cable). Tracks are as predicted
    (``step`` apart), ``tips`` their ends seen as free, ``gates`` as for
    :func:`fit_pieces`; ``step`` the segment length.
    """
    ends = [
        (t, end, track[0] if end == 0 else track[-1])
        for t, (track, free) in enumerate(zip(tracks, tips, strict=True))
        for end in (0, 1)
        if free[end] and len(track) >= MET_ENDS_JOINTS
    ]
    near = any(
        a[0] != b[0] and np.hypot(*(a[2] - b[2])) <= MET_ENDS_NEAR * step
        for i, a in enumerate(ends)
        for b in ends[i + 1 :]
    )
    if not near:  # no two free ends of two tracks near each other: the usual frame
        return pieces
    counts = np.array([len(t) for t in tracks], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    result = []
    for piece in pieces:
        halves = _met_ends_cut(piece, tracks, tips, gates, counts, starts)
        result.extend([piece] if halves is None else halves)
    return result


def _met_ends_cut(piece, tracks, tips, gates, counts, starts):
    """The two halves of ``piece`` (see :func:`cut_at_met_ends`), or None."""
    joints = piece.joints
    if len(joints) < 2 * MET_ENDS_JOINTS:
        return None
    points, directions, _ = _samples(joints)
    points, directions = points[0::2], directions[0::2]  # the joints
    distance, arc, cosine = _tracking_kernels.nearest_on_polylines(
        np.ascontiguousarray(points),
        np.ascontiguousarray(directions),
        np.ascontiguousarray(np.concatenate(tracks)),
        starts,
        counts,
        np.ascontiguousarray(gates, dtype=np.float64),
    )
    distance = np.where(np.abs(cosine) >= MIN_COSINE, distance, np.inf)
    on = np.where(np.isfinite(distance.min(axis=1)), np.argmin(distance, axis=1), -1)
    labelled = np.flatnonzero(on >= 0)
    if len(labelled) < 2 * MET_ENDS_JOINTS:
        return None
    first, second = int(on[labelled[0]]), int(on[labelled[-1]])
    if first == second:
        return None
    # Labels run first ... first, then second ... second along the piece (once).
    change = int(np.flatnonzero(on[labelled] != first)[0])
    if np.any(on[labelled[change:]] != second) or change < MET_ENDS_JOINTS:
        return None
    if len(labelled) - change < MET_ENDS_JOINTS:
        return None
    last_on_first, first_on_second = int(labelled[change - 1]), int(labelled[change])
    for track, at in ((first, last_on_first), (second, first_on_second)):
        foot = arc[at, track]
        at_first, at_last = foot <= MET_ENDS_REACH, foot >= counts[track] - 1 - MET_ENDS_REACH
        if not ((at_first and tips[track][0]) or (at_last and tips[track][1])):
            return None
    return [
        Piece(
            piece.chain,
            piece.first,
            joints[: last_on_first + 1],
            (piece.tips[0], False),
            piece.radius,
            piece.arcs[: last_on_first + 1],
        ),
        Piece(
            piece.chain,
            piece.first + first_on_second,
            joints[first_on_second:],
            (False, piece.tips[1]),
            piece.radius,
            piece.arcs[first_on_second:] - piece.arcs[first_on_second],
        ),
    ]
