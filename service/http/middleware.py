"""Request ids, request metrics, the last-resort 500, client hang-ups (499) and over-long
request targets (414), as one plain ASGI middleware."""

from __future__ import annotations

import json
import logging
import time
import uuid

from starlette.datastructures import MutableHeaders
from starlette.requests import ClientDisconnect
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.http.server import MAX_TARGET_BYTES, TARGET_LENGTH_KEY
from service.runtime.metrics import Metrics

logger = logging.getLogger(__name__)

REQUEST_ID_HEADER = "X-Request-ID"
CLIENT_CLOSED = 499
"""Status counted for a request whose client hung up before it was read (as nginx logs it)."""


def request_id_of(scope: Scope) -> str:
    """The id :class:`RequestContextMiddleware` gave this request ('' outside one)."""
    return scope.get("state", {}).get("request_id", "")


def error_payload(status: int, code: str, message: str, request_id: str) -> dict[str, object]:
    """The JSON body of every error answer."""
    return {"status": status, "error": code, "detail": message, "request_id": request_id}


class RequestContextMiddleware:
    """Give every request a uuid4 (``X-Request-ID`` on every response) and count it.

    An exception nothing else handled is logged with its traceback and the request id,
    and answered with a JSON 500 holding only the id: no traceback reaches the client,
    and the server goes on serving. A client that hangs up before its request was read
    is no failure of the service: one line at INFO, counted as :data:`CLIENT_CLOSED`. A
    request target longer than :data:`~service.http.server.MAX_TARGET_BYTES` is answered
    414 without running the route.
    """

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        request_id = str(uuid.uuid4())
        scope.setdefault("state", {})["request_id"] = request_id
        status = 500
        started = False

        async def send_with_id(message: Message) -> None:
            nonlocal status, started
            if message["type"] == "http.response.start":
                started = True
                status = message["status"]
                MutableHeaders(scope=message)[REQUEST_ID_HEADER] = request_id
            await send(message)

        async def send_error(status: int, code: str, message: str) -> None:
            body = json.dumps(error_payload(status, code, message, request_id)).encode("utf-8")
            await send_with_id(
                {
                    "type": "http.response.start",
                    "status": status,
                    "headers": [
                        (b"content-type", b"application/json"),
                        (b"content-length", str(len(body)).encode()),
                    ],
                }
            )
            await send_with_id({"type": "http.response.body", "body": body})

        began = time.perf_counter()
        target_bytes = scope.get(TARGET_LENGTH_KEY) or len(scope.get("raw_path", b"")) + len(
            scope.get("query_string", b"")
        )
        try:
            if target_bytes > MAX_TARGET_BYTES:
                await send_error(
                    414,
                    "uri_too_long",
                    f"the request target (path and query) is {target_bytes} bytes, more than "
                    f"the limit of {MAX_TARGET_BYTES}",
                )
            else:
                await self.app(scope, receive, send_with_id)
        except ClientDisconnect:
            status = CLIENT_CLOSED
            logger.info(
                "request %s (%s %s): the client closed the connection before sending it all",
                request_id,
                scope["method"],
                scope["path"],
            )
        except Exception:
            logger.exception(
                "request %s (%s %s) failed", request_id, scope["method"], scope["path"]
            )
            if not started:
                await send_error(
                    500,
                    "internal_error",
                    f"internal error; quote request id {request_id} when reporting it",
                )
        finally:
            route = _route_label(scope)
            self.metrics.requests.labels(route, scope["method"], str(status)).inc()
            self.metrics.request_seconds.labels(route).observe(time.perf_counter() - began)


def _route_label(scope: Scope) -> str:
    """The path template of the route that answered (bounded label values), or 'unmatched'."""
    route = scope.get("route")
    if route is None:  # routes that do not record themselves in the scope (e.g. /openapi.json)
        routes = getattr(getattr(scope.get("app"), "router", None), "routes", ())
        route = next((r for r in routes if r.matches(scope)[0] is Match.FULL), None)
    return getattr(route, "path", None) or "unmatched"
