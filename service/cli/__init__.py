"""The ``dlo`` command line: every subcommand, registered in one place.

Each subcommand is named here by import path with the line ``dlo --help`` shows for it, and
is imported only when the command line names it (:mod:`service.cli.lazy`): ``dlo --help``
and ``dlo version`` load no detector, ``dlo detect`` no web stack, ``dlo serve`` no robot
adapter. The commands of the service live beside this module (``detect.py``, ``serve.py``
...), ``dlo eval`` beside the evaluation, and the robot commands in their adapter packages.
Exit statuses and the Typer set-up are those of :mod:`service.console`.
"""

from __future__ import annotations

import sys

import typer

from service.cli.lazy import Subcommand, lazy_group
from service.console import EXIT_FAILED, typer_app

SUBCOMMANDS = (
    Subcommand(
        "detect",
        "service.cli.detect:detect",
        "Detect the cables in each image, or in every frame of a video or camera stream.",
    ),
    Subcommand(
        "track",
        "service.cli.track:track",
        "Follow the cables through videos or a camera stream: one id per cable.",
    ),
    Subcommand(
        "demo",
        "service.cli.demo:demo",
        "Generate the bundled synthetic example scene and detect the cables in it.",
    ),
    Subcommand("version", "service.cli:version", "Print the installed version of dlo-service."),
    Subcommand(
        "eval",
        "service.evaluation.cli:eval_command",
        "Score the detector on a labelled data set, or on synthetic scenes (--synthetic N).",
    ),
    Subcommand(
        "serve",
        "service.cli.serve:serve",
        "Serve detection over HTTP (POST /v1/detect; OpenAPI docs at /docs).",
    ),
    Subcommand(
        "router",
        "service.cli.router:router",
        "Run a zenoh router until Ctrl-C; start services with connect/endpoints set to it.",
    ),
    Subcommand(
        "bench",
        "service.cli.bench:bench",
        "Time the detector per stage on one thread: photographs, generated scenes, scaling.",
    ),
    Subcommand(
        "feasibility",
        "adapters.hexarotor.cli:feasibility",
        "Can a fully-actuated hexarotor pull this hard while hovering with zero net torque?",
    ),
    Subcommand(
        "ur3",
        "adapters.ur3.cli:ur3_app",
        "Plan a grasp on a detected cable and pick it with a UR3.",
    ),
    Subcommand(
        "hexa",
        "adapters.hexarotor.cli:hexa_app",
        "Fly grasp approaches with a hexarotor over MAVLink (against the built-in fake).",
    ),
)
"""Every ``dlo`` subcommand, in the order ``dlo --help`` lists them."""

app = typer_app(name="dlo", cls=lazy_group(SUBCOMMANDS))


@app.callback()
def dlo() -> None:
    """Detect cables (deformable linear objects) in images as chains of segments."""


def version() -> None:
    """Print the installed version of dlo-service."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed_version

    try:
        number = installed_version("dlo-service")
    except PackageNotFoundError:
        number = "unknown (not installed)"
    typer.echo(f"dlo-service {number}")


def main() -> None:
    """Entry point of the ``dlo`` console script; no traceback ever reaches the user."""
    try:
        app(prog_name="dlo")
    except Exception as exc:  # last line of defence: bugs in the shell itself
        print(f"error: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        sys.exit(EXIT_FAILED)
