"""``dlo detect``: the cables in image files, folders, videos and camera streams.

Output conventions: stdout carries only results (the detection JSON of a single image);
progress, summaries and errors go to stderr, each error on one line ``error: <file>:
<problem>`` (``warning: ...`` for frames of a video that were skipped while the rest went
through). Exit status (:mod:`service.console`): 0 when everything worked, 1 when any input
failed (a video fails only when none of its frames could be processed), 2 for a usage
error, 130 when Ctrl-C stopped the run (every output written so far is whole, but a
script must not take the run for complete).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from pydantic import ValidationError
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from schemas import CameraModel, DepthSurface, Detection, DetectParams
from schemas.model import CablePhysics
from service.batch import (
    IMAGE_OUTPUTS,
    InvalidParametersError,
    describe_json_validation_error,
    detection_to_json,
    expand_inputs,
    failure_message,
    find_output_clashes,
    parse_outputs,
    process_file,
)
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
from service.imageio import OutputWriteError
from service.interrupts import raise_if_interrupted
from service.perception.segmenter import Segmenter
from service.video import (
    FrameOutcome,
    FrameSource,
    StreamAnalyser,
    StreamSummary,
    VideoSourceError,
    is_video_path,
    open_camera,
    open_video,
    parse_camera,
    process_stream,
)

if TYPE_CHECKING:
    from service.ros.recording import McapRecorder

FRAME_MESSAGES_PER_STREAM = 5
"""Skipped frames reported one by one per video; the rest only counted in the summary."""
CAMERA_MODEL_SUFFIXES = (".json", ".yaml", ".yml")
"""A ``--camera`` naming a file with one of these suffixes is a camera model, not a source."""


def detect(
    paths: Annotated[
        list[Path] | None,
        typer.Argument(
            metavar="PATH",
            help="Image or video files, or directories of images.",
            show_default=False,
        ),
    ] = None,
    camera: Annotated[
        str | None,
        typer.Option(
            metavar="SRC|CAMERA.json",
            help="Read a camera (device index such as 0) or a stream URL instead of files; "
            "needs --out-dir. Stop with Ctrl-C or --max-frames. Or, with image files, a "
            "camera model (.json, .yaml, .yml; see docs/examples/camera.json): the chains "
            "are lifted to the robot base frame (points_3d, radius_m) and <stem>.mjcf.xml, "
            "a MuJoCo model of the cables, is written too.",
        ),
    ] = None,
    depth: Annotated[
        Path | None,
        typer.Option(
            metavar="DEPTH",
            help="Depth image aligned with the single input image (16-bit PNG or .npy), "
            "for a camera model whose surface is a depth image.",
        ),
    ] = None,
    physics: Annotated[
        str | None,
        typer.Option(
            metavar="JSON|FILE",
            help="The cables' physics in <stem>.mjcf.xml, a JSON object (e.g. "
            "'{\"bending_stiffness\": 1e-3}') or a file holding one; see the README.",
            show_default=False,
        ),
    ] = None,
    mask: Annotated[
        Path | None,
        typer.Option(help="Foreground mask (non-zero = cable) for a single input image."),
    ] = None,
    segment_length: SegmentLength = None,
    expected_count: ExpectedCount = None,
    segmentation: Segmentation = None,
    hsv_low: HsvLow = None,
    hsv_high: HsvHigh = None,
    segmenter_model: SegmenterModel = None,
    params_text: ParamsText = None,
    out_dir: Annotated[
        Path | None,
        typer.Option(
            metavar="DIR",
            help="Write <stem>.json, <stem>.labels.png and <stem>.overlay.png per image, "
            "<stem>.jsonl per video or camera here; without it, the JSON of the single "
            "input image goes to stdout.",
        ),
    ] = None,
    outputs: Annotated[
        str | None,
        typer.Option(
            metavar="LIST",
            help="What to write, comma-separated from json, labels, overlay, mjcf, mcap. "
            "Default: json, labels and overlay per image (and mjcf with a camera model); json "
            "(the <stem>.jsonl) per video. For videos, overlay is the overlay video and labels "
            "are not available. mcap: a ROS 2 recording (frames and chains as markers, for "
            "Foxglove), <stem>.mcap per video or camera, one for all the images (named after "
            "the one PATH, else images.mcap).",
            show_default=False,
        ),
    ] = None,
    overlay_video: OverlayVideo = False,
    max_frames: MaxFrames = None,
) -> None:
    """Detect the cables in each image, or in every frame of a video or camera stream.

    One image without --out-dir: its Detection JSON on stdout, one line per chain and per
    crossing. Videos (.mp4 .avi .mkv .mov .webm .m4v .mpg .mpeg) and cameras write one
    line of JSON per frame to <stem>.jsonl: {"frame": i, "timestamp_s": t, "detection":
    {...}}. Ctrl-C stops cleanly, keeping every line written so far, and exits with 130.
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
    try:
        selected = IMAGE_OUTPUTS if outputs is None else parse_outputs(outputs)
    except InvalidParametersError as exc:
        exit_usage(console, str(exc))
    if max_frames is not None and max_frames < 1:
        exit_usage(console, "--max-frames: must be at least 1")
    camera_model = None
    if camera is not None and Path(camera).suffix.lower() in CAMERA_MODEL_SUFFIXES:
        camera_model = _load_camera_model(console, Path(camera))
        camera = None
        if not paths:
            exit_usage(
                console,
                "a camera model (--camera FILE) lifts the chains of image files: give PATH...",
            )
        if outputs is None:
            selected = (*IMAGE_OUTPUTS, "mjcf")
    cable_physics = _three_d_options(console, camera_model, depth, physics, selected)

    if camera is not None:
        if paths:
            exit_usage(console, "--camera cannot be combined with PATH arguments")
        if mask is not None:
            exit_usage(console, "--mask applies to a single input image")
        if out_dir is None:
            exit_usage(console, "--camera needs --out-dir")
        chosen_outputs = video_outputs(console, outputs, selected, overlay_video)
        make_out_dir(console, out_dir)
        source = parse_camera(camera)
        load_kernels(console)
        summary = run_stream(
            console,
            lambda: open_camera(source),
            params,
            out_dir,
            chosen_outputs,
            max_frames,
            segmenter,
        )
        if summary is not None and summary.interrupted:
            raise typer.Exit(EXIT_INTERRUPTED)
        raise typer.Exit(0 if summary is not None and summary.succeeded else EXIT_FAILED)

    if not paths:
        exit_usage(console, "give image or video files (PATH...), or --camera SRC")
    files, problems, skipped = expand_inputs(paths)
    videos = [path for path in files if is_video_path(path)]
    images = [path for path in files if not is_video_path(path)]
    if mask is not None and (len(paths) != 1 or len(files) > 1 or videos):
        exit_usage(console, "--mask applies to a single input image")
    if depth is not None and (len(paths) != 1 or len(files) > 1 or videos):
        exit_usage(console, "--depth applies to a single input image")
    if camera_model is not None and videos:
        exit_usage(console, "a camera model (--camera FILE) applies to images, not videos")
    if out_dir is None and videos:
        exit_usage(console, "videos need --out-dir")
    if out_dir is None and len(files) > 1:
        exit_usage(console, "several inputs need --out-dir")
    if out_dir is None and outputs is not None:
        exit_usage(console, "--outputs needs --out-dir")
    chosen_outputs = (
        video_outputs(console, outputs, selected, overlay_video)
        if videos
        else (False, False, False)
    )
    recording = None
    if "mcap" in selected and images:
        recording = out_dir / f"{recording_stem(paths)}.mcap"

    for note in skipped:
        print_warning(console, note)
    for problem in problems:
        print_error(console, problem)
    failed = len(problems)
    if files:
        load_kernels(console)

    per_image = {
        "camera": camera_model,
        "depth_path": depth,
        "physics": cable_physics,
        "segmenter": segmenter,
    }
    if out_dir is None:
        if files:
            detection = _process_or_report(console, files[0], params, None, mask, **per_image)
            if detection is None:
                failed += 1
            else:
                typer.echo(detection_to_json(detection))
        raise typer.Exit(EXIT_FAILED if failed else 0)

    make_out_dir(console, out_dir)
    interrupted = False
    if images:
        _, images_failed, interrupted = _detect_images(
            console, images, params, out_dir, mask, selected, per_image, recording
        )
        failed += images_failed
    clashes = find_output_clashes(videos)
    if recording is not None:  # the images' recording is named like a video's outputs
        clashes.update({path: images[0] for path in videos if path.stem == recording.stem})
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
            chosen_outputs,
            max_frames,
            segmenter,
        )
        if summary is None or not (summary.succeeded or summary.interrupted):
            failed += 1
        if summary is not None:
            interrupted = summary.interrupted

    if interrupted:
        raise typer.Exit(EXIT_INTERRUPTED)
    raise typer.Exit(EXIT_FAILED if failed else 0)


def video_outputs(
    console: Console, given: str | None, selected: Iterable[str], overlay_video: bool
) -> tuple[bool, bool, bool]:
    """Which outputs videos get: (JSON Lines, overlay video, MCAP recording); labels are a
    usage error."""
    chosen = set(selected)
    if given is None:
        return True, overlay_video, False
    if "labels" in chosen:
        exit_usage(
            console, "--outputs: labels are not available for videos (use json, overlay, mcap)"
        )
    return "json" in chosen, "overlay" in chosen or overlay_video, "mcap" in chosen


def recording_stem(paths: list[Path]) -> str:
    """The name of the one recording of a run's images: the stem of the one PATH given
    (a folder's name, or an image's stem), else ``images``."""
    if len(paths) == 1:
        return paths[0].stem or paths[0].resolve().name or "images"
    return "images"


def make_out_dir(console: Console, out_dir: Path) -> None:
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print_error(console, f"{out_dir}: cannot create output directory: {exc.strerror or exc}")
        raise typer.Exit(EXIT_FAILED) from None


def _detect_images(
    console: Console,
    images: list[Path],
    params: DetectParams,
    out_dir: Path,
    mask: Path | None,
    outputs: Iterable[str],
    per_image: dict,
    recording_path: Path | None = None,
) -> tuple[int, int, bool]:
    """Process image files into ``out_dir``; returns (processed, failed, interrupted).

    With ``recording_path``, every image processed also goes into that one MCAP recording.
    """
    outputs = frozenset(outputs)
    clashes = find_output_clashes(images)
    processed = failed = 0
    interrupted = False
    recording = _open_recording(console, recording_path)
    if recording_path is not None and recording is None:
        failed += 1
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
        disable=len(images) < 2 or not console.is_terminal,
    )
    try:
        with progress:
            task = progress.add_task("detecting", total=len(images))
            for path in images:
                progress.update(task, description=path.name)
                if path in clashes:
                    print_error(
                        console,
                        f"{path}: outputs would overwrite those of {clashes[path]} (same name)",
                    )
                    failed += 1
                elif (
                    detection := _process_or_report(
                        console, path, params, out_dir, mask, outputs, **per_image
                    )
                ) is None:
                    failed += 1
                else:
                    processed += 1
                    if recording is not None and not _record_image(
                        console, recording, path, detection
                    ):
                        failed += 1
                progress.advance(task)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if recording is not None and not _close_recording(console, recording):
            failed += 1
    state = " (interrupted)" if interrupted else ""
    into = f" (recorded in {recording.path})" if recording is not None and recording.frames else ""
    console.print(
        f"{processed} of {len(images)} image(s) processed into {out_dir}{into}{state}",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    return processed, failed, interrupted


def _open_recording(console: Console, path: Path | None) -> McapRecorder | None:
    """The images' recording at ``path`` (None when not asked for, or when it cannot be
    created: the error is printed)."""
    if path is None:
        return None
    from service.ros.recording import McapRecorder, RecordingError

    try:
        return McapRecorder(path)
    except RecordingError as exc:
        print_error(console, str(exc))
        return None


def _record_image(
    console: Console, recording: McapRecorder, path: Path, detection: Detection
) -> bool:
    """Add an image's frame to the recording; on failure print the error, return False."""
    from service.ros.recording import RecordingError

    try:
        recording.write_file(path, detection)
    except RecordingError as exc:  # reported per file, as every other output
        print_error(console, str(exc))
        return False
    except Exception as exc:
        print_error(console, failure_message(path, exc))
        return False
    return True


def _close_recording(console: Console, recording: McapRecorder) -> bool:
    from service.ros.recording import RecordingError

    try:
        recording.close()
    except RecordingError as exc:
        print_error(console, str(exc))
        return False
    return True


def run_stream(
    console: Console,
    open_source: Callable[[], FrameSource],
    params: DetectParams,
    out_dir: Path,
    outputs: tuple[bool, bool, bool],
    max_frames: int | None,
    segmenter: Segmenter | None = None,
    analyser: Callable[[FrameSource], StreamAnalyser] | None = None,
) -> StreamSummary | None:
    """Open a video or camera and process it with a progress bar; report on stderr.

    ``analyser``, given the opened source, makes what runs on each of its frames instead
    of plain detection (``dlo track``'s tracker). Returns None when the source cannot be
    opened or the output cannot be created (the error is printed), else the summary,
    also when Ctrl-C stopped it.
    """
    try:
        source = open_source()
    except VideoSourceError as exc:
        print_error(console, str(exc))
        return None
    except KeyboardInterrupt:
        return StreamSummary(source="", interrupted=True)

    jsonl, overlay_video, mcap = outputs
    reported = 0
    started = time.perf_counter()
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[fps]:.1f} fps"),
        TimeElapsedColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,
    )

    def on_frame(outcome: FrameOutcome) -> None:
        nonlocal reported
        if outcome.problem is not None:
            if reported < FRAME_MESSAGES_PER_STREAM:
                print_warning(console, f"{source.label}: {outcome.problem}")
            elif reported == FRAME_MESSAGES_PER_STREAM:
                print_warning(
                    console, f"{source.label}: further skipped frames are only counted below"
                )
            reported += 1
        progress.advance(task)
        done = progress.tasks[0].completed
        progress.update(task, fps=done / max(time.perf_counter() - started, 1e-9))

    with progress:
        task = progress.add_task(source.name, total=source.frame_count, fps=0.0)
        try:
            summary = process_stream(
                source,
                params,
                out_dir,
                jsonl=jsonl,
                overlay_video=overlay_video,
                mcap=mcap,
                max_frames=max_frames,
                on_frame=on_frame,
                segmenter=segmenter,
                analyser=None if analyser is None else analyser(source),
            )
        except OutputWriteError as exc:
            print_error(console, str(exc))
            return None

    if summary.stop_reason is not None:
        report = print_warning if summary.processed else print_error
        report(console, f"{source.label}: {summary.stop_reason}")
    if summary.output_error is not None:
        print_error(console, summary.output_error)
    elif summary.processed == 0 and not summary.interrupted and summary.stop_reason is None:
        print_error(console, f"{source.label}: no frame could be processed")
    console.print(_stream_summary_line(summary), markup=False, highlight=False, soft_wrap=True)
    return summary


def _stream_summary_line(summary: StreamSummary) -> str:
    """``clip.mp4: 12 frame(s) processed, 0 dropped or unreadable, 0 failed; ...``."""
    counts = (
        f"{summary.processed} frame(s) processed, {summary.unreadable} dropped or unreadable, "
        f"{summary.failed} failed"
    )
    p50 = summary.p50_ms
    timing = "" if p50 is None else f"; p50 {p50:.1f} ms/frame, {summary.fps:.1f} fps overall"
    state = " (interrupted)" if summary.interrupted else ""
    if summary.stop_reason is not None or summary.output_error is not None:
        state = " (stopped early)"
    outputs = (summary.jsonl_path, summary.overlay_path, summary.mcap_path)
    written = [str(path) for path in outputs if path is not None]
    into = f" -> {', '.join(written)}" if written and summary.processed else ""
    return f"{summary.source}: {counts}{timing}{state}{into}"


def _process_or_report(
    console: Console,
    path: Path,
    params: DetectParams,
    out_dir: Path | None,
    mask: Path | None,
    outputs: Iterable[str] = IMAGE_OUTPUTS,
    *,
    camera: CameraModel | None = None,
    depth_path: Path | None = None,
    physics: CablePhysics | None = None,
    segmenter: Segmenter | None = None,
) -> Detection | None:
    """Run :func:`process_file`; on failure print the one-line error and return None."""
    try:
        return process_file(
            path,
            params,
            out_dir,
            mask_path=mask,
            outputs=frozenset(outputs),
            camera=camera,
            depth_path=depth_path,
            physics=physics,
            segmenter=segmenter,
        )
    except Exception as exc:  # every failure is reported per file and the batch goes on
        raise_if_interrupted(exc)
        print_error(console, failure_message(path, exc))
        return None


def _load_camera_model(console: Console, path: Path) -> CameraModel:
    """:meth:`CameraModel.from_file`; a bad file is a usage error naming it (exit 2)."""
    try:
        return CameraModel.from_file(path)
    except OSError as exc:
        exit_usage(console, f"--camera {path}: {exc.strerror or exc}")
    except ValidationError as exc:
        exit_usage(console, f"--camera {path}: {describe_json_validation_error(exc, 'camera')}")
    except ValueError as exc:  # unknown suffix, YAML syntax
        exit_usage(console, f"--camera {path}: {str(exc).removeprefix(f'{path}: ')}")


def _three_d_options(
    console: Console,
    camera_model: CameraModel | None,
    depth: Path | None,
    physics: str | None,
    selected: Iterable[str],
) -> CablePhysics | None:
    """Check --depth, --physics and --outputs mjcf against the camera model; the physics."""
    if camera_model is None:
        for given, option in ((depth, "--depth"), (physics, "--physics")):
            if given is not None:
                exit_usage(console, f"{option} needs a camera model: --camera CAMERA.json")
        if "mjcf" in selected:
            exit_usage(console, "--outputs mjcf needs a camera model: --camera CAMERA.json")
        return None
    surface = camera_model.surface
    if isinstance(surface, DepthSurface) and depth is None:
        exit_usage(
            console,
            "the camera model's surface is a depth image (kind 'depth'): give --depth DEPTH "
            "(a 16-bit PNG or a .npy array aligned with the image)",
        )
    if not isinstance(surface, DepthSurface) and depth is not None:
        exit_usage(
            console,
            f"--depth: the camera model's surface is the plane z = {surface.plane_z} m; a "
            'depth image needs the surface {"kind": "depth", "depth_scale": ...}',
        )
    if physics is None:
        return None
    text = physics
    if not physics.lstrip().startswith("{"):
        try:
            text = Path(physics).read_text(encoding="utf-8")
        except OSError as exc:
            exit_usage(console, f"--physics {physics}: {exc.strerror or exc}")
    try:
        return CablePhysics.model_validate_json(text)
    except ValidationError as exc:
        exit_usage(console, f"--physics: {describe_json_validation_error(exc, 'physics')}")
