"""Steps 2 to 5 by the references, on the shared inputs (each computed once a session)."""

import functools
from typing import NamedTuple

import numpy as np

from service.perception.contours import extract_contours
from tests.perception.cases import INPUTS
from tests.perception.references import fitting, pruning, skeleton


class ReferenceSteps(NamedTuple):
    skeleton: np.ndarray
    radius: float
    pruned_skeleton: np.ndarray
    zones: np.ndarray
    pieces: list[np.ndarray]
    kept: list[np.ndarray]


def run(mask: np.ndarray, segment_length: float = 10.0) -> ReferenceSteps:
    """Thinning, radius, spurs, zones, fitting and pruning of ``mask``, all plain."""
    thinned = skeleton.thin(mask)
    radius = max(skeleton.estimate_radius(mask, thinned), 1.0)
    pruned_skeleton = skeleton.remove_spurs(thinned, 2.5 * radius)
    contours = extract_contours(pruned_skeleton)
    zones = fitting.junction_zones(pruned_skeleton, radius)
    pieces = fitting.fit_chains(contours, pruned_skeleton, zones, segment_length)
    kept = pruning.prune_overlaps(pieces, mask.shape)
    return ReferenceSteps(thinned, radius, pruned_skeleton, zones, pieces, kept)


@functools.cache
def on_input(name: str, segment_length: float = 10.0) -> ReferenceSteps:
    """:func:`run` on ``INPUTS[name]`` (the plain thinning is slow: once is enough)."""
    return run(INPUTS[name], segment_length)
