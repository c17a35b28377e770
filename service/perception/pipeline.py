"""The detection pipeline, from an image (or a mask) to a Detection, and its warm-up.

The six steps of Keipour et al. (RA-L 2022), one module each: segmentation, skeleton,
contours, fitting, pruning and merging; then each merged path's ends are extended to
the cable's ends (end_extension), the path is resampled to joints exactly ``l_s``
apart, the crossings are found and ordered (crossings), and, on the brightness path,
the mask grows by each cable's own threshold (segmentation again).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from schemas import (
    Chain,
    Crossing,
    Detection,
    DetectParams,
    GapCurve,
    SegmentationMethod,
    StageTimings,
)
from service.perception import _pipeline_kernels
from service.perception._kernel_cache import kernels_cached, write_stamp
from service.perception.appearance import _first_off, _front, ground_beside
from service.perception.bridge_ends import ends_clear_of_crossing
from service.perception.contours import extract_contours
from service.perception.crossings import detect_crossings, find_intersections
from service.perception.cut_ends import _border_distance, _far_border, middle_line
from service.perception.deadline import Deadline, check
from service.perception.end_extension import extend_ends
from service.perception.errors import InvalidInputError
from service.perception.fitting import fit_chains, junction_zones
from service.perception.geometry import (
    arc_lengths,
    fit_where_skipped,
    median,
    polyline_length,
    resample,
)
from service.perception.merging import (
    Join,
    chain_ends,
    choose_joins,
    join_cost,
    merge_chains,
    tips_in_junctions,
)
from service.perception.paths import MergedPath, gap_curve
from service.perception.pruning import prune_overlaps
from service.perception.segmentation import (
    as_bgr,
    clean_mask,
    grow_by_own_thresholds,
    segment_full,
    segment_with_cue,
    validate_mask,
)
from service.perception.segmenter import Segmenter
from service.perception.skeleton import (
    distance_transform,
    estimate_radius,
    remove_spurs,
    short_blobs_kept,
    spurs_removed,
    thin_listed,
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


# Merged paths finished between two looks at the deadline.
DEADLINE_CHECK_EVERY = 256


class _Stopwatch:
    def __init__(self):
        self.times: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.times[stage] = self.times.get(stage, 0.0) + (now - self._last) * 1000.0
        self._last = now


def _finalise_path(path: MergedPath, mask, distance, params: DetectParams, radius: float):
    """A merged path with its ends extended, as joints exactly ``l_s`` apart.

    Returns the joints, the per-segment "inferred" flags, the chain's scale for the
    later steps' thresholds (the median distance transform at its joints on the cable,
    less half a pixel: what the crossings' window, the hidden segments' reach and each
    cable's own threshold were built on) and its radius (:func:`chain_radius`).
    """
    span = max(2.0 * params.segment_length, 3.0 * radius)
    vertices, filled = extend_ends(path.vertices, path.filled, mask, radius, span)
    height, width = mask.shape
    # The last pixel of each axis, (x, y): points are rounded and clipped to the image.
    last_pixel = np.array([width - 1, height - 1])
    # A filled edge across foreground (a crossing) is seen; across background, hidden.
    steps = vertices[1:] - vertices[:-1]
    midpoints = 0.5 * (vertices[:-1] + vertices[1:])
    pixels = np.minimum(np.maximum(np.rint(midpoints).astype(int), 0), last_pixel)
    hidden_edge = filled & ~mask[pixels[:, 1], pixels[:, 0]]
    joints, source_edge = resample(vertices, params.segment_length)
    # What np.linalg.norm(steps, axis=1) adds (two squares) and roots, without its checks.
    edge_lengths = np.sqrt((steps * steps).sum(axis=1))
    # Inferred where more than half the length of the edges a segment spans is hidden.
    inferred = _pipeline_kernels.inferred_segments(
        source_edge.astype(np.int64),
        np.ascontiguousarray(edge_lengths, np.float64),
        np.ascontiguousarray(hidden_edge, bool),
    )
    pixels = np.minimum(np.maximum(np.rint(joints).astype(int), 0), last_pixel)
    at_joints = distance[pixels[:, 1], pixels[:, 0]]
    on_cable = at_joints[at_joints > 0]
    scale = max(float(median(on_cable)) - 0.5, 0.5) if on_cable.size else radius
    return joints, inferred, scale, chain_radius(joints, mask, radius)


# Each side of a width across a chain is off by at most half a pixel's diagonal: the ray
# leaves the cable on a pixel's border, the cable's edge runs somewhere in that pixel.
ACROSS_QUANTISATION_PX = float(np.sqrt(2.0))
# How far out a side's edge is looked for, in typical radii (a ray along a crossing
# strand stops there), plus a few pixels for thin cables.
ACROSS_REACH_RADII = 6.0
# The share of a width either side must span for the chain to count as on its middle.
CENTRED_SHARE = 1.0 / 3.0
ACROSS_REACH_PX = 6.0


def chain_radius(joints: np.ndarray, mask: np.ndarray, radius: float) -> float:
    """A chain's radius in pixels: half the mask's width across it, where it is seen.

    The width is measured across the chain at each joint and at each segment's middle,
    from border to border of the mask's pixels (:func:`_pipeline_kernels.edge_distance`),
    so a cable drawn ``w`` pixels wide measures ``w`` at any angle and curvature on
    average (a distance transform at the centreline runs about half a pixel short off
    the axes). Widths the chain does not run through the middle third of are left out;
    the rest near their median (within two sides' quantisation) are averaged.

    Parameters
    ----------
    joints : ndarray
        ``(N, 2)`` joints ``(x, y)`` of the chain.
    mask : ndarray of bool
        The foreground mask.
    radius : float
        The cables' typical radius (``estimate_radius``): sets how far out an edge is
        looked for, and is the answer where no width can be measured (a chain seen
        nowhere, or only where it leaves the image).
    """
    limit = ACROSS_REACH_RADII * radius + ACROSS_REACH_PX
    sides = _pipeline_kernels.sides_across(
        np.ascontiguousarray(joints, np.float64), np.ascontiguousarray(mask, bool), limit
    )
    # A chain runs along its cable's middle: where it lies off the middle third of what
    # the mask spans across it, the span is something else (the other side of a cable
    # it touches, a strand it crosses, a blob it runs along the edge of). An even count
    # split far apart has none near its median: the median it is.
    return float(
        _pipeline_kernels.radius_from_sides(
            sides, float(radius), CENTRED_SHARE, ACROSS_QUANTISATION_PX
        )
    )


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
    *,
    segmenter: Segmenter | None = None,
    deadline: Deadline | None = None,
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
    return _detect(image, params, mask, segmenter, deadline, mask_wanted=True)


def _detect(
    image: np.ndarray | None,
    params: DetectParams | None,
    mask: np.ndarray | None,
    segmenter: Segmenter | None,
    deadline: Deadline | None,
    mask_wanted: bool,
) -> DetectionResult:
    """:func:`detect_full`; with ``mask_wanted`` False the result's mask is the one the
    chains were found in, not grown by each cable's own threshold afterwards
    (:func:`grow_by_own_thresholds`): that growth changes nothing but the mask, which
    :func:`detect` does not return (a third of a ms per photograph)."""
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
    cue, image_low, distance = None, np.inf, None
    if mask is not None:
        foreground = clean_mask(
            validate_mask(mask, shape), params.min_component_area, params.max_hole_area
        )
    else:
        found = segment_full(image_bgr, params, segmenter, deadline=deadline)
        foreground, cue, image_low, distance = found.mask, found.cue, found.low, found.distance
    watch.lap("segmentation")
    check(deadline, "segmentation")
    if not foreground.any():
        return _empty(width, height, params, watch, foreground, foreground)

    # 2. Skeletonization, then spurs shorter than a few cable radii are cut.
    # The skeleton's pixels come with it (no scan of the image for them below).
    skeleton, pixels = thin_listed(foreground)
    # The compiled distance transform: cv2's values, bit for bit, in O(foreground)
    # (segmentation's own, when the brightness path needed it).
    if distance is None:
        distance = distance_transform(foreground)
    radius = max(estimate_radius(skeleton, distance=distance, pixels=pixels), 1.0)
    spur_length = 2.5 * radius if params.spur_length is None else params.spur_length
    if spur_length > 0:
        pruned, removed, pruned_pixels = spurs_removed(skeleton, spur_length, pixels)
        # A blob that thins to nothing but spurs is a short piece, not a side branch
        # (with nothing removed there is no such blob: the skeleton is kept as it is).
        kept = short_blobs_kept(skeleton, pruned, spur_length) if removed else pruned
        # The pixels listed are the pruned skeleton's; a blob's path put back is not in
        # them (junction_zones lists them itself then).
        skeleton, pixels = kept, (pruned_pixels if kept is pruned else None)
    watch.lap("skeleton")
    check(deadline, "skeleton")

    # 3. Contours (Suzuki-Abe) of the skeleton.
    contours = extract_contours(skeleton)
    watch.lap("contours")
    check(deadline, "contours")

    # 4. Fitting: chains of l_s segments, split at tips and junction zones.
    zones = junction_zones(skeleton, radius, pixels)
    pieces = fit_chains(contours, skeleton, zones, params.segment_length)
    watch.lap("fitting")
    check(deadline, "fitting")

    # 5. Pruning of segments that repeat kept ones.
    pieces = prune_overlaps(pieces, shape)
    # Scraps shorter than the cable is wide carry no direction worth merging on, unless
    # neither tip is in a junction zone: then the scrap is all thinning leaves of a
    # stretch of cable seen between two objects (a blob cut short at both ends, about as
    # long as it is wide), and without it the two gaps round it are one nothing explains.
    free = ~tips_in_junctions(pieces, zones).reshape(-1, 2).any(axis=1)
    shortest = min(radius, params.min_chain_length)
    pieces = [
        points
        for points, alone in zip(pieces, free.tolist(), strict=True)
        if alone or polyline_length(points) >= shortest
    ]
    watch.lap("pruning")
    check(deadline, "pruning")

    # 6. Merging across gaps and crossings; each path's free ends extended to the
    # cable's ends and the path resampled; then crossings and their order.
    merged = merge_chains(
        pieces, params, radius, zones, distance, deadline, image=image_bgr, mask=foreground
    )
    finals = []
    for index, path in enumerate(merged.paths):
        if index % DEADLINE_CHECK_EVERY == 0:
            check(deadline, "merging")
        if polyline_length(path.vertices) < params.min_chain_length:
            continue
        finals.append(_finalise_path(path, foreground, distance, params, radius))
    finals.sort(key=lambda item: -polyline_length(item[0]))
    joint_arrays = [joints for joints, *_ in finals]
    # The thresholds of the steps below are in the scale they were built on.
    radii = [scale for _, _, scale, _ in finals]
    check(deadline, "merging")
    found = detect_crossings(joint_arrays, radii, image_bgr)
    inferred_flags = [inferred.copy() for _, inferred, *_ in finals]
    for crossing in found:
        # The strand underneath is hidden where the top strand covers it.
        under = joint_arrays[crossing.under]
        reach = radii[crossing.over] + 0.5 * params.segment_length
        midpoints = 0.5 * (under[:-1] + under[1:])
        near = np.hypot(midpoints[:, 0] - crossing.x, midpoints[:, 1] - crossing.y) < reach
        inferred_flags[crossing.under][near] = True
    watch.lap("merging")
    check(deadline, "merging")

    if mask_wanted and cue is not None and joint_arrays:
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
            radius=measured,
            inferred=inferred_flags[index].tolist(),
        )
        for index, (joints, _, _, measured) in enumerate(finals)
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
    *,
    segmenter: Segmenter | None = None,
    deadline: Deadline | None = None,
) -> Detection:
    """Detect every deformable linear object in an image as a chain of segments.

    The six steps of Keipour et al. (RA-L 2022): segmentation, skeletonization,
    contour extraction, fitting, pruning and merging; then the chains' free ends are
    extended to the cables' ends and the order of the strands at each crossing is found.

    Parameters
    ----------
    image : ndarray or None
        ``(H, W, 3)`` BGR or ``(H, W)`` grayscale ``uint8``. May be None when ``mask``
        is given; crossings then carry no over/under information (confidence 0).
    params : DetectParams, optional
        Defaults when None.
    mask : ndarray, optional
        ``(H, W)`` foreground mask (nonzero = cable) to use instead of segmentation.
    segmenter : callable, optional
        For ``params.segmentation == "model"``: ``segmenter(image_bgr) -> mask``, a
        learned model (:class:`service.perception.segmenter.OnnxSegmenter`) or any
        function; see :mod:`service.perception.segmenter` for what it may return.
    deadline : Deadline, optional
        A time budget (:class:`service.perception.deadline.Deadline`), checked between
        the steps and inside the loops that grow with the number of cable pieces.

    Returns
    -------
    Detection

    Raises
    ------
    InvalidInputError
        The image or mask cannot be used (wrong type or shape, empty mask ...).
    DeadlineExceeded
        ``deadline`` passed before the detection was done.

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
    # The mask is not returned: it is not grown by the cables' own thresholds either.
    return _detect(image, params, mask, segmenter, deadline, mask_wanted=False).detection


def _numba_cache_dir() -> str:
    """The directory numba caches the kernels in ("" when numba does not say).

    Every kernel module lives in this package, so one kernel's directory is all of theirs.
    """
    cache = getattr(_pipeline_kernels.inferred_segments, "_cache", None)
    return str(getattr(cache, "_cache_path", "") or "")


def warm_up() -> None:
    """Load every compiled kernel, compiling it first when numba's cache lacks it.

    Runs each step on small inputs through the same wrappers, and so with the same
    argument types, as :func:`detect_full`: afterwards a detection compiles and loads
    nothing, so its ``timings_ms`` are detection time alone. On a machine's first run
    (see :func:`service.perception.kernels_cached`) the kernels are compiled, which
    takes tens of seconds, and cached by numba; the stamp that ``kernels_cached`` reads
    is then written. Later processes load the machine code from the cache (a fraction
    of a second), and calls after the first in a process take a few milliseconds.
    """
    mask = np.zeros((40, 48), bool)
    mask[17:23, 2:46] = True  # a cross: one junction, four arms
    mask[2:38, 21:27] = True
    mask[8, 4] = True  # a speck
    image = np.repeat((mask * 200 + 20).astype(np.uint8)[:, :, None], 3, axis=2)
    # 1. The brightness path (Otsu, hysteresis and clean-up in one pass), the clean-up
    # of other masks, and the growth by a cable's own threshold.
    _, cue, _ = segment_with_cue(image, DetectParams())
    # The cable-contrast path: a dark line on a light ground, large enough for a level.
    lines = np.full((96, 96, 3), 210, np.uint8)
    lines[44:50, 8:88] = (40, 60, 170)
    segment_with_cue(lines, DetectParams(segmentation=SegmentationMethod.contrast))
    clean_mask(mask, 2, 2)
    line = np.array([[2.0, 20.0], [45.0, 20.0]])
    grow_by_own_thresholds(cue, mask, [line], [3.0], [np.array([False])], [])
    # The arc lengths of a float64 polyline (compiled for those).
    polyline_length(line)
    arc_lengths(line)
    # 2 to 5.
    skeleton, pixels = thin_listed(mask)
    distance = distance_transform(mask)
    radius = max(estimate_radius(skeleton, distance=distance, pixels=pixels), 1.0)
    skeleton, _, pixels = spurs_removed(skeleton, 2.5 * radius, pixels)
    zones = junction_zones(skeleton, radius, pixels)
    # Without the pixels (other callers): they are listed by a scan, compiled too.
    remove_spurs(skeleton, 2.5 * radius)
    junction_zones(skeleton, radius)
    prune_overlaps(fit_chains(extract_contours(skeleton), skeleton, zones, 5.0), mask.shape)
    # 6. End fits (leaving out narrow ends) and the gap curves: the natural curve's three
    # shapes (straight, arc, Bezier) and the smooth one.
    strands = [
        np.array([[0.0, 5.0], [4.0, 5.0], [8.0, 5.0], [12.0, 5.0]]),
        np.array([[6.0, 0.0], [6.0, 4.0], [6.0, 8.0], [6.0, 12.0]]),
    ]
    ends = chain_ends(strands, 10.0, skip=1.0, distance=distance, full_width=2.0)
    # One end's fit alone, where its skipped tip begins (the bridges from the fits).
    fit_where_skipped(strands[0], True, 10.0, 1.0)
    # A crossing's bridge clear of the other strand (from the cross's distance transform).
    ends_clear_of_crossing(strands[0], ends[0], ends[1].skip, 10.0, distance)
    # The candidates' grid, and a junction's pairing (the strands' first ends meet).
    choose_joins(ends, len(strands), DetectParams(), radius, junction_of_end=[0, -1, 0, -1])
    # The image's evidence: ends running to the border, the ends' colours (warmed even
    # when a caller's colour_weight is 0).
    colour = DetectParams(colour_weight=0.5)
    merge_chains(strands, colour, radius, zones, distance, image=image, mask=mask)
    join_cost(ends[0], ends[2], DetectParams(), radius)  # one pair's (junctions)
    east, north = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    for shape in GapCurve:
        for end, arriving in (
            (strands[0][-1], east),
            (np.array([20.0, 20.0]), north),
            (np.array([-9.0, 9.0]), north),
        ):
            gap_curve(strands[0][0], east, end, arriving, shape=shape)
    # The sections a gap's cut reading samples across the mask (compiled).
    section_steps = np.arange(0.5, 6.0, 0.5)
    _border_distance(mask, 24.0, 20.0, 1.0, 0.0, section_steps, 6.0)
    _far_border(mask, 24.0, 20.0, 1.0, 0.0, section_steps, 6.0)
    # The middle line traced to a cut (both readings of a narrowing), and the colour
    # beyond a cable's border, from the image's 3x3 patches (compiled).
    for first_narrowing in (False, True):
        middle_line(mask, np.array([6.0, 20.0]), east, 0.01, 3.0, 50.0, first_narrowing)
    ground_beside(image, mask, np.array([[24.0, 10.0], [10.0, 10.0], [40.0, 30.0]]))
    # The end readings' marches to the mask's border (compiled).
    _front(mask, np.array([6.0, 20.0]), east, 90)
    _first_off(mask, line)
    # End extension, resampling and the inferred flags; the crossings' sweep.
    _finalise_path(MergedPath(line, np.array([False])), mask, distance, DetectParams(), radius)
    find_intersections(strands)
    # OpenCV builds its Lab tables on the first conversion (about 60 ms), which the
    # crossings step and the labels would otherwise report as their own time.
    cv2.cvtColor(image[:1, :1], cv2.COLOR_BGR2LAB)
    if not kernels_cached():
        write_stamp(_numba_cache_dir())
