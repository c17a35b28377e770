"""What travels beside a frame and its result on zenoh: the attachments.

A camera's frame on ``dlo/<camera>/image`` (or a query on ``dlo/detect``) may carry a JSON
object as its attachment: the detection parameters (:class:`~schemas.params.DetectParams`
fields) and, beside them, the frame's identity (:class:`FrameIdentity`: ``frame_id``,
``capture_time``). An attachment of parameters only, or none, is what cameras sent before
frame identity existed, and still works. Every result the service publishes for that frame
(``dlo/<camera>/chains``, ``.../errors``, a query's reply; later tracks and markers) carries
:class:`ResultAttachment` as its attachment: the identity given back, the zenoh timestamp of
the frame's sample and the replica that detected it.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, StrictInt, StringConstraints

FRAME_ID_MAX_CHARS = 256

FrameId = StrictInt | Annotated[str, StringConstraints(min_length=1, max_length=FRAME_ID_MAX_CHARS)]


class FrameIdentity(BaseModel):
    """Which frame this is, as the camera names it; the service gives it back unchanged."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    frame_id: FrameId | None = Field(
        None,
        description="The camera's name for the frame: an integer (e.g. a frame counter) or "
        f"a string of 1 to {FRAME_ID_MAX_CHARS} characters.",
    )
    capture_time: float | None = Field(
        None,
        allow_inf_nan=False,
        description="When the frame was captured, in seconds since the Unix epoch (UTC) on "
        "the camera's clock; not interpreted, only given back.",
    )


IDENTITY_FIELDS = tuple(FrameIdentity.model_fields)
"""The attachment keys that are the frame's identity; every other key is a parameter."""


class ResultAttachment(FrameIdentity):
    """The attachment of every result sample: which frame, seen when, detected where."""

    sample_timestamp: str | None = Field(
        None,
        description="The zenoh timestamp of the frame's sample (RFC 3339 time, '/', the id "
        "of the zenoh node that stamped it: the router, or the camera's session when it "
        "stamps its samples); null for a query or an unstamped sample.",
    )
    replica: str = Field(description="The zenoh id of the service replica that detected it.")
