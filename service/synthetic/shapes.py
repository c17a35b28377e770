"""Designed stretches of centreline for the scene families: tight loops, hairpins, and
straight or gently curving stretches for shallow crossings and cables side by side.

A designed stretch (:class:`Insert`) is a run of pieces of constant curvature. It is set
into a cable's random curvature (:func:`designed_centreline`), whose turn it replaces
exactly: every segment's curvature is the mean of the designed profile over that
segment, so a designed stretch turns by exactly its angle and the geometry it promises
(a loop's radius, the gap between the two strands of a hairpin) holds to a fraction of
a pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from service.synthetic.curves import SAMPLE_SPACING, _smooth_random_curvature

# Random stretches bend no tighter than 4 radii (as in make_scene): tighter bends are the
# designed ones, where the family says so.
RANDOM_BEND_RADII = 4.0


@dataclass(frozen=True)
class Insert:
    """A designed stretch: pieces of constant curvature, in order along the cable.

    Attributes
    ----------
    kind : str
        ``"loop"``, ``"hairpin"``, ``"straight"``, ``"arc"`` or ``"turn"``.
    lengths, curvatures : tuple of float
        Arc length (px) and curvature (1/px, positive turns towards the left normal
        ``(-dy, dx)``) of each piece.
    values : dict
        What the stretch promises, for the ground truth (radii and angles).
    """

    kind: str
    lengths: tuple[float, ...]
    curvatures: tuple[float, ...]
    values: dict[str, float] = field(default_factory=dict)

    @property
    def length(self) -> float:
        return float(sum(self.lengths))


def loop_insert(rng, radius: float, loop_radii: tuple[float, float]) -> Insert:
    """A loop that crosses itself: straight arm, arc turning ``pi + beta``, straight arm.

    The arms are tangent to the circle and meet where they started, so the cable crosses
    itself there at ``beta`` (45-100 degrees); the circle's radius is ``loop_radii`` cable
    radii (its hole stays open: ``loop radius - cable radius`` across at the least).
    """
    loop_radius = rng.uniform(loop_radii[0] * radius, loop_radii[1] * radius)
    beta = rng.uniform(math.radians(45.0), math.radians(100.0))
    arm = loop_radius / math.tan(beta / 2.0)
    sign = rng.choice([-1.0, 1.0])
    return Insert(
        "loop",
        (arm, loop_radius * (math.pi + beta), arm),
        (0.0, sign / loop_radius, 0.0),
        {"bend_radius": loop_radius, "crossing_angle": math.degrees(beta)},
    )


def hairpin_insert(rng, radius: float, gap: float, parallel_radii=(6.0, 25.0)) -> Insert:
    """A cable doubled back on itself, its two strands ``gap`` px apart (0: touching).

    The two strands run side by side and straight for 6-25 cable radii, their centrelines
    ``2 radius + gap`` apart. At the far end the cable turns round through a bulb: an
    outward bend of radius ``rho1`` by ``psi``, then a bend of radius ``rho2`` (2-4 cable
    radii, the tightest bend) by ``pi/2 + psi`` to the axis between the strands, and the
    mirror image back; ``cos psi = (d/2 + rho1) / (rho1 + rho2)`` brings it to the axis
    square. Before and after, the strands turn away from each other by ``delta`` (20-50
    degrees), so they part cleanly.
    """
    half = radius + gap / 2.0
    rho1 = rng.uniform(3.0, 6.0) * radius
    rho2 = rng.uniform(2.0, 4.0) * radius
    psi = math.acos((half + rho1) / (rho1 + rho2))
    parallel = rng.uniform(*parallel_radii) * radius
    delta = rng.uniform(math.radians(20.0), math.radians(50.0))
    rho3 = rng.uniform(4.0, 8.0) * radius
    turn = math.pi / 2.0 + psi
    sign = rng.choice([-1.0, 1.0])
    lengths = (rho3 * delta, parallel, rho1 * psi, rho2 * turn)
    curvatures = (1.0 / rho3, 0.0, 1.0 / rho1, -1.0 / rho2)
    return Insert(
        "hairpin",
        lengths + lengths[::-1],
        tuple(sign * k for k in curvatures + curvatures[::-1]),
        {
            "bend_radius": rho2,
            "gap": gap,
            "parallel_length": parallel,
            "part_angle": math.degrees(delta),
        },
    )


def straight_insert(length: float) -> Insert:
    return Insert("straight", (length,), (0.0,))


def arc_insert(length: float, curvature: float) -> Insert:
    return Insert("arc", (length,), (curvature,))


def turn_insert(turn_radius: float, angle: float) -> Insert:
    """A bend by ``angle`` (radians, signed: positive to the left) of radius ``turn_radius``."""
    return Insert("turn", (turn_radius * abs(angle),), (math.copysign(1.0, angle) / turn_radius,))


def designed_centreline(
    rng, radius, length, diagonal, inserts, *, at_start=False, heading=None, anchor_insert=0
):
    """A random smooth centreline with designed stretches set into it.

    Parameters
    ----------
    rng : numpy.random.Generator
    radius : float
        Cable radius: random stretches bend no tighter than 4 of them.
    length : float
        Approximate total length (px).
    diagonal : float
        Image diagonal: sets the scale of the random curvature.
    inserts : sequence of Insert
        Placed in order at random positions, away from the ends; with ``at_start`` the
        first one starts at arc 0.
    heading : float, optional
        Direction (radians) at arc 0; random when None.
    anchor_insert : int
        The sample at the middle of this insert is the anchor (with no insert, a random
        sample in the middle 30 % of the length).

    Returns
    -------
    points : ndarray, shape (N, 2)
        With the anchor at the origin (``at_start``: the first sample at the origin).
    anchor_index : int
    spans : list of (float, float)
        Arc range (px from sample 0) of each insert.

    Returns None when the inserts do not fit into ``length``.
    """
    n_segments = max(2, math.ceil(length / SAMPLE_SPACING))
    total = n_segments * SAMPLE_SPACING
    max_curvature = 1.0 / (RANDOM_BEND_RADII * radius)
    curvature = _smooth_random_curvature(rng, n_segments, diagonal, max_curvature)
    designed_length = sum(insert.length for insert in inserts)
    end_margin = 0.0 if at_start else 0.15 * total
    free = total - designed_length - 2.0 * end_margin
    if free < 0:
        return None
    gaps = rng.dirichlet(np.ones(len(inserts) + 1)) * free
    if at_start:
        gaps[0] = 0.0
    starts = []
    position = end_margin
    for gap, insert in zip(gaps, inserts, strict=False):
        position += gap
        starts.append(position)
        position += insert.length

    bounds = np.arange(n_segments + 1) * SAMPLE_SPACING
    spans = []
    for start, insert in zip(starts, inserts, strict=True):
        breaks = start + np.concatenate([[0.0], np.cumsum(insert.lengths)])
        turned = np.concatenate([[0.0], np.cumsum(np.multiply(insert.lengths, insert.curvatures))])
        # Each segment takes the designed curvature averaged over the part of it the insert
        # covers, and keeps its random curvature for the rest: the turn is exact.
        clipped = np.clip(bounds, breaks[0], breaks[-1])
        covered = np.diff(clipped) / SAMPLE_SPACING
        designed = np.diff(np.interp(clipped, breaks, turned)) / SAMPLE_SPACING
        curvature = curvature * (1.0 - covered) + designed
        spans.append((float(breaks[0]), float(breaks[-1])))

    start_heading = rng.uniform(0.0, 2.0 * math.pi) if heading is None else heading
    # Each step follows the heading at its middle, which is exact for circular arcs.
    headings = start_heading + (np.cumsum(curvature) - curvature / 2.0) * SAMPLE_SPACING
    steps = SAMPLE_SPACING * np.column_stack([np.cos(headings), np.sin(headings)])
    points = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    if at_start:
        return points, 0, spans
    if spans:
        low, high = spans[anchor_insert]
        anchor_arc = (low + high) / 2.0
    else:
        anchor_arc = rng.uniform(0.35, 0.65) * total
    anchor_index = min(round(anchor_arc / SAMPLE_SPACING), n_segments)
    return points - points[anchor_index], anchor_index, spans


def bend_radii(points: np.ndarray, span: float) -> np.ndarray:
    """Radius of the circle through each sample and the samples ``span`` px either side.

    Infinite where the three are in line; NaN within ``span`` of the ends.
    """
    step = max(1, round(span / SAMPLE_SPACING))
    radii = np.full(len(points), np.nan)
    if len(points) <= 2 * step:
        return radii
    a, b, c = points[: -2 * step], points[step:-step], points[2 * step :]
    ab = np.linalg.norm(b - a, axis=1)
    bc = np.linalg.norm(c - b, axis=1)
    ca = np.linalg.norm(a - c, axis=1)
    cross = np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    with np.errstate(divide="ignore"):
        radii[step:-step] = ab * bc * ca / (2.0 * cross)
    return radii
