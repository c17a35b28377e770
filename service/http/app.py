"""The FastAPI application: :func:`create_app` wires settings, state, middleware and routes."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException

from service.http.live import live_api, live_socket
from service.http.middleware import RequestContextMiddleware, error_payload, request_id_of
from service.http.routes import api, router
from service.http.state import AppState
from service.http.viewer import viewer
from service.perception.segmenter import OnnxSegmenter
from service.runtime.errors import RequestError
from service.runtime.jobs import DetectFunction, default_detect, detect_with_segmenter, warm_up
from service.runtime.metrics import Metrics
from service.runtime.settings import Settings

logger = logging.getLogger(__name__)


def create_app(settings: Settings | None = None, detect: DetectFunction | None = None) -> FastAPI:
    """Build the dlo HTTP service.

    Parameters
    ----------
    settings : Settings, optional
        Limits and pool size; by default read from ``DLO_*`` environment variables.
    detect : callable, optional
        ``detect(image, params, mask, deadline) -> Detection`` run for each request; by
        default :func:`service.perception.detect`, with the ONNX segmenter of
        ``settings.segmenter_model`` for requests with ``segmentation=model``. Tests
        inject slow or failing ones.

    Returns
    -------
    FastAPI
        The app; its lifespan starts the worker pool and the warm-up detection, and
        stores the :class:`AppState` as ``app.state.dlo``.

    Raises
    ------
    SegmenterModelError
        ``settings.segmenter_model`` cannot be loaded (one-line message).
    """
    settings = Settings() if settings is None else settings
    segmenter = None
    if settings.segmenter_model is not None:
        segmenter = OnnxSegmenter(settings.segmenter_model)
    if detect is None:
        detect = default_detect if segmenter is None else detect_with_segmenter(segmenter)
    metrics = Metrics()
    api_token = settings.read_api_token()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        state = AppState.start(settings, metrics, detect, api_token, segmenter)
        app.state.dlo = state
        logger.info("%s", _where_it_listens(settings, api_token is not None))
        state.background.append(asyncio.create_task(_warm_up(state)))
        if settings.zenoh:
            state.background.append(asyncio.create_task(_open_bus(state)))
        try:
            yield
        finally:
            await state.close()

    app = FastAPI(
        title="dlo-service",
        summary="Cables (deformable linear objects) in images as chains of fixed-length segments.",
        version="0.1.0",
        lifespan=lifespan,
    )
    app.include_router(api)
    app.include_router(live_api)
    app.include_router(live_socket)
    app.include_router(router)
    app.include_router(viewer)
    app.add_middleware(RequestContextMiddleware, metrics=metrics)
    app.add_exception_handler(RequestError, _request_error)
    app.add_exception_handler(HTTPException, _http_exception)
    return app


def _where_it_listens(settings: Settings, token_required: bool) -> str:
    """One line: where HTTP listens (and whether it asks for a token), and where zenoh does."""
    access = "bearer token required on /v1/*" if token_required else "no token required"
    if token_required and settings.protect_metrics:
        access += " and /metrics"
    http = f"HTTP on http://{settings.host}:{settings.port} ({access})"
    if not settings.zenoh:
        return f"listening: {http}; zenoh off"
    from service.bus.config import describe_config  # only load zenoh when enabled

    try:
        zenoh = describe_config(_zenoh_config(settings))
    except Exception as exc:  # a bad file: _open_bus reports it (and /readyz)
        zenoh = f"zenoh configuration unusable ({type(exc).__name__})"
    return f"listening: {http}; {zenoh}"


def _zenoh_config(settings: Settings) -> Any:
    from service.bus.config import service_config

    return service_config(
        settings.zenoh_config, listen=settings.zenoh_listen, multicast=settings.zenoh_multicast
    )


async def _warm_up(state: AppState) -> None:
    """Run one detection on a tiny image in the pool; then the service is ready."""
    try:
        await state.pool.run(warm_up, state.detect)
    except asyncio.CancelledError:
        raise
    except Exception as exc:
        state.warm_up_error = f"warm-up detection failed: {type(exc).__name__}: {exc}"
        logger.exception("warm-up detection failed; /readyz answers 503")
        return
    state.ready = True
    state.metrics.ready.set(1)
    logger.info("warm-up detection done; ready")


async def _open_bus(state: AppState) -> None:
    """Open the zenoh front end (in a thread: opening may take a moment)."""
    # only load zenoh when enabled
    from service.bus.detection import DetectionBus

    settings = state.settings
    try:
        config = _zenoh_config(settings)
        bus = DetectionBus(
            config,
            detect=state.detect,
            metrics=state.metrics,
            max_pixels=settings.max_pixels,
            max_bytes=settings.max_body_bytes,
            image_keys=settings.zenoh_image_keys,
            balanced=settings.zenoh_assignment == "balanced",
            max_detect_seconds=settings.max_detect_seconds,
        )
        state.bus = bus  # before opening: close() then waits for open() to finish
        await asyncio.to_thread(bus.open)
    except asyncio.CancelledError:
        raise
    except Exception as exc:
        state.bus_error = f"zenoh session failed to open: {type(exc).__name__}: {exc}"
        logger.exception("zenoh session failed to open; /readyz answers 503")
        return
    logger.info(
        "zenoh session open; serving %s and dlo/detect", ", ".join(settings.zenoh_image_keys)
    )


async def _request_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestError)
    return _json_error(request, exc.status, exc.code, exc.message, dict(exc.headers))


async def _http_exception(request: Request, exc: Exception) -> JSONResponse:
    """404, 405 and the like, in the same JSON shape as every other error."""
    assert isinstance(exc, HTTPException)
    code = {404: "not_found", 405: "method_not_allowed"}.get(exc.status_code, "http_error")
    return _json_error(request, exc.status_code, code, str(exc.detail), dict(exc.headers or {}))


def _json_error(
    request: Request, status: int, code: str, message: str, headers: dict[str, str]
) -> JSONResponse:
    payload = error_payload(status, code, message, request_id_of(request.scope))
    return JSONResponse(payload, status_code=status, headers=headers)
