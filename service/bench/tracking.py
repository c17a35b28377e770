"""``dlo bench --tracking``: what tracking adds to detection, per frame and as a process.

Per frame (in this one-thread process): generated 640 x 480 videos, one of each kind
(:data:`service.synthetic.VIDEO_KINDS`, seeds 0-5 and 12, so 1 to 3 cables), every frame
detected (:func:`service.perception.detect_full`) and then tracked
(:meth:`service.perception.Tracker.follow`), each timed, wall clock and this thread's CPU
time, in the same run: detection alone, detection + tracking, and tracking alone, p50 and
p90 over the frames (the first frame, which starts the tracks, left out).

As whole processes: one generated 640 x 480 video of three cables written to a temporary
folder, then ``dlo detect VIDEO --out-dir`` and ``dlo track VIDEO --out-dir`` run in
turn (``repeats`` times each) as a user would run them, the numeric libraries on one
thread; reported: the process's wall time from start to exit (start-up, reading and
decoding the video, detection, tracking, writing the JSON Lines) and frames per second
over it, the process's CPU time (user + system, from the kernel's accounting of the
child: what it costs on a busy machine, where the wall clock also counts waiting for a
core) and frames per second over that, and the frame rate the command itself reports
(from its first frame to its last).
"""

from __future__ import annotations

import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

FRAME_SEEDS = (0, 1, 2, 3, 4, 5, 12)
PROCESS_SEED = 12  # drift, three cables
SUMMARY_FPS = re.compile(r"([0-9.]+) fps overall")


def run_tracking_bench(
    quick: bool, as_json: bool, frames: int, repeats: int, cpu: str, dlo: list[str]
) -> int:
    """Time the cases, print the tables (or JSON); the exit status of ``dlo bench``."""
    import json

    import cv2
    import numba

    from service.console import load_kernels, stderr_console

    cv2.setNumThreads(1)
    numba.set_num_threads(1)
    load_kernels(stderr_console(), ("detection", "tracking"))
    n_frames = 10 if quick else frames
    seeds = FRAME_SEEDS[:2] if quick else FRAME_SEEDS
    rows = [_frame_case(seed, n_frames) for seed in seeds]
    rows.append(_all_frames(rows))
    processes = _process_cases(30 if quick else 300, 1 if quick else repeats, dlo)
    if as_json:
        print(
            json.dumps(
                {"cpu": cpu, "frames": [_public(row) for row in rows], "processes": processes},
                indent=2,
            )
        )
        return 0
    _print_tables(rows, processes, n_frames, cpu)
    return 0


def _frame_case(seed: int, n_frames: int) -> dict[str, Any]:
    from service.perception import Tracker, detect_full
    from service.synthetic import make_video

    video = make_video(seed, n_frames=n_frames)
    tracker = Tracker()
    times: dict[str, list[float]] = {
        name: [] for name in ("detect", "both", "track", "detect_cpu", "both_cpu", "track_cpu")
    }
    for frame in video.frames():
        wall0, cpu0 = time.perf_counter(), time.thread_time()
        detection = detect_full(frame.image).detection
        wall1, cpu1 = time.perf_counter(), time.thread_time()
        tracker.follow(detection, frame.image, frame.timestamp_s)
        wall2, cpu2 = time.perf_counter(), time.thread_time()
        if frame.index == 0:
            continue  # the first frame starts the tracks
        for name, value in (
            ("detect", wall1 - wall0),
            ("both", wall2 - wall0),
            ("track", wall2 - wall1),
            ("detect_cpu", cpu1 - cpu0),
            ("both_cpu", cpu2 - cpu0),
            ("track_cpu", cpu2 - cpu1),
        ):
            times[name].append(1000.0 * value)
    return {"case": f"{video.kind} (seed {seed}, {video.n_cables} cable(s))", "times": times}


def _all_frames(rows: list[dict[str, Any]]) -> dict[str, Any]:
    merged = {name: [v for row in rows for v in row["times"][name]] for name in rows[0]["times"]}
    return {"case": "all frames", "times": merged}


def _public(row: dict[str, Any]) -> dict[str, Any]:
    result: dict[str, Any] = {"case": row["case"], "frames": len(row["times"]["detect"])}
    for name, values in row["times"].items():
        result[f"{name}_p50_ms"] = round(statistics.median(values), 3)
        result[f"{name}_p90_ms"] = round(_p90(values), 3)
    return result


def _p90(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(0.9 * len(ordered)))]


def _process_cases(n_frames: int, repeats: int, dlo: list[str]) -> list[dict[str, Any]]:
    """Whole ``dlo detect`` and ``dlo track`` processes on one generated video, in turn."""
    from service.bench.detector import THREAD_VARIABLES
    from service.synthetic import make_video, write_video

    env = dict(os.environ, **dict.fromkeys(THREAD_VARIABLES, "1"))
    results: dict[str, dict[str, list[float]]] = {
        command: {"wall": [], "reported": [], "cpu": []} for command in ("detect", "track")
    }
    with tempfile.TemporaryDirectory(prefix="dlo-bench-") as folder:
        video = make_video(PROCESS_SEED, n_frames=n_frames)
        path = write_video(video, Path(folder) / "cables.mp4")
        for _ in range(repeats):
            for command in ("detect", "track"):
                out = Path(folder) / command
                started = time.perf_counter()
                children_before = resource.getrusage(resource.RUSAGE_CHILDREN)
                done = subprocess.run(
                    [*dlo, command, str(path), "--out-dir", str(out)],
                    env=env,
                    capture_output=True,
                    text=True,
                    check=False,
                )
                elapsed = time.perf_counter() - started
                children_after = resource.getrusage(resource.RUSAGE_CHILDREN)
                results[command]["cpu"].append(
                    children_after.ru_utime
                    - children_before.ru_utime
                    + children_after.ru_stime
                    - children_before.ru_stime
                )
                if done.returncode != 0:
                    raise RuntimeError(f"dlo {command} failed: {done.stderr.strip()[-300:]}")
                results[command]["wall"].append(elapsed)
                found = SUMMARY_FPS.search(done.stderr)
                if found:
                    results[command]["reported"].append(float(found.group(1)))
    return [
        {
            "command": f"dlo {command}",
            "video": f"640x480, {n_frames} frames, {video.n_cables} cables",
            "runs": repeats,
            "wall_s_median": round(statistics.median(values["wall"]), 3),
            "fps_whole_process": round(n_frames / statistics.median(values["wall"]), 1),
            "cpu_s_median": round(statistics.median(values["cpu"]), 3),
            "fps_whole_process_cpu": round(n_frames / statistics.median(values["cpu"]), 1),
            "fps_reported": (
                round(statistics.median(values["reported"]), 1) if values["reported"] else None
            ),
        }
        for command, values in results.items()
    ]


def _print_tables(rows, processes, n_frames: int, cpu: str) -> None:
    from rich.console import Console
    from rich.table import Table

    out = Console(highlight=False, width=160)
    table = Table(
        title=f"tracking per 640x480 frame, one thread ({n_frames} frames per video; {cpu})",
        title_justify="left",
    )
    for column in (
        "video",
        "detection p50",
        "detection + tracking p50",
        "tracking p50 (p90)",
        "tracking CPU p50",
    ):
        table.add_column(column, justify="right")
    for row in rows:
        times = row["times"]
        table.add_row(
            row["case"],
            f"{statistics.median(times['detect']):.2f} ms",
            f"{statistics.median(times['both']):.2f} ms",
            f"{statistics.median(times['track']):.2f} ms ({_p90(times['track']):.2f})",
            f"{statistics.median(times['track_cpu']):.2f} ms",
            end_section=row is rows[-2],
        )
    out.print(table)
    table = Table(title="whole processes on one video (one thread)", title_justify="left")
    for column in (
        "command",
        "video",
        "runs",
        "wall (median)",
        "fps, whole process",
        "CPU (median)",
        "fps on its CPU time",
        "fps reported",
    ):
        table.add_column(column, justify="right")
    for row in processes:
        table.add_row(
            row["command"],
            row["video"],
            str(row["runs"]),
            f"{row['wall_s_median']:.2f} s",
            f"{row['fps_whole_process']:.1f}",
            f"{row['cpu_s_median']:.2f} s",
            f"{row['fps_whole_process_cpu']:.1f}",
            "-" if row["fps_reported"] is None else f"{row['fps_reported']:.1f}",
        )
    out.print(table)


def dlo_command() -> list[str]:
    """The ``dlo`` beside this Python (as the start-up benchmark runs it)."""
    return [sys.executable, "-m", "service.cli"]
