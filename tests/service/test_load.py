"""A bounded load test: many requests from 8 concurrent clients against a `dlo serve` process.

The server is a real ``dlo serve`` subprocess (uvicorn, 2 detection threads, 4 queue slots,
zenoh off: this test is about HTTP) on a free loopback port; the clients are 8 threads with
an httpx connection each. The mix is mostly good detections (PNG, JPEG, multipart with a
mask, overlays) with bad requests among them (truncated PNG, wrong content type, bad
parameters), so that the error paths run under load too. 8 clients against 6 places
(2 workers + 4 queue slots) make the service refuse some requests with 503 + Retry-After:
those are deliberate. Every other answer must be the expected one, and no 5xx else.

Memory: the server's resident set (``VmRSS`` in ``/proc/<pid>/status``) is read after a
warm-up batch of the same mix, and again after the measured batch; it must be back within
:data:`RSS_TOLERANCE_MIB` of the first reading. The warm-up matters: before it, the first
requests load code, create the worker threads and their malloc arenas, and fill
Prometheus's label sets and the allocators' free lists, all of which stay (and are not
leaks). After it, a leak of anything per request shows: the decoded 160x120 image alone is
56 KiB, so leaking it would add 110 MiB over the 2,000 requests.

The 2,000 requests take 4-7 s on the project's shared 2-core machine (10-25 s with the
server's start and the warm-up), so they run in the normal suite. Nothing here asserts a
speed (the benchmark, ``dlo bench --service``, measures it): a hung server shows as
requests that time out (:data:`REQUEST_TIMEOUT_S` each), reported as unexpected answers.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import httpx
import numpy as np

from service.synthetic import make_scene
from tests.helpers import dlo_serve as serving_process

CLIENTS = 8
WORKERS, QUEUE_SIZE = 2, 4
WARM_UP_REQUESTS = 200
REQUESTS = 2000
RSS_TOLERANCE_MIB = 12.0
"""Allowed growth of the server's resident set over the measured batch. On the project's
2-core machine it grew by 0.1-0.5 MiB; elsewhere it may move by a few MiB without any leak
(glibc keeps freed memory in per-thread arenas and returns it to the system lazily, and
which arena a request's buffers land in depends on the thread that ran it). 12 MiB leaves
room for that and still catches a leak of 6 KiB or more per request."""
REQUEST_TIMEOUT_S = 60.0
"""A request with no answer by then counts as unexpected (a hung server), not as slow."""


@dataclass(frozen=True)
class Call:
    """One kind of request of the mix, and the statuses it may get."""

    name: str
    path: str
    expected: frozenset[int]
    content: bytes | None = None
    files: dict[str, tuple[str, bytes, str]] | None = None
    content_type: str | None = None


def encode(array: np.ndarray, suffix: str) -> bytes:
    ok, data = cv2.imencode(suffix, array)
    assert ok
    return data.tobytes()


def request_mix() -> list[Call]:
    """Ten requests: seven good ones, three bad ones, on a 160x120 scene with two cables."""
    scene = make_scene(160, 120, 2, seed=3, loops=False, radius_range=(3.0, 5.0))
    png, jpeg = encode(scene.image, ".png"), encode(scene.image, ".jpg")
    mask = encode(scene.mask.astype(np.uint8) * 255, ".png")
    good, busy = frozenset({200, 503}), 503  # any detection may find the pool full
    detect = "/v1/detect?segment_length=8"
    png_call = Call("png", detect, good, content=png, content_type="image/png")
    return [
        png_call,
        Call("jpeg", detect, good, content=jpeg, content_type="image/jpeg"),
        png_call,
        Call(
            "multipart+mask",
            detect,
            good,
            files={"image": ("scene.png", png, "image/png"), "mask": ("m.png", mask, "image/png")},
        ),
        Call("overlay", "/v1/detect/overlay", good, content=png, content_type="image/png"),
        png_call,
        # decoded in the pool, so it may be refused before anyone sees it is truncated
        Call(
            "truncated", detect, frozenset({422, busy}), content=png[:200], content_type="image/png"
        ),
        Call("text/plain", detect, frozenset({415}), content=b"hello", content_type="text/plain"),
        Call(
            "bad params",
            "/v1/detect?segment_length=-1",
            frozenset({422}),
            content=png,
            content_type="image/png",
        ),
        png_call,
    ]


@contextlib.contextmanager
def dlo_serve(log: Path) -> Iterator[tuple[int, str]]:
    """A ``dlo serve`` process on a free loopback port, ready; yields its pid and base URL."""
    environment = {
        **os.environ,
        "DLO_WORKERS": str(WORKERS),
        "DLO_QUEUE_SIZE": str(QUEUE_SIZE),
        "DLO_LOG_LEVEL": "warning",  # uvicorn's access log would be 2,000 lines
    }
    arguments = ["--host", "127.0.0.1", "--no-zenoh"]
    with serving_process(arguments, log, environment) as (process, base):
        yield process.pid, base


def resident_mib(pid: int) -> float:
    """The resident set size of process ``pid`` in MiB (``VmRSS``, reported in kB)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError(f"no VmRSS in /proc/{pid}/status")


@dataclass
class Outcome:
    """What the clients saw: status counts per kind of request, and the unexpected answers."""

    statuses: Counter[tuple[str, int]]
    unexpected: list[str]
    finished: int
    seconds: float


def drive(base: str, calls: list[Call], total: int) -> Outcome:
    """Send ``total`` requests of the mix from :data:`CLIENTS` threads, each its own client."""
    statuses: Counter[tuple[str, int]] = Counter()
    unexpected: list[str] = []
    lock = threading.Lock()
    next_index = iter(range(total))
    started = time.monotonic()

    def client() -> None:
        with httpx.Client(base_url=base, timeout=REQUEST_TIMEOUT_S) as http:
            while True:
                with lock:
                    index = next(next_index, None)
                if index is None:
                    return
                call = calls[index % len(calls)]
                headers = {"Content-Type": call.content_type} if call.content_type else None
                try:
                    response = http.post(
                        call.path, content=call.content, files=call.files, headers=headers
                    )
                except httpx.HTTPError as exc:  # no answer at all: hung or gone
                    with lock:
                        unexpected.append(f"{call.name}: {type(exc).__name__}: {exc}")
                    continue
                status = response.status_code
                refused_well = status != 503 or response.headers.get("retry-after") == "1"
                with lock:
                    statuses[call.name, status] += 1
                    if status not in call.expected or not refused_well:
                        unexpected.append(f"{call.name}: {status} {response.text[:200]}")
                if status == 503:
                    time.sleep(0.02)  # a real client waits Retry-After; a short pause will do

    threads = [threading.Thread(target=client, name=f"client-{n}") for n in range(CLIENTS)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return Outcome(statuses, unexpected, sum(statuses.values()), time.monotonic() - started)


def run_load(total: int, tmp_path: Path) -> None:
    calls = request_mix()
    with dlo_serve(tmp_path / "server.log") as (pid, base):
        warm_up = drive(base, calls, WARM_UP_REQUESTS)
        assert not warm_up.unexpected, warm_up.unexpected[:5]
        before = resident_mib(pid)
        outcome = drive(base, calls, total)
        after = resident_mib(pid)
        metrics = httpx.get(f"{base}/metrics").text

    by_status = Counter[int]()
    for (_, status), count in outcome.statuses.items():
        by_status[status] += count
    print(
        f"\n{total} requests from {CLIENTS} clients in {outcome.seconds:.1f} s: "
        f"statuses {dict(sorted(by_status.items()))}; "
        f"server RSS {before:.1f} MiB after warm-up, {after:.1f} MiB after ({after - before:+.1f})"
    )
    assert not outcome.unexpected, outcome.unexpected[:5]
    assert outcome.finished == total
    assert all(status < 500 or status == 503 for status in by_status)
    assert 'status="500"' not in metrics
    # the service did serve under load, and every kind of good request succeeded
    for name in ("png", "jpeg", "multipart+mask", "overlay"):
        assert outcome.statuses[name, 200] > 0, name
    assert after - before <= RSS_TOLERANCE_MIB, f"RSS grew {before:.1f} -> {after:.1f} MiB"


def test_2000_requests_from_8_clients_no_5xx_but_503_and_no_memory_growth(
    tmp_path: Path,
) -> None:
    run_load(REQUESTS, tmp_path)
