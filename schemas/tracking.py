"""Tracks: the chains of a video or stream, each one cable from frame to frame.

A :class:`Tracks` is a :class:`~schemas.detection.Detection` whose chains are
:class:`Track` s: the same fields, so that anything that reads a Detection reads it, plus
what a tracker knows. A track's ``id`` stays with its cable while the cable is in view
(and when it comes back within the tracker's memory, recognised by its colour, width and
length); its joints keep their material points (joint ``j`` is the same point of the
cable, counted from the same end, in every frame); ``inferred`` segments are those not
seen in this frame (hidden under something, under another cable at a crossing, or
outside the picture), placed where the visible ones and the cable's bending limit say.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from schemas.detection import Chain, Detection

EndKind = Literal["tip", "open"]


class Track(Chain):
    """A chain followed from frame to frame (see the module's documentation).

    ``points`` keep their material points: a track's joint count changes only when more of
    its cable comes into view at an ``open`` end (one that was at the picture's edge, or
    hidden, when it was last seen), and then joints are added there; joints are never
    dropped. Consecutive points are exactly ``segment_length`` apart. Joints of a cable
    that has partly left the picture are kept, outside it (``inferred``).
    """

    first_joint: int = Field(
        0,
        le=0,
        description="The track's number of points[0]: joint j of the track is "
        "points[j - first_joint]. 0 unless the track grew at its first end, then negative, "
        "so that joints keep their numbers.",
    )
    ends: tuple[EndKind, EndKind] = Field(
        ("open", "open"),
        description="Per end (first, last): 'tip' when it is the cable's real end, seen "
        "free; 'open' when the cable may go on beyond it (at the picture's edge, hidden).",
    )
    age: int = Field(1, ge=1, description="Frames since the track began, this one included.")
    unseen: int = Field(
        0,
        ge=0,
        description="Consecutive frames in which nothing of the cable was seen (0: seen in "
        "this one); while > 0 the track is predicted and every segment is inferred.",
    )


class TrackingStatus(BaseModel):
    """What the tracker did with this frame."""

    model_config = ConfigDict(frozen=True)

    session: str = Field(
        description="This run of the tracker; track ids are unique within it and start "
        "again from 0 in a new one (after a reset, or when another replica takes a camera)."
    )
    frame: int = Field(ge=0, description="Frames given to this session before this one.")
    frames_lost: int = Field(
        0, ge=0, description="Frames lost (dropped, unreadable) just before this one."
    )
    frames_lost_total: int = Field(0, ge=0, description="Frames lost in this session so far.")
    reset: str | None = Field(
        None, description="Why the tracks were started afresh at this frame, if they were."
    )
    remembered: list[int] = Field(
        default_factory=list,
        description="Ids of tracks out of view that get their id back if their cable returns.",
    )
    tracking_ms: float = Field(0.0, ge=0, description="Time spent tracking, beyond detection.")


class Tracks(Detection):
    """A frame's tracks: a Detection whose chains are :class:`Track` s, sorted by id."""

    chains: list[Track] = Field(default_factory=list)
    tracking: TrackingStatus


class TrackParams(BaseModel):
    """How the tracker keeps its tracks (the detection keeps its own DetectParams)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    memory_s: float = Field(
        5.0,
        ge=0,
        le=3600,
        description="How long a cable out of view is remembered: if it comes back within "
        "this time and is recognised (colour, width, length) it gets its id back.",
    )
    coast_s: float = Field(
        0.5,
        ge=0,
        le=60,
        description="How long a track whose cable is not seen at all (covered, missed) is "
        "still predicted and published, all inferred, before it is only remembered.",
    )
    confirm_frames: int = Field(
        2,
        ge=1,
        le=100,
        description="Consecutive frames a new cable must be seen in before it becomes a track "
        "(the first frame of a session starts its tracks at once).",
    )
    fps: float = Field(
        30.0, gt=0, le=1000, description="Frame rate assumed for frames given without a time."
    )
