"""``dlo eval``: score the detector on a labelled data set or on synthetic scenes.

Two modes:

``dlo eval DATASET_DIR``
    Every ``<subset>/images/<name>.jpg`` with a ``<subset>/labels/<name>.png`` (the
    layout of ``../shared/datasets/mbest``) is detected with the default parameters
    and scored by mean instance DICE and crossing order (see
    :mod:`service.evaluation.dataset`).
``dlo eval --synthetic N``
    N scenes of :func:`service.synthetic.make_scene` are detected and scored like the
    results table of Keipour et al.: frames, occlusions and merges (see
    :mod:`service.evaluation.synthetic_eval`).

The results table goes to stdout (or JSON with ``--json``); the progress bar and the
errors, one line each, go to stderr. Exit status: 0 when every image was scored, 1 when
some failed (they are reported and left out), 2 for a usage error or a data-set folder
without labelled images.

The scoring modules import the detector and SciPy, so they are imported only when the
command runs, to keep ``dlo`` quick to start.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TextIO

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from service.console import EXIT_FAILED, exit_usage, load_kernels, print_error

if TYPE_CHECKING:
    from schemas import DetectParams

SYNTHETIC_SIZE = (1280, 720)
SYNTHETIC_CABLES = "1-3"
SYNTHETIC_OCCLUDERS = 2
SYNTHETIC_SEED = 0
MIN_SIDE = 64


def eval_command(
    dataset_dir: Annotated[
        Path | None,
        typer.Argument(
            metavar="DATASET_DIR",
            help="Data set with <subset>/images/<name>.jpg and <subset>/labels/<name>.png.",
            show_default=False,
        ),
    ] = None,
    mask_from_labels: Annotated[
        bool,
        typer.Option(
            "--mask-from-labels",
            help="Give the detector the ground-truth foreground (labels > 0) as its mask, "
            "with the image, to score the instance reasoning alone.",
        ),
    ] = False,
    csv_file: Annotated[
        Path | None,
        typer.Option("--csv", metavar="FILE", help="Write one row per image (or scene) here."),
    ] = None,
    out_dir: Annotated[
        Path | None,
        typer.Option(
            metavar="DIR",
            help="Keep <subset>_<name>.json, .labels.png and .overlay.png per image "
            "(scene_<seed>.png and the same per synthetic scene).",
        ),
    ] = None,
    worst: Annotated[
        int,
        typer.Option(metavar="N", help="List the N lowest-scoring images (or frames)."),
    ] = 3,
    synthetic: Annotated[
        int | None,
        typer.Option(
            metavar="N", help="Score N synthetic scenes instead of a data set.", show_default=False
        ),
    ] = None,
    seed: Annotated[
        int | None,
        typer.Option(
            metavar="S",
            help="Seed of the first synthetic scene; scene i uses seed S + i.",
            show_default=str(SYNTHETIC_SEED),
        ),
    ] = None,
    occluders: Annotated[
        int | None,
        typer.Option(
            metavar="K",
            help="Occluders per synthetic scene.",
            show_default=str(SYNTHETIC_OCCLUDERS),
        ),
    ] = None,
    cables: Annotated[
        str | None,
        typer.Option(
            metavar="C|LO-HI",
            help="Cables per synthetic scene: C in every scene, or LO-HI cycled by seed "
            "(seed s gets LO + s mod (HI - LO + 1) cables).",
            show_default=SYNTHETIC_CABLES,
        ),
    ] = None,
    width: Annotated[
        int | None,
        typer.Option(
            metavar="W", help="Synthetic image width.", show_default=str(SYNTHETIC_SIZE[0])
        ),
    ] = None,
    height: Annotated[
        int | None,
        typer.Option(
            metavar="H", help="Synthetic image height.", show_default=str(SYNTHETIC_SIZE[1])
        ),
    ] = None,
    json_output: Annotated[
        bool,
        typer.Option("--json", help="Print the results as JSON instead of a table."),
    ] = False,
    params_text: Annotated[
        str | None,
        typer.Option(
            "--params",
            metavar="JSON|FILE",
            help="Detection parameters other than the defaults, as a JSON object such as "
            '\'{"gap_curve": "natural"}\' or a file holding one.',
            show_default=False,
        ),
    ] = None,
) -> None:
    """Score the detector on a labelled data set, or on synthetic scenes (--synthetic N)."""
    errors = Console(stderr=True)
    if worst < 0:
        exit_usage(errors, "--worst must be 0 or more")
    params = _parse_params(errors, params_text)
    synthetic_options = {
        "--seed": seed,
        "--occluders": occluders,
        "--cables": cables,
        "--width": width,
        "--height": height,
    }
    if synthetic is None:
        if dataset_dir is None:
            exit_usage(errors, "give a DATASET_DIR or --synthetic N")
        given = [name for name, value in synthetic_options.items() if value is not None]
        if given:
            exit_usage(errors, f"{', '.join(given)} apply only with --synthetic N")
        _run_dataset(
            errors, dataset_dir, mask_from_labels, csv_file, out_dir, worst, json_output, params
        )
    else:
        if dataset_dir is not None:
            exit_usage(errors, "give either a DATASET_DIR or --synthetic N, not both")
        _run_synthetic(
            errors,
            synthetic,
            SYNTHETIC_SEED if seed is None else seed,
            SYNTHETIC_OCCLUDERS if occluders is None else occluders,
            SYNTHETIC_CABLES if cables is None else cables,
            SYNTHETIC_SIZE[0] if width is None else width,
            SYNTHETIC_SIZE[1] if height is None else height,
            mask_from_labels,
            csv_file,
            out_dir,
            worst,
            json_output,
            params,
        )


def _parse_params(errors: Console, text: str | None) -> DetectParams | None:
    """``--params``: a JSON object of DetectParams fields, or a file holding one."""
    from service.batch import InvalidParametersError, read_params

    if text is None:
        return None
    try:
        return read_params(text)
    except InvalidParametersError as exc:
        exit_usage(errors, str(exc))


def _params_json(params: DetectParams | None) -> dict[str, Any]:
    """The parameters that differ from the defaults (empty for the defaults)."""
    return {} if params is None else params.model_dump(mode="json", exclude_defaults=True)


def _params_note(params: DetectParams | None) -> str:
    changed = _params_json(params)
    return f", parameters {json.dumps(changed)}" if changed else ""


# --------------------------------------------------------------------------- data set


def _run_dataset(
    errors: Console,
    root: Path,
    mask_from_labels: bool,
    csv_file: Path | None,
    out_dir: Path | None,
    worst: int,
    json_output: bool,
    params: DetectParams | None = None,
) -> None:
    from service.evaluation import dataset
    from service.imageio import read_image

    try:
        items, unlabelled = dataset.find_labelled_images(root)
    except dataset.DatasetLayoutError as exc:
        exit_usage(errors, str(exc))
    for problem in unlabelled:
        print_error(errors, problem)
    _make_out_dir(errors, out_dir)

    # Load the compiled kernels first, so that ms/image is the detection alone.
    load_kernels(errors)
    scores = []
    failed = len(unlabelled)
    with (
        _csv_writer(errors, csv_file, dataset.CSV_COLUMNS) as writer,
        _progress(errors, len(items), "evaluating") as advance,
    ):
        for item in items:
            try:
                image = read_image(item.image)
                truth = dataset.read_labels(item.labels)
                score, result, predicted = dataset.evaluate_image(
                    image,
                    truth,
                    subset=item.subset,
                    name=item.name,
                    params=params,
                    mask_from_labels=mask_from_labels,
                )
                if out_dir is not None:
                    _write_outputs(out_dir / f"{item.subset}_{item.name}", image, result, predicted)
            except Exception as exc:  # one line per failed image; the run goes on
                print_error(errors, _failure(item.image, exc))
                failed += 1
            else:
                scores.append(score)
                if writer is not None:
                    writer(dataset.csv_row(score))
            advance(item.name)

    if scores:
        per_subset, overall = dataset.summarise_by_subset(scores, worst)
        mode = "mask from labels" if mask_from_labels else "segmented from the image"
        mode += _params_note(params)
        if json_output:
            _print_json(
                {
                    "dataset": str(root),
                    "mask_from_labels": mask_from_labels,
                    "params": _params_json(params),
                    "subsets": [_subset_json(s) for s in per_subset],
                    "all": _subset_json(overall),
                    "failed": failed,
                }
            )
        else:
            _print_dataset_table(root, mode, per_subset, overall, worst)
    raise typer.Exit(EXIT_FAILED if failed else 0)


def _subset_json(summary) -> dict[str, Any]:
    return {
        "subset": summary.subset,
        "images": summary.images,
        "mean_dice": _finite(summary.mean_dice),
        "min_dice": _finite(summary.min_dice),
        "worst": [{"image": name, "dice": round(dice, 4)} for name, dice in summary.worst],
        "crossings_detected": summary.crossings_detected,
        "crossings_self": summary.crossings_self,
        "crossings_judged": summary.crossings_judged,
        "crossings_correct": summary.crossings_correct,
        "crossing_accuracy": _finite(summary.crossing_accuracy),
        "mean_ms": _finite(summary.mean_ms, 1),
    }


def _print_dataset_table(root: Path, mode: str, per_subset, overall, worst: int) -> None:
    out = Console(highlight=False)
    table = Table(title=f"{root} ({mode})", title_justify="left")
    for column in ("subset", "images", "mean DICE", "min DICE", "crossing order", "ms/image"):
        table.add_column(column, justify="right")
    if worst:
        table.add_column(f"worst {worst}", justify="left")
    rows = [*per_subset, overall] if len(per_subset) > 1 else per_subset
    for summary in rows:
        order = (
            f"{summary.crossings_correct}/{summary.crossings_judged} "
            f"({100.0 * summary.crossing_accuracy:.0f} %)"
            if summary.crossings_judged
            else "-"
        )
        cells = [
            summary.subset,
            str(summary.images),
            f"{summary.mean_dice:.3f}",
            f"{summary.min_dice:.3f}",
            order,
            f"{summary.mean_ms:.0f}",
        ]
        if worst:
            cells.append(", ".join(f"{name} {dice:.3f}" for name, dice in summary.worst))
        table.add_row(*cells, end_section=summary is per_subset[-1])
    out.print(table)
    not_judged = overall.crossings_detected - overall.crossings_judged - overall.crossings_self
    out.print(
        "crossing order: correct/judged detected crossings between chains matched to two "
        f"different ground-truth cables; {overall.crossings_self} self-crossing(s) cannot be "
        f"judged from labels and {not_judged} other crossing(s) were not judged "
        "(unmatched chains, both on one cable, or no label at the crossing).",
        soft_wrap=True,
    )


# --------------------------------------------------------------------------- synthetic


def _run_synthetic(
    errors: Console,
    count: int,
    first_seed: int,
    occluders: int,
    cables: str,
    width: int,
    height: int,
    mask_from_labels: bool,
    csv_file: Path | None,
    out_dir: Path | None,
    worst: int,
    json_output: bool,
    params: DetectParams | None = None,
) -> None:
    from service.evaluation import synthetic_eval
    from service.synthetic import make_scene

    if count < 1:
        exit_usage(errors, "--synthetic must be 1 or more")
    if first_seed < 0:
        exit_usage(errors, "--seed must be 0 or more")
    if occluders < 0:
        exit_usage(errors, "--occluders must be 0 or more")
    if width < MIN_SIDE or height < MIN_SIDE:
        exit_usage(errors, f"--width and --height must be {MIN_SIDE} or more")
    load_kernels(errors)  # ms per scene is the detection alone
    try:
        low, high = synthetic_eval.parse_cable_counts(cables)
    except ValueError as exc:
        exit_usage(errors, str(exc))
    _make_out_dir(errors, out_dir)

    scores = []
    failed = 0
    with (
        _csv_writer(errors, csv_file, synthetic_eval.CSV_COLUMNS) as writer,
        _progress(errors, count, "evaluating") as advance,
    ):
        for seed in range(first_seed, first_seed + count):
            try:
                n_cables = synthetic_eval.cables_for_seed(seed, low, high)
                scene = make_scene(width, height, n_cables, seed=seed, occluders=occluders)
                score, result = synthetic_eval.evaluate_scene(
                    scene, seed, params, mask_from_labels=mask_from_labels
                )
                if out_dir is not None:
                    from service.imageio import write_png
                    from service.perception import render_labels

                    stem = out_dir / f"scene_{seed}"
                    write_png(stem.with_name(f"{stem.name}.png"), scene.image)
                    predicted = render_labels(result.detection, result.mask, scene.image)
                    _write_outputs(stem, scene.image, result, predicted)
            except Exception as exc:  # one line per failed scene; the run goes on
                print_error(errors, _failure(f"scene seed {seed}", exc))
                failed += 1
            else:
                scores.append(score)
                if writer is not None:
                    writer(synthetic_eval.csv_row(score))
            advance(f"seed {seed}")

    if scores:
        summary = synthetic_eval.summarise_scenes(scores)
        lowest = sorted(scores, key=lambda s: (s.frame.correct, min(s.frame.coverage, default=1)))
        lowest = [s for s in lowest if not s.frame.correct][:worst]
        setup = {
            "scenes": count,
            "first_seed": first_seed,
            "width": width,
            "height": height,
            "cables": f"{low}-{high}" if low != high else str(low),
            "occluders": occluders,
            "mask_from_labels": mask_from_labels,
            "params": _params_json(params),
        }
        if json_output:
            _print_json(_synthetic_json(setup, summary, lowest, failed))
        else:
            _print_synthetic_table(setup, summary, lowest)
    raise typer.Exit(EXIT_FAILED if failed else 0)


def _tally_json(tally) -> dict[str, Any]:
    return {
        "total": tally.total,
        "correct": tally.correct,
        "incorrect": tally.incorrect,
        "accuracy": _finite(tally.accuracy, 1),
    }


def _synthetic_json(setup, summary, lowest, failed: int) -> dict[str, Any]:
    from service.evaluation.synthetic_eval import PAPER_ACCURACY

    return {
        "setup": setup,
        "frames": _tally_json(summary.frames),
        "occlusions": _tally_json(summary.occlusions),
        "merges": _tally_json(summary.merges),
        "crossings": {**_tally_json(summary.crossings), "found": summary.crossings_found},
        "self_crossings": {
            **_tally_json(summary.self_crossings),
            "found": summary.self_crossings_found,
        },
        "mean_dice": _finite(summary.mean_dice),
        "mean_ms": _finite(summary.mean_ms, 1),
        "incorrect_frames": list(summary.failed_frames),
        "worst": [_frame_json(score) for score in lowest],
        "paper_accuracy": PAPER_ACCURACY,
        "failed": failed,
    }


def _frame_json(score) -> dict[str, Any]:
    return {
        "seed": score.seed,
        "cables": score.frame.n_cables,
        "chains": score.frame.n_chains,
        "coverage": [round(value, 4) for value in score.frame.coverage],
    }


def _print_synthetic_table(setup: dict[str, Any], summary, lowest) -> None:
    from service.evaluation.synthetic_eval import PAPER_ACCURACY

    out = Console(highlight=False)
    last_seed = setup["first_seed"] + setup["scenes"] - 1
    title = (
        f"{setup['scenes']} synthetic scenes {setup['width']}x{setup['height']}, "
        f"{setup['cables']} cable(s), {setup['occluders']} occluder(s), "
        f"seeds {setup['first_seed']}-{last_seed}"
        + (", mask from labels" if setup["mask_from_labels"] else "")
        + (f", parameters {json.dumps(setup['params'])}" if setup["params"] else "")
    )
    table = Table(title=title, title_justify="left")
    table.add_column("")
    for column in ("Total", "Correct", "Incorrect", "Accuracy"):
        table.add_column(column, justify="right")
    rows = [
        ("Frames", summary.frames),
        ("Occlusions", summary.occlusions),
        ("Merges", summary.merges),
        ("Crossing order, two cables", summary.crossings),
        ("Crossing order, self", summary.self_crossings),
    ]
    for name, tally in rows:
        accuracy = f"{tally.accuracy:.1f} %" if tally.total else "-"
        table.add_row(
            name,
            f"{tally.total:,}",
            f"{tally.correct:,}",
            f"{tally.incorrect:,}",
            accuracy,
            end_section=name == "Merges",
        )
    out.print(table)
    out.print(
        "paper (Keipour et al., 4,230 real video frames): "
        f"{PAPER_ACCURACY['frames']} % frames, {PAPER_ACCURACY['occlusions']} % occlusions, "
        f"{PAPER_ACCURACY['merges']} % merges",
        soft_wrap=True,
    )
    out.print(
        f"crossings found within 10 px: {summary.crossings_found} of "
        f"{summary.crossings.total} (two cables), {summary.self_crossings_found} of "
        f"{summary.self_crossings.total} (self); mean instance DICE {summary.mean_dice:.3f}; "
        f"mean detection time {summary.mean_ms:.0f} ms per scene",
        soft_wrap=True,
    )
    if lowest:
        listed = "; ".join(
            f"seed {s.seed}: {s.frame.n_chains} chain(s) for {s.frame.n_cables} cable(s), "
            f"coverage {', '.join(f'{c:.2f}' for c in s.frame.coverage)}"
            for s in lowest
        )
        out.print(f"worst incorrect frames: {listed}", soft_wrap=True)


# --------------------------------------------------------------------------- shared


def _write_outputs(stem: Path, image, result, predicted) -> None:
    from service.imageio import write_png, write_text
    from service.perception import render_overlay

    write_png(stem.with_name(f"{stem.name}.labels.png"), predicted)
    write_png(stem.with_name(f"{stem.name}.overlay.png"), render_overlay(image, result.detection))
    write_text(
        stem.with_name(f"{stem.name}.json"), result.detection.model_dump_json(indent=2) + "\n"
    )


def _make_out_dir(errors: Console, out_dir: Path | None) -> None:
    if out_dir is None:
        return
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        exit_usage(errors, f"{out_dir}: cannot create output directory: {exc.strerror or exc}")


@contextmanager
def _csv_writer(errors: Console, path: Path | None, columns) -> Iterator:
    """Yield a function writing one row (flushed at once), or None without a file."""
    if path is None:
        yield None
        return
    try:
        handle: TextIO = path.open("w", newline="", encoding="utf-8")
    except OSError as exc:
        exit_usage(errors, f"{path}: cannot write the CSV file: {exc.strerror or exc}")
    with handle:
        writer = csv.DictWriter(handle, fieldnames=list(columns))
        writer.writeheader()

        def write(row: dict[str, str]) -> None:
            writer.writerow(row)
            handle.flush()

        yield write


@contextmanager
def _progress(errors: Console, total: int, label: str) -> Iterator:
    """A progress bar on stderr (only on a terminal); yields ``advance(description)``."""
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=errors,
        transient=True,
        disable=not errors.is_terminal,
    )
    with progress:
        task = progress.add_task(label, total=total)

        def advance(description: str) -> None:
            progress.update(task, advance=1, description=description)

        yield advance


def _failure(what, error: BaseException) -> str:
    from service.imageio import ImageFileError
    from service.perception import InvalidInputError

    if isinstance(error, ImageFileError):  # already "<file>: <problem>"
        message = str(error)
    elif isinstance(error, InvalidInputError | ValueError | OSError | RuntimeError):
        message = f"{what}: {error}"
    else:
        message = f"{what}: internal error: {type(error).__name__}: {error}"
    return " ".join(line.strip() for line in message.splitlines() if line.strip())


def _finite(value: float, digits: int = 4) -> float | None:
    return None if math.isnan(value) else round(value, digits)


def _print_json(data: dict[str, Any]) -> None:
    typer.echo(json.dumps(data, indent=2))
