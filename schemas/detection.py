"""Detection output: each DLO as a chain of fixed-length segments.

Coordinates are pixels, ``x`` the column and ``y`` the row, with the origin at the
centre of the top-left pixel. A chain lifted to 3-D (``service.geometry3d.lift``) also
carries its joints in the robot base frame, in metres (``points_3d``, ``radius_m``).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

Point = tuple[float, float]
Point3 = tuple[float, float, float]


def _absent(value: object) -> bool:
    """Fields that only a lifted detection has are left out of its JSON until set."""
    return value is None


class Chain(BaseModel):
    """One deformable linear object as a chain of segments joined by spherical joints.

    Consecutive ``points`` are exactly ``Detection.segment_length`` apart (the last
    segment may be shorter). ``inferred[k]`` tells whether segment ``k`` (points
    ``k`` to ``k + 1``) was filled across a gap, an occlusion or the hidden part of a
    crossing rather than seen in the image.
    """

    model_config = ConfigDict(frozen=True)

    id: int = Field(ge=0, description="Chain identifier, unique within a detection.")
    points: list[Point] = Field(min_length=2, description="Joint positions [x, y] in px.")
    radius: float = Field(ge=0, description="Half width of the cable in px.")
    inferred: list[bool] = Field(description="Per segment: filled across a gap, not seen.")
    points_3d: list[Point3 | None] | None = Field(
        None,
        exclude_if=_absent,
        description="Only when a camera model was given: each joint's point on the cable's "
        "centreline [x, y, z] in the robot base frame, metres, in the order of `points`; "
        "null for a joint that could not be located (no valid depth around a seen joint, "
        "or its ray misses the table). Hidden joints (on inferred segments) lie on their "
        "rays at a depth interpolated between the located joints on either side.",
    )
    radius_m: float | None = Field(
        None,
        ge=0,
        exclude_if=_absent,
        description="Only when a camera model was given: the cable's radius in metres.",
    )

    @model_validator(mode="after")
    def _one_flag_per_segment(self) -> Chain:
        if len(self.inferred) != len(self.points) - 1:
            raise ValueError(
                f"inferred has {len(self.inferred)} flags for {len(self.points) - 1} segments"
            )
        if self.points_3d is not None and len(self.points_3d) != len(self.points):
            raise ValueError(
                f"points_3d has {len(self.points_3d)} entries for {len(self.points)} points"
            )
        return self

    @property
    def length(self) -> float:
        """Arc length of the chain in pixels."""
        total = 0.0
        for (x0, y0), (x1, y1) in zip(self.points, self.points[1:], strict=False):
            total += ((x1 - x0) ** 2 + (y1 - y0) ** 2) ** 0.5
        return total


class Crossing(BaseModel):
    """A place where two strands cross; ``over`` is the chain on top.

    ``over`` and ``under`` are equal when a cable crosses itself (a loop).
    """

    model_config = ConfigDict(frozen=True)

    x: float
    y: float
    over: int = Field(ge=0)
    under: int = Field(ge=0)
    over_segment: int = Field(ge=0, description="Segment index of the crossing on `over`.")
    under_segment: int = Field(ge=0, description="Segment index of the crossing on `under`.")
    confidence: float = Field(
        ge=0,
        le=1,
        description="How clearly the image shows which strand is on top (0: a guess).",
    )


class StageTimings(BaseModel):
    """Wall-clock time of each pipeline stage in milliseconds."""

    segmentation: float = 0.0
    skeleton: float = 0.0
    contours: float = 0.0
    fitting: float = 0.0
    pruning: float = 0.0
    merging: float = 0.0
    total: float = 0.0


class Detection(BaseModel):
    """All DLOs found in one image."""

    width: int = Field(gt=0)
    height: int = Field(gt=0)
    segment_length: float = Field(gt=0)
    chains: list[Chain] = Field(default_factory=list)
    crossings: list[Crossing] = Field(default_factory=list)
    timings_ms: StageTimings = Field(default_factory=StageTimings)

    def chain(self, chain_id: int) -> Chain:
        """Return the chain with identifier ``chain_id``."""
        for candidate in self.chains:
            if candidate.id == chain_id:
                return candidate
        raise KeyError(f"no chain with id {chain_id}")
