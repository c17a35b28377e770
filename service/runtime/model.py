"""A MuJoCo model of the cables as a job of the runtime: detect the cables in a frame, lift
the chains to the robot base frame with a camera model (and depth image), write the MJCF.

The lifting is :func:`service.geometry3d.lift` and the model :func:`service.simulation.to_mjcf`;
here their refusals become :class:`~service.runtime.errors.RequestError` answers (422).
"""

from __future__ import annotations

from dataclasses import dataclass

from schemas import CameraModel, Detection
from schemas.model import CablePhysics
from service.geometry3d import DepthImageError, LiftError, lift
from service.runtime.errors import RequestError
from service.runtime.frames import Frame
from service.runtime.grasp import decode_depth_part
from service.runtime.jobs import DetectFunction, run_detection
from service.simulation import ModelError, to_mjcf
from service.simulation.mjcf import with_surface


@dataclass(frozen=True)
class ModelFrame:
    """A model of the cables in an image: the frame to detect, the camera, the physics.

    ``depth`` is the encoded depth image (16-bit PNG), present exactly when the camera's
    surface is a depth image.
    """

    frame: Frame
    camera: CameraModel
    physics: CablePhysics
    depth: bytes | None = None


def run_model(
    request: ModelFrame, detect: DetectFunction, max_pixels: int, budget_s: float | None = None
) -> tuple[str, Detection]:
    """Decode the depth image (if any), detect, lift and write the MJCF.

    Returns the MJCF text and the lifted detection. The depth image is decoded first, so
    that a bad one is refused (422 ``invalid_depth``) before the detection is paid for.

    Raises
    ------
    RequestError
        422 ``invalid_depth`` (the depth image cannot be decoded or does not fit the
        camera), ``invalid_camera`` (the image's size is not the camera's) or
        ``invalid_physics`` (physics the model would not be stable with).
    """
    depth = decode_depth_part(request.depth)
    _, detection = run_detection(request.frame, detect, max_pixels, budget_s)
    try:
        lifted = lift(detection, request.camera, depth)
    except DepthImageError as exc:
        raise RequestError(422, "invalid_depth", f"depth: {exc}") from None
    except LiftError as exc:
        raise RequestError(422, "invalid_camera", f"camera: {exc}") from None
    physics = with_surface(request.physics, request.camera)
    try:
        return to_mjcf(lifted, **physics.model_dump()), lifted
    except ModelError as exc:
        raise RequestError(422, "invalid_physics", f"physics: {exc}") from None
