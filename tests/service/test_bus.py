"""The zenoh front end, with real zenoh sessions on loopback (no multicast scouting)."""

from __future__ import annotations

import contextlib
import json
import os
import queue
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import httpx
import numpy as np
import zenoh

from schemas import Detection, DetectParams
from service.bus.config import QUERY_KEY, make_config
from service.bus.detection import DetectionBus
from service.http import Settings
from service.perception import detect as real_detect
from service.synthetic import make_scene

TIMEOUT = 15.0


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def encoded_scene(seed: int = 0, extension: str = ".png") -> bytes:
    scene = make_scene(240, 160, 2, seed=seed, loops=False, noise_sigma=2.0)
    ok, data = cv2.imencode(extension, scene.image)
    assert ok
    return data.tobytes()


@contextlib.contextmanager
def client_of(endpoint: str, mode: str = "peer") -> Iterator[zenoh.Session]:
    """A session connected to ``endpoint`` only."""
    config = make_config(mode=mode, multicast=False, listen=[], connect=[endpoint])
    session = zenoh.open(config)
    try:
        yield session
    finally:
        session.close()


@contextlib.contextmanager
def bus_and_client(detect=None, **options) -> Iterator[tuple[DetectionBus, zenoh.Session]]:
    """A bus listening on a free loopback port and a client session connected to it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = make_config(multicast=False, listen=[endpoint], connect=[])
    with DetectionBus(config, detect=detect, **options) as bus, client_of(endpoint) as client:
        yield bus, client


def subscribe(client: zenoh.Session, key: str) -> queue.Queue[tuple[str, bytes]]:
    """Collect ``(key, payload)`` of the samples on ``key`` in a queue."""
    received: queue.Queue[tuple[str, bytes]] = queue.Queue()
    client.declare_subscriber(
        key, lambda sample: received.put((str(sample.key_expr), sample.payload.to_bytes()))
    )
    return received


def publisher_to_bus(client: zenoh.Session, key: str) -> zenoh.Publisher:
    """A publisher on ``key``, once the bus's subscriber is known to match it."""
    publisher = client.declare_publisher(key)
    deadline = time.monotonic() + TIMEOUT
    while not publisher.matching_status.matching:
        assert time.monotonic() < deadline, "the bus's subscriber never showed up"
        time.sleep(0.02)
    time.sleep(0.1)  # and our own subscribers have reached the bus
    return publisher


def take(received: queue.Queue[tuple[str, bytes]]) -> tuple[str, bytes]:
    return received.get(timeout=TIMEOUT)


def query(client: zenoh.Session, image: bytes, attachment: str | None = None) -> zenoh.Reply:
    deadline = time.monotonic() + TIMEOUT
    while True:  # until the queryable is known to the client
        replies = list(client.get(QUERY_KEY, payload=image, attachment=attachment, timeout=TIMEOUT))
        if replies or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert len(replies) == 1
    return replies[0]


def test_image_in_detection_out() -> None:
    with bus_and_client() as (bus, client):
        chains = subscribe(client, "dlo/cam1/chains")
        publisher = publisher_to_bus(client, "dlo/cam1/image")
        publisher.put(encoded_scene(), attachment=json.dumps({"segment_length": 12}))
        key, payload = take(chains)
        assert key == "dlo/cam1/chains"
        detection = Detection.model_validate_json(payload)
        assert detection.width == 240 and detection.height == 160
        assert detection.segment_length == 12
        assert len(detection.chains) >= 1
        publisher.put(encoded_scene(1, ".jpg"))  # JPEG, no attachment: default parameters
        detection = Detection.model_validate_json(take(chains)[1])
        assert detection.segment_length == DetectParams().segment_length
        assert bus.counts["published"] == 2


def test_queryable_answers_a_get() -> None:
    with bus_and_client() as (bus, client):
        reply = query(client, encoded_scene(), json.dumps({"segment_length": 15}))
        assert reply.ok is not None, reply.err
        detection = Detection.model_validate_json(reply.ok.payload.to_bytes())
        assert detection.segment_length == 15 and detection.chains

        reply = query(client, b"GIF89a not what we take")
        assert reply.err is not None
        error = json.loads(reply.err.payload.to_bytes())
        assert error["error"] == "invalid_image" and "image" in error["detail"]

        reply = query(client, encoded_scene(), json.dumps({"segment_length": -3}))
        assert reply.err is not None
        error = json.loads(reply.err.payload.to_bytes())
        assert error["error"] == "invalid_params" and "segment_length" in error["detail"]
        assert bus.counts["query_answered"] == 1 and bus.counts["query_rejected"] == 2


def test_bad_samples_are_counted_and_the_next_good_one_works() -> None:
    with bus_and_client() as (bus, client):
        chains = subscribe(client, "dlo/cam1/chains")
        errors = subscribe(client, "dlo/cam1/errors")
        publisher = publisher_to_bus(client, "dlo/cam1/image")

        publisher.put(b"\x89PNG\r\n\x1a\n truncated")
        record = json.loads(take(errors)[1])
        assert record["camera"] == "cam1" and record["error"] == "invalid_image"

        publisher.put(encoded_scene(), attachment=b"{not json")
        record = json.loads(take(errors)[1])
        assert record["error"] == "invalid_params"

        publisher.put(encoded_scene())
        Detection.model_validate_json(take(chains)[1])
        assert bus.counts["rejected"] == 2 and bus.counts["published"] == 1
        assert chains.empty() and errors.empty()


class SlowDetect:
    """Real detection, slowed down; records how many frames of each camera were waiting."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.bus: DetectionBus | None = None
        self.most_waiting = 0

    def __call__(self, image: np.ndarray, params: DetectParams, mask: np.ndarray | None):
        time.sleep(self.seconds)
        if self.bus is not None:
            self.most_waiting = max(
                self.most_waiting, self.bus.pending("cam1"), self.bus.pending("cam2")
            )
        return real_detect(image, params, mask)


def test_latest_frame_wins_under_a_burst() -> None:
    slow = SlowDetect(0.1)
    with bus_and_client(slow) as (bus, client):
        slow.bus = bus
        chains = subscribe(client, "dlo/cam1/chains")
        publisher = publisher_to_bus(client, "dlo/cam1/image")
        frames = 20
        for index in range(frames):
            # the frame's number travels in its parameters: segment_length 5 + index
            publisher.put(encoded_scene(), attachment=json.dumps({"segment_length": 5 + index}))
        last = None
        while last is None or last.segment_length != 5 + frames - 1:
            last = Detection.model_validate_json(take(chains)[1])
        time.sleep(0.3)
        assert chains.empty()
        assert bus.counts["replaced"] > 0
        assert bus.counts["replaced"] + bus.counts["published"] == frames
        assert slow.most_waiting <= 1


def test_two_cameras_at_once() -> None:
    slow = SlowDetect(0.02)
    with bus_and_client(slow) as (bus, client):
        slow.bus = bus
        chains = subscribe(client, "dlo/*/chains")
        first = publisher_to_bus(client, "dlo/cam1/image")
        second = publisher_to_bus(client, "dlo/cam2/image")
        first.put(encoded_scene(1))
        second.put(encoded_scene(2))
        got = dict(take(chains) for _ in range(2))
        assert set(got) == {"dlo/cam1/chains", "dlo/cam2/chains"}
        for payload in got.values():
            Detection.model_validate_json(payload)
        assert bus.counts["published"] == 2 and bus.counts["replaced"] == 0


def test_http_app_runs_the_bus(tmp_path: Path) -> None:
    """The lifespan opens the bus from a configuration file; /readyz and /metrics show it."""
    from tests.service.test_http import running_server

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config_file = tmp_path / "zenoh.json5"
    config_file.write_text(
        '{ mode: "peer", listen: { endpoints: ["ENDPOINT"] }, // the bus\n'
        "  scouting: { multicast: { enabled: false } } }\n".replace("ENDPOINT", endpoint)
    )
    settings = Settings(workers=1, zenoh=True, zenoh_config=config_file)
    with running_server(settings) as base, client_of(endpoint) as client:
        assert httpx.get(f"{base}/readyz").json() == {"status": "ready"}
        chains = subscribe(client, "dlo/cam7/chains")
        publisher_to_bus(client, "dlo/cam7/image").put(encoded_scene())
        Detection.model_validate_json(take(chains)[1])
        metrics = httpx.get(f"{base}/metrics").text
        assert 'dlo_zenoh_frames_total{outcome="published"} 1.0' in metrics


def test_readyz_fails_when_zenoh_cannot_open(tmp_path: Path) -> None:
    from tests.service.test_http import running_server

    config_file = tmp_path / "zenoh.json5"
    config_file.write_text('{ mode: "peer", listen: { endpoints: ["nonsense/1.2.3.4:5"] } }')
    settings = Settings(workers=1, zenoh=True, zenoh_config=config_file)
    with running_server(settings, wait_ready=False) as base:
        deadline = time.monotonic() + TIMEOUT
        while (answer := httpx.get(f"{base}/readyz").json())["status"] != "failed":
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert "zenoh" in answer["detail"]


def test_http_app_without_zenoh() -> None:
    from tests.service.test_http import running_server

    with running_server(Settings(workers=1, zenoh=False)) as base:
        assert httpx.get(f"{base}/readyz").json() == {"status": "ready"}


# --- dlo router with two dlo serve processes ---------------------------------------------------

DLO = [sys.executable, "-c", "from service.cli import main; main()"]


def test_router_with_two_services(tmp_path: Path) -> None:
    router_address = ("127.0.0.1", free_port())
    router = f"tcp/127.0.0.1:{router_address[1]}"
    config_file = tmp_path / "zenoh.json5"
    config_file.write_text(
        json.dumps(
            {
                # clients: everything goes through the router (peers would rather
                # connect to each other directly, once the router told them where)
                "mode": "client",
                "connect": {"endpoints": [router]},
                "scouting": {"multicast": {"enabled": False}},
            }
        )
    )
    environment = {**os.environ, "DLO_LOG_LEVEL": "WARNING"}
    processes = [
        subprocess.Popen(
            [*DLO, "router", "--listen", router, "--no-multicast"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    try:
        deadline = time.monotonic() + 30
        while True:  # the router listens (clients give up when it is not there yet)
            assert processes[0].poll() is None, "dlo router exited"
            with contextlib.suppress(OSError), socket.create_connection(router_address, 1):
                break
            assert time.monotonic() < deadline, "dlo router did not come up"
            time.sleep(0.05)
        bases = []
        for _ in range(2):
            port = free_port()
            processes.append(
                subprocess.Popen(
                    [*DLO, "serve", "--port", str(port), *("--zenoh-config", str(config_file))],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    env=environment,
                )
            )
            bases.append(f"http://127.0.0.1:{port}")
        for base in bases:
            deadline = time.monotonic() + 60
            while True:
                assert all(process.poll() is None for process in processes)
                with contextlib.suppress(httpx.TransportError):
                    answer = httpx.get(f"{base}/readyz")
                    if answer.status_code == 200:
                        break
                    assert answer.json()["status"] != "failed", answer.text
                assert time.monotonic() < deadline, "dlo serve did not become ready"
                time.sleep(0.1)
        with client_of(router, "client") as client:
            chains = subscribe(client, "dlo/*/chains")
            publisher = publisher_to_bus(client, "dlo/cam3/image")
            publisher.put(encoded_scene())
            for _ in range(2):  # one Detection from each service
                key, payload = take(chains)
                assert key == "dlo/cam3/chains"
                Detection.model_validate_json(payload)
            reply = query(client, encoded_scene())
            assert reply.ok is not None
    finally:
        for process in reversed(processes):
            process.terminate()
        for process in processes:
            process.wait(timeout=10)
