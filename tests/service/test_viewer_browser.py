"""The viewer page in a real browser: Debian's chromium driven by Playwright, against a real
service on loopback (and, for the live mode, a camera publishing on a loopback zenoh session).

Skipped, with the reason, when Playwright or chromium is missing, except in CI (``CI`` set),
where ``.ci/run`` installs chromium and a missing browser is a failure. Screenshots are kept
under ``out/viewer/`` for people to look at.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from service.browser import (
    browser_problem,
    chromium,
    detect_in_page,
    hover_chain,
    open_viewer,
)
from service.http import Settings
from service.synthetic import make_scene
from tests.helpers import DLO, free_port, wait_until

from .test_bus import client_of
from .test_http import Controls, running_server

pytestmark = pytest.mark.browser

ROOT = Path(__file__).resolve().parents[2]
SHOTS = ROOT / "out" / "viewer"
TOKEN = "browser-test-token-4d1"
TIMEOUT_MS = 60_000
"""Generous for a loaded 2-core machine; every wait ends as soon as its condition holds."""


@pytest.fixture(scope="module")
def browser():
    problem = browser_problem()
    if problem is not None:
        if os.environ.get("CI"):
            pytest.fail(f"CI needs the browser tests: {problem} (.ci/run installs chromium)")
        pytest.skip(problem)
    with chromium() as launched:
        yield launched


@pytest.fixture(scope="module")
def service() -> Iterator[tuple[str, str]]:
    """A service with zenoh on a free loopback port: its base URL and zenoh endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with running_server(Settings(workers=2, zenoh_listen=[endpoint])) as base:
        yield base, endpoint


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory) -> Path:
    scene = make_scene(640, 480, 3, seed=100_218)
    path = tmp_path_factory.mktemp("viewer") / "cables.png"
    cv2.imwrite(str(path), scene.image)
    return path


def detect_over_http(base: str, image: Path, **headers: str) -> dict:
    response = httpx.post(
        f"{base}/v1/detect",
        content=image.read_bytes(),
        headers={"Content-Type": "image/png", **headers},
        timeout=60,
    )
    assert response.status_code == 200, response.text
    return response.json()


def lonely_joint(detection: dict, chain: dict) -> tuple[float, float]:
    """The joint of ``chain`` farthest from every other chain (so that hovering it can only
    mean this chain)."""
    others = np.array(
        [p for c in detection["chains"] if c["id"] != chain["id"] for p in c["points"]]
    )
    points = np.array(chain["points"][1:-1])
    if not len(others):
        return tuple(points[len(points) // 2])
    distances = np.linalg.norm(points[:, None, :] - others[None, :, :], axis=2).min(axis=1)
    return tuple(points[int(distances.argmax())])


def canvas_is_drawn(page, test_id: str) -> bool:
    """True when the canvas holds more than one colour (never a blank canvas)."""
    return page.get_by_test_id(test_id).evaluate(
        """(canvas) => {
            const { width, height } = canvas;
            const data = canvas.getContext("2d").getImageData(0, 0, width, height).data;
            for (let i = 4; i < data.length; i += 4) {
                const same = data[i] === data[0] && data[i + 1] === data[1];
                if (!same || data[i + 2] !== data[2]) return true;
            }
            return false;
        }"""
    )


def only_this_service(page, base: str) -> list[str]:
    """Every request the page makes from now on whose URL is not on ``base``."""
    elsewhere: list[str] = []
    host = base.removeprefix("http://")
    page.on(
        "request",
        lambda request: (
            None
            if re.match(rf"^(https?|wss?)://{re.escape(host)}/", request.url)
            or request.url.startswith(("blob:", "data:"))
            else elsewhere.append(request.url)
        ),
    )
    return elsewhere


# --- the image mode ------------------------------------------------------------------------------


def test_an_uploaded_scene_shows_its_chains(browser, service, scene_file, tmp_path) -> None:
    from playwright.sync_api import expect

    base, _ = service
    expected = detect_over_http(base, scene_file)
    page, problems = open_viewer(browser, base)
    elsewhere = only_this_service(page, base)
    try:
        assert detect_in_page(page, scene_file, TIMEOUT_MS) == len(expected["chains"])
        rows = page.get_by_test_id("chains-table").locator("tbody tr")
        expect(rows).to_have_count(len(expected["chains"]))
        expect(page.get_by_test_id("timings-table").locator("tbody tr")).to_have_count(8)
        assert canvas_is_drawn(page, "image-canvas")

        longest = max(expected["chains"], key=lambda chain: len(chain["points"]))
        text = hover_chain(page, lonely_joint(expected, longest))
        assert f"chain {longest['id']}" in text
        assert f"{len(longest['points'])} joints" in text and "% inferred" in text
        expect(rows.locator(f"xpath=self::tr[@data-chain='{longest['id']}']")).to_have_class(
            "highlight"
        )
        SHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SHOTS / "image.png"))

        with page.expect_download() as download:
            page.click("#download-json")
        saved = json.loads(Path(download.value.path()).read_text())
        assert saved["chains"] == expected["chains"]
        assert download.value.suggested_filename == "cables.json"
        with page.expect_download() as download:
            page.click("#download-labels")
        labels = cv2.imread(download.value.path(), cv2.IMREAD_UNCHANGED)
        assert download.value.suggested_filename == "cables.labels.png"
        assert labels.dtype == np.uint16 and labels.shape == (480, 640)
        assert int(labels.max()) == len(expected["chains"])
        assert problems == []
        assert elsewhere == []
    finally:
        page.close()


def message_of(page, test_id: str = "image-message"):
    from playwright.sync_api import expect

    message = page.locator(f"#{test_id}")
    expect(message).to_be_visible()
    return message


def test_errors_read_as_messages_never_a_blank_canvas(browser, service, tmp_path) -> None:
    from playwright.sync_api import expect

    base, _ = service
    page, _ = open_viewer(browser, base)
    try:
        text_file = tmp_path / "notes.txt"
        text_file.write_text("not an image")
        page.set_input_files("input[type=file]", str(text_file))
        expect(message_of(page)).to_contain_text("415")
        expect(message_of(page)).to_contain_text("text/plain")
        assert canvas_is_drawn(page, "image-canvas")
        expect(page.get_by_test_id("chain-count")).to_have_text("")

        broken = tmp_path / "broken.png"
        good = cv2.imencode(".png", make_scene(200, 150, 1, seed=3).image)[1].tobytes()
        broken.write_bytes(good[: len(good) // 2])
        page.set_input_files("input[type=file]", str(broken))
        expect(message_of(page)).to_contain_text("422")
        expect(message_of(page)).to_contain_text("image")
        assert canvas_is_drawn(page, "image-canvas")

        page.fill("#segment-length", "0.1")  # below the minimum: the form says so first
        page.click("#detect-button")
        assert page.locator("#segment-length").evaluate("(input) => !input.validity.valid")
    finally:
        page.close()


def test_too_large_busy_and_unauthorized_read_as_messages(browser, scene_file) -> None:
    from playwright.sync_api import expect

    small = Settings(workers=1, zenoh=False, max_megapixels=0.1)
    with running_server(small) as base:
        page, _ = open_viewer(browser, base)
        page.set_input_files("input[type=file]", str(scene_file))
        expect(message_of(page)).to_contain_text("413", timeout=TIMEOUT_MS)
        expect(message_of(page)).to_contain_text("megapixels")
        assert canvas_is_drawn(page, "image-canvas")  # the image, dimmed, with the message
        page.close()

    controls = Controls()
    with running_server(Settings(workers=1, queue_size=0, zenoh=False), controls.detect) as base:
        controls.gate.clear()
        with ThreadPoolExecutor(1) as client:
            held = client.submit(
                httpx.post,
                f"{base}/v1/detect",
                content=scene_file.read_bytes(),
                headers={"Content-Type": "image/png"},
                timeout=60,
            )
            wait_until(lambda: controls.calls == 1, "the worker to be taken")
            page, _ = open_viewer(browser, base)
            page.set_input_files("input[type=file]", str(scene_file))
            expect(message_of(page)).to_contain_text("503", timeout=TIMEOUT_MS)
            expect(message_of(page)).to_contain_text("retry")
            controls.gate.set()
            assert held.result().status_code == 200
            page.close()

    with running_server(Settings(workers=1, zenoh=False, api_token=TOKEN)) as base:
        page, _ = open_viewer(browser, base)
        expect(page.locator("#token-form")).to_be_visible()
        page.set_input_files("input[type=file]", str(scene_file))
        expect(message_of(page)).to_contain_text("401", timeout=TIMEOUT_MS)
        page.fill("[data-testid=token-input]", TOKEN)
        page.click("#token-form button")
        expected = detect_over_http(base, scene_file, Authorization=f"Bearer {TOKEN}")
        expect(page.get_by_test_id("chain-count")).to_have_text(
            str(len(expected["chains"])), timeout=TIMEOUT_MS
        )
        assert page.evaluate("() => sessionStorage.getItem('dlo-viewer-token')") == TOKEN
        page.close()


# --- the live mode -------------------------------------------------------------------------------


class Camera:
    """Publishes JPEG frames (with frame ids) on ``dlo/<name>/image`` at ``fps`` until stopped
    or ``limit`` frames, from a loopback zenoh session connected to the service."""

    def __init__(self, endpoint: str, name: str, frames: list[bytes], fps: float, limit: int):
        self.endpoint, self.name, self.frames = endpoint, name, frames
        self.period_s, self.limit = 1.0 / fps, limit
        self.stop = threading.Event()
        self.sent = 0

    def run(self) -> None:
        with client_of(self.endpoint) as session:
            publisher = session.declare_publisher(f"dlo/{self.name}/image")
            while not self.stop.is_set() and self.sent < self.limit:
                frame = self.frames[self.sent % len(self.frames)]
                publisher.put(frame, attachment=json.dumps({"frame_id": self.sent}))
                self.sent += 1
                self.stop.wait(self.period_s)  # the camera's clock, not a wait for a result


def test_the_live_mode_shows_the_frames_of_a_camera(browser, service, scene_file) -> None:
    from playwright.sync_api import expect

    base, endpoint = service
    expected = detect_over_http(base, scene_file)
    jpeg = cv2.imencode(".jpg", cv2.imread(str(scene_file)))[1].tobytes()
    camera = Camera(endpoint, "cell1-top", [jpeg], fps=15, limit=15 * 120)
    thread = threading.Thread(target=camera.run, daemon=True)
    page, problems = open_viewer(browser, base, "#live")
    elsewhere = only_this_service(page, base)
    thread.start()
    try:
        expect(page.get_by_test_id("camera-select")).to_have_value("cell1-top", timeout=TIMEOUT_MS)
        page.get_by_test_id("watch-button").click()
        expect(page.get_by_test_id("live-frames")).to_have_text(
            re.compile(r"^([3-9]\d|\d{3,})$"), timeout=TIMEOUT_MS
        )
        expect(page.get_by_test_id("live-chain-count")).to_have_text(str(len(expected["chains"])))
        expect(page.get_by_test_id("live-fps")).to_have_text(re.compile(r"^\d+\.\d$"))
        assert canvas_is_drawn(page, "live-canvas")
        assert page.locator("#live-pairing").inner_text() == "frame_id"
        SHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SHOTS / "live.png"))
        page.click("#stop-button")
        assert problems == []
        assert elsewhere == []
    finally:
        camera.stop.set()
        thread.join(timeout=10)
        page.close()


# --- the commands that drive the page ------------------------------------------------------------


def test_the_readme_screenshot_command(browser, tmp_path) -> None:
    """``dlo demo --viewer-screenshot`` (the README's picture) makes a picture of the page."""
    shot = tmp_path / "viewer.png"
    completed = subprocess.run(
        [*DLO, "demo", "--out-dir", str(tmp_path / "demo"), "--viewer-screenshot", str(shot)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    picture = cv2.imread(str(shot))
    assert picture is not None and picture.shape[1] == 1400


def test_the_viewer_benchmark_reports_what_the_page_did(browser) -> None:
    """``dlo bench --viewer`` (BENCHMARKS.md, "Viewer"): a short run, for the report's shape."""
    completed = subprocess.run(
        [*DLO, "bench", "--viewer", "--seconds", "2", "--json"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    report = json.loads(completed.stdout)
    assert report["frames_sent"] > 0 and report["frames_shown"] > 0
    assert report["heap_start_bytes"] > 0 and report["heap_end_bytes"] > 0
    assert report["page_problems"] == []
