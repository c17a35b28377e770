"""What a hostile or careless client can cost the HTTP service, on a real uvicorn on loopback:
decompression bombs in any upload, a time budget per detection, hang-ups mid-upload,
over-long request targets and malformed requests (issue 20)."""

from __future__ import annotations

import json
import logging
import socket
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from service.bench.bombs import peak_rss_mb
from service.bench.rings import rings_image
from service.http import Settings
from tests.helpers import blank_png, dlo_serve, wait_until
from tests.service.test_http import assert_error, encode, running_server

EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples"
BOMB_SIDE = 30_000
"""A 1-bit PNG of 30000x30000 px: about 110 KB that decodes to 900 megapixels."""
MEMORY_ALLOWANCE_MB = 64.0
"""How much a refused bomb may raise the server's peak memory (decoding one: 900+ MB)."""


@pytest.fixture(scope="module")
def bomb() -> bytes:
    return blank_png(BOMB_SIDE, BOMB_SIDE)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")
def test_bombs_in_every_upload_are_refused_from_the_header(bomb: bytes, tmp_path: Path) -> None:
    """The image, the mask, /v1/grasp's mask and depth image: a 110 KB PNG that claims
    900 megapixels is refused before it is decoded, and the server's memory stays put."""
    small = encode(np.zeros((360, 640, 3), np.uint8))
    camera = (EXAMPLES / "camera.json").read_bytes()
    depth_camera = (EXAMPLES / "camera_depth.json").read_bytes()
    with dlo_serve(["--no-zenoh", "--workers", "1"], tmp_path / "serve.log") as (process, base):
        before = peak_rss_mb(process.pid)
        raw = httpx.post(f"{base}/v1/detect", content=bomb, headers={"Content-Type": "image/png"})
        assert_error(raw, 413, "image is 30000x30000", "megapixels")
        mask = httpx.post(
            f"{base}/v1/detect", files={"image": ("a.png", small), "mask": ("m.png", bomb)}
        )
        body = assert_error(mask, 413, "mask is 30000x30000", "megapixels")
        assert body["error"] == "mask_too_large"
        overlay = httpx.post(
            f"{base}/v1/detect/overlay",
            files={"image": ("a.png", small), "mask": ("m.png", bomb)},
        )
        assert_error(overlay, 413, "mask is 30000x30000")
        grasp_mask = httpx.post(
            f"{base}/v1/grasp",
            files={"image": ("a.png", small), "mask": ("m.png", bomb), "camera": camera},
        )
        assert_error(grasp_mask, 413, "mask is 30000x30000")
        grasp_depth = httpx.post(
            f"{base}/v1/grasp",
            files={"image": ("a.png", small), "depth": ("d.png", bomb), "camera": depth_camera},
        )
        assert grasp_depth.status_code in (413, 422), grasp_depth.text
        assert "30000x30000" in grasp_depth.json()["detail"]
        growth = peak_rss_mb(process.pid) - before
    assert growth < MEMORY_ALLOWANCE_MB, f"peak memory grew by {growth:.0f} MB"


def test_uploads_other_than_png_and_jpeg_are_refused_before_decoding() -> None:
    with running_server(Settings(workers=1, zenoh=False)) as base:
        image = encode(np.zeros((40, 60, 3), np.uint8))
        for suffix, kind in ((".bmp", "BMP"), (".tiff", "TIFF"), (".webp", "WebP")):
            other = encode(np.zeros((40, 60, 3), np.uint8), suffix)
            response = httpx.post(
                f"{base}/v1/detect", files={"image": ("a.png", image), "mask": ("m", other)}
            )
            assert_error(response, 415, "mask", kind.lower(), "png and jpeg")
        wrong_size = httpx.post(
            f"{base}/v1/detect",
            files={"image": ("a.png", image), "mask": ("m.png", blank_png(61, 40, 8))},
        )
        assert_error(wrong_size, 422, "mask is 61x40 but the image is 60x40")
        text = httpx.post(
            f"{base}/v1/detect", files={"image": ("a.png", image), "mask": ("m", b"hello")}
        )
        assert_error(text, 422, "mask", "not an image", "png and jpeg")


def test_a_detection_past_its_budget_is_stopped_and_the_worker_is_free_again() -> None:
    """One worker, no queue: the rings scene (seconds of work) runs past a 0.5 s budget
    and gets 422 time_budget_exceeded; the next request is served by the freed worker."""
    settings = Settings(workers=1, queue_size=0, max_detect_seconds=0.5, zenoh=False)
    heavy = encode(rings_image(4_000))
    with running_server(settings) as base:
        response = httpx.post(
            f"{base}/v1/detect", content=heavy, headers={"Content-Type": "image/png"}
        )
        body = assert_error(response, 422, "budget of 0.5 s", "dlo_max_detect_seconds")
        assert body["error"] == "time_budget_exceeded"
        light = encode(rings_image(4))
        after = httpx.post(
            f"{base}/v1/detect", content=light, headers={"Content-Type": "image/png"}
        )
        assert after.status_code == 200, after.text
        assert len(after.json()["chains"]) == 4
        metrics = httpx.get(f"{base}/metrics").text
        assert "dlo_detection_over_budget_total 1.0" in metrics
        assert 'route="/v1/detect",status="422"' in metrics


def test_a_client_hanging_up_mid_upload_is_499_on_one_info_line(caplog) -> None:
    caplog.set_level(logging.INFO, logger="service.http")
    with running_server(Settings(workers=1, zenoh=False)) as base:
        port = int(base.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port)) as client:
            client.sendall(
                b"POST /v1/detect HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                b"Content-Type: image/png\r\nContent-Length: 1000000\r\n\r\n" + b"\x89PNG" * 1000
            )
        wait_until(
            lambda: 'route="/v1/detect",status="499"} 1.0' in httpx.get(f"{base}/metrics").text,
            "the hang-up to be counted as 499",
        )
        metrics = httpx.get(f"{base}/metrics").text
    assert 'status="500"' not in metrics
    ours = [record for record in caplog.records if record.name.startswith("service.http")]
    closed = [record for record in ours if "closed the connection" in record.getMessage()]
    assert len(closed) == 1
    assert closed[0].levelno == logging.INFO and closed[0].exc_info is None
    assert "\n" not in closed[0].getMessage()
    assert not [record for record in ours if record.levelno >= logging.WARNING]


def raw_exchange(port: int, request: bytes) -> tuple[str, dict]:
    """Send ``request`` as is (httpx refuses URLs over 64 KiB); the head and JSON body."""
    with socket.create_connection(("127.0.0.1", port)) as client:
        client.sendall(request)
        reply = b""
        while chunk := client.recv(65536):
            reply += chunk
    head, _, payload = reply.decode().partition("\r\n\r\n")
    return head, json.loads(payload)


def test_over_long_request_targets_get_json_errors_with_a_request_id() -> None:
    with running_server(Settings(workers=1, zenoh=False)) as base:
        port = int(base.rsplit(":", 1)[1])
        for length in (20_000, 70_000):  # past the limit; past the HTTP parser's own
            head, body = raw_exchange(
                port,
                f"POST /v1/detect?segment_length={'9' * length} HTTP/1.1\r\nHost: x\r\n"
                "Content-Type: image/png\r\nContent-Length: 1\r\n"
                "Connection: close\r\n\r\nx".encode(),
            )
            assert head.startswith("HTTP/1.1 414"), head
            assert body["error"] == "uri_too_long" and body["status"] == 414
            assert "limit of 8192" in body["detail"]
            assert f"x-request-id: {body['request_id']}" in head.lower()
            assert len(json.dumps(body)) < 400  # the value is not echoed back
        long_value = "x" * 5_000  # within the limit: 422, the value shown cut short
        for query, words in (
            (f"segment_length={long_value}", ("segment_length", "valid number")),
            (f"{long_value}=1", ("unknown parameter",)),
        ):
            response = httpx.post(
                f"{base}/v1/detect?{query}", content=b"x", headers={"Content-Type": "image/png"}
            )
            assert_error(response, 422, *words)
            assert len(response.text) < 400
        head, body = raw_exchange(port, b"NOT HTTP AT ALL\r\n\r\n")
        assert head.startswith("HTTP/1.1 400")
        assert body["status"] == 400 and body["error"] == "bad_request"
        assert f"x-request-id: {body['request_id']}" in head.lower()


def test_image_with_mask_checks_sizes_before_decoding_either() -> None:
    """A mask whose header declares another size than the image's is refused at once."""
    with running_server(Settings(workers=1, zenoh=False)) as base:
        image = cv2.imencode(".jpg", np.zeros((30, 50, 3), np.uint8))[1].tobytes()
        response = httpx.post(
            f"{base}/v1/detect",
            files={"image": ("a.jpg", image), "mask": ("m.png", blank_png(5000, 5000))},
        )
        assert_error(response, 422, "mask is 5000x5000 but the image is 50x30")
