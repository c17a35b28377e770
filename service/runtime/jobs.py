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
from service.allocator import keep_freed_memory
from service.imageio import ImageFileError, decode_image, decode_mask
from service.perception import (
    Deadline,
    DeadlineExceeded,
    InvalidInputError,
    detect_full,
    render_labels,
    render_overlay,
)
from service.perception import detect as detect_dlos
from service.perception import warm_up as warm_up_kernels
from service.perception.segmenter import Segmenter
from service.runtime.errors import RequestError
from service.runtime.frames import Frame, check_pixels

DetectFunction = Callable[[np.ndarray, DetectParams, np.ndarray | None, Deadline | None], Detection]
"""``detect(image, params, mask, deadline) -> Detection``, as :func:`service.perception.detect`;
``deadline`` is the request's time budget (None: none), to be checked as it goes."""

OVER_BUDGET = "time_budget_exceeded"
"""The code of the answer to a detection stopped at its time budget."""


def default_detect(
    image: np.ndarray, params: DetectParams, mask: np.ndarray | None, deadline: Deadline | None
) -> Detection:
    """:func:`service.perception.detect` with positional arguments."""
    return detect_dlos(image, params, mask, deadline=deadline)


def detect_with_segmenter(segmenter: Segmenter) -> DetectFunction:
    """:func:`default_detect` with ``segmenter`` for requests with ``segmentation=model``."""

    def detect(
        image: np.ndarray,
        params: DetectParams,
        mask: np.ndarray | None,
        deadline: Deadline | None,
    ) -> Detection:
        return detect_dlos(image, params, mask, segmenter=segmenter, deadline=deadline)

    return detect


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
    return image, decode_upload_mask(frame.mask, image.shape)


def decode_upload_mask(data: bytes, shape: tuple[int, ...]) -> np.ndarray:
    """Decode an uploaded mask (PNG or JPEG, non-zero = cable) for an image of ``shape``.

    Raises
    ------
    RequestError
        422 ``invalid_mask`` when it cannot be decoded, its size differs from the image's
        or it marks nothing.
    """
    try:
        mask = decode_mask(data, shape, "mask")
    except ImageFileError as exc:
        raise RequestError(422, "invalid_mask", str(exc)) from None
    if not mask.any():
        raise RequestError(422, "invalid_mask", "mask: empty, it marks no cable pixel")
    return mask


def run_detection(
    frame: Frame, detect: DetectFunction, max_pixels: int, budget_s: float | None = None
) -> tuple[np.ndarray, Detection]:
    """Decode ``frame`` and detect the DLOs in it; returns the image and the Detection.

    ``budget_s`` is the time the decoding and the detection may take together, counted
    from now (the worker taking the job up); None: no limit.

    Raises
    ------
    RequestError
        As :func:`decode_frame`; 422 ``invalid_input`` for input the detector cannot use;
        422 :data:`OVER_BUDGET` when the budget ran out (the detection stopped, the
        thread is free again).
    """
    deadline = budget(budget_s)
    image, mask = decode_frame(frame, max_pixels)
    return image, detect_decoded(image, frame.params, detect, mask, deadline)


def budget(seconds: float | None) -> Deadline | None:
    """The deadline ``seconds`` from now (None: no limit)."""
    return None if seconds is None else Deadline(seconds)


def detect_decoded(
    image: np.ndarray,
    params: DetectParams,
    detect: DetectFunction,
    mask: np.ndarray | None = None,
    deadline: Deadline | None = None,
) -> Detection:
    """Detect the DLOs in an image already decoded (and checked): as :func:`run_detection`
    after the decoding (422 for unusable input, or when ``deadline`` passes)."""
    try:
        return detect(image, params, mask, deadline)
    except InvalidInputError as exc:
        raise RequestError(422, "invalid_input", str(exc)) from None
    except DeadlineExceeded as exc:
        raise over_budget(exc) from None


def over_budget(exc: DeadlineExceeded) -> RequestError:
    """The 422 answer to a detection stopped at its time budget.

    Not 503 (busy: retry in a second) nor another 5xx: the same image would run out of
    time again, so a retrying client must not be invited to send it back; like 413 for
    too many pixels, the content asks more than the service gives one request.
    """
    return RequestError(
        422,
        OVER_BUDGET,
        f"{exc} (DLO_MAX_DETECT_SECONDS): this image holds more cable pieces than can be "
        "detected in that time; send a smaller image or a crop, or a mask",
    )


def run_overlay(
    frame: Frame, detect: DetectFunction, max_pixels: int, budget_s: float | None = None
) -> tuple[bytes, Detection]:
    """As :func:`run_detection`, then the overlay drawn on the image, encoded as PNG."""
    image, detection = run_detection(frame, detect, max_pixels, budget_s)
    encoded_ok, encoded = cv2.imencode(".png", render_overlay(image, detection))
    if not encoded_ok:
        raise RuntimeError("OpenCV could not encode the overlay as PNG")
    return encoded.tobytes(), detection


def run_labels(
    frame: Frame, segmenter: Segmenter | None, max_pixels: int, budget_s: float | None = None
) -> tuple[bytes, Detection]:
    """Decode ``frame``, detect, and render the instance labels (as ``dlo detect`` writes
    ``<stem>.labels.png``: 16-bit, 0 background, chain *i* as *i* + 1), encoded as PNG.

    The labels need the mask the detection used, so this runs the pipeline itself
    (:func:`service.perception.detect_full`, with ``segmenter`` for ``segmentation=model``),
    not a front end's injected detect function. Errors as :func:`run_detection`.
    """
    deadline = None if budget_s is None else Deadline(budget_s)
    image, mask = decode_frame(frame, max_pixels)
    try:
        result = detect_full(image, frame.params, mask, segmenter=segmenter, deadline=deadline)
    except InvalidInputError as exc:
        raise RequestError(422, "invalid_input", str(exc)) from None
    except DeadlineExceeded as exc:
        raise over_budget(exc) from None
    labels = render_labels(result.detection, result.mask, image)
    encoded_ok, encoded = cv2.imencode(".png", labels)
    if not encoded_ok:
        raise RuntimeError("OpenCV could not encode the labels as PNG")
    return encoded.tobytes(), result.detection


def warm_up(detect: DetectFunction) -> Detection:
    """Load every compiled kernel (compiling them on a machine's first run), then run one
    detection on a tiny synthetic image (two crossing strokes) through ``detect``: after
    this no request pays for loading code, and its ``timings_ms`` are detection alone.
    The process keeps the memory a detection frees for the next (:mod:`service.allocator`)."""
    keep_freed_memory()
    warm_up_kernels()
    image = np.full((96, 160, 3), 30, np.uint8)
    cv2.line(image, (8, 20), (150, 80), (40, 160, 230), 7, cv2.LINE_AA)
    cv2.line(image, (10, 85), (150, 15), (230, 120, 40), 7, cv2.LINE_AA)
    return detect(image, DetectParams(), None, None)
