"""Step 5, pruning: one chain per skeleton branch, and its kernels."""

import numpy as np
import pytest

from service.perception import _pruning_kernels
from service.perception.contours import extract_contours
from service.perception.fitting import fit_chains, junction_zones
from service.perception.geometry import polyline_length
from service.perception.pruning import prune_overlaps
from service.perception.skeleton import remove_spurs, skeletonize
from tests.perception.cases import INPUTS, assert_same_chains, thick_polylines
from tests.perception.references import pruning as reference
from tests.perception.references import steps


def test_fitting_and_pruning_give_one_chain_per_branch():
    mask = thick_polylines((80, 200), [[(20, 40), (180, 40)]], 9)
    skeleton = remove_spurs(skeletonize(mask), 12)
    zones = junction_zones(skeleton, 4.5)
    pieces = fit_chains(extract_contours(skeleton), skeleton, zones, 10)
    assert len(pieces) == 2  # the contour walks the branch twice
    kept = prune_overlaps(pieces, mask.shape)
    assert len(kept) == 1
    assert polyline_length(kept[0]) == pytest.approx(polyline_length(pieces[0]), rel=0.05)


# --------------------------------------------------------------------------- kernels


@pytest.mark.parametrize("name", sorted(INPUTS))
def test_pruning_equals_the_reference(name):
    expected = steps.on_input(name)
    assert_same_chains(prune_overlaps(expected.pieces, INPUTS[name].shape), expected.kept)


def test_chain_lengths_add_up_like_numpy():
    rng = np.random.default_rng(0)
    arrays = [rng.random((n, 2)) * 300 for n in (0, 1, 2, 7, 8, 9, 130, 300, 1100)]
    ends = np.cumsum([len(a) for a in arrays])
    lengths = _pruning_kernels.chain_lengths(np.concatenate(arrays), ends)
    assert list(lengths) == [reference.chain_length(a) for a in arrays]
