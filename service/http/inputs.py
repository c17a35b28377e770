"""From an HTTP request to the inputs of one detection (image, optional mask, parameters),
of one grasp plan (those, or a saved detection, plus a camera model and a selector) or of
one model of the cables (an image, a camera model and their physics).

Everything here runs on the event loop and is cheap: reading the body (bounded), parsing
the multipart form, its small JSON fields and the query, and checking the depth image's
PNG header. Decoding and validating large bodies, which is CPU work, happens in the
worker pool (:mod:`service.runtime.jobs`, :mod:`service.runtime.grasp`). Every problem
becomes a :class:`~service.runtime.errors.RequestError` carrying the HTTP status and a
one-line message saying what is wrong.
"""

from __future__ import annotations

from typing import Any, TypeVar, get_origin

from pydantic import BaseModel, ValidationError
from starlette.datastructures import QueryParams, UploadFile
from starlette.requests import Request

from schemas import CameraModel, DepthSurface, DetectParams, GraspSelector
from schemas.model import CablePhysics
from service.runtime.errors import RequestError, describe_fields, shortened
from service.runtime.frames import PNG_SIGNATURE, Frame, image_size
from service.runtime.grasp import GraspFrame
from service.runtime.model import ModelFrame

RAW_IMAGE_TYPES = ("image/jpeg", "image/png")
"""Content types accepted for an image sent as the whole request body."""
MULTIPART_TYPE = "multipart/form-data"
JSON_TYPE = "application/json"
FORM_FIELDS = ("image", "mask")
"""The multipart fields of ``/v1/detect``: image and mask files."""
GRASP_FORM_FIELDS = ("image", "mask", "camera", "selector", "depth")
"""The multipart fields of ``/v1/grasp``: image and mask files, camera and selector JSON,
and the depth image file for a camera whose surface is a depth image."""
MODEL_FORM_FIELDS = ("image", "mask", "camera", "physics", "depth")
"""The multipart fields of ``/v1/model``: as ``/v1/grasp``'s, with the cables' physics
(JSON) instead of a selector."""

ModelT = TypeVar("ModelT", bound=BaseModel)

_TUPLE_FIELDS = frozenset(
    name for name, info in DetectParams.model_fields.items() if get_origin(info.annotation) is tuple
)


async def read_frame(request: Request, max_body_bytes: int) -> Frame:
    """Read the image (raw body or multipart ``image``), the optional mask and the query.

    Raises
    ------
    RequestError
        415 for another content type, 413 for a body over ``max_body_bytes``, 422 for
        bad parameters, a missing or unexpected form field.
    """
    params = parse_params(request.query_params)
    media_type = content_type(request)
    if media_type not in (*RAW_IMAGE_TYPES, MULTIPART_TYPE):
        shown = media_type or "none"
        raise RequestError(
            415,
            "unsupported_media_type",
            f"Content-Type {shown} is not accepted: send the image as the body with "
            "Content-Type image/jpeg or image/png, or as the file field 'image' of a "
            "multipart/form-data body (optional file field 'mask')",
        )
    body = await read_body(request, max_body_bytes)
    if media_type == MULTIPART_TYPE:
        parts = await _parse_form(
            request,
            body,
            max_body_bytes,
            FORM_FIELDS,
            "the file field 'image' and optionally 'mask'",
        )
        return Frame(image=parts["image"], mask=parts["mask"], params=params)
    if not body:
        raise RequestError(422, "invalid_image", "image: empty body (0 bytes)")
    return Frame(image=body, params=params)


async def read_grasp_request(request: Request, max_body_bytes: int) -> GraspFrame | bytes:
    """Read a ``/v1/grasp`` request: a multipart form with an image, or a JSON body.

    Returns
    -------
    GraspFrame or bytes
        For ``multipart/form-data`` (file ``image``, optional file ``mask``, JSON fields
        ``camera`` and optional ``selector``, file ``depth`` when the camera's surface is
        a depth image; detection parameters in the query), the frame with the camera and
        selector already validated and the depth image's presence and declared size
        checked. For ``application/json``
        the raw body, a :class:`GraspRequest` validated in the worker pool since a
        detection may be large.

    Raises
    ------
    RequestError
        415 for another content type, 413 for a body over ``max_body_bytes``, 422 for
        a missing, unexpected or invalid field, bad parameters, query parameters with a
        JSON body (they only apply to detecting an image), or a depth image missing for
        a depth surface, given for a plane, empty or declaring another size than the
        camera's (``invalid_depth``).
    """
    media_type = content_type(request)
    if media_type == JSON_TYPE:
        if request.query_params:
            names = ", ".join(dict.fromkeys(request.query_params.keys()))
            raise RequestError(
                422,
                "invalid_parameters",
                f"query parameters ({names}) set up detecting an image; a JSON body "
                "carries a detection already",
            )
        body = await read_body(request, max_body_bytes)
        if not body:
            raise RequestError(422, "invalid_body", "empty body (0 bytes): send a JSON object")
        return body
    if media_type != MULTIPART_TYPE:
        shown = media_type or "none"
        raise RequestError(
            415,
            "unsupported_media_type",
            f"Content-Type {shown} is not accepted: send multipart/form-data (file 'image', "
            "JSON fields 'camera' and optionally 'selector', file 'depth' for a depth "
            "surface) or application/json "
            '({"detection": ..., "camera": ..., "selector": ...})',
        )
    parts, camera, params = await _camera_form(
        request,
        max_body_bytes,
        GRASP_FORM_FIELDS,
        "the file field 'image', optionally 'mask', the JSON fields 'camera' and "
        "optionally 'selector', and the file field 'depth' for a depth surface",
    )
    selector = optional_json_field(GraspSelector, "selector", parts["selector"])
    frame = Frame(image=parts["image"], mask=parts["mask"], params=params)
    return GraspFrame(frame=frame, camera=camera, selector=selector, depth=parts["depth"])


async def read_model_request(request: Request, max_body_bytes: int) -> ModelFrame:
    """Read a ``/v1/model`` request: a multipart form with an image and a camera model.

    File ``image``, optional file ``mask``, JSON field ``camera``, optional JSON field
    ``physics`` (:class:`~schemas.model.CablePhysics`), file ``depth`` when the camera's
    surface is a depth image; detection parameters in the query.

    Raises
    ------
    RequestError
        415 for another content type, 413 for a body over ``max_body_bytes``, 422 for a
        missing, unexpected or invalid field (``invalid_camera``, ``invalid_physics``,
        ``invalid_depth`` as for ``/v1/grasp``), or bad parameters.
    """
    if content_type(request) != MULTIPART_TYPE:
        shown = content_type(request) or "none"
        raise RequestError(
            415,
            "unsupported_media_type",
            f"Content-Type {shown} is not accepted: send multipart/form-data (file 'image', "
            "JSON field 'camera', optionally 'physics', file 'depth' for a depth surface)",
        )
    parts, camera, params = await _camera_form(
        request,
        max_body_bytes,
        MODEL_FORM_FIELDS,
        "the file field 'image', optionally 'mask', the JSON fields 'camera' and "
        "optionally 'physics', and the file field 'depth' for a depth surface",
    )
    physics = optional_json_field(CablePhysics, "physics", parts["physics"])
    frame = Frame(image=parts["image"], mask=parts["mask"], params=params)
    return ModelFrame(frame=frame, camera=camera, physics=physics, depth=parts["depth"])


async def _camera_form(
    request: Request, max_body_bytes: int, fields: tuple[str, ...], expected: str
) -> tuple[dict[str, bytes | None], CameraModel, DetectParams]:
    """The parts of a multipart form with a camera model (validated) and a depth image (its
    presence and declared size checked), and the detection parameters of the query."""
    params = parse_params(request.query_params)
    body = await read_body(request, max_body_bytes)
    parts = await _parse_form(request, body, max_body_bytes, fields, expected)
    if parts["camera"] is None:
        raise RequestError(422, "invalid_camera", "multipart body has no 'camera' field")
    camera = parse_json_field(CameraModel, "camera", parts["camera"])
    check_depth_part(camera, parts["depth"])
    return parts, camera, params


def check_depth_part(camera: CameraModel, depth: bytes | None) -> None:
    """422 ``invalid_depth`` unless the ``depth`` part fits the camera's surface.

    Required for a depth surface and refused for a plane; a PNG whose header declares the
    camera's size (the header is read, not the image: a wrong-sized one is never decoded).
    """
    surface = camera.surface
    if not isinstance(surface, DepthSurface):
        if depth is not None:
            raise RequestError(
                422,
                "invalid_depth",
                f"depth: the camera's surface is the plane z = {surface.plane_z} m; a depth "
                'image needs the surface {"kind": "depth", "depth_scale": ...}',
            )
        return
    if depth is None:
        raise RequestError(
            422,
            "invalid_depth",
            "the camera's surface is a depth image (kind 'depth'): send it as the file field "
            "'depth', a 16-bit PNG aligned with the image",
        )
    if not depth:
        raise RequestError(422, "invalid_depth", "depth: empty file (0 bytes)")
    if not depth.startswith(PNG_SIGNATURE):
        # PNG only: its header declares the size, so nothing larger than the camera's
        # image is ever decompressed.
        raise RequestError(
            422, "invalid_depth", "depth: not a PNG file; send a single-channel 16-bit PNG"
        )
    declared = image_size(depth)
    if declared is not None and declared != (camera.width, camera.height):
        raise RequestError(
            422,
            "invalid_depth",
            f"depth: image is {declared[0]}x{declared[1]} px but the camera model is "
            f"{camera.width}x{camera.height} px",
        )


def optional_json_field(model: type[ModelT], name: str, data: bytes | None) -> ModelT:
    """:func:`parse_json_field`, or the model's defaults when the field was not sent."""
    return model() if data is None else parse_json_field(model, name, data)


def parse_json_field(model: type[ModelT], name: str, data: bytes) -> ModelT:
    """Validate the JSON ``data`` of form field ``name``; 422 ``invalid_<name>`` if wrong."""
    try:
        return model.model_validate_json(data)
    except ValidationError as exc:
        problems = describe_fields(exc)
        raise RequestError(422, f"invalid_{name}", f"{name}: " + "; ".join(problems)) from None


def content_type(request: Request) -> str:
    """The media type of the request body, lower case, without parameters ('' if none)."""
    return request.headers.get("content-type", "").split(";", 1)[0].strip().lower()


async def read_body(request: Request, limit: int) -> bytes:
    """The whole request body, refusing (413) as soon as it is known to exceed ``limit``.

    A ``Content-Length`` over the limit is refused before anything is read; a body
    without one (chunked) is refused when the bytes read pass the limit.
    """
    declared = request.headers.get("content-length")
    if declared is not None and declared.strip().isdigit() and int(declared) > limit:
        raise _body_too_large(int(declared), limit)
    received = bytearray()
    async for chunk in request.stream():
        received += chunk
        if len(received) > limit:
            raise _body_too_large(None, limit)
    return bytes(received)


def _body_too_large(size: int | None, limit: int) -> RequestError:
    given = "" if size is None else f" ({size / 1048576:.1f} MiB)"
    return RequestError(
        413,
        "payload_too_large",
        f"request body{given} is larger than the limit of {limit / 1048576:.1f} MiB",
    )


async def _parse_form(
    request: Request, body: bytes, limit: int, fields: tuple[str, ...], expected: str
) -> dict[str, bytes | None]:
    """The ``fields`` of a multipart body already read (None when absent); ``image`` required.

    ``expected`` describes the fields for the message about an unexpected one.
    """
    delivered = False

    async def replay() -> dict[str, Any]:
        nonlocal delivered
        if delivered:
            return {"type": "http.disconnect"}
        delivered = True
        return {"type": "http.request", "body": body, "more_body": False}

    form_request = Request(request.scope, replay)
    try:
        form = await form_request.form(max_files=5, max_fields=8, max_part_size=limit)
    except Exception as exc:  # the multipart parser's own error types vary between versions
        detail = getattr(exc, "detail", None) or getattr(exc, "message", None) or exc
        raise RequestError(422, "invalid_form", f"malformed multipart body: {detail}") from None
    try:
        unexpected = sorted(set(form.keys()) - set(fields))
        if unexpected:
            raise RequestError(
                422,
                "invalid_form",
                f"unexpected form field(s) {', '.join(unexpected)}: send {expected}",
            )
        parts: dict[str, bytes | None] = {}
        for name in fields:
            values = form.getlist(name)
            if len(values) > 1:
                raise RequestError(422, "invalid_form", f"form field '{name}' is given twice")
            parts[name] = await _part_bytes(values[0]) if values else None
        if parts["image"] is None:
            raise RequestError(422, "invalid_form", "multipart body has no 'image' file field")
        if not parts["image"]:
            raise RequestError(422, "invalid_image", "image: empty file (0 bytes)")
        if parts["mask"] is not None and not parts["mask"]:
            raise RequestError(422, "invalid_mask", "mask: empty file (0 bytes)")
        return parts
    finally:
        await form.close()


async def _part_bytes(value: UploadFile | str) -> bytes:
    if isinstance(value, str):
        return value.encode("utf-8")
    return await value.read()


def parse_params(query: QueryParams) -> DetectParams:
    """Validate the query into :class:`DetectParams` (422 with a one-line message if not).

    Tuple fields (``hsv_low``, ``hsv_high``) are given repeated (``?hsv_low=0&hsv_low=80
    &hsv_low=60``) or comma separated (``?hsv_low=0,80,60``); other fields once.
    """
    values: dict[str, Any] = {}
    problems: list[str] = []
    for name in dict.fromkeys(query.keys()):
        given = query.getlist(name)
        if name not in DetectParams.model_fields:
            problems.append(f"{shortened(name)}: unknown parameter")
        elif name in _TUPLE_FIELDS:
            values[name] = [part.strip() for item in given for part in item.split(",")]
        elif len(given) > 1:
            problems.append(f"{name}: given {len(given)} times, expected once")
        else:
            values[name] = given[0]
    if not problems:
        try:
            return DetectParams.model_validate(values)
        except ValidationError as exc:
            problems = _describe(exc)
    raise RequestError(422, "invalid_parameters", "invalid parameters: " + "; ".join(problems))


def _describe(error: ValidationError) -> list[str]:
    problems = []
    for detail in error.errors(include_url=False):
        message = str(detail["msg"]).removeprefix("Value error, ")
        location = detail["loc"]
        if not location:
            problems.append(message)
            continue
        name = str(location[0])
        name += "".join(f"[{index}]" for index in location[1:])
        problems.append(f"{name}: {message} (got {shortened(repr(detail.get('input')))})")
    return problems
