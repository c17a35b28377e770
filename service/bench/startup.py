"""``dlo bench --startup``: how long whole ``dlo`` processes take, from start to exit.

Timed, each as a separate process, as a user runs them: ``dlo --help``, ``dlo version``
and a one-image ``dlo detect IMAGE --out-dir DIR`` (the first photograph of the data set
when present, else a generated 1280x720 scene with three cables), and under them the
floors (:data:`FLOORS`: Python, its native libraries, the kernels loaded). One untimed
``dlo detect`` of the image runs first, so the kernels are compiled (once per machine)
and the files are in the page cache: the figures are those of a warm kernel cache.
Then the commands run round after round, one of each per round, so that a busy spell of a
shared machine slows all of them alike; each is reported as min, median and max over its
runs, against the targets of issue 15. With ``PYTHONDONTWRITEBYTECODE`` set, Python compiles
every module of ``dlo`` from source in every process (about 0.15 s of a ``dlo detect``), so
the table says so: those are not the figures of an installed ``dlo``.
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from service.bench.detector import cpu_name

TARGETS_S = {"dlo --help": 0.3, "dlo detect IMAGE --out-dir DIR": 0.7}
"""Whole-process targets, in seconds (issue 15)."""
GENERATED_SIZE = (1280, 720)
_PYTHON = sys.executable
_WARM_UP = "import cv2\nfrom service.perception import warm_up\nwarm_up()"
FLOORS = {
    "floor: python -c pass": [_PYTHON, "-c", "pass"],
    "floor: import numpy, cv2": [_PYTHON, "-c", "import numpy, cv2"],
    "floor: import numpy, cv2, numba": [_PYTHON, "-c", "import numpy, cv2, numba"],
    "floor: + every kernel loaded (warm_up), numba's JIT": [
        _PYTHON,
        "-c",
        "import os\n"
        "os.environ['DLO_KERNELS'] = 'jit'\n"
        "from service.numba_start import load_cached_kernels_lightly, skip_numba_blas_probe\n"
        "skip_numba_blas_probe()\n"
        "load_cached_kernels_lightly()\n" + _WARM_UP,
    ],
    "floor: + every kernel loaded (warm_up), as dlo loads them": [_PYTHON, "-c", _WARM_UP],
}
"""What any ``dlo detect`` costs before its own work, timed as the commands are: Python
alone, the native libraries it needs (with and without numba), and those with every
detection kernel loaded: from numba's cache as ``dlo`` loads them without the
ahead-of-time build, and as this checkout loads them (compiled ahead of time when
``python -m service.build_kernels`` built them; see ``kernels`` in the results). This
Python and this checkout, whatever ``--dlo`` says."""
_KERNELS_STATUS = "from service.perception import _aot\nprint(_aot.status())"


@dataclass
class StartupRow:
    """The wall times of one command, in seconds, and the median CPU time its process
    used (user and system, all threads): on a busy machine the wall time carries the
    waiting for a core, the CPU time hardly."""

    command: str
    runs: int
    min_s: float
    median_s: float
    max_s: float
    target_s: float | None
    cpu_median_s: float


def dlo_command() -> list[str]:
    """How to start ``dlo``: the console script beside this Python, else the module."""
    script = Path(sys.executable).with_name("dlo")
    if script.is_file():
        return [str(script)]
    return [sys.executable, "-m", "service.cli"]


def run_startup_bench(dlo: list[str], dataset: Path, runs: int, as_json: bool) -> int:
    """Time the commands, started with ``dlo``, ``runs`` times each; print a table (or
    JSON); the exit status of ``dlo bench --startup``."""
    with tempfile.TemporaryDirectory(prefix="dlo-startup-") as folder:
        image, image_note = _image(dataset, Path(folder))
        out_dir = Path(folder) / "out"
        commands = {
            "dlo --help": [*dlo, "--help"],
            "dlo version": [*dlo, "version"],
            "dlo detect IMAGE --out-dir DIR": [
                *dlo,
                "detect",
                str(image),
                "--out-dir",
                str(out_dir),
            ],
            **FLOORS,
        }
        _run(commands["dlo detect IMAGE --out-dir DIR"])  # warm: kernels, page cache
        kernels = subprocess.run(
            [_PYTHON, "-c", _KERNELS_STATUS], capture_output=True, text=True, check=False
        ).stdout.strip()
        load_before = os.getloadavg()
        seconds: dict[str, list[float]] = {name: [] for name in commands}
        cpu: dict[str, list[float]] = {name: [] for name in commands}
        for _ in range(runs):
            for name, command in commands.items():
                wall, used = _run(command)
                seconds[name].append(wall)
                cpu[name].append(used)
    rows = [
        StartupRow(
            command=name,
            runs=len(times),
            min_s=min(times),
            median_s=statistics.median(times),
            max_s=max(times),
            target_s=TARGETS_S.get(name),
            cpu_median_s=statistics.median(cpu[name]),
        )
        for name, times in seconds.items()
    ]
    results = {
        "dlo": " ".join(dlo),
        "image": image_note,
        "rows": [asdict(row) for row in rows],
        "cpu": cpu_name(),
        "bytecode_cached": not os.environ.get("PYTHONDONTWRITEBYTECODE"),
        "kernels": kernels,
        "load_average": {"before": load_before, "after": os.getloadavg()},
    }
    if as_json:
        print(json.dumps(results, indent=2))
    else:
        _print_table(results, rows)
    return 0


def _run(command: list[str]) -> tuple[float, float]:
    """Run ``command`` to its end; its wall time and CPU time in seconds. Fails loudly if
    it fails."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    finished = subprocess.run(command, capture_output=True, check=False)
    elapsed = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    used = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if finished.returncode != 0:
        detail = finished.stderr.decode(errors="replace").strip().splitlines()[-1:]
        raise RuntimeError(f"{' '.join(command)} exited {finished.returncode}: {detail}")
    return elapsed, used


def _image(dataset: Path, folder: Path) -> tuple[Path, str]:
    """The image to detect and a note saying what it is."""
    photos = sorted(dataset.glob("*/images/*.jpg")) if dataset.is_dir() else []
    if photos:
        return photos[0], f"{photos[0]} (photograph)"
    from service.imageio import write_png
    from service.synthetic import make_scene

    width, height = GENERATED_SIZE
    scene = make_scene(width, height, 3, seed=0, occluders=1)
    path = folder / "scene.png"
    write_png(path, scene.image)
    return path, f"generated {width}x{height} scene, 3 cables ({dataset} not found)"


def _print_table(results: dict[str, Any], rows: list[StartupRow]) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console(width=160)
    console.print(
        f"dlo bench --startup: whole processes of {results['dlo']}, warm kernel cache; "
        f"image {results['image']}; CPU {results['cpu']}; kernels: {results['kernels']}; "
        "times in s",
        highlight=False,
    )
    table = Table(title="start-up", title_justify="left")
    for column in ("command", "runs", "min", "median", "max", "target", "CPU median"):
        table.add_column(column, justify="left" if column == "command" else "right")
    for row in rows:
        if row.target_s is None:
            target = ""
        else:
            verdict = "met" if row.median_s <= row.target_s else "NOT met"
            target = f"<= {row.target_s:g} ({verdict})"
        table.add_row(
            row.command,
            str(row.runs),
            f"{row.min_s:.3f}",
            f"{row.median_s:.3f}",
            f"{row.max_s:.3f}",
            target,
            f"{row.cpu_median_s:.3f}",
        )
    console.print(table)
    load = results["load_average"]
    console.print(
        "load average (1, 5, 15 min) before "
        + " / ".join(f"{value:.1f}" for value in load["before"])
        + ", after "
        + " / ".join(f"{value:.1f}" for value in load["after"]),
        highlight=False,
    )
    if not results["bytecode_cached"]:
        console.print(
            "PYTHONDONTWRITEBYTECODE is set: every run compiled dlo's modules from source "
            "(unset it for an installed dlo's figures)",
            highlight=False,
        )
