"""Step 1: segmentation, the foreground mask of cable pixels.

The automatic method assumes what cable cells usually show: cables that are brighter
or more colourful than their background. It thresholds whichever of the two cues
separates the image better (Otsu's between-class variance ratio), so a bright white
cable on a dark colourful mat and a red cable on a light grey table both work without
tuning.
"""

from __future__ import annotations

import cv2
import numpy as np

from schemas import DetectParams, SegmentationMethod
from service.perception import _kernels
from service.perception.errors import InvalidInputError


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


def _otsu(feature: np.ndarray, hist: np.ndarray | None = None) -> tuple[float, float]:
    """Otsu threshold of a ``uint8`` image and its separability (0..1)."""
    if hist is None:
        hist = _histogram(feature)
    total = hist.sum()
    levels = np.arange(256, dtype=np.float64)
    mean_all = (hist * levels).sum() / total
    var_all = (hist * (levels - mean_all) ** 2).sum() / total
    if var_all <= 1e-9:
        return 255.0, 0.0
    weight_low = np.cumsum(hist) / total
    mean_low_sum = np.cumsum(hist * levels) / total
    weight_high = 1.0 - weight_low
    valid = (weight_low > 0) & (weight_high > 0)
    between = np.zeros(256)
    between[valid] = (mean_all * weight_low[valid] - mean_low_sum[valid]) ** 2 / (
        weight_low[valid] * weight_high[valid]
    )
    # With an empty stretch of the histogram between the classes every threshold in it
    # is equally good; the middle one keeps the most margin to both classes.
    peak = between.max()
    best_levels = np.flatnonzero(between >= peak * (1.0 - 1e-12))
    best = int(best_levels[len(best_levels) // 2])
    return float(best), float(peak / var_all)


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


def hysteresis_threshold(cue: np.ndarray, low: float, high: float) -> np.ndarray:
    """Pixels above ``low`` that are 8-connected to a pixel above ``high``."""
    cue = np.ascontiguousarray(cue)
    weak_count = int(np.count_nonzero(cue > low))
    # The fused kernel with no clean-up is the plain hysteresis.
    return _kernels.threshold_and_clean(cue, float(low), float(high), weak_count, 0, 0).view(
        np.bool_
    )


def _cable_like(
    cue: np.ndarray, threshold: float, separability: float, hist: np.ndarray | None = None
) -> bool:
    """Does thresholding this cue look like cables against a background?

    Either the histogram is clearly two-class, or it is moderately so and the bright
    class is a small share of the image: cables are thin, while a split of plain
    texture puts about half the image on each side.
    """
    if separability >= BIMODAL_SEPARABILITY:
        return True
    if hist is None:
        above = np.count_nonzero(cue > threshold)
    else:
        # The threshold is a whole level: the pixels above it are the levels after it.
        above = int(hist[int(threshold) + 1 :].sum())
    share = float(above) / cue.size
    return separability >= THIN_SEPARABILITY and share <= THIN_FOREGROUND_SHARE


def segment_auto(
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
    # No blur: it moves the border of thin cables more than it removes noise, and
    # the clean-up afterwards removes the specks noise leaves.
    brightness, counts = _kernels.brightness_histogram(image_bgr)
    hist = counts.astype(np.float64)
    threshold, separability = _otsu(brightness, hist)
    if _cable_like(brightness, threshold, separability, hist):
        # The mean of the levels up to the threshold, from the histogram: sums of
        # whole numbers are exact in float64, so this is the mean of those pixels.
        level = int(threshold)
        below_count = hist[: level + 1].sum()
        below_sum = (hist[: level + 1] * np.arange(level + 1, dtype=np.float64)).sum()
        background = float(below_sum / below_count) if below_count else 0.0
        low = background + HYSTERESIS_FRACTION * (threshold - background)
        # Pixels above ``low``: the levels from the first whole level above it.
        weak_count = int(hist[max(int(np.floor(low)) + 1, 0) :].sum())
        return _kernels.threshold_and_clean(
            brightness, low, threshold, weak_count, int(min_component_area), int(max_hole_area)
        ).view(np.bool_)
    colourfulness = cue_images(image_bgr)[1]
    colour_hist = _histogram(colourfulness)
    colour_threshold, colour_separability = _otsu(colourfulness, colour_hist)
    if _cable_like(colourfulness, colour_threshold, colour_separability, colour_hist):
        return clean_mask(colourfulness > colour_threshold, min_component_area, max_hole_area)
    # Neither cue looks like cables: an empty table, or cables this method cannot
    # tell from their background. Reporting nothing is safer for a robot than chains
    # traced through texture; such scenes need a mask or an HSV range.
    return np.zeros(brightness.shape, bool)


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
        _kernels.remove_small_components(cleaned, int(min_component_area))
    if max_hole_area > 0:
        _kernels.fill_small_holes(cleaned, int(max_hole_area))
    return cleaned.view(np.bool_)


def segment(image_bgr: np.ndarray, params: DetectParams) -> np.ndarray:
    """Step 1 of the pipeline: the cleaned foreground mask of an image.

    Parameters
    ----------
    image_bgr : ndarray
        ``(H, W, 3)`` ``uint8`` BGR image.
    params : DetectParams
        Uses ``segmentation``, ``hsv_low``, ``hsv_high``, ``min_component_area`` and
        ``max_hole_area``.

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
    if params.segmentation is SegmentationMethod.hsv:
        raw = segment_hsv(image_bgr, params.hsv_low, params.hsv_high)
        return clean_mask(raw, params.min_component_area, params.max_hole_area)
    return segment_auto(image_bgr, params.min_component_area, params.max_hole_area)
