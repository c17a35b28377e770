"""Step 1: segmentation, the foreground mask of cable pixels.

Four ways to find the mask (``DetectParams.segmentation``), and the caller's own:

``brightness``
    Cables brighter (or more colourful) than a plain, darker background: Otsu's
    threshold of brightness with hysteresis, and again per cable once the chains are
    known (:func:`grow_by_own_thresholds`). Exact and cheap where it applies.
``contrast``
    Cable contrast (:mod:`service.perception.cable_segmentation`): lines of one colour
    that differ from both sides and from the local background, at every width, on
    bright, dark and textured backgrounds alike.
``auto``
    ``brightness`` where the image shows that it applies: brightness is two-class and
    its bright class is thin, bands no wider than a cable over a quarter of the image
    at most (:func:`_thin_bright_class`); ``contrast`` everywhere else.
``hsv``
    A fixed HSV range.
``model``
    A segmenter the caller supplies (:mod:`service.perception.segmenter`): a learned
    model run with onnxruntime, or any callable from the image to a mask.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from schemas import DetectParams, SegmentationMethod
from service.perception import _segmentation_kernels
from service.perception.cable_segmentation import segment_cables
from service.perception.deadline import Deadline
from service.perception.errors import InvalidInputError
from service.perception.objects import distance_and_ridges, without_objects
from service.perception.segmenter import Segmenter, run_segmenter


def as_bgr(image: np.ndarray) -> np.ndarray:
    """Validate an input image and return it as a BGR ``uint8`` array.

    Parameters
    ----------
    image : ndarray
        ``(H, W, 3)`` BGR, ``(H, W, 4)`` BGRA or ``(H, W)`` grayscale, ``uint8``.

    Returns
    -------
    ndarray
        ``(H, W, 3)`` ``uint8``, C-contiguous.
    """
    if not isinstance(image, np.ndarray):
        raise InvalidInputError(f"image must be a numpy array, not {type(image).__name__}")
    if image.dtype != np.uint8:
        raise InvalidInputError(f"image must be uint8, not {image.dtype}")
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = cv2.cvtColor(image[:, :, 0], cv2.COLOR_GRAY2BGR)
    elif not (image.ndim == 3 and image.shape[2] == 3):
        raise InvalidInputError(f"image must be (H, W), (H, W, 3) or (H, W, 4), not {image.shape}")
    if image.shape[0] < 8 or image.shape[1] < 8:
        raise InvalidInputError(f"image is too small ({image.shape[1]}x{image.shape[0]} px)")
    return np.ascontiguousarray(image)


def validate_mask(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Check a caller's mask against the image size and return it as ``bool``."""
    if not isinstance(mask, np.ndarray):
        raise InvalidInputError(f"mask must be a numpy array, not {type(mask).__name__}")
    if mask.ndim == 3 and mask.shape[2] in (1, 3, 4):
        mask = mask[:, :, 0]
    if mask.shape != shape:
        raise InvalidInputError(
            f"mask is {mask.shape[1]}x{mask.shape[0]} px but the image is {shape[1]}x{shape[0]} px"
        )
    binary = mask > 0
    if not binary.any():
        raise InvalidInputError("mask is empty: it marks no cable pixel")
    return binary


def _histogram(feature: np.ndarray) -> np.ndarray:
    """Counts of the 256 levels of a ``uint8`` image, as ``float64``.

    ``cv2.calcHist`` is several times faster than ``np.bincount``; it counts in
    ``float32``, which is exact below 2**24 pixels.
    """
    if feature.size < 2**24:
        hist = cv2.calcHist([feature], [0], None, [256], [0, 256])
        return hist.ravel().astype(np.float64)
    return np.bincount(feature.ravel(), minlength=256).astype(np.float64)


def _otsu(hist: np.ndarray) -> tuple[float, float]:
    """Otsu threshold of a 256-level histogram and its separability (0..1)."""
    return _segmentation_kernels.otsu_kernel(np.ascontiguousarray(hist, np.float64))


def cue_images(image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Brightness (max channel) and colourfulness (max minus min channel) as ``uint8``."""
    # OpenCV's per-element max/min are an order of magnitude faster than numpy's
    # reductions over the channel axis.
    blue, green, red = cv2.split(image_bgr)
    brightness = cv2.max(cv2.max(blue, green), red)
    darkest = cv2.min(cv2.min(blue, green), red)
    return brightness, cv2.subtract(brightness, darkest)


# Otsu separability above which a cue is taken as clearly two-class (cable and not).
BIMODAL_SEPARABILITY = 0.8
# A less clearly two-class cue still counts when its bright class is this thin.
THIN_SEPARABILITY = 0.5
THIN_FOREGROUND_SHARE = 0.25
# Hysteresis: pixels down to this fraction of the way from the background's mean to
# Otsu's threshold are cable when they touch pixels above the threshold, which keeps
# dim stretches and soft edges of a cable without letting background pixels in.
HYSTERESIS_FRACTION = 0.85


def _hysteresis_low(hist: np.ndarray, threshold: float) -> float:
    """The weak threshold: :data:`HYSTERESIS_FRACTION` of the way up from the background.

    The background's mean is the mean of the levels up to Otsu's ``threshold``, from
    the histogram: sums of whole numbers are exact in float64, so this is the mean of
    those pixels.
    """
    level = int(threshold)
    below_count = hist[: level + 1].sum()
    below_sum = (hist[: level + 1] * np.arange(level + 1, dtype=np.float64)).sum()
    background = float(below_sum / below_count) if below_count else 0.0
    return background + HYSTERESIS_FRACTION * (threshold - background)


def _cable_like(cue: np.ndarray, threshold: float, separability: float, hist: np.ndarray) -> bool:
    """Does thresholding this cue look like cables against a background?

    Either the histogram is clearly two-class, or it is moderately so and the bright
    class is a small share of the image: cables are thin, while a split of plain
    texture puts about half the image on each side.
    """
    if separability >= BIMODAL_SEPARABILITY:
        return True
    # The threshold is a whole level: the pixels above it are the levels after it.
    above = int(hist[int(threshold) + 1 :].sum())
    share = float(above) / cue.size
    return separability >= THIN_SEPARABILITY and share <= THIN_FOREGROUND_SHARE


# The widest cable the defaults are made for (DetectParams: cables 6 to 40 px wide).
MAX_CABLE_WIDTH = 40
# Cables lying on a table cover at most a third of the picture (mbest: 3-9 %; the rings
# scene of dlo bench, a ring in every 40 px cell: 26 %); a sheet of paper or a lit table
# top in view is most of it (ariadne's paper: 74-93 %).
CABLES_SHARE = 1.0 / 3.0
BLOCK = 4


def _thin_bright_class(hist: np.ndarray, threshold: float, mask: np.ndarray) -> bool:
    """Is the bright class of a brightness split made of cables, not of a bright surface?

    Cables are thin: the bright class covers at most :data:`CABLES_SHARE` of the
    image, and at most :data:`THIN_FOREGROUND_SHARE` of the mask lies where a square
    wider than the widest cable fits inside it. A sheet of paper, a lit table top or the
    light half of a busy print fails one or the other.
    """
    above = float(hist[int(threshold) + 1 :].sum())
    if above > CABLES_SHARE * mask.size:
        return False
    area = np.count_nonzero(mask)
    if area == 0:
        return True
    # On blocks of BLOCK x BLOCK px (a block counts when the mask covers more than half
    # of it), at a sixteenth of the cost: wide regions are wide at any resolution.
    height, width = mask.shape
    if height % BLOCK == 0 and width % BLOCK == 0 and 3 <= BLOCK < 256:
        # OpenCV's area resize by a whole factor is each block's mean: counted directly,
        # without resampling the image (compiled, a third of a ms less per photograph).
        full = _segmentation_kernels.full_blocks(mask.view(np.uint8), BLOCK)
    else:
        blocks = cv2.resize(
            mask.view(np.uint8), (width // BLOCK, height // BLOCK), interpolation=cv2.INTER_AREA
        )
        full = (blocks == 1).view(np.uint8)
    side = MAX_CABLE_WIDTH // BLOCK + 1
    core = cv2.erode(full, np.ones((side, side), np.uint8))
    return BLOCK * BLOCK * np.count_nonzero(core) <= THIN_FOREGROUND_SHARE * area


def segment_auto(
    image_bgr: np.ndarray,
    min_component_area: int = 0,
    max_hole_area: int = 0,
    *,
    deadline: Deadline | None = None,
) -> np.ndarray:
    """``brightness`` where the image shows that it applies, else ``contrast``.

    Brightness thresholded by Otsu's method (with hysteresis) is used when it looks
    like cables against a background (:func:`_cable_like`) and its bright class is
    thin (:func:`_thin_bright_class`): bright cables on a darker, plain background,
    where its edges follow the cable better than any other cue. Everywhere else (a
    light or textured background, dark cables) :func:`segment_cables` finds the cables
    by their contrast with what lies beside them.
    """
    return _segment_auto(image_bgr, min_component_area, max_hole_area, deadline).mask


@dataclass(frozen=True)
class Segmentation:
    """A mask and what the later steps may reuse of its making (:func:`segment_full`).

    Attributes
    ----------
    mask : ndarray of bool
        ``(H, W)`` the foreground.
    cue : ndarray or None
        The brightness, when the brightness path made the mask (else ``None``).
    low : float
        The weak threshold the brightness was cut at (0 otherwise).
    distance : ndarray of float32 or None
        ``skeleton.distance_transform(mask)`` when segmentation computed it for
        ``mask`` itself (else ``None``).
    """

    mask: np.ndarray
    cue: np.ndarray | None = None
    low: float = 0.0
    distance: np.ndarray | None = None


def _segment_auto(
    image_bgr: np.ndarray,
    min_component_area: int,
    max_hole_area: int,
    deadline: Deadline | None = None,
) -> Segmentation:
    """:func:`segment_auto`, and the brightness and weak threshold when brightness made it."""
    found = _segment_by_brightness(image_bgr, min_component_area, max_hole_area, thin_only=True)
    if found is not None:
        mask, brightness, low = found
        # A bright object lying on a cable passes the threshold with it.
        # Its distances serve the objects' test (their ridges found in the same pass)
        # and, when no object is taken out, the skeleton step.
        distance, ridges = distance_and_ridges(mask)
        kept = without_objects(mask, min_component_area, distance, ridges)
        return Segmentation(kept, brightness, low, distance if kept is mask else None)
    mask = segment_cables(image_bgr, min_component_area, max_hole_area, deadline=deadline)
    return Segmentation(mask)


def segment_brightness(
    image_bgr: np.ndarray, min_component_area: int = 0, max_hole_area: int = 0
) -> np.ndarray:
    """Foreground mask from brightness, or from colourfulness when brightness fails.

    Brightness thresholded by Otsu's method (with hysteresis) is used whenever it
    looks like cables against a background (:func:`_cable_like`): it keeps white and
    coloured cables alike, and its edges follow the cable better than colour, which
    JPEG chroma subsampling smears. Otherwise (a colourful cable on a light surface)
    colourfulness is used if it looks like cables; if neither does, the image is taken
    to show no cable and the mask is empty.

    The mask is cleaned as :func:`clean_mask` would clean it; on the brightness path
    in the same pass as the threshold.
    """
    return _segment_brightness(image_bgr, min_component_area, max_hole_area)[0]


def _segment_brightness(
    image_bgr: np.ndarray, min_component_area: int, max_hole_area: int
) -> tuple[np.ndarray, np.ndarray | None, float]:
    """:func:`segment_brightness`, and the brightness and weak threshold when it made it."""
    found = _segment_by_brightness(image_bgr, min_component_area, max_hole_area, thin_only=False)
    if found is not None:
        return found
    return _segment_by_colourfulness(image_bgr, min_component_area, max_hole_area)


def _segment_by_brightness(
    image_bgr: np.ndarray, min_component_area: int, max_hole_area: int, thin_only: bool
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The brightness path: the mask, the brightness and the weak threshold; None when
    brightness does not look like cables (or, with ``thin_only``, its class is not thin)."""
    # No blur: it moves the border of thin cables more than it removes noise, and
    # the clean-up afterwards removes the specks noise leaves.
    brightness, counts = _segmentation_kernels.brightness_histogram(image_bgr)
    hist = counts.astype(np.float64)
    threshold, separability = _otsu(hist)
    if not _cable_like(brightness, threshold, separability, hist):
        return None
    low = _hysteresis_low(hist, threshold)
    # Pixels above ``low``: the levels from the first whole level above it.
    weak_count = int(hist[max(int(np.floor(low)) + 1, 0) :].sum())
    mask = _segmentation_kernels.threshold_and_clean(
        brightness, low, threshold, weak_count, int(min_component_area), int(max_hole_area)
    ).view(np.bool_)
    if thin_only and not _thin_bright_class(hist, threshold, mask):
        return None
    return mask, brightness, low


def _segment_by_colourfulness(
    image_bgr: np.ndarray, min_component_area: int, max_hole_area: int
) -> tuple[np.ndarray, None, float]:
    """The colourfulness path of ``brightness``: Otsu's threshold of colourfulness."""
    colourfulness = cue_images(image_bgr)[1]
    colour_hist = _histogram(colourfulness)
    colour_threshold, colour_separability = _otsu(colour_hist)
    if _cable_like(colourfulness, colour_threshold, colour_separability, colour_hist):
        mask = clean_mask(colourfulness > colour_threshold, min_component_area, max_hole_area)
        return mask, None, 0.0
    # Neither cue looks like cables: an empty table, or cables this method cannot
    # tell from their background. Reporting nothing is safer for a robot than chains
    # traced through texture; such scenes need a mask or an HSV range.
    return np.zeros(colourfulness.shape, bool), None, 0.0


def segment_hsv(image_bgr: np.ndarray, low: tuple[int, int, int], high: tuple[int, int, int]):
    """Foreground mask of the pixels inside an HSV box (OpenCV ranges)."""
    hsv = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV)
    return cv2.inRange(hsv, np.array(low, np.uint8), np.array(high, np.uint8)) > 0


def clean_mask(mask: np.ndarray, min_component_area: int, max_hole_area: int) -> np.ndarray:
    """Remove foreground specks and fill small background holes.

    Parameters
    ----------
    mask : ndarray of bool
    min_component_area : int
        8-connected foreground components with fewer pixels are removed.
    max_hole_area : int
        4-connected background components with at most this many pixels that do not
        touch the border are filled.

    Returns
    -------
    ndarray of bool
        A new mask; ``mask`` is not changed.
    """
    # The fills visit the foreground and the background next to it, not the whole image.
    cleaned = np.array(mask, dtype=bool, order="C").view(np.uint8)
    if min_component_area > 0:
        _segmentation_kernels.remove_small_components(cleaned, int(min_component_area))
    if max_hole_area > 0:
        _segmentation_kernels.fill_small_holes(cleaned, int(max_hole_area))
    return cleaned.view(np.bool_)


def segment_with_cue(
    image_bgr: np.ndarray,
    params: DetectParams,
    segmenter: Segmenter | None = None,
    *,
    deadline: Deadline | None = None,
) -> tuple[np.ndarray, np.ndarray | None, float]:
    """:func:`segment`, with the brightness image and the weak threshold it was cut at.

    The brightness is returned (else ``None``) only when the brightness path made the
    mask, so that :func:`grow_by_own_thresholds` can apply the same rule to each cable.
    """
    found = segment_full(image_bgr, params, segmenter, deadline=deadline)
    return found.mask, found.cue, found.low


def segment_full(
    image_bgr: np.ndarray,
    params: DetectParams,
    segmenter: Segmenter | None = None,
    *,
    deadline: Deadline | None = None,
) -> Segmentation:
    """:func:`segment_with_cue`, and the mask's distance transform where it was needed
    to make the mask (the brightness path's objects test), for the skeleton step."""
    area, holes = params.min_component_area, params.max_hole_area
    method = params.segmentation
    if method is SegmentationMethod.auto:
        return _segment_auto(image_bgr, area, holes, deadline)
    if method is SegmentationMethod.brightness:
        return Segmentation(*_segment_brightness(image_bgr, area, holes))
    return Segmentation(segment(image_bgr, params, segmenter, deadline=deadline))


# Each cable's own threshold is found among the pixels within this many of its radii
# of its centreline: about one part cable to two parts background, a balance at which
# Otsu's method is reliable. (2.5 to 4 radii give the same masks to within 0.001 DICE.)
OWN_SURROUNDINGS_RADII = 3.0
# Pixels at most this far (px) beyond a cable's radius may join it.
OWN_THRESHOLD_REACH = 2.0
# The level is judged from every sixth profile (one pixel apart along the cable):
# still thousands of pixels, at a sixth of the cost.
PROFILE_STRIDE = 6


def grow_by_own_thresholds(
    cue: np.ndarray,
    mask: np.ndarray,
    centrelines: list[np.ndarray],
    radii: list[float],
    hidden: list[np.ndarray] | None = None,
    crossings: list[tuple[float, float, int, int]] = (),
    image_low: float = np.inf,
) -> np.ndarray:
    """Grow a mask by each cable's own threshold, found in that cable's surroundings.

    One Otsu threshold for the whole image falls between the background and the
    cables as a whole, so a cable clearly dimmer than the others loses its soft rims
    (the shaded side of a round cable, say). Here the same rule, Otsu's threshold and
    the hysteresis below it, is applied again to the pixels around each cable: its
    brightness profiles across the centreline, out to :data:`OWN_SURROUNDINGS_RADII`
    radii, leaving out hidden segments and the stretches near the cable's crossings,
    where the other cable would weigh in. Along each profile, pixels above the cable's
    own weak threshold that continue the mask outwards without a break, up to
    :data:`OWN_THRESHOLD_REACH` px beyond the cable's radius, join the mask. Pixels
    are only added: a cable as bright as the rest keeps its mask.

    Parameters
    ----------
    cue : ndarray of uint8
        ``(H, W)`` brightness the mask was thresholded from.
    mask : ndarray of bool
        ``(H, W)`` foreground mask.
    centrelines : list of ndarray
        Each cable's ``(K, 2)`` centreline joints, ``[x, y]`` in pixels.
    radii : list of float
        Each cable's radius in pixels.
    hidden : list of ndarray of bool, optional
        Per cable, ``(K - 1,)`` flags of the segments inferred under occluders or
        other cables; their profiles are not used.
    crossings : list of (x, y, i, j)
        Crossing points and the two cables (indices into ``centrelines``) that cross.
    image_low : float, optional
        The weak threshold ``mask`` was cut at. A cable whose own is not lower gains
        nothing (every pixel above it next to the mask is in the mask already) and is
        skipped.

    Returns
    -------
    ndarray of bool
        A new mask, ``mask`` plus the grown pixels.

    Examples
    --------
    >>> import numpy as np
    >>> cue = np.zeros((40, 60), np.uint8)
    >>> cue[14:27, :] = 60            # a shaded rim two pixels wide ...
    >>> cue[16:25, :] = 120           # ... round the cable's lit core
    >>> mask = cue >= 100             # as brighter cables elsewhere would set it
    >>> line = np.array([[0.0, 20.0], [59.0, 20.0]])
    >>> grown = grow_by_own_thresholds(cue, mask, [line], [4.5])
    >>> int(mask[:, 30].sum()), int(grown[:, 30].sum())
    (9, 13)
    """
    before = np.ascontiguousarray(mask, dtype=bool).view(np.uint8)
    grown = before.copy()
    cue = np.ascontiguousarray(cue, dtype=np.uint8)
    # Each cable's crossings, gathered once (in their order): a scene of thousands of
    # cables must not scan every crossing for every cable.
    crossings_of: dict[int, list[tuple[float, float, int, int]]] = {}
    for crossing in crossings:
        for cable in dict.fromkeys(crossing[2:4]):
            crossings_of.setdefault(cable, []).append(crossing)
    for index, (points, radius) in enumerate(zip(centrelines, radii, strict=True)):
        points = np.ascontiguousarray(points, np.float64)
        if len(points) < 2:
            continue
        seen = np.ones(len(points) - 1, bool)
        if hidden is not None:
            seen = ~np.asarray(hidden[index], bool)
        radius = max(float(radius), 1.0)
        span = int(np.ceil(OWN_SURROUNDINGS_RADII * radius))
        mine = crossings_of.get(index, [])
        avoid_xy = np.array([(c[0], c[1]) for c in mine], np.float64).reshape(-1, 2)
        avoid_reach = np.array(
            [span + radii[c[3] if c[2] == index else c[2]] for c in mine], np.float64
        )
        hist, feet = _segmentation_kernels.profile_histogram(
            cue, points, seen, avoid_xy, avoid_reach, span, PROFILE_STRIDE
        )
        if feet * PROFILE_STRIDE < 2 * span:
            continue  # too little of the cable in the open to judge its own level
        threshold, separability = _otsu(hist)
        if separability < THIN_SEPARABILITY:
            continue  # no clear cable-and-background split around this cable
        low = _hysteresis_low(hist, threshold)
        if low >= image_low:
            continue
        # Walk out from the centre both ways; a pixel joins while the walk has met only
        # mask pixels and pixels above the cable's own weak threshold.
        reach = min(int(np.ceil(radius + OWN_THRESHOLD_REACH)), span)
        # Walks start two pixels inside the typical edge when the mask is there.
        start = max(int(np.ceil(radius)) - 2, 0)
        _segmentation_kernels.grow_along_profiles(
            cue, before, grown, points, seen, avoid_xy, avoid_reach, start, reach, low
        )
    return grown.view(np.bool_)


def segment(
    image_bgr: np.ndarray,
    params: DetectParams,
    segmenter: Segmenter | None = None,
    *,
    deadline: Deadline | None = None,
) -> np.ndarray:
    """Step 1 of the pipeline: the cleaned foreground mask of an image.

    Parameters
    ----------
    image_bgr : ndarray
        ``(H, W, 3)`` ``uint8`` BGR image.
    params : DetectParams
        Uses ``segmentation``, ``hsv_low``, ``hsv_high``, ``min_component_area`` and
        ``max_hole_area``.
    segmenter : callable, optional
        For ``segmentation="model"``: called with ``image_bgr``, returns the mask
        (:func:`service.perception.segmenter.run_segmenter` checks it).
    deadline : Deadline, optional
        Checked inside cable contrast (``auto`` and ``contrast``), whose work grows with
        the image.

    Returns
    -------
    ndarray of bool
        ``(H, W)``, True on cable pixels.

    Examples
    --------
    >>> import numpy as np
    >>> from schemas import DetectParams
    >>> image = np.zeros((64, 64, 3), np.uint8)
    >>> image[30:36, 4:60] = (40, 200, 255)
    >>> int(segment(image, DetectParams()).sum()) > 250
    True
    """
    area, holes = params.min_component_area, params.max_hole_area
    method = params.segmentation
    if method is SegmentationMethod.hsv:
        return clean_mask(segment_hsv(image_bgr, params.hsv_low, params.hsv_high), area, holes)
    if method is SegmentationMethod.model:
        return clean_mask(run_segmenter(segmenter, image_bgr), area, holes)
    if method is SegmentationMethod.contrast:
        return segment_cables(image_bgr, area, holes, deadline=deadline)
    if method is SegmentationMethod.brightness:
        return segment_brightness(image_bgr, area, holes)
    return segment_auto(image_bgr, area, holes, deadline=deadline)
