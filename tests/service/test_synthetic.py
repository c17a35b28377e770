"""The synthetic scene generator: determinism, and ground truth that matches the image."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.synthetic import SyntheticScene, make_scene, render


@pytest.fixture(scope="module")
def scene() -> SyntheticScene:
    return make_scene(1280, 720, 3, seed=0, occluders=2)


@pytest.fixture(scope="module")
def many_scenes() -> list[SyntheticScene]:
    """Small scenes with loops, crossings and occluders, to check rules over many layouts."""
    return [make_scene(640, 360, 4, seed=seed, occluders=1) for seed in range(6)]


def arc_length(centreline: np.ndarray) -> np.ndarray:
    steps = np.linalg.norm(np.diff(centreline, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Exact distance from each point to the polyline (via its nearest vertex's segments)."""
    _, nearest = cKDTree(polyline).query(points)
    best = np.full(len(points), np.inf)
    for segment in (np.clip(nearest - 1, 0, len(polyline) - 2), np.clip(nearest, 0, None)):
        segment = np.minimum(segment, len(polyline) - 2)
        start, step = polyline[segment], polyline[segment + 1] - polyline[segment]
        t = np.einsum("ij,ij->i", points - start, step) / np.einsum("ij,ij->i", step, step)
        foot = start + np.clip(t, 0.0, 1.0)[:, None] * step
        best = np.minimum(best, np.linalg.norm(points - foot, axis=1))
    return best


def inside_convex_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    edges = np.roll(polygon, -1, axis=0) - polygon
    offsets = points[:, None, :] - polygon[None, :, :]
    cross = edges[None, :, 0] * offsets[:, :, 1] - edges[None, :, 1] * offsets[:, :, 0]
    return np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)


def pixel_centres(shape: tuple[int, int]) -> np.ndarray:
    rows, cols = np.indices(shape)
    return np.column_stack([cols.ravel(), rows.ravel()]).astype(float)


def pixels_under(polygon: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the pixels whose centres lie inside a convex polygon."""
    x0, y0 = np.maximum(np.floor(polygon.min(axis=0)).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(polygon.max(axis=0)).astype(int), [shape[1] - 1, shape[0] - 1])
    rows, cols = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
    rows, cols = rows.ravel(), cols.ravel()
    inside = inside_convex_polygon(np.column_stack([cols, rows]).astype(float), polygon)
    return rows[inside], cols[inside]


def test_same_seed_gives_the_same_scene():
    first, second = make_scene(640, 360, seed=7), make_scene(640, 360, seed=7)
    assert np.array_equal(first.image, second.image)
    assert np.array_equal(first.labels, second.labels)
    for a, b in zip(first.cables, second.cables, strict=True):
        assert np.array_equal(a.centreline, b.centreline)
    assert [(c.x, c.y, c.over, c.under) for c in first.crossings] == [
        (c.x, c.y, c.over, c.under) for c in second.crossings
    ]


@pytest.mark.parametrize("background", ["textured", "plain"])
def test_image_does_not_depend_on_the_band_size(monkeypatch, background):
    """The image is composed in bands of rows; thin bands must give the very same image.

    An odd size makes the noise bytes of the whole image no multiple of 4, and an occluder
    and loops put paints across band borders.
    """
    arguments = dict(seed=5, occluders=1, background=background)
    whole = make_scene(641, 363, 3, **arguments)
    monkeypatch.setattr(render, "_BAND_PIXELS", 1)  # bands of 4 rows
    banded = make_scene(641, 363, 3, **arguments)
    assert np.array_equal(whole.image, banded.image)
    assert np.array_equal(whole.labels, banded.labels)


def test_different_seeds_give_different_scenes():
    assert not np.array_equal(
        make_scene(640, 360, seed=1).image, make_scene(640, 360, seed=2).image
    )


def test_shapes_and_dtypes(scene):
    assert scene.image.shape == (720, 1280, 3) and scene.image.dtype == np.uint8
    assert scene.mask.shape == (720, 1280) and scene.mask.dtype == bool
    assert scene.labels.shape == (720, 1280) and scene.labels.dtype == np.uint16
    assert len(scene.cables) == 3
    assert sorted(cable.depth for cable in scene.cables) == [0, 1, 2]
    for cable in scene.cables:
        n = len(cable.centreline)
        assert cable.centreline.shape == (n, 2) and cable.centreline.dtype == np.float64
        assert cable.hidden.shape == (n,) and cable.hidden.dtype == bool
        assert 4.0 <= cable.radius <= 9.0
        assert len(cable.colour) == 3 and max(cable.colour) >= 150
    assert len(scene.occluders) == 2


def test_labels_are_the_mask_split_by_cable(scene):
    assert np.array_equal(scene.labels > 0, scene.mask)
    assert set(np.unique(scene.labels)) == {0, 1, 2, 3}


def test_labelled_pixels_lie_within_their_cable(scene):
    for index, cable in enumerate(scene.cables):
        rows, cols = np.nonzero(scene.labels == index + 1)
        distance = distance_to_polyline(
            np.column_stack([cols, rows]).astype(float), cable.centreline
        )
        assert distance.max() <= cable.radius + 1.0


def test_mask_covers_every_unoccluded_pixel_well_inside_a_cable(many_scenes):
    scene = many_scenes[0]
    occluded = np.zeros(scene.mask.shape, dtype=bool)
    for occluder in scene.occluders:
        occluded[pixels_under(occluder.polygon, scene.mask.shape)] = True
    centres = pixel_centres(scene.mask.shape)
    for cable in scene.cables:
        near = cKDTree(cable.centreline).query(centres, distance_upper_bound=cable.radius)[0]
        well_inside = (near <= cable.radius - 1.0).reshape(scene.mask.shape) & ~occluded
        assert well_inside.any()
        assert scene.mask[well_inside].all()


def test_centrelines_are_densely_sampled_and_in_the_image(many_scenes):
    for scene in many_scenes:
        height, width = scene.mask.shape
        for cable in scene.cables:
            steps = np.linalg.norm(np.diff(cable.centreline, axis=0), axis=1)
            assert steps.max() <= 1.0 and steps.min() > 0.0
            assert cable.centreline.min() >= 0.0
            assert np.all(cable.centreline.max(axis=0) <= [width - 1, height - 1])


def test_crossings_lie_on_both_centrelines_with_the_top_cable_labelled(many_scenes):
    n_crossings = n_self_crossings = 0
    for scene in many_scenes:
        for crossing in scene.crossings:
            point = np.array([[crossing.x, crossing.y]])
            over, under = scene.cables[crossing.over], scene.cables[crossing.under]
            assert distance_to_polyline(point, over.centreline)[0] < 1e-6
            assert distance_to_polyline(point, under.centreline)[0] < 1e-6
            assert scene.labels[round(crossing.y), round(crossing.x)] == crossing.over + 1
            if crossing.over == crossing.under:
                n_self_crossings += 1
                # The loop's later part lies on top.
                assert crossing.over_arc > crossing.under_arc
            else:
                n_crossings += 1
                assert over.depth > under.depth
    assert n_crossings > 0 and n_self_crossings > 0


def test_crossings_are_at_a_clear_angle(many_scenes):
    for scene in many_scenes:
        for crossing in scene.crossings:
            tangents = []
            for index, arc_at in (
                (crossing.over, crossing.over_arc),
                (crossing.under, crossing.under_arc),
            ):
                centreline = scene.cables[index].centreline
                arc = arc_length(centreline)
                sample = int(np.searchsorted(arc, arc_at))
                ahead, behind = min(sample + 4, len(arc) - 1), max(sample - 4, 0)
                tangent = centreline[ahead] - centreline[behind]
                tangents.append(tangent / np.linalg.norm(tangent))
            (ax, ay), (bx, by) = tangents
            sine = abs(ax * by - ay * bx)
            assert sine >= math.sin(math.radians(29.0))


def test_without_loops_no_cable_crosses_itself():
    for seed in range(3):
        scene = make_scene(640, 360, 4, seed=seed, loops=False)
        assert all(crossing.over != crossing.under for crossing in scene.crossings)


def test_occluders_hide_a_stretch_inside_one_cable(scene):
    assert any(cable.hidden.any() for cable in scene.cables)
    for occluder in scene.occluders:
        assert occluder.polygon.shape == (4, 2)
        rows, cols = pixels_under(occluder.polygon, scene.mask.shape)
        assert rows.size > 0
        assert not scene.mask[rows, cols].any()
    for cable in scene.cables:
        if not cable.hidden.any():
            continue
        covered = np.zeros(len(cable.centreline), dtype=bool)
        for occluder in scene.occluders:
            covered |= inside_convex_polygon(cable.centreline, occluder.polygon)
        assert np.array_equal(covered, cable.hidden)
        arc = arc_length(cable.centreline)
        hidden_arc = arc[cable.hidden]
        assert hidden_arc.min() >= 3.0 * cable.radius
        assert hidden_arc.max() <= arc[-1] - 3.0 * cable.radius


def test_hidden_stretches_are_contiguous_and_short(many_scenes):
    for scene in many_scenes:
        hidden_cables = [cable for cable in scene.cables if cable.hidden.any()]
        assert len(hidden_cables) == 1  # one occluder per scene
        cable = hidden_cables[0]
        assert not cable.hidden[0] and not cable.hidden[-1]
        starts = np.flatnonzero(np.diff(cable.hidden.astype(int)) == 1)
        assert len(starts) == 1
        hidden_length = arc_length(cable.centreline[cable.hidden])[-1]
        assert 15.0 <= hidden_length <= 100.0


def test_occluders_keep_off_crossings(many_scenes):
    for scene in many_scenes:
        points = np.array([[c.x, c.y] for c in scene.crossings]).reshape(-1, 2)
        for occluder in scene.occluders:
            assert not inside_convex_polygon(points, occluder.polygon).any()


def test_margin_keeps_whole_cables_inside():
    scene = make_scene(640, 360, 3, seed=3, margin=25.0)
    for cable in scene.cables:
        assert cable.centreline.min() >= 25.0
        assert np.all(cable.centreline.max(axis=0) <= [640 - 1 - 25.0, 360 - 1 - 25.0])


@pytest.mark.parametrize(("width", "height"), [(640, 360), (1920, 1080)])
def test_other_sizes(width, height):
    scene = make_scene(width, height, 3, seed=1, occluders=1)
    assert scene.image.shape == (height, width, 3)
    assert scene.mask.any() and len(scene.cables) == 3


def test_smallest_image_with_thin_cables():
    scene = make_scene(64, 64, 1, seed=0, radius_range=(2.0, 3.0))
    assert scene.mask.any()


def test_no_cables_gives_an_empty_mask():
    scene = make_scene(320, 240, 0, seed=0)
    assert not scene.mask.any() and not scene.labels.any()
    assert scene.cables == [] and scene.crossings == [] and scene.occluders == []


@pytest.mark.parametrize("background", ["textured", "plain"])
def test_background_is_dark_and_grey_with_bright_cables(background):
    scene = make_scene(640, 360, 3, seed=5, background=background)
    image = scene.image.astype(float)
    brightness = image.mean(axis=2)
    colourfulness = image.max(axis=2) - image.min(axis=2)
    assert 30.0 <= brightness[~scene.mask].mean() <= 100.0
    assert colourfulness[~scene.mask].mean() < 25.0
    cable_stands_out = (brightness > 100.0) | (colourfulness > 60.0)
    assert cable_stands_out[scene.mask].mean() > 0.9


def test_noise_free_scene_is_noise_free_in_flat_regions():
    scene = make_scene(320, 240, 0, seed=0, background="plain", noise_sigma=0.0)
    # A plain background is a gentle gradient: neighbouring pixels differ by at most 1.
    assert np.abs(np.diff(scene.image.astype(int), axis=1)).max() <= 1


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({"width": 63}, "width"),
        ({"height": 10}, "height"),
        ({"width": 640.0}, "width"),
        ({"n_cables": -1}, "n_cables"),
        ({"n_cables": 11}, "n_cables"),
        ({"radius_range": (5.0, 4.0)}, "radius_range"),
        ({"radius_range": (0.0, 4.0)}, "radius_range"),
        ({"radius_range": (-2.0, 4.0)}, "radius_range"),
        ({"radius_range": 4.0}, "radius_range"),
        ({"occluders": -1}, "occluders"),
        ({"n_cables": 0, "occluders": 1}, "occluders"),
        ({"background": "stripes"}, "background"),
        ({"noise_sigma": -1.0}, "noise_sigma"),
        ({"margin": -1.0}, "margin"),
        ({"margin": 200.0}, "margin"),
        ({"seed": -3}, "seed"),
    ],
)
def test_bad_arguments_are_rejected(arguments, message):
    with pytest.raises(ValueError, match=message):
        make_scene(**{"width": 320, "height": 240, **arguments})


def test_impossible_layouts_raise_a_clear_error():
    with pytest.raises(RuntimeError, match="could not place cable"):
        make_scene(64, 64, 10, seed=0, radius_range=(9.0, 9.0))
