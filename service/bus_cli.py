"""``dlo router``: run a zenoh router that cameras, services and clients connect to."""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path
from typing import Annotated

import typer

EXIT_USAGE = 2


def router_command(
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
    import zenoh  # here, so that the other commands do not load zenoh

    from service.bus import make_config

    logging.basicConfig(level="INFO", format="%(levelname)s:     %(name)s: %(message)s")
    try:
        zenoh_config = make_config(config, mode="router", multicast=multicast, listen=listen)
        session = zenoh.open(zenoh_config)
    except Exception as exc:  # zenoh reports bad endpoints and files as ZError
        typer.echo(f"error: cannot start the zenoh router: {exc}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    typer.echo(
        f"zenoh router {session.zid()} listening on {', '.join(listen or ['the default'])}; "
        "Ctrl-C to stop",
        err=True,
    )
    try:
        while not stop.wait(0.5):
            pass
    finally:
        session.close()
    typer.echo("zenoh router stopped", err=True)
