"""``dlo demo``: generate the bundled synthetic example scene and detect the cables in it."""

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
) -> None:
    """Generate the bundled synthetic example scene and detect the cables in it."""
    console = stderr_console()
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
