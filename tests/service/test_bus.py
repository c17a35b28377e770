"""The zenoh front end, with real zenoh sessions on loopback (no multicast scouting)."""

from __future__ import annotations

import base64
import contextlib
import json
import queue
import threading
from collections.abc import Iterator
from pathlib import Path

import cv2
import httpx
import numpy as np
import zenoh

from schemas import Detection, DetectParams
from service.bus.config import QUERY_KEY, make_config
from service.bus.detection import DetectionBus
from service.http import Settings, create_app
from service.perception import detect as real_detect
from service.synthetic import make_scene
from tests.helpers import free_port, wait_until

TIMEOUT = 15.0
READY_TIMEOUT_S = 120.0
"""A first start on a machine compiles the numba kernels before a service is ready."""


def encoded_scene(seed: int = 0, extension: str = ".png") -> bytes:
    scene = make_scene(240, 160, 2, seed=seed, loops=False, noise_sigma=2.0)
    ok, data = cv2.imencode(extension, scene.image)
    assert ok
    return data.tobytes()


@contextlib.contextmanager
def client_of(endpoint: str, mode: str = "peer") -> Iterator[zenoh.Session]:
    """A session connected to ``endpoint`` only."""
    config = make_config(mode=mode, multicast=False, gossip=False, listen=[], connect=[endpoint])
    session = zenoh.open(config)
    try:
        yield session
    finally:
        session.close()


@contextlib.contextmanager
def bus_and_client(detect=None, **options) -> Iterator[tuple[DetectionBus, zenoh.Session]]:
    """A bus listening on a free loopback port and a client session connected to it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = make_config(multicast=False, gossip=False, listen=[endpoint], connect=[])
    with DetectionBus(config, detect=detect, **options) as bus, client_of(endpoint) as client:
        yield bus, client


def subscribe(client: zenoh.Session, key: str) -> queue.Queue[tuple[str, bytes]]:
    """Collect ``(key, payload)`` of the samples on ``key`` in a queue."""
    received: queue.Queue[tuple[str, bytes]] = queue.Queue()
    client.declare_subscriber(
        key, lambda sample: received.put((str(sample.key_expr), sample.payload.to_bytes()))
    )
    return received


def publisher_to_bus(
    client: zenoh.Session, key: str, bus_session: zenoh.Session | None = None
) -> zenoh.Publisher:
    """A publisher on ``key`` (``dlo/<camera>/image``), once the bus's subscriber matches it.

    With ``bus_session`` (the session that publishes the results), also wait until it
    knows the client's subscriber on ``dlo/<camera>/chains``, so that no result is lost.
    """
    # BLOCK: a frame larger than a zenoh batch goes in fragments, and the default (DROP)
    # drops it whole when they wait for the link longer than 50 ms, as on a loaded machine.
    publisher = client.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    wait_until(lambda: publisher.matching_status.matching, "the bus's subscriber", TIMEOUT)
    if bus_session is not None:
        wait_for_subscriber(bus_session, f"dlo/{key.split('/')[1]}/chains")
    return publisher


def wait_for_subscriber(session: zenoh.Session, key: str) -> None:
    """Until ``session`` knows a subscriber on ``key`` (a publisher of its own matches one)."""
    probe = session.declare_publisher(key)
    try:
        wait_until(lambda: probe.matching_status.matching, f"a subscriber on {key}", TIMEOUT)
    finally:
        probe.undeclare()


def take(received: queue.Queue[tuple[str, bytes]]) -> tuple[str, bytes]:
    return received.get(timeout=TIMEOUT)


def query(client: zenoh.Session, image: bytes, attachment: str | None = None) -> zenoh.Reply:
    """The one reply to a ``get`` on ``dlo/detect``, asked again until the queryable is known."""
    replies: list[zenoh.Reply] = []

    def answered() -> bool:
        replies[:] = client.get(QUERY_KEY, payload=image, attachment=attachment, timeout=TIMEOUT)
        return bool(replies)

    wait_until(answered, "a reply from dlo/detect", TIMEOUT)
    assert len(replies) == 1
    return replies[0]


def test_image_in_detection_out() -> None:
    with bus_and_client() as (bus, client):
        chains = subscribe(client, "dlo/cam1/chains")
        publisher = publisher_to_bus(client, "dlo/cam1/image", bus.session)
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
        assert error["error"] == "unsupported_media_type" and "GIF" in error["detail"]

        reply = query(client, encoded_scene(), json.dumps({"segment_length": -3}))
        assert reply.err is not None
        error = json.loads(reply.err.payload.to_bytes())
        assert error["error"] == "invalid_params" and "segment_length" in error["detail"]
        assert bus.counts["query_answered"] == 1 and bus.counts["query_rejected"] == 2


def test_bad_samples_are_counted_and_the_next_good_one_works() -> None:
    with bus_and_client() as (bus, client):
        chains = subscribe(client, "dlo/cam1/chains")
        errors = subscribe(client, "dlo/cam1/errors")
        publisher = publisher_to_bus(client, "dlo/cam1/image", bus.session)
        wait_for_subscriber(bus.session, "dlo/cam1/errors")

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


def one_cable_mask(seed: int = 0) -> tuple[np.ndarray, np.ndarray, str]:
    """A scene's image, a mask of its first cable alone, and the mask's PNG as base64."""
    scene = make_scene(240, 160, 2, seed=seed, loops=False, noise_sigma=2.0)
    mask = scene.labels == 1
    ok, png = cv2.imencode(".png", mask.astype(np.uint8) * 255)
    assert ok
    return scene.image, mask, base64.b64encode(png.tobytes()).decode("ascii")


def test_a_mask_in_the_attachment_is_what_is_detected_from() -> None:
    image, mask, mask_text = one_cable_mask()
    params = DetectParams(segment_length=12)
    expected = real_detect(image, params, mask).model_dump(exclude={"timings_ms"})
    unmasked = real_detect(image, params).model_dump(exclude={"timings_ms"})
    assert expected != unmasked  # the mask leaves out a cable: a different detection
    ok, png = cv2.imencode(".png", image)
    assert ok
    attachment = json.dumps({"segment_length": 12, "frame_id": "f-7", "mask": mask_text})
    with bus_and_client() as (bus, client):
        reply = query(client, png.tobytes(), attachment)
        assert reply.ok is not None, reply.err
        answered = Detection.model_validate_json(reply.ok.payload.to_bytes())
        assert answered.model_dump(exclude={"timings_ms"}) == expected

        chains = subscribe(client, "dlo/cam1/chains")
        publisher = publisher_to_bus(client, "dlo/cam1/image", bus.session)
        publisher.put(png.tobytes(), attachment=attachment)
        published = Detection.model_validate_json(take(chains)[1])
        assert published.model_dump(exclude={"timings_ms"}) == expected


def test_bad_masks_in_the_attachment_get_one_line_errors() -> None:
    image, mask, mask_text = one_cable_mask()
    ok, png = cv2.imencode(".png", image)
    assert ok
    ok, small = cv2.imencode(".png", mask[:80].astype(np.uint8) * 255)
    assert ok
    ok, empty = cv2.imencode(".png", np.zeros_like(mask, dtype=np.uint8))
    assert ok
    cases = {
        "not base64 !": "not base64",
        42: "JSON int",
        "": "empty",
        base64.b64encode(small.tobytes()).decode(): "mask is 240x80 but the image is 240x160",
        base64.b64encode(empty.tobytes()).decode(): "marks no cable pixel",
        base64.b64encode(b"GIF89a").decode(): "GIF",
    }
    with bus_and_client(max_bytes=len(png) + 1000) as (bus, client):
        for text, said in cases.items():
            reply = query(client, png.tobytes(), json.dumps({"mask": text, "frame_id": "x"}))
            assert reply.err is not None, text
            error = json.loads(reply.err.payload.to_bytes())
            assert error["error"] in {"invalid_mask", "unsupported_media_type"}, error
            assert said in error["detail"] and "\n" not in error["detail"], error
        huge = base64.b64encode(b"\x89PNG" + bytes(len(png) + 2000)).decode()
        reply = query(client, png.tobytes(), json.dumps({"mask": huge}))
        assert reply.err is not None
        assert json.loads(reply.err.payload.to_bytes())["error"] == "mask_too_large"
        reply = query(client, png.tobytes(), json.dumps({"mask": mask_text}))
        assert reply.ok is not None, reply.err  # the service goes on
        assert bus.counts["query_rejected"] == len(cases) + 1


class GatedDetect:
    """Real detection whose calls wait until :attr:`release` is set, so frames pile up."""

    def __init__(self) -> None:
        self.entered = threading.Event()
        self.release = threading.Event()

    def __call__(self, image: np.ndarray, params: DetectParams, mask: np.ndarray | None, deadline):
        self.entered.set()
        assert self.release.wait(TIMEOUT), "the test never released the detection"
        return real_detect(image, params, mask, deadline=deadline)


def numbered_frame(publisher: zenoh.Publisher, number: int) -> None:
    """Publish a frame whose number travels in its parameters: segment_length 5 + number."""
    publisher.put(encoded_scene(), attachment=json.dumps({"segment_length": 5 + number}))


def test_latest_frame_wins_under_a_burst() -> None:
    gated = GatedDetect()
    with bus_and_client(gated) as (bus, client):
        chains = subscribe(client, "dlo/cam1/chains")
        publisher = publisher_to_bus(client, "dlo/cam1/image", bus.session)
        numbered_frame(publisher, 0)
        assert gated.entered.wait(TIMEOUT), "frame 0 never reached the detector"
        frames = 20
        for number in range(1, frames):  # a burst while frame 0 is being detected
            numbered_frame(publisher, number)
        wait_until(lambda: bus.counts["replaced"] == frames - 2, "the burst to arrive", TIMEOUT)
        assert bus.pending("cam1") == 1  # only the newest frame waits
        gated.release.set()
        numbers = [Detection.model_validate_json(take(chains)[1]).segment_length - 5]
        numbers.append(Detection.model_validate_json(take(chains)[1]).segment_length - 5)
        # A frame published after the burst: any result of a replaced frame, published
        # before it on the same key, would be in the queue by the time it arrives.
        numbered_frame(publisher, frames)
        while numbers[-1] != frames:
            numbers.append(Detection.model_validate_json(take(chains)[1]).segment_length - 5)
        assert numbers == [0, frames - 1, frames]
        assert bus.counts["replaced"] == frames - 2 and bus.counts["published"] == 3


def test_two_cameras_at_once() -> None:
    gated = GatedDetect()
    with bus_and_client(gated) as (bus, client):
        chains = subscribe(client, "dlo/*/chains")
        first = publisher_to_bus(client, "dlo/cam1/image", bus.session)
        second = publisher_to_bus(client, "dlo/cam2/image", bus.session)
        first.put(encoded_scene(1))
        assert gated.entered.wait(TIMEOUT), "cam1's frame never reached the detector"
        second.put(encoded_scene(2))
        wait_until(lambda: bus.pending("cam2") == 1, "cam2's frame to wait", TIMEOUT)
        gated.release.set()
        got = dict(take(chains) for _ in range(2))
        assert set(got) == {"dlo/cam1/chains", "dlo/cam2/chains"}
        for payload in got.values():
            Detection.model_validate_json(payload)
        assert bus.counts["published"] == 2 and bus.counts["replaced"] == 0


def test_http_app_runs_the_bus(tmp_path: Path) -> None:
    """The lifespan opens the bus from a configuration file; /readyz and /metrics show it."""
    from tests.service.test_http import serving

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config_file = tmp_path / "zenoh.json5"
    config_file.write_text(
        '{ mode: "peer", listen: { endpoints: ["ENDPOINT"] }, // the bus\n'
        "  scouting: { multicast: { enabled: false } } }\n".replace("ENDPOINT", endpoint)
    )
    app = create_app(Settings(workers=1, zenoh=True, zenoh_config=config_file, zenoh_listen=None))
    with serving(app) as base, client_of(endpoint) as client:
        assert httpx.get(f"{base}/readyz").json() == {"status": "ready"}
        chains = subscribe(client, "dlo/cam7/chains")
        bus_session = app.state.dlo.bus.session
        publisher_to_bus(client, "dlo/cam7/image", bus_session).put(encoded_scene())
        Detection.model_validate_json(take(chains)[1])
        metrics = httpx.get(f"{base}/metrics").text
        assert 'dlo_zenoh_frames_total{outcome="published"} 1.0' in metrics


def test_readyz_fails_when_zenoh_cannot_open(tmp_path: Path) -> None:
    from tests.service.test_http import running_server

    config_file = tmp_path / "zenoh.json5"
    config_file.write_text('{ mode: "peer", listen: { endpoints: ["nonsense/1.2.3.4:5"] } }')
    settings = Settings(workers=1, zenoh=True, zenoh_config=config_file, zenoh_listen=None)
    with running_server(settings, wait_ready=False) as base:
        wait_until(
            lambda: httpx.get(f"{base}/readyz").json()["status"] == "failed",
            "/readyz to report the failure",
            READY_TIMEOUT_S,
        )
        assert "zenoh" in httpx.get(f"{base}/readyz").json()["detail"]


def test_http_app_without_zenoh() -> None:
    from tests.service.test_http import running_server

    with running_server(Settings(workers=1, zenoh=False)) as base:
        assert httpx.get(f"{base}/readyz").json() == {"status": "ready"}
