"""Subcommands registered by import path and imported only when they run.

``dlo --help`` lists every subcommand from its one-line help alone; ``dlo detect ...``
imports the detector, ``dlo serve`` the web stack, ``dlo ur3`` the robot adapter, and
none of them imports the others. A subcommand is loaded when the command line names it
(to run it or to show its own ``--help``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from importlib import import_module
from typing import Any

import typer
from typer.core import TyperCommand

from service.console import DloGroup, typer_app


@dataclass(frozen=True)
class Subcommand:
    """A subcommand of a :class:`LazyGroup`.

    ``target`` is ``"package.module:attribute"``: a Typer command function or a
    :class:`typer.Typer` group. ``summary`` is the line ``dlo --help`` shows for it,
    the first line of the target's own help.
    """

    name: str
    target: str
    summary: str

    def load(self) -> Any:
        """The function or :class:`typer.Typer` that ``target`` names (imported now)."""
        module, _, attribute = self.target.partition(":")
        return getattr(import_module(module), attribute)


class _NotLoaded(TyperCommand):
    """Stands for a subcommand in listings until the command line names it."""


class LazyGroup(DloGroup):
    """A Typer group whose :attr:`subcommands` are imported when first resolved."""

    subcommands: Sequence[Subcommand] = ()

    def __init__(self, **settings: Any) -> None:
        super().__init__(**settings)
        for entry in self.subcommands:
            self.commands[entry.name] = _NotLoaded(entry.name, help=entry.summary)

    def resolve_command(
        self, ctx: typer.Context, args: list[str]
    ) -> tuple[str | None, Any, list[str]]:
        name, command, rest = super().resolve_command(ctx, args)
        if isinstance(command, _NotLoaded) and name is not None:
            command = self.commands[name] = self.load(name)
        return name, command, rest

    def load(self, name: str) -> Any:
        """The click command of subcommand ``name``, its module imported now."""
        entry = next(entry for entry in self.subcommands if entry.name == name)
        target = entry.load()
        if isinstance(target, typer.Typer):
            command = typer.main.get_group(target)
        else:
            single = typer_app(no_args_is_help=False)
            single.command(name=name)(target)
            command = typer.main.get_command(single)
        command.name = name
        return command


def lazy_group(subcommands: Sequence[Subcommand]) -> type[LazyGroup]:
    """A :class:`LazyGroup` class holding ``subcommands``, for ``typer.Typer(cls=...)``."""
    return type("DloGroup", (LazyGroup,), {"subcommands": tuple(subcommands)})
