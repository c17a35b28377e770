"""Chains lifted to 3-D against the closed-form centrelines of rendered scenes.

Two questions, kept apart: is the lifting itself exact (a perfect 2-D chain in, its true
3-D centreline out), and how close does the whole thing come, detector included (the
rendered image in, ``points_3d`` against the truth)?
"""

from __future__ import annotations

import numpy as np
import pytest

from schemas import Chain, Detection
from service.evaluation.lifting import nearest_cable as evaluation_nearest_cable
from service.geometry3d import lift
from service.synthetic3d import SCENE_KINDS
from tests.service.geometry3d.scenes import detected, lifted_points, scene, true_detection

FLAT_KINDS = ("down", "tilted", "distorted", "crossing")
"""Cables on the bare table: a plane surface describes them; so does the depth image."""
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
@pytest.mark.parametrize(
    ("kind", "mode"), [case for case in cases() if case != ("tilted", "plane")]
)
def test_detected_chains_lie_within_a_millimetre_of_the_truth(kind, mode, seed):
    share, joints = within_a_millimetre(kind, seed, mode)
    assert joints >= 100
    assert share >= 0.95, f"{share:.1%} of {joints} joints within 1 mm"


@pytest.mark.parametrize("seed", SEEDS)
def test_on_a_tilted_table_the_detectors_radius_sets_the_error(seed):
    """Seen obliquely, a plane surface places the centreline ``radius`` above the table
    along an oblique ray, so the detector's pixel radius (10-15 % short on shaded cables)
    costs more there than anything in the lifting: with each chain's radius set to its
    cable's, the same detected chains lie within a millimetre."""
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
    assert share_found < share_fixed


def nearest_cable(scene_3d, chain: Chain):
    """The cable of the scene a lifted chain lies along."""
    return evaluation_nearest_cable(scene_3d, lifted_points_of(chain))


def lifted_points_of(chain: Chain) -> np.ndarray:
    return np.array([p if p is not None else (np.nan,) * 3 for p in chain.points_3d], float)
