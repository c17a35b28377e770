"""Grasp planning: pixel to table point in closed form, point selection, refusals."""

from __future__ import annotations

import math
import sys

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from adapters.grasp import (
    GraspPlanningError,
    InferredSegmentError,
    closing_yaw,
    normalize_half_turn,
    pixel_to_plane,
    plan_grasp,
)
from schemas import (
    CameraModel,
    Chain,
    Detection,
    EndPoint,
    FractionPoint,
    GraspSelector,
    PixelPoint,
    SegmentPoint,
)

FX, FY, CX, CY, W, H = 800.0, 820.0, 320.0, 240.0, 640, 480
TOL = 1e-4  # 0.1 mm

# A camera looking straight down: its x along base +x, its y along base -y, its z down.
DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


def rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def camera(rotation=DOWN, origin=(0.4, 0.05, 0.6), plane_z=0.02, dist=(0, 0, 0, 0, 0)):
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = origin
    return CameraModel(
        fx=FX,
        fy=FY,
        cx=CX,
        cy=CY,
        width=W,
        height=H,
        dist=dist,
        T_base_camera=transform.tolist(),
        surface={"plane_z": plane_z},
    )


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
    with pytest.raises(GraspPlanningError, match="behind the camera"):
        pixel_to_plane(camera(rotation=up), (CX, CY))


def test_ray_parallel_to_the_plane_is_refused():
    horizontal = rot_x(-math.pi / 2) @ DOWN  # optical axis along base -y
    np.testing.assert_allclose(horizontal[:, 2], [0, -1, 0], atol=1e-12)
    with pytest.raises(GraspPlanningError, match="parallel"):
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
