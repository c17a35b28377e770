"""Tracking: how a track's joints moved between two frames (its velocity's measure).

Across a cable a joint's displacement is seen; along it, hardly (a stretch of cable slid
along itself looks the same). :func:`motion` gives each joint's displacement from a rigid
motion fitted to the cross-cable parts (and to free ends found again), with the
cross-cable remainder smoothed along the cable.
"""

from __future__ import annotations

import math

import numpy as np

VELOCITY_KERNEL = np.array([1.0, 2.0, 3.0, 2.0, 1.0]) / 9.0
"""Weights of a joint's velocity and its neighbours' (two each side)."""
NO_SLIDE_WEIGHT = 10.0
"""How strongly, without a free end seen, the rigid motion is kept from sliding the cable
along itself: its mean motion along the seen joints weighs this much squared (100) times
all their cross-cable displacements together (a constraint, in effect)."""
RIDGE = 0.02
"""How strongly the rigid motion fitted to a cable's cross-cable displacements is kept
small (relative to the data): enough to leave a straight cable's slide at zero."""


def tangents(joints: np.ndarray) -> np.ndarray:
    """Unit tangents at the joints (central differences, one-sided at the ends)."""
    tangent = np.empty_like(joints)
    if len(joints) < 2:
        return np.zeros_like(joints)
    tangent[0] = joints[1] - joints[0]
    tangent[-1] = joints[-1] - joints[-2]
    tangent[1:-1] = (joints[2:] - joints[:-2]) / 2.0
    length = np.sqrt(tangent[:, 0] ** 2 + tangent[:, 1] ** 2)
    return tangent / np.maximum(length, 1e-12)[:, None]


def motion(
    previous: np.ndarray,
    current: np.ndarray,
    use: np.ndarray,
    pinned: list[tuple[int, np.ndarray]] = (),
    tangent: np.ndarray | None = None,
    rigid_only: np.ndarray | None = None,
) -> np.ndarray:
    """Each joint's displacement, with its part along the cable from the whole cable.

    Across the cable a joint's displacement is measured; along it, hardly (a stretch of
    cable slid along itself looks the same). A rigid motion (translation and rotation)
    fitted to the measured cross-cable displacements of the joints in ``use`` gives the
    along-cable part wherever the cable bends enough to tell (a ridge keeps a straight
    cable's slide at zero); the cross-cable remainder of each joint, smoothed along the
    cable, is added back. The motion coherence of CPD-style trackers, along the cable.
    ``pinned`` are ``(joint, displacement)``: a free end seen in both frames, a material
    point found again, whose whole displacement (along the cable too) is measured; it
    weighs in the fit as much as the cross-cable displacements of all the joints in
    ``use`` together, so that a cable moving along itself is followed wherever one of
    its ends is seen. Without one, the rigid motion is fitted with no mean motion along
    the seen joints (a travelling bend would otherwise pass for a slide along the
    cable). ``tangent``: :func:`tangents` of ``current``, when known.
    ``rigid_only``: joints whose displacement was not measured (beyond the seen ones,
    outside the picture): they get the rigid motion alone, so that a stretch out of view
    moves with the cable as a whole and keeps its shape.
    """
    tangent = tangents(current) if tangent is None else tangent
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    across = ((current - previous) * normal).sum(axis=1)
    centre = previous[use].mean(axis=0)
    arm = previous - centre
    turned = np.column_stack([-arm[:, 1], arm[:, 0]])
    design = np.column_stack([normal, (turned * normal).sum(axis=1)])
    count = np.count_nonzero(use)
    scale = max(float(np.sqrt((arm[use] ** 2).sum(axis=1).mean())), 1.0)
    ridge = RIDGE * count * np.diag([1.0, 1.0, scale * scale])
    rows = design[use]
    values = across[use]
    if len(pinned):
        weight = math.sqrt(count / (2.0 * len(pinned)))
        ends = np.array([joint for joint, _ in pinned])
        moved = np.concatenate([displacement for _, displacement in pinned])
        end_rows = np.zeros((2 * len(ends), 3))
        end_rows[0::2, 0] = 1.0
        end_rows[1::2, 1] = 1.0
        end_rows[0::2, 2] = turned[ends, 0]
        end_rows[1::2, 2] = turned[ends, 1]
        rows = np.vstack([rows, weight * end_rows])
        values = np.concatenate([values, weight * moved])
    else:
        # No free end measures the motion along the cable, and the shape cannot: a bend
        # travelling along it looks the same as the cable sliding along itself (and
        # turning), which a rigid motion fits well. The slide is taken as nil (the least
        # motion): a velocity carrying one on slides the track, the next frame finds the
        # bends moved on again, and the track is dragged along by them.
        weight = math.sqrt(count) * NO_SLIDE_WEIGHT
        slide_row = np.column_stack([tangent, (turned * tangent).sum(axis=1)])[use].mean(axis=0)
        rows = np.vstack([rows, weight * slide_row])
        values = np.concatenate([values, [0.0]])
    translation_x, translation_y, rotation = np.linalg.solve(rows.T @ rows + ridge, rows.T @ values)
    rigid = np.array([translation_x, translation_y]) + rotation * turned
    remainder = across - (rigid * normal).sum(axis=1)
    result = rigid + smooth_along(remainder)[:, None] * normal
    if rigid_only is not None:
        result[rigid_only] = rigid[rigid_only]
    return result


def smooth_along(values: np.ndarray) -> np.ndarray:
    """Per-joint values averaged with their neighbours' (two each side)."""
    if len(values) < 3:
        return values
    padded = np.concatenate([values[:1], values[:1], values, values[-1:], values[-1:]])
    return sum(VELOCITY_KERNEL[i] * padded[i : i + len(values)] for i in range(5))
