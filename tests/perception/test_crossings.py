"""Crossings: the segment sweep and the centreline profiles, against plain code."""

import numpy as np
import pytest

from service.perception.crossings import find_intersections, profile_variations
from service.synthetic import make_scene
from tests.perception.references import crossings as reference


@pytest.mark.parametrize("seed", range(4))
def test_intersection_kernel_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    chains = [
        np.cumsum(rng.normal(0, 6, (int(rng.integers(2, 40)), 2)), axis=0) + 100.0 for _ in range(4)
    ]
    chains.append(np.array([[0.0, 100.0], [200.0, 100.0], [0.0, 100.0]]))  # collinear
    found, expected = find_intersections(chains), reference.find_intersections(chains)
    assert [f[:4] for f in found] == [e[:4] for e in expected]
    for f, e in zip(found, expected, strict=True):
        np.testing.assert_array_equal(f[4], e[4])


def test_crossing_profiles_on_patches_equal_the_whole_image():
    image = make_scene(320, 180, 3, seed=2).image
    rng = np.random.default_rng(0)
    for _ in range(40):
        # Most lines lie inside; some reach the border and use the whole image.
        centre = rng.uniform([0, 0], [320, 180])
        angle = rng.uniform(0, np.pi)
        lines = [(centre, np.array([np.cos(a), np.sin(a)]), 7.5) for a in (angle, angle + 1.0)]
        values, _ = profile_variations(image, lines)
        assert values == [reference.profile_variation(image, *line) for line in lines]
