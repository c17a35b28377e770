"""The viewer page as files and HTTP, without a browser: what ``GET /`` serves, that it loads
nothing from elsewhere, its configuration, and ``POST /v1/detect/labels``."""

from __future__ import annotations

import re
from collections.abc import Iterator
from html.parser import HTMLParser

import cv2
import httpx
import numpy as np
import pytest

from service.http import Settings
from service.http.viewer import STATIC, static_files
from service.perception import detect_full, render_labels
from service.synthetic import make_scene

from .test_http import assert_error, encode, running_server

TOKEN = "viewer-test-token-77"


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    with running_server(Settings(workers=1, zenoh=False)) as base:
        yield base


class _References(HTMLParser):
    """Every URL an HTML page names in src, href or action."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.urls += [value for name, value in attrs if name in ("src", "href", "action") and value]


def page_references(html: str) -> list[str]:
    parser = _References()
    parser.feed(html)
    return parser.urls


def test_the_page_and_every_file_it_loads_are_served(server) -> None:
    page = httpx.get(f"{server}/")
    assert page.status_code == 200
    assert page.headers["content-type"] == "text/html; charset=utf-8"
    assert "default-src 'self'" in page.headers["content-security-policy"]
    assert 'type="file"' in page.text and 'data-testid="chain-count"' in page.text
    loaded = [url for url in page_references(page.text) if url.startswith("/viewer/")]
    modules = {
        f"/viewer/{name.removeprefix('./')}"
        for path in STATIC.glob("*.js")
        for name in re.findall(r'from "([^"]+)"', path.read_text())
    }
    assert {"/viewer/viewer.js", "/viewer/viewer.css", "/viewer/draw.js"} <= {*loaded, *modules}
    types = {".js": "text/javascript", ".css": "text/css", ".svg": "image/svg+xml"}
    for url in {*loaded, *modules}:
        response = httpx.get(f"{server}{url}")
        assert response.status_code == 200, url
        assert response.headers["content-type"].startswith(types[url[url.rindex(".") :]])


def test_the_page_loads_nothing_from_elsewhere() -> None:
    """No absolute URL in any of the page's files (an SVG's XML namespace is a name, not a
    load); links and imports are paths on this service. The browser tests also check every
    request the page makes."""
    absolute = re.compile(r"""\b(?:https?|wss?|ftp)://|["'(]//\w""", re.IGNORECASE)
    for name, path in static_files().items():
        text = re.sub(r'xmlns="http://www\.w3\.org/2000/svg"', "", path.read_text())
        assert not absolute.search(text), f"{name}: {absolute.search(text)}"
        # the one URL the scripts build: the live socket, on the page's own host
        for found in re.finditer("://", text):
            assert text[found.end() :].startswith("${location.host}/"), name
    html = (STATIC / "index.html").read_text()
    for url in page_references(html):
        assert url.startswith(("/", "#")) and not url.startswith("//"), url
    for path in STATIC.glob("*.js"):
        for module in re.findall(r'from "([^"]+)"', path.read_text()):
            assert module.startswith("./"), f"{path.name} imports {module}"


def test_only_the_page_files_can_be_fetched(server) -> None:
    assert httpx.get(f"{server}/viewer/viewer.js").status_code == 200
    for name in ("missing.js", "..%2Fviewer.py", "%2E%2E%2Fapp.py", "index.htm"):
        assert_error(httpx.get(f"{server}/viewer/{name}"), 404)
    assert httpx.get(f"{server}/viewer/../viewer.py").status_code == 404


def test_the_configuration_says_what_the_page_needs(server) -> None:
    config = httpx.get(f"{server}/viewer/config").json()
    assert config["token_required"] is False and config["zenoh"] is False
    assert config["defaults"]["segment_length"] == 10.0
    assert config["segmentation_methods"] == ["auto", "contrast", "brightness", "hsv"]
    with running_server(Settings(workers=1, zenoh=False, api_token=TOKEN)) as base:
        assert httpx.get(f"{base}/viewer/config").json()["token_required"] is True
        assert httpx.get(f"{base}/").status_code == 200  # the page itself stays open


def test_the_label_image_is_the_one_dlo_detect_writes(server) -> None:
    scene = make_scene(320, 240, 3, seed=11)
    png = encode(scene.image)
    response = httpx.post(
        f"{server}/v1/detect/labels?segment_length=12",
        content=png,
        headers={"Content-Type": "image/png"},
        timeout=60,
    )
    assert response.status_code == 200 and response.headers["content-type"] == "image/png"
    labels = cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert labels.dtype == np.uint16 and labels.shape == (240, 320)
    from schemas import DetectParams

    result = detect_full(scene.image, DetectParams(segment_length=12))
    np.testing.assert_array_equal(labels, render_labels(result.detection, result.mask, scene.image))
    detection = httpx.post(
        f"{server}/v1/detect?segment_length=12",
        content=png,
        headers={"Content-Type": "image/png"},
        timeout=60,
    ).json()
    assert set(np.unique(labels)) == {0, *range(1, len(detection["chains"]) + 1)}


def test_the_label_image_refuses_what_detect_refuses(server) -> None:
    url = f"{server}/v1/detect/labels"
    assert_error(httpx.post(url, content=b"x", headers={"Content-Type": "text/plain"}), 415)
    broken = encode(np.zeros((40, 40, 3), np.uint8))[:30]
    assert_error(httpx.post(url, content=broken, headers={"Content-Type": "image/png"}), 422)
    with running_server(Settings(workers=1, zenoh=False, api_token=TOKEN)) as base:
        png = encode(make_scene(160, 120, 1, seed=2).image)
        headers = {"Content-Type": "image/png"}
        assert_error(httpx.post(f"{base}/v1/detect/labels", content=png, headers=headers), 401)
        headers["Authorization"] = f"Bearer {TOKEN}"
        response = httpx.post(f"{base}/v1/detect/labels", content=png, headers=headers, timeout=60)
        assert response.status_code == 200
