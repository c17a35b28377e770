"""The tracker's kernels that stand in for NumPy code give its bits exactly (the
tracker's output must not change by a last bit when its arithmetic is compiled)."""

from __future__ import annotations

import numpy as np
import pytest

from service.perception import _tracking_kernels as kernels
from service.perception.geometry import distances_to_polyline, rigid_fit
from service.perception.track_motion import motion, tangents
from service.perception.track_update import _rigid
from service.perception.tracking_warm_up import warm_up_tracking
from tests.perception.references import tracking as reference


@pytest.fixture(scope="module", autouse=True)
def _kernels_loaded():
    warm_up_tracking()


def wavy_chain(rng, n):
    heading = rng.uniform(0, 2 * np.pi) + np.cumsum(rng.normal(0, 0.2, n - 1))
    steps = 10.0 * np.column_stack([np.cos(heading), np.sin(heading)])
    start = rng.uniform(0, 600, 2)
    return np.vstack([start, start + np.cumsum(steps, axis=0)])


@pytest.mark.parametrize("seed", range(6))
def test_rigid_motion_of_points_is_numpys_to_the_bit(seed):
    rng = np.random.default_rng(seed)
    for n in (1, 2, 3, 6, 9, 40):
        source = wavy_chain(rng, n)
        target = source + rng.normal(0, 3, source.shape) + rng.normal(0, 20, 2)
        points = wavy_chain(rng, 7)
        mean, rotation, target_mean = rigid_fit(source, target)
        if n == 1:
            expected = points + (target.mean(axis=0) - source.mean(axis=0))
        else:
            expected = (points - mean) @ rotation.T + target_mean
        assert np.array_equal(_rigid(source, target, points), expected)


@pytest.mark.parametrize("seed", range(8))
def test_motion_is_numpys_to_the_bit(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(4, 90))
    previous = wavy_chain(rng, n)
    current = previous + rng.normal(0, 2, previous.shape) + rng.normal(0, 5, 2)
    use = rng.uniform(size=n) < 0.8
    use[:3] = True
    rigid_only = np.zeros(n, bool)
    rigid_only[: int(rng.integers(0, 3))] = True
    pinned = [(0, rng.normal(0, 4, 2))] if seed % 2 else []
    tangent = tangents(current)
    expected = reference.motion_numpy(previous, current, use, pinned, tangent, rigid_only)
    assert np.array_equal(motion(previous, current, use, pinned, tangent, rigid_only), expected)


@pytest.mark.parametrize("seed", range(6))
def test_piece_samples_are_numpys_to_the_bit(seed):
    rng = np.random.default_rng(200 + seed)
    for n in (2, 3, 4, 17, 120):
        joints = wavy_chain(rng, n)
        joints[n // 2] = joints[n // 2 - 1]  # a segment of no length
        for got, expected in zip(
            kernels.piece_samples(joints), reference.piece_samples(joints), strict=True
        ):
            assert np.array_equal(got, expected)


@pytest.mark.parametrize("seed", range(4))
def test_farthest_from_polyline_is_numpys_to_the_bit(seed):
    rng = np.random.default_rng(300 + seed)
    for n in (2, 3, 30):
        polyline = wavy_chain(rng, n)
        polyline[1] = polyline[0]  # a segment of no length
        points = polyline[: int(rng.integers(1, n + 1))] + rng.normal(0, 6, (1, 2))
        expected = distances_to_polyline(points, polyline).max()
        assert kernels.farthest_from_polyline(points, polyline) == expected


@pytest.mark.parametrize("seed", range(4))
def test_tangents_are_numpys_to_the_bit(seed):
    rng = np.random.default_rng(400 + seed)
    for n in (2, 3, 50):
        joints = wavy_chain(rng, n)
        joints[-1] = joints[-2]  # a segment of no length
        assert np.array_equal(tangents(joints), reference.unit_tangents(joints))
    assert tangents(np.zeros((1, 2))).shape == (1, 2)
