"""Polyline helpers: resampling to exact chords and end directions, and their kernels."""

import numpy as np
import pytest

from service.perception import _geometry_kernels
from service.perception.geometry import (
    arc_lengths,
    end_direction,
    end_fit,
    fit_where_skipped,
    median,
    polyline_length,
    resample,
)
from tests.perception.references import geometry as reference


def test_resample_gives_exact_chord_lengths():
    t = np.linspace(0, np.pi, 400)
    arc = np.stack([100 + 50 * np.cos(t), 100 + 50 * np.sin(t)], axis=1)
    joints, _ = resample(arc, 10.0)
    steps = np.linalg.norm(np.diff(joints, axis=0), axis=1)
    assert np.allclose(steps[:-1], 10.0, atol=1e-9)
    assert steps[-1] <= 10.0 + 1e-9
    assert np.allclose(joints[-1], arc[-1])


def test_end_direction_points_outwards():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    assert np.allclose(end_direction(line, at_start=False, span=15), [1, 0])
    assert np.allclose(end_direction(line, at_start=True, span=15), [-1, 0])


@pytest.mark.parametrize("seed", range(4))
def test_resample_kernel_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    for _ in range(50):
        points = np.cumsum(rng.normal(0, 3, (rng.integers(2, 50), 2)), axis=0) + 400.0
        step = float(rng.uniform(1.0, 12.0))
        joints, edges = _geometry_kernels.resample_kernel(points, step)
        expected_joints, expected_edges = reference.resample(points, step)
        np.testing.assert_array_equal(joints, expected_joints)
        np.testing.assert_array_equal(edges, expected_edges)
        full_joints, _ = resample(points, step)
        np.testing.assert_array_equal(full_joints[: len(joints)], joints)


@pytest.mark.parametrize("radius", [15.0, 40.0, 120.0])
def test_end_fit_measures_the_curvature_of_a_circle_travelled_outwards(radius):
    """Anticlockwise in image axes (x right, y down: from +x towards +y) the outward
    travel through the last point turns positive; through the first point, negative.
    (A quadratic fit over the stretch reads a circle's curvature a few per cent low.)"""
    t = np.linspace(0.0, 1.5, 200)
    arc = np.stack([200 + radius * np.cos(t), 200 + radius * np.sin(t)], axis=1)
    _, direction, at_last = end_fit(arc, False, 0.5 * radius)
    _, _, at_first = end_fit(arc, True, 0.5 * radius)
    assert at_last == pytest.approx(1.0 / radius, rel=0.12)
    assert at_first == pytest.approx(-1.0 / radius, rel=0.12)
    np.testing.assert_allclose(direction, [-np.sin(1.5), np.cos(1.5)], atol=0.02)
    straight = np.stack([np.linspace(0, 50, 30), np.full(30, 7.0)], axis=1)
    assert end_fit(straight, False, 20.0)[2] == pytest.approx(0.0, abs=1e-9)


def test_the_fit_where_the_skipped_tip_ends_lies_on_a_bend_and_follows_it():
    """On a circle of radius 60 with joints 10 px apart, the fit evaluated 8 px in from
    the end lies on the circle and points along it; with nothing skipped there is none."""
    angles = np.arange(0.0, 1.2, 10.0 / 60.0)
    arc = np.column_stack([60 * np.cos(angles), 60 * np.sin(angles)])
    position, direction = fit_where_skipped(arc, False, 40.0, 8.0)
    assert np.hypot(*position) == pytest.approx(60.0, abs=0.1)
    along = np.array([-position[1], position[0]]) / 60.0  # the circle's tangent there
    assert float(direction @ along) == pytest.approx(1.0, abs=1e-3)
    assert fit_where_skipped(arc, False, 40.0, 0.0) is None


@pytest.mark.parametrize("seed", range(3))
def test_arc_length_kernels_equal_the_references_bit_for_bit(seed):
    # Lengths past NumPy's blocks of 128 (summed pairwise), and the polylines the
    # kernels are not compiled for (views, reversed, integer, a list), which take NumPy.
    rng = np.random.default_rng(seed)
    for count in [*range(0, 20), 127, 128, 129, 130, 257, 300, 1000]:
        points = np.cumsum(rng.normal(size=(count, 2)) * rng.uniform(0.1, 30.0), axis=0) + 300.0
        expected_arcs = reference.arc_lengths(points)
        for variant in (points, points[::-1], np.asfortranarray(points), points.tolist()):
            assert polyline_length(variant) == reference.polyline_length(variant)
        np.testing.assert_array_equal(arc_lengths(points), expected_arcs)
        np.testing.assert_array_equal(
            arc_lengths(points[::-1]), reference.arc_lengths(points[::-1])
        )
        if count >= 2:
            assert _geometry_kernels.polyline_length(points) == reference.polyline_length(points)
            np.testing.assert_array_equal(_geometry_kernels.arc_lengths(points), expected_arcs)
    pixels = rng.integers(0, 500, (40, 2))
    assert polyline_length(pixels) == reference.polyline_length(pixels)
    np.testing.assert_array_equal(arc_lengths(pixels), reference.arc_lengths(pixels))


@pytest.mark.parametrize("seed", range(3))
def test_median_is_numpys_bit_for_bit(seed):
    # Odd and even counts, float32 (distances: the two middle values halved in float32)
    # and float64, ties and values far apart.
    rng = np.random.default_rng(seed)
    for count in [*range(1, 12), 63, 64, 1000, 1001]:
        for dtype in (np.float32, np.float64):
            for values in (
                rng.normal(size=count) * rng.uniform(0.1, 1e6),
                rng.integers(0, 4, count) * 1.4,
                np.full(count, 2.1969),
            ):
                values = values.astype(dtype)
                kept = values.copy()
                found, expected = median(values), np.median(values)
                assert found.dtype == expected.dtype and found == expected
                np.testing.assert_array_equal(values, kept)  # not reordered
