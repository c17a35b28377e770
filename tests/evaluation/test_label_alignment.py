import cv2
import numpy as np
import pytest

from service.evaluation.label_alignment import (
    facing_angles,
    half_way_borders,
    interval_dice,
    normal_samples,
    run_borders,
    summarize,
)


def paper_with_a_cable(columns=(40, 48), size=(100, 100)):
    """White paper with a dark vertical cable over ``columns`` (end exclusive)."""
    image = np.full((*size, 3), 220, np.uint8)
    image[:, columns[0] : columns[1]] = 40
    return image


def band(columns, size=(100, 100), label=1):
    labels = np.zeros(size, np.uint8)
    labels[:, columns[0] : columns[1]] = label
    return labels


def test_run_borders_interpolates_where_the_profile_falls_to_one_half():
    profile = np.array([0.0, 0.0, 1.0, 1.0, 1.0, 0.5, 0.0])
    low, high = run_borders(profile, 3)
    assert low == pytest.approx(1.5)
    assert high == pytest.approx(5.0)
    assert np.isnan(run_borders(profile, 0)).all()
    assert np.isnan(run_borders(np.ones(5), 2)[0])


def test_half_way_borders_are_where_a_blurred_edge_crosses():
    offsets = np.arange(-12.0, 12.25, 0.5)
    # A cable from -3 to +3 with edges ramped over 2 px (blur), on paper.
    lightness = np.interp(np.abs(offsets), [3.0 - 1.0, 3.0 + 1.0], [20.0, 90.0])
    colours = np.stack([lightness, np.zeros_like(offsets), np.zeros_like(offsets)], axis=1)
    low, high = half_way_borders(colours, offsets, centre=0.5)
    assert low == pytest.approx(-3.0, abs=0.05)
    assert high == pytest.approx(3.0, abs=0.05)


def test_interval_dice():
    one = np.array([[0.0, 8.0], [0.0, 8.0], [0.0, 4.0]])
    two = np.array([[0.0, 8.0], [2.0, 10.0], [5.0, 9.0]])
    np.testing.assert_allclose(interval_dice(one, two), [1.0, 0.75, 0.0])


def test_labels_two_pixels_off_the_cable_are_measured_as_such():
    image = paper_with_a_cable((40, 48))
    labels = band((38, 46))  # drawn two pixels left of the cable
    mask = band((40, 48)) > 0  # a mask that follows the photograph
    samples = normal_samples(image, labels, mask)
    assert len(samples.points) > 20
    # Normals point right (+x); the photograph's borders lie 2 px right of the labels'.
    np.testing.assert_allclose(samples.image - samples.truth, 2.0, atol=0.05)
    np.testing.assert_allclose(samples.mask, samples.image, atol=0.05)
    summary = summarize(samples)
    assert summary["offset median"] == pytest.approx(2.0, abs=0.05)
    assert summary["width image"] == pytest.approx(8.0, abs=0.05)
    assert summary["mask~image"] == pytest.approx(1.0, abs=0.01)
    assert summary["mask~truth"] == pytest.approx(0.75, abs=0.01)
    assert summary["image~truth"] == pytest.approx(0.75, abs=0.01)
    # The labels reach 2 px beyond the photograph on the side facing left (180 degrees)
    # and stop 2 px short of it on the side facing right (0 degrees).
    assert summary["truth beyond 180"] == pytest.approx(2.0, abs=0.05)
    assert summary["truth beyond 0"] == pytest.approx(-2.0, abs=0.05)
    assert summary["mask beyond 0"] == pytest.approx(0.0, abs=0.05)


def test_a_mask_that_takes_a_shadow_reaches_out_on_the_shadow_side_only():
    image = paper_with_a_cable((40, 48))
    image[:, 48:51] = 150  # a shadow to the right, darker paper
    labels = band((40, 48))
    mask = band((40, 51)) > 0
    summary = summarize(normal_samples(image, labels, mask))
    # The shadow is darker than the paper, so the half-way colour lies a little into it.
    assert 2.5 < summary["mask beyond 0"] <= 3.0
    assert summary["mask beyond 180"] == pytest.approx(0.0, abs=0.05)
    assert summary["image~truth"] == pytest.approx(1.0, abs=0.03)


def test_no_samples_beside_another_cable_or_where_labels_are_left_out():
    image = paper_with_a_cable((40, 48))
    labels = band((40, 48)) + band((56, 62), label=2)  # another cable 8 px beside
    samples = normal_samples(image, labels, labels > 0)
    assert len(samples.points) == 0
    assert summarize(samples) == {"samples": 0.0}
    labels = band((40, 48))
    labels[45:55, :] = 255
    ignore = labels == 255
    samples = normal_samples(image, labels, labels > 0, ignore)
    assert len(samples.points) > 0
    assert (np.abs(samples.points[:, 1] - 50) >= 12).all()


def test_facing_angles_of_a_diagonal_cable():
    image = np.full((120, 120, 3), 220, np.uint8)
    cv2.line(image, (10, 10), (110, 110), (40, 40, 40), 7)
    labels = np.zeros((120, 120), np.uint8)
    cv2.line(labels, (10, 10), (110, 110), 1, 7)
    samples = normal_samples(image, labels, labels > 0)
    assert len(samples.points) > 5
    # The cable runs down to the right: its negative side faces down-left, its positive up-right.
    np.testing.assert_allclose(
        facing_angles(samples), [[135.0, 315.0]] * len(samples.points), atol=1.0
    )


def test_sizes_must_agree():
    with pytest.raises(ValueError, match="one size"):
        normal_samples(
            np.zeros((10, 10, 3), np.uint8), np.zeros((10, 12), np.uint8), np.zeros((10, 10), bool)
        )
