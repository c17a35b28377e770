"""``dlo eval --tracking N``: score the tracker on N generated videos (and the bare
detection beside it), one row per kind of video and a total (:mod:`.tracking_eval`)."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.table import Table

from service.console import EXIT_FAILED, exit_usage, load_kernels, print_error

CSV_COLUMNS = (
    "seed",
    "kind",
    "cables",
    "frames",
    "identity",
    "same_end",
    "switches",
    "cable_minutes",
    "joint_error",
    "joint_error_after_300",
    "detection_identity",
    "detection_switches",
    "tracking_ms_p50",
)


def parse_kinds(errors: Console, text: str | None) -> tuple[str, ...]:
    """``--kinds``: names of :data:`service.synthetic.VIDEO_KINDS`, or all of them."""
    from service.synthetic import VIDEO_KINDS

    if text is None or text.strip() == "all":
        return ()
    kinds = tuple(name.strip() for name in text.split(",") if name.strip())
    unknown = [name for name in kinds if name not in VIDEO_KINDS]
    if unknown or not kinds:
        exit_usage(
            errors,
            f"--kinds: unknown kind {', '.join(unknown) or text!r}; choose from "
            f"{', '.join(VIDEO_KINDS)} or all",
        )
    return kinds


def run_tracking(
    errors: Console,
    count: int,
    seed: int,
    kinds: tuple[str, ...],
    n_frames: int,
    mask_from_labels: bool,
    csv_file: Path | None,
    json_output: bool,
    params: Any,
    csv_writer,
    progress,
    print_json,
    stdout_console,
) -> None:
    """Track ``count`` videos from ``seed`` (kind by seed, or cycling through ``kinds``)
    and print the table; exits the command (0, or 1 when a video failed)."""
    from service.evaluation.tracking_eval import evaluate_video
    from service.synthetic import VIDEO_KINDS

    if count < 1:
        exit_usage(errors, "--tracking must be at least 1")
    if n_frames < 1:
        exit_usage(errors, "--frames must be at least 1")
    load_kernels(errors, ("detection", "tracking"))
    scores = []
    failed = 0
    with (
        csv_writer(errors, csv_file, CSV_COLUMNS) as write,
        progress(errors, count, "tracking") as advance,
    ):
        for number in range(count):
            video_seed = seed + number
            kind = kinds[number % len(kinds)] if kinds else None
            label = f"video {video_seed} ({kind or VIDEO_KINDS[video_seed % len(VIDEO_KINDS)]})"
            try:
                score = evaluate_video(
                    video_seed,
                    kind,
                    n_frames=n_frames,
                    params=params,
                    use_mask=mask_from_labels,
                )
            except Exception as exc:  # one line per failed video; the run goes on
                print_error(errors, f"{label}: {type(exc).__name__}: {exc}")
                failed += 1
            else:
                scores.append(score)
                if write is not None:
                    write(_csv_row(score))
            advance(label)
    rows = _rows(scores)
    if json_output:
        print_json(
            {
                "videos": len(scores),
                "frames": n_frames,
                "first_seed": seed,
                "mask_from_labels": mask_from_labels,
                "kinds": rows,
                "failed": failed,
            }
        )
    elif rows:
        _print_table(stdout_console(), rows, seed, n_frames, mask_from_labels)
    raise typer.Exit(EXIT_FAILED if failed else 0)


def _share(pair: tuple[int, int]) -> float:
    return pair[0] / pair[1] if pair[1] else float("nan")


def _csv_row(score) -> dict[str, str]:
    minutes = score.cable_frames / score.fps / 60.0
    return {
        "seed": str(score.seed),
        "kind": score.kind,
        "cables": str(score.cables),
        "frames": str(score.frames),
        "identity": f"{_share(score.identity):.4f}",
        "same_end": f"{_share(score.same_end):.4f}",
        "switches": str(score.switches),
        "cable_minutes": f"{minutes:.3f}",
        "joint_error": f"{score.error_sum / max(score.error_frames, 1):.4f}",
        "joint_error_after_300": (
            f"{score.late_error_sum / score.late_error_frames:.4f}"
            if score.late_error_frames
            else ""
        ),
        "detection_identity": f"{_share(score.detection_identity):.4f}",
        "detection_switches": str(score.detection_switches),
        "tracking_ms_p50": f"{statistics.median(score.tracking_ms[1:] or [0.0]):.2f}",
    }


def _rows(scores) -> list[dict[str, Any]]:
    """One summary per kind (in the kinds' order), then the total when there are several."""
    from service.synthetic import VIDEO_KINDS

    groups = [[s for s in scores if s.kind == kind] for kind in VIDEO_KINDS]
    rows = [_summary(kind, group) for kind, group in zip(VIDEO_KINDS, groups, strict=True) if group]
    if len(rows) > 1:
        rows.append(_summary("all", scores))
    return rows


def _summary(name: str, scores) -> dict[str, Any]:
    def total(field: str) -> tuple[int, int]:
        pairs = [getattr(s, field) for s in scores]
        return sum(p[0] for p in pairs), sum(p[1] for p in pairs)

    minutes = sum(s.cable_frames / s.fps / 60.0 for s in scores)
    switches = sum(s.switches for s in scores)
    detection_switches = sum(s.detection_switches for s in scores)
    error_frames = sum(s.error_frames for s in scores)
    late_frames = sum(s.late_error_frames for s in scores)
    tracking_ms = [ms for s in scores for ms in s.tracking_ms[1:]]
    return {
        "kind": name,
        "videos": len(scores),
        "cable_minutes": round(minutes, 3),
        "identity": round(_share(total("identity")), 4),
        "same_end": round(_share(total("same_end")), 4),
        "switches": switches,
        "switches_per_10_cable_minutes": round(10.0 * switches / minutes, 3) if minutes else None,
        "joint_error": (
            round(sum(s.error_sum for s in scores) / error_frames, 4) if error_frames else None
        ),
        "joint_error_after_300": (
            round(sum(s.late_error_sum for s in scores) / late_frames, 4) if late_frames else None
        ),
        "detection_identity": round(_share(total("detection_identity")), 4),
        "detection_switches_per_10_cable_minutes": (
            round(10.0 * detection_switches / minutes, 3) if minutes else None
        ),
        "tracking_ms_p50": round(statistics.median(tracking_ms), 3) if tracking_ms else None,
    }


def _print_table(out: Console, rows, seed: int, n_frames: int, mask_from_labels: bool) -> None:
    mode = "true mask" if mask_from_labels else "segmented from the image"
    table = Table(
        title=f"tracking: generated videos from seed {seed}, {n_frames} frames each ({mode})",
        title_justify="left",
    )
    columns = (
        "kind",
        "videos",
        "cable-min",
        "identity",
        "same end",
        "switches /10 cable-min",
        "joint error (l_s)",
        "after 300 (l_s)",
        "detection alone: identity",
        "switches /10 cable-min",
        "ms/frame p50",
    )
    for column in columns:
        table.add_column(column, justify="right")

    def number(value, pattern):
        return "-" if value is None else pattern.format(value)

    for row in rows:
        table.add_row(
            row["kind"],
            str(row["videos"]),
            f"{row['cable_minutes']:.1f}",
            f"{100 * row['identity']:.2f} %",
            f"{100 * row['same_end']:.2f} %",
            f"{row['switches']} ({number(row['switches_per_10_cable_minutes'], '{:.2f}')})",
            number(row["joint_error"], "{:.3f}"),
            number(row["joint_error_after_300"], "{:.3f}"),
            f"{100 * row['detection_identity']:.2f} %",
            number(row["detection_switches_per_10_cable_minutes"], "{:.2f}"),
            number(row["tracking_ms_p50"], "{:.2f}"),
            end_section=row is rows[-2] if len(rows) > 1 else False,
        )
    out.print(table)
    out.print(
        "identity: share of a cable's frames in view in which it carries its most common "
        "id; same end: share in which joint 0 is at the same end as most of the time; joint "
        "error: mean distance of a joint from its material point, in segment lengths (after "
        "300: frames 290-299); ms/frame: the tracking alone, beyond detection (wall clock). "
        "Rules: service/evaluation/tracking_eval.py.",
        soft_wrap=True,
    )
