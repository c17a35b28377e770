"""How ``dlo serve`` runs the app in uvicorn (:func:`uvicorn_options`), with an HTTP/1.1
protocol whose every answer is JSON.

uvicorn answers a request its parser rejects with a plain-text 400 before the app sees it,
and a request target over 64 KiB (a long query string) is such a request. This protocol
(uvicorn's httptools one, which ``dlo serve`` uses anyway) keeps only the first
:data:`MAX_TARGET_BYTES` of a longer target, so the request still reaches the app, which
refuses it with a JSON 414 holding a request id (:mod:`service.http.middleware`); and what
the parser still rejects gets a JSON 400 with a request id too.
"""

from __future__ import annotations

import json
import uuid
from typing import Any

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

MAX_TARGET_BYTES = 8192
"""The longest request target (path and query) served; longer: 414 (as nginx, 8 KiB)."""
TARGET_LENGTH_KEY = "dlo.target_bytes"
"""Scope key holding the length of a request target cut at :data:`MAX_TARGET_BYTES`."""


class JsonErrorsProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol, with over-long targets passed on cut, and JSON 400s."""

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._target_bytes = 0

    def on_url(self, url: bytes) -> None:
        self._target_bytes += len(url)
        room = MAX_TARGET_BYTES + 1 - len(self.url)
        if room > 0:
            self.url += url[:room]

    def on_headers_complete(self) -> None:
        if self._target_bytes > MAX_TARGET_BYTES:
            # The path alone when it fits (so the route is still known), and the length
            # for the app's 414.
            path = self.url.split(b"?", 1)[0][:MAX_TARGET_BYTES]
            self.url = path if path.startswith(b"/") else b"/"
            self.scope[TARGET_LENGTH_KEY] = self._target_bytes  # type: ignore[typeddict-unknown-key]
        super().on_headers_complete()

    def send_400_response(self, msg: str) -> None:
        request_id = str(uuid.uuid4())
        body = json.dumps(
            {
                "status": 400,
                "error": "bad_request",
                "detail": f"malformed HTTP request: {msg}",
                "request_id": request_id,
            }
        ).encode()
        head = [b"HTTP/1.1 400 Bad Request\r\n"]
        for name, value in self.server_state.default_headers:
            head.append(name + b": " + value + b"\r\n")
        head += [
            b"content-type: application/json\r\n",
            b"content-length: " + str(len(body)).encode("ascii") + b"\r\n",
            b"x-request-id: " + request_id.encode("ascii") + b"\r\n",
            b"connection: close\r\n\r\n",
        ]
        self.transport.write(b"".join(head) + body)
        self.transport.close()


def uvicorn_options(host: str, port: int, log_level: str = "info") -> dict[str, Any]:
    """The keyword arguments ``dlo serve`` gives :func:`uvicorn.run` (tests serve the app
    with a :class:`uvicorn.Config` of the same)."""
    return {"host": host, "port": port, "log_level": log_level, "http": JsonErrorsProtocol}
