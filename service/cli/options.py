"""The detection options ``dlo detect`` and ``dlo track`` share, and how they become
parameters: one definition, so that both commands read the same command line alike."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from schemas import DetectParams, SegmentationMethod
from service.batch import InvalidParametersError, build_params, read_params
from service.console import exit_usage
from service.perception.segmenter import OnnxSegmenter, Segmenter, SegmenterModelError


def default_of(field: str) -> str:
    """The default of a :class:`DetectParams` field, as shown in ``--help``."""
    default = DetectParams.model_fields[field].default
    if isinstance(default, SegmentationMethod):
        return default.value
    if isinstance(default, tuple):
        return " ".join(map(str, default))
    return str(default)


SegmentLength = Annotated[
    float | None,
    typer.Option(
        metavar="PX",
        help="Length of each chain segment.",
        show_default=default_of("segment_length"),
    ),
]
ExpectedCount = Annotated[
    int | None, typer.Option(metavar="N", help="Number of cables in view, when known.")
]
Segmentation = Annotated[
    SegmentationMethod | None,
    typer.Option(
        help="Segmentation when no mask is given.", show_default=default_of("segmentation")
    ),
]
HsvLow = Annotated[
    tuple[int, int, int] | None,
    typer.Option(
        metavar="H S V",
        help="Lower HSV bound for --segmentation hsv.",
        show_default=default_of("hsv_low"),
    ),
]
HsvHigh = Annotated[
    tuple[int, int, int] | None,
    typer.Option(
        metavar="H S V",
        help="Upper HSV bound for --segmentation hsv.",
        show_default=default_of("hsv_high"),
    ),
]
SegmenterModel = Annotated[
    Path | None,
    typer.Option(
        metavar="FILE",
        help="A learned segmenter in ONNX format (input 1x3xHxW RGB, output a cable "
        "probability or logit map; see the README) that makes the mask; implies "
        "--segmentation model. Needs onnxruntime: pip install 'dlo-service[onnx]'.",
    ),
]
ParamsText = Annotated[
    str | None,
    typer.Option(
        "--params",
        metavar="JSON|FILE",
        help="Any detection parameters, as a JSON object such as "
        '\'{"gap_curve": "natural", "max_gap": 150}\' or a file holding one (as dlo eval '
        "--params); the options above override the fields they set.",
        show_default=False,
    ),
]
OverlayVideo = Annotated[
    bool,
    typer.Option("--overlay-video", help="Also write <stem>.overlay.mp4 per video or camera."),
]
MaxFrames = Annotated[
    int | None,
    typer.Option(metavar="N", help="Stop each video or camera after N frames."),
]


def detection_setup(
    console: Console,
    params_text: str | None,
    segment_length: float | None,
    expected_count: int | None,
    segmentation: SegmentationMethod | None,
    hsv_low: tuple[int, int, int] | None,
    hsv_high: tuple[int, int, int] | None,
    segmenter_model: Path | None,
) -> tuple[DetectParams, Segmenter | None]:
    """The parameters and the segmenter the options ask for; a usage error (exit 2) when
    they do not go together or a value is out of range."""
    if segmenter_model is not None:
        if segmentation not in (None, SegmentationMethod.model):
            exit_usage(
                console, f"--segmenter-model cannot be used with --segmentation {segmentation}"
            )
        segmentation = SegmentationMethod.model
    elif segmentation is SegmentationMethod.model:
        exit_usage(console, "--segmentation model needs --segmenter-model FILE.onnx")
    try:
        params = build_params(
            None if params_text is None else read_params(params_text),
            segment_length=segment_length,
            expected_count=expected_count,
            segmentation=segmentation,
            hsv_low=hsv_low,
            hsv_high=hsv_high,
        )
    except InvalidParametersError as exc:
        exit_usage(console, str(exc))
    segmenter = None
    if segmenter_model is not None:
        try:
            segmenter = OnnxSegmenter(segmenter_model)
        except SegmenterModelError as exc:
            exit_usage(console, str(exc))
    return params, segmenter
