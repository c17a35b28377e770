"""``dlo serve``: run the detection service (HTTP with uvicorn, and zenoh) until Ctrl-C."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import typer
import uvicorn
from pydantic import ValidationError

from service.console import EXIT_USAGE, FIRST_RUN_NOTICE
from service.http import create_app
from service.http.server import uvicorn_options
from service.perception import kernels_cached
from service.perception.segmenter import SegmenterModelError
from service.runtime.settings import Settings


def serve(
    host: Annotated[
        str | None, typer.Option(help="Address to listen on (env DLO_HOST, default 127.0.0.1).")
    ] = None,
    port: Annotated[int | None, typer.Option(help="TCP port (env DLO_PORT, default 8000).")] = None,
    workers: Annotated[
        int | None,
        typer.Option(help="Detection threads (env DLO_WORKERS, default 2)."),
    ] = None,
    zenoh: Annotated[
        bool | None,
        typer.Option(
            "--zenoh/--no-zenoh",
            help="Also serve over zenoh: dlo/*/image -> dlo/*/chains, dlo/detect "
            "(env DLO_ZENOH, default on).",
        ),
    ] = None,
    zenoh_config: Annotated[
        Path | None,
        typer.Option(
            metavar="FILE",
            help="zenoh JSON5 configuration file (env DLO_ZENOH_CONFIG; default: a peer "
            "listening on tcp/127.0.0.1:7447 only, no scouting).",
        ),
    ] = None,
    zenoh_listen: Annotated[
        list[str] | None,
        typer.Option(
            metavar="ENDPOINT",
            help="zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7447 to be reachable from "
            "the network (repeatable; env DLO_ZENOH_LISTEN, comma separated; default: the "
            "configuration file's, else tcp/127.0.0.1:7447).",
        ),
    ] = None,
    image_keys: Annotated[
        list[str] | None,
        typer.Option(
            metavar="KEYEXPR",
            help="The frames this replica takes, dlo/<camera or pattern>/image, e.g. "
            "dlo/line1-$*/image for a fixed group of cameras (repeatable; env "
            "DLO_ZENOH_IMAGE_KEYS, comma separated; default dlo/*/image). Replicas with the "
            "same keys share the cameras out among themselves.",
        ),
    ] = None,
    segmenter_model: Annotated[
        Path | None,
        typer.Option(
            metavar="FILE",
            help="ONNX segmenter for requests with segmentation=model "
            "(env DLO_SEGMENTER_MODEL; needs pip install 'dlo-service[onnx]').",
        ),
    ] = None,
    track: Annotated[
        bool,
        typer.Option(
            "--track",
            help="Also track every camera over zenoh: each frame's Tracks (one id per cable "
            "from frame to frame) on dlo/<camera>/tracks (env DLO_TRACK=*).",
        ),
    ] = False,
    track_camera: Annotated[
        list[str] | None,
        typer.Option(
            metavar="NAME",
            help="Track this camera (a name, or a key expression of names such as "
            "line1-$*); repeatable (env DLO_TRACK, comma separated).",
        ),
    ] = None,
) -> None:
    """Serve detection over HTTP (POST /v1/detect; OpenAPI docs at /docs).

    Other settings come from DLO_* variables (see the README): DLO_QUEUE_SIZE,
    DLO_MAX_MEGAPIXELS, DLO_MAX_BODY_MB, DLO_MAX_DETECT_SECONDS, DLO_ZENOH_MULTICAST,
    DLO_ZENOH_ASSIGNMENT, DLO_TRACK_MEMORY_S, DLO_API_TOKEN or DLO_API_TOKEN_FILE (a
    bearer token on /v1/*), DLO_PROTECT_METRICS, DLO_LOG_LEVEL.
    """
    options = {
        "host": host,
        "port": port,
        "workers": workers,
        "zenoh": zenoh,
        "zenoh_config": zenoh_config,
        "zenoh_listen": zenoh_listen or None,
        "zenoh_image_keys": image_keys or None,
        "segmenter_model": segmenter_model,
        "track": ["*"] if track else (track_camera or None),
    }
    try:
        settings = Settings(**{name: value for name, value in options.items() if value is not None})
    except ValidationError as exc:
        for detail in exc.errors(include_url=False):
            where = "/".join(str(part) for part in detail["loc"])
            message = str(detail["msg"]).removeprefix("Value error, ")
            typer.echo(f"error: {where}: {message}" if where else f"error: {message}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(levelname)s:     %(name)s: %(message)s"
    )
    try:
        app = create_app(settings)
    except SegmenterModelError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    if not kernels_cached():  # the app's warm-up compiles them; /readyz waits for it
        typer.echo(f"{FIRST_RUN_NOTICE}; /readyz answers 503 until then", err=True)
    uvicorn.run(app, **uvicorn_options(settings.host, settings.port, settings.log_level))
