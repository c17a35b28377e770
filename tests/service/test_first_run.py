"""The first run on a machine: the front ends that detect say on stderr that the kernels
compile, and load them before the first detection, so that its ``timings_ms`` hold no
compiling or loading of machine code.

"Not cached" is made by pointing the stamp that ``kernels_cached`` reads at an empty
folder (the kernels then load from numba's cache, quickly); the slow test compiles for real
into a numba cache of its own.
"""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from rich.console import Console
from typer.testing import CliRunner

import service.cli.serve
import service.console
from schemas import Detection
from service.cli import app
from service.console import FIRST_RUN_NOTICE, load_kernels
from service.perception import _kernel_cache, kernels_cached, warm_up

DLO = [sys.executable, "-c", "from service.cli import main; main()"]


def run_dlo(*args: str | Path):
    return CliRunner().invoke(app, [str(arg) for arg in args], prog_name="dlo")


@pytest.fixture
def image(tmp_path: Path) -> Path:
    picture = np.full((120, 160, 3), 25, np.uint8)
    cv2.line(picture, (10, 20), (150, 100), (220, 220, 220), 7)
    path = tmp_path / "cable.png"
    cv2.imwrite(str(path), picture)
    return path


@pytest.fixture
def first_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """This machine looks as if the kernels were never compiled: no stamp yet."""
    stamp = tmp_path / "stamp" / "kernels"
    monkeypatch.setattr(
        _kernel_cache,
        "stamp_path",
        lambda group="detection": stamp if group == "detection" else stamp.with_name(group),
    )
    assert not kernels_cached()
    return stamp


def test_detect_says_so_and_loads_the_kernels_first(first_run: Path, image: Path, tmp_path):
    result = run_dlo("detect", image, "--out-dir", tmp_path / "out")
    assert result.exit_code == 0, result.stderr
    assert result.stderr.splitlines()[0] == FIRST_RUN_NOTICE
    assert result.stderr.count(FIRST_RUN_NOTICE) == 1
    assert kernels_cached()  # the warm-up ran and wrote the stamp

    again = run_dlo("detect", image, "--out-dir", tmp_path / "out")
    assert again.exit_code == 0 and FIRST_RUN_NOTICE not in again.stderr


def test_usage_errors_come_before_any_warm_up(first_run: Path, image: Path) -> None:
    result = run_dlo("detect", image, "--outputs", "json")  # --outputs needs --out-dir
    assert result.exit_code == 2
    assert FIRST_RUN_NOTICE not in result.stderr and not kernels_cached()


def test_demo_and_eval_say_so(first_run: Path, tmp_path: Path) -> None:
    demo = run_dlo("demo", "--out-dir", tmp_path / "demo")
    assert demo.exit_code == 0, demo.stderr
    assert FIRST_RUN_NOTICE in demo.stderr
    first_run.unlink()
    evaluated = run_dlo("eval", "--synthetic", "1", "--width", "160", "--height", "120")
    assert evaluated.exit_code in (0, 1), evaluated.stderr
    assert FIRST_RUN_NOTICE in evaluated.stderr


@pytest.mark.parametrize("built", [True, False])
def test_a_first_run_on_numba_then_compiles_the_kernels_ahead_of_time(
    first_run: Path, monkeypatch: pytest.MonkeyPatch, built: bool
) -> None:
    """Without DLO_KERNELS=jit (which the tests set), the first run builds the module
    in a child process (here a stand-in for it), saying so; a failed build is a warning."""
    children = []

    def child(command, **_):
        children.append(command)
        return subprocess.CompletedProcess(command, 0 if built else 1, "", "no gcc\n")

    monkeypatch.setattr(subprocess, "run", child)
    monkeypatch.delenv("DLO_KERNELS")
    console = Console(file=io.StringIO(), width=300)
    load_kernels(console)
    lines = console.file.getvalue().splitlines()
    assert lines[:2] == [FIRST_RUN_NOTICE, service.console.AOT_BUILD_NOTICE]
    assert children == [[sys.executable, "-m", "service.build_kernels", "--quiet"]]
    assert lines[2:] == ([] if built else ["warning: kernels not compiled ahead of time: no gcc"])

    children.clear()
    load_kernels(Console(file=io.StringIO()))  # not a first run: nothing to build
    monkeypatch.setenv("DLO_KERNELS", "jit")
    first_run.unlink()
    load_kernels(Console(file=io.StringIO()))  # a first run, but the JIT is asked for
    assert children == []


OTHER_WARM_UPS: list[str] = []


def warm_up_other_kernels() -> None:
    """The warm-up of a set of kernels that only some front ends load (a tracker's, say)."""
    OTHER_WARM_UPS.append("ran")
    _kernel_cache.write_stamp(str(tmp_numba_cache()), group="other")


def tmp_numba_cache() -> str:
    stamp = json.loads(_kernel_cache.stamp_path().read_text())
    return stamp["numba_cache"]


def test_a_front_end_loads_only_its_kernel_sets_and_says_so_for_a_missing_one(
    first_run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(service.console.KERNEL_SETS, "other", f"{__name__}:warm_up_other_kernels")
    OTHER_WARM_UPS.clear()
    console = Console(file=io.StringIO())
    load_kernels(console)  # the detector's, as a first run: notice, and its stamp
    assert console.file.getvalue().splitlines() == [FIRST_RUN_NOTICE]
    assert kernels_cached() and not kernels_cached("other") and OTHER_WARM_UPS == []

    console = Console(file=io.StringIO())
    load_kernels(console)  # nothing to compile for a one-image dlo detect now
    assert console.file.getvalue() == ""

    console = Console(file=io.StringIO())
    load_kernels(console, ("detection", "other"))  # a front end that needs both
    assert console.file.getvalue().splitlines() == [FIRST_RUN_NOTICE]
    assert OTHER_WARM_UPS == ["ran"] and kernels_cached("other")
    console = Console(file=io.StringIO())
    load_kernels(console, ("detection", "other"))
    assert console.file.getvalue() == ""


def test_serve_says_so_before_starting(first_run: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    started = []
    monkeypatch.setattr(service.cli.serve.uvicorn, "run", lambda app, **_: started.append(app))
    result = run_dlo("serve", "--port", "0", "--no-zenoh")
    assert result.exit_code == 0, result.stderr
    assert FIRST_RUN_NOTICE in result.stderr and "/readyz" in result.stderr
    assert len(started) == 1  # the app's own warm-up compiles them, before it is ready


@pytest.mark.slow
def test_a_real_first_run_compiles_says_so_and_times_only_the_detection(
    image: Path, tmp_path: Path
) -> None:
    """numba's cache in an empty folder: this process compiles every kernel (tens of s)."""
    environment = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    started = time.perf_counter()
    try:
        finished = subprocess.run(
            [*DLO, "detect", str(image)],
            capture_output=True,
            text=True,
            env=environment,
            timeout=600,
        )
        run_ms = (time.perf_counter() - started) * 1000.0
    finally:
        # The stamp now names that cache: put back this environment's (loads, no compile).
        if not kernels_cached():
            warm_up()
    assert finished.returncode == 0, finished.stderr
    assert re.match(re.escape(FIRST_RUN_NOTICE), finished.stderr)
    detection = Detection.model_validate(json.loads(finished.stdout))
    # Compiling takes tens of seconds, a 160x120 detection milliseconds: had the compile
    # been timed as detection, it would be most of the run, not a sliver of it.
    assert detection.timings_ms.total < run_ms / 10, (detection.timings_ms, run_ms)
