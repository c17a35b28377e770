"""Merged paths: the curves that fill gaps and the walk that strings pieces and bridges.

:func:`gap_curve` is the curve ``DetectParams.gap_curve`` names: by default "smooth", a
cubic along both end directions that spreads the turn over the whole gap as an elastic
cable bends (the Euler spiral, :mod:`.euler_spiral`, where the ends turn by a right angle
or more); or the paper's "natural" curve (Keipour et al.), straight along the end
directions and then one arc of constant curvature. :func:`assemble_paths` walks every
group of pieces :mod:`.merging` joined from one free end to the other and bridges each
join. Its compiled curves are in ``_merging_kernels``, beside the rest of the merging
step's kernels.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from dataclasses import dataclass, field

import numpy as np

from schemas import GapCurve
from service.perception import _merging_kernels
from service.perception.bridge_ends import partners
from service.perception.euler_spiral import euler_spiral, is_large_turn
from service.perception.geometry import arc_lengths


@dataclass
class MergedPath:
    """A merged DLO as a dense polyline before resampling.

    ``filled[k]`` is True when edge ``k`` (vertices ``k`` to ``k + 1``) was drawn by
    the merging step across a gap rather than taken from a fitted piece.
    """

    vertices: np.ndarray
    filled: np.ndarray
    pieces: list[int] = field(default_factory=list)


def gap_curve(
    start: np.ndarray,
    leaving: np.ndarray,
    end: np.ndarray,
    arriving: np.ndarray,
    step: float = 1.0,
    shape: GapCurve | str = GapCurve.smooth,
) -> np.ndarray:
    """The curve that bridges a gap between two chain ends.

    With ``shape="natural"`` (Keipour et al.), it leaves ``start`` along ``leaving``,
    goes straight while that still helps, turns with one constant rate (the gentlest
    arc tangent to both end directions), and arrives at ``end`` heading along
    ``arriving``. When the two end rays do not meet ahead of both ends (an S-shaped or
    backward gap), no single arc fits, and a cubic Bezier with tangents along both
    directions is used instead.

    With ``shape="smooth"``, it is a cubic Bezier along both end directions whose
    handles would trace a circular arc between symmetric ends: the turning is spread
    over the whole gap instead of following a straight stretch, as an elastic cable
    bends. It is the default of :class:`schemas.DetectParams` (``gap_curve``): on
    generated scenes its bridges follow hidden stretches more closely. Where the end
    headings turn by :data:`.euler_spiral.LARGE_TURN` (a right angle) or more about the
    line between the ends, the cubic's equal handles flatten the turn, and a loop's
    hidden arc past a half turn it takes the short way round: there the curve is the
    Euler spiral between the two ends (:func:`.euler_spiral.euler_spiral`), the cubic
    only where none joins them.

    Parameters
    ----------
    start, end : ndarray
        ``[x, y]`` of the two ends.
    leaving, arriving : ndarray
        Unit headings at ``start`` and at ``end``.
    step : float
        Spacing of the returned samples.
    shape : {"smooth", "natural"}
        Default "smooth", as ``DetectParams.gap_curve``.

    Returns
    -------
    ndarray
        ``(M, 2)`` samples from ``start`` to ``end`` inclusive.
    """
    if GapCurve(shape) is GapCurve.smooth and is_large_turn(start, leaving, end, arriving):
        spiral = euler_spiral(start, leaving, end, arriving, step)
        if spiral is not None:
            return spiral
    # Compiled: a frame bridges hundreds of gaps and crossings. The plain versions are
    # the references in tests/perception/references/merging.py.
    kernel = (
        _merging_kernels.smooth_curve_kernel
        if GapCurve(shape) is GapCurve.smooth
        else _merging_kernels.natural_curve_kernel
    )
    return kernel(
        np.asarray(start, np.float64),
        np.asarray(leaving, np.float64),
        np.asarray(end, np.float64),
        np.asarray(arriving, np.float64),
        float(step),
    )


def assemble_paths(
    pieces: list[np.ndarray],
    ends: list,
    joins: list[tuple[int, int, float]],
    curve: GapCurve | str = GapCurve.smooth,
    trims: np.ndarray | None = None,
    bridges: dict[tuple[int, int], np.ndarray] | None = None,
) -> list[MergedPath]:
    """Walk every group of joined pieces from one free end to the other; each join is
    bridged by :func:`gap_curve` of the given ``curve`` shape, or by the curve
    ``bridges[i, j]`` (from end ``i`` to end ``j``) where given: the shape a turn out
    of sight was found hidden along (:mod:`.turn_joins`), or a strand's own side of a
    stretch where it touches another (:mod:`.touching`). ``trims[e]`` (optional)
    is the arc length left out of end ``e``'s piece at that end, where its bridge
    starts further in. ``ends`` are :class:`.merging.ChainEnd` (only ``position`` and
    ``direction`` are read), two per piece."""
    partner = partners(len(ends), joins)
    if trims is not None:
        pieces = _trimmed(pieces, trims)
    visited = np.zeros(len(pieces), bool)
    paths = []
    for first_end in range(len(ends)):
        piece = first_end // 2
        if visited[piece] or partner[first_end] != -1:
            continue
        vertices, filled, order = [], [], []
        entry = first_end
        while True:
            piece = entry // 2
            visited[piece] = True
            order.append(piece)
            points = pieces[piece] if entry % 2 == 0 else pieces[piece][::-1]
            filled.append(np.zeros(len(points) - 1, bool))
            vertices.append(points)
            exit_end = entry ^ 1
            next_entry = partner[exit_end]
            if next_entry == -1:
                break
            bridge = _given_bridge(bridges, exit_end, next_entry)
            if bridge is None:
                bridge = gap_curve(
                    ends[exit_end].position,
                    ends[exit_end].direction,
                    ends[next_entry].position,
                    -ends[next_entry].direction,
                    shape=curve,
                )
            vertices.append(bridge[1:-1])
            filled.append(np.ones(len(bridge) - 1, bool))
            entry = next_entry
        paths.append(MergedPath(np.concatenate(vertices), np.concatenate(filled), pieces=order))
    return paths


def _given_bridge(bridges, start: int, end: int) -> np.ndarray | None:
    """The curve ``bridges`` holds from end ``start`` to end ``end`` (either way)."""
    if not bridges:
        return None
    if (start, end) in bridges:
        return bridges[start, end]
    if (end, start) in bridges:
        return bridges[end, start][::-1]
    return None


def _trimmed(pieces: list[np.ndarray], trims: np.ndarray) -> list[np.ndarray]:
    """The pieces less the joints within ``trims[2 k]`` of piece ``k``'s start and
    ``trims[2 k + 1]`` of its end (at least two joints kept)."""
    result = []
    ends = np.asarray(trims, np.float64).reshape(-1, 2).T.tolist()
    for points, head, tail in zip(pieces, *ends, strict=True):
        if head <= 0 and tail <= 0:
            result.append(points)
            continue
        # The arc lengths never decrease: the joints kept are one run, found by bisection
        # (in a list: what np.searchsorted finds, without its call per bound and piece).
        along = arc_lengths(points).tolist()
        first = bisect_left(along, head)
        stop = bisect_right(along, along[-1] - tail)
        result.append(points[first:stop].copy() if stop - first >= 2 else points)
    return result
