"""Step 4, fitting: junction zones and chains of l_s segments, and their kernels."""

import numpy as np
import pytest

from service.perception.contours import extract_contours
from service.perception.fitting import fit_chains, junction_zones
from service.perception.skeleton import remove_spurs, skeletonize
from tests.perception.cases import INPUTS, assert_same_chains, thick_polylines
from tests.perception.references import steps


def _line_skeleton():
    """A one-pixel line from x = 5 to x = 105 on row 10: tips at both ends."""
    skeleton = np.zeros((20, 120), bool)
    skeleton[10, 5:106] = True
    return skeleton


def test_joints_are_one_segment_length_apart_from_tip_to_tip():
    skeleton = _line_skeleton()
    chains = fit_chains(extract_contours(skeleton), skeleton, np.zeros_like(skeleton), 10)
    assert len(chains) == 2  # the contour walks the line out and back
    for joints in chains:
        assert np.all(joints[:, 1] == 10)
        assert np.all(np.abs(np.diff(joints[:, 0])) == 10)
        assert {joints[0, 0], joints[-1, 0]} == {5, 105}


def test_chains_end_at_tips_and_stop_short_of_junction_zones():
    skeleton = _line_skeleton()
    zones = np.zeros_like(skeleton)
    zones[8:13, 50:60] = True
    chains = fit_chains(extract_contours(skeleton), skeleton, zones, 10)
    extents = sorted((float(j[:, 0].min()), float(j[:, 0].max())) for j in chains)
    # Each side of the zone, out and back; no joint inside the zone.
    assert extents == [(5, 49), (5, 49), (60, 105), (60, 105)]


def test_junction_zones_cover_a_crossing_but_not_the_arms():
    mask = thick_polylines((200, 200), [[(20, 20), (180, 180)], [(20, 180), (180, 20)]], 9)
    skeleton = remove_spurs(skeletonize(mask), 12)
    zones = junction_zones(skeleton, 4.5)
    assert zones[100, 100]
    assert not zones[40, 40] and not zones[160, 40]


# --------------------------------------------------------------------------- kernels


@pytest.mark.parametrize("name", sorted(INPUTS))
def test_zones_and_chains_equal_the_reference(name):
    expected = steps.on_input(name)
    skeleton = expected.pruned_skeleton
    zones = junction_zones(skeleton, expected.radius)
    assert zones.dtype == bool
    np.testing.assert_array_equal(zones, expected.zones)
    pieces = fit_chains(extract_contours(skeleton), skeleton, zones, 10.0)
    assert_same_chains(pieces, expected.pieces)


def test_chains_with_short_segments_equal_the_reference():
    expected = steps.on_input("random3", segment_length=3.0)
    skeleton = expected.pruned_skeleton
    pieces = fit_chains(extract_contours(skeleton), skeleton, expected.zones, 3.0)
    assert_same_chains(pieces, expected.pieces)
