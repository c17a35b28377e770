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
from service.evaluation.conventions import FAMILY_NAMES, HELD_OUT_FIRST_SEED, TUNING_SEEDS

if TYPE_CHECKING:
    from schemas import DetectParams

SYNTHETIC_SIZE = (1280, 720)
SYNTHETIC_CABLES = "1-3"
SYNTHETIC_OCCLUDERS = 2
SYNTHETIC_SEED = 0
MIN_SIDE = 64
FAMILY_MIN_SIZE = (320, 240)
PIPE_WIDTH = 160


def eval_command(
    dataset_dirs: Annotated[
        list[Path] | None,
        typer.Argument(
            metavar="DATASET_DIR...",
            help="Data sets with <subset>/images/<name>.jpg and <subset>/labels/<name>.png "
            "(and optionally <subset>/masks/<name>.png); several are scored into one table.",
            show_default=False,
        ),
    ] = None,
    mask_from_labels: Annotated[
        bool,
        typer.Option(
            "--mask-from-labels",
            help="Give the detector the true foreground as its mask, with the image, to score "
            "the instance reasoning alone: a data set's masks/ where present, otherwise "
            "labels > 0; a synthetic scene's own mask.",
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
    family: Annotated[
        str | None,
        typer.Option(
            metavar="F[,F...]|all",
            help="Score scenes of these named families (N scenes each; 'all': every family, "
            "one row each and a total) instead of make_scene's: "
            + ", ".join(FAMILY_NAMES)
            + ". See docs/BENCHMARKS.md for what each draws.",
            show_default=False,
        ),
    ] = None,
    seed: Annotated[
        int | None,
        typer.Option(
            metavar="S",
            help="Seed of the first synthetic scene; scene i uses seed S + i. Seeds "
            f"{TUNING_SEEDS[0]}-{TUNING_SEEDS[1]} are for tuning; seeds from "
            f"{HELD_OUT_FIRST_SEED} up are held out, to run only when reporting.",
            show_default=str(SYNTHETIC_SEED),
        ),
    ] = None,
    occluders: Annotated[
        int | None,
        typer.Option(
            metavar="K",
            help="Occluders per synthetic scene (make_scene only, not with --family).",
            show_default=str(SYNTHETIC_OCCLUDERS),
        ),
    ] = None,
    cables: Annotated[
        str | None,
        typer.Option(
            metavar="C|LO-HI",
            help="Cables per synthetic scene: C in every scene, or LO-HI cycled by seed "
            "(seed s gets LO + s mod (HI - LO + 1) cables); make_scene only, not with --family.",
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
    tracking: Annotated[
        int | None,
        typer.Option(
            metavar="N",
            help="Score the tracker (dlo track) on N generated videos instead: identity, "
            "same end, id switches and joint error against each cable's material points, "
            "beside the bare detection's; video i uses seed S + i.",
            show_default=False,
        ),
    ] = None,
    kinds: Annotated[
        str | None,
        typer.Option(
            metavar="K[,K...]|all",
            help="With --tracking: the kinds of video, taken in turn (default all: the kind "
            "goes by the seed): drift, rotation, bends, occluders, crossings, enter_leave.",
            show_default=False,
        ),
    ] = None,
    frames: Annotated[
        int,
        typer.Option(metavar="F", help="With --tracking: frames per video (30 per second)."),
    ] = 300,
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
    """Score the detector on a labelled data set, or on synthetic scenes (--synthetic N).

    Seeds: tune on seeds 0-99999 (and look at their failures); seeds from 100000 up are
    held out, to be run only to report a result (e.g. --synthetic 200 --seed 100001).
    """
    errors = Console(stderr=True)
    if worst < 0:
        exit_usage(errors, "--worst must be 0 or more")
    params = _parse_params(errors, params_text)
    if tracking is not None:
        _tracking_mode(errors, tracking, locals())
    elif kinds is not None:
        exit_usage(errors, "--kinds applies only with --tracking N")
    synthetic_options = {
        "--family": family,
        "--seed": seed,
        "--occluders": occluders,
        "--cables": cables,
        "--width": width,
        "--height": height,
    }
    if synthetic is None:
        if not dataset_dirs:
            exit_usage(errors, "give a DATASET_DIR or --synthetic N")
        given = [name for name, value in synthetic_options.items() if value is not None]
        if given:
            exit_usage(errors, f"{', '.join(given)} apply only with --synthetic N")
        _run_dataset(
            errors, dataset_dirs, mask_from_labels, csv_file, out_dir, worst, json_output, params
        )
    else:
        if dataset_dirs:
            exit_usage(errors, "give either a DATASET_DIR or --synthetic N, not both")
        if family is not None and (cables is not None or occluders is not None):
            exit_usage(errors, "--cables and --occluders apply only without --family")
        _run_synthetic(
            errors,
            _parse_families(errors, family),
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


def _tracking_mode(errors: Console, count: int, given: dict[str, Any]) -> None:
    """``--tracking N``: the tracker on generated videos (service/evaluation/tracking_cli.py)."""
    from service.evaluation import tracking_cli

    others = {
        "DATASET_DIR": given["dataset_dirs"],
        "--synthetic": given["synthetic"],
        "--family": given["family"],
        "--occluders": given["occluders"],
        "--cables": given["cables"],
        "--width": given["width"],
        "--height": given["height"],
        "--out-dir": given["out_dir"],
    }
    clash = [name for name, value in others.items() if value]
    if clash:
        exit_usage(errors, f"{', '.join(clash)} cannot be combined with --tracking")
    tracking_cli.run_tracking(
        errors,
        count,
        SYNTHETIC_SEED if given["seed"] is None else given["seed"],
        tracking_cli.parse_kinds(errors, given["kinds"]),
        given["frames"],
        given["mask_from_labels"],
        given["csv_file"],
        given["json_output"],
        given["params"],
        _csv_writer,
        _progress,
        _print_json,
        _stdout_console,
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
    roots: list[Path],
    mask_from_labels: bool,
    csv_file: Path | None,
    out_dir: Path | None,
    worst: int,
    json_output: bool,
    params: DetectParams | None = None,
) -> None:
    from service.evaluation import dataset

    found = []
    for root in roots:
        try:
            items, unlabelled = dataset.find_labelled_images(root)
        except dataset.DatasetLayoutError as exc:
            exit_usage(errors, str(exc))
        found.append((root, items, unlabelled))
    _make_out_dir(errors, out_dir)

    # Load the compiled kernels first, so that ms/image is the detection alone.
    load_kernels(errors)
    reports = []
    failed = 0
    columns = ("dataset", *dataset.CSV_COLUMNS) if len(roots) > 1 else dataset.CSV_COLUMNS
    with _csv_writer(errors, csv_file, columns) as writer:
        for root, items, unlabelled in found:
            for problem in unlabelled:
                print_error(errors, problem)
            scores, order_truth, root_failed = _score_dataset(
                errors, root, items, mask_from_labels, out_dir, writer, len(roots) > 1, params
            )
            failed += len(unlabelled) + root_failed
            if scores:
                per_subset, overall = dataset.summarise_by_subset(scores, worst)
                reports.append((root, order_truth, per_subset, overall))

    if reports:
        mode = "mask from labels" if mask_from_labels else "segmented from the image"
        mode += _params_note(params)
        if json_output:
            _print_json(
                {
                    "mask_from_labels": mask_from_labels,
                    "params": _params_json(params),
                    "datasets": [
                        {
                            "dataset": str(root),
                            "crossing_order_truth": order_truth,
                            "subsets": [_subset_json(s) for s in per_subset],
                            "all": _subset_json(overall),
                        }
                        for root, order_truth, per_subset, overall in reports
                    ],
                    "failed": failed,
                }
            )
        else:
            _print_dataset_table(mode, reports, worst)
    raise typer.Exit(EXIT_FAILED if failed else 0)


def _score_dataset(
    errors: Console, root: Path, items, mask_from_labels, out_dir, writer, name_dataset, params
):
    """Detect and score every image of one data set: (scores, order truth, failures)."""
    from service.evaluation import dataset
    from service.imageio import read_image

    order_truth = dataset.has_crossing_order_truth(items)
    scores = []
    failed = 0
    prefix = f"{root.name}_" if name_dataset else ""
    with _progress(errors, len(items), f"evaluating {root.name}") as advance:
        for item in items:
            try:
                image = read_image(item.image)
                truth = dataset.read_labels(item.labels)
                truth_mask = None if item.mask is None else dataset.read_mask(item.mask)
                score, result, predicted = dataset.evaluate_image(
                    image,
                    truth,
                    subset=item.subset,
                    name=item.name,
                    params=params,
                    mask_from_labels=mask_from_labels,
                    truth_mask=truth_mask,
                    judge_crossings=order_truth,
                )
                if out_dir is not None:
                    stem = out_dir / f"{prefix}{item.subset}_{item.name}"
                    _write_outputs(stem, image, result, predicted)
            except Exception as exc:  # one line per failed image; the run goes on
                print_error(errors, _failure(item.image, exc))
                failed += 1
            else:
                scores.append(score)
                if writer is not None:
                    row = dataset.csv_row(score)
                    writer({"dataset": root.name, **row} if name_dataset else row)
            advance(item.name)
    return scores, order_truth, failed


def _subset_json(summary) -> dict[str, Any]:
    return {
        "subset": summary.subset,
        "images": summary.images,
        "mean_dice": _finite(summary.mean_dice),
        "min_dice": _finite(summary.min_dice),
        "mean_foreground_dice": _finite(summary.mean_foreground_dice),
        "worst": [{"image": name, "dice": round(dice, 4)} for name, dice in summary.worst],
        "crossings_detected": summary.crossings_detected,
        "crossings_self": summary.crossings_self,
        "crossings_judged": summary.crossings_judged,
        "crossings_correct": summary.crossings_correct,
        "crossing_accuracy": _finite(summary.crossing_accuracy),
        "mean_ms": _finite(summary.mean_ms, 1),
    }


def _print_dataset_table(mode: str, reports, worst: int) -> None:
    out = _stdout_console()
    names = ", ".join(str(root) for root, *_ in reports)
    table = Table(title=f"{names} ({mode})", title_justify="left")
    columns = ["subset", "images", "mean DICE", "min DICE", "fg DICE", "crossing order"]
    if len(reports) > 1:
        columns.insert(0, "data set")
    for column in (*columns, "ms/image"):
        table.add_column(column, justify="right")
    if worst:
        table.add_column(f"worst {worst}", justify="left")
    notes = []
    for root, order_truth, per_subset, overall in reports:
        rows = [*per_subset, overall] if len(per_subset) > 1 else per_subset
        for summary in rows:
            if not order_truth:
                order = "n/a"
            elif summary.crossings_judged:
                order = (
                    f"{summary.crossings_correct}/{summary.crossings_judged} "
                    f"({100.0 * summary.crossing_accuracy:.0f} %)"
                )
            else:
                order = "-"
            cells = [
                summary.subset,
                str(summary.images),
                f"{summary.mean_dice:.4f}",
                f"{summary.min_dice:.3f}",
                f"{summary.mean_foreground_dice:.4f}",
                order,
                f"{summary.mean_ms:.0f}",
            ]
            if len(reports) > 1:
                cells.insert(0, root.name if summary is rows[0] else "")
            if worst:
                cells.append(", ".join(f"{name} {dice:.3f}" for name, dice in summary.worst))
            table.add_row(*cells, end_section=summary is per_subset[-1] or summary is overall)
        if order_truth:
            not_judged = overall.crossings_detected - overall.crossings_judged
            not_judged -= overall.crossings_self
            notes.append(
                f"{root.name}: crossing order = correct/judged detected crossings between "
                "chains matched to two different ground-truth cables; "
                f"{overall.crossings_self} self-crossing(s) cannot be judged from labels and "
                f"{not_judged} other crossing(s) were not judged (unmatched chains, both on "
                "one cable, or no label at the crossing)."
            )
        else:
            notes.append(
                f"{root.name}: crossing order n/a: its labels give every cable in full and mark "
                "the overlaps 255 (left out of the DICE), so they do not say which cable is on "
                f"top; {overall.crossings_detected} detected crossing(s) not judged."
            )
    out.print(table)
    out.print(
        "fg DICE: the detector's foreground mask against the true one (masks/ where the data "
        "set has them, otherwise labels > 0); with --mask-from-labels only the detector's "
        "clean-up of specks and small holes keeps it below 1.",
        soft_wrap=True,
    )
    for note in notes:
        out.print(note, soft_wrap=True)


# --------------------------------------------------------------------------- synthetic


def _parse_families(errors: Console, text: str | None) -> list[str] | None:
    """``--family``: None (make_scene's scenes), or the list of family names."""
    if text is None:
        return None
    names = [name.strip() for name in text.split(",") if name.strip()]
    if names == ["all"]:
        return list(FAMILY_NAMES)
    unknown = [name for name in names if name not in FAMILY_NAMES]
    if not names or unknown:
        exit_usage(
            errors,
            f"--family: unknown family {', '.join(map(repr, unknown)) or repr(text)}; "
            f"expected 'all' or names from {', '.join(FAMILY_NAMES)}",
        )
    return list(dict.fromkeys(names))


def _run_synthetic(
    errors: Console,
    families: list[str] | None,
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
    from service.synthetic import make_family_scene, make_scene

    if count < 1:
        exit_usage(errors, "--synthetic must be 1 or more")
    if first_seed < 0:
        exit_usage(errors, "--seed must be 0 or more")
    if occluders < 0:
        exit_usage(errors, "--occluders must be 0 or more")
    if width < MIN_SIDE or height < MIN_SIDE:
        exit_usage(errors, f"--width and --height must be {MIN_SIDE} or more")
    if families is not None and (width < FAMILY_MIN_SIZE[0] or height < FAMILY_MIN_SIZE[1]):
        exit_usage(
            errors, "--family needs --width {} and --height {} or more".format(*FAMILY_MIN_SIZE)
        )
    load_kernels(errors)  # ms per scene is the detection alone
    try:
        low, high = synthetic_eval.parse_cable_counts(cables)
    except ValueError as exc:
        exit_usage(errors, str(exc))
    _make_out_dir(errors, out_dir)

    if families is None:

        def legacy(seed: int):
            n_cables = synthetic_eval.cables_for_seed(seed, low, high)
            return make_scene(width, height, n_cables, seed=seed, occluders=occluders)

        sources = [("", legacy)]
    else:
        sources = [
            (name, lambda seed, name=name: make_family_scene(name, seed, width, height))
            for name in families
        ]
    seeds = range(first_seed, first_seed + count)
    columns = synthetic_eval.CSV_COLUMNS
    if families is not None:
        columns = ("family", *columns)
    results = []
    failed = 0
    with (
        _csv_writer(errors, csv_file, columns) as writer,
        _progress(errors, count * len(sources), "evaluating") as advance,
    ):
        for name, make in sources:
            scores = []
            for seed in seeds:
                what = f"{name} seed {seed}" if name else f"seed {seed}"
                try:
                    scene = make(seed)
                    score, result = synthetic_eval.evaluate_scene(
                        scene, seed, params, mask_from_labels=mask_from_labels
                    )
                    if out_dir is not None:
                        _write_scene_outputs(out_dir, name, seed, scene, result)
                except Exception as exc:  # one line per failed scene; the run goes on
                    print_error(errors, _failure(f"scene {what}", exc))
                    failed += 1
                else:
                    scores.append(score)
                    if writer is not None:
                        row = synthetic_eval.csv_row(score)
                        writer({"family": name, **row} if families is not None else row)
                advance(what)
            results.append((name, scores))

    setup = {
        "scenes": count,
        "first_seed": first_seed,
        "width": width,
        "height": height,
        "mask_from_labels": mask_from_labels,
        "params": _params_json(params),
    }
    if families is None:
        setup["cables"] = f"{low}-{high}" if low != high else str(low)
        setup["occluders"] = occluders
    else:
        setup["families"] = families
    if len(results) == 1:
        name, scores = results[0]
        if scores:
            if name:
                setup["family"] = name
            summary = synthetic_eval.summarise_scenes(scores)
            lowest = _lowest_frames(scores, worst)
            if json_output:
                _print_json(_synthetic_json(setup, summary, lowest, failed))
            else:
                _print_synthetic_table(setup, summary, lowest)
    elif any(scores for _, scores in results):
        summaries = [
            (name, synthetic_eval.summarise_scenes(scores), _lowest_frames(scores, worst))
            for name, scores in results
            if scores
        ]
        every = [score for _, scores in results for score in scores]
        total = synthetic_eval.summarise_scenes(every)
        if json_output:
            _print_json(_families_json(setup, summaries, total, failed))
        else:
            _print_families_table(setup, summaries, total)
    raise typer.Exit(EXIT_FAILED if failed else 0)


def _lowest_frames(scores, worst: int):
    lowest = sorted(scores, key=lambda s: (s.frame.correct, min(s.frame.coverage, default=1)))
    return [s for s in lowest if not s.frame.correct][:worst]


def _write_scene_outputs(out_dir: Path, family: str, seed: int, scene, result) -> None:
    from service.imageio import write_png
    from service.perception import render_labels

    stem = out_dir / (f"{family}_{seed}" if family else f"scene_{seed}")
    write_png(stem.with_name(f"{stem.name}.png"), scene.image)
    predicted = render_labels(result.detection, result.mask, scene.image)
    _write_outputs(stem, scene.image, result, predicted)


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
        "mean_foreground_dice": _finite(summary.mean_foreground_dice),
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

    out = _stdout_console()
    if "family" in setup:
        drawn = f"of family {setup['family']}"
    else:
        drawn = f"{setup['cables']} cable(s), {setup['occluders']} occluder(s)"
    title = f"{setup['scenes']} synthetic scenes {setup['width']}x{setup['height']}, {drawn}, "
    title += _seeds_and_mode(setup)
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
        f"{summary.self_crossings.total} (self); mean instance DICE {summary.mean_dice:.3f}, "
        f"foreground DICE {summary.mean_foreground_dice:.3f}; "
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


def _seeds_and_mode(setup: dict[str, Any]) -> str:
    last_seed = setup["first_seed"] + setup["scenes"] - 1
    return (
        f"seeds {setup['first_seed']}-{last_seed}"
        + (", mask from labels" if setup["mask_from_labels"] else "")
        + (f", parameters {json.dumps(setup['params'])}" if setup["params"] else "")
    )


def _families_json(setup, summaries, total, failed: int) -> dict[str, Any]:
    return {
        "setup": setup,
        "families": [
            {"family": name, **_synthetic_json({}, summary, lowest, 0)}
            for name, summary, lowest in summaries
        ],
        "total": {
            key: value
            for key, value in _synthetic_json({}, total, [], 0).items()
            if key not in ("setup", "worst", "paper_accuracy", "failed", "incorrect_frames")
        },
        "failed": failed,
    }


def _percent(tally) -> str:
    if not tally.total:
        return "-"
    return f"{tally.accuracy:.1f} % ({tally.correct}/{tally.total})"


def _print_families_table(setup: dict[str, Any], summaries, total) -> None:
    """One row per family and a total: the paper's rows, crossing order, DICE."""
    out = _stdout_console()
    title = (
        f"{setup['scenes']} synthetic scenes per family, {setup['width']}x{setup['height']}, "
        + _seeds_and_mode(setup)
    )
    table = Table(title=title, title_justify="left")
    for column in (
        "family",
        "frames",
        "occlusions",
        "merges",
        "crossing order",
        "self (loops)",
        "DICE",
        "fg DICE",
        "ms",
    ):
        if column == "family":
            table.add_column(column, no_wrap=True)
        else:
            table.add_column(column, justify="right")
    for name, summary, _ in [*summaries, ("total", total, [])]:
        table.add_row(
            name,
            _percent(summary.frames),
            _percent(summary.occlusions),
            _percent(summary.merges),
            _percent(summary.crossings),
            _percent(summary.self_crossings),
            f"{summary.mean_dice:.3f}",
            f"{summary.mean_foreground_dice:.3f}",
            f"{summary.mean_ms:.0f}",
            end_section=name == summaries[-1][0],
        )
    out.print(table)
    listed = [
        f"{name}: " + ", ".join(f"seed {score.seed}" for score in lowest)
        for name, _, lowest in summaries
        if lowest
    ]
    if listed:
        out.print(f"worst incorrect frames: {'; '.join(listed)}", soft_wrap=True)


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


def _stdout_console() -> Console:
    """Rich console for the tables: the terminal's width, or 160 columns into a file or pipe
    (rich's 80 would wrap the wider tables)."""
    out = Console(highlight=False)
    return out if out.is_terminal else Console(highlight=False, width=PIPE_WIDTH)


def _finite(value: float, digits: int = 4) -> float | None:
    return None if math.isnan(value) else round(value, digits)


def _print_json(data: dict[str, Any]) -> None:
    typer.echo(json.dumps(data, indent=2))
