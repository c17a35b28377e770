"""The six-step detection pipeline, from an image (or a mask) to a Detection."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from schemas import Chain, Crossing, Detection, DetectParams, StageTimings
from service.perception import _kernels
from service.perception.contours import extract_contours
from service.perception.crossings import detect_crossings
from service.perception.errors import InvalidInputError
from service.perception.fitting import fit_chains, junction_zones
from service.perception.geometry import end_direction, polyline_length, resample
from service.perception.merging import Join, MergedPath, merge_chains
from service.perception.pruning import prune_overlaps
from service.perception.segmentation import (
    as_bgr,
    clean_mask,
    grow_by_own_thresholds,
    segment_with_cue,
    validate_mask,
)
from service.perception.skeleton import (
    as_uint8,
    distance_transform,
    estimate_radius,
    remove_spurs,
    skeletonize,
)


@dataclass(frozen=True)
class DetectionResult:
    """A detection together with the intermediate products a caller may want.

    Attributes
    ----------
    detection : Detection
        The wire-contract result.
    mask : ndarray of bool
        The foreground mask the chains were found in (for :func:`render_labels`).
    skeleton : ndarray of bool
        The pruned skeleton.
    joins : list of Join
        The joins the merging step made, cheapest first.
    """

    detection: Detection
    mask: np.ndarray
    skeleton: np.ndarray
    joins: list[Join] = field(default_factory=list)


class _Stopwatch:
    def __init__(self):
        self.times: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.times[stage] = self.times.get(stage, 0.0) + (now - self._last) * 1000.0
        self._last = now


def _extend_end(points: np.ndarray, at_start: bool, mask, radius: float, span: float):
    """Push a chain end out to where the cable ends in the mask, less one radius.

    Thinning stops about one radius short of a square-cut cable end; a grasp at "the
    end" should still be on the cable, so the end is placed one radius inside: along
    the end's direction to where the mask stops, or, when it is farther, toward the
    farthest pixel of the cable within 35 degrees ahead. A cable that runs out of the
    picture does not end there: its chain goes to the edge.
    """
    direction = end_direction(points, at_start, span)
    tip = points[0] if at_start else points[-1]
    height, width = mask.shape
    reach = 0.0
    limit = 3.0 * radius + 2.0
    leaves_image = False
    while reach < limit:
        probe = tip + (reach + 1.0) * direction
        col, row = round(probe[0]), round(probe[1])
        if not (0 <= col < width and 0 <= row < height):
            leaves_image = True
            break
        if not mask[row, col]:
            break
        reach += 1.0
    extension = reach if leaves_image else reach - radius
    if not leaves_image:
        # A curving end, or one whose tip fork fell to spur removal, leaves the straight
        # walk through the side of the cap: the farthest pixel of the cable ahead marks
        # the end better.
        far = _farthest_ahead(tip, direction, mask, TIP_SEARCH_RADII * radius + 2.0)
        if far is not None:
            offset = far - tip
            length = float(np.hypot(*offset))
            if length - radius > extension:
                direction = offset / length
                extension = length - radius
    if extension < 1.0:
        return points
    new_tip = tip + extension * direction
    return np.vstack([new_tip, points]) if at_start else np.vstack([points, new_tip])


# At most this many extensions of a free end, each from where the last one stopped.
END_EXTENSION_ROUNDS = 3
# How far ahead of a free chain end (in radii) and within which angle of its direction
# the cable's farthest pixel is looked for.
TIP_SEARCH_RADII = 5.0
TIP_SEARCH_COS = float(np.cos(np.radians(35.0)))
FAR_RIM_PX = 2.0


def _farthest_ahead(tip, direction, mask, limit, cos_half_angle=TIP_SEARCH_COS):
    """The middle of the mask's farthest rim from ``tip``: the pixels at most ``limit``
    px away, within the cone of ``cos_half_angle`` round ``direction`` and connected to
    the tip through the mask near it, that lie within FAR_RIM_PX of the largest
    distance (the middle, so the corners of a square-cut end do not pull the end
    sideways). None when there is none. Compiled: the plain version is the reference in
    tests/perception.
    """
    found, x, y = _kernels.farthest_rim_ahead(
        as_uint8(mask),
        round(float(tip[0])),
        round(float(tip[1])),
        float(tip[0]),
        float(tip[1]),
        float(direction[0]),
        float(direction[1]),
        float(limit),
        float(cos_half_angle),
        FAR_RIM_PX,
    )
    return np.array([x, y]) if found else None


def _finalise_path(path: MergedPath, mask, distance, params: DetectParams, radius: float):
    """Resample a merged path to joints exactly ``l_s`` apart, with per-segment flags."""
    vertices, filled = path.vertices, path.filled
    span = max(2.0 * params.segment_length, 3.0 * radius)
    # End extensions are seen cable (they lie on the mask). An extension that ends at its
    # search limit still inside the cable (a thin cable whose skeleton stopped several
    # widths short of its tip) goes on from its new tip; once at the end it adds nothing.
    for at_start in (True, False):
        for _ in range(END_EXTENSION_ROUNDS):
            extended = _extend_end(vertices, at_start, mask, radius, span)
            added = len(extended) - len(vertices)
            if added == 0:
                break
            flags = np.zeros(added, bool)
            filled = np.concatenate([flags, filled] if at_start else [filled, flags])
            vertices = extended
    height, width = mask.shape
    # A filled edge across foreground (a crossing) is seen; across background, hidden.
    midpoints = 0.5 * (vertices[:-1] + vertices[1:])
    cols = np.clip(np.rint(midpoints[:, 0]).astype(int), 0, width - 1)
    rows = np.clip(np.rint(midpoints[:, 1]).astype(int), 0, height - 1)
    hidden_edge = filled & ~mask[rows, cols]
    joints, source_edge = resample(vertices, params.segment_length)
    edge_lengths = np.linalg.norm(np.diff(vertices, axis=0), axis=1)
    # Inferred where more than half the length of the edges a segment spans is hidden.
    inferred = _kernels.inferred_segments(
        source_edge.astype(np.int64),
        np.ascontiguousarray(edge_lengths, np.float64),
        np.ascontiguousarray(hidden_edge, bool),
    )
    cols = np.clip(np.rint(joints[:, 0]).astype(int), 0, width - 1)
    rows = np.clip(np.rint(joints[:, 1]).astype(int), 0, height - 1)
    on_cable = distance[rows, cols] > 0
    chain_radius = (
        max(float(np.median(distance[rows, cols][on_cable])) - 0.5, 0.5)
        if on_cable.any()
        else radius
    )
    return joints, inferred, chain_radius


def _empty(width, height, params, watch, mask, skeleton) -> DetectionResult:
    watch.times["total"] = sum(watch.times.values())
    detection = Detection(
        width=width,
        height=height,
        segment_length=params.segment_length,
        timings_ms=StageTimings(**watch.times),
    )
    return DetectionResult(detection, mask, skeleton)


def detect_full(
    image: np.ndarray | None,
    params: DetectParams | None = None,
    mask: np.ndarray | None = None,
) -> DetectionResult:
    """Detect every DLO in an image and return the intermediate products too.

    Same as :func:`detect`, but returns a :class:`DetectionResult` holding the mask,
    the skeleton and the joins as well as the :class:`schemas.Detection`.

    Examples
    --------
    >>> import cv2, numpy as np
    >>> image = np.zeros((120, 200, 3), np.uint8)
    >>> _ = cv2.line(image, (10, 60), (190, 60), (0, 200, 255), 9)
    >>> result = detect_full(image)
    >>> len(result.detection.chains), result.mask.shape, bool(result.mask[60, 100])
    (1, (120, 200), True)
    """
    started = time.perf_counter()
    params = DetectParams() if params is None else params
    if not isinstance(params, DetectParams):
        raise InvalidInputError(f"params must be a DetectParams, not {type(params).__name__}")
    watch = _Stopwatch()
    image_bgr = None
    if image is None:
        if mask is None:
            raise InvalidInputError("give an image, a mask, or both")
        shape = np.asarray(mask).shape[:2]
    else:
        image_bgr = as_bgr(image)
        shape = image_bgr.shape[:2]
    height, width = shape

    # 1. Segmentation (the caller's mask gets the same clean-up as our own).
    cue, image_low = None, np.inf
    if mask is not None:
        foreground = clean_mask(
            validate_mask(mask, shape), params.min_component_area, params.max_hole_area
        )
    else:
        foreground, cue, image_low = segment_with_cue(image_bgr, params)
    watch.lap("segmentation")
    if not foreground.any():
        return _empty(width, height, params, watch, foreground, foreground)

    # 2. Skeletonization, then spurs shorter than a few cable radii are cut.
    skeleton = skeletonize(foreground)
    # The compiled distance transform: cv2's values, bit for bit, in O(foreground).
    distance = distance_transform(foreground)
    radius = max(estimate_radius(foreground, skeleton, distance), 1.0)
    spur_length = 2.5 * radius if params.spur_length is None else params.spur_length
    if spur_length > 0:
        skeleton = remove_spurs(skeleton, spur_length)
    watch.lap("skeleton")

    # 3. Contours (Suzuki-Abe) of the skeleton.
    contours = extract_contours(skeleton)
    watch.lap("contours")

    # 4. Fitting: chains of l_s segments, split at tips and junction zones.
    zones = junction_zones(skeleton, radius)
    pieces = fit_chains(contours, skeleton, zones, params.segment_length)
    watch.lap("fitting")

    # 5. Pruning of segments that repeat kept ones.
    pieces = prune_overlaps(pieces, shape)
    # Scraps shorter than the cable is wide carry no direction worth merging on.
    pieces = [p for p in pieces if polyline_length(p) >= min(radius, params.min_chain_length)]
    watch.lap("pruning")

    # 6. Merging across gaps and crossings, then crossings and their order.
    merged = merge_chains(pieces, params, radius, zones, distance)
    finals = []
    for path in merged.paths:
        if polyline_length(path.vertices) < params.min_chain_length:
            continue
        finals.append(_finalise_path(path, foreground, distance, params, radius))
    finals.sort(key=lambda item: -polyline_length(item[0]))
    joint_arrays = [joints for joints, _, _ in finals]
    radii = [chain_radius for _, _, chain_radius in finals]
    found = detect_crossings(joint_arrays, radii, image_bgr)
    inferred_flags = [inferred.copy() for _, inferred, _ in finals]
    for crossing in found:
        # The strand underneath is hidden where the top strand covers it.
        under = joint_arrays[crossing.under]
        reach = radii[crossing.over] + 0.5 * params.segment_length
        midpoints = 0.5 * (under[:-1] + under[1:])
        near = np.hypot(midpoints[:, 0] - crossing.x, midpoints[:, 1] - crossing.y) < reach
        inferred_flags[crossing.under][near] = True
    watch.lap("merging")

    if cue is not None and joint_arrays:
        # Back to step 1 with the chains known: a cable dimmer than the rest gets the
        # rims the image-wide threshold cut off (the caller's own mask is kept as is).
        foreground = grow_by_own_thresholds(
            cue,
            foreground,
            joint_arrays,
            radii,
            inferred_flags,
            [(c.x, c.y, c.over, c.under) for c in found],
            image_low,
        )
        watch.lap("segmentation")

    chains = [
        Chain(
            id=index,
            points=joints.tolist(),
            radius=chain_radius,
            inferred=inferred_flags[index].tolist(),
        )
        for index, (joints, _, chain_radius) in enumerate(finals)
    ]
    crossings = [
        Crossing(
            x=c.x,
            y=c.y,
            over=c.over,
            under=c.under,
            over_segment=c.over_segment,
            under_segment=c.under_segment,
            confidence=c.confidence,
        )
        for c in found
    ]
    watch.times["total"] = (time.perf_counter() - started) * 1000.0
    detection = Detection(
        width=width,
        height=height,
        segment_length=params.segment_length,
        chains=chains,
        crossings=crossings,
        timings_ms=StageTimings(**watch.times),
    )
    return DetectionResult(detection, foreground, skeleton, merged.joins)


def detect(
    image: np.ndarray | None,
    params: DetectParams | None = None,
    mask: np.ndarray | None = None,
) -> Detection:
    """Detect every deformable linear object in an image as a chain of segments.

    The six steps of Keipour et al. (RA-L 2022): segmentation, skeletonization,
    contour extraction, fitting, pruning and merging, plus the order of the strands at
    each crossing.

    Parameters
    ----------
    image : ndarray or None
        ``(H, W, 3)`` BGR or ``(H, W)`` grayscale ``uint8``. May be None when ``mask``
        is given; crossings then carry no over/under information (confidence 0).
    params : DetectParams, optional
        Defaults when None.
    mask : ndarray, optional
        ``(H, W)`` foreground mask (nonzero = cable) to use instead of segmentation.

    Returns
    -------
    Detection

    Raises
    ------
    InvalidInputError
        The image or mask cannot be used (wrong type or shape, empty mask ...).

    Notes
    -----
    Pure: no I/O and no shared state, so it is safe to call from several threads.

    Examples
    --------
    >>> import cv2, numpy as np
    >>> image = np.zeros((120, 200, 3), np.uint8)
    >>> _ = cv2.line(image, (10, 60), (190, 60), (0, 200, 255), 9)
    >>> detection = detect(image)
    >>> len(detection.chains)
    1
    >>> round(detection.chains[0].length / 10)
    18
    """
    return detect_full(image, params, mask).detection
