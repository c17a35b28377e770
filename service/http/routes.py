"""The HTTP routes: thin wrappers over :mod:`service.http.inputs` and :mod:`service.http.jobs`."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST

from schemas import Detection, DetectParams
from service.http.inputs import RAW_IMAGE_TYPES, RequestError, read_frame
from service.http.jobs import check_declared_size, run_detection, run_overlay
from service.http.state import AppState, PoolBusyError

router = APIRouter()


def app_state(request: Request) -> AppState:
    """The :class:`AppState` the lifespan stored on the app."""
    return request.app.state.dlo


def _query_parameters() -> list[dict[str, Any]]:
    """OpenAPI query parameters, one per :class:`DetectParams` field, from its JSON schema."""
    schema = DetectParams.model_json_schema()
    definitions = schema.get("$defs", {})

    def inline(node: Any) -> Any:
        if isinstance(node, dict):
            if "$ref" in node:
                return inline(definitions[node["$ref"].rsplit("/", 1)[-1]])
            return {key: inline(value) for key, value in node.items()}
        if isinstance(node, list):
            return [inline(item) for item in node]
        return node

    parameters = []
    for name, field_schema in schema["properties"].items():
        field_schema = inline(field_schema)
        description = field_schema.pop("description", "")
        field_schema.pop("title", None)
        if name.startswith("hsv_"):
            description += " Three values: repeated (?hsv_low=0&hsv_low=80&hsv_low=60) or 0,80,60."
        parameters.append(
            {
                "name": name,
                "in": "query",
                "required": False,
                "description": description,
                "schema": field_schema,
                "style": "form",
                "explode": True,
            }
        )
    return parameters


_BINARY = {"type": "string", "format": "binary"}
_DETECT_OPENAPI = {
    "parameters": _query_parameters(),
    "requestBody": {
        "required": True,
        "description": "The image as the whole body, or a multipart form with the file "
        "field `image` and optionally `mask` (non-zero = cable, same size as the image).",
        "content": {
            **{media_type: {"schema": _BINARY} for media_type in RAW_IMAGE_TYPES},
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["image"],
                    "properties": {"image": _BINARY, "mask": _BINARY},
                }
            },
        },
    },
}


def _error(description: str) -> dict[str, Any]:
    return {
        "description": description,
        "content": {
            "application/json": {
                "example": {
                    "status": 422,
                    "error": "invalid_image",
                    "detail": "image: truncated PNG file",
                    "request_id": "5b0c3c8e-1f0e-4a43-9f57-3f6c4b0c2a61",
                }
            }
        },
    }


_ERRORS: dict[int | str, dict[str, Any]] = {
    413: _error("Body or image larger than the configured limits."),
    415: _error("Content type other than image/jpeg, image/png or multipart/form-data."),
    422: _error("Image or mask unreadable, mask of another size or empty, bad parameters."),
    500: _error("Detection failed inside the service; the body holds the request id."),
    503: _error("Every worker and queue slot is busy; retry after `Retry-After` seconds."),
}


async def _run(request: Request, job: Any) -> Any:
    """Read the request, then run ``job`` in the pool (503 at once when it is full)."""
    state = app_state(request)
    settings = state.settings
    frame = await read_frame(request, settings.max_body_bytes)
    check_declared_size(frame.image, settings.max_pixels)
    try:
        result = await state.pool.run(job, frame, state.detect, settings.max_pixels)
    except PoolBusyError:
        state.metrics.frames_dropped.inc()
        raise RequestError(
            503,
            "busy",
            f"all {state.pool.workers} worker(s) and {state.pool.queue_size} queue slot(s) "
            "are busy; retry in a second",
            headers={"Retry-After": "1"},
        ) from None
    except RequestError:
        raise
    except Exception:
        state.metrics.detection_failures.inc()
        raise  # logged and answered with a 500 by RequestContextMiddleware
    state.metrics.observe_detection(result[1])
    return result


@router.post(
    "/v1/detect",
    summary="Detect the cables in an image",
    response_model=None,
    responses={200: {"model": Detection, "description": "The detected chains."}, **_ERRORS},
    openapi_extra=_DETECT_OPENAPI,
)
async def detect(request: Request) -> Response:
    """Every DLO in the image as a chain of `segment_length` px segments, with crossings."""
    _, detection = await _run(request, run_detection)
    return Response(detection.model_dump_json(), media_type="application/json")


@router.post(
    "/v1/detect/overlay",
    summary="Draw the detected cables on the image",
    response_model=None,
    response_class=Response,
    responses={200: {"content": {"image/png": {}}, "description": "PNG overlay."}, **_ERRORS},
    openapi_extra=_DETECT_OPENAPI,
)
async def detect_overlay(request: Request) -> Response:
    """The image with the chains drawn on it (inferred segments dashed), as PNG."""
    png, _ = await _run(request, run_overlay)
    return Response(png, media_type="image/png")


@router.get("/healthz", summary="Liveness: the process answers")
async def healthz() -> dict[str, str]:
    return {"status": "ok"}


@router.get(
    "/readyz",
    summary="Readiness: the warm-up detection has run (and the zenoh session is open)",
    responses={503: {"description": "Still warming up, or the warm-up or zenoh failed."}},
)
async def readyz(request: Request) -> JSONResponse:
    state = app_state(request)
    if state.bus_error is not None:
        return JSONResponse({"status": "failed", "detail": state.bus_error}, status_code=503)
    if state.ready and state.bus_ready:
        return JSONResponse({"status": "ready"})
    if state.warm_up_error is not None:
        return JSONResponse({"status": "failed", "detail": state.warm_up_error}, status_code=503)
    status = "warming up" if not state.ready else "opening the zenoh session"
    return JSONResponse({"status": status}, status_code=503, headers={"Retry-After": "1"})


@router.get("/metrics", summary="Prometheus metrics", response_class=Response)
async def metrics(request: Request) -> Response:
    return Response(app_state(request).metrics.render(), media_type=CONTENT_TYPE_LATEST)
