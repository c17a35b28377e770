"""Plain junction zones and fitting (step 4): cut each contour into runs, walk each run."""

import cv2
import numpy as np

from service.perception.fitting import BRIDGE_RADII
from tests.perception.references.skeleton import branch_counts


def junction_zones(skeleton, radius):
    junctions = (branch_counts(skeleton) >= 3).astype(np.uint8)
    if not junctions.any():
        return np.zeros_like(skeleton, dtype=bool)
    zone_radius = max(2, round(1.5 * radius))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * zone_radius + 1,) * 2)
    zones = cv2.dilate(junctions, disc) > 0
    outside = (skeleton & ~zones).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(outside, connectivity=8)
    if count > 1:
        tips = branch_counts(skeleton) == 1
        has_tip = np.zeros(count, bool)
        has_tip[np.unique(labels[tips & (labels > 0)])] = True
        short = (stats[:, cv2.CC_STAT_AREA] < BRIDGE_RADII * radius) & ~has_tip
        short[0] = False
        zones |= short[labels]
    return zones


def walk_joints(pixels: np.ndarray, segment_length: float) -> np.ndarray:
    """Joints along an ordered pixel run, each ``segment_length`` from the previous one.

    The first and last pixels are always joints, so the last segment may be shorter.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    joints = [pixels[0]]
    start = pixels[0]
    limit_sq = segment_length * segment_length
    for point in pixels[1:]:
        delta = point - start
        if delta[0] * delta[0] + delta[1] * delta[1] >= limit_sq:
            joints.append(point)
            start = point
    if len(pixels) > 1 and not np.array_equal(joints[-1], pixels[-1]):
        joints.append(pixels[-1])
    return np.array(joints)


def split_contour(contour: np.ndarray, is_tip: np.ndarray, in_zone: np.ndarray):
    """Cut a closed contour into runs that end at tips and stop short of junction zones.

    ``is_tip`` and ``in_zone`` are per contour pixel; the runs come out in walking order.
    """
    n = len(contour)
    breaks = np.flatnonzero(is_tip | in_zone)
    if len(breaks) == 0:
        # A closed loop with no tip or junction: one run around it.
        return [contour]
    # Start the cyclic walk at a break so that no run wraps around the array end.
    order = np.roll(np.arange(n), -int(breaks[0]))
    runs: list[np.ndarray] = []
    current: list[int] = []
    for index in order:
        if in_zone[index]:
            if len(current) > 1:
                runs.append(contour[current])
            current = []
        elif is_tip[index]:
            current.append(index)
            if len(current) > 1:
                runs.append(contour[current])
            current = [index]
        else:
            current.append(index)
    if len(current) > 1:
        first_break = order[0]
        if is_tip[first_break] and not in_zone[first_break]:
            current.append(first_break)
        runs.append(contour[current])
    return runs


def fit_chains(contours, skeleton, zones, segment_length):
    tips = branch_counts(skeleton) == 1
    chains = []
    for contour in contours:
        xs, ys = contour[:, 0], contour[:, 1]
        for run in split_contour(contour, tips[ys, xs], zones[ys, xs]):
            chains.append(walk_joints(run, segment_length))
    return chains
