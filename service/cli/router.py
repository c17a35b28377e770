"""``dlo router``: run a zenoh router that cameras, services and clients connect to."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import typer

from service.bus.router import RouterStartError, open_router, run_until_stopped
from service.console import EXIT_USAGE


def router(
    listen: Annotated[
        list[str] | None,
        typer.Option(
            help="Endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable; default: "
            "zenoh's, tcp/[::]:7447)."
        ),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(
            "--zenoh-config",
            exists=True,
            dir_okay=False,
            help="zenoh JSON5 configuration file; --listen and --multicast override it.",
        ),
    ] = None,
    multicast: Annotated[
        bool | None,
        typer.Option(
            "--multicast/--no-multicast", help="Multicast scouting (default: as configured)."
        ),
    ] = None,
) -> None:
    """Run a zenoh router until Ctrl-C; start services with connect/endpoints set to it."""
    logging.basicConfig(level="INFO", format="%(levelname)s:     %(name)s: %(message)s")
    try:
        session = open_router(config, listen=listen, multicast=multicast)
    except RouterStartError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    typer.echo(
        f"zenoh router {session.zid()} listening on {', '.join(listen or ['the default'])}; "
        "Ctrl-C to stop",
        err=True,
    )
    run_until_stopped(session)
    typer.echo("zenoh router stopped", err=True)
