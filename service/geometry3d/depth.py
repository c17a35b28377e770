"""Depth images: decode, check against the camera, convert, sample (grasping and lifting).

A depth image is a single-channel 16-bit PNG (or a ``.npy`` array of uint16 or float
samples) aligned with the colour image, in units of the camera surface's ``depth_scale``
metres. The depth at a pixel is the sample of the *nearest* pixel, not a bilinear blend:
across the edge of a box or a cable lying on another, a blend would invent a point in
mid-air, while the nearest sample always lies on something seen (on a smooth slope it costs
at most half a pixel's change of depth). A missing one is filled with the median of the
valid samples in a window around it.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np

from schemas import CameraModel, DepthSurface
from service.geometry3d.errors import DepthImageError

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
        As :func:`checked_depth`.
    """
    samples = checked_depth(camera, depth)
    if samples is None:
        return None
    surface = camera.surface
    assert isinstance(surface, DepthSurface)
    return to_metres(surface, samples)


def checked_depth(camera: CameraModel, depth: np.ndarray | None) -> np.ndarray | None:
    """The depth samples after checking them against the camera's surface, unconverted.

    Returns None for a plane surface (and no depth image); a ``(height, width)`` array of
    :data:`DEPTH_SAMPLE_TYPES` for a depth surface.

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
    return check_depth_image(camera, depth)


def to_metres(surface: DepthSurface, samples: np.ndarray) -> np.ndarray:
    """Depth samples (any shape) in metres, float64, NaN where not valid for ``surface``."""
    metres = np.asarray(samples).astype(np.float64) * surface.depth_scale
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
    value = depth_at_pixels(depth_m, np.asarray([pixel], dtype=float), window)[0]
    return None if math.isnan(value) else float(value)


def depth_at_pixels(
    depth: np.ndarray, pixels: np.ndarray, window: int, surface: DepthSurface | None = None
) -> np.ndarray:
    """:func:`depth_at` for many pixels at once: ``(N, 2)`` ``[x, y]`` in, ``(N,)`` metres out.

    ``depth`` is in metres with NaN where missing (:func:`depth_in_metres`), or, with
    ``surface``, the raw samples (:func:`checked_depth`), of which only those looked at
    are converted. NaN where :func:`depth_at` gives None (and for a non-finite pixel).
    """

    def metres(values: np.ndarray) -> np.ndarray:
        if surface is None:
            return np.asarray(values, dtype=np.float64)
        return to_metres(surface, values)

    height, width = depth.shape[:2]
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    depths = np.full(len(pixels), np.nan)
    finite = np.isfinite(pixels).all(axis=1)
    # Far outside the image nothing is sampled; clipping first keeps the integers small.
    limit = float(max(width, height) + window)
    nearest = np.floor(np.clip(np.where(finite[:, None], pixels, 0.0), -limit, limit) + 0.5)
    columns, rows = nearest.astype(np.int64).T
    inside = finite & (rows >= 0) & (rows < height) & (columns >= 0) & (columns < width)
    depths[inside] = metres(depth[rows[inside], columns[inside]])
    half = window // 2
    for index in np.flatnonzero(finite & np.isnan(depths)):
        row, column = rows[index], columns[index]
        samples = metres(
            depth[
                max(row - half, 0) : max(min(row + half + 1, height), 0),
                max(column - half, 0) : max(min(column + half + 1, width), 0),
            ]
        )
        valid = samples[~np.isnan(samples)]
        if valid.size:
            depths[index] = float(np.median(valid))
    return depths


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


NUMPY_SUFFIX = ".npy"
"""A depth file with this suffix is a NumPy array; anything else an image (16-bit PNG)."""


def read_depth_file(path: str | os.PathLike[str]) -> np.ndarray:
    """The depth samples in a file, unscaled: a ``.npy`` array, else a 16-bit PNG.

    Raises
    ------
    OSError
        The file cannot be read.
    DepthImageError
        It is not a NumPy array (for ``.npy``) or not a usable depth image
        (:func:`decode_depth_image`).
    """
    path = Path(path)
    if path.suffix.lower() != NUMPY_SUFFIX:
        return decode_depth_image(path.read_bytes())
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, EOFError) as error:  # not an .npy file, or cut short
        raise DepthImageError(f"not a NumPy .npy array: {' '.join(str(error).split())}") from None
