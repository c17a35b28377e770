"""The CPU-bound work of one request, run in a worker thread: decode, check, detect, render,
plan a grasp.

Plain functions of bytes and parameters, so that any front end (HTTP now, a message bus
later) can run them in its pool. Client mistakes raise :class:`RequestError`; anything
else raised here is a failure of the service.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np
from pydantic import ValidationError

from adapters.grasp import (
    DepthImageError,
    GraspPlanningError,
    InferredSegmentError,
    decode_depth_image,
)
from adapters.pick_plan import plan_pick
from schemas import CameraModel, DepthSurface, Detection, DetectParams, GraspSelector
from schemas.grasp import GraspPlan
from service.http.inputs import (
    Frame,
    GraspFrame,
    GraspRequest,
    RequestError,
    describe_fields,
    image_size,
)
from service.imageio import ImageFileError, decode_image, decode_mask
from service.perception import InvalidInputError, render_overlay
from service.perception import detect as detect_dlos
from service.perception.segmenter import Segmenter

DetectFunction = Callable[[np.ndarray, DetectParams, np.ndarray | None], Detection]
"""``detect(image, params, mask) -> Detection``, as :func:`service.perception.detect`."""


def default_detect(image: np.ndarray, params: DetectParams, mask: np.ndarray | None) -> Detection:
    """:func:`service.perception.detect` with positional arguments."""
    return detect_dlos(image, params, mask)


def detect_with_segmenter(segmenter: Segmenter) -> DetectFunction:
    """:func:`default_detect` with ``segmenter`` for requests with ``segmentation=model``."""

    def detect(image: np.ndarray, params: DetectParams, mask: np.ndarray | None) -> Detection:
        return detect_dlos(image, params, mask, segmenter)

    return detect


def check_declared_size(data: bytes, max_pixels: int) -> None:
    """413 when the PNG/JPEG header announces more than ``max_pixels`` pixels."""
    size = image_size(data)
    if size is not None:
        _check_pixels(*size, max_pixels)


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
    _check_pixels(image.shape[1], image.shape[0], max_pixels)
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
    try:
        detection = detect(image, frame.params, mask)
    except InvalidInputError as exc:
        raise RequestError(422, "invalid_input", str(exc)) from None
    return image, detection


def run_overlay(frame: Frame, detect: DetectFunction, max_pixels: int) -> tuple[bytes, Detection]:
    """As :func:`run_detection`, then the overlay drawn on the image, encoded as PNG."""
    image, detection = run_detection(frame, detect, max_pixels)
    encoded_ok, encoded = cv2.imencode(".png", render_overlay(image, detection))
    if not encoded_ok:
        raise RuntimeError("OpenCV could not encode the overlay as PNG")
    return encoded.tobytes(), detection


def run_grasp(
    request: GraspFrame, detect: DetectFunction, max_pixels: int
) -> tuple[GraspPlan, Detection]:
    """Decode the depth image (if any), detect the DLOs in the image, then plan the grasp.

    Returns the plan and the detection. The depth image is decoded first so that a bad
    one is refused (422 ``invalid_depth``) before the detection is paid for.
    """
    depth = None
    if request.depth is not None:
        try:
            depth = decode_depth_image(request.depth)
        except DepthImageError as exc:
            raise RequestError(422, "invalid_depth", f"depth: {exc}") from None
    _, detection = run_detection(request.frame, detect, max_pixels)
    plan = plan_or_refuse(detection, request.camera, request.selector, depth)
    return plan, detection


def plan_from_json(body: bytes) -> GraspPlan:
    """Validate a :class:`GraspRequest` JSON body and plan the grasp it asks for.

    Raises
    ------
    RequestError
        422 ``invalid_detection``, ``invalid_camera`` or ``invalid_selector`` after the
        part that failed first (``invalid_body`` for malformed JSON or unknown keys),
        and as :func:`plan_or_refuse`.
    """
    try:
        request = GraspRequest.model_validate_json(body)
    except ValidationError as exc:
        part = next((str(error["loc"][0]) for error in exc.errors() if error["loc"]), "")
        code = f"invalid_{part}" if part in GraspRequest.model_fields else "invalid_body"
        raise RequestError(422, code, "; ".join(describe_fields(exc))) from None
    if isinstance(request.camera.surface, DepthSurface):
        raise RequestError(
            422,
            "invalid_depth",
            "the camera's surface is a depth image (kind 'depth'), which a JSON body cannot "
            "carry: send multipart/form-data with the image and the file field 'depth'",
        )
    return plan_or_refuse(request.detection, request.camera, request.selector)


def plan_or_refuse(
    detection: Detection,
    camera: CameraModel,
    selector: GraspSelector,
    depth: np.ndarray | None = None,
) -> GraspPlan:
    """:func:`adapters.pick_plan.plan_pick`, its refusals turned into 422 answers.

    A target outside the workspace is not refused: the plan says so
    (``within_workspace``, ``refusal``), since no robot is moved here.

    Raises
    ------
    RequestError
        422 ``invalid_depth`` when the depth image does not fit the camera (size,
        channels, sample type; missing or not wanted); 422 ``inferred_segment`` when the
        point lies on an inferred segment that was not allowed; 422 ``ungraspable`` for
        every other reason there is no grasp: no chain, no such chain id or segment,
        image size other than the camera's, a ray that misses the table, no valid depth
        around the grasp point, or coordinates so extreme the arithmetic overflows.
    """
    try:
        plan = plan_pick(detection, camera, selector, depth=depth)
    except DepthImageError as exc:
        raise RequestError(422, "invalid_depth", f"depth: {exc}") from None
    except InferredSegmentError as exc:
        raise RequestError(422, "inferred_segment", str(exc)) from None
    except GraspPlanningError as exc:
        raise RequestError(422, "ungraspable", str(exc)) from None
    except (ArithmeticError, ValueError, cv2.error) as exc:
        # Finite but absurd numbers in a valid detection or camera (say 1e300 px) overflow
        # on the way; that is the client's input, not a failure of the service.
        raise RequestError(
            422,
            "ungraspable",
            f"no grasp can be computed from these values: {type(exc).__name__}: "
            f"{' '.join(str(exc).split())}",
        ) from None
    if not all(math.isfinite(value) for value in plan.target.position_m):
        raise RequestError(
            422,
            "ungraspable",
            f"the grasp point {list(plan.target.position_m)} is not finite: the ray through "
            f"pixel {list(plan.target.pixel)} meets the table too far away",
        )
    return plan


def warm_up(detect: DetectFunction) -> Detection:
    """One detection on a tiny synthetic image (two crossing strokes), to load everything."""
    image = np.full((96, 160, 3), 30, np.uint8)
    cv2.line(image, (8, 20), (150, 80), (40, 160, 230), 7, cv2.LINE_AA)
    cv2.line(image, (10, 85), (150, 15), (230, 120, 40), 7, cv2.LINE_AA)
    return detect(image, DetectParams(), None)


def _check_pixels(width: int, height: int, max_pixels: int) -> None:
    if width * height > max_pixels:
        raise RequestError(
            413,
            "image_too_large",
            f"image is {width}x{height} = {width * height / 1e6:.1f} megapixels, "
            f"more than the limit of {max_pixels / 1e6:g}",
        )
