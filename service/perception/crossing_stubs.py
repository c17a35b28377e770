"""A strand that crosses another cable and passes out of sight just past the crossing.

Where a cable crosses another and, a few widths further on, runs under an object, the
stretch seen between the crossing and the object's border is a stub of skeleton
hanging off the crossing's junction: spur removal takes it (it is shorter than a spur
from the junction it joins) or the junction zone swallows it. The strand's piece then
ends in the crossing's zone, and the junction's pairing, having no strand on the far
side to give it, leaves it free. Its cut, where the object's border crosses the
cable, lies beyond the crossing, on the stub: read at the end's fitted tip, inside the
crossing, the foreground runs on ahead (the other cable, then the stub), so the end
reads as no cut, and the stretch right past it is on the foreground, not under the
object. A join across the object is then refused for want of the evidence that is
there to see one stub further on.

:func:`ends_past_crossings` gives such an end, for the tests of the image's evidence
only (:mod:`.gap_evidence`, :func:`.appearance.gap_hidden`), at the stub's front: where
the foreground along the strand's own direction stops past the junction zone, when
the mask there bears no other piece (the stub lost its skeleton: a piece there is a
strand of its own, with its own end) and the stub is no longer than an end's fit
reads. The join's cost and its bridge still start from the end itself: the stub lies
straight along its direction.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import cv2
import numpy as np

from service.perception.bridge_ends import FIT_JOINTS

# The ray along a strand is read in steps of this many px.
RAY_STEP_PX = 0.5


def stub_front(
    tip: np.ndarray,
    direction: np.ndarray,
    mask: np.ndarray,
    zones: np.ndarray,
    reach: float,
) -> tuple[float, float] | None:
    """Where the foreground along a strand stops past the junction zone its tip lies in.

    Parameters
    ----------
    tip : ndarray (2,)
        The piece's tip joint (x, y), in a junction zone.
    direction : ndarray (2,)
        The end's outward unit direction.
    mask : ndarray (H, W) of bool
        The foreground.
    zones : ndarray (H, W) of bool
        The junction zones.
    reach : float
        The longest stub (px past the zone) looked for.

    Returns
    -------
    (float, float) or None
        The distances (px from the tip) at which the ray leaves the zone and at which it
        leaves the foreground after that; None when it leaves the foreground inside the
        zone (no stub: the other cable's far side), runs on past ``reach``, or leaves the
        picture.
    """
    height, width = mask.shape
    # All the ray's samples at once (a Python loop per step cost ~4 ms a photograph).
    steps = np.arange(0.0, 2.0 * reach, RAY_STEP_PX)
    x, y = np.rint(tip[None, :] + steps[:, None] * direction[None, :]).astype(np.int64).T
    outside = (x < 0) | (y < 0) | (x >= width) | (y >= height)
    x, y = x.clip(0, width - 1), y.clip(0, height - 1)
    stops = np.flatnonzero(outside | ~mask[y, x])
    stop = int(stops[0]) if len(stops) else len(steps)
    in_zone = zones[y[:stop], x[:stop]]
    # Into the zone (the tip may lie a few px short of it), across it and then the stub.
    exit_index = None
    if in_zone.any():
        after = np.flatnonzero(~in_zone[int(np.argmax(in_zone)) :])
        if len(after):
            exit_index = int(np.argmax(in_zone)) + int(after[0])
    if exit_index is not None:
        too_far = np.flatnonzero(steps[exit_index + 1 : stop + 1] > steps[exit_index] + reach)
        if len(too_far):
            return None  # the stub runs on past reach
    if stop == len(steps) or outside[stop] or exit_index is None:
        return None
    return float(steps[exit_index]), float(steps[stop])


class LazyEnds(Sequence):
    """A sequence of ends, each made when first asked for and kept.

    The image's evidence is read for the few pairs of ends a join or a turn is weighed
    between (on a photograph, a handful of the hundreds of ends), so an end is moved
    only when asked for: the same end object for every ask, as a list would give.
    """

    def __init__(self, count: int, make: Callable[[int], object]):
        self._count = count
        self._make = make
        self._made: dict[int, object] = {}

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(self._count))]
        if index < 0:
            index += self._count
        if not 0 <= index < self._count:
            raise IndexError(index)
        if index not in self._made:
            self._made[index] = self._make(index)
        return self._made[index]


def ends_past_crossings(
    pieces: list[np.ndarray],
    ends: list,
    in_junction: np.ndarray,
    mask: np.ndarray,
    zones: np.ndarray,
    reach: float,
) -> LazyEnds:
    """``ends`` with each end whose tip lies in a junction zone and whose strand runs on
    past it, straight, as a stub bearing no piece, moved to the stub's front (its
    ``skip`` 0: nothing of a hook to leave out there), for the image's evidence.

    Parameters
    ----------
    pieces : list of ndarray
        ``(K, 2)`` joints of the pieces (x, y).
    ends : list of ChainEnd
        Both ends of every piece (piece i: ends 2i, 2i+1), ``direction`` outwards.
    in_junction : ndarray of bool
        Per end, whether its piece's tip lies in a junction zone
        (:func:`.merging.tips_in_junctions`).
    mask, zones : ndarray (H, W) of bool
        The foreground and the junction zones.
    reach : float
        The longest stub (px past the zone): what an end's fit spans.

    Returns
    -------
    LazyEnds
        The ends, those moved replaced, the others the same objects; each read when
        first asked for.
    """
    drawn: list[np.ndarray] = []

    def pieces_drawn() -> np.ndarray:
        # The pieces drawn one px wide (once, when a stub is first found): a stub that
        # kept its skeleton holds a piece.
        if not drawn:
            image = np.zeros(mask.shape, np.uint8)
            cv2.polylines(
                image,
                [np.rint(p).astype(np.int32).reshape(-1, 1, 2) for p in pieces if len(p)],
                False,
                1,
            )
            drawn.append(image)
        return drawn[0]

    def moved(index: int):
        end = ends[index]
        if index >= len(in_junction) or not in_junction[index]:
            return end
        points = pieces[end.piece]
        tip = np.asarray(points[0] if end.at_start else points[-1], np.float64)
        direction = np.asarray(end.direction, np.float64)
        found = stub_front(tip, direction, mask, zones, reach)
        if found is None:
            return end
        exit_at, front = found
        half_width = max(float(end.width), 1.0)
        if front - exit_at < half_width:
            return end  # the other cable's far side just past the zone, not a stub
        normal = np.array([-direction[1], direction[0]])
        offsets = np.arange(-np.ceil(half_width), np.ceil(half_width) + 1.0)
        # Its outer half: near the zone the crossing cable's own pieces leave it.
        along = np.arange(0.5 * (exit_at + front), front, RAY_STEP_PX)
        samples = (
            tip[None, None, :]
            + along[:, None, None] * direction[None, None, :]
            + offsets[None, :, None] * normal[None, None, :]
        ).reshape(-1, 2)
        x, y = np.rint(samples).astype(np.int64).T
        height, width = mask.shape
        inside = (x >= 0) & (y >= 0) & (x < width) & (y < height)
        if pieces_drawn()[y[inside], x[inside]].any():
            return end
        # The last foreground sample before the front: the cut's edge.
        position = tip + (front - RAY_STEP_PX) * direction
        return replace(end, position=position, skip=0.0)

    return LazyEnds(len(ends), moved)


def evidence_ends(judged: Sequence, ends: Sequence, moved: Sequence) -> LazyEnds:
    """``judged`` (the ends as the turn pass judges them: a scrap's with its strand's
    colour and width) with each end :func:`ends_past_crossings` moved at its stub's
    front (``moved[k]`` not ``ends[k]``), for the image's evidence; each read when first
    asked for."""
    if not len(judged) == len(ends) == len(moved):
        raise ValueError("judged, ends and moved differ in length")

    def seen(index: int):
        shifted = moved[index]
        if shifted is ends[index]:
            return judged[index]
        return replace(judged[index], position=shifted.position, skip=shifted.skip)

    return LazyEnds(len(judged), seen)


def stub_fronts(
    pieces: list[np.ndarray],
    joins: list[tuple[int, int, float]],
    junction_of_end: list[int],
    ends: Sequence,
    moved: Sequence,
    given: frozenset[int],
) -> dict[int, object]:
    """Per end of a gap's join that lies in a crossing's junction and whose strand runs on
    as a stub to where it passes out of sight (``moved[k]`` not ``ends[k]``:
    :func:`ends_past_crossings`), its end at the stub's front; only joins whose other end
    is in no junction and neither end has a curve of its own (``given``).

    The join's bridge is drawn from the stub's cut (:func:`.cut_ends.bridges_from_the_cuts`):
    the stub lies straight on past the crossing, and where the cable passes out of sight
    there, not in the crossing, is where the hidden stretch begins. Only where the end's
    piece holds the joints its fit needs (:data:`.bridge_ends.FIT_JOINTS`): the stub is
    read along the end's direction, which on a scrap of two or three joints (a fork
    thinning makes in a cut's wedge) is a chord of a few px, no strand's line."""
    return {
        k: moved[k]
        for i, j, _ in joins
        for k, other in ((i, j), (j, i))
        if junction_of_end[k] >= 0
        and junction_of_end[other] < 0
        and len(pieces[ends[k].piece]) >= FIT_JOINTS
        and not {k, other} & given
        and moved[k] is not ends[k]
    }
