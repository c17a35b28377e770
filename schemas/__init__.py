"""The wire contract of dlo-service: pydantic v2 models shared by every interface.

Everything that crosses a process boundary (JSON files, HTTP bodies, zenoh samples)
is one of these models, so producers and consumers validate the same way.
"""

from schemas.bus import FrameIdentity, ResultAttachment
from schemas.detection import Chain, Crossing, Detection, StageTimings
from schemas.grasp import (
    CameraModel,
    DepthSurface,
    EndPoint,
    FractionPoint,
    GraspSelector,
    GraspTarget,
    Motion,
    PickReport,
    PickStep,
    PixelPoint,
    PlaneSurface,
    SegmentPoint,
)
from schemas.params import DetectParams, GapCurve, SegmentationMethod
from schemas.tracking import Track, TrackingStatus, TrackParams, Tracks

__all__ = [
    "CameraModel",
    "Chain",
    "Crossing",
    "DepthSurface",
    "DetectParams",
    "Detection",
    "EndPoint",
    "FractionPoint",
    "FrameIdentity",
    "GapCurve",
    "GraspSelector",
    "GraspTarget",
    "Motion",
    "PickReport",
    "PickStep",
    "PixelPoint",
    "PlaneSurface",
    "ResultAttachment",
    "SegmentPoint",
    "SegmentationMethod",
    "StageTimings",
    "Track",
    "TrackParams",
    "TrackingStatus",
    "Tracks",
]
