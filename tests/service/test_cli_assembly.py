"""The ``dlo`` assembly point: every subcommand listed, each imported only when it runs.

What a command loads is read from ``python -X importtime`` of a whole ``dlo`` process, as
a user starts it; how long that takes is the start-up benchmark's business
(``dlo bench --startup``), not a test's.
"""

from __future__ import annotations

import inspect
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from service.cli import SUBCOMMANDS, app
from service.console import EXIT_USAGE

DLO = [sys.executable, "-X", "importtime", "-m", "service.cli"]
HEAVY = ("numpy", "cv2", "numba", "scipy", "fastapi", "uvicorn", "zenoh", "adapters")
"""What neither ``dlo --help`` nor ``dlo version`` needs."""
ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")


def imported_by(*args: str) -> tuple[set[str], subprocess.CompletedProcess[str]]:
    """The top-level packages a ``dlo`` process imported, and the finished process."""
    finished = subprocess.run([*DLO, *args], capture_output=True, text=True, timeout=120)
    modules = set()
    for line in finished.stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            modules.add(line.rsplit("|", 1)[1].strip().split(".")[0])
    return modules, finished


@pytest.mark.parametrize("args", [["--help"], ["version"], []], ids=["--help", "version", "none"])
def test_help_and_version_load_no_subcommand(args: list[str]) -> None:
    modules, finished = imported_by(*args)
    assert finished.returncode == (EXIT_USAGE if not args else 0), finished.stderr[-500:]
    assert "typer" in modules  # the measurement itself works
    assert not modules & set(HEAVY), sorted(modules & set(HEAVY))


def test_detect_loads_no_web_stack_zenoh_or_robot(tmp_path: Path) -> None:
    image = tmp_path / "blank.png"
    cv2.imwrite(str(image), np.zeros((40, 60, 3), np.uint8))
    modules, finished = imported_by("detect", str(image), "--out-dir", str(tmp_path / "out"))
    assert finished.returncode == 0, finished.stderr[-500:]
    assert {"numpy", "cv2", "numba"} <= modules
    assert not modules & {
        "fastapi",
        "uvicorn",
        "starlette",
        "zenoh",
        "adapters",
        "prometheus_client",
    }


def test_every_subcommand_is_listed_with_its_own_first_help_line() -> None:
    runner = CliRunner()
    listing = ANSI_ESCAPE.sub("", runner.invoke(app, ["--help"], prog_name="dlo").stdout)
    for entry in SUBCOMMANDS:
        assert re.search(rf"│ {entry.name} ", listing), entry.name
        target = entry.load()
        own_help = target.info.help if isinstance(target, typer.Typer) else inspect.getdoc(target)
        first_line = " ".join(own_help.split("\n\n")[0].split())
        assert entry.summary == first_line, entry.name


def test_a_subcommand_runs_and_shows_its_help_through_the_lazy_group() -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["router", "--help"], prog_name="dlo")
    assert result.exit_code == 0
    assert "--zenoh-config" in ANSI_ESCAPE.sub("", result.stdout)
    assert runner.invoke(app, ["version"], prog_name="dlo").stdout.startswith("dlo-service ")


def test_a_mistyped_subcommand_gets_a_suggestion() -> None:
    result = CliRunner().invoke(app, ["detec"], prog_name="dlo")
    assert result.exit_code == EXIT_USAGE
    assert "Did you mean 'detect'?" in ANSI_ESCAPE.sub("", result.output)
