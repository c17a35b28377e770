"""``dlo demo``: generate the bundled synthetic example scene and detect the cables in it;
with ``--examples DIR``, (re)write the README's example photograph and depth image."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from schemas import Detection, DetectParams
from service.batch import OutputPaths, failure_message, process_file
from service.console import EXIT_FAILED, load_kernels, print_error, stderr_console
from service.imageio import write_png
from service.perception import render_overlay
from service.synthetic import make_scene

DEMO_SIZE = (1280, 720)
DEMO_CABLES = 3
DEMO_OCCLUDERS = 2

EXAMPLE_SIZE = (640, 360)
"""The README's example camera (docs/examples/camera*.json) takes 640x360 images."""
EXAMPLE_SEED = 1
"""A scene with an orange cable, which the README's HSV box picks out."""
EXAMPLE_TABLE_MM = 600
"""The example camera looks straight down from 0.6 m onto the table."""
EXAMPLE_MM_PER_PX = EXAMPLE_TABLE_MM / 900.0
"""Millimetres per pixel on the table at that height (focal length 900 px)."""


def demo(
    out_dir: Annotated[
        Path, typer.Option(metavar="DIR", help="Where to write the scene and the outputs.")
    ] = Path("out/demo"),
    seed: Annotated[int, typer.Option(help="Seed of the synthetic scene.")] = 7,
    figure: Annotated[
        Path | None,
        typer.Option(
            metavar="FILE",
            help="Also write the scene and its overlay side by side at half size "
            "(the README picture).",
        ),
    ] = None,
    viewer_screenshot: Annotated[
        Path | None,
        typer.Option(
            metavar="FILE",
            help="Also open the viewer page (GET /) of a service started here in Debian's "
            "chromium, detect the scene in it, point at its longest chain and save a "
            "screenshot (the README picture; needs the dev extra's Playwright).",
        ),
    ] = None,
    examples: Annotated[
        Path | None,
        typer.Option(
            metavar="DIR",
            help="Instead, write the README's example photograph cables.jpg and its depth "
            "image cables_depth.png (16-bit, mm) here, for the camera of "
            "docs/examples/camera.json.",
        ),
    ] = None,
) -> None:
    """Generate the bundled synthetic example scene and detect the cables in it."""
    console = stderr_console()
    if examples is not None:
        try:
            for path in write_examples(examples):
                typer.echo(str(path))
        except Exception as exc:
            print_error(console, failure_message(str(examples), exc))
            raise typer.Exit(EXIT_FAILED) from None
        return
    width, height = DEMO_SIZE
    load_kernels(console)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        scene = make_scene(width, height, DEMO_CABLES, seed=seed, occluders=DEMO_OCCLUDERS)
        example = out_dir / "example.png"
        write_png(example, scene.image)
        started = time.perf_counter()
        detection = process_file(example, DetectParams(), out_dir)
        elapsed_ms = (time.perf_counter() - started) * 1000.0
        if figure is not None:
            overlay = render_overlay(scene.image, detection)
            side_by_side = np.hstack([scene.image, overlay])[::2, ::2]
            write_png(figure, np.ascontiguousarray(side_by_side))
    except Exception as exc:  # report any failure on one line, never a traceback
        print_error(console, failure_message("demo", exc))
        raise typer.Exit(EXIT_FAILED) from None

    _print_summary(console, detection, len(scene.cables), elapsed_ms)
    for path in (example, *OutputPaths.for_input(example, out_dir).all()):
        typer.echo(str(path))
    if viewer_screenshot is not None:
        try:
            _screenshot_viewer(example, detection, viewer_screenshot)
        except Exception as exc:  # no browser, or the page failed: one line
            print_error(console, failure_message("viewer screenshot", exc))
            raise typer.Exit(EXIT_FAILED) from None
        typer.echo(str(viewer_screenshot))


def _screenshot_viewer(example: Path, detection: Detection, out: Path) -> None:
    """Serve the viewer here (no zenoh, no token) and photograph it with ``example``."""
    from service.browser import screenshot_viewer, serving
    from service.http import create_app
    from service.http.server import uvicorn_options
    from service.runtime.settings import Settings

    settings = Settings(workers=1, zenoh=False, api_token=None, api_token_file=None)
    with serving(create_app(settings), uvicorn_options("127.0.0.1", 0, "warning")) as base:
        screenshot_viewer(base, example, detection, out)


def write_examples(directory: Path) -> tuple[Path, Path]:
    """Write ``cables.jpg`` (three cables, one orange, one occluder) and
    ``cables_depth.png``: depth along the optical axis in mm (16-bit), the table at 600
    mm, each cable as high as it is wide, the occluder a 20 mm block. Returns both paths."""
    import cv2

    scene = make_scene(*EXAMPLE_SIZE, 3, seed=EXAMPLE_SEED, occluders=1, radius_range=(4.0, 7.0))
    depth = np.full(scene.mask.shape, EXAMPLE_TABLE_MM, np.uint16)
    for label, cable in enumerate(scene.cables, start=1):
        height_mm = 2.0 * cable.radius * EXAMPLE_MM_PER_PX
        depth[scene.labels == label] = round(EXAMPLE_TABLE_MM - height_mm)
    for occluder in scene.occluders:
        corners = np.round(occluder.polygon).astype(np.int32)
        cv2.fillPoly(depth, [corners], EXAMPLE_TABLE_MM - 20)
    directory.mkdir(parents=True, exist_ok=True)
    photo, depth_png = directory / "cables.jpg", directory / "cables_depth.png"
    encoded_ok, jpeg = cv2.imencode(".jpg", scene.image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not encoded_ok:
        raise RuntimeError("OpenCV could not encode the example photograph as JPEG")
    photo.write_bytes(jpeg.tobytes())  # a photograph: 40 KB where a PNG takes 400
    write_png(depth_png, depth)
    return photo, depth_png


def _print_summary(
    console: Console, detection: Detection, cable_count: int, elapsed_ms: float
) -> None:
    console.print(
        f"{len(detection.chains)} chain(s) found in a {detection.width}x{detection.height} "
        f"scene of {cable_count} cable(s), segments of {detection.segment_length:g} px",
        highlight=False,
    )
    chains = Table(title="chains", title_justify="left")
    for column in ("id", "points", "length px", "radius px", "inferred segments"):
        chains.add_column(column, justify="right")
    for chain in detection.chains:
        chains.add_row(
            str(chain.id),
            str(len(chain.points)),
            f"{chain.length:.1f}",
            f"{chain.radius:.1f}",
            str(sum(chain.inferred)),
        )
    console.print(chains)

    if detection.crossings:
        crossings = Table(title="crossings", title_justify="left")
        for column in ("x", "y", "over", "under", "confidence"):
            crossings.add_column(column, justify="right")
        for crossing in detection.crossings:
            crossings.add_row(
                f"{crossing.x:.0f}",
                f"{crossing.y:.0f}",
                str(crossing.over),
                str(crossing.under),
                f"{crossing.confidence:.2f}",
            )
        console.print(crossings)
    else:
        console.print("no crossings")

    stage_times = ", ".join(
        f"{stage} {milliseconds:.0f}"
        for stage, milliseconds in detection.timings_ms.model_dump().items()
    )
    console.print(
        f"timings (ms): {stage_times}; with file I/O {elapsed_ms:.0f}",
        highlight=False,
        soft_wrap=True,
    )
