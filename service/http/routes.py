"""The HTTP routes: thin wrappers over :mod:`service.http.inputs` (reading a request) and the
runtime's jobs (:mod:`service.runtime.jobs`, :mod:`service.runtime.grasp`) run in its pool."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST
from pydantic import BaseModel

from schemas import Detection, DetectParams
from schemas.grasp import GraspPlan
from schemas.model import CablePhysics
from service.http.auth import API_TOKEN, METRICS_TOKEN
from service.http.inputs import (
    JSON_TYPE,
    RAW_IMAGE_TYPES,
    read_frame,
    read_grasp_request,
    read_model_request,
)
from service.http.state import AppState
from service.runtime.errors import RequestError
from service.runtime.frames import Frame, check_frame, check_upload
from service.runtime.grasp import GraspFrame, GraspRequest, plan_from_json, run_grasp
from service.runtime.jobs import OVER_BUDGET, run_detection, run_labels, run_overlay
from service.runtime.model import run_model
from service.runtime.pool import PoolBusyError

router = APIRouter()
"""Open routes: probes and metrics."""
api = APIRouter(dependencies=[API_TOKEN])
"""The data routes (``/v1/*``): the bearer token is required on each, when one is set."""


def app_state(request: Request) -> AppState:
    """The :class:`AppState` the lifespan stored on the app."""
    return request.app.state.dlo


def inline_schema(model: type[BaseModel]) -> dict[str, Any]:
    """The JSON schema of ``model`` with every ``$ref`` replaced by its definition.

    OpenAPI ``openapi_extra`` cannot point into the model's own ``$defs``. Discriminator
    mappings are ``$ref`` strings too, so they are dropped: the ``kind`` constants of
    the ``oneOf`` branches already tell the variants apart.
    """
    schema = model.model_json_schema()
    definitions = schema.pop("$defs", {})

    def inline(node: Any) -> Any:
        if isinstance(node, dict):
            if "$ref" in node:  # the field's own keys (its description) win over the model's
                siblings = {key: value for key, value in node.items() if key != "$ref"}
                return {**inline(definitions[node["$ref"].rsplit("/", 1)[-1]]), **siblings}
            return {key: inline(value) for key, value in node.items() if key != "discriminator"}
        if isinstance(node, list):
            return [inline(item) for item in node]
        return node

    return inline(schema)


def _query_parameters() -> list[dict[str, Any]]:
    """OpenAPI query parameters, one per :class:`DetectParams` field, from its JSON schema."""
    schema = inline_schema(DetectParams)
    parameters = []
    for name, field_schema in schema["properties"].items():
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


_DEPTH_PART = {
    **_BINARY,
    "description": "Depth image aligned with `image`, a single-channel 16-bit PNG of the "
    "camera's size in units of the surface's `depth_scale` metres (0 = not measured). "
    'Required when the camera\'s surface is {"kind": "depth", ...}, refused otherwise.',
}


def _camera_form(name: str, field: dict[str, Any]) -> dict[str, Any]:
    """The multipart form of ``/v1/grasp`` and ``/v1/model``: image, mask, camera, depth
    and the route's own JSON field ``name``."""
    return {
        "schema": {
            "type": "object",
            "required": ["image", "camera"],
            "properties": {
                "image": _BINARY,
                "mask": _BINARY,
                "camera": {
                    "type": "string",
                    "description": "CameraModel as JSON, e.g. docs/examples/camera.json.",
                },
                name: field,
                "depth": _DEPTH_PART,
            },
        },
        "encoding": {"camera": {"contentType": JSON_TYPE}, name: {"contentType": JSON_TYPE}},
    }


_GRASP_OPENAPI = {
    "parameters": _query_parameters(),
    "requestBody": {
        "required": True,
        "description": "Either a multipart form: the file field `image` (optionally `mask`), "
        "the field `camera` holding a CameraModel as JSON, optionally `selector` holding "
        "a GraspSelector as JSON (default: the middle of the longest chain), and the file "
        "field `depth` when the camera's surface is a depth image; the query sets up the "
        "detection as for `/v1/detect`. Or a JSON body with a saved `detection`, the "
        "`camera` (its surface a plane: a JSON body cannot carry a depth image) and the "
        "optional `selector`; no query parameters then.",
        "content": {
            JSON_TYPE: {"schema": inline_schema(GraspRequest)},
            "multipart/form-data": _camera_form(
                "selector",
                {
                    "type": "string",
                    "description": 'GraspSelector as JSON, e.g. {"chain": "longest", '
                    '"point": {"kind": "fraction", "value": 0.5}}.',
                },
            ),
        },
    },
}


_MODEL_OPENAPI = {
    "parameters": _query_parameters(),
    "requestBody": {
        "required": True,
        "description": "A multipart form: the file field `image` (optionally `mask`), the "
        "field `camera` holding a CameraModel as JSON, optionally `physics` holding the "
        "cables' physics as JSON, and the file field `depth` when the camera's surface is "
        "a depth image; the query sets up the detection as for `/v1/detect`.",
        "content": {
            "multipart/form-data": _camera_form(
                "physics",
                {
                    **inline_schema(CablePhysics),
                    "description": "The cables' physics (per metre of cable) as JSON, "
                    'e.g. {"bending_stiffness": 1e-3}; every field optional.',
                },
            ),
        },
    },
}


def _error(
    description: str,
    status: int = 422,
    code: str = "invalid_image",
    detail: str = "image: truncated PNG file",
) -> dict[str, Any]:
    example = {
        "status": status,
        "error": code,
        "detail": detail,
        "request_id": "5b0c3c8e-1f0e-4a43-9f57-3f6c4b0c2a61",
    }
    return {"description": description, "content": {"application/json": {"example": example}}}


_UNAUTHORIZED = {
    "status": 401,
    "code": "unauthorized",
    "detail": "a bearer token is required: send the header 'Authorization: Bearer <token>'",
}


_ERRORS: dict[int | str, dict[str, Any]] = {
    401: _error(
        "A bearer token is set (DLO_API_TOKEN) and the request's is missing or wrong.",
        **_UNAUTHORIZED,
    ),
    413: _error(
        "Body, image or mask larger than the configured limits (read from the PNG or JPEG "
        "header, before decoding)."
    ),
    415: _error(
        "Content type other than image/jpeg, image/png or multipart/form-data, or an "
        "uploaded file in another image format than PNG or JPEG."
    ),
    422: _error(
        "Image or mask unreadable, mask of another size or empty, bad parameters; "
        "`time_budget_exceeded`: the detection ran past DLO_MAX_DETECT_SECONDS and was stopped."
    ),
    500: _error("Detection failed inside the service; the body holds the request id."),
    503: _error("Every worker and queue slot is busy; retry after `Retry-After` seconds."),
}


_GRASP_ERRORS: dict[int | str, dict[str, Any]] = {
    401: _error(
        "A bearer token is set (DLO_API_TOKEN) and the request's is missing or wrong.",
        **_UNAUTHORIZED,
    ),
    **_ERRORS,
    415: _error("Content type other than multipart/form-data or application/json."),
    422: _error(
        "Unreadable image or mask, invalid camera, selector, detection or parameters "
        "(`invalid_*`); a depth image missing for a depth surface, given for a plane, "
        "unreadable, not 16-bit single-channel or of another size than the camera's "
        "(`invalid_depth`); a point on an inferred segment not allowed (`inferred_segment`); "
        "no grasp: no chain, unknown chain id or segment, image size other than the "
        "camera's, a ray missing the table, no valid depth around the point (`ungraspable`); "
        "the detection ran past DLO_MAX_DETECT_SECONDS (`time_budget_exceeded`)."
    ),
}


_MODEL_ERRORS: dict[int | str, dict[str, Any]] = {
    **_ERRORS,
    415: _error("Content type other than multipart/form-data."),
    422: _error(
        "Unreadable image or mask, invalid camera (`invalid_camera`: also an image of "
        "another size than the camera's), physics (`invalid_physics`: also a damping too "
        "low for the timestep) or parameters; a depth image missing for a depth surface, "
        "given for a plane, unreadable, not 16-bit single-channel or of another size than "
        "the camera's (`invalid_depth`)."
    ),
}


async def _checked_frame(request: Request) -> tuple[AppState, Frame]:
    """The app's state and the request's frame, its limits checked."""
    state = app_state(request)
    frame = await read_frame(request, state.settings.max_body_bytes)
    check_frame(frame, state.settings.max_pixels)
    return state, frame


async def _run(request: Request, job: Any) -> Any:
    """Read the request, then run ``job(frame, the app's detect, max_pixels, budget)`` in
    the pool (503 at once when it is full)."""
    state, frame = await _checked_frame(request)
    settings = state.settings
    result = await _in_pool(
        state, job, frame, state.detect, settings.max_pixels, settings.max_detect_seconds
    )
    state.metrics.observe_detection(result[1])
    return result


async def _in_pool(state: AppState, job: Any, *args: Any) -> Any:
    """``job(*args)`` in the worker pool: 503 at once when it is full; failures counted."""
    try:
        return await state.pool.run(job, *args)
    except PoolBusyError:
        state.metrics.frames_dropped.inc()
        raise RequestError(
            503,
            "busy",
            f"all {state.pool.workers} worker(s) and {state.pool.queue_size} queue slot(s) "
            "are busy; retry in a second",
            headers={"Retry-After": "1"},
        ) from None
    except RequestError as exc:
        if exc.code == OVER_BUDGET:
            state.metrics.over_budget.inc()
        raise
    except Exception:
        state.metrics.detection_failures.inc()
        raise  # logged and answered with a 500 by RequestContextMiddleware


@api.post(
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


@api.post(
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


@api.post(
    "/v1/detect/labels",
    summary="The instance label image of the detected cables",
    response_model=None,
    response_class=Response,
    responses={
        200: {"content": {"image/png": {}}, "description": "16-bit PNG of the image's size."},
        **_ERRORS,
    },
    openapi_extra=_DETECT_OPENAPI,
)
async def detect_labels(request: Request) -> Response:
    """Every cable pixel labelled with its chain: 0 background, chain *i* as *i* + 1, the
    strand on top at crossings, inferred segments as tubes of the chain's radius (as
    `dlo detect` writes `<stem>.labels.png`)."""
    state, frame = await _checked_frame(request)
    settings = state.settings
    png, detection = await _in_pool(
        state, run_labels, frame, state.segmenter, settings.max_pixels, settings.max_detect_seconds
    )
    state.metrics.observe_detection(detection)
    return Response(png, media_type="image/png")


@api.post(
    "/v1/grasp",
    summary="Plan a grasp on a detected cable and the UR3 motions to pick it (no robot moves)",
    response_model=None,
    responses={
        200: {"model": GraspPlan, "description": "The grasp target and the motions."},
        **_GRASP_ERRORS,
    },
    openapi_extra=_GRASP_OPENAPI,
)
async def grasp(request: Request) -> Response:
    """Where to grasp (robot base frame) and the moves a UR3 pick would send; never moves.

    `within_workspace` is false, with the reason in `refusal`, when `dlo ur3 pick` would
    refuse the motions for the default workspace; the checks that need the robot itself
    (safety limits, stops) are not made here.
    """
    state = app_state(request)
    settings = state.settings
    inputs = await read_grasp_request(request, settings.max_body_bytes)
    if isinstance(inputs, GraspFrame):
        check_frame(inputs.frame, settings.max_pixels)
        if inputs.depth is not None:
            check_upload(inputs.depth, "depth", settings.max_pixels)
        plan, detection = await _in_pool(
            state,
            run_grasp,
            inputs,
            state.detect,
            settings.max_pixels,
            settings.max_detect_seconds,
        )
        state.metrics.observe_detection(detection)
    else:
        # Validating a large detection is CPU work too: the pool, not the event loop.
        plan = await _in_pool(state, plan_from_json, inputs)
    return Response(plan.model_dump_json(exclude_none=True), media_type="application/json")


@api.post(
    "/v1/model",
    summary="A MuJoCo model (MJCF) of the cables in an image, lifted to the robot base frame",
    response_model=None,
    response_class=Response,
    responses={
        200: {"content": {"application/xml": {}}, "description": "The MJCF model."},
        **_MODEL_ERRORS,
    },
    openapi_extra=_MODEL_OPENAPI,
)
async def model(request: Request) -> Response:
    """Detect the cables, lift every joint to the base frame with the camera model (and
    depth image), and answer the MJCF: per chain, one capsule body per segment joined by
    ball joints, on the surface plane (see the README for the structure and physics)."""
    state = app_state(request)
    settings = state.settings
    inputs = await read_model_request(request, settings.max_body_bytes)
    check_frame(inputs.frame, settings.max_pixels)
    if inputs.depth is not None:
        check_upload(inputs.depth, "depth", settings.max_pixels)
    text, detection = await _in_pool(
        state,
        run_model,
        inputs,
        state.detect,
        settings.max_pixels,
        settings.max_detect_seconds,
    )
    state.metrics.observe_detection(detection)
    return Response(text, media_type="application/xml")


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


@router.get(
    "/metrics",
    summary="Prometheus metrics",
    response_class=Response,
    dependencies=[METRICS_TOKEN],
    responses={
        401: _error(
            "DLO_PROTECT_METRICS is on and the bearer token is missing or wrong.", **_UNAUTHORIZED
        )
    },
)
async def metrics(request: Request) -> Response:
    return Response(app_state(request).metrics.render(), media_type=CONTENT_TYPE_LATEST)
