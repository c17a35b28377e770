"""Step 2, skeletonization: thinning, spurs, radius and distances, and their kernels."""

import cv2
import numpy as np
import pytest

from service.perception.fitting import junction_zones
from service.perception.skeleton import (
    distance_transform,
    estimate_radius,
    remove_spurs,
    short_blobs_kept,
    skeletonize,
    spurs_removed,
    thin_listed,
)
from tests.perception.cases import INPUTS, thick_polylines
from tests.perception.references import skeleton as reference
from tests.perception.references import steps


def skeleton_without_spurs(mask, spur_length):
    """Step 2 as the pipeline runs it, with a given spur length."""
    skeleton = skeletonize(mask)
    return remove_spurs(skeleton, spur_length) if spur_length > 0 else skeleton


def test_skeleton_of_a_band_is_one_connected_branch_on_its_centreline():
    mask = thick_polylines((80, 200), [[(20, 40), (180, 40)]], 11)
    skeleton = skeleton_without_spurs(mask, spur_length=12)
    counts = reference.branch_counts(skeleton)
    assert (counts == 1).sum() == 2  # two tips
    assert (counts >= 3).sum() == 0  # no junction
    assert np.abs(np.argwhere(skeleton)[:, 0] - 40).max() <= 1
    assert cv2.connectedComponents(skeleton.astype(np.uint8))[0] == 2  # background + 1
    assert estimate_radius(skeleton, distance=distance_transform(mask)) == pytest.approx(
        5.5, abs=1.0
    )


def test_skeleton_of_a_crossing_has_a_junction_and_four_tips():
    mask = thick_polylines((200, 200), [[(20, 20), (180, 180)], [(20, 180), (180, 20)]], 9)
    skeleton = skeleton_without_spurs(mask, spur_length=12)
    counts = reference.branch_counts(skeleton)
    assert (counts == 1).sum() == 4
    assert (counts >= 3).any()


def test_spurs_from_a_ragged_border_are_removed():
    mask = thick_polylines((80, 200), [[(20, 40), (180, 40)]], 11)
    mask[30:35, 100:103] = True  # a bump on the border grows a spur
    raw = skeleton_without_spurs(mask, spur_length=0)
    pruned = skeleton_without_spurs(mask, spur_length=15)
    assert (reference.branch_counts(raw) == 1).sum() >= 2
    assert (reference.branch_counts(pruned) == 1).sum() == 2
    assert (reference.branch_counts(pruned) >= 3).sum() == 0


@pytest.mark.parametrize("seed", range(4))
def test_thinning_keeps_topology_and_leaves_lines_one_pixel_wide(seed):
    # Rings, thick strokes and solid blobs, overlapping at random.
    rng = np.random.default_rng(seed)
    shapes = np.zeros((120, 160), np.uint8)
    for _ in range(12):
        centre = (int(rng.integers(10, 150)), int(rng.integers(10, 110)))
        radius = int(rng.integers(5, 14))
        cv2.circle(shapes, centre, radius, 1, int(rng.choice([-1, 3, 5])))
        end = (int(rng.integers(0, 160)), int(rng.integers(0, 120)))
        cv2.line(shapes, centre, end, 1, int(rng.integers(3, 9)))
    skeleton = skeletonize(shapes).astype(np.uint8)

    def components(image):
        # Background round the image, as the thinning assumes: a hole is a 4-connected
        # background component that does not reach it.
        padded = np.pad(image, 1)
        return (
            cv2.connectedComponents(padded, connectivity=8)[0],
            cv2.connectedComponents(1 - padded, connectivity=4)[0],
        )

    assert components(skeleton) == components(shapes)
    blocks = skeleton[:-1, :-1] & skeleton[1:, :-1] & skeleton[:-1, 1:] & skeleton[1:, 1:]
    assert not blocks.any()
    # Lines, not clumps: most pixels have exactly two branches.
    counts = reference.branch_counts(skeleton > 0)
    assert np.count_nonzero(counts == 2) > 0.8 * np.count_nonzero(skeleton)


def test_thinning_a_bar_leaves_its_centre_line():
    bar = np.zeros((21, 60), bool)
    bar[6:15, 5:55] = True
    rows, cols = np.nonzero(skeletonize(bar))
    assert set(rows[(cols > 12) & (cols < 48)]) == {10}


# --------------------------------------------------------------------------- kernels


@pytest.mark.parametrize("name", sorted(INPUTS))
def test_thinning_spurs_and_radius_equal_the_reference(name):
    mask = INPUTS[name]
    expected = steps.on_input(name)
    thinned = skeletonize(mask)
    assert thinned.dtype == bool
    np.testing.assert_array_equal(thinned, expected.skeleton)
    assert max(estimate_radius(thinned, distance=distance_transform(mask)), 1.0) == expected.radius
    pruned = remove_spurs(thinned, 2.5 * expected.radius)
    assert pruned.dtype == bool
    np.testing.assert_array_equal(pruned, expected.pruned_skeleton)


@pytest.mark.parametrize("seed", range(4))
def test_thinning_equals_the_reference_on_random_noise(seed):
    # Dense noise makes every removal pattern of the thinning tables occur.
    rng = np.random.default_rng(seed)
    mask = rng.random((64, 80)) < (0.5 + 0.1 * seed)
    np.testing.assert_array_equal(skeletonize(mask), reference.thin(mask))
    full = np.ones((7 + seed, 9), bool)
    np.testing.assert_array_equal(skeletonize(full), reference.thin(full))


@pytest.mark.parametrize("seed", range(3))
def test_thinning_thick_blobs_equals_the_reference(seed):
    # Blobs up to 21 px wide with pinholes take many sub-iterations: the kernel looks
    # again at a kept pixel only when a neighbour went or the other table removes its
    # pattern, and must still remove exactly what the plain sweep removes. Blobs on
    # the image's edge, integer and Fortran-ordered masks, and a mask of no pixels.
    rng = np.random.default_rng(seed)
    dots = (rng.random((70, 90)) < 0.01).astype(np.uint8)
    side = 7 + 7 * seed
    mask = cv2.dilate(dots, np.ones((side, side), np.uint8)) > 0
    mask[rng.random(mask.shape) < 0.02] = False
    for image in (mask, mask.astype(np.uint8) * 7, np.asfortranarray(mask), mask[:, :1]):
        thinned = skeletonize(image)
        assert thinned.dtype == bool and thinned.shape == image.shape
        np.testing.assert_array_equal(thinned, reference.thin(np.asarray(image) != 0))
    assert not skeletonize(np.zeros((0, 4), bool)).any()


@pytest.mark.parametrize("seed", range(3))
def test_distance_transform_equals_opencv(seed):
    rng = np.random.default_rng(seed)
    mask = cv2.dilate((rng.random((90, 70)) < 0.05).astype(np.uint8), np.ones((9, 9), np.uint8))
    mask[rng.random(mask.shape) < 0.03] = 0
    for image in (mask, np.ones((6, 9), np.uint8), np.zeros((5, 5), np.uint8)):
        np.testing.assert_array_equal(
            distance_transform(image > 0), cv2.distanceTransform(image, cv2.DIST_L2, 5)
        )


def test_a_short_blob_of_spurs_keeps_its_longest_path_and_a_cable_its_spurs_cut():
    # A stretch of cable between two round objects: a blob 16 px wide and about 20
    # long whose thinning is a short middle with forks at the cut corners, every
    # branch shorter than a spur. Beside it a long band with a ragged spur.
    mask = np.zeros((120, 240), np.uint8)
    cv2.line(mask, (20, 40), (40, 44), 1, 16)
    cv2.circle(mask, (8, 38), 14, 0, -1)
    cv2.circle(mask, (52, 48), 14, 0, -1)
    cv2.line(mask, (20, 90), (220, 90), 1, 11)
    mask[80:84, 120:123] = 1  # a bump on the band's side: a spur
    mask = mask.astype(bool)
    skeleton = skeletonize(mask)
    spur = 20.0
    pruned = remove_spurs(skeleton, spur)
    kept = short_blobs_kept(skeleton, pruned, spur)
    blob = np.zeros_like(mask)
    blob[:70] = True
    assert np.count_nonzero(pruned & blob) < spur  # spur removal leaves the blob almost nothing
    path = np.argwhere(kept & blob)
    extent = np.hypot(*(path.max(0) - path.min(0)))
    assert extent >= 15  # tip to tip across the blob
    counts = reference.branch_counts(kept & blob)
    assert (counts >= 3).sum() == 0 and (counts == 1).sum() == 2  # one line
    assert np.array_equal(kept & ~blob, pruned & ~blob)  # the band's spur stays cut


@pytest.mark.filterwarnings("ignore:overflow")  # the reference's median of all-set masks
@pytest.mark.parametrize("seed", range(4))
def test_the_listed_thinning_and_spur_removal_equal_the_plain_steps(seed):
    # The thinning's own list of the skeleton's pixels stands for a scan of the image
    # in the radius and the spur removal; the pipeline skips the short blobs' pass when
    # no spur went. Random blobs, lines and noise, on and off the image's edge.
    rng = np.random.default_rng(seed)
    for trial in range(60):
        height, width = rng.integers(1, 70, size=2)
        mask = np.zeros((height, width), np.uint8)
        for _ in range(rng.integers(0, 6)):
            points = rng.integers(-5, max(height, width) + 5, size=(2, 2)).tolist()
            cv2.line(mask, tuple(points[0]), tuple(points[1]), 1, int(rng.integers(1, 12)))
        mask[rng.random(mask.shape) < 0.02 * (trial % 4)] ^= 1
        mask = mask.astype(bool)
        skeleton, pixels = thin_listed(mask)
        np.testing.assert_array_equal(skeleton, reference.thin(mask))
        assert pixels.dtype == np.int64
        np.testing.assert_array_equal(pixels, np.flatnonzero(skeleton))
        distance = distance_transform(mask)
        radius = estimate_radius(skeleton, distance=distance, pixels=pixels)
        assert radius == estimate_radius(skeleton, distance=distance)
        if skeleton.any():
            assert max(radius, 1.0) == max(reference.estimate_radius(mask, skeleton), 1.0)
        for spur in (0.5, 3.0, 2.5 * max(radius, 1.0), 25.0):
            pruned, removed, left = spurs_removed(skeleton, spur, pixels)
            expected = reference.remove_spurs(skeleton, spur)
            np.testing.assert_array_equal(pruned, expected)
            np.testing.assert_array_equal(remove_spurs(skeleton, spur), expected)
            assert removed == (not np.array_equal(expected, skeleton))
            assert left.dtype == np.int64
            np.testing.assert_array_equal(left, np.flatnonzero(expected))
            # (A mask with no background has infinite distances: a plain radius then.)
            zone_radius = min(max(radius, 1.0), 9.0)
            zones = junction_zones(pruned, zone_radius, left)
            np.testing.assert_array_equal(zones, junction_zones(pruned, zone_radius))
            if not removed:
                assert short_blobs_kept(skeleton, pruned, spur) is pruned


def test_one_spur_pass_leaves_a_0_1_skeleton_as_the_plain_pass_does():
    # The pass keeps its walks' marks (tip, junction, visited) in the skeleton's own
    # bytes: after it, every byte is 0 or 1 again, the pixels it kept untouched, and
    # the pass is the plain one (the reference's single pass, thinned after a cut).
    from service.perception import _skeleton_kernels
    from service.perception.skeleton import _BRANCH_COUNT

    rng = np.random.default_rng(21)
    cuts = 0
    for trial in range(150):
        height, width = (int(v) for v in rng.integers(1, 50, size=2))
        mask = np.zeros((height, width), np.uint8)
        for _ in range(rng.integers(1, 6)):
            points = rng.integers(-5, max(height, width) + 5, size=(2, 2)).tolist()
            cv2.line(mask, tuple(points[0]), tuple(points[1]), 1, int(rng.integers(1, 8)))
        mask[rng.random(mask.shape) < 0.03 * (trial % 3)] = 1
        skeleton, pixels = thin_listed(mask.astype(bool))
        for spur in (0.0, 1.0, 4.0, 12.0, 1e12):
            image = skeleton.view(np.uint8).copy()
            cut = _skeleton_kernels.remove_spurs_inplace(image, pixels, spur, _BRANCH_COUNT)
            assert set(np.unique(image).tolist()) <= {0, 1}
            assert not (image & ~skeleton.view(np.uint8)).any()  # only ever cleared
            expected = reference.remove_spurs(skeleton, spur, passes=1)
            assert cut == (not np.array_equal(expected, skeleton))
            after = skeletonize(image.view(bool)) if cut else image.view(bool)
            np.testing.assert_array_equal(after, expected)
            cuts += cut
    assert cuts > 50
