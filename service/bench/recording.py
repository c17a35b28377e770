"""``dlo bench``: what a ROS 2 recording adds per frame (``--outputs mcap``).

Each generated 640 x 480 scene (and 1280 x 720 for scale) is detected once, then written
``repeats`` times into an MCAP file in a temporary folder through
:meth:`service.ros.recording.McapRecorder.write`, as a video frame is: the frame encoded as
JPEG, the ``CompressedImage`` and the ``MarkerArray`` serialized, both messages added to the
file (LZ4-compressed chunks; the chunks' compression and writes show in the mean). The
parts are timed apart too. Each time is taken twice: wall clock (``perf_counter``) and
this thread's CPU time (``thread_time``), which other processes on a shared machine
disturb less. Closing the file (last chunk, indexes, summary) is timed once per case and
spread over its frames. Same thread and warm-up rules as the detector cases.
"""

from __future__ import annotations

import os
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Any

CASES = ((640, 480, 1), (640, 480, 3), (1280, 720, 3))
PARTS = ("jpeg", "image_message", "markers", "write")


def run_recording_cases(quick: bool, frames: int, repeats: int) -> list[dict[str, Any]]:
    """One row per case: joints per frame and, per part, p50 / p90 / max in ms."""
    import numpy as np

    from service.perception import detect
    from service.ros.messages import compressed_image_cdr, markers_cdr
    from service.ros.recording import McapRecorder, encode_jpeg
    from service.synthetic import make_scene

    cases = CASES[:2] if quick else CASES
    rows = []
    with tempfile.TemporaryDirectory(prefix="dlo-bench-") as folder:
        for width, height, cables in cases:
            wall: dict[str, list[float]] = {part: [] for part in PARTS}
            cpu: dict[str, list[float]] = {part: [] for part in PARTS}
            joints, sizes = [], []
            path = Path(folder) / f"{width}x{height}-{cables}.mcap"
            recorder = McapRecorder(path)
            stamp = 0
            for seed in range(frames):
                image = make_scene(width, height, cables, seed=seed).image
                detection = detect(image)
                joints.append(sum(len(chain.points) for chain in detection.chains))
                recorder.write(stamp, detection, image=image)  # warm
                encoded = encode_jpeg(image)
                sizes.append(len(encoded))
                steps = {
                    "jpeg": partial(encode_jpeg, image),
                    "image_message": partial(compressed_image_cdr, encoded, "jpeg", stamp),
                    "markers": partial(markers_cdr, detection, stamp),
                }
                for _ in range(repeats):
                    for part, step in steps.items():
                        _time(step, wall[part], cpu[part])
                    stamp += 33_333_333
                    write = partial(recorder.write, stamp, detection, image=image)
                    _time(write, wall["write"], cpu["write"])
            written = recorder.frames
            close_wall, close_cpu = [], []
            _time(recorder.close, close_wall, close_cpu)

            def stats(values: list[float]) -> dict[str, float]:
                return {
                    "p50": float(np.percentile(values, 50)),
                    "p90": float(np.percentile(values, 90)),
                    "mean": float(np.mean(values)),
                    "max": float(np.max(values)),
                }

            rows.append(
                {
                    "case": f"{width}x{height}, {cables} cable(s)",
                    "width": width,
                    "height": height,
                    "frames": len(wall["write"]),
                    "joints": float(np.mean(joints)),
                    "jpeg_kb": float(np.mean(sizes)) / 1000.0,
                    "wall_ms": {part: stats(values) for part, values in wall.items()},
                    "cpu_ms": {part: stats(values) for part, values in cpu.items()},
                    "close_per_frame_ms": close_wall[0] / written,
                }
            )
    return rows


def run_recording_bench(quick: bool, as_json: bool, frames: int, repeats: int, cpu: str) -> int:
    """``dlo bench --recording``: the recording cases alone, as a table or JSON; ``cpu``
    names the processor in the report."""
    import json

    import cv2
    import numba
    from rich.console import Console

    from service.console import load_kernels, stderr_console

    cv2.setNumThreads(1)
    numba.set_num_threads(1)
    load_kernels(stderr_console())
    if quick:
        frames, repeats = 1, 1
    rows = run_recording_cases(quick, frames, repeats)
    load = os.getloadavg()
    if as_json:
        print(json.dumps({"cpu": cpu, "load_average": load, "recording": rows}, indent=2))
        return 0
    console = Console(width=160)
    console.print(
        f"dlo bench --recording: one thread, CPU {cpu}, load average "
        f"{load[0]:.1f} {load[1]:.1f} {load[2]:.1f} (1, 5, 15 min)",
        highlight=False,
    )
    print_recording_table(console, rows)
    return 0


def _time(step, wall: list[float], cpu: list[float]) -> None:
    started_wall, started_cpu = time.perf_counter(), time.thread_time()
    step()
    cpu.append((time.thread_time() - started_cpu) * 1000.0)
    wall.append((time.perf_counter() - started_wall) * 1000.0)


def print_recording_table(console, rows: list[dict[str, Any]]) -> None:
    from rich.table import Table

    table = Table(
        title="a ROS 2 recording per frame (--outputs mcap): ms wall / ms CPU of this thread, "
        "p50 (write: mean and p90 too)",
        title_justify="left",
    )
    for column in (
        "case",
        "frames",
        "joints",
        "JPEG kB",
        "jpeg",
        "image msg",
        "markers",
        "write (all)",
        "write mean",
        "write p90",
        "close/frame",
    ):
        table.add_column(column, justify="right")
    for row in rows:
        wall, cpu = row["wall_ms"], row["cpu_ms"]
        table.add_row(
            row["case"],
            str(row["frames"]),
            f"{row['joints']:.0f}",
            f"{row['jpeg_kb']:.0f}",
            *(f"{wall[part]['p50']:.2f} / {cpu[part]['p50']:.2f}" for part in PARTS),
            f"{wall['write']['mean']:.2f} / {cpu['write']['mean']:.2f}",
            f"{wall['write']['p90']:.2f} / {cpu['write']['p90']:.2f}",
            f"{row['close_per_frame_ms']:.3f}",
        )
    console.print(table)
