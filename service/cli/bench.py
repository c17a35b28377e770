"""``dlo bench``: the detector per stage on one thread; with ``--service`` what HTTP and
zenoh add; with ``--startup`` how long whole ``dlo`` processes take; with ``--rings`` how
detection grows with the number of cables; with ``--viewer`` how the viewer's live mode
keeps up with a camera (:mod:`service.bench`).

The detector and service benchmarks run in a process of their own with the numeric
libraries set to one thread (they size their thread pools when first imported); the
start-up benchmark runs ``dlo`` processes as a user would, with the environment as given.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from service.bench.detector import DEFAULT_DATASET, THREAD_VARIABLES, cpu_name
from service.console import exit_usage, stderr_console


class Assignment(StrEnum):
    """How zenoh replicas share the cameras (the setting DLO_ZENOH_ASSIGNMENT)."""

    balanced = "balanced"
    rendezvous = "rendezvous"


CHILD_FLAG = "DLO_BENCH_CHILD"
"""Set in the one-thread process that ``dlo bench`` starts for the timing itself."""
STARTUP_RUNS, STARTUP_QUICK_RUNS = 10, 2


def bench(
    quick: Annotated[
        bool,
        typer.Option("--quick", help="Tiny images and one frame per case: a smoke test."),
    ] = False,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the results as JSON instead of tables.")
    ] = False,
    dataset: Annotated[
        Path,
        typer.Option(
            metavar="DIR",
            help="Photographs to time: every <subset>/images/*.jpg (skipped when absent); "
            "with --startup, the first one is the image detected.",
        ),
    ] = DEFAULT_DATASET,
    frames: Annotated[
        int,
        typer.Option(min=1, metavar="N", help="Generated scenes (seeds) per case."),
    ] = 10,
    repeats: Annotated[
        int | None,
        typer.Option(
            min=1,
            metavar="N",
            help="Detections timed per generated scene; with --startup, runs of each command.",
            show_default=f"3; {STARTUP_RUNS} with --startup",
        ),
    ] = None,
    service: Annotated[
        bool,
        typer.Option(
            "--service",
            help="Time the service instead: HTTP and zenoh latency against bare detection "
            "(service/bench/overhead.py).",
        ),
    ] = False,
    recording: Annotated[
        bool,
        typer.Option(
            "--recording",
            help="Time only what a ROS 2 recording (--outputs mcap) adds per frame "
            "(service/bench/recording.py); the full run includes it.",
        ),
    ] = False,
    startup: Annotated[
        bool,
        typer.Option(
            "--startup",
            help="Time whole dlo processes instead: dlo --help, dlo version and a one-image "
            "dlo detect, with a warm kernel cache, and the floors under them "
            "(service/bench/startup.py).",
        ),
    ] = False,
    bombs: Annotated[
        bool,
        typer.Option(
            "--bombs",
            help="Time how dlo serve refuses a 110 KB PNG claiming 30000x30000 px, as the "
            "image and as the mask, and its peak memory before and after "
            "(service/bench/bombs.py).",
        ),
    ] = False,
    rings: Annotated[
        str | None,
        typer.Option(
            metavar="N,N,...",
            help="Time scenes of N small rings instead (one chain each, 40x40 px per ring: "
            "10000 rings make 16 megapixels), e.g. --rings 1000,4000,10000 "
            "(service/bench/rings.py).",
            show_default=False,
        ),
    ] = None,
    replicas: Annotated[
        int | None,
        typer.Option(
            min=1,
            metavar="N",
            help="With --service: frames per second through 1, then N zenoh replicas behind "
            "a router instead (service/bench/replicas.py).",
            show_default=False,
        ),
    ] = None,
    cameras: Annotated[
        int, typer.Option(min=1, metavar="N", help="With --replicas: cameras sending frames.")
    ] = 3,
    detect_ms: Annotated[
        float,
        typer.Option(
            min=0,
            metavar="MS",
            help="With --replicas: each detection sleeps this long without CPU, so that the "
            "figure measures the distribution, not the cores; 0: the real detector.",
        ),
    ] = 50.0,
    assignment: Annotated[
        Assignment,
        typer.Option(
            help="With --replicas: how the replicas share the cameras (DLO_ZENOH_ASSIGNMENT).",
        ),
    ] = Assignment.balanced,
    viewer: Annotated[
        bool,
        typer.Option(
            "--viewer",
            help="Run the viewer's live mode in Debian's chromium on a 15 fps 640x480 camera "
            "instead: frame rate shown, dropped frames, the page's JS heap at start and end "
            "(service/bench/viewer.py; needs the dev extra's Playwright).",
        ),
    ] = False,
    seconds: Annotated[
        float,
        typer.Option(min=1, metavar="S", help="With --viewer: how long the live mode runs."),
    ] = 60.0,
    cpu_slowdown: Annotated[
        float,
        typer.Option(
            min=1,
            metavar="X",
            help="With --viewer: slow the page's CPU X times (Chrome's throttling), as a "
            "weak client's.",
        ),
    ] = 1.0,
    dlo: Annotated[
        str | None,
        typer.Option(
            metavar="COMMAND",
            help="With --startup: the command line that starts dlo, e.g. another "
            "checkout's (default: the dlo beside this Python).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Time the detector per stage on one thread: photographs, generated scenes, scaling."""
    if service + startup + bombs + (rings is not None) + recording > 1:
        exit_usage(
            stderr_console(),
            "--service, --startup, --bombs, --rings and --recording time different things: "
            "give one",
        )
    if bombs:
        from service.bench.bombs import run_bomb_bench

        raise typer.Exit(run_bomb_bench(5 if quick else repeats or 50, as_json))
    ring_counts = None if rings is None else _ring_counts(rings)
    if dlo is not None and not startup:
        exit_usage(stderr_console(), "--dlo applies only with --startup")
    if viewer:
        if service or startup:
            exit_usage(
                stderr_console(), "--viewer times the page alone: without --service/--startup"
            )
        from service.bench.viewer import run_viewer_bench

        raise typer.Exit(run_viewer_bench(10.0 if quick else seconds, as_json, cpu_slowdown))
    if replicas is not None:
        if not service:
            exit_usage(stderr_console(), "--replicas applies only with --service")
        from service.bench.replicas import run_replica_bench

        code = run_replica_bench(replicas, cameras, detect_ms, quick, as_json, assignment.value)
        raise typer.Exit(code)
    if startup:
        from service.bench.startup import dlo_command, run_startup_bench

        runs = repeats or (STARTUP_QUICK_RUNS if quick else STARTUP_RUNS)
        command = dlo_command() if dlo is None else shlex.split(dlo)
        raise typer.Exit(run_startup_bench(command, dataset, runs, as_json))
    repeats = repeats or 3
    if os.environ.get(CHILD_FLAG) == "1":
        if recording:
            from service.bench.recording import run_recording_bench

            raise typer.Exit(run_recording_bench(quick, as_json, frames, repeats, cpu_name()))
        if ring_counts is not None:
            from service.bench.rings import run_rings_bench

            raise typer.Exit(run_rings_bench(ring_counts, 1 if quick else repeats, as_json))
        if service:
            from service.bench.overhead import run_service_bench

            raise typer.Exit(run_service_bench(quick, as_json))
        from service.bench.detector import run_detector_bench

        raise typer.Exit(run_detector_bench(quick, as_json, dataset, frames, repeats))
    env = dict(os.environ, **dict.fromkeys(THREAD_VARIABLES, "1"), **{CHILD_FLAG: "1"})
    args = [sys.executable, "-m", "service.cli", "bench", "--dataset", str(dataset)]
    args += ["--frames", str(frames), "--repeats", str(repeats)]
    args += ["--quick"] * quick + ["--json"] * as_json + ["--service"] * service
    args += ["--recording"] * recording
    args += [] if rings is None else ["--rings", rings]
    raise typer.Exit(subprocess.call(args, env=env))


def _ring_counts(text: str) -> list[int]:
    """``"1000,4000"`` as ``[1000, 4000]``; a usage error unless each is 1 to 40,000."""
    try:
        counts = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        counts = []
    if not counts or not all(1 <= count <= 40_000 for count in counts):
        exit_usage(
            stderr_console(),
            f"--rings: give ring counts from 1 to 40000, e.g. 1000,4000 (got {text!r})",
        )
    return counts
