"""The optional bearer token (``DLO_API_TOKEN`` or ``DLO_API_TOKEN_FILE``), as FastAPI
dependencies: :data:`API_TOKEN` on every data route (``/v1/*``, the viewer's among them;
its live WebSocket calls :func:`check_token`), :data:`METRICS_TOKEN` on ``/metrics`` (only
with ``DLO_PROTECT_METRICS``). ``/healthz`` and ``/readyz`` stay open for probes.

The token is compared in constant time (as SHA-256 digests, so that not even its length
leaks) and never written anywhere: errors say only that it is missing or wrong.
"""

from __future__ import annotations

import hashlib
import hmac

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.runtime.errors import RequestError

CHALLENGE = 'Bearer realm="dlo"'

_bearer = HTTPBearer(
    auto_error=False,  # a missing token is answered below, in the service's error shape
    description="The service's token (DLO_API_TOKEN), when it is set; otherwise none needed.",
)
_CREDENTIALS = Depends(_bearer)


def require_token(
    request: Request, credentials: HTTPAuthorizationCredentials | None = _CREDENTIALS
) -> None:
    """401 unless the request carries ``Authorization: Bearer <token>`` when one is set."""
    given = None if credentials is None else credentials.credentials
    check_token(request.app.state.dlo.api_token, given)


def check_token(expected: str | None, given: str | None) -> None:
    """401 (a :class:`RequestError`) unless ``given`` is the ``expected`` token, or no
    token is expected. For the transports that carry the token otherwise than in a
    header FastAPI reads (the viewer's live WebSocket)."""
    if expected is None:
        return
    if given is None or not given.strip():
        raise RequestError(
            401,
            "unauthorized",
            "a bearer token is required: send the header 'Authorization: Bearer <token>'",
            headers={"WWW-Authenticate": CHALLENGE},
        )
    if not _same(given.strip(), expected):
        raise RequestError(
            401,
            "unauthorized",
            "the bearer token is not the service's",
            headers={"WWW-Authenticate": f'{CHALLENGE}, error="invalid_token"'},
        )


def bearer_token(authorization: str | None) -> str | None:
    """The token of an ``Authorization: Bearer <token>`` header value (None: no bearer)."""
    scheme, _, token = (authorization or "").partition(" ")
    return token if scheme.lower() == "bearer" and token.strip() else None


def require_token_for_metrics(
    request: Request, credentials: HTTPAuthorizationCredentials | None = _CREDENTIALS
) -> None:
    """:func:`require_token`, when the settings protect ``/metrics`` too."""
    if request.app.state.dlo.settings.protect_metrics:
        require_token(request, credentials)


def _same(given: str, expected: str) -> bool:
    digest = hashlib.sha256
    return hmac.compare_digest(digest(given.encode()).digest(), digest(expected.encode()).digest())


API_TOKEN = Depends(require_token)
"""Add to a route's ``dependencies`` to require the token."""
METRICS_TOKEN = Depends(require_token_for_metrics)
