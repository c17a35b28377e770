"""Request ids, request metrics and the last-resort 500, as one plain ASGI middleware."""

from __future__ import annotations

import json
import logging
import time
import uuid

from starlette.datastructures import MutableHeaders
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.runtime.metrics import Metrics

logger = logging.getLogger(__name__)

REQUEST_ID_HEADER = "X-Request-ID"


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
    and the server goes on serving.
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

        began = time.perf_counter()
        try:
            await self.app(scope, receive, send_with_id)
        except Exception:
            logger.exception(
                "request %s (%s %s) failed", request_id, scope["method"], scope["path"]
            )
            if not started:
                payload = error_payload(
                    500,
                    "internal_error",
                    f"internal error; quote request id {request_id} when reporting it",
                    request_id,
                )
                body = json.dumps(payload).encode("utf-8")
                await send_with_id(
                    {
                        "type": "http.response.start",
                        "status": 500,
                        "headers": [
                            (b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                        ],
                    }
                )
                await send_with_id({"type": "http.response.body", "body": body})
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
