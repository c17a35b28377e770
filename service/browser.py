"""The viewer page in a real browser: Debian's ``chromium`` driven by Playwright.

For the pictures and measurements the repository makes of the page (``dlo demo
--viewer-screenshot``, ``dlo bench --viewer``) and its browser tests. Playwright is a
development dependency (``pip install -e '.[dev]'``) and drives the system's chromium
(``apt-get install chromium``); its own browser download is never used. Both are imported
or looked for only when a browser is asked for.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fastapi import FastAPI
    from playwright.sync_api import Browser, Page

    from schemas import Detection

CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser")
"""Where Debian (and Ubuntu) put chromium; ``DLO_CHROMIUM`` names another."""
CHROMIUM_ARGS = (
    "--headless",
    "--no-sandbox",  # as root in a container, chromium's sandbox cannot start
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-background-networking",  # nothing but the page's own requests leave it
    "--disable-component-update",
    "--disable-sync",
    "--disable-default-apps",
    "--no-first-run",
    "--no-default-browser-check",
)
VIEWPORT = {"width": 1400, "height": 900}
_DIGITS = re.compile(r"^\d+$")


class BrowserUnavailable(RuntimeError):
    """Playwright or chromium is missing (the message says how to install it)."""


def chromium_path() -> str | None:
    """The chromium to drive: ``DLO_CHROMIUM``, else Debian's, else one on the PATH."""
    named = os.environ.get("DLO_CHROMIUM")
    if named:
        return named if Path(named).exists() else None
    for candidate in CHROMIUM_CANDIDATES:
        if Path(candidate).exists():
            return candidate
    return shutil.which("chromium")


def browser_problem() -> str | None:
    """Why no browser can be driven here (one line), or None."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "Playwright is not installed: pip install -e '.[dev]'"
    if chromium_path() is None:
        return "no chromium: apt-get install chromium (or set DLO_CHROMIUM)"
    return None


@contextlib.contextmanager
def chromium() -> Iterator[Browser]:
    """A headless chromium, closed on the way out.

    Raises
    ------
    BrowserUnavailable
        Playwright or chromium is missing.
    """
    problem = browser_problem()
    if problem is not None:
        raise BrowserUnavailable(problem)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=chromium_path(), args=list(CHROMIUM_ARGS)
        )
        try:
            yield browser
        finally:
            browser.close()


@contextlib.contextmanager
def serving(
    app: FastAPI, options: dict[str, Any] | None = None, ready_timeout_s: float = 180.0
) -> Iterator[str]:
    """Serve ``app`` with uvicorn (``options``: its keyword arguments, as ``dlo serve``
    gives them; host and port are replaced) on a free loopback port in a thread until
    ``/readyz`` says 200 (a first run compiles the kernels); yields the base URL."""
    import httpx
    import uvicorn

    config = {"log_level": "warning", **(options or {}), "host": "127.0.0.1", "port": 0}
    server = uvicorn.Server(uvicorn.Config(app, **config))
    thread = threading.Thread(target=server.run, name="dlo-viewer-server", daemon=True)
    thread.start()
    try:
        _wait(lambda: server.started or not thread.is_alive(), "the server to start", 60)
        if not server.started:
            raise RuntimeError("the server stopped before it started serving")
        port = server.servers[0].sockets[0].getsockname()[1]
        base = f"http://127.0.0.1:{port}"

        def ready() -> bool:
            with contextlib.suppress(httpx.TransportError):
                return httpx.get(f"{base}/readyz").status_code == 200
            return False

        _wait(ready, "the service to become ready", ready_timeout_s)
        yield base
    finally:
        server.should_exit = True
        thread.join(timeout=15)


def _wait(condition: Any, what: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        time.sleep(0.02)


def open_viewer(browser: Browser, base: str, fragment: str = "") -> tuple[Page, list[str]]:
    """A new page on the viewer, loaded, and a list that collects, one line each, the
    page's console errors and warnings, failed requests and uncaught exceptions."""
    page = browser.new_page(viewport=VIEWPORT)
    problems: list[str] = []

    def console(message: Any) -> None:
        if message.type in ("error", "warning"):
            problems.append(f"console {message.type}: {message.text}")

    page.on("console", console)
    page.on("pageerror", lambda error: problems.append(f"uncaught: {error}"))
    page.on(
        "requestfailed",
        lambda request: problems.append(f"request failed: {request.url} {request.failure}"),
    )
    page.goto(f"{base}/{fragment}")
    page.locator("body[data-ready=true]").wait_for()
    return page, problems


def detect_in_page(page: Page, image: Path, timeout_ms: float = 60_000) -> int:
    """Choose ``image`` in the page's file input; the number of chains the page shows."""
    from playwright.sync_api import expect

    page.set_input_files("input[type=file]", str(image))
    count = page.get_by_test_id("chain-count")
    expect(count).to_have_text(_DIGITS, timeout=timeout_ms)
    return int(count.inner_text())


def hover_chain(page: Page, point: tuple[float, float]) -> str:
    """Move the pointer over image pixel ``point`` of the page's canvas; the tooltip's text."""
    canvas = page.get_by_test_id("image-canvas")
    box = canvas.bounding_box()
    assert box is not None, "the canvas is not shown"
    width, height = canvas.evaluate("(c) => [c.width, c.height]")
    page.mouse.move(
        box["x"] + point[0] * box["width"] / width, box["y"] + point[1] * box["height"] / height
    )
    tooltip = page.get_by_test_id("tooltip")
    tooltip.wait_for(state="visible", timeout=5000)
    return tooltip.inner_text()


def lonely_joint(detection: Detection, chain_id: int) -> tuple[float, float]:
    """The inner joint of chain ``chain_id`` farthest from every other chain: hovering it
    can only mean this chain."""
    chain = detection.chain(chain_id)
    inner = chain.points[1:-1] or chain.points
    others = [point for other in detection.chains if other.id != chain_id for point in other.points]
    if not others:
        return inner[len(inner) // 2]

    def clearance(point: tuple[float, float]) -> float:
        return min((point[0] - x) ** 2 + (point[1] - y) ** 2 for x, y in others)

    return max(inner, key=clearance)


def screenshot_viewer(base: str, image: Path, detection: Detection, out: Path) -> None:
    """The viewer at ``base`` with ``image`` detected in it and the pointer on its longest
    chain (``detection``: the service's, for where that chain is), saved as PNG to ``out``.

    Raises
    ------
    BrowserUnavailable
        Playwright or chromium is missing.
    RuntimeError
        The page reported an error.
    """
    with chromium() as browser:
        page, problems = open_viewer(browser, base)
        detect_in_page(page, image)
        if detection.chains:
            longest = max(detection.chains, key=lambda chain: chain.length)
            hover_chain(page, lonely_joint(detection, longest.id))
        out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(out), full_page=True)
    if problems:
        raise RuntimeError(f"the page reported: {problems[0]}")


def js_heap_bytes(page: Page) -> dict[str, float]:
    """After a full garbage collection: the page's JS heap in use, DOM nodes and event
    listeners (Chrome DevTools Protocol: HeapProfiler, Runtime, Performance)."""
    session = page.context.new_cdp_session(page)
    try:
        session.send("HeapProfiler.collectGarbage")
        usage = session.send("Runtime.getHeapUsage")
        session.send("Performance.enable")
        metrics = {
            item["name"]: item["value"]
            for item in session.send("Performance.getMetrics")["metrics"]
        }
    finally:
        session.detach()
    return {
        "js_heap_used": float(usage["usedSize"]),
        "js_heap_total": float(usage["totalSize"]),
        "dom_nodes": metrics.get("Nodes", float("nan")),
        "event_listeners": metrics.get("JSEventListeners", float("nan")),
    }
