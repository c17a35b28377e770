"""Chains lifted to 3-D against the closed-form centrelines of rendered scenes.

Two questions, kept apart: is the lifting itself exact (a perfect 2-D chain in, its true
3-D centreline out), and how close does the whole thing come, detector included (the
rendered image in, ``points_3d`` against the truth)?
"""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from schemas import Chain, Detection
from service.evaluation.lifting import nearest_cable as evaluation_nearest_cable
from service.evaluation.lifting import project
from service.geometry3d import DepthImageError, LiftError, lift
from service.synthetic.scene3d import SCENE_KINDS, distance_to_polylines
from tests.service.geometry3d.scenes import detected, lifted_points, scene, true_detection

BOX_KINDS = ("box", "box_tilted")
"""A cable over a box: only the depth image describes it."""
SEEDS = (0, 1)


def cases():
    for kind in SCENE_KINDS:
        for mode in ("depth",) if kind in BOX_KINDS else ("plane", "depth"):
            yield kind, mode


def lift_scene(detection: Detection, kind: str, seed: int, mode: str) -> Detection:
    scene_3d = scene(kind, seed)
    if mode == "plane":
        return lift(detection, scene_3d.camera)
    return lift(detection, scene_3d.depth_camera, scene_3d.depth_m)


# --- the lifting alone: a perfect chain in --------------------------------------------


@pytest.mark.parametrize(("kind", "mode"), list(cases()))
def test_a_perfect_chain_is_lifted_onto_its_true_centreline(kind, mode):
    lifted = lift_scene(true_detection(kind, 0), kind, 0, mode)
    points = lifted_points(lifted)
    errors = scene(kind, 0).distance_to_centrelines(points)
    assert np.isfinite(errors).all()
    # Plane: the pixel radius is the projected one's median along the cable; depth: the
    # depth of the nearest pixel (up to half a pixel's change of depth on a slope), and
    # the cable's direction from the neighbouring joints, which is least exact where it
    # wraps round the box's edge (bending at its own radius).
    assert np.percentile(errors, 95) < 0.15e-3, f"p95 {np.percentile(errors, 95) * 1e3:.3f} mm"
    # Where one cable lies over another on a plane surface, the upper one's rise is
    # modelled, not measured (service.geometry3d.crossings): within a millimetre there.
    limit = 1e-3 if (kind, mode) == ("crossing", "plane") else 0.6e-3
    assert errors.max() < limit, f"max {errors.max() * 1e3:.3f} mm"
    for chain, cable in zip(lifted.chains, scene(kind, 0).cables, strict=True):
        assert chain.radius_m == pytest.approx(cable.radius, rel=0.03)


# --- detector included: the rendered image in ------------------------------------------


def within_a_millimetre(kind: str, seed: int, mode: str) -> tuple[float, int]:
    lifted = lift_scene(detected(kind, seed), kind, seed, mode)
    errors = scene(kind, seed).distance_to_centrelines(lifted_points(lifted))
    assert np.isfinite(errors).all(), "no joint of these scenes lacks depth"
    return float(np.mean(errors <= 1e-3)), len(errors)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize(("kind", "mode"), list(cases()))
def test_detected_chains_lie_within_a_millimetre_of_the_truth(kind, mode, seed):
    share, joints = within_a_millimetre(kind, seed, mode)
    assert joints >= 100
    assert share >= 0.95, f"{share:.1%} of {joints} joints within 1 mm"


@pytest.mark.parametrize("seed", SEEDS)
def test_on_a_tilted_table_the_detectors_radius_sets_the_error(seed):
    """Seen obliquely, a plane surface places the centreline ``radius`` above the table
    along an oblique ray, so the detector's pixel radius (about 5 % short on these shaded
    cables: their darker rims fall outside the mask) costs more there than anything in
    the lifting: with each chain's radius set to its cable's, the same detected chains
    lie closer still."""
    scene_3d = scene("tilted", seed)
    found = detected("tilted", seed)
    as_found = lift(found, scene_3d.camera)
    cables = [nearest_cable(scene_3d, chain) for chain in as_found.chains]
    assert all(c.radius_m < cable.radius for c, cable in zip(as_found.chains, cables, strict=True))
    corrected = [
        chain.model_copy(update={"radius": chain.radius * cable.radius / lifted.radius_m})
        for chain, lifted, cable in zip(found.chains, as_found.chains, cables, strict=True)
    ]
    fixed = lift(found.model_copy(update={"chains": corrected}), scene_3d.camera)
    share_found = np.mean(scene_3d.distance_to_centrelines(lifted_points(as_found)) <= 1e-3)
    share_fixed = np.mean(scene_3d.distance_to_centrelines(lifted_points(fixed)) <= 1e-3)
    assert share_fixed >= 0.95, f"{share_fixed:.1%}"
    assert share_found <= share_fixed


def nearest_cable(scene_3d, chain: Chain):
    """The cable of the scene a lifted chain lies along."""
    return evaluation_nearest_cable(scene_3d, lifted_points_of(chain))


def lifted_points_of(chain: Chain) -> np.ndarray:
    return np.array([p if p is not None else (np.nan,) * 3 for p in chain.points_3d], float)


# --- nulls, hidden joints, refusals, the contract ----------------------------------------


def test_a_hole_in_the_depth_image_gives_null_joints_and_nothing_else():
    scene_3d = scene("down", 0)
    truth = true_detection("down", 0)
    chain = truth.chains[0]
    middle = len(chain.points) // 2
    x, y = (round(v) for v in chain.points[middle])
    depth = scene_3d.depth_m.copy()
    depth[y - 30 : y + 31, x - 30 : x + 31] = 0.0  # not measured (as depth cameras write)
    lifted = lift(truth, scene_3d.depth_camera, depth)
    points = lifted.chains[0].points_3d
    missing = [k for k, point in enumerate(points) if point is None]
    assert middle in missing and 2 <= len(missing) <= 8
    located = lifted_points(lifted)
    errors = scene_3d.distance_to_centrelines(located[np.isfinite(located).all(axis=1)])
    assert errors.max() < 0.6e-3
    assert lifted.chains[0].radius_m == pytest.approx(scene_3d.cables[0].radius, rel=0.03)


def test_hidden_joints_lie_between_their_seen_neighbours_whatever_hides_them():
    scene_3d = scene("tilted", 1)
    truth = true_detection("tilted", 1)
    chain = truth.chains[0]
    hidden = range(10, 16)
    inferred = [k in hidden for k in range(len(chain.points) - 1)]
    occluded = truth.model_copy(
        update={"chains": [chain.model_copy(update={"inferred": inferred}), *truth.chains[1:]]}
    )
    # Something 5 cm nearer the camera lies over those segments in the depth image (and
    # not over the seen joints either side).
    depth = scene_3d.depth_m.copy()
    rows, columns = np.mgrid[: depth.shape[0], : depth.shape[1]]
    for x, y in chain.points[10:17]:
        depth[(columns - x) ** 2 + (rows - y) ** 2 <= 6**2] -= 0.05
    lifted = lift(occluded, scene_3d.depth_camera, depth)
    points = np.array(lifted.chains[0].points_3d)
    errors = scene_3d.distance_to_centrelines(points[10:17])
    assert errors.max() < 0.3e-3, errors  # a cable on the table: interpolation is exact
    # ... each on its own ray: seen where the chain says.
    back = project(scene_3d, points[10:17])
    np.testing.assert_allclose(back, np.array(chain.points[10:17]), atol=1e-6)


def test_lifting_and_grasp_planning_place_a_pixel_alike():
    """One implementation: a grasp target on a plane is where lifting puts the joint, less
    the cable's radius (the grasp is on the table, the centreline a radius above it)."""
    from adapters.grasp.target import plan_grasp
    from schemas import GraspSelector

    scene_3d = scene("distorted", 0)
    truth = true_detection("distorted", 0)
    lifted = lift(truth, scene_3d.camera)
    chain = lifted.chains[0]
    end = {"kind": "end", "end": "start"}
    target = plan_grasp(truth, scene_3d.camera, GraspSelector(chain=chain.id, point=end))
    on_table = np.array(target.position_m)
    centre = np.array(chain.points_3d[0])
    ray = centre - np.asarray(scene_3d.camera.T_base_camera)[:3, 3]
    expected = centre + ray * (-chain.radius_m / ray[2])
    np.testing.assert_allclose(on_table, expected, atol=1e-9)


def test_refusals():
    scene_3d = scene("down", 0)
    truth = true_detection("down", 0)
    small = scene_3d.camera.model_copy(update={"width": 320, "height": 240})
    with pytest.raises(LiftError, match="320x240"):
        lift(truth, small)
    with pytest.raises(DepthImageError, match="plane"):
        lift(truth, scene_3d.camera, scene_3d.depth_m)
    with pytest.raises(DepthImageError, match="no depth image"):
        lift(truth, scene_3d.depth_camera)
    with pytest.raises(DepthImageError, match="camera model is"):
        lift(truth, scene_3d.depth_camera, scene_3d.depth_m[:100])
    empty = truth.model_copy(update={"chains": [], "crossings": []})
    assert lift(empty, scene_3d.camera).chains == []


def test_points_3d_are_optional_in_the_contract():
    truth = true_detection("down", 0)
    plain = json.loads(truth.model_dump_json())
    assert "points_3d" not in plain["chains"][0] and "radius_m" not in plain["chains"][0]
    lifted = lift(truth, scene("down", 0).camera)
    again = Detection.model_validate_json(lifted.model_dump_json())
    assert again.chains[0].points_3d == lifted.chains[0].points_3d
    schema = Chain.model_json_schema()["properties"]
    assert "robot base frame" in schema["points_3d"]["description"]
    assert "null" in schema["points_3d"]["description"]
    assert "points_3d" not in Chain.model_json_schema().get("required", [])
    with pytest.raises(ValueError, match="points_3d has 1 entries"):
        Chain(id=0, points=[(0, 0), (1, 1)], radius=1, inferred=[False], points_3d=[(0, 0, 0)])


@pytest.mark.parametrize("seed", SEEDS)
def test_on_a_plane_the_upper_strand_rests_on_the_lower_one(seed):
    """Both strands of a crossing lifted to the table would run through each other; the
    upper one is raised so that their surfaces at most touch (as in the scene)."""
    found = detected("crossing", seed)
    assert found.crossings, "the detector reports the crossing"
    lifted = lift(found, scene("crossing", seed).camera)
    crossing = found.crossings[0]
    over, under = lifted.chain(crossing.over), lifted.chain(crossing.under)
    over_points = np.array(over.points_3d)
    under_points = np.array(under.points_3d)
    samples = np.linspace(0, 1, 20)[:, None]
    dense = np.vstack([a + samples * (b - a) for a, b in itertools.pairwise(under_points)])
    apart = distance_to_polylines(over_points, [dense])
    assert apart.min() >= 0.9 * (over.radius_m + under.radius_m)
    # ... and away from the crossing it lies on the table like the other.
    assert np.median(over_points[:, 2]) == pytest.approx(over.radius_m, abs=1e-4)
