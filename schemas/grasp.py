"""Grasping: the camera model, which point of a detection to grasp, and the grasp target.

Frames and units
----------------
* Pixels follow :mod:`schemas.detection` (``x`` column, ``y`` row, origin at the centre
  of the top-left pixel), which is also OpenCV's convention.
* The camera frame is OpenCV's: ``+z`` along the optical axis, ``+x`` towards growing
  columns, ``+y`` towards growing rows.
* Depth, in a depth image, is the camera-frame ``z`` of the point seen at a pixel
  (distance along the optical axis), as depth cameras report it.
* The base frame is the robot base frame; every length in it is in metres and every
  angle in radians.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    field_validator,
    model_validator,
)

Matrix4 = tuple[
    tuple[float, float, float, float],
    tuple[float, float, float, float],
    tuple[float, float, float, float],
    tuple[float, float, float, float],
]

ROTATION_TOLERANCE = 1e-4
"""Largest entry of ``R^T R - I`` (and deviation of ``det R`` from 1) accepted in
``T_base_camera``: loose enough for a calibration written out with 5 decimals."""

MAX_DEPTH_WINDOW = 101
"""Largest fill window, pixels: beyond it the median would describe another surface."""


class PlaneSurface(BaseModel):
    """The surface the cables lie on: the horizontal plane ``z = plane_z`` of the base frame."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["plane"] = "plane"
    plane_z: float = Field(description="Height of the table plane in the base frame, metres.")


class DepthSurface(BaseModel):
    """The surface the cables lie on, measured by a depth image aligned with the colour image.

    The depth image itself is data sent next to the camera model (a 16-bit PNG or a
    ``.npy`` array); this says how to read it. It has the camera's ``width`` x ``height``
    and holds, for each pixel, the distance along the camera's optical axis (the camera
    frame's ``z``, not the length of the ray) in units of ``depth_scale`` metres. A
    sample is valid when it is finite, positive and inside ``[min_depth_m, max_depth_m]``;
    a missing one (0 or NaN, as depth cameras write) at a pixel that is needed is filled
    with the median of the valid samples in the ``window`` x ``window`` square around it.

    Examples
    --------
    ``{"kind": "depth", "depth_scale": 0.001}``: uint16 millimetres (RealSense, Azure
    Kinect); ``{"kind": "depth", "depth_scale": 1.0}``: float32 metres.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["depth"]
    depth_scale: float = Field(
        gt=0,
        allow_inf_nan=False,
        description="Metres per depth unit: 0.001 for uint16 millimetres, 1.0 for float metres.",
    )
    min_depth_m: float | None = Field(
        None, ge=0, allow_inf_nan=False, description="Nearer samples are missing, metres."
    )
    max_depth_m: float | None = Field(
        None, gt=0, allow_inf_nan=False, description="Farther samples are missing, metres."
    )
    window: int = Field(
        5,
        ge=1,
        le=MAX_DEPTH_WINDOW,
        description="Side of the square (odd, pixels) around a pixel whose depth is missing "
        "in which the median of the valid samples fills it.",
    )

    @field_validator("window")
    @classmethod
    def _odd_window(cls, value: int) -> int:
        if value % 2 == 0:
            raise ValueError(f"window must be odd so that it centres on the pixel, got {value}")
        return value

    @model_validator(mode="after")
    def _range_not_empty(self) -> DepthSurface:
        if (
            self.min_depth_m is not None
            and self.max_depth_m is not None
            and self.min_depth_m >= self.max_depth_m
        ):
            raise ValueError(
                f"min_depth_m ({self.min_depth_m}) must be less than max_depth_m "
                f"({self.max_depth_m})"
            )
        return self


def _surface_kind(value: Any) -> str | None:
    # Camera files written before depth surfaces existed say {"plane_z": ...} without a kind.
    if isinstance(value, dict):
        return value.get("kind", "plane")
    return getattr(value, "kind", None)


Surface = Annotated[
    Annotated[PlaneSurface, Tag("plane")] | Annotated[DepthSurface, Tag("depth")],
    Discriminator(
        _surface_kind,
        custom_error_type="surface_kind",
        custom_error_message="surface must be an object whose kind is 'plane' (the default) "
        "or 'depth'",
    ),
]
"""A :class:`PlaneSurface` (``kind`` may be left out) or a :class:`DepthSurface`."""


class CameraModel(BaseModel):
    """A calibrated pinhole camera with OpenCV distortion, placed in the robot base frame.

    ``T_base_camera`` maps camera coordinates to base coordinates
    (``p_base = R p_camera + t``), row-major, translation in metres.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    fx: float = Field(gt=0, description="Focal length along x, pixels.")
    fy: float = Field(gt=0, description="Focal length along y, pixels.")
    cx: float = Field(description="Principal point column, pixels.")
    cy: float = Field(description="Principal point row, pixels.")
    width: int = Field(gt=0, description="Image width the intrinsics belong to, pixels.")
    height: int = Field(gt=0, description="Image height the intrinsics belong to, pixels.")
    dist: tuple[float, float, float, float, float] = Field(
        (0.0, 0.0, 0.0, 0.0, 0.0),
        description="Distortion coefficients in OpenCV order k1, k2, p1, p2, k3.",
    )
    T_base_camera: Matrix4 = Field(
        description="4x4 rigid transform from camera to base frame, row-major, metres."
    )
    surface: Surface = Field(
        description="Where the cables lie: the table plane, or a depth image aligned with "
        "the colour image."
    )

    @field_validator("T_base_camera")
    @classmethod
    def _rigid_transform(cls, value: Matrix4) -> Matrix4:
        if any(not math.isfinite(entry) for row in value for entry in row):
            raise ValueError("T_base_camera has a non-finite entry")
        if tuple(value[3]) != (0.0, 0.0, 0.0, 1.0):
            raise ValueError(f"T_base_camera last row must be [0, 0, 0, 1], got {list(value[3])}")
        rotation = [row[:3] for row in value[:3]]
        for i in range(3):
            for j in range(3):
                dot = sum(rotation[k][i] * rotation[k][j] for k in range(3))
                if abs(dot - (1.0 if i == j else 0.0)) > ROTATION_TOLERANCE:
                    raise ValueError(
                        "T_base_camera rotation is not orthonormal "
                        f"(column {i} . column {j} = {dot:.6f})"
                    )
        (a, b, c), (d, e, f), (g, h, i) = rotation
        det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
        if abs(det - 1.0) > ROTATION_TOLERANCE:
            raise ValueError(f"T_base_camera rotation has determinant {det:.6f}, not +1")
        return value

    @classmethod
    def from_file(cls, path: str | Path) -> CameraModel:
        """Load a camera model from a ``.json``, ``.yaml`` or ``.yml`` file (YAML: PyYAML).

        Raises
        ------
        ValueError
            On an unknown extension, YAML that does not parse, when PyYAML is needed but
            missing, or when the content is not a valid camera model (a pydantic
            ``ValidationError``).
        OSError
            When the file cannot be read.
        """
        path = Path(path)
        suffix = path.suffix.lower()
        text = path.read_text(encoding="utf-8")
        if suffix == ".json":
            return cls.model_validate_json(text)
        if suffix in (".yaml", ".yml"):
            try:
                import yaml
            except ImportError as error:
                raise ValueError(
                    f"{path}: reading YAML needs PyYAML, which is not installed; "
                    "install pyyaml or give the camera model as JSON"
                ) from error
            try:
                data: Any = yaml.safe_load(text)
            except yaml.YAMLError as error:
                # A ValueError, like every other bad content, so callers catch one type.
                raise ValueError(f"{path}: not valid YAML: {_one_line(str(error))}") from None
            return cls.model_validate(data)
        raise ValueError(f"{path}: camera model must be .json, .yaml or .yml, not {suffix!r}")

    def to_json_file(self, path: str | Path) -> None:
        """Write the model as indented JSON (the format :meth:`from_file` reads back)."""
        Path(path).write_text(json.dumps(self.model_dump(), indent=2) + "\n", encoding="utf-8")


class FractionPoint(BaseModel):
    """The point at ``value`` of the chain's arc length from its first point (0 to 1)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["fraction"] = "fraction"
    value: float = Field(ge=0, le=1)


class SegmentPoint(BaseModel):
    """The midpoint of segment ``index`` (points ``index`` to ``index + 1``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["segment"] = "segment"
    index: int = Field(ge=0)


class PixelPoint(BaseModel):
    """The point of the chain nearest to the pixel ``(x, y)``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["pixel"] = "pixel"
    x: float
    y: float


class EndPoint(BaseModel):
    """The first (``start``) or last (``end``) point of the chain."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["end"] = "end"
    end: Literal["start", "end"]


GraspPoint = Annotated[
    FractionPoint | SegmentPoint | PixelPoint | EndPoint, Field(discriminator="kind")
]


class GraspSelector(BaseModel):
    """Which chain of a detection to grasp and where along it.

    Examples
    --------
    ``{"chain": "longest", "point": {"kind": "fraction", "value": 0.5}}`` is the middle
    of the longest chain; ``{"chain": 3, "point": {"kind": "end", "end": "start"}}`` the
    first point of chain 3.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    chain: int | Literal["longest"] = Field(
        "longest", description="Chain id, or the longest chain (ties: the lowest id)."
    )
    point: GraspPoint = Field(default_factory=lambda: FractionPoint(value=0.5))
    allow_inferred: bool = Field(
        False, description="Accept a point on a segment that was inferred, not seen."
    )

    @field_validator("chain")
    @classmethod
    def _non_negative_id(cls, value: int | str) -> int | str:
        if isinstance(value, int) and value < 0:
            raise ValueError(f"chain id must be >= 0, got {value}")
        return value


class GraspTarget(BaseModel):
    """Where and how to grasp, in the robot base frame.

    ``yaw_rad`` is the direction, about base ``+z`` from base ``+x``, along which the
    gripper fingers close: perpendicular to the cable's local tangent on the surface.
    A parallel gripper is symmetric under a half turn, so it lies in ``(-pi/2, pi/2]``.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    position_m: tuple[float, float, float] = Field(description="Grasp point [x, y, z], metres.")
    yaw_rad: float = Field(gt=-math.pi / 2, le=math.pi / 2)
    chain_id: int = Field(ge=0)
    segment_index: int = Field(ge=0, description="Segment of the chain the point lies on.")
    inferred: bool = Field(description="The segment was inferred (not seen in the image).")
    pixel: tuple[float, float] = Field(description="The grasp point in the image [x, y], px.")


Pose = tuple[float, float, float, float, float, float]
"""A UR tool pose ``[x, y, z, rx, ry, rz]``: metres and a rotation vector in radians."""


class Motion(BaseModel):
    """One planned robot command: a linear move or a gripper output change."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    label: Literal["approach", "descend", "close_gripper", "lift"]
    kind: Literal["moveL", "gripper"]
    pose: Pose | None = Field(None, description="moveL: target tool pose.")
    speed_m_s: float | None = Field(None, gt=0, description="moveL: tool speed.")
    acceleration_m_s2: float | None = Field(None, gt=0, description="moveL: tool acceleration.")
    output_value: bool | None = Field(None, description="gripper: the digital output level.")

    @model_validator(mode="after")
    def _fields_match_kind(self) -> Motion:
        move_fields = (self.pose, self.speed_m_s, self.acceleration_m_s2)
        if self.kind == "moveL" and (None in move_fields or self.output_value is not None):
            raise ValueError("a moveL needs pose, speed and acceleration and no output value")
        if self.kind == "gripper" and (
            self.output_value is None or any(v is not None for v in move_fields)
        ):
            raise ValueError("a gripper motion needs an output value and no pose")
        return self


class GraspPlan(BaseModel):
    """A pick planned without a robot: the target, the motions, and the offline safety check.

    ``within_workspace`` and ``refusal`` tell whether :meth:`adapters.ur3.driver.UR3Picker.pick`
    would refuse the motions because of the configured workspace (reach, table clearance,
    keep-out cylinder). The checks that need the robot (``isPoseWithinSafetyLimits``,
    protective and emergency stops, the path from the current tool position) are not run.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    target: GraspTarget
    motions: list[Motion] = Field(description="What a pick sends, in order.")
    within_workspace: bool = Field(
        description="Every moveL position lies inside the workspace; a pick would not refuse "
        "them on that ground."
    )
    refusal: str | None = Field(
        None, description="Why a pick would refuse the motions; None when within the workspace."
    )


class PickStep(BaseModel):
    """What happened when one planned motion was sent."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    motion: Motion
    ok: bool
    reached_pose: Pose | None = Field(None, description="getActualTCPPose after the step.")
    duration_s: float = Field(ge=0)
    error: str | None = None


class PickReport(BaseModel):
    """The outcome of a pick: every step sent, and why it stopped when it failed."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    ok: bool
    reason: str | None = Field(None, description="Why the pick failed; None when ok.")
    target: GraspTarget
    steps: list[PickStep] = Field(default_factory=list)
    stop_sent: bool = Field(False, description="stopL was sent after a failure.")
    reconnect_attempted: bool = False
    reconnected: bool = False


def _one_line(text: str) -> str:
    return " ".join(line.strip() for line in text.splitlines() if line.strip())
