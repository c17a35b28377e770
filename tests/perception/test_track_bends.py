"""A cable whose both ends are out of the picture while bends travel along it.

Two frames of its shape cannot tell a bend travelling along the cable from the cable
sliding along itself, and no free end is in view to tell. Over more frames the cable's
own bends (fixed to its material) stay put while the wave moves on: its shape does not
keep, as that of a cable moved as a whole does, and the track must not slide along it.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from service.perception import Tracker, warm_up
from service.perception.track_motion import SHAPE_LAG, motion, shape_window, tangents

WIDTH, HEIGHT = 320, 240
LENGTH = 760.0  # px of cable: far longer than the picture is wide
SPACING = 1.0  # px between material samples
AMPLITUDE = 0.016  # curvature of the travelling wave (1/px)
WAVELENGTH = 160.0
SPEED = 2.5  # px of cable per frame the wave travels along it
FRAMES = 70
BENDS = 0.008  # curvature of the cable's own bends, fixed to its material (1/px)
BENDS_LENGTH = 430.0  # px of cable per period of them


@pytest.fixture(scope="module", autouse=True)
def _kernels_loaded():
    warm_up()


def centreline(frame: int) -> np.ndarray:
    """The cable's material samples at a frame: its middle fixed at the picture's centre,
    heading along x there, its own bends and a wave of curvature travelling along it (no
    material moves along the cable there; away from the middle it swings as the bends
    go by)."""
    arcs = np.arange(0.0, LENGTH + SPACING, SPACING)
    curvature = AMPLITUDE * np.sin(2.0 * np.pi * (arcs - SPEED * frame) / WAVELENGTH)
    curvature += BENDS * np.sin(2.0 * np.pi * arcs / BENDS_LENGTH + 1.0)
    headings = np.concatenate([[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1]))])
    headings -= headings[len(arcs) // 2]
    steps = SPACING * np.column_stack([np.cos(headings[:-1]), np.sin(headings[:-1])])
    points = np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])
    return points - points[len(arcs) // 2] + np.array([WIDTH / 2.0, HEIGHT / 2.0])


def draw(points: np.ndarray) -> np.ndarray:
    image = np.full((HEIGHT, WIDTH, 3), 30, np.uint8)
    cv2.polylines(image, [np.round(points).astype(np.int32)], False, (40, 170, 230), 9)
    return image


def test_travelling_bends_without_free_ends_do_not_drag_the_track_along_the_cable():
    first = centreline(0)
    assert not (0 <= first[0, 0] < WIDTH) and not (0 <= first[-1, 0] < WIDTH)
    tracker = Tracker()
    material = None  # joint number -> its material sample, from the first frame
    for frame in range(FRAMES):
        line = centreline(frame)
        tracks = tracker.update(draw(line))
        assert len(tracks.chains) == 1
        track = tracks.chains[0]
        joints = np.asarray(track.points)
        nearest = np.linalg.norm(joints[:, None] - line[None], axis=2).argmin(axis=1)
        numbers = track.first_joint + np.arange(len(joints))
        if material is None:
            material = dict(zip(numbers, nearest, strict=True))
    inside = (joints[:, 0] >= 0) & (joints[:, 0] < WIDTH)
    known = np.array([number in material for number in numbers]) & inside
    # How far along the cable (px) the joints now lie from their material points.
    slide = np.median(nearest[known] - np.array([material[n] for n in numbers[known]]))
    travelled = SPEED * (FRAMES - 1)
    # The wave travelled 172 px along the cable. A track dragged along by it goes most
    # of that way (about 150 px on a cable with no bends of its own, where nothing tells
    # the wave from a slide; 91 px on this one when every slide the shape shows is
    # believed). The cable's material in view does move along it as the wave passes
    # (0.3-0.8 px a frame, against the wave's travel), and the least motion the track
    # takes without a free end leaves that much (and grows the track at its open ends,
    # 10-11 joints either way):
    # the shape window (the shape does not keep) leaves under 70 px (57 px).
    assert abs(slide) < travelled / 2.5, f"slid {slide:.0f} px along the cable"


def test_without_a_free_end_the_measured_motion_does_not_start_a_slide_along_the_cable():
    # A wavy cable whose bends moved on along it: the shape alone is that of the cable
    # slid along itself (and turned a little), which a rigid motion fits well.
    before = centreline(0)[::10]
    after = centreline(4)[::10]
    use = np.zeros(len(before), bool)
    use[20:57] = True  # the stretch in the picture
    still = np.zeros_like(before)  # no slide before this frame
    tangent = tangents(after)
    unbounded = motion(before, after, use, tangent=tangent)
    moved = motion(before, after, use, tangent=tangent, carried=still)
    along = (moved[use] * tangent[use]).sum(axis=1).mean()
    # The wave travelled 10 px along the cable; its middle did not move at all. The
    # shape alone says it slid 4 px; the motion measured starts no slide.
    assert abs((unbounded[use] * tangent[use]).sum(axis=1).mean()) > 3.0
    assert abs(along) < 0.5
    # The motion stays rigid (one shift and one small turn), as the stretch out of view
    # needs: a displacement field t + w * (-y, x).
    outside = ~use
    rigid = motion(before, after, use, tangent=tangent, rigid_only=outside, carried=still)
    design = np.zeros((2 * outside.sum(), 3))
    design[0::2, 0] = design[1::2, 1] = 1.0
    design[0::2, 2] = -before[outside, 1]
    design[1::2, 2] = before[outside, 0]
    field = rigid[outside].ravel()
    fitted = np.linalg.lstsq(design, field, rcond=None)[0]
    np.testing.assert_allclose(design @ fitted, field, atol=1e-6)


def test_a_slide_a_free_end_measured_goes_on_while_the_shape_shows_it():
    # A bent cable moving (rigidly) mostly along itself, 12 px a frame: its free end was
    # seen doing so, and is lost this frame (under a crossing, say). Its shape still
    # shows the motion.
    before = centreline(0)[::10]
    shift = np.array([12.0, 2.0])
    after = before + shift
    use = np.zeros(len(before), bool)
    use[20:57] = True
    tangent = tangents(after)
    carried = np.tile(shift, (len(before), 1))  # the motion the free end measured
    shown = (carried[use] * tangent[use]).sum(axis=1).mean()
    moved = motion(before, after, use, tangent=tangent, carried=carried)
    along = (moved[use] * tangent[use]).sum(axis=1).mean()
    # Kept up, a share of it (one no free end measures again dies away frame by frame).
    assert 0.75 * shown <= along <= shown + 0.5
    # Never measured by a free end, the same motion is not taken for a slide: the bends
    # travelling along a cable show the same.
    moved = motion(before, after, use, tangent=tangent, carried=np.zeros_like(before))
    assert abs((moved[use] * tangent[use]).sum(axis=1).mean()) < 0.5
    # With a free end seen again, its measure is the motion along the cable.
    pinned = [(56, shift)]
    moved = motion(before, after, use, pinned, tangent, carried=np.zeros_like(before))
    np.testing.assert_allclose(moved[use], carried[use], atol=0.5)


def test_the_shape_window_tells_travelling_bends_from_a_cable_moved_whole():
    # Joints 10 px apart along the stretch in view; after SHAPE_LAG frames the wave
    # has travelled on (the material and its own bends still), or the cable has moved
    # as a whole: slid 13 px along itself (the track lagging 1.3 joints behind), turned
    # and shifted. (A wave alone, on a cable with no bends of its own, is the cable slid
    # along itself: nothing tells them apart.)
    step = 10.0
    seen = np.zeros(75, bool)
    seen[20:57] = True
    then = centreline(0)[::10][:75]
    window = shape_window(None, 0, then, seen, step, frame=0)
    assert window.travelling is False
    travelled = centreline(SHAPE_LAG)[::10][:75]
    assert shape_window(window, 0, travelled, seen, step, SHAPE_LAG).travelling is True
    angle = 0.05
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    moved = centreline(0)[13::10][:75] @ turn.T + np.array([4.0, -3.0])
    assert shape_window(window, 0, moved, seen, step, SHAPE_LAG).travelling is False
    # Between looks the window is carried on unchanged.
    assert shape_window(window, 0, travelled, seen, step, SHAPE_LAG - 1) is window
