"""Terminal conventions shared by every ``dlo`` command, including the robot CLIs in
``adapters/``: the exit-code table, the Typer factory, one-line errors on stderr.

Exit statuses (the same for every command):

=====  ==========================================================================
0      everything worked
1      at least one input could not be processed (:data:`EXIT_FAILED`)
2      the command line itself is wrong, or a robot refused before moving (:data:`EXIT_USAGE`)
130    Ctrl-C stopped the run, whatever it had done so far (:data:`EXIT_INTERRUPTED`)
=====  ==========================================================================
"""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from importlib import import_module
from typing import Any, NoReturn

import click
import typer
from rich.console import Console
from rich.text import Text
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption

EXIT_OK = 0
"""Everything worked."""
EXIT_FAILED = 1
"""At least one input could not be processed."""
EXIT_USAGE = 2
"""The command line itself is wrong (options, parameters)."""
EXIT_INTERRUPTED = 130
"""Ctrl-C stopped the run (128 + SIGINT, as shells report it), even when some inputs were
done: a script running ``dlo ... && next-step`` must not go on with part of the outputs."""


class _Option(TyperOption):
    """An option in ``--help``: no value type for a flag, a default shown as written."""

    def display_type_rich(self, ctx: click.Context) -> str | None:
        if self.is_flag or self.count:  # "--help <bool>" would say it takes a value
            return None
        return super().display_type_rich(ctx)

    def _get_default_string(self, *, ctx: click.Context, show_default_is_str: bool, **kw: Any):
        if show_default_is_str:  # Typer would print "(10.0)"
            return str(self.show_default)
        return super()._get_default_string(ctx=ctx, show_default_is_str=False, **kw)


class _Argument(TyperArgument):
    """An argument in ``--help``: named by its metavar alone, required without braces."""

    def display_type_rich(self, ctx: click.Context) -> str | None:
        return None if self.metavar else super().display_type_rich(ctx)

    def _usage_display_name(self) -> str:
        name = self.display_name_raw if self.required else f"[{self.display_name_raw}]"
        return name + ("..." if self.nargs != 1 else "")


def _tidy_params(params: list[click.Parameter]) -> list[click.Parameter]:
    for param in params:
        if type(param) is TyperOption:
            param.__class__ = _Option
        elif type(param) is TyperArgument:
            param.__class__ = _Argument
    return params


def _rewrapped(text: str | None) -> str | None:
    """Help text with each paragraph on one line, for the terminal to wrap: a docstring's
    own line breaks would otherwise break lines mid-sentence. ``\b`` paragraphs are kept."""
    if not text:
        return text
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join(
        part if part.startswith("\b") else " ".join(part.split("\n")) for part in paragraphs
    )


class DloCommand(TyperCommand):
    """A ``dlo`` command: help paragraphs rewrapped, flags and arguments shown plainly."""

    def __init__(self, name: str | None, **settings: Any) -> None:
        settings["help"] = _rewrapped(settings.get("help"))
        super().__init__(name, **settings)

    def get_params(self, ctx: click.Context) -> list[click.Parameter]:
        return _tidy_params(super().get_params(ctx))


class DloGroup(TyperGroup):
    """A ``dlo`` command group, with the help of :class:`DloCommand`."""

    def __init__(self, **settings: Any) -> None:
        settings["help"] = _rewrapped(settings.get("help"))
        super().__init__(**settings)

    def get_params(self, ctx: click.Context) -> list[click.Parameter]:
        return _tidy_params(super().get_params(ctx))


class _DloTyper(typer.Typer):
    """A Typer whose commands are :class:`DloCommand` unless told otherwise."""

    def command(self, *args: Any, cls: type[TyperCommand] | None = None, **kwargs: Any) -> Any:
        return super().command(*args, cls=cls or DloCommand, **kwargs)


def typer_app(**settings: Any) -> typer.Typer:
    """A :class:`typer.Typer` set up as every ``dlo`` command (group) is.

    Help when called without arguments, no shell-completion options, and no rich
    tracebacks: ``dlo`` reports failures on one line (see :func:`print_error`). Help
    text is rewrapped by paragraph, flags show no value type, and required arguments
    appear plainly in usage lines (:class:`DloCommand`, :class:`DloGroup`).
    ``settings`` (``name``, ``help``, ``cls`` ...) are passed on to Typer.
    """
    defaults: dict[str, Any] = {
        "no_args_is_help": True,
        "add_completion": False,
        "pretty_exceptions_enable": False,
        "cls": DloGroup,
    }
    return _DloTyper(**{**defaults, **settings})


FIRST_RUN_NOTICE = "compiling the detection kernels, once per machine, about 20 s"
AOT_BUILD_NOTICE = (
    "compiling the kernels ahead of time, once per machine, about a minute"
    " (later runs start without numba)"
)


KERNEL_SETS = {
    "detection": "service.perception:warm_up",
    "tracking": "service.perception.tracking_warm_up:warm_up_tracking",
}
"""Each set of compiled kernels a front end may load, by name: its warm-up function
(``"module:function"``, imported only when the set is loaded). A warm-up loads (on a
machine's first run: compiles) its kernels and writes its group's stamp
(:func:`service.perception.kernels_cached` with the same name). A front end loads only the
sets it uses: a one-image ``dlo detect`` the detector's alone. ``python -m
service.build_kernels`` compiles every set ahead of time."""


def load_kernels(console: Console, kernel_sets: Sequence[str] = ("detection",)) -> None:
    """Load the compiled kernels of ``kernel_sets`` (:data:`KERNEL_SETS`) before the first
    detection is timed.

    When the kernels run compiled ahead of time (:mod:`service.build_kernels`) there is
    nothing to load from numba and numba is not imported. Otherwise, on a machine's first
    run numba compiles them (tens of seconds): say so on one line of ``console`` first,
    and afterwards compile them ahead of time for the next runs (saying so too; a failed
    build is a one-line warning, and numba's kernels stay in use). Either way the next
    detection's ``timings_ms`` are detection time alone, not compiling or loading machine
    code. Ctrl-C meanwhile exits with :data:`EXIT_INTERRUPTED` (nothing was processed yet).
    Kernels load without numba's registries and BLAS probe (:mod:`service.numba_start`),
    and the process keeps the memory a detection frees for the next one
    (:mod:`service.allocator`).
    """
    from service.allocator import keep_freed_memory
    from service.perception import compiled_ahead_of_time, kernels_cached

    keep_freed_memory()

    on_numba = not all(compiled_ahead_of_time(name) for name in kernel_sets)
    first_run = not all(kernels_cached(name) for name in kernel_sets)
    if on_numba:
        from service.numba_start import load_cached_kernels_lightly, skip_numba_blas_probe

        skip_numba_blas_probe()
        load_cached_kernels_lightly()
    if first_run:
        console.print(FIRST_RUN_NOTICE, markup=False, highlight=False, soft_wrap=True)
    try:
        for name in kernel_sets:
            module, _, function = KERNEL_SETS[name].partition(":")
            getattr(import_module(module), function)()
        if first_run and on_numba:
            build_ahead_of_time(console)
    except KeyboardInterrupt:
        raise typer.Exit(EXIT_INTERRUPTED) from None


def build_ahead_of_time(console: Console) -> bool:
    """Compile the kernels ahead of time in a child process (``python -m
    service.build_kernels``), unless ``DLO_KERNELS=jit``; returns whether it built."""
    import os
    import subprocess
    import sys

    if os.environ.get("DLO_KERNELS", "").strip().lower() == "jit":
        return False
    console.print(AOT_BUILD_NOTICE, markup=False, highlight=False, soft_wrap=True)
    result = subprocess.run(
        [sys.executable, "-m", "service.build_kernels", "--quiet"],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        check=False,
    )
    if result.returncode != 0:
        lines = result.stderr.strip().splitlines() or ["failed"]
        print_warning(console, f"kernels not compiled ahead of time: {lines[-1]}")
        return False
    return True


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
