"""Step 1, segmentation: the mask on hand-made images, and its kernels against plain code."""

import cv2
import numpy as np
import pytest

from schemas import DetectParams, SegmentationMethod
from service.perception import InvalidInputError, _segmentation_kernels, detect_full
from service.perception.segmentation import (
    _histogram,
    as_bgr,
    clean_mask,
    grow_by_own_thresholds,
    segment,
    validate_mask,
)
from service.synthetic import make_scene
from tests.perception.cases import speckled_mask
from tests.perception.references import segmentation as reference


def test_auto_segmentation_finds_a_bright_cable_on_a_dark_background():
    image = np.full((100, 160, 3), 30, np.uint8)
    cv2.line(image, (10, 50), (150, 50), (200, 200, 200), 7)
    mask = segment(image, DetectParams())
    truth = np.zeros((100, 160), np.uint8)
    cv2.line(truth, (10, 50), (150, 50), 1, 7)
    dice = 2 * (mask & (truth > 0)).sum() / (mask.sum() + truth.sum())
    assert dice > 0.95


def test_auto_segmentation_uses_colour_when_brightness_does_not_separate():
    # A red cable on a light grey table: as bright as the table, but colourful.
    image = np.full((100, 160, 3), 200, np.uint8)
    cv2.line(image, (10, 50), (150, 50), (40, 40, 210), 9)
    mask = segment(image, DetectParams())
    assert mask[50, 80] and not mask[20, 80]
    assert 0.8 < mask.sum() / (141 * 9) < 1.3


def test_hsv_segmentation_selects_only_the_given_hue():
    image = np.zeros((60, 100, 3), np.uint8)
    cv2.line(image, (5, 20), (95, 20), (0, 0, 255), 5)  # red
    cv2.line(image, (5, 40), (95, 40), (255, 0, 0), 5)  # blue
    params = DetectParams(
        segmentation=SegmentationMethod.hsv, hsv_low=(100, 100, 100), hsv_high=(130, 255, 255)
    )
    mask = segment(image, params)
    assert mask[40, 50] and not mask[20, 50]


def test_clean_mask_removes_specks_and_fills_small_holes():
    mask = np.zeros((60, 60), bool)
    mask[10:40, 10:40] = True
    mask[20:22, 20:22] = False  # small hole
    mask[50:52, 50:52] = True  # speck
    cleaned = clean_mask(mask, min_component_area=20, max_hole_area=10)
    assert cleaned[20:22, 20:22].all()
    assert not cleaned[50:52, 50:52].any()
    assert cleaned[10:40, 10:40].all()


def test_input_validation_gives_clear_errors():
    with pytest.raises(InvalidInputError, match="uint8"):
        as_bgr(np.zeros((20, 20), np.float32))
    with pytest.raises(InvalidInputError, match="too small"):
        as_bgr(np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(InvalidInputError, match="mask is 30x20 px but the image is 40x20 px"):
        validate_mask(np.ones((20, 30), bool), (20, 40))
    with pytest.raises(InvalidInputError, match="empty"):
        validate_mask(np.zeros((20, 40), bool), (20, 40))
    assert as_bgr(np.zeros((20, 20), np.uint8)).shape == (20, 20, 3)
    assert as_bgr(np.zeros((20, 20, 4), np.uint8)).shape == (20, 20, 3)


def _dim_and_bright_cables():
    """Two horizontal cables on black: a bright one, and a dim one with shaded rims."""
    cue = np.zeros((80, 120), np.uint8)
    cue[16:25, :] = 200  # bright cable, hard edges
    cue[52:65, :] = 60  # dim cable's shaded rims, two pixels each side ...
    cue[54:63, :] = 120  # ... round its lit core
    lines = [np.array([[0.0, 20.0], [119.0, 20.0]]), np.array([[0.0, 58.0], [119.0, 58.0]])]
    return cue, lines


def test_own_thresholds_give_a_dim_cable_its_shaded_rims():
    cue, lines = _dim_and_bright_cables()
    # A threshold for the whole image sits between the background and both cables.
    mask = cue >= 100
    grown = grow_by_own_thresholds(cue, mask, lines, [4.5, 4.5], image_low=90.0)
    assert np.array_equal(grown[:40], mask[:40])  # the bright cable keeps its mask
    assert grown[52:65, 5:115].all()  # the dim cable gains its rims ...
    assert not grown[66:, :].any() and not grown[40:51, :].any()  # ... and no background
    assert (grown >= mask).all()  # only ever adds
    # A cable whose own weak threshold is not below the image's gains nothing.
    assert np.array_equal(
        grow_by_own_thresholds(cue, mask, lines, [4.5, 4.5], image_low=10.0), mask
    )


def test_own_thresholds_leave_out_hidden_segments_and_crossings():
    cue, _ = _dim_and_bright_cables()
    mask = cue >= 100
    dim = [np.array([[0.0, 58.0], [60.0, 58.0], [119.0, 58.0]])]
    # With its only seen half next to a crossing, the cable is not judged at all ...
    hidden = [np.array([True, False])]
    crossing = [(90.0, 58.0, 0, 0)]
    same = grow_by_own_thresholds(cue, mask, dim, [4.5], hidden, crossing, image_low=90.0)
    assert np.array_equal(same, mask)
    # ... while with the seen half in the open, only that half grows.
    grown = grow_by_own_thresholds(cue, mask, dim, [4.5], hidden, image_low=90.0)
    assert grown[52:65, 62:118].all() and np.array_equal(grown[:, :58], mask[:, :58])


@pytest.mark.parametrize("angle", [0.0, 17.0, 30.0, 45.0, 60.0, 90.0, 135.0])
def test_own_thresholds_grow_whole_rims_at_any_angle(angle):
    cue = np.zeros((160, 160), np.uint8)
    direction = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    ends = np.rint([[80.0, 80.0] - 70 * direction, [80.0, 80.0] + 70 * direction])
    line = [ends.astype(np.int32).reshape(-1, 1, 2)]
    cv2.polylines(cue, line, False, 60, 13)  # shaded rims ...
    cv2.polylines(cue, line, False, 120, 9)  # ... round a lit core
    mask = cue >= 100
    grown = grow_by_own_thresholds(cue, mask, [ends], [4.5], image_low=90.0)
    # Away from the ends, every rim pixel joins and nothing else does.
    x, y = np.meshgrid(np.arange(160), np.arange(160))
    along = np.abs((x - 80) * direction[0] + (y - 80) * direction[1])
    middle = along < 55
    assert np.array_equal(grown[middle], (cue > 0)[middle])


def test_a_callers_mask_is_not_grown():
    image = np.zeros((80, 120, 3), np.uint8)
    image[16:25, :] = 200
    image[52:65, :] = 60
    image[54:63, :] = 120
    mask = image[:, :, 0] >= 100
    assert np.array_equal(detect_full(image, mask=mask).mask, mask)
    # From the image alone, the dim cable's rims are part of the mask.
    assert detect_full(image).mask[52:65, 10:110].all()


def test_an_hsv_mask_is_not_grown():
    image = np.zeros((80, 120, 3), np.uint8)
    image[16:25, :] = (0, 0, 200)  # a red cable
    image[52:65, :] = (0, 0, 60)  # a dim red one with shaded rims
    image[54:63, :] = (0, 0, 120)
    params = DetectParams(
        segmentation=SegmentationMethod.hsv, hsv_low=(0, 100, 100), hsv_high=(10, 255, 255)
    )
    assert np.array_equal(detect_full(image, params).mask, segment(image, params))


# --------------------------------------------------------------------------- kernels


@pytest.mark.parametrize("seed", range(6))
def test_clean_mask_equals_the_reference(seed):
    mask = speckled_mask(seed)
    for min_area, max_hole in ((0, 0), (5, 0), (0, 6), (5, 6), (30, 40), (1000, 3)):
        np.testing.assert_array_equal(
            clean_mask(mask, min_area, max_hole), reference.clean_mask(mask, min_area, max_hole)
        )
    for edge_case in (np.zeros((9, 11), bool), np.ones((9, 11), bool)):
        np.testing.assert_array_equal(
            clean_mask(edge_case, 5, 6), reference.clean_mask(edge_case, 5, 6)
        )
    # Many specks: the whole-box lookup path.
    specks = np.random.default_rng(seed).random((60, 60)) < 0.05
    np.testing.assert_array_equal(clean_mask(specks, 3, 2), reference.clean_mask(specks, 3, 2))


@pytest.mark.parametrize("seed", range(4))
def test_histogram_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    cue = cv2.GaussianBlur((rng.random((70, 90)) * 255).astype(np.uint8), (5, 5), 0)
    np.testing.assert_array_equal(_histogram(cue), reference.histogram(cue))


def test_the_brightness_histogram_equals_a_count_of_the_largest_channel_on_any_size():
    # Eight interleaved 32-bit histograms: every tail length (sizes not a multiple of
    # eight), long runs of one level, every level, and an empty image.
    rng = np.random.default_rng(11)
    for trial in range(300):
        height, width = rng.integers(0, 40, size=2) if trial else (0, 5)
        image = rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)
        if trial % 3 == 0:
            image[: height // 2] = rng.integers(0, 256, size=3, dtype=np.uint8)
        brightness, counts = _segmentation_kernels.brightness_histogram(image)
        np.testing.assert_array_equal(brightness, image.max(axis=2))
        assert counts.dtype == np.int64
        np.testing.assert_array_equal(counts, np.bincount(image.max(axis=2).ravel(), minlength=256))


@pytest.mark.parametrize("seed", range(3))
def test_brightness_and_cleaning_equal_the_reference_on_scenes(seed):
    image = make_scene(seed=seed, width=320, height=240, n_cables=3).image
    brightness, counts = _segmentation_kernels.brightness_histogram(image)
    channels = cv2.split(image)
    np.testing.assert_array_equal(
        brightness, cv2.max(cv2.max(channels[0], channels[1]), channels[2])
    )
    np.testing.assert_array_equal(counts, reference.histogram(brightness))
    # Noisy thresholds of a real scene: many specks and holes, of every size.
    rng = np.random.default_rng(seed)
    mask = (brightness > np.median(brightness)) ^ (rng.random(brightness.shape) < 0.02)
    for min_area, max_hole in ((120, 60), (1, 1), (400, 0), (0, 400)):
        np.testing.assert_array_equal(
            clean_mask(mask, min_area, max_hole), reference.clean_mask(mask, min_area, max_hole)
        )


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("shape", [(80, 110), (37, 53)])
def test_threshold_and_clean_equals_hysteresis_then_clean_mask(seed, shape):
    # 37 x 53 px: an image whose pixel count is no multiple of 8 (the seeds are scanned
    # 8 at a time), with components and holes on its border.
    rng = np.random.default_rng(seed)
    cue = cv2.GaussianBlur((rng.random(shape) * 255).astype(np.uint8), (5, 5), 0)
    counts = np.bincount(cue.ravel(), minlength=256)
    for low, high in ((120.0, 135.0), (127.5, 127.5), (130.0, 125.0), (250.0, 254.0), (0.0, 10.0)):
        weak_count = int(counts[max(int(np.floor(low)) + 1, 0) :].sum())
        for min_area, max_hole in ((0, 0), (1, 1), (30, 12), (120, 60), (5000, 5)):
            fused = _segmentation_kernels.threshold_and_clean(
                cue, low, high, weak_count, min_area, max_hole
            )
            expected = reference.clean_mask(
                reference.hysteresis(cue, low, high), min_area, max_hole
            )
            np.testing.assert_array_equal(fused.view(bool), expected)


def test_the_first_level_above_both_thresholds_is_where_the_pixel_test_starts_to_pass():
    levels = np.arange(256, dtype=np.uint8)
    rng = np.random.default_rng(0)
    pairs = [(float(a), float(b)) for a, b in rng.uniform(-20.0, 280.0, (300, 2))]
    pairs += [(float(a), float(b)) for a, b in rng.integers(-2, 258, (200, 2))]
    pairs += [(np.nan, 100.0), (100.0, np.nan), (np.nan, np.nan), (-np.inf, np.inf)]
    pairs += [(254.5, -1.0), (255.0, 0.0), (-np.inf, -np.inf), (127.0, 127.0)]
    for low, high in pairs:
        passing = np.flatnonzero((levels > high) & (levels > low))
        expected = int(passing[0]) if passing.size else 256
        assert _segmentation_kernels.first_level_above(low, high) == expected, (low, high)
        # The test is monotone in the level: every level from the first passes.
        assert passing.size == 256 - expected


@pytest.mark.parametrize("seed", range(3))
def test_threshold_and_clean_equals_the_reference_on_many_random_images(seed):
    # Sizes on and off the seeds' blocks of 64 pixels (a short last block, images of
    # one row or column), noise, blurred noise and two-level images with components
    # and holes on every border, thresholds anywhere (NaN included).
    rng = np.random.default_rng(seed)
    for shape in ((0, 0), (0, 9), (9, 0)):
        empty = _segmentation_kernels.threshold_and_clean(
            np.zeros(shape, np.uint8), -1.0, -1.0, 0, 1, 1
        )
        assert empty.shape == shape
    for case in range(400):
        height, width = (int(n) for n in rng.integers(1, 70, 2))
        kind = case % 3
        if kind == 0:
            cue = rng.integers(0, 256, (height, width)).astype(np.uint8)
        elif kind == 1:
            cue = cv2.GaussianBlur(
                rng.integers(0, 256, (height, width)).astype(np.uint8), (5, 5), 0
            )
        else:
            bright = rng.random((height, width)) < rng.uniform(0.2, 0.8)
            cue = np.where(
                bright, rng.integers(150, 256, bright.shape), rng.integers(0, 120, bright.shape)
            )
            cue = cue.astype(np.uint8)
        low, high = (float(v) for v in rng.uniform(-10.0, 270.0, 2))
        if case % 7 == 0:
            low = float(rng.integers(0, 256))
            high = low + float(rng.integers(0, 3))
        if case % 41 == 0:
            low = np.nan
        weak_count = int(np.count_nonzero(cue > low))
        min_area = int(rng.choice([0, 1, 3, 30, 120]))
        max_hole = int(rng.choice([0, 1, 4, 12, 60]))
        fused = _segmentation_kernels.threshold_and_clean(
            cue, low, high, weak_count, min_area, max_hole
        )
        expected = reference.clean_mask(reference.hysteresis(cue, low, high), min_area, max_hole)
        np.testing.assert_array_equal(fused.view(bool), expected, err_msg=f"case {case}")


@pytest.mark.parametrize("seed", range(4))
def test_full_blocks_equal_opencvs_area_resize(seed):
    rng = np.random.default_rng(seed)
    for block in (3, 4, 5):
        height, width = block * rng.integers(3, 40, 2)
        # Shares near a half: many blocks exactly half set (OpenCV rounds those to 0).
        mask = (rng.random((height, width)) < rng.uniform(0.3, 0.7)).astype(np.uint8)
        found = _segmentation_kernels.full_blocks(mask, block)
        np.testing.assert_array_equal(found, reference.full_blocks(mask, block))
    half = np.zeros((8, 8), np.uint8)
    half[:2, :4] = 1  # the first 4 x 4 block exactly half set
    half[4:7, 4:] = 1  # the last three quarters
    assert _segmentation_kernels.full_blocks(half, 4).tolist() == [[0, 0], [0, 1]]


def test_full_blocks_of_four_equal_opencvs_area_resize_on_many_masks():
    # Blocks of 4 add each block's four column counts as one word: every count 0 to 4,
    # sums of exactly half (8 of 16, which OpenCV rounds to 0), and widths of an odd
    # number of blocks (the count words' last one short of the row's end).
    rng = np.random.default_rng(7)
    for _ in range(300):
        height, width = 4 * rng.integers(1, 30, 2)
        mask = (rng.random((height, width)) < rng.uniform(0.2, 0.8)).astype(np.uint8)
        found = _segmentation_kernels.full_blocks(mask, 4)
        np.testing.assert_array_equal(found, reference.full_blocks(mask, 4))
    every = np.zeros((4, 4 * 17), np.uint8)
    for count in range(17):  # block k has its first k pixels set, row by row
        block = np.zeros(16, np.uint8)
        block[:count] = 1
        every[:, 4 * count : 4 * count + 4] = block.reshape(4, 4)
    expected = [[int(2 * count > 16) for count in range(17)]]
    assert _segmentation_kernels.full_blocks(every, 4).tolist() == expected


@pytest.mark.parametrize("seed", range(6))
def test_own_threshold_kernels_equal_the_reference(seed):
    rng = np.random.default_rng(seed)
    height, width = 60, 80
    cue = cv2.GaussianBlur(rng.integers(0, 256, (height, width)).astype(np.uint8), (5, 5), 0)
    before = cue > np.percentile(cue, 70)
    points = np.cumsum(rng.normal(0.0, 6.0, (7, 2)), axis=0) + np.array([width, height]) / 2
    points[3] = points[2]  # a zero-length segment
    seen = rng.random(len(points) - 1) > 0.25
    avoid_xy = rng.uniform(0, [width, height], (2, 2))
    avoid_reach = rng.uniform(3.0, 12.0, 2)
    span, stride, start, reach = 7, 1 + seed % 3, seed % 3, 4
    low = float(rng.integers(60, 200))
    hist, feet = _segmentation_kernels.profile_histogram(
        cue, points, seen, avoid_xy, avoid_reach, span, stride
    )
    want_hist, want_feet = reference.profile_histogram(
        cue, points, seen, avoid_xy, avoid_reach, span, stride
    )
    assert feet == want_feet and np.array_equal(hist, want_hist)
    grown = before.view(np.uint8).copy()
    _segmentation_kernels.grow_along_profiles(
        cue, before.view(np.uint8), grown, points, seen, avoid_xy, avoid_reach, start, reach, low
    )
    want = reference.grow_along_profiles(
        cue, before, points, seen, avoid_xy, avoid_reach, start, reach, low
    )
    assert np.array_equal(grown.view(bool), want)


@pytest.mark.parametrize("seed", range(8))
def test_otsu_kernel_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    hists = [
        rng.integers(0, 1000, 256).astype(np.float64),
        np.bincount(rng.integers(0, 256, 5000), minlength=256).astype(np.float64),
    ]
    # Two classes with an empty stretch between them (a plateau of equal thresholds),
    # and a histogram of one level.
    gapped = np.zeros(256)
    gapped[rng.integers(0, 60, 300)] += 1
    gapped[rng.integers(150, 256, 100)] += 1
    single = np.zeros(256)
    single[rng.integers(0, 256)] = 7
    for hist in [*hists, gapped, single]:
        threshold, separability = _segmentation_kernels.otsu_kernel(hist)
        want_threshold, want_separability = reference.otsu(hist)
        assert threshold == want_threshold
        assert separability == pytest.approx(want_separability, rel=1e-12, abs=1e-15)
