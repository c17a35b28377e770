"""The HTTP service, through a real uvicorn server on a loopback port, talked to with httpx."""

from __future__ import annotations

import contextlib
import logging
import os
import re
import subprocess
import sys
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import cv2
import httpx
import numpy as np
import pytest
import uvicorn
from fastapi import FastAPI

from schemas import Detection, DetectParams
from service.http import Settings, create_app
from service.http.server import uvicorn_options
from service.perception import detect as real_detect
from service.runtime.frames import image_size
from service.synthetic import make_scene
from tests.helpers import free_port, wait_until

WIDTH, HEIGHT = 480, 320
READY_TIMEOUT_S = 120.0
"""A first run on a machine compiles the numba kernels before the service is ready."""


@contextlib.contextmanager
def running_server(settings: Settings, detect=None, wait_ready: bool = True) -> Iterator[str]:
    """Serve ``create_app(settings, detect)`` on a free loopback port; yields its base URL."""
    with serving(create_app(settings, detect), wait_ready) as base:
        yield base


@contextlib.contextmanager
def serving(app: FastAPI, wait_ready: bool = True) -> Iterator[str]:
    """Serve ``app`` with uvicorn, set up as ``dlo serve`` does, on a free loopback port;
    yields its base URL."""
    config = uvicorn.Config(app, **uvicorn_options("127.0.0.1", 0, "warning"))
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    wait_until(lambda: server.started or not thread.is_alive(), "the server to start", 30)
    assert server.started, "the server thread ended before it started serving"
    port = server.servers[0].sockets[0].getsockname()[1]
    base = f"http://127.0.0.1:{port}"
    assert httpx.get(f"{base}/healthz").status_code == 200
    if wait_ready:
        wait_until_ready(base)
    try:
        yield base
    finally:
        server.should_exit = True
        thread.join(timeout=10)


def wait_until_ready(base: str) -> None:
    """Until /readyz answers 200."""
    wait_until(
        lambda: httpx.get(f"{base}/readyz").status_code == 200,
        "the service to become ready",
        READY_TIMEOUT_S,
    )


def answers(url: str) -> bool:
    """True when a GET of ``url`` gets 200 (False while nothing listens)."""
    with contextlib.suppress(httpx.TransportError):
        return httpx.get(url).status_code == 200
    return False


def encode(array: np.ndarray, suffix: str = ".png") -> bytes:
    ok, data = cv2.imencode(suffix, array)
    assert ok
    return data.tobytes()


def assert_error(response: httpx.Response, status: int, *words: str) -> dict:
    """The response is a JSON error of ``status`` whose message holds ``words``."""
    assert response.status_code == status, response.text
    body = response.json()
    assert body["status"] == status
    assert body["request_id"] == response.headers["x-request-id"]
    for word in words:
        assert word in body["detail"].lower(), body["detail"]
    assert "traceback" not in response.text.lower()
    return body


@pytest.fixture(scope="module")
def scene():
    return make_scene(WIDTH, HEIGHT, 2, seed=1)


@pytest.fixture(scope="module")
def png(scene) -> bytes:
    return encode(scene.image)


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    with running_server(Settings(workers=2, queue_size=4)) as base:
        yield base


class Controls:
    """A detect function the tests can make block or fail."""

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.gate.set()
        self.fail = False
        self.calls = 0

    def detect(self, image, params, mask, deadline) -> Detection:
        self.calls += 1
        if self.fail:
            raise RuntimeError("injected failure")
        assert self.gate.wait(timeout=10), "test gate never opened"
        return real_detect(image, params, mask, deadline=deadline)


# --- detection --------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix, media_type", [(".png", "image/png"), (".jpg", "image/jpeg")])
def test_detect_raw_body_returns_a_detection(server, scene, suffix, media_type) -> None:
    response = httpx.post(
        f"{server}/v1/detect?segment_length=12&expected_count=2",
        content=encode(scene.image, suffix),
        headers={"Content-Type": media_type},
    )
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "application/json"
    assert response.headers["x-request-id"]
    detection = Detection.model_validate_json(response.content)
    assert (detection.width, detection.height) == (WIDTH, HEIGHT)
    assert detection.segment_length == 12
    assert detection.chains


def test_detect_multipart_with_mask(server, scene, png) -> None:
    mask = encode(scene.mask.astype(np.uint8) * 255)
    response = httpx.post(
        f"{server}/v1/detect",
        files={"image": ("scene.png", png, "image/png"), "mask": ("mask.png", mask, "image/png")},
    )
    assert response.status_code == 200, response.text
    detection = Detection.model_validate_json(response.content)
    assert detection.chains
    assert detection.segment_length == DetectParams().segment_length


def test_overlay_is_a_png_of_the_image_size(server, png) -> None:
    response = httpx.post(
        f"{server}/v1/detect/overlay", content=png, headers={"Content-Type": "image/png"}
    )
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "image/png"
    overlay = cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert overlay.shape == (HEIGHT, WIDTH, 3)


def test_hsv_bounds_as_repeated_or_comma_separated_query_fields(server, png) -> None:
    for query in (
        "segmentation=hsv&hsv_low=0&hsv_low=0&hsv_low=60&hsv_high=179,255,255",
        "segmentation=hsv&hsv_low=0,0,60",
    ):
        response = httpx.post(
            f"{server}/v1/detect?{query}", content=png, headers={"Content-Type": "image/png"}
        )
        assert response.status_code == 200, (query, response.text)


# --- client errors ----------------------------------------------------------------------------


@pytest.mark.parametrize("media_type", ["text/plain", "application/json", "image/gif", None])
def test_other_content_types_are_415(server, png, media_type) -> None:
    headers = {} if media_type is None else {"Content-Type": media_type}
    response = httpx.post(f"{server}/v1/detect", content=png, headers=headers)
    assert_error(response, 415, "content-type", "image/png")


def test_unreadable_images_are_422_saying_why(server, png) -> None:
    cases = {
        b"": "empty",
        b"this is not an image at all" * 20: "not an image",
        png[: len(png) // 2]: "truncated png",
        encode(np.zeros((50, 50, 3), np.uint8), ".jpg")[:300]: "truncated jpeg",
    }
    for body, words in cases.items():
        for media_type in ("image/png", "image/jpeg"):
            response = httpx.post(
                f"{server}/v1/detect", content=body, headers={"Content-Type": media_type}
            )
            assert_error(response, 422, "image", words)


@pytest.mark.parametrize(
    "query, words",
    [
        ("segment_length=0", ["segment_length", "greater than 0.5"]),
        ("segment_length=abc", ["segment_length", "number"]),
        ("expected_count=0", ["expected_count"]),
        ("segment_length=10&segment_length=12", ["segment_length", "2 times"]),
        ("segmentaton=hsv", ["segmentaton", "unknown parameter"]),
        ("segmentation=magic", ["segmentation"]),
        ("hsv_low=0,80", ["hsv_low"]),
        ("hsv_low=50,0,0&hsv_high=20,255,255", ["exceeds"]),
    ],
)
def test_bad_parameters_are_422(server, png, query, words) -> None:
    response = httpx.post(
        f"{server}/v1/detect?{query}", content=png, headers={"Content-Type": "image/png"}
    )
    assert_error(response, 422, "invalid parameters", *words)


def test_bad_masks_and_forms_are_422(server, scene, png) -> None:
    small_mask = encode(np.full((HEIGHT // 2, WIDTH // 2), 255, np.uint8))
    empty_mask = encode(np.zeros((HEIGHT, WIDTH), np.uint8))
    cases = [
        ({"image": png, "mask": small_mask}, ["mask", "240x160", "480x320"]),
        ({"image": png, "mask": empty_mask}, ["mask", "empty"]),
        ({"image": png, "mask": b"garbage"}, ["mask", "not an image"]),
        ({"image": png, "mask": b""}, ["mask", "empty"]),
        ({"mask": empty_mask}, ["no 'image'"]),
        ({"image": png, "picture": png}, ["unexpected", "picture"]),
        ({"image": b"\x89PNG\r\n\x1a\n"}, ["image", "truncated png"]),
    ]
    for fields, words in cases:
        files = {name: (f"{name}.png", data, "image/png") for name, data in fields.items()}
        response = httpx.post(f"{server}/v1/detect", files=files)
        assert_error(response, 422, *words)


def test_unknown_routes_and_methods_get_json_errors(server) -> None:
    assert_error(httpx.get(f"{server}/v2/nothing"), 404)
    assert_error(httpx.get(f"{server}/v1/detect"), 405)


def test_limits_are_413() -> None:
    settings = Settings(workers=1, max_body_mb=0.05, max_megapixels=0.1)
    with running_server(settings) as base:
        wide = encode(np.zeros((400, 400, 3), np.uint8))  # 0.16 MP in a tiny file
        for suffix, media_type in ((".png", "image/png"), (".jpg", "image/jpeg")):
            body = encode(np.zeros((400, 400, 3), np.uint8), suffix)
            response = httpx.post(
                f"{base}/v1/detect", content=body, headers={"Content-Type": media_type}
            )
            assert_error(response, 413, "400x400", "megapixels")
        # WebP: its size is not read from the header, so it is not taken at all
        webp = encode(np.zeros((400, 400, 3), np.uint8), ".webp")
        response = httpx.post(f"{base}/v1/detect", files={"image": ("wide.webp", webp)})
        assert_error(response, 415, "webp", "png and jpeg")

        big = np.random.default_rng(0).integers(0, 255, 100_000, np.uint8).tobytes()
        response = httpx.post(
            f"{base}/v1/detect", content=big, headers={"Content-Type": "image/png"}
        )
        assert_error(response, 413, "body", "larger than the limit")
        chunked = httpx.post(
            f"{base}/v1/detect",
            content=iter([big[:40_000], big[40_000:]]),
            headers={"Content-Type": "image/png"},
        )
        assert_error(chunked, 413, "body")
        response = httpx.post(f"{base}/v1/detect/overlay", files={"image": ("w.png", wide)})
        assert_error(response, 413, "megapixels")
        small = encode(np.zeros((100, 100, 3), np.uint8))
        response = httpx.post(
            f"{base}/v1/detect", content=small, headers={"Content-Type": "image/png"}
        )
        assert response.status_code == 200, response.text


@pytest.mark.parametrize(
    "suffix, flags",
    [(".png", []), (".jpg", []), (".jpg", [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]), (".webp", [])],
)
def test_image_size_from_headers(suffix, flags) -> None:
    ok, data = cv2.imencode(suffix, np.zeros((40, 30, 3), np.uint8), flags)
    assert ok
    expected = None if suffix == ".webp" else (30, 40)
    assert image_size(data.tobytes()) == expected
    assert image_size(data.tobytes()[:5]) is None


# --- service behaviour ------------------------------------------------------------------------


def test_health_ready_docs(server) -> None:
    assert httpx.get(f"{server}/healthz").json() == {"status": "ok"}
    assert httpx.get(f"{server}/readyz").json() == {"status": "ready"}
    assert httpx.get(f"{server}/docs").status_code == 200
    schema = httpx.get(f"{server}/openapi.json").json()
    detect = schema["paths"]["/v1/detect"]["post"]
    assert {"segment_length", "expected_count", "hsv_low"} <= {
        parameter["name"] for parameter in detect["parameters"]
    }
    assert {"image/jpeg", "image/png", "multipart/form-data"} <= set(
        detect["requestBody"]["content"]
    )
    assert "/v1/detect/overlay" in schema["paths"]


def test_readyz_is_503_until_the_warm_up_detection_is_done() -> None:
    controls = Controls()
    controls.gate.clear()
    with running_server(Settings(workers=1), controls.detect, wait_ready=False) as base:
        response = httpx.get(f"{base}/readyz")
        assert response.status_code == 503
        assert response.json()["status"] == "warming up"
        controls.gate.set()
        wait_until_ready(base)


def test_metrics_count_requests_stages_and_drops(server, png) -> None:
    httpx.post(f"{server}/v1/detect", content=png, headers={"Content-Type": "image/png"})
    httpx.post(f"{server}/v1/detect", content=b"", headers={"Content-Type": "image/png"})
    response = httpx.get(f"{server}/metrics")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/plain")
    text = response.text
    assert re.search(
        r'dlo_http_requests_total\{[^}]*route="/v1/detect"[^}]*status="200"\} [1-9]', text
    )
    assert re.search(
        r'dlo_http_requests_total\{[^}]*route="/v1/detect"[^}]*status="422"\} [1-9]', text
    )
    for stage in ("segmentation", "skeleton", "merging", "total"):
        assert re.search(rf'dlo_detection_stage_seconds_count\{{stage="{stage}"\}} [1-9]', text)
    assert "dlo_frames_dropped_total 0.0" in text
    assert "dlo_ready 1.0" in text


def metric(base: str, name: str) -> float:
    text = httpx.get(f"{base}/metrics").text
    match = re.search(rf"^{re.escape(name)} (\S+)$", text, re.MULTILINE)
    assert match, name
    return float(match.group(1))


def test_full_pool_and_queue_answer_503_at_once(png) -> None:
    controls = Controls()
    with running_server(Settings(workers=1, queue_size=1), controls.detect) as base:
        controls.gate.clear()
        url = f"{base}/v1/detect"
        headers = {"Content-Type": "image/png"}
        with ThreadPoolExecutor(2) as clients:
            # one request runs (blocked in detect), one waits in the queue
            held = [clients.submit(httpx.post, url, content=png, headers=headers, timeout=20)]
            held.append(clients.submit(httpx.post, url, content=png, headers=headers, timeout=20))
            wait_until(
                lambda: metric(base, "dlo_detections_in_flight") == 2,
                "the two requests to be admitted",
            )
            # Answered while both admitted requests are still held at the gate: refused
            # at once, not queued until a slot frees (that would wait for gate.set()).
            refused = httpx.post(url, content=png, headers=headers)
            assert not any(future.done() for future in held)
            assert_error(refused, 503, "busy")
            assert refused.headers["retry-after"] == "1"
            assert metric(base, "dlo_frames_dropped_total") == 1
            controls.gate.set()
            assert [future.result().status_code for future in held] == [200, 200]
        assert metric(base, "dlo_detections_in_flight") == 0
        response = httpx.post(url, content=png, headers=headers)
        assert response.status_code == 200


def test_a_failing_detection_is_500_with_request_id_and_the_server_goes_on(
    png, caplog: pytest.LogCaptureFixture
) -> None:
    controls = Controls()
    with running_server(Settings(workers=1), controls.detect) as base:
        controls.fail = True
        with caplog.at_level(logging.ERROR):
            response = httpx.post(
                f"{base}/v1/detect", content=png, headers={"Content-Type": "image/png"}
            )
        body = assert_error(response, 500, "internal error")
        assert "injected failure" not in response.text
        assert body["request_id"] in body["detail"]
        logged = [record for record in caplog.records if body["request_id"] in record.getMessage()]
        assert logged and logged[0].exc_info is not None  # traceback in the server log only
        assert metric(base, "dlo_detection_failures_total") == 1

        controls.fail = False
        response = httpx.post(
            f"{base}/v1/detect/overlay", content=png, headers={"Content-Type": "image/png"}
        )
        assert response.status_code == 200
        assert response.headers["x-request-id"] != body["request_id"]


# --- dlo serve --------------------------------------------------------------------------------


def test_dlo_serve_runs_the_service(png) -> None:
    port = free_port()
    command = [sys.executable, "-c", "from service.cli import main; main()", "serve"]
    process = subprocess.Popen(
        [*command, "--port", str(port), "--workers", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env={**os.environ, "DLO_QUEUE_SIZE": "2", "DLO_LOG_LEVEL": "WARNING"},
    )
    try:
        base = f"http://127.0.0.1:{port}"
        wait_until(
            lambda: process.poll() is not None or answers(f"{base}/healthz"),
            "dlo serve to come up",
            READY_TIMEOUT_S,
        )
        assert process.poll() is None, process.stdout.read().decode()
        wait_until_ready(base)
        response = httpx.post(
            f"{base}/v1/detect?segment_length=10",
            content=png,
            headers={"Content-Type": "image/png"},
        )
        assert response.status_code == 200
        assert Detection.model_validate_json(response.content).chains
    finally:
        process.terminate()
        process.wait(timeout=10)


def test_dlo_serve_rejects_bad_settings_without_a_traceback() -> None:
    command = [sys.executable, "-c", "from service.cli import main; main()", "serve"]
    result = subprocess.run(
        [*command, "--workers", "0"], capture_output=True, text=True, timeout=30
    )
    assert result.returncode == 2
    assert "workers" in result.stderr and "greater than or equal to 1" in result.stderr
    assert "Traceback" not in result.stderr
