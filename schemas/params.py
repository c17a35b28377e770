"""Detection parameters: one validated model with documented defaults in pixels."""

from __future__ import annotations

from enum import StrEnum

from pydantic import BaseModel, ConfigDict, Field, model_validator


class GapCurve(StrEnum):
    """The curve that fills a gap or crossing between two joined chain ends."""

    smooth = "smooth"
    """A cubic whose handles follow both end directions and would trace a circular arc
    between symmetric ends: the turning is spread over the whole gap, as an elastic
    cable bends; where the ends turn by a right angle or more about the line between
    them, the Euler spiral (curvature changing at a constant rate) between them."""
    natural = "natural"
    """Keipour et al.'s natural curve: straight along the end directions, then one
    constant-rate arc (a cubic where no single arc fits)."""


class SegmentationMethod(StrEnum):
    """How the foreground mask is found when the caller gives none."""

    auto = "auto"
    """``brightness`` when the image shows what it needs (bright, thin cables on a darker,
    plain background: brightness is clearly two-class and its bright class is thin);
    ``contrast`` otherwise."""
    contrast = "contrast"
    """Cable contrast: lines of one colour that differ from both sides and from the local
    background, at every cable width, on any background (bright, dark or textured)."""
    brightness = "brightness"
    """Otsu with hysteresis on brightness (again per cable once the chains are known);
    colourfulness when brightness is not two-class (``auto`` before cable contrast)."""
    hsv = "hsv"
    """Fixed HSV range ``hsv_low`` .. ``hsv_high`` (OpenCV ranges: H 0-179, S and V 0-255)."""
    model = "model"
    """A segmenter the caller supplies: a learned model (ONNX, ``--segmenter-model``) or,
    in Python, any callable from the image to a mask."""


class DetectParams(BaseModel):
    """Parameters of the six-step detection pipeline.

    Every length is in pixels of the input image. The defaults suit cables 6 to 40 px
    wide in images from 640x360 to 3840x2160; none is tuned to a data set.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    segment_length: float = Field(
        10.0, gt=0.5, le=500.0, description="l_s: length of each chain segment."
    )
    expected_count: int | None = Field(
        None,
        ge=1,
        le=100,
        description="Number of DLOs in view, when known: merging stops when it is reached "
        "and goes on past the cost threshold until it is.",
    )
    segmentation: SegmentationMethod = Field(
        SegmentationMethod.auto, description="Segmentation when no mask is given."
    )
    hsv_low: tuple[int, int, int] = Field(
        (0, 0, 60), description="Lower HSV bound; only with segmentation hsv."
    )
    hsv_high: tuple[int, int, int] = Field(
        (179, 255, 255), description="Upper HSV bound; only with segmentation hsv."
    )
    min_component_area: int = Field(
        120, ge=0, le=1_000_000, description="Foreground specks smaller than this are removed."
    )
    max_hole_area: int = Field(
        60, ge=0, le=1_000_000, description="Background holes smaller than this are filled."
    )
    spur_length: float | None = Field(
        None,
        ge=0,
        le=1000,
        description="Skeleton branches from a tip to a junction shorter than this are "
        "spurs and removed; None: 2.5 times the cable radius.",
    )
    max_gap: float = Field(
        250.0, ge=0, le=10_000, description="Largest gap (occlusion) merging will bridge."
    )
    gap_curve: GapCurve = Field(
        GapCurve.smooth, description="Curve drawn across gaps, occlusions and crossings."
    )
    merge_cost_threshold: float = Field(
        0.6,
        ge=0,
        le=100,
        description="Joins cheaper than this are made; dearer ones only to reach expected_count.",
    )
    distance_weight: float = Field(
        1.0, ge=0, le=100, description="Weight of the end-to-end distance (per max_gap)."
    )
    direction_weight: float = Field(
        0.6, ge=0, le=100, description="Weight of the end direction difference (per pi)."
    )
    curvature_weight: float = Field(
        0.9,
        ge=0,
        le=100,
        description="Weight of the turning needed to connect (per 2 pi: two turns of up to pi).",
    )
    colour_weight: float = Field(
        0.5,
        ge=0,
        le=100,
        description="Weight of the colour difference of two ends (per 10 Lab units beyond "
        "their own scatter, at most 2); 0 joins on geometry alone. Needs the image. An end "
        "whose piece runs into something much wider than a cable (an object segmented "
        "with the cables), whose colour is not its piece's further in, or whose piece is "
        "shorter than three radii, has no colour and costs nothing.",
    )
    min_chain_length: float = Field(
        20.0, ge=0, le=10_000, description="Chains shorter than this after merging are dropped."
    )

    @model_validator(mode="after")
    def _hsv_ranges_are_valid(self) -> DetectParams:
        limits = (179, 255, 255)
        for name, bound in (("hsv_low", self.hsv_low), ("hsv_high", self.hsv_high)):
            for value, limit in zip(bound, limits, strict=True):
                if not 0 <= value <= limit:
                    raise ValueError(f"{name} {bound} is outside 0..{limits}")
        if any(lo > hi for lo, hi in zip(self.hsv_low, self.hsv_high, strict=True)):
            raise ValueError(f"hsv_low {self.hsv_low} exceeds hsv_high {self.hsv_high}")
        # An HSV box without the hsv segmentation would be ignored without a word: refuse
        # it. (The defaults are let through, so that a saved DetectParams reloads.)
        fields = type(self).model_fields
        boxed = (self.hsv_low, self.hsv_high) != (
            fields["hsv_low"].default,
            fields["hsv_high"].default,
        )
        if boxed and self.segmentation is not SegmentationMethod.hsv:
            raise ValueError(
                f"hsv_low/hsv_high apply only to segmentation 'hsv', and segmentation is "
                f"'{self.segmentation.value}': set segmentation to hsv too"
            )
        return self
