"""``dlo bench``: how fast the detector runs, per stage, on one CPU thread.

What is timed: :func:`service.perception.detect` on an image already in memory (no
file I/O), after a warm-up, one call at a time. Per stage the times are the
``timings_ms`` the pipeline reports (segmentation, skeleton, contours, fitting,
pruning, merging, total); ``wall`` is the time around the whole ``detect()`` call.
Each is reported as p50, p90 and max over all frames, with frames per second from
the p50 wall time. The cases:

* the photographs of ``../shared/datasets/mbest`` when present (skipped with a note
  otherwise);
* generated 1280x720 scenes with 1, 2 and 3 cables, and 1920x1080 scenes;
* scaling: 3 cables at 640x360, 1280x720, 1920x1080 and 3840x2160, and 1 to 5 cables
  (with their crossings) at 1280x720;
* other backgrounds, where ``segmentation=auto`` takes cable contrast: the ``bright``
  and ``textured`` scene families, and the photographs of ``../shared/datasets/ariadne``
  (beside the mbest folder) when present;
* what a camera model adds: lifting the chains to 3-D, and the MJCF
  (:mod:`service.bench.lifting`);
* what a ROS 2 recording adds per frame (``--outputs mcap``, :mod:`service.bench.recording`).

One thread: the numeric libraries size their thread pools when they are first
imported, so ``dlo bench`` runs this in a process of its own (``python -m service.cli
bench``) with :data:`THREAD_VARIABLES` (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
``MKL_NUM_THREADS``, ``NUMBA_NUM_THREADS``) set to 1, and there also calls
``cv2.setNumThreads(1)`` and ``numba.set_num_threads(1)``.
The peak resident memory of that process (``ru_maxrss``) is reported too. Each scene
is generated just before it is timed and dropped after (photographs are read likewise),
so the process never holds more than one image of a case at a time.
"""

from __future__ import annotations

import itertools
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

STAGES = ("segmentation", "skeleton", "contours", "fitting", "pruning", "merging", "total")
# The stages whose code is compiled (service/perception/_*_kernels.py).
KERNEL_STAGES = ("skeleton", "contours", "fitting", "pruning")
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMBA_NUM_THREADS",
)
DEFAULT_DATASET = Path(__file__).resolve().parents[3] / "shared" / "datasets" / "mbest"
"""``../shared/datasets/mbest`` beside the checkout."""
OCCLUDERS = 1


# --------------------------------------------------------------------------- the run


def run_detector_bench(quick: bool, as_json: bool, dataset: Path, frames: int, repeats: int) -> int:
    """Time the cases, then print the tables (or JSON); the exit status of ``dlo bench``."""
    import resource

    import cv2
    import numba
    import numpy as np

    from service.console import load_kernels, stderr_console
    from service.perception import detect
    from service.synthetic import make_scene

    cv2.setNumThreads(1)
    numba.set_num_threads(1)
    load_kernels(stderr_console())

    if quick:
        frames, repeats = 1, 1
        base, big = (320, 180), (480, 270)
        areas = [(160, 90), (320, 180), (480, 270)]
        cable_counts = [1, 2, 3]
        photo_limit = 2
    else:
        base, big = (1280, 720), (1920, 1080)
        areas = [(640, 360), (1280, 720), (1920, 1080), (3840, 2160)]
        cable_counts = [1, 2, 3, 4, 5]
        photo_limit = None

    def scenes(width, height, n_cables, count):
        """Yield up to ``count`` generated images, each with its number of true crossings.

        Each scene is made only when the previous one is done with, and only its image is
        kept: a 3840x2160 scene with its ground truth takes about 50 MB, so holding a
        case's scenes at once would set the process's peak memory, not the detector.
        """
        made = 0
        for seed in range(10 * count + 20):
            if made == count:
                return
            try:
                scene = make_scene(width, height, n_cables, seed=seed, occluders=OCCLUDERS)
            except RuntimeError:
                continue  # the layout rules cannot be met with this seed; try the next
            made += 1
            image, true_crossings = scene.image, len(scene.crossings)
            del scene
            yield image, true_crossings
            del image  # before the next scene is made

    def time_frames(images, times_each):
        """Time ``detect`` on ``(image, true crossings)`` pairs; also count crossings found."""
        samples = {stage: [] for stage in (*STAGES, "wall")}
        found, truth = [], []
        for image, true_crossings in images:
            for _ in range(times_each):
                started = time.perf_counter()
                detection = detect(image)
                wall = (time.perf_counter() - started) * 1000.0
                for stage, value in detection.timings_ms.model_dump().items():
                    samples[stage].append(value)
                samples["wall"].append(wall)
            found.append(len(detection.crossings))
            truth.append(true_crossings)
            # Let go of this frame before the generator makes the next one.
            del image, detection
        return samples, found, truth

    def summary(name, width, height, samples, extra=None):
        stats = {
            stage: {
                "p50": float(np.percentile(values, 50)),
                "p90": float(np.percentile(values, 90)),
                "max": float(np.max(values)),
            }
            for stage, values in samples.items()
        }
        kernels = np.sum([samples[stage] for stage in KERNEL_STAGES], axis=0)
        return {
            "case": name,
            "width": width,
            "height": height,
            "frames": len(samples["wall"]),
            "stages_ms": stats,
            "kernel_stages_p50_ms": float(np.percentile(kernels, 50)),
            "fps": 1000.0 / stats["wall"]["p50"],
            **(extra or {}),
        }

    # Warm-up: a few detections so that caches, allocators and branch predictors settle.
    for image, _ in scenes(*base, 2, 2):
        for _ in range(2):
            detect(image)

    results: dict[str, Any] = {
        "settings": {
            "threads": 1,
            "environment": {name: os.environ.get(name) for name in THREAD_VARIABLES},
            "cv2_threads": cv2.getNumThreads(),
            "numba_threads": numba.get_num_threads(),
            "warm_up": "kernels loaded (perception.warm_up) and 4 detections before timing",
            "quick": quick,
            "frames_per_case": frames,
            "repeats_per_frame": repeats,
            "cpu": cpu_name(),
            "versions": {
                "python": sys.version.split()[0],
                "numpy": np.__version__,
                "opencv": cv2.__version__,
                "numba": numba.__version__,
            },
        },
        "cases": [],
        "notes": [],
    }

    photos = sorted(dataset.glob("*/images/*.jpg")) if dataset.is_dir() else []
    if photos:
        if photo_limit is not None:
            photos = photos[:photo_limit]
        # Read one at a time, like the generated scenes: all 150 at once would be 270 MB.
        read = (cv2.imread(str(path), cv2.IMREAD_COLOR) for path in photos)
        images = (image for image in read if image is not None)
        first = next(images, None)
        if first is None:
            results["notes"].append(f"no photographs timed: none readable in {dataset}")
        else:
            height, width = first.shape[:2]
            pairs = ((image, 0) for image in itertools.chain([first], images))
            del first
            samples, _, _ = time_frames(pairs, 1)
            name = f"photographs ({dataset.name})"
            results["cases"].append(summary(name, width, height, samples))
    else:
        results["notes"].append(f"no photographs timed: {dataset} not found")

    results["backgrounds"] = _background_cases(
        dataset.parent / "ariadne", base, frames, repeats, photo_limit, time_frames, summary
    )

    for n_cables in (1, 2, 3):
        samples, _, _ = time_frames(scenes(*base, n_cables, frames), repeats)
        name = f"generated {base[0]}x{base[1]}, {n_cables} cable(s)"
        results["cases"].append(summary(name, *base, samples))
    samples, _, _ = time_frames(scenes(*big, 3, frames), repeats)
    results["cases"].append(summary(f"generated {big[0]}x{big[1]}, 3 cables", *big, samples))

    results["scaling_area"] = []
    for width, height in areas:
        count = max(1, frames // 3) if width * height > 4_000_000 else frames
        samples, _, _ = time_frames(scenes(width, height, 3, count), repeats)
        row = summary(f"{width}x{height}", width, height, samples)
        row["megapixels"] = width * height / 1e6
        results["scaling_area"].append(row)

    results["scaling_cables"] = []
    for n_cables in cable_counts:
        samples, found, truth = time_frames(scenes(*base, n_cables, frames), repeats)
        row = summary(f"{n_cables} cable(s)", *base, samples)
        row.update(
            cables=n_cables,
            crossings_true=float(np.mean(truth)),
            crossings_found=float(np.mean(found)),
        )
        results["scaling_cables"].append(row)

    from service.bench.lifting import run_lifting_cases

    results["lifting"] = run_lifting_cases(quick, frames, repeats)

    from service.bench.recording import run_recording_cases

    results["recording"] = run_recording_cases(quick, frames, repeats)

    # ru_maxrss is in KiB on Linux (bytes on macOS).
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    results["peak_rss_mb"] = peak / (1024.0 * 1024.0 if sys.platform == "darwin" else 1024.0)

    if as_json:
        print(json.dumps(results, indent=2))
    else:
        _print_tables(results)
    return 0


def _background_cases(ariadne, base, frames, repeats, photo_limit, time_frames, summary):
    """The cases on bright and textured backgrounds (cable contrast), timed like the others."""
    import cv2

    from service.synthetic.families import make_family_scene

    def family_scenes(family):
        for seed in range(frames):
            image = make_family_scene(family, seed, *base).image
            yield image, 0
            del image

    # Families are drawn at 320x240 at least (--quick's images are smaller).
    base = (max(base[0], 320), max(base[1], 240))
    cases = []
    for family in ("bright", "textured"):
        samples, _, _ = time_frames(family_scenes(family), repeats)
        cases.append(summary(f"{family} family {base[0]}x{base[1]}", *base, samples))
    photos = sorted(ariadne.glob("*/images/*.jpg")) if ariadne.is_dir() else []
    if photo_limit is not None:
        photos = photos[:photo_limit]
    read = (cv2.imread(str(path), cv2.IMREAD_COLOR) for path in photos)
    images = [(image, 0) for image in read if image is not None]
    if images:
        height, width = images[0][0].shape[:2]
        samples, _, _ = time_frames(iter(images), 1)
        cases.append(summary(f"photographs ({ariadne.name})", width, height, samples))
    return cases


def cpu_name() -> str:
    """The CPU model, as /proc/cpuinfo (or the platform) names it."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or "unknown"


# --------------------------------------------------------------------------- output


def _print_tables(results: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console(width=160)
    settings = results["settings"]
    console.print(
        "dlo bench: one thread ("
        + ", ".join(f"{k}={v}" for k, v in settings["environment"].items())
        + f", cv2 threads {settings['cv2_threads']}, numba threads {settings['numba_threads']})"
        + f"; after warm-up ({settings['warm_up']})",
        highlight=False,
    )
    console.print(
        f"CPU {settings['cpu']}; "
        + ", ".join(f"{k} {v}" for k, v in settings["versions"].items())
        + f"; detect() on images in memory, {settings['repeats_per_frame']} timing(s) per "
        f"generated scene; times in ms",
        highlight=False,
    )
    for note in results["notes"]:
        console.print(f"note: {note}", highlight=False)

    columns = (*STAGES, "wall")
    table = Table(title="p50 per stage (ms)", title_justify="left")
    table.add_column("case")
    table.add_column("frames", justify="right")
    for stage in columns:
        table.add_column(stage, justify="right")
    table.add_column("steps 2-5", justify="right")
    table.add_column("fps", justify="right")
    # The other backgrounds (bright, textured) take cable contrast under auto.
    for case in results["cases"] + results.get("backgrounds", []):
        stats = case["stages_ms"]
        table.add_row(
            case["case"],
            str(case["frames"]),
            *(f"{stats[stage]['p50']:.2f}" for stage in columns),
            f"{case['kernel_stages_p50_ms']:.2f}",
            f"{case['fps']:.1f}",
        )
    console.print(table)

    table = Table(title="p90 / max per stage (ms)", title_justify="left")
    table.add_column("case")
    for stage in columns:
        table.add_column(stage, justify="right")
    for case in results["cases"] + results.get("backgrounds", []):
        stats = case["stages_ms"]
        table.add_row(
            case["case"],
            *(f"{stats[stage]['p90']:.1f} / {stats[stage]['max']:.1f}" for stage in columns),
        )
    console.print(table)

    table = Table(title="scaling with image area (3 cables)", title_justify="left")
    for column in ("size", "Mpx", "frames", "total p50", "steps 2-5 p50", "ms per Mpx", "fps"):
        table.add_column(column, justify="right")
    for row in results["scaling_area"]:
        total = row["stages_ms"]["total"]["p50"]
        table.add_row(
            row["case"],
            f"{row['megapixels']:.2f}",
            str(row["frames"]),
            f"{total:.2f}",
            f"{row['kernel_stages_p50_ms']:.2f}",
            f"{total / row['megapixels']:.1f}",
            f"{row['fps']:.1f}",
        )
    console.print(table)

    first = results["scaling_cables"][0]
    title = f"scaling with the number of cables ({first['width']}x{first['height']})"
    table = Table(title=title, title_justify="left")
    for column in (
        "cables",
        "crossings (true)",
        "crossings (found)",
        "total p50",
        "steps 2-5 p50",
        "merging p50",
        "fps",
    ):
        table.add_column(column, justify="right")
    for row in results["scaling_cables"]:
        stats = row["stages_ms"]
        table.add_row(
            str(row["cables"]),
            f"{row['crossings_true']:.1f}",
            f"{row['crossings_found']:.1f}",
            f"{stats['total']['p50']:.2f}",
            f"{row['kernel_stages_p50_ms']:.2f}",
            f"{stats['merging']['p50']:.2f}",
            f"{row['fps']:.1f}",
        )
    console.print(table)
    from service.bench.lifting import print_lifting_table

    print_lifting_table(console, results["lifting"])

    from service.bench.recording import print_recording_table

    print_recording_table(console, results["recording"])
    console.print(f"peak resident memory: {results['peak_rss_mb']:.0f} MB", highlight=False)
