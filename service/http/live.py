"""The viewer's live mode over HTTP: the cameras seen on zenoh and a WebSocket per camera.

``GET /v1/live/cameras`` lists the cameras publishing on ``dlo/*/image``; the WebSocket
``/v1/live/{camera}`` streams that camera's frames, each with the result made from it
(:mod:`service.bus.live` pairs them). Both need the bearer token when one is set: the
cameras list as every ``/v1/*`` route, the WebSocket in its ``Authorization`` header or,
from a browser (which cannot set that header on a WebSocket), in its first message.

The protocol of ``/v1/live/{camera}?results=auto|chains|tracks``:

* client -> server, text JSON: ``{"type": "auth", "token": "..."}`` first when a token is
  needed and no header carried it; then ``{"type": "ack"}`` each time it has drawn a frame;
* server -> client, text JSON: ``{"type": "hello", ...}`` once watching,
  ``{"type": "status", ...}`` each second without a frame to send, and
  ``{"type": "error", "status", "error", "detail"}`` before it closes the socket with code
  4000 + the HTTP status it stands for (4401, 4422, 4503);
* server -> client, binary: a frame. A 4-byte big-endian length, that many bytes of header
  JSON (``seq``, ``frame_id``, ``kind``, ``pairing``, ``latency_ms``, ``camera_fps``,
  ``dropped_slow_link``, ``result_bytes``, ``image_bytes``, ...), then ``result_bytes`` of
  result JSON (the Detection, or the error record), then ``image_bytes`` of JPEG.

Back-pressure, so that a slow client neither grows the server's memory nor its own: at most
:data:`WINDOW` frames are sent and not yet acknowledged; meanwhile only the newest view
waits (latest wins) and each one it replaces is counted in ``dropped_slow_link``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import struct
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from fastapi import APIRouter, Request, WebSocket
from fastapi.responses import JSONResponse

from service.http.auth import API_TOKEN, bearer_token, check_token
from service.http.state import AppState
from service.runtime.errors import RequestError

if TYPE_CHECKING:  # zenoh is loaded when the bus is, not with the app
    from service.bus.live import LiveHub, LiveView

logger = logging.getLogger(__name__)

WINDOW = 2
"""Frames sent and not yet acknowledged by the client, at most."""
STATUS_EVERY_S = 1.0
"""A status message this often while no frame is sent."""
AUTH_TIMEOUT_S = 10.0
"""How long the server waits for the token message."""

live_api = APIRouter(dependencies=[API_TOKEN])
"""``GET /v1/live/cameras`` (the token as on every ``/v1/*`` route)."""
live_socket = APIRouter()
"""The WebSocket, which checks the token itself (header or first message)."""


def live_hub(state: AppState) -> LiveHub:
    """The app's :class:`LiveHub`, made on first use on the zenoh bus's session.

    Raises
    ------
    RequestError
        503 when zenoh is off, failed, or is still opening.
    """
    if state.live is not None:
        return state.live
    if not state.settings.zenoh:
        raise RequestError(503, "zenoh_off", "zenoh is off in this service (DLO_ZENOH=false)")
    bus = state.bus
    if bus is None or not bus.is_open:
        detail = state.bus_error or "the zenoh session is still opening; retry in a second"
        raise RequestError(503, "zenoh_unavailable", detail, headers={"Retry-After": "1"})
    from service.bus.live import LiveHub

    settings = state.settings
    state.live = LiveHub(
        bus.session, max_bytes=settings.max_body_bytes, max_pixels=settings.max_pixels
    )
    return state.live


@live_api.get(
    "/v1/live/cameras",
    summary="The cameras publishing frames on zenoh (dlo/<camera>/image), for the live view",
    responses={
        503: {"description": "zenoh is off, failed, or is still opening."},
        401: {"description": "A bearer token is set and the request's is missing or wrong."},
    },
)
async def cameras(request: Request) -> JSONResponse:
    """Each camera seen in the last minute: `camera`, `fps` (null when unknown),
    `last_frame_s` (seconds since its last frame), `frames` seen, `watchers` (live views)."""
    from service.bus.live import CAMERAS_KEY

    hub = live_hub(request.app.state.dlo)
    return JSONResponse({"key": CAMERAS_KEY, "cameras": hub.cameras()})


class _Mailbox:
    """One client's newest view and its credit; touched on the event loop only."""

    def __init__(self) -> None:
        self.view: LiveView | None = None
        self.replaced = 0
        self.credit = WINDOW
        self.wake = asyncio.Event()

    def put(self, view: LiveView) -> None:
        if self.view is not None:
            self.replaced += 1
        self.view = view
        self.wake.set()

    def ack(self) -> None:
        self.credit = min(WINDOW, self.credit + 1)
        self.wake.set()


@live_socket.websocket("/v1/live/{camera}")
async def live(websocket: WebSocket, camera: str, results: str = "auto") -> None:
    """Stream ``camera``'s frames with their chains (or tracks); see the module's doc."""
    if not _same_origin(websocket):
        await websocket.close(code=1008)  # before accepting: a 403 to another site's page
        return
    await websocket.accept()
    state: AppState = websocket.app.state.dlo
    try:
        await _authenticate(websocket, state.api_token)
        hub = live_hub(state)
        from service.bus.live import camera_name_problem  # loaded with the hub

        problem = camera_name_problem(camera)
        if problem is not None:
            raise RequestError(422, "invalid_camera", problem)
        if results not in ("auto", "chains", "tracks"):
            raise RequestError(422, "invalid_results", f"results={results}: auto, chains or tracks")
    except RequestError as exc:
        await _refuse(websocket, exc)
        return
    except _Disconnected:
        return
    await _stream(websocket, hub, camera, results, state.settings.max_pixels)


class _Disconnected(Exception):
    """The client went away."""


def _same_origin(websocket: WebSocket) -> bool:
    """False for a browser page of another site (its ``Origin`` is not this host, nor the
    host a reverse proxy says it forwarded): no cross-site page may read the cameras.
    Clients that are not browsers send no Origin."""
    origin = websocket.headers.get("origin")
    if origin is None:
        return True
    hosts = {websocket.headers.get(name, "").lower() for name in ("host", "x-forwarded-host")}
    return urlsplit(origin).netloc.lower() in hosts - {""}


async def _authenticate(websocket: WebSocket, expected: str | None) -> None:
    """The token from the ``Authorization`` header, else from the first message."""
    if expected is None:
        return
    given = bearer_token(websocket.headers.get("authorization"))
    if given is None:
        try:
            message = await asyncio.wait_for(websocket.receive(), AUTH_TIMEOUT_S)
        except TimeoutError:
            raise RequestError(401, "unauthorized", "no token message within 10 s") from None
        if message["type"] == "websocket.disconnect":
            raise _Disconnected
        given = _token_of(message.get("text"))
    check_token(expected, given)


def _token_of(text: str | None) -> str | None:
    try:
        message = json.loads(text or "")
    except ValueError:
        return None
    if isinstance(message, dict) and message.get("type") == "auth":
        token = message.get("token")
        return token if isinstance(token, str) else None
    return None


async def _refuse(websocket: WebSocket, error: RequestError) -> None:
    """Say why (a message the page shows), then close with 4000 + the status."""
    with contextlib.suppress(Exception):  # the client may be gone already
        await websocket.send_json(
            {"type": "error", "status": error.status, "error": error.code, "detail": error.message}
        )
        await websocket.close(code=4000 + error.status, reason=error.message[:120])


async def _stream(
    websocket: WebSocket, hub: LiveHub, camera: str, results: str, max_pixels: int
) -> None:
    mailbox = _Mailbox()
    loop = asyncio.get_running_loop()

    def deliver(view: LiveView) -> None:  # on a zenoh thread
        with contextlib.suppress(RuntimeError):  # the loop closed: the server is stopping
            loop.call_soon_threadsafe(mailbox.put, view)

    unwatch = hub.watch(camera, deliver, results)
    receiver = asyncio.create_task(_receive_acks(websocket, mailbox))
    sender = asyncio.create_task(_send_views(websocket, mailbox, hub, camera, max_pixels))
    try:
        await websocket.send_json(
            {"type": "hello", "camera": camera, "results": results, "window": WINDOW}
        )
        await asyncio.wait({receiver, sender}, return_when=asyncio.FIRST_COMPLETED)
    except Exception:  # the client went away while we said hello
        logger.debug("live: camera %s: hello failed", camera, exc_info=True)
    finally:
        unwatch()
        for task in (receiver, sender):
            task.cancel()
        await asyncio.gather(receiver, sender, return_exceptions=True)
    logger.debug("live: camera %s: client gone after %d replaced views", camera, mailbox.replaced)


async def _receive_acks(websocket: WebSocket, mailbox: _Mailbox) -> None:
    """Until the client goes: each ``{"type": "ack"}`` gives a credit back."""
    while True:
        message = await websocket.receive()
        if message["type"] == "websocket.disconnect":
            return
        text = message.get("text")
        if text and '"ack"' in text:
            with contextlib.suppress(ValueError):
                if json.loads(text).get("type") == "ack":
                    mailbox.ack()


async def _send_views(
    websocket: WebSocket, mailbox: _Mailbox, hub: LiveHub, camera: str, max_pixels: int
) -> None:
    """Send the newest view whenever there is one and credit for it; a status otherwise."""
    while True:
        if mailbox.view is not None and mailbox.credit > 0:
            view, mailbox.view = mailbox.view, None
            mailbox.credit -= 1
            header = {"camera_fps": _rounded(hub.camera_fps(camera))}
            header["dropped_slow_link"] = mailbox.replaced
            message = await asyncio.to_thread(encode_view, view, header, max_pixels)
            await websocket.send_bytes(message)
            continue
        mailbox.wake.clear()
        try:
            await asyncio.wait_for(mailbox.wake.wait(), STATUS_EVERY_S)
        except TimeoutError:
            last = hub.last_frame_s(camera)
            await websocket.send_json(
                {
                    "type": "status",
                    "camera_fps": _rounded(hub.camera_fps(camera)),
                    "last_frame_s": _rounded(last),
                    "waiting_for_ack": mailbox.credit <= 0,
                    "dropped_slow_link": mailbox.replaced,
                }
            )


def encode_view(view: LiveView, extra: dict[str, Any], max_pixels: int) -> bytes:
    """One binary frame message (see the module's doc): header, result JSON, JPEG."""
    frame = view.frame
    try:
        image = frame.jpeg(max_pixels)
        image_error = None
    except ValueError as exc:
        image, image_error = b"", str(exc)
    result = view.result or b""
    header = {
        "type": "frame",
        "camera": view.camera,
        "seq": frame.seq,
        "frame_id": frame.frame_id,
        "capture_time": frame.capture_time,
        "kind": view.kind,
        "pairing": view.pairing,
        "latency_ms": view.latency_ms,
        "replica": view.replica,
        **extra,
        "result_bytes": len(result),
        "image_bytes": len(image),
        "image_error": image_error,
    }
    encoded = json.dumps(header).encode()
    return struct.pack(">I", len(encoded)) + encoded + result + image


def decode_view(message: bytes) -> tuple[dict[str, Any], bytes, bytes]:
    """The header, result and JPEG of a binary frame message (the inverse of
    :func:`encode_view`), for Python clients and tests."""
    (length,) = struct.unpack(">I", message[:4])
    header = json.loads(message[4 : 4 + length])
    start = 4 + length
    result = message[start : start + header["result_bytes"]]
    image = message[start + header["result_bytes"] :]
    return header, result, image


def _rounded(value: float | None) -> float | None:
    return None if value is None else round(value, 2)
