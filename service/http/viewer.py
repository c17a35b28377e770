"""The viewer page (``GET /``): plain HTML, CSS and JavaScript from ``static/`` beside this
module, served by the service itself (no build step, nothing fetched from elsewhere: it works
in a cell without internet), and ``GET /viewer/config``, what the page needs to know first.

The page's data comes from the ``/v1/*`` routes (``/v1/detect``, ``/v1/detect/labels``,
``/v1/live/*``), which need the bearer token when one is set; the page itself, its scripts
and its configuration are open, so that it can ask for the token. Its Content-Security-Policy
allows this origin only: even a changed script could not reach another host.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, JSONResponse

from schemas import DetectParams, SegmentationMethod
from service.runtime.errors import RequestError

STATIC = Path(__file__).with_name("static")
"""The page's files."""
MEDIA_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
}
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
    "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'none'; "
    "frame-ancestors 'none'"
)
"""This origin only (``connect-src 'self'`` covers its WebSocket too)."""
_HEADERS = {
    "Cache-Control": "no-cache",
    "Content-Security-Policy": CONTENT_SECURITY_POLICY,
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}

viewer = APIRouter(include_in_schema=False)


def static_files() -> dict[str, Path]:
    """Name -> path of every file the page may load (``/viewer/<name>``)."""
    return {
        path.name: path
        for path in sorted(STATIC.iterdir())
        if path.is_file() and path.suffix in MEDIA_TYPES
    }


def _file(path: Path) -> FileResponse:
    return FileResponse(path, media_type=MEDIA_TYPES[path.suffix], headers=_HEADERS)


@viewer.get("/")
async def page() -> FileResponse:
    """The viewer: upload an image or watch a camera, and see the chains."""
    return _file(STATIC / "index.html")


@viewer.get("/viewer/config")
async def config(request: Request) -> JSONResponse:
    """Whether a token is needed, whether the live mode can work, limits, defaults and the
    segmentation methods (``model`` only when the service has a segmenter model)."""
    state = request.app.state.dlo
    settings = state.settings
    return JSONResponse(
        {
            "token_required": state.api_token is not None,
            "zenoh": settings.zenoh,
            "max_body_bytes": settings.max_body_bytes,
            "max_pixels": settings.max_pixels,
            "defaults": DetectParams().model_dump(mode="json"),
            "segmentation_methods": [
                method.value
                for method in SegmentationMethod
                if method != SegmentationMethod.model or settings.segmenter_model is not None
            ],
        },
        headers={"Cache-Control": "no-cache"},
    )


@viewer.get("/viewer/{name}")
async def static(name: str) -> FileResponse:
    """One of the page's files (a fixed set: nothing else on disk can be reached)."""
    path = static_files().get(name)
    if path is None:
        raise RequestError(404, "not_found", f"the viewer has no file {name!r}")
    return _file(path)
