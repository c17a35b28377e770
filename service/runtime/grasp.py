"""Grasp planning as a job of the runtime: detect the cables in a frame (or take a saved
Detection), then plan where to grasp and the UR3 motions, without moving any robot.

The planning itself is :mod:`adapters.grasp.pick`; here its refusals become
:class:`~service.runtime.errors.RequestError` answers (422), and the inputs of one plan are
gathered: :class:`GraspFrame` (an image to detect, with a camera model and a selector) or
:class:`GraspRequest` (a saved Detection, as JSON).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from adapters.grasp.errors import DepthImageError, GraspPlanningError, InferredSegmentError
from adapters.grasp.pick import plan_pick
from schemas import CameraModel, DepthSurface, Detection, GraspSelector
from schemas.grasp import GraspPlan
from service.geometry3d.depth import decode_depth_image
from service.runtime.errors import RequestError, describe_fields
from service.runtime.frames import Frame
from service.runtime.jobs import DetectFunction, run_detection


class GraspRequest(BaseModel):
    """A plan on a saved detection: the ``application/json`` body of ``POST /v1/grasp``."""

    model_config = ConfigDict(extra="forbid")

    detection: Detection = Field(description="The chains, as `/v1/detect` or `dlo detect` give.")
    camera: CameraModel = Field(description="Intrinsics, pose in the robot base frame, table.")
    selector: GraspSelector = Field(
        default_factory=GraspSelector,
        description="Which chain and point; default: the middle of the longest chain.",
    )


@dataclass(frozen=True)
class GraspFrame:
    """A plan on an image: the frame to detect, the camera and the selector.

    ``depth`` is the encoded depth image (16-bit PNG), present exactly when the camera's
    surface is a depth image.
    """

    frame: Frame
    camera: CameraModel
    selector: GraspSelector
    depth: bytes | None = None


def run_grasp(
    request: GraspFrame, detect: DetectFunction, max_pixels: int, budget_s: float | None = None
) -> tuple[GraspPlan, Detection]:
    """Decode the depth image (if any), detect the DLOs in the image, then plan the grasp.

    Returns the plan and the detection. The depth image is decoded first so that a bad
    one is refused (422 ``invalid_depth``) before the detection is paid for.
    """
    depth = decode_depth_part(request.depth)
    _, detection = run_detection(request.frame, detect, max_pixels, budget_s)
    plan = plan_or_refuse(detection, request.camera, request.selector, depth)
    return plan, detection


def decode_depth_part(data: bytes | None) -> np.ndarray | None:
    """The depth image sent as a form part, decoded (422 ``invalid_depth`` if it cannot be)."""
    if data is None:
        return None
    try:
        return decode_depth_image(data)
    except DepthImageError as exc:
        raise RequestError(422, "invalid_depth", f"depth: {exc}") from None


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
    """:func:`adapters.grasp.pick.plan_pick`, its refusals turned into 422 answers.

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
