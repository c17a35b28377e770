"""The ``dlo`` command line: a thin typer shell over :mod:`service.batch`.

Output conventions: stdout carries only results (the detection JSON of a single
image, or the paths ``dlo demo`` wrote); progress, summaries and errors go to
stderr, each error on one line ``error: <file>: <problem>``. Exit status: 0 when
everything worked, 1 when any input failed, 2 for a usage error.
"""

from __future__ import annotations

import sys
import time
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as installed_version
from pathlib import Path
from typing import Annotated, NoReturn

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from schemas import Detection, DetectParams, SegmentationMethod
from service.batch import (
    InvalidParametersError,
    OutputPaths,
    build_params,
    detection_to_json,
    expand_inputs,
    failure_message,
    find_output_clashes,
    process_file,
)
from service.imageio import write_png
from service.perception import render_overlay

EXIT_FAILED = 1
"""At least one input could not be processed."""
EXIT_USAGE = 2
"""The command line itself is wrong; nothing was processed."""

DEMO_SIZE = (1280, 720)
DEMO_CABLES = 3
DEMO_OCCLUDERS = 2


def _default_of(field: str) -> str:
    """The default of a :class:`DetectParams` field, as shown in ``--help``."""
    default = DetectParams.model_fields[field].default
    if isinstance(default, SegmentationMethod):
        return default.value
    if isinstance(default, tuple):
        return " ".join(map(str, default))
    return str(default)


app = typer.Typer(
    name="dlo",
    help="Detect cables (deformable linear objects) in images as chains of segments.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.command()
def detect(
    paths: Annotated[
        list[Path],
        typer.Argument(metavar="PATH", help="Image files, or directories of images."),
    ],
    mask: Annotated[
        Path | None,
        typer.Option(help="Foreground mask (non-zero = cable) for a single input image."),
    ] = None,
    segment_length: Annotated[
        float | None,
        typer.Option(
            metavar="PX",
            help="Length of each chain segment.",
            show_default=_default_of("segment_length"),
        ),
    ] = None,
    expected_count: Annotated[
        int | None, typer.Option(metavar="N", help="Number of cables in view, when known.")
    ] = None,
    segmentation: Annotated[
        SegmentationMethod | None,
        typer.Option(
            help="Segmentation when no mask is given.",
            show_default=_default_of("segmentation"),
        ),
    ] = None,
    hsv_low: Annotated[
        tuple[int, int, int] | None,
        typer.Option(
            metavar="H S V",
            help="Lower HSV bound for --segmentation hsv.",
            show_default=_default_of("hsv_low"),
        ),
    ] = None,
    hsv_high: Annotated[
        tuple[int, int, int] | None,
        typer.Option(
            metavar="H S V",
            help="Upper HSV bound for --segmentation hsv.",
            show_default=_default_of("hsv_high"),
        ),
    ] = None,
    out_dir: Annotated[
        Path | None,
        typer.Option(
            metavar="DIR",
            help="Write <stem>.json, <stem>.labels.png and <stem>.overlay.png here; "
            "without it, the JSON of the single input goes to stdout.",
        ),
    ] = None,
) -> None:
    """Detect the cables in each image; write JSON, label and overlay files."""
    console = _stderr_console()
    try:
        params = build_params(
            segment_length=segment_length,
            expected_count=expected_count,
            segmentation=segmentation,
            hsv_low=hsv_low,
            hsv_high=hsv_high,
        )
    except InvalidParametersError as exc:
        _exit_usage(console, str(exc))

    files, problems = expand_inputs(paths)
    if mask is not None and (len(paths) != 1 or len(files) > 1):
        _exit_usage(console, "--mask applies to a single input image")
    if out_dir is None and len(files) > 1:
        _exit_usage(console, "several inputs need --out-dir")

    for problem in problems:
        _print_error(console, problem)
    failed = len(problems)

    if out_dir is None:
        if files:
            detection = _process_or_report(console, files[0], params, None, mask)
            if detection is None:
                failed += 1
            else:
                typer.echo(detection_to_json(detection))
        raise typer.Exit(EXIT_FAILED if failed else 0)

    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _print_error(console, f"{out_dir}: cannot create output directory: {exc.strerror or exc}")
        raise typer.Exit(EXIT_FAILED) from None

    clashes = find_output_clashes(files)
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
        disable=len(files) < 2 or not console.is_terminal,
    )
    with progress:
        task = progress.add_task("detecting", total=len(files))
        for path in files:
            progress.update(task, description=path.name)
            if path in clashes:
                _print_error(
                    console,
                    f"{path}: outputs would overwrite those of {clashes[path]} (same name)",
                )
                failed += 1
            elif _process_or_report(console, path, params, out_dir, mask) is None:
                failed += 1
            progress.advance(task)

    done = len(files) - (failed - len(problems))
    console.print(
        f"{done} of {len(files)} image(s) processed into {out_dir}",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    raise typer.Exit(EXIT_FAILED if failed else 0)


@app.command()
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
    console = _stderr_console()
    width, height = DEMO_SIZE
    try:
        # Imported here so that `dlo detect` does not depend on the scene generator.
        from service.synthetic import make_scene

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
        _print_error(console, failure_message("demo", exc))
        raise typer.Exit(EXIT_FAILED) from None

    _print_summary(console, detection, len(scene.cables), elapsed_ms)
    for path in (example, *OutputPaths.for_input(example, out_dir).all()):
        typer.echo(str(path))


@app.command()
def version() -> None:
    """Print the installed version of dlo-service."""
    try:
        number = installed_version("dlo-service")
    except PackageNotFoundError:
        number = "unknown (not installed)"
    typer.echo(f"dlo-service {number}")


def main() -> None:
    """Entry point of the ``dlo`` console script; no traceback ever reaches the user."""
    try:
        app(prog_name="dlo")
    except Exception as exc:  # last line of defence: bugs in the shell itself
        print(f"error: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        sys.exit(EXIT_FAILED)


def _process_or_report(
    console: Console,
    path: Path,
    params: DetectParams,
    out_dir: Path | None,
    mask: Path | None,
) -> Detection | None:
    """Run :func:`process_file`; on failure print the one-line error and return None."""
    try:
        return process_file(path, params, out_dir, mask_path=mask)
    except Exception as exc:  # every failure is reported per file and the batch goes on
        _print_error(console, failure_message(path, exc))
        return None


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


def _stderr_console() -> Console:
    return Console(stderr=True)


def _print_error(console: Console, message: str) -> None:
    line = Text("error: ", style="bold red")
    line.append(message)
    console.print(line, soft_wrap=True, highlight=False)


def _exit_usage(console: Console, message: str) -> NoReturn:
    _print_error(console, message)
    raise typer.Exit(EXIT_USAGE)
