"""The scene families: seeds reproduce, and each family's ground truth matches its image
and keeps the promises of its description (radii, gaps, angles, occluders)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.evaluation import conventions
from service.synthetic import (
    FAMILIES,
    FAMILY_NAMES,
    SyntheticScene,
    make_family_scene,
    make_scene,
)
from service.synthetic.shapes import bend_radii
from tests.service.test_synthetic import arc_length, distance_to_polyline, inside_convex_polygon

WIDTH, HEIGHT = 640, 480
SEEDS = (1, 2)
SLOW_SEEDS = range(3, 23)
DESIGNED = [name for name in FAMILY_NAMES if name != "baseline"]


def tangent_at(centreline: np.ndarray, arc_at: float) -> np.ndarray:
    arc = arc_length(centreline)
    sample = int(np.searchsorted(arc, arc_at))
    ahead, behind = min(sample + 4, len(arc) - 1), max(sample - 4, 0)
    tangent = centreline[ahead] - centreline[behind]
    return tangent / np.linalg.norm(tangent)


def crossing_angle(scene: SyntheticScene, crossing) -> float:
    """Degrees, 0-90, between the two strands at a crossing."""
    a = tangent_at(scene.cables[crossing.over].centreline, crossing.over_arc)
    b = tangent_at(scene.cables[crossing.under].centreline, crossing.under_arc)
    return math.degrees(math.asin(min(1.0, abs(a[0] * b[1] - a[1] * b[0]))))


def features(scene: SyntheticScene, kind: str):
    return [feature for feature in scene.features if feature.kind == kind]


def check_ground_truth(scene: SyntheticScene) -> None:
    """What every scene of every family must satisfy."""
    height, width = scene.mask.shape
    assert scene.image.shape == (height, width, 3) and scene.image.dtype == np.uint8
    assert np.array_equal(scene.labels > 0, scene.mask)
    assert set(np.unique(scene.labels)) <= set(range(len(scene.cables) + 1))
    occluded = np.zeros(scene.mask.shape, dtype=bool)
    rows, cols = np.indices(scene.mask.shape)
    centres = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    for occluder in scene.occluders:
        occluded |= inside_convex_polygon(centres, occluder.polygon).reshape(scene.mask.shape)
    assert not scene.mask[occluded].any()
    for index, cable in enumerate(scene.cables):
        steps = np.linalg.norm(np.diff(cable.centreline, axis=0), axis=1)
        assert steps.max() <= 1.0 and steps.min() > 0.0
        assert cable.centreline.min() >= 0.0
        assert np.all(cable.centreline.max(axis=0) <= [width - 1, height - 1])
        # Labelled pixels lie within the cable; pixels well inside it are cable (or a cable
        # on top of it) unless an occluder covers them.
        labelled = np.column_stack(np.nonzero(scene.labels == index + 1)[::-1]).astype(float)
        if len(labelled):
            assert distance_to_polyline(labelled, cable.centreline).max() <= cable.radius + 1.0
        near = cKDTree(cable.centreline).query(centres, distance_upper_bound=cable.radius)[0]
        well_inside = (near <= cable.radius - 1.0).reshape(scene.mask.shape) & ~occluded
        assert scene.mask[well_inside].all()
        # Hidden samples are those under an occluder, with visible cable on both sides.
        under = np.zeros(len(cable.centreline), dtype=bool)
        for occluder in scene.occluders:
            under |= inside_convex_polygon(cable.centreline, occluder.polygon)
        assert np.array_equal(under, cable.hidden)
        if cable.hidden.any():
            arc = arc_length(cable.centreline)
            assert arc[cable.hidden].min() >= 3.0 * cable.radius - 0.5
            assert arc[cable.hidden].max() <= arc[-1] - 3.0 * cable.radius + 0.5
    for crossing in scene.crossings:
        point = np.array([[crossing.x, crossing.y]])
        for index in (crossing.over, crossing.under):
            assert distance_to_polyline(point, scene.cables[index].centreline)[0] < 1e-6
        assert scene.labels[round(crossing.y), round(crossing.x)] == crossing.over + 1
        if crossing.over == crossing.under:
            assert crossing.over_arc > crossing.under_arc
        else:
            assert scene.cables[crossing.over].depth > scene.cables[crossing.under].depth


@pytest.fixture(scope="module")
def scenes() -> dict[str, list[SyntheticScene]]:
    return {
        name: [make_family_scene(name, seed, WIDTH, HEIGHT) for seed in SEEDS]
        for name in FAMILY_NAMES
    }


def test_family_names_agree_with_the_light_conventions_module() -> None:
    assert FAMILY_NAMES == conventions.FAMILY_NAMES == tuple(FAMILIES)
    assert conventions.TUNING_SEEDS[1] < conventions.HELD_OUT_FIRST_SEED
    for family in FAMILIES.values():
        assert family.summary


def test_baseline_is_make_scene_as_dlo_eval_always_drew_it() -> None:
    for seed in (4, 5):
        family = make_family_scene("baseline", seed, 640, 360)
        plain = make_scene(640, 360, 1 + seed % 3, seed=seed, occluders=2)
        assert np.array_equal(family.image, plain.image)
        assert np.array_equal(family.labels, plain.labels)


def test_a_seed_reproduces_its_scene_and_families_do_not_share_scenes() -> None:
    first = make_family_scene("loops", 7, WIDTH, HEIGHT)
    again = make_family_scene("loops", 7, WIDTH, HEIGHT)
    assert np.array_equal(first.image, again.image)
    assert np.array_equal(first.labels, again.labels)
    for a, b in zip(first.cables, again.cables, strict=True):
        assert np.array_equal(a.centreline, b.centreline) and np.array_equal(a.hidden, b.hidden)
    assert not np.array_equal(first.image, make_family_scene("loops", 8, WIDTH, HEIGHT).image)
    assert not np.array_equal(first.image, make_family_scene("many", 7, WIDTH, HEIGHT).image)


@pytest.mark.parametrize("name", FAMILY_NAMES)
def test_ground_truth_matches_the_image(scenes, name) -> None:
    for scene in scenes[name]:
        check_ground_truth(scene)


@pytest.mark.slow
@pytest.mark.parametrize("name", DESIGNED)
def test_ground_truth_matches_the_image_over_many_seeds(name) -> None:
    for seed in SLOW_SEEDS:
        scene = make_family_scene(name, seed)
        check_ground_truth(scene)
        check_promises(name, scene)


@pytest.mark.parametrize("name", DESIGNED)
def test_each_family_keeps_its_promises(scenes, name) -> None:
    for scene in scenes[name]:
        check_promises(name, scene)


def check_promises(name: str, scene: SyntheticScene) -> None:
    shallow_pairs = {frozenset(f.cables) for f in features(scene, "shallow_crossing")}
    for crossing in scene.crossings:
        angle = crossing_angle(scene, crossing)
        if frozenset((crossing.over, crossing.under)) in shallow_pairs:
            assert angle >= 9.9
        else:
            assert angle >= 29.0
    for feature in features(scene, "occluder"):
        radius = scene.cables[feature.cables[0]].radius
        assert 3.0 * radius - 0.01 <= feature.values["hidden_length"] <= 15.0 * radius + 0.01
    check = {
        "loops": check_loops,
        "doubled_back": check_hairpin,
        "shallow_crossings": check_shallow_crossing,
        "side_by_side": check_side_by_side,
        "many": check_many,
        "occluded": check_occluded,
        "edge": check_edge,
        "bright": check_bright,
        "textured": check_textured,
        "same_colour": check_same_colour,
    }[name]
    check(scene)


def check_loops(scene: SyntheticScene) -> None:
    loops = features(scene, "loop")
    assert {f.cables[0] for f in loops} == set(range(len(scene.cables)))
    for feature in loops:
        cable = scene.cables[feature.cables[0]]
        assert 3.0 * cable.radius <= feature.values["bend_radius"] <= 6.0 * cable.radius
        assert 45.0 <= feature.values["crossing_angle"] <= 100.0
    for index, cable in enumerate(scene.cables):
        measured = np.nanmin(bend_radii(cable.centreline, 1.0))
        assert measured >= 0.99 * 3.0 * cable.radius
        own = [c for c in scene.crossings if c.over == c.under == index]
        assert len(own) >= sum(f.cables[0] == index for f in loops)


def check_hairpin(scene: SyntheticScene) -> None:
    [feature] = features(scene, "hairpin")
    cable = scene.cables[feature.cables[0]]
    values = feature.values
    assert values["gap"] == 0.0 or 0.3 * cable.radius <= values["gap"] <= cable.radius
    assert 2.0 * cable.radius <= values["bend_radius"] <= 4.0 * cable.radius
    assert 6.0 * cable.radius <= values["parallel_length"] <= 25.0 * cable.radius
    arc = arc_length(cable.centreline)
    strand = (arc > values["strand_start"] + 1) & (arc < values["strand_end"] - 1)
    back = (arc > values["return_start"] + 1) & (arc < values["return_end"] - 1)
    distance = distance_to_polyline(cable.centreline[strand], cable.centreline[back])
    assert distance == pytest.approx(2.0 * cable.radius + values["gap"], abs=0.05)
    assert np.nanmin(bend_radii(cable.centreline, 1.0)) >= 0.95 * 2.0 * cable.radius
    for crossing in scene.crossings:
        if crossing.over == crossing.under == feature.cables[0]:
            for arc_at in (crossing.over_arc, crossing.under_arc):
                assert not values["strand_start"] <= arc_at <= values["return_end"]


def check_shallow_crossing(scene: SyntheticScene) -> None:
    [feature] = features(scene, "shallow_crossing")
    assert 10.0 <= feature.values["angle"] <= 30.0
    pair = set(feature.cables)
    [crossing] = [
        c
        for c in scene.crossings
        if {c.over, c.under} == pair
        and math.hypot(c.x - feature.values["x"], c.y - feature.values["y"]) < 1.0
    ]
    assert crossing_angle(scene, crossing) == pytest.approx(feature.values["angle"], abs=0.5)


def check_side_by_side(scene: SyntheticScene) -> None:
    [feature] = features(scene, "side_by_side")
    first, second = (scene.cables[i] for i in feature.cables)
    values = feature.values
    assert values["gap"] == 0.0 or values["gap"] >= 0.3 * min(first.radius, second.radius) - 1e-9
    assert 10.0 * max(first.radius, second.radius) <= values["length"]
    assert values["length"] <= 40.0 * max(first.radius, second.radius)
    arc = arc_length(second.centreline)
    alongside = (arc > values["partner_start"] + 1) & (arc < values["partner_end"] - 1)
    distance = distance_to_polyline(second.centreline[alongside], first.centreline)
    assert distance == pytest.approx(first.radius + second.radius + values["gap"], abs=0.05)
    for crossing in scene.crossings:
        if {crossing.over, crossing.under} == set(feature.cables):
            arc_at = (
                crossing.under_arc if crossing.under == feature.cables[1] else crossing.over_arc
            )
            assert not values["partner_start"] <= arc_at <= values["partner_end"]


def check_many(scene: SyntheticScene) -> None:
    assert 4 <= len(scene.cables) <= 10
    assert all(3.0 <= cable.radius <= 6.0 for cable in scene.cables)


def check_occluded(scene: SyntheticScene) -> None:
    assert 2 <= len(scene.occluders) <= 4
    assert len(features(scene, "occluder")) == len(scene.occluders)


def check_edge(scene: SyntheticScene) -> None:
    height, width = scene.mask.shape
    assert scene.occluders
    for feature in features(scene, "occluder"):
        assert feature.values["at_edge"] == 1.0
        cable = scene.cables[feature.cables[0]]
        arc = arc_length(cable.centreline)
        hidden = arc[cable.hidden]
        # Between the occluder and the cable's end at the picture's border: 3-10 radii
        # (measured along the hidden stretch's nearer side, for some hidden stretch).
        tails = [hidden.min(), arc[-1] - hidden.max()]
        ends = [cable.centreline[0], cable.centreline[-1]]
        on_border = [min(x, y) < 0.5 or x > width - 1.5 or y > height - 1.5 for x, y in ends]
        assert any(
            border and 3.0 * cable.radius - 0.5 <= tail <= 16.0 * cable.radius
            for tail, border in zip(tails, on_border, strict=True)
        )


def check_bright(scene: SyntheticScene) -> None:
    assert scene.backdrop == "paper"
    brightness = scene.image.astype(float).mean(axis=2)
    assert np.median(brightness[~scene.mask]) > 150.0


def check_textured(scene: SyntheticScene) -> None:
    assert scene.backdrop == "painted"
    image = scene.image.astype(float)
    colourful = image.max(axis=2) - image.min(axis=2)
    # Busy: strong local contrast everywhere, not a plain table.
    assert np.std(image.mean(axis=2)[~scene.mask]) > 20.0 or colourful[~scene.mask].std() > 20.0


def check_same_colour(scene: SyntheticScene) -> None:
    colours = np.array([cable.colour for cable in scene.cables])
    assert np.ptp(colours, axis=0).max() <= 8


def test_bright_scenes_have_dark_and_bright_cables() -> None:
    seen = set()
    for seed in range(1, 9):
        for cable in make_family_scene("bright", seed, WIDTH, HEIGHT).cables:
            seen.add("dark" if max(cable.colour) < 150 else "bright")
    assert seen == {"dark", "bright"}


def test_occluders_come_in_both_colourings_on_bends_and_as_discs() -> None:
    kinds = set()
    for seed in range(1, 7):
        scene = make_family_scene("occluded", seed, WIDTH, HEIGHT)
        for occluder, feature in zip(scene.occluders, features(scene, "occluder"), strict=True):
            kinds.add(("like", occluder.like_background))
            kinds.add(("bend", feature.values["on_bend"] == 1.0))
            kinds.add(("disc", len(occluder.polygon) > 4))
    assert kinds == {(k, v) for k in ("like", "bend", "disc") for v in (True, False)}


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (("stripes", 1), "unknown scene family"),
        (("loops", -1), "seed"),
        (("loops", 1, 200, 100), "320x240"),
    ],
)
def test_bad_arguments_are_rejected(arguments, message) -> None:
    with pytest.raises(ValueError, match=message):
        make_family_scene(*arguments)
