"""Terminal conventions shared by every ``dlo`` command, including the robot CLIs in
``adapters/``: the exit-code table, the Typer factory, one-line errors on stderr.

Exit statuses (the same for every command):

=====  ==========================================================================
0      everything worked
1      at least one input could not be processed (:data:`EXIT_FAILED`)
2      the command line itself is wrong, or a robot refused before moving (:data:`EXIT_USAGE`)
130    Ctrl-C stopped the run before anything was processed (:data:`EXIT_INTERRUPTED`)
=====  ==========================================================================
"""

from __future__ import annotations

from typing import Any, NoReturn

import typer
from rich.console import Console
from rich.text import Text

EXIT_OK = 0
"""Everything worked."""
EXIT_FAILED = 1
"""At least one input could not be processed."""
EXIT_USAGE = 2
"""The command line itself is wrong (options, parameters)."""
EXIT_INTERRUPTED = 130
"""Ctrl-C before anything was processed (128 + SIGINT, as shells report it)."""


def typer_app(**settings: Any) -> typer.Typer:
    """A :class:`typer.Typer` set up as every ``dlo`` command (group) is.

    Help when called without arguments, no shell-completion options, and no rich
    tracebacks: ``dlo`` reports failures on one line (see :func:`print_error`).
    ``settings`` (``name``, ``help``, ``cls`` ...) are passed on to Typer.
    """
    defaults: dict[str, Any] = {
        "no_args_is_help": True,
        "add_completion": False,
        "pretty_exceptions_enable": False,
    }
    return typer.Typer(**{**defaults, **settings})


FIRST_RUN_NOTICE = "compiling the detection kernels, once per machine, about 20 s"


def load_kernels(console: Console) -> None:
    """Load the detector's compiled kernels before the first detection is timed.

    On a machine's first run numba compiles them (tens of seconds): say so on one line of
    ``console`` first. Either way the next detection's ``timings_ms`` are detection time
    alone, not compiling or loading machine code. Ctrl-C meanwhile exits with
    :data:`EXIT_INTERRUPTED` (nothing was processed yet).
    """
    from service.perception import kernels_cached, warm_up

    skip_numba_blas_probe()
    if not kernels_cached():
        console.print(FIRST_RUN_NOTICE, markup=False, highlight=False, soft_wrap=True)
    try:
        warm_up()
    except KeyboardInterrupt:
        raise typer.Exit(EXIT_INTERRUPTED) from None


def skip_numba_blas_probe() -> None:
    """Tell numba, in this ``dlo`` process, not to look for a BLAS library.

    The first time numba compiles or loads a kernel it imports its array-maths support,
    which probes for BLAS by importing all of ``scipy.linalg``: about 0.2 s of a one-image
    ``dlo detect``. The detector's kernels use neither BLAS nor LAPACK (a test in
    tests/perception/test_warm_up.py reads their sources to keep it so), so the probe only
    costs time. Only the CLI does this, never the library: a program that imports
    ``service.perception`` may compile numba code of its own that needs BLAS. A numba
    whose internals differ keeps its probe.
    """
    import sys

    if "numba.np.arraymath" in sys.modules:  # too late: numba has probed already
        return
    try:
        from numba.np import linalg
    except ImportError:
        return

    def no_blas() -> None:
        raise ImportError("BLAS not probed: the dlo kernels need none")

    if hasattr(linalg, "ensure_blas"):
        linalg.ensure_blas = no_blas


def stderr_console() -> Console:
    """A rich console on stderr, so stdout carries only results."""
    return Console(stderr=True)


def print_error(console: Console, message: str) -> None:
    """Print ``error: <message>`` on one line."""
    line = Text("error: ", style="bold red")
    line.append(message)
    console.print(line, soft_wrap=True, highlight=False)


def print_warning(console: Console, message: str) -> None:
    """Print ``warning: <message>`` on one line."""
    line = Text("warning: ", style="bold yellow")
    line.append(message)
    console.print(line, soft_wrap=True, highlight=False)


def exit_usage(console: Console, message: str) -> NoReturn:
    """Report a usage error and exit with :data:`EXIT_USAGE`."""
    print_error(console, message)
    raise typer.Exit(EXIT_USAGE)
