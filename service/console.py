"""Terminal output shared by the ``dlo`` commands: one-line errors on stderr, exit codes."""

from __future__ import annotations

from typing import NoReturn

import typer
from rich.console import Console
from rich.text import Text

EXIT_FAILED = 1
"""At least one input could not be processed."""
EXIT_USAGE = 2
"""The command line itself is wrong (options, parameters)."""


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
