"""``dlo bench --viewer``: does the viewer's live mode keep up with a camera, and does the
page's memory stay flat?

On loopback: a ``dlo serve`` process (zenoh on a free loopback port), a camera in this
process publishing 640x480 JPEG frames of generated scenes on ``dlo/bench-cam/image`` at
15 fps with frame ids (a paced clock, as a camera's), and Debian's chromium (Playwright)
showing the page's live mode on that camera. After a warm-up, the run lasts ``seconds``;
the page's JS heap is measured after a forced garbage collection (Chrome DevTools Protocol)
at the start, every 10 s and at the end, with its DOM nodes and event listeners. The frame
rate and dropped frames are the ones the page itself shows, and the frames it drew are
counted over the run. ``cpu_slowdown`` > 1 slows the page's CPU that many times (Chrome's
CPU throttling), as a weak client would be: it then draws fewer frames, and the service's
back-pressure (latest wins) must keep its memory flat all the same.
"""

from __future__ import annotations

import json
import re
import threading
import time
from dataclasses import asdict, dataclass, field

import cv2

from service.bench.overhead import _dlo_serve
from service.browser import chromium, js_heap_bytes, open_viewer
from service.synthetic import make_scene

CAMERA = "bench-cam"
WIDTH, HEIGHT = 640, 480
SCENES = 30
"""Distinct frames the camera cycles through (2 s at 15 fps)."""
WARM_UP_S = 5.0
SAMPLE_EVERY_S = 10.0


@dataclass
class ViewerRun:
    """What the page did while watching the camera."""

    seconds: float
    cpu_slowdown: float
    camera_fps: float
    frames_sent: int
    frames_shown: int
    shown_per_second: float
    page_fps_shown: str
    """The frame rate the page displays at the end (its own rolling 2 s figure)."""
    page_dropped: int
    """Dropped frames the page counts since it began watching, warm-up included (frames of
    the camera it never drew), and what it says of them."""
    page_dropped_detail: str
    heap_start_bytes: float
    heap_end_bytes: float
    heap_max_bytes: float
    dom_nodes: tuple[float, float]
    event_listeners: tuple[float, float]
    heap_samples: list[tuple[float, float]] = field(default_factory=list)
    """(seconds into the run, JS heap in use after a collection)."""
    page_problems: list[str] = field(default_factory=list)


class _Camera:
    def __init__(self, session, frames: list[bytes], fps: float) -> None:
        self.publisher = session.declare_publisher(f"dlo/{CAMERA}/image")
        self.frames = frames
        self.period_s = 1.0 / fps
        self.stop = threading.Event()
        self.sent = 0

    def run(self) -> None:
        next_time = time.monotonic()
        while not self.stop.is_set():
            frame = self.frames[self.sent % len(self.frames)]
            self.publisher.put(frame, attachment=json.dumps({"frame_id": self.sent}))
            self.sent += 1
            next_time += self.period_s
            self.stop.wait(max(0.0, next_time - time.monotonic()))


def _frames() -> list[bytes]:
    frames = []
    for seed in range(SCENES):
        scene = make_scene(WIDTH, HEIGHT, 3, seed=200_000 + seed)
        ok, encoded = cv2.imencode(".jpg", scene.image, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        frames.append(encoded.tobytes())
    return frames


def _number(text: str) -> int:
    found = re.search(r"\d+", text)
    return int(found.group()) if found else 0


def measure_viewer(seconds: float, fps: float = 15.0, cpu_slowdown: float = 1.0) -> ViewerRun:
    """Run the live mode for ``seconds`` against a ``fps`` camera; see the module's doc."""
    import zenoh
    from playwright.sync_api import expect

    from service.bus.config import make_config

    frames = _frames()
    with _dlo_serve() as (port, endpoint), chromium() as browser:
        config = make_config(
            mode="peer", multicast=False, gossip=False, listen=[], connect=[endpoint]
        )
        with zenoh.open(config) as session:
            camera = _Camera(session, frames, fps)
            thread = threading.Thread(target=camera.run, name="bench-camera", daemon=True)
            thread.start()
            try:
                page, problems = open_viewer(browser, f"http://127.0.0.1:{port}", "#live")
                throttle = page.context.new_cdp_session(page)
                throttle.send("Emulation.setCPUThrottlingRate", {"rate": cpu_slowdown})
                expect(page.get_by_test_id("camera-select")).to_have_value(CAMERA, timeout=60_000)
                page.get_by_test_id("watch-button").click()
                shown = page.get_by_test_id("live-frames")
                expect(shown).not_to_have_text("0", timeout=60_000)
                time.sleep(WARM_UP_S)  # a fixed warm-up: the measurement is of time itself
                start = js_heap_bytes(page)
                frames_start, sent_start = _number(shown.inner_text()), camera.sent
                began = time.monotonic()
                samples = [(0.0, start["js_heap_used"])]
                while (elapsed := time.monotonic() - began) < seconds:
                    time.sleep(min(SAMPLE_EVERY_S, seconds - elapsed))
                    sample = js_heap_bytes(page)
                    samples.append((time.monotonic() - began, sample["js_heap_used"]))
                duration = time.monotonic() - began
                sent = camera.sent - sent_start
                frames_shown = _number(shown.inner_text()) - frames_start
                end = js_heap_bytes(page)
                run = ViewerRun(
                    seconds=round(duration, 1),
                    cpu_slowdown=cpu_slowdown,
                    camera_fps=round(sent / duration, 2),
                    frames_sent=sent,
                    frames_shown=frames_shown,
                    shown_per_second=round(frames_shown / duration, 2),
                    page_fps_shown=page.get_by_test_id("live-fps").inner_text(),
                    page_dropped=_number(page.get_by_test_id("live-dropped").inner_text()),
                    page_dropped_detail=page.locator("#live-dropped-detail").inner_text(),
                    heap_start_bytes=start["js_heap_used"],
                    heap_end_bytes=end["js_heap_used"],
                    heap_max_bytes=max(value for _, value in samples),
                    dom_nodes=(start["dom_nodes"], end["dom_nodes"]),
                    event_listeners=(start["event_listeners"], end["event_listeners"]),
                    heap_samples=[(round(t, 1), value) for t, value in samples],
                    page_problems=list(problems),
                )
                page.close()
            finally:
                camera.stop.set()
                thread.join(timeout=10)
    return run


def run_viewer_bench(seconds: float, as_json: bool, cpu_slowdown: float = 1.0) -> int:
    """Measure, then print a table (or JSON). Exit status."""
    run = measure_viewer(seconds, cpu_slowdown=cpu_slowdown)
    if as_json:
        print(json.dumps(asdict(run), indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title=f"viewer live mode: a {WIDTH}x{HEIGHT} JPEG camera at 15 fps, {run.seconds:.0f} s"
        + (f", page CPU {run.cpu_slowdown:g}x slower" if run.cpu_slowdown > 1 else "")
    )
    for column in ("", "value"):
        table.add_column(column, justify="right")
    mib = 1024 * 1024
    rows = [
        ("camera frames/s (sent)", f"{run.camera_fps:.2f}"),
        ("frames shown / sent", f"{run.frames_shown} / {run.frames_sent}"),
        ("frames shown per second", f"{run.shown_per_second:.2f}"),
        ("page's fps display at the end", run.page_fps_shown),
        ("dropped since watching (page)", f"{run.page_dropped} {run.page_dropped_detail}".strip()),
        (
            "JS heap start -> end (MiB)",
            f"{run.heap_start_bytes / mib:.2f} -> {run.heap_end_bytes / mib:.2f}",
        ),
        ("JS heap max sample (MiB)", f"{run.heap_max_bytes / mib:.2f}"),
        ("DOM nodes start -> end", f"{run.dom_nodes[0]:.0f} -> {run.dom_nodes[1]:.0f}"),
        (
            "event listeners start -> end",
            f"{run.event_listeners[0]:.0f} -> {run.event_listeners[1]:.0f}",
        ),
        ("page errors", str(len(run.page_problems))),
    ]
    for name, value in rows:
        table.add_row(name, value)
    console = Console()
    console.print(table)
    samples = ", ".join(f"{t:.0f} s {value / mib:.2f}" for t, value in run.heap_samples)
    console.print(f"JS heap after GC (MiB): {samples}", soft_wrap=True)
    for problem in run.page_problems:
        console.print(f"page: {problem}", highlight=False)
    return 0 if not run.page_problems else 1
