"""The CPU-bound work of one detection, run in a worker thread: decode, check, detect, render.

Plain functions of bytes and parameters, so that every front end (the HTTP routes, the
zenoh bus) runs the same code in its own thread or pool. Client mistakes raise
:class:`~service.runtime.errors.RequestError`; anything else raised here is a failure of
the service.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from schemas import Detection, DetectParams
from service.imageio import ImageFileError, decode_image, decode_mask
from service.perception import InvalidInputError, render_overlay
from service.perception import detect as detect_dlos
from service.perception import warm_up as warm_up_kernels
from service.runtime.errors import RequestError
from service.runtime.frames import Frame, check_pixels

DetectFunction = Callable[[np.ndarray, DetectParams, np.ndarray | None], Detection]
"""``detect(image, params, mask) -> Detection``, as :func:`service.perception.detect`."""


def default_detect(image: np.ndarray, params: DetectParams, mask: np.ndarray | None) -> Detection:
    """:func:`service.perception.detect` with positional arguments."""
    return detect_dlos(image, params, mask)


def decode_frame(frame: Frame, max_pixels: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Decode and check the image and the mask of ``frame``.

    Returns
    -------
    (image, mask)
        BGR ``uint8`` image, and the boolean mask of its size or None.

    Raises
    ------
    RequestError
        422 when either cannot be decoded (saying which and why), the mask's size differs
        or it marks nothing; 413 when the image has more than ``max_pixels`` pixels.
    """
    try:
        image = decode_image(frame.image, "image")
    except ImageFileError as exc:
        raise RequestError(422, "invalid_image", str(exc)) from None
    check_pixels(image.shape[1], image.shape[0], max_pixels)
    if frame.mask is None:
        return image, None
    try:
        mask = decode_mask(frame.mask, image.shape, "mask")
    except ImageFileError as exc:
        raise RequestError(422, "invalid_mask", str(exc)) from None
    if not mask.any():
        raise RequestError(422, "invalid_mask", "mask: empty, it marks no cable pixel")
    return image, mask


def run_detection(
    frame: Frame, detect: DetectFunction, max_pixels: int
) -> tuple[np.ndarray, Detection]:
    """Decode ``frame`` and detect the DLOs in it; returns the image and the Detection."""
    image, mask = decode_frame(frame, max_pixels)
    return image, detect_decoded(image, frame.params, detect, mask)


def detect_decoded(
    image: np.ndarray, params: DetectParams, detect: DetectFunction, mask: np.ndarray | None = None
) -> Detection:
    """Detect the DLOs in an image already decoded (and checked); 422 for unusable input."""
    try:
        return detect(image, params, mask)
    except InvalidInputError as exc:
        raise RequestError(422, "invalid_input", str(exc)) from None


def run_overlay(frame: Frame, detect: DetectFunction, max_pixels: int) -> tuple[bytes, Detection]:
    """As :func:`run_detection`, then the overlay drawn on the image, encoded as PNG."""
    image, detection = run_detection(frame, detect, max_pixels)
    encoded_ok, encoded = cv2.imencode(".png", render_overlay(image, detection))
    if not encoded_ok:
        raise RuntimeError("OpenCV could not encode the overlay as PNG")
    return encoded.tobytes(), detection


def warm_up(detect: DetectFunction) -> Detection:
    """Load every compiled kernel (compiling them on a machine's first run), then run one
    detection on a tiny synthetic image (two crossing strokes) through ``detect``: after
    this no request pays for loading code, and its ``timings_ms`` are detection alone."""
    warm_up_kernels()
    image = np.full((96, 160, 3), 30, np.uint8)
    cv2.line(image, (8, 20), (150, 80), (40, 160, 230), 7, cv2.LINE_AA)
    cv2.line(image, (10, 85), (150, 15), (230, 120, 40), 7, cv2.LINE_AA)
    return detect(image, DetectParams(), None)
