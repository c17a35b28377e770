"""Tracking: how a track's joints moved between two frames (its velocity's measure).

Across a cable a joint's displacement is seen; along it, hardly (a stretch of cable slid
along itself looks the same). :func:`motion` gives each joint's displacement from a rigid
motion fitted to the cross-cable parts (and to free ends found again), with the
cross-cable remainder smoothed along the cable.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from service.perception import _tracking_kernels

VELOCITY_KERNEL = np.array([1.0, 2.0, 3.0, 2.0, 1.0]) / 9.0
"""Weights of a joint's velocity and its neighbours' (two each side)."""
SLIDE_KEPT = 0.9
"""Share of the slide along the cable carried in from the last frame that, with no free
end in view, the shape may keep up (frame after frame, so a slide no free end measures
dies away unless the shape keeps showing it)."""
SHAPE_LAG = 15
"""Frames between the looks at whether a cable's shape in view keeps (see
:func:`shape_window`)."""
CONGRUENT_RMS = 0.125
"""Root-mean-square misfit (in segment lengths) within which the shape in view is the
shape :data:`SHAPE_LAG` frames before, moved as a whole (detection noise is a few
hundredths of a segment; a travelling bend changes the shape by several tenths)."""
RIDGE = 0.02
"""How strongly the rigid motion fitted to a cable's cross-cable displacements is kept
small (relative to the data): enough to leave a straight cable's slide at zero."""


def tangents(joints: np.ndarray) -> np.ndarray:
    """Unit tangents at the joints (central differences, one-sided at the ends)."""
    if len(joints) < 2:
        return np.zeros_like(joints)
    return _tracking_kernels.unit_tangents(_contiguous(joints))


def motion(
    previous: np.ndarray,
    current: np.ndarray,
    use: np.ndarray,
    pinned: list[tuple[int, np.ndarray]] = (),
    tangent: np.ndarray | None = None,
    rigid_only: np.ndarray | None = None,
    carried: np.ndarray | None = None,
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
    its ends is seen. Without one, the rigid motion's slide along the cable (its mean
    motion along the seen joints) is kept between nil and the slide ``carried`` (the
    joints' displacement the velocity predicted, when given) gives: see
    :func:`_slide_bounded`. ``tangent``: :func:`tangents` of ``current``, when known.
    ``rigid_only``: joints whose displacement was not measured (beyond the seen ones,
    outside the picture): they get the rigid motion alone, so that a stretch out of view
    moves with the cable as a whole and keeps its shape.
    """
    tangent = tangents(current) if tangent is None else tangent
    # The elementwise work and the sums in one compiled loop each side of the solve
    # (the same bits as NumPy's), the products of matrices in NumPy (its BLAS).
    normal, across, turned, rows, values, scale = _tracking_kernels.motion_design(
        _contiguous(previous), _contiguous(current), _flags(use), _contiguous(tangent)
    )
    count = len(values)
    ridge = np.zeros((3, 3))
    ridge[0, 0] = ridge[1, 1] = RIDGE * count * 1.0
    ridge[2, 2] = RIDGE * count * (scale * scale)
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
    normal_matrix = rows.T @ rows + ridge
    fitted = np.linalg.solve(normal_matrix, rows.T @ values)
    if not len(pinned) and carried is not None:
        fitted = _slide_bounded(
            fitted, normal_matrix, tangent, turned, use, carried, tangents(previous)
        )
    only = np.zeros(len(turned), bool) if rigid_only is None else _flags(rigid_only)
    return _tracking_kernels.motion_result(
        _contiguous(fitted), turned, across, normal, only, VELOCITY_KERNEL
    )


def _contiguous(values: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float64)


def _flags(values: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=bool)


def _slide_bounded(fitted, normal_matrix, tangent, turned, use, carried, carried_tangent):
    """The rigid motion ``fitted`` (``tx, ty, rotation``), its slide along the cable kept
    between nil and :data:`SLIDE_KEPT` of the slide ``carried`` in from the last frames.

    No free end in view measures the motion along the cable, and the shape cannot tell
    it from a bend travelling along the cable: that looks the same as the cable sliding
    along itself (and turning), which a rigid motion fits well. A velocity carrying such
    a slide on slides the track, the next frame finds the bends moved on again, and the
    track is dragged along by them, faster and faster. So the shape may keep up or slow
    down a slide that was measured (a free end seen moving along the cable, then lost
    under a crossing, say, while the cable goes on), but it does not start one, nor
    speed one up. The slide carried in is measured along the cable as it lay when that
    motion was measured (``carried_tangent``: the cross-cable part of a bending cable's
    motion then would show along it now, and ratchet a slide up frame by frame). The
    bound is a constraint on the least-squares fit (``normal_matrix``: its normal
    equations), so the motion stays rigid.
    """
    slide_row = np.column_stack([tangent, (turned * tangent).sum(axis=1)])[use].mean(axis=0)
    slide = float(slide_row @ fitted)
    before = SLIDE_KEPT * float((carried[use] * carried_tangent[use]).sum(axis=1).mean())
    target = min(max(slide, min(0.0, before)), max(0.0, before))
    if target == slide:
        return fitted
    # The least-squares fit with its slide fixed (Lagrange): move along the direction
    # that changes the slide at least cost.
    direction = np.linalg.solve(normal_matrix, slide_row)
    return fitted + direction * ((target - slide) / max(float(slide_row @ direction), 1e-12))


class ShapeWindow(NamedTuple):
    """A track's shape as last looked at (:func:`shape_window`)."""

    frame: int
    first_joint: int  # the track's joint number of ``joints[0]`` then
    joints: np.ndarray
    travelling: bool  # the shape did not keep at the last look: bends travel along it


def shape_window(window, first_joint, joints, seen, step, frame) -> ShapeWindow:
    """The track's :class:`ShapeWindow` carried on to this frame (``window`` None: the
    first).

    Every :data:`SHAPE_LAG` frames the seen joints are laid on the joints of the window
    (by joint number, shifted along the track by up to 4 segments) by the best rigid
    motion: a cable that moved as a whole (drifting along itself, say) keeps its shape,
    and so its material-fixed bends, while bends travelling along it change the shape.
    ``travelling`` says the shape did not keep, so that a slide along the cable the
    two-frame rigid fit finds is not believed (see :func:`motion`'s ``carried``).
    """
    if window is not None and frame - window.frame < SHAPE_LAG:
        return window
    travelling = False if window is None else window.travelling
    if window is not None:
        misfit = _shape_misfit(window.first_joint, window.joints, first_joint, joints, seen)
        travelling = travelling if misfit is None else misfit > CONGRUENT_RMS * step
    return ShapeWindow(frame, first_joint, joints, travelling)


def _shape_misfit(then_first, then_joints, first_joint, joints, seen):
    """Least RMS misfit (px) of the seen joints to the joints then, over shifts along
    the track, after the best rigid motion (None: too few joints in common). All the
    shifts at once: the joints kept at a shift weigh, the rest are nil."""
    if len(then_joints) < 2:
        return None
    shifts = np.arange(-4.0, 4.001, 0.1)[:, None]
    at = (first_joint + np.flatnonzero(seen) - then_first)[None, :] + shifts
    keep = (at >= 0) & (at <= len(then_joints) - 1)
    counts = np.count_nonzero(keep, axis=1)
    if counts.max() < 8:
        return None
    below = np.clip(np.floor(at).astype(int), 0, len(then_joints) - 2)
    share = np.clip(at - below, 0.0, 1.0)[..., None]
    then = (1.0 - share) * then_joints[below] + share * then_joints[below + 1]
    now = np.broadcast_to(joints[seen], then.shape)
    weight = keep[..., None] / np.maximum(counts, 1)[:, None, None]
    then = (then - (then * weight).sum(axis=1, keepdims=True)) * keep[..., None]
    now = (now - (now * weight).sum(axis=1, keepdims=True)) * keep[..., None]
    u, _, vt = np.linalg.svd(then.transpose(0, 2, 1) @ now)
    flip = np.ones((len(u), 2))
    flip[:, 1] = np.sign(np.linalg.det(u @ vt))
    rotation = (u * flip[:, None, :]) @ vt
    misfit = np.sqrt((((then @ rotation - now) ** 2).sum(axis=(1, 2))) / np.maximum(counts, 1))
    return float(misfit[counts >= 8].min())


def smooth_along(values: np.ndarray) -> np.ndarray:
    """Per-joint values averaged with their neighbours' (two each side)."""
    if len(values) < 3:
        return values
    padded = np.concatenate([values[:1], values[:1], values, values[-1:], values[-1:]])
    return sum(VELOCITY_KERNEL[i] * padded[i : i + len(values)] for i in range(5))
