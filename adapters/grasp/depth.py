"""Depth images for grasp planning: decode, check against the camera, convert, sample.

A depth image is a single-channel 16-bit PNG (or a ``.npy`` array of uint16 or float
samples) aligned with the colour image, in units of the camera surface's ``depth_scale``
metres. The depth at a pixel is the sample of the *nearest* pixel (see
:mod:`adapters.grasp.target` for why not a blend); a missing one is filled with the median
of the valid samples in a window around it.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from adapters.grasp.errors import DepthImageError
from schemas import CameraModel, DepthSurface

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

DEPTH_SAMPLE_TYPES = (np.dtype(np.uint16), np.dtype(np.float32), np.dtype(np.float64))
"""Sample types of a depth image: uint16 (16-bit PNG) or float (``.npy``)."""


def depth_in_metres(camera: CameraModel, depth: np.ndarray | None) -> np.ndarray | None:
    """Check ``depth`` against ``camera`` and convert it to metres, NaN where not valid.

    Returns
    -------
    np.ndarray or None
        ``(height, width)`` float64 metres along the optical axis; NaN where the sample
        is not finite, not positive or outside the surface's ``[min_depth_m,
        max_depth_m]``. None for a plane surface (and no depth image).

    Raises
    ------
    DepthImageError
        A depth surface without a depth image, a plane surface with one, or a depth
        image of another size than the camera's, with more than one channel or with
        samples other than uint16 or float.
    """
    surface = camera.surface
    if not isinstance(surface, DepthSurface):
        if depth is not None:
            raise DepthImageError(
                f"a depth image was given but the camera's surface is the plane z = "
                f"{surface.plane_z} m; set the surface to "
                '{"kind": "depth", "depth_scale": ...} to use it'
            )
        return None
    if depth is None:
        raise DepthImageError(
            "the camera's surface is a depth image (kind 'depth') but no depth image was given"
        )
    samples = check_depth_image(camera, depth)
    metres = samples.astype(np.float64) * surface.depth_scale
    with np.errstate(invalid="ignore"):
        invalid = ~np.isfinite(metres) | (metres <= 0)
        if surface.min_depth_m is not None:
            invalid |= metres < surface.min_depth_m
        if surface.max_depth_m is not None:
            invalid |= metres > surface.max_depth_m
    metres[invalid] = np.nan
    return metres


def check_depth_image(camera: CameraModel, depth: np.ndarray) -> np.ndarray:
    """``depth`` as a ``(height, width)`` array after checking its shape and sample type.

    Raises
    ------
    DepthImageError
        When it is not a single-channel uint16 or float array of the camera's size.
    """
    if not isinstance(depth, np.ndarray):
        raise DepthImageError(f"a depth image is an array, not {type(depth).__name__}")
    if depth.ndim == 3 and depth.shape[2] == 1:
        depth = depth[:, :, 0]
    if depth.ndim != 2:
        channels = f"{depth.shape[2]} channels" if depth.ndim == 3 else f"shape {depth.shape}"
        raise DepthImageError(f"a depth image has one channel, not {channels}")
    if depth.dtype not in DEPTH_SAMPLE_TYPES:
        raise DepthImageError(
            f"depth samples are uint16 (a 16-bit PNG) or float32/float64 (.npy), not {depth.dtype}"
        )
    height, width = depth.shape
    if (width, height) != (camera.width, camera.height):
        raise DepthImageError(
            f"depth image is {width}x{height} px but the camera model is "
            f"{camera.width}x{camera.height} px"
        )
    return depth


def depth_at(depth_m: np.ndarray, pixel: tuple[float, float], window: int) -> float | None:
    """The depth (metres) at the pixel nearest to ``pixel``, filled when missing.

    Parameters
    ----------
    depth_m
        Depth in metres, NaN where missing (:func:`depth_in_metres`).
    pixel
        ``(x, y)``, pixel centres at integer coordinates.
    window
        Side (odd, pixels) of the square around the pixel whose valid samples' median
        fills a missing one.

    Returns
    -------
    float or None
        None when neither the pixel nor its window (clipped to the image) holds a valid
        sample; a pixel outside the image has no sample of its own but may still have
        valid ones in its window.
    """
    height, width = depth_m.shape
    column, row = math.floor(pixel[0] + 0.5), math.floor(pixel[1] + 0.5)
    if 0 <= row < height and 0 <= column < width:
        value = depth_m[row, column]
        if not math.isnan(value):
            return float(value)
    half = window // 2
    rows = slice(max(row - half, 0), max(min(row + half + 1, height), 0))
    columns = slice(max(column - half, 0), max(min(column + half + 1, width), 0))
    samples = depth_m[rows, columns]
    valid = samples[~np.isnan(samples)]
    if valid.size == 0:
        return None
    return float(np.median(valid))


def describe_valid_depth(surface: DepthSurface) -> str:
    """What counts as a valid depth sample, for error messages."""
    low = "> 0 m" if surface.min_depth_m is None else f">= {surface.min_depth_m} m"
    high = "" if surface.max_depth_m is None else f" and <= {surface.max_depth_m} m"
    return f"valid: finite, {low}{high}"


def decode_depth_image(data: bytes) -> np.ndarray:
    """Decode an encoded depth image (a 16-bit single-channel PNG), samples unchanged.

    Returns
    -------
    np.ndarray
        ``(height, width)`` uint16 (or float32, for a float TIFF) samples, unscaled.

    Raises
    ------
    DepthImageError
        When ``data`` is empty, truncated or not an image, has more than one channel,
        or has 8-bit samples (a picture of the depth, not the depth).
    """
    if not data:
        raise DepthImageError("empty file (0 bytes)")
    previous = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # errors are ours
    try:
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as error:
        raise DepthImageError(f"cannot decode: {' '.join(str(error).split())}") from None
    finally:
        cv2.utils.logging.setLogLevel(previous)
    if image is None or image.size == 0:
        if data.startswith(PNG_SIGNATURE):
            raise DepthImageError("truncated or corrupt PNG file")
        raise DepthImageError("not an image, or a format OpenCV cannot decode")
    if image.ndim == 3 and image.shape[2] != 1:
        raise DepthImageError(
            f"has {image.shape[2]} channels; a depth image is a single-channel 16-bit PNG"
        )
    if image.dtype == np.uint8:
        raise DepthImageError(
            "has 8-bit samples; a depth image is a 16-bit PNG (an 8-bit one is a picture of "
            "the depth, too coarse to measure it)"
        )
    return image.reshape(image.shape[:2])
