"""``dlo serve``: run the HTTP service with uvicorn."""

from __future__ import annotations

import logging
from typing import Annotated

import typer
from pydantic import ValidationError

EXIT_USAGE = 2


def serve_command(
    host: Annotated[
        str | None, typer.Option(help="Address to listen on (env DLO_HOST, default 127.0.0.1).")
    ] = None,
    port: Annotated[int | None, typer.Option(help="TCP port (env DLO_PORT, default 8000).")] = None,
    workers: Annotated[
        int | None,
        typer.Option(help="Detection threads (env DLO_WORKERS, default 2)."),
    ] = None,
) -> None:
    """Serve detection over HTTP (POST /v1/detect; OpenAPI docs at /docs).

    Other settings come from DLO_* environment variables: DLO_QUEUE_SIZE,
    DLO_MAX_MEGAPIXELS, DLO_MAX_BODY_MB, DLO_LOG_LEVEL (see the README).
    """
    # Imported here so that the other commands do not load the web stack.
    import uvicorn

    from service.http import Settings, create_app

    options = {"host": host, "port": port, "workers": workers}
    try:
        settings = Settings(**{name: value for name, value in options.items() if value is not None})
    except ValidationError as exc:
        for detail in exc.errors(include_url=False):
            where = "/".join(str(part) for part in detail["loc"])
            typer.echo(f"error: {where}: {detail['msg']}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(levelname)s:     %(name)s: %(message)s"
    )
    uvicorn.run(
        create_app(settings),
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
    )
