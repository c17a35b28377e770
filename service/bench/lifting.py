"""``dlo bench``: what a camera model adds to a detection (``dlo detect --camera``).

On rendered 3-D scenes (:mod:`service.synthetic.scene3d`, 1280 x 960 px) each detection is made
once and then lifted to 3-D (:func:`service.geometry3d.lift`) ``repeats`` times: with the
table plane (a camera looking straight down, and a tilted one with lens distortion) and
with the depth image (a cable over a box). The MJCF (:func:`service.simulation.to_mjcf`),
an extra output, is timed apart. Same thread and warm-up as the detector cases.
"""

from __future__ import annotations

import time
from typing import Any

CASES = (
    ("plane, straight down", "down", "plane"),
    ("plane, tilted with distortion", "distorted", "plane"),
    ("depth image, cable over a box", "box", "depth"),
)


def run_lifting_cases(quick: bool, frames: int, repeats: int) -> list[dict[str, Any]]:
    """One row per case: joints, detection, lifting and MJCF times (p50, p90, max in ms)."""
    import numpy as np

    from service.geometry3d import lift
    from service.perception import detect
    from service.simulation import to_mjcf
    from service.synthetic.scene3d import make_scene_3d

    size = {"width": 640, "height": 480, "focal": 700.0} if quick else {}
    rows = []
    for name, kind, mode in CASES:
        detect_ms, lift_ms, model_ms, joints = [], [], [], []
        for seed in range(frames):
            scene = make_scene_3d(kind, seed=seed, **size)
            camera = scene.camera if mode == "plane" else scene.depth_camera
            depth = None if mode == "plane" else scene.depth_m
            started = time.perf_counter()
            detection = detect(scene.image)
            detect_ms.append((time.perf_counter() - started) * 1000.0)
            lifted = lift(detection, camera, depth)  # warm
            for _ in range(max(repeats, 5)):
                started = time.perf_counter()
                lifted = lift(detection, camera, depth)
                lift_ms.append((time.perf_counter() - started) * 1000.0)
            started = time.perf_counter()
            to_mjcf(lifted)
            model_ms.append((time.perf_counter() - started) * 1000.0)
            joints.append(sum(len(chain.points) for chain in detection.chains))
            del scene, detection, lifted

        def stats(values):
            return {
                "p50": float(np.percentile(values, 50)),
                "p90": float(np.percentile(values, 90)),
                "max": float(np.max(values)),
            }

        rows.append(
            {
                "case": name,
                "frames": frames,
                "joints": float(np.mean(joints)),
                "detect_ms": stats(detect_ms),
                "lift_ms": stats(lift_ms),
                "mjcf_ms": stats(model_ms),
            }
        )
    return rows


def print_lifting_table(console, rows: list[dict[str, Any]]) -> None:
    from rich.table import Table

    table = Table(
        title="a camera model: lifting to 3-D per image (dlo detect --camera), and the MJCF",
        title_justify="left",
    )
    for column in (
        "case",
        "frames",
        "joints",
        "detect p50",
        "lift p50",
        "lift p90",
        "lift max",
        "mjcf p50",
    ):
        table.add_column(column, justify="right")
    for row in rows:
        table.add_row(
            row["case"],
            str(row["frames"]),
            f"{row['joints']:.0f}",
            f"{row['detect_ms']['p50']:.1f}",
            f"{row['lift_ms']['p50']:.3f}",
            f"{row['lift_ms']['p90']:.3f}",
            f"{row['lift_ms']['max']:.3f}",
            f"{row['mjcf_ms']['p50']:.2f}",
        )
    console.print(table)
