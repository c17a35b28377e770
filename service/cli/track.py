"""``dlo track``: the cables of videos and camera streams followed from frame to frame.

The outputs and conventions are ``dlo detect``'s for videos (:mod:`service.cli.detect`):
``<stem>.jsonl`` with one line per frame, ``{"frame", "timestamp_s", "detection"}``, the
``detection`` being the frame's :class:`schemas.Tracks` (each chain a track: its id kept
from frame to frame, joint ``j`` on the same point of the cable), and on request the
overlay video (each track in its own colour with its id) and the MCAP recording. Frames
that could not be read or detected are warned of, counted in the summary line and in the
next frame's ``tracking.frames_lost``; the tracks go on across them. A frame of another
size starts the tracks afresh, with a one-line warning. Exit statuses as ``dlo detect``:
0, 1 (a video none of whose frames could be processed, or an output that could not be
written), 2 (usage), 130 (Ctrl-C).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from pydantic import ValidationError

from schemas import TrackParams
from service.batch import InvalidParametersError, expand_inputs, find_output_clashes, parse_outputs
from service.cli.detect import make_out_dir, run_stream, video_outputs
from service.cli.options import (
    ExpectedCount,
    HsvHigh,
    HsvLow,
    MaxFrames,
    OverlayVideo,
    ParamsText,
    Segmentation,
    SegmenterModel,
    SegmentLength,
    detection_setup,
)
from service.console import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    exit_usage,
    load_kernels,
    print_error,
    print_warning,
    stderr_console,
)
from service.tracking import StreamTracker
from service.video import FrameSource, is_video_path, open_camera, open_video, parse_camera


def _track_default(field: str) -> str:
    return str(TrackParams.model_fields[field].default)


def track(
    paths: Annotated[
        list[Path] | None,
        typer.Argument(metavar="VIDEO", help="Video files to track.", show_default=False),
    ] = None,
    camera: Annotated[
        str | None,
        typer.Option(
            metavar="SRC",
            help="Track a camera (device index such as 0) or a stream URL instead of files. "
            "Stop with Ctrl-C or --max-frames.",
        ),
    ] = None,
    segment_length: SegmentLength = None,
    expected_count: ExpectedCount = None,
    segmentation: Segmentation = None,
    hsv_low: HsvLow = None,
    hsv_high: HsvHigh = None,
    segmenter_model: SegmenterModel = None,
    params_text: ParamsText = None,
    memory: Annotated[
        float | None,
        typer.Option(
            metavar="S",
            help="How long a cable out of view is remembered: back within this time and "
            "recognised (colour, width, length), it gets its id back.",
            show_default=_track_default("memory_s"),
        ),
    ] = None,
    coast: Annotated[
        float | None,
        typer.Option(
            metavar="S",
            help="How long a cable not seen at all (covered, missed) is still predicted "
            "and written, all inferred.",
            show_default=_track_default("coast_s"),
        ),
    ] = None,
    confirm: Annotated[
        int | None,
        typer.Option(
            metavar="N",
            help="Frames in a row a new cable must be seen in before it gets a track (the "
            "first frame's cables start theirs at once).",
            show_default=_track_default("confirm_frames"),
        ),
    ] = None,
    out_dir: Annotated[
        Path | None,
        typer.Option(
            metavar="DIR",
            help="Write <stem>.jsonl (and the other outputs) here.",
            show_default=False,
        ),
    ] = None,
    outputs: Annotated[
        str | None,
        typer.Option(
            metavar="LIST",
            help="What to write per video or camera, comma-separated from json (the "
            "<stem>.jsonl), overlay (<stem>.overlay.mp4), mcap (<stem>.mcap, a ROS 2 "
            "recording with each track as a marker). Default: json.",
            show_default=False,
        ),
    ] = None,
    overlay_video: OverlayVideo = False,
    max_frames: MaxFrames = None,
) -> None:
    """Follow the cables through videos or a camera stream: one id per cable.

    Writes <stem>.jsonl per video or camera, one line per frame: {"frame": i,
    "timestamp_s": t, "detection": {...}}, the detection's chains being tracks (the same
    id and joint numbering from frame to frame) with "tracking" (frames lost, resets).
    Ctrl-C stops cleanly, keeping every line written so far, and exits with 130.
    """
    console = stderr_console()
    params, segmenter = detection_setup(
        console,
        params_text,
        segment_length,
        expected_count,
        segmentation,
        hsv_low,
        hsv_high,
        segmenter_model,
    )
    given = {"memory_s": memory, "coast_s": coast, "confirm_frames": confirm}
    try:
        track_params = TrackParams(**{k: v for k, v in given.items() if v is not None})
    except ValidationError as exc:
        problem = exc.errors(include_url=False)[0]
        option = {"memory_s": "--memory", "coast_s": "--coast", "confirm_frames": "--confirm"}
        name = option.get(str(problem["loc"][0]), str(problem["loc"][0]))
        exit_usage(console, f"{name}: {problem['msg']}")
    if max_frames is not None and max_frames < 1:
        exit_usage(console, "--max-frames: must be at least 1")
    if out_dir is None:
        exit_usage(console, "dlo track needs --out-dir")
    selected = frozenset({"json"})
    if outputs is not None:
        try:
            selected = parse_outputs(outputs)
        except InvalidParametersError as exc:
            exit_usage(console, str(exc))
        if "mjcf" in selected:
            exit_usage(
                console, "--outputs: mjcf is not available for tracks (use json, overlay, mcap)"
            )
    chosen = video_outputs(console, outputs, selected, overlay_video)

    def tracker_for(source: FrameSource) -> StreamTracker:
        def warn(frame, why: str) -> None:
            print_warning(console, f"{source.label}: frame {frame.index}: {why}")

        return StreamTracker(params, track_params, segmenter=segmenter, on_reset=warn)

    if camera is not None:
        if paths:
            exit_usage(console, "--camera cannot be combined with VIDEO arguments")
        make_out_dir(console, out_dir)
        source = parse_camera(camera)
        load_kernels(console, ("detection", "tracking"))
        summary = run_stream(
            console,
            lambda: open_camera(source),
            params,
            out_dir,
            chosen,
            max_frames,
            segmenter,
            analyser=tracker_for,
        )
        if summary is not None and summary.interrupted:
            raise typer.Exit(EXIT_INTERRUPTED)
        raise typer.Exit(0 if summary is not None and summary.succeeded else EXIT_FAILED)

    if not paths:
        exit_usage(console, "give video files (VIDEO...), or --camera SRC")
    files, problems, _ = expand_inputs(paths)
    failed = len(problems)
    for problem in problems:
        print_error(console, problem)
    videos = []
    for path in files:
        if is_video_path(path):
            videos.append(path)
        else:
            print_error(console, f"{path}: not a video (tracking needs a video or --camera)")
            failed += 1
    make_out_dir(console, out_dir)
    if videos:
        load_kernels(console, ("detection", "tracking"))
    clashes = find_output_clashes(videos)
    interrupted = False
    for path in videos:
        if interrupted:
            break
        if path in clashes:
            print_error(
                console, f"{path}: outputs would overwrite those of {clashes[path]} (same name)"
            )
            failed += 1
            continue
        summary = run_stream(
            console,
            lambda path=path: open_video(path),
            params,
            out_dir,
            chosen,
            max_frames,
            segmenter,
            analyser=tracker_for,
        )
        if summary is None or not (summary.succeeded or summary.interrupted):
            failed += 1
        if summary is not None:
            interrupted = summary.interrupted
    if interrupted:
        raise typer.Exit(EXIT_INTERRUPTED)
    raise typer.Exit(EXIT_FAILED if failed else 0)
