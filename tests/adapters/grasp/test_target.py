"""Grasp planning: pixel to table point in closed form, point selection, refusals."""

from __future__ import annotations

import json
import math
import sys

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from adapters.grasp.errors import DepthImageError, GraspPlanningError, InferredSegmentError
from adapters.grasp.target import closing_yaw, normalize_half_turn, plan_grasp
from schemas import (
    CameraModel,
    Chain,
    DepthSurface,
    Detection,
    EndPoint,
    FractionPoint,
    GraspSelector,
    PixelPoint,
    PlaneSurface,
    SegmentPoint,
)
from service.geometry3d.camera import pixel_to_plane
from service.geometry3d.depth import decode_depth_image
from service.geometry3d.errors import LiftError
from tests.adapters.builders import DOWN, looking_down

FX, FY, CX, CY, W, H = 800.0, 820.0, 320.0, 240.0, 640, 480
TOL = 1e-4  # 0.1 mm


def rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def camera(rotation=DOWN, origin=(0.4, 0.05, 0.6), plane_z=0.02, dist=(0, 0, 0, 0, 0)):
    """The default 640 x 480 camera (principal point CX, CY) with focal lengths FX, FY."""
    return looking_down(origin, rotation=rotation, fx=FX, fy=FY, plane_z=plane_z, dist=dist)


def detection(*chains: Chain) -> Detection:
    return Detection(width=W, height=H, segment_length=10.0, chains=list(chains))


def chain(points, chain_id=0, inferred=None) -> Chain:
    inferred = inferred if inferred is not None else [False] * (len(points) - 1)
    return Chain(id=chain_id, points=points, radius=3.0, inferred=inferred)


# --- pixel to plane, closed form -------------------------------------------------------


@pytest.mark.parametrize("pixel", [(CX, CY), (500.0, 100.0), (12.5, 470.0)])
def test_straight_down_camera_offsets_by_pixel_over_focal_times_height(pixel):
    cam = camera()
    height = 0.6 - 0.02
    point = pixel_to_plane(cam, pixel)
    expected = (
        0.4 + (pixel[0] - CX) / FX * height,
        0.05 - (pixel[1] - CY) / FY * height,
        0.02,
    )
    np.testing.assert_allclose(point, expected, atol=TOL)


@pytest.mark.parametrize("pixel", [(CX, CY), (600.0, 30.0), (40.0, 400.0)])
def test_tilted_camera_matches_hand_derivation(pixel):
    tilt = math.radians(30)
    origin = (0.35, -0.1, 0.5)
    cam = camera(rotation=rot_x(tilt) @ DOWN, origin=origin, plane_z=0.0)
    # Ray in the camera (a, b, 1); in base Rx(t) @ (a, -b, -1)
    # = (a, s - b c, -(b s + c)); it drops h = 0.5 over a length factor h / (b s + c).
    a, b = (pixel[0] - CX) / FX, (pixel[1] - CY) / FY
    s, c = math.sin(tilt), math.cos(tilt)
    scale = 0.5 / (b * s + c)
    expected = (origin[0] + a * scale, origin[1] + (s - b * c) * scale, 0.0)
    np.testing.assert_allclose(pixel_to_plane(cam, pixel), expected, atol=TOL)
    if pixel == (CX, CY):
        np.testing.assert_allclose(expected[1], origin[1] + 0.5 * math.tan(tilt), atol=1e-12)


@pytest.mark.parametrize("base_point", [(0.42, 0.13, 0.01), (0.2, 0.02, 0.01), (0.33, -0.05, 0.01)])
def test_distorted_pixel_is_undistorted_back_to_the_known_point(base_point):
    dist = (-0.28, 0.09, 0.0012, -0.0009, -0.012)
    rotation = rot_x(math.radians(20)) @ DOWN
    origin = np.array([0.3, -0.15, 0.55])
    cam = camera(rotation=rotation, origin=origin, plane_z=0.01, dist=dist)
    # Project the base point with the camera's extrinsics (base to camera) and distortion.
    rvec, _ = cv2.Rodrigues(rotation.T)
    tvec = -rotation.T @ origin
    K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    projected, _ = cv2.projectPoints(
        np.array([base_point], dtype=float), rvec, tvec, K, np.array(dist)
    )
    pixel = tuple(float(v) for v in projected.reshape(2))
    assert 0 <= pixel[0] < W and 0 <= pixel[1] < H
    # Without distortion the same pixel lands elsewhere: the test has teeth.
    plain = pixel_to_plane(camera(rotation=rotation, origin=origin, plane_z=0.01), pixel)
    assert np.linalg.norm(plain - base_point) > 5 * TOL
    target = plan_grasp(
        detection(chain([pixel, (pixel[0] + 10.0, pixel[1])])),
        cam,
        GraspSelector(chain=0, point=EndPoint(end="start")),
    )
    np.testing.assert_allclose(target.position_m, base_point, atol=TOL)


def test_ray_meeting_the_plane_behind_the_camera_is_refused():
    up = rot_x(math.pi) @ DOWN  # looking straight up
    with pytest.raises(LiftError, match="behind the camera"):
        pixel_to_plane(camera(rotation=up), (CX, CY))
    # The grasp planning refuses it as a grasp that cannot be planned.
    line = detection(chain([(CX - 10.0, CY), (CX + 10.0, CY)]))
    with pytest.raises(GraspPlanningError, match="behind the camera"):
        plan_grasp(line, camera(rotation=up), GraspSelector())


def test_ray_parallel_to_the_plane_is_refused():
    horizontal = rot_x(-math.pi / 2) @ DOWN  # optical axis along base -y
    np.testing.assert_allclose(horizontal[:, 2], [0, -1, 0], atol=1e-12)
    with pytest.raises(LiftError, match="parallel"):
        pixel_to_plane(camera(rotation=horizontal), (CX, CY))


# --- point selection, yaw, refusals ------------------------------------------------------


def test_fraction_is_along_the_arc_length():
    # An L: 100 px right then 300 px down; 0.5 of 400 px is 100 px down the second leg.
    c = chain([(100.0, 100.0), (200.0, 100.0), (200.0, 400.0)])
    cam = camera()
    target = plan_grasp(detection(c), cam, GraspSelector(point=FractionPoint(value=0.5)))
    assert target.pixel == pytest.approx((200.0, 200.0))
    assert target.segment_index == 1
    np.testing.assert_allclose(target.position_m, pixel_to_plane(cam, (200.0, 200.0)), atol=1e-12)
    end = plan_grasp(detection(c), cam, GraspSelector(point=FractionPoint(value=1.0)))
    assert (end.pixel, end.segment_index) == ((200.0, 400.0), 1)
    start = plan_grasp(detection(c), cam, GraspSelector(point=FractionPoint(value=0.0)))
    assert (start.pixel, start.segment_index) == ((100.0, 100.0), 0)


def test_segment_index_gives_its_midpoint_and_ends_give_the_ends():
    c = chain([(100.0, 100.0), (110.0, 100.0), (120.0, 110.0), (130.0, 110.0)])
    cam = camera()
    mid = plan_grasp(detection(c), cam, GraspSelector(point=SegmentPoint(index=1)))
    assert (mid.pixel, mid.segment_index) == ((115.0, 105.0), 1)
    first = plan_grasp(detection(c), cam, GraspSelector(point=EndPoint(end="start")))
    last = plan_grasp(detection(c), cam, GraspSelector(point=EndPoint(end="end")))
    assert (first.pixel, first.segment_index) == ((100.0, 100.0), 0)
    assert (last.pixel, last.segment_index) == ((130.0, 110.0), 2)
    with pytest.raises(GraspPlanningError, match="no segment 3"):
        plan_grasp(detection(c), cam, GraspSelector(point=SegmentPoint(index=3)))


def test_pixel_picks_the_nearest_point_on_the_polyline():
    c = chain([(100.0, 100.0), (200.0, 100.0), (200.0, 300.0)])
    target = plan_grasp(detection(c), camera(), GraspSelector(point=PixelPoint(x=150, y=90)))
    assert (target.pixel, target.segment_index) == ((150.0, 100.0), 0)
    target = plan_grasp(detection(c), camera(), GraspSelector(point=PixelPoint(x=260, y=250)))
    assert (target.pixel, target.segment_index) == ((200.0, 250.0), 1)


def test_longest_and_by_id_chain_choice():
    short = chain([(10.0, 10.0), (40.0, 10.0)], chain_id=4)
    long = chain([(10.0, 50.0), (90.0, 50.0)], chain_id=7)
    det = detection(short, long)
    assert plan_grasp(det, camera(), GraspSelector()).chain_id == 7
    assert plan_grasp(det, camera(), GraspSelector(chain=4)).chain_id == 4
    with pytest.raises(GraspPlanningError, match=r"no chain with id 5; the ids are \[4, 7\]"):
        plan_grasp(det, camera(), GraspSelector(chain=5))
    with pytest.raises(GraspPlanningError, match="no chains"):
        plan_grasp(detection(), camera(), GraspSelector())


def test_inferred_segment_is_refused_unless_allowed():
    c = chain([(100.0, 100.0), (200.0, 100.0), (300.0, 100.0)], inferred=[False, True])
    selector = GraspSelector(point=FractionPoint(value=0.75))
    with pytest.raises(InferredSegmentError, match="chain 0 segment 1 was inferred"):
        plan_grasp(detection(c), camera(), selector)
    allowed = selector.model_copy(update={"allow_inferred": True})
    target = plan_grasp(detection(c), camera(), allowed)
    assert target.inferred and target.segment_index == 1
    seen = plan_grasp(detection(c), camera(), GraspSelector(point=FractionPoint(value=0.25)))
    assert not seen.inferred


def test_yaw_closes_across_the_cable_on_the_table():
    cam = camera()  # image +x is base +x, image +y is base -y
    along_u = chain([(100.0, 200.0), (300.0, 200.0)])  # cable along base x
    along_v = chain([(200.0, 100.0), (200.0, 300.0)])  # cable along base -y
    diagonal = chain([(100.0, 300.0), (300.0, 100.0)])  # base (+x, +y) with fx != fy
    assert plan_grasp(detection(along_u), cam, GraspSelector()).yaw_rad == pytest.approx(
        math.pi / 2
    )
    assert plan_grasp(detection(along_v), cam, GraspSelector()).yaw_rad == pytest.approx(0.0)
    expected = normalize_half_turn(math.atan2(200 / FY, 200 / FX) + math.pi / 2)
    assert plan_grasp(detection(diagonal), cam, GraspSelector()).yaw_rad == pytest.approx(
        expected, abs=1e-9
    )
    # Reversing the chain direction gives the same grasp.
    reversed_diagonal = chain(list(reversed(diagonal.points)))
    assert plan_grasp(detection(reversed_diagonal), cam, GraspSelector()).yaw_rad == (
        pytest.approx(expected, abs=1e-9)
    )


@pytest.mark.parametrize(
    ("angle", "expected"),
    [
        (0.0, 0.0),
        (math.pi / 2, math.pi / 2),
        (-math.pi / 2, math.pi / 2),
        (math.pi, 0.0),
        (3 * math.pi / 4, -math.pi / 4),
        (-3 * math.pi / 4, math.pi / 4),
        (7.0, 7.0 - 2 * math.pi),
    ],
)
def test_half_turn_normalisation(angle, expected):
    folded = normalize_half_turn(angle)
    assert -math.pi / 2 < folded <= math.pi / 2
    assert folded == pytest.approx(expected, abs=1e-12)


def test_closing_yaw_is_tangent_plus_quarter_turn():
    assert closing_yaw(1.0, 0.0) == pytest.approx(math.pi / 2)
    assert closing_yaw(0.0, 1.0) == pytest.approx(0.0)
    assert closing_yaw(1.0, 1.0) == pytest.approx(-math.pi / 4)


def test_image_size_mismatch_is_refused():
    det = Detection(width=1280, height=720, segment_length=10, chains=[chain([(1, 1), (9, 9)])])
    with pytest.raises(GraspPlanningError, match="1280x720 px but the camera model is 640x480"):
        plan_grasp(det, camera(), GraspSelector())


# --- camera model -----------------------------------------------------------------------


def test_camera_model_rejects_a_non_rigid_transform():
    scaled = DOWN * 1.01
    with pytest.raises(ValidationError, match="not orthonormal"):
        camera(rotation=scaled)
    mirrored = np.diag([1.0, 1.0, -1.0])
    with pytest.raises(ValidationError, match="determinant"):
        camera(rotation=mirrored)
    transform = np.eye(4)
    transform[3] = [0, 0, 1, 1]
    with pytest.raises(ValidationError, match="last row"):
        CameraModel(
            fx=1,
            fy=1,
            cx=0,
            cy=0,
            width=2,
            height=2,
            T_base_camera=transform.tolist(),
            surface={"plane_z": 0},
        )


def test_camera_model_round_trips_through_json(tmp_path):
    cam = camera(dist=(-0.1, 0.01, 0.0, 0.0, 0.0))
    path = tmp_path / "camera.json"
    cam.to_json_file(path)
    assert CameraModel.from_file(path) == cam
    with pytest.raises(ValueError, match=r"must be \.json, \.yaml or \.yml"):
        (tmp_path / "camera.txt").write_text("{}")
        CameraModel.from_file(tmp_path / "camera.txt")


def test_camera_model_yaml_needs_pyyaml(tmp_path, monkeypatch):
    path = tmp_path / "camera.yaml"
    path.write_text("fx: 1\n")
    monkeypatch.setitem(sys.modules, "yaml", None)
    with pytest.raises(ValueError, match="needs PyYAML"):
        CameraModel.from_file(path)


def test_camera_model_from_yaml_when_pyyaml_is_installed(tmp_path):
    yaml = pytest.importorskip("yaml")
    cam = camera()
    path = tmp_path / "camera.yml"
    path.write_text(yaml.safe_dump(cam.model_dump(mode="json")))
    assert CameraModel.from_file(path) == cam


# --- depth surface ------------------------------------------------------------------------


def depth_camera(rotation=DOWN, origin=(0.4, 0.05, 0.6), depth_scale=1.0, **surface):
    """As :func:`camera`, with a depth-image surface instead of the table plane."""
    plane = camera(rotation=rotation, origin=origin)
    return plane.model_copy(
        update={"surface": DepthSurface(kind="depth", depth_scale=depth_scale, **surface)}
    )


def plane_depth(rotation, origin, plane_z, dtype=np.float32) -> np.ndarray:
    """The depth image (metres along the optical axis) of the plane ``z = plane_z``.

    The ray of pixel (u, v) is ``(a, b, 1)`` in the camera; in the base frame it rises
    ``R[2] . (a, b, 1)`` per unit of depth, so it meets the plane at that depth.
    """
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    a, b = (u - CX) / FX, (v - CY) / FY
    rotation = np.asarray(rotation)
    rise = rotation[2, 0] * a + rotation[2, 1] * b + rotation[2, 2]
    return ((plane_z - origin[2]) / rise).astype(dtype)


CABLE = chain([(200.0, 150.0), (260.0, 190.0), (330.0, 230.0), (400.0, 300.0)])
"""Joints on whole pixels, so the nearest depth sample is the joint's own."""
SELECTORS = [
    GraspSelector(point=SegmentPoint(index=1)),  # (295, 210): a whole pixel too
    GraspSelector(point=EndPoint(end="start")),
    GraspSelector(point=PixelPoint(x=330, y=230)),
]


@pytest.mark.parametrize("selector", SELECTORS)
def test_depth_of_a_flat_table_seen_straight_down_equals_the_plane(selector):
    origin, table = (0.4, 0.05, 0.6), 0.02
    depth = np.full((H, W), origin[2] - table, np.float32)
    from_depth = plan_grasp(detection(CABLE), depth_camera(origin=origin), selector, depth)
    from_plane = plan_grasp(detection(CABLE), camera(origin=origin, plane_z=table), selector)
    np.testing.assert_allclose(from_depth.position_m, from_plane.position_m, atol=TOL)
    assert from_depth.yaw_rad == pytest.approx(from_plane.yaw_rad, abs=1e-6)
    assert from_depth.model_dump(exclude={"position_m", "yaw_rad"}) == from_plane.model_dump(
        exclude={"position_m", "yaw_rad"}
    )


@pytest.mark.parametrize("selector", SELECTORS)
def test_depth_of_a_plane_seen_by_a_tilted_camera_equals_the_plane(selector):
    rotation = rot_x(math.radians(30)) @ DOWN
    origin, table = (0.35, -0.1, 0.5), 0.01
    depth = plane_depth(rotation, origin, table)
    cam = depth_camera(rotation=rotation, origin=origin)
    from_depth = plan_grasp(detection(CABLE), cam, selector, depth)
    plane = camera(rotation=rotation, origin=origin, plane_z=table)
    from_plane = plan_grasp(detection(CABLE), plane, selector)
    np.testing.assert_allclose(from_depth.position_m, from_plane.position_m, atol=TOL)
    assert from_depth.position_m[2] == pytest.approx(table, abs=TOL)
    assert from_depth.yaw_rad == pytest.approx(from_plane.yaw_rad, abs=1e-6)


def test_the_grasp_lands_on_top_of_a_box():
    origin, table, box_top = (0.4, 0.05, 0.6), 0.0, 0.05
    depth = np.full((H, W), origin[2] - table, np.float32)
    depth[180:280, 240:360] = origin[2] - box_top  # a box under the middle of the image
    on_box = chain([(250.0, 230.0), (350.0, 230.0)])  # along image x, on the box
    target = plan_grasp(detection(on_box), depth_camera(origin=origin), GraspSelector(), depth)
    height = origin[2] - box_top
    expected = (origin[0] + (300 - CX) / FX * height, origin[1] - (230 - CY) / FY * height, box_top)
    np.testing.assert_allclose(target.position_m, expected, atol=TOL)
    assert target.yaw_rad == pytest.approx(math.pi / 2)  # across a cable along base x
    # The same chain beside the box lies on the table.
    beside = chain([(450.0, 400.0), (550.0, 400.0)])
    target = plan_grasp(detection(beside), depth_camera(origin=origin), GraspSelector(), depth)
    assert target.position_m[2] == pytest.approx(table, abs=TOL)


def test_a_cable_off_the_box_edge_takes_its_joints_from_their_own_depths():
    # A straight-down camera: the yaw only depends on the joints' x-y, which each depth
    # scales about the optical axis; joints at different depths tilt the tangent.
    origin = (0.4, 0.05, 0.6)
    depth = np.full((H, W), 0.6, np.float32)
    depth[:, 320:] = 0.5  # the right half is a 10 cm step up
    c = chain([(220.0, 140.0), (420.0, 340.0)])  # starts on the floor, ends on the step
    target = plan_grasp(detection(c), depth_camera(origin=origin), GraspSelector(), depth)
    start = (origin[0] + (220 - CX) / FX * 0.6, origin[1] - (140 - CY) / FY * 0.6)
    end = (origin[0] + (420 - CX) / FX * 0.5, origin[1] - (340 - CY) / FY * 0.5)
    expected = closing_yaw(end[0] - start[0], end[1] - start[1])
    assert target.yaw_rad == pytest.approx(expected, abs=1e-6)
    # The grasp pixel (320, 240) falls on the step: nearest sample, no blend across the edge.
    assert target.position_m[2] == pytest.approx(0.1, abs=TOL)


def test_missing_depth_is_filled_with_the_median_of_the_window():
    origin = (0.4, 0.05, 0.6)
    depth = np.full((H, W), 0.58, np.float32)
    c = chain([(300.0, 240.0), (340.0, 240.0)])  # grasp pixel (320, 240)
    depth[237:244, 317:324] = np.nan  # a 7x7 hole around it
    cam = depth_camera(origin=origin, window=9)
    target = plan_grasp(detection(c), cam, GraspSelector(), depth)
    assert target.position_m == pytest.approx((0.4, 0.05, 0.02), abs=TOL)
    # The median, not the mean: within a 3x3 window, 5 valid samples 0.50 0.50 0.55 0.70 0.70.
    depth = np.zeros((H, W), np.uint16)  # 0 = no measurement, as depth cameras write
    ring = {(239, 319): 500, (239, 320): 500, (239, 321): 550, (241, 319): 700, (241, 321): 700}
    for (row, column), millimetres in ring.items():
        depth[row, column] = millimetres
    depth[230:250, 310:319] = 580  # outside the 3x3 window: ignored
    cam = depth_camera(origin=origin, depth_scale=0.001, window=3)
    target = plan_grasp(detection(c), cam, GraspSelector(), depth)
    assert target.position_m == pytest.approx((0.4, 0.05, 0.6 - 0.55), abs=TOL)


def test_a_window_without_any_valid_depth_refuses_the_grasp():
    depth = np.full((H, W), 0.58, np.float32)
    depth[235:246, 315:326] = np.nan  # 11x11 hole: wider than the 5 px window
    c = chain([(300.0, 240.0), (340.0, 240.0)])
    with pytest.raises(GraspPlanningError, match=r"no valid depth at pixel \(320.0, 240.0\)"):
        plan_grasp(detection(c), depth_camera(), GraspSelector(), depth)
    # A wider window reaches the valid samples around the hole.
    target = plan_grasp(detection(c), depth_camera(window=13), GraspSelector(), depth)
    assert target.position_m[2] == pytest.approx(0.02, abs=TOL)


def test_a_joint_without_depth_falls_back_to_the_grasp_points_depth():
    origin = (0.4, 0.05, 0.6)
    depth = np.full((H, W), 0.5, np.float32)
    depth[:, 400:] = np.nan  # nothing measured on the right
    c = chain([(250.0, 100.0), (450.0, 300.0)])  # grasp at (350, 200); end joint unmeasured
    target = plan_grasp(detection(c), depth_camera(origin=origin), GraspSelector(), depth)
    # Both joints at 0.5 m: the tangent is the image diagonal scaled alike.
    expected = closing_yaw(200 / FX, -200 / FY)
    assert target.yaw_rad == pytest.approx(expected, abs=1e-6)
    assert target.position_m[2] == pytest.approx(0.1, abs=TOL)


def test_depth_outside_the_valid_range_counts_as_missing():
    depth = np.full((H, W), 0.58, np.float32)
    depth[240, 320] = 0.2  # a speck of dust on the lens side
    c = chain([(300.0, 240.0), (340.0, 240.0)])
    speck = plan_grasp(detection(c), depth_camera(), GraspSelector(), depth)
    assert speck.position_m[2] == pytest.approx(0.6 - 0.2, abs=TOL)
    ranged = depth_camera(min_depth_m=0.3, max_depth_m=1.0)
    target = plan_grasp(detection(c), ranged, GraspSelector(), depth)
    assert target.position_m[2] == pytest.approx(0.02, abs=TOL)
    with pytest.raises(GraspPlanningError, match=r"valid: finite, >= 0.6 m and <= 1.0 m"):
        plan_grasp(
            detection(c), depth_camera(min_depth_m=0.6, max_depth_m=1.0), GraspSelector(), depth
        )


@pytest.mark.parametrize(
    ("samples", "scale"),
    [
        (np.full((H, W), 580, np.uint16), 0.001),  # millimetres, as a 16-bit PNG holds them
        (np.full((H, W), 0.58, np.float32), 1.0),  # metres, as a .npy holds them
        (np.full((H, W), 0.58, np.float64), 1.0),
        (np.full((H, W, 1), 580, np.uint16), 0.001),  # a trailing channel axis
    ],
)
def test_uint16_millimetres_and_float_metres_give_the_same_point(samples, scale):
    c = chain([(100.0, 400.0), (140.0, 380.0)])
    target = plan_grasp(detection(c), depth_camera(depth_scale=scale), GraspSelector(), samples)
    expected = plan_grasp(detection(c), camera(plane_z=0.02), GraspSelector())
    np.testing.assert_allclose(target.position_m, expected.position_m, atol=TOL)


@pytest.mark.parametrize(
    ("depth", "words"),
    [
        (np.full((240, 320), 0.5, np.float32), "depth image is 320x240 px but the camera model"),
        (np.full((H, W, 3), 500, np.uint16), "one channel, not 3 channels"),
        (np.full((H, W), 50, np.uint8), "not uint8"),
        (None, "no depth image was given"),
    ],
)
def test_unusable_depth_images_are_refused(depth, words):
    c = chain([(100.0, 400.0), (140.0, 380.0)])
    with pytest.raises(DepthImageError, match=words):
        plan_grasp(detection(c), depth_camera(), GraspSelector(), depth)


def test_a_depth_image_with_a_plane_surface_is_refused():
    c = chain([(100.0, 400.0), (140.0, 380.0)])
    with pytest.raises(DepthImageError, match=r"surface is the plane z = 0\.02 m"):
        plan_grasp(detection(c), camera(), GraspSelector(), np.ones((H, W), np.float32))


def test_depth_surface_schema():
    surface = depth_camera(depth_scale=0.001).surface
    assert surface == DepthSurface(kind="depth", depth_scale=0.001, window=5)
    # Camera files without a surface kind are planes, as before depth surfaces existed.
    assert isinstance(camera().surface, PlaneSurface)
    data = depth_camera().model_dump(mode="json")
    assert CameraModel.model_validate_json(json.dumps(data)) == depth_camera()
    for bad, words in [
        ({"kind": "depth"}, "depth_scale"),
        ({"kind": "depth", "depth_scale": 0}, "greater than 0"),
        ({"kind": "depth", "depth_scale": 1, "window": 4}, "window must be odd"),
        ({"kind": "depth", "depth_scale": 1, "min_depth_m": 2, "max_depth_m": 1}, "less than"),
        ({"kind": "sphere"}, r"kind is 'plane' \(the default\) or 'depth'"),
        ({"kind": "plane", "plane_z": 0, "depth_scale": 1}, "Extra inputs"),
    ]:
        with pytest.raises(ValidationError, match=words):
            CameraModel.model_validate({**data, "surface": bad})


def test_the_depth_camera_example_loads():
    from pathlib import Path

    examples = Path(__file__).resolve().parents[3] / "docs" / "examples"
    cam = CameraModel.from_file(examples / "camera_depth.json")
    assert isinstance(cam.surface, DepthSurface) and cam.surface.depth_scale == 0.001


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_decode_depth_image_keeps_the_samples(dtype):
    samples = (np.arange(W * H).reshape(H, W) % 4000 + 1).astype(dtype)
    suffix = ".png" if dtype == np.uint16 else ".tiff"
    encoded_ok, encoded = cv2.imencode(suffix, samples)
    assert encoded_ok
    decoded = decode_depth_image(encoded.tobytes())
    assert decoded.dtype == dtype
    np.testing.assert_array_equal(decoded, samples)


def test_decode_depth_image_refuses_what_is_not_a_depth_image():
    png16 = cv2.imencode(".png", np.full((4, 4), 500, np.uint16))[1].tobytes()
    cases = [
        (b"", "empty"),
        (b"not an image", "not an image"),
        (png16[: len(png16) // 2], "truncated or corrupt PNG"),
        (cv2.imencode(".png", np.zeros((4, 4), np.uint8))[1].tobytes(), "8-bit samples"),
        (cv2.imencode(".png", np.zeros((4, 4, 3), np.uint16))[1].tobytes(), "3 channels"),
    ]
    for data, words in cases:
        with pytest.raises(DepthImageError, match=words):
            decode_depth_image(data)
