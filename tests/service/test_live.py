"""The viewer's live mode without a browser: :class:`service.bus.live.LiveHub` on real zenoh
sessions, and the ``/v1/live/*`` endpoints of a real uvicorn server, talked to with httpx
and the ``websockets`` client, on loopback only (no scouting)."""

from __future__ import annotations

import contextlib
import json
import queue
import time
from collections.abc import Iterator

import cv2
import httpx
import numpy as np
import pytest
import zenoh
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from schemas import Detection
from service.bus.config import make_config
from service.bus.live import LiveHub, LiveView, camera_name_problem
from service.http import Settings
from service.http.live import WINDOW, decode_view
from service.perception import detect
from tests.helpers import free_port, wait_until

from .test_bus import client_of, encoded_scene, wait_for_subscriber
from .test_http import running_server

TIMEOUT = 15.0
TOKEN = "live-test-token-1c5e"


# --- helpers -------------------------------------------------------------------------------------


@contextlib.contextmanager
def peer_pair() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """A session listening on a free loopback port (the service's) and one connected to it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = make_config(multicast=False, gossip=False, listen=[endpoint], connect=[])
    with zenoh.open(config) as service, client_of(endpoint) as client:
        yield service, client


@contextlib.contextmanager
def service_with_zenoh(**settings) -> Iterator[tuple[str, str]]:
    """A running service whose zenoh peer listens on a free loopback port; yields its base
    URL and that endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    options = {"workers": 1, "zenoh_listen": [endpoint], **settings}
    with running_server(Settings(**options)) as base:
        yield base, endpoint


def ws_url(base: str, camera: str, results: str = "auto") -> str:
    return f"{base.replace('http://', 'ws://')}/v1/live/{camera}?results={results}"


def open_socket(base: str, camera: str, **options) -> ClientConnection:
    return connect(ws_url(base, camera), proxy=None, open_timeout=TIMEOUT, **options)


def next_text(socket: ClientConnection, kind: str) -> dict:
    """The next text message of ``kind`` (frames and other kinds before it are skipped)."""
    while True:
        message = socket.recv(timeout=TIMEOUT)
        if isinstance(message, str) and json.loads(message)["type"] == kind:
            return json.loads(message)


def next_frame(socket: ClientConnection) -> tuple[dict, bytes, bytes]:
    """The next binary frame message: header, result bytes, JPEG bytes."""
    while True:
        message = socket.recv(timeout=TIMEOUT)
        if isinstance(message, bytes):
            return decode_view(message)


def ack(socket: ClientConnection) -> None:
    socket.send(json.dumps({"type": "ack"}))


def acknowledged_until(socket: ClientConnection, kind: str, frame_id) -> tuple[dict, bytes, bytes]:
    """The frame message with a ``kind`` result for ``frame_id``, every frame before it
    acknowledged (skipped); fails after TIMEOUT (statuses keep coming while none does)."""
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        try:
            message = socket.recv(timeout=max(0.0, deadline - time.monotonic()))
        except TimeoutError:
            break
        if not isinstance(message, bytes):
            continue
        header, result, jpeg = decode_view(message)
        ack(socket)
        if header["kind"] == kind and header["frame_id"] == frame_id:
            return header, result, jpeg
    raise AssertionError(f"no {kind} for frame {frame_id!r} within {TIMEOUT} s")


def watched_publisher(client: zenoh.Session, camera: str) -> zenoh.Publisher:
    """A publisher on ``dlo/<camera>/image``, once a subscriber (the hub's) matches it."""
    publisher = client.declare_publisher(  # BLOCK: see tests/service/test_bus.py
        f"dlo/{camera}/image", congestion_control=zenoh.CongestionControl.BLOCK
    )
    wait_until(lambda: publisher.matching_status.matching, "a subscriber of the frames", TIMEOUT)
    return publisher


@contextlib.contextmanager
def watched_hub(name: str) -> Iterator[tuple[LiveHub, zenoh.Session, queue.Queue, zenoh.Publisher]]:
    """A hub on the service's session watching camera ``name``, the camera's session, the
    queue of the views handed on, and the camera's publisher (matched by the hub)."""
    with (
        peer_pair() as (service, camera),
        contextlib.closing(LiveHub(service, max_bytes=10_000_000, max_pixels=10_000_000)) as hub,
    ):
        views: queue.Queue[LiveView] = queue.Queue()
        hub.watch(name, views.put)
        yield hub, camera, views, watched_publisher(camera, name)


def next_result(views: queue.Queue[LiveView]) -> LiveView:
    """The next view with a result (bare frames, handed on while none came lately, skipped)."""
    while (view := views.get(timeout=TIMEOUT)).kind is None:
        pass
    return view


def scene_jpeg(seed: int = 0) -> bytes:
    return encoded_scene(seed, ".jpg")


# --- the hub on zenoh sessions ---------------------------------------------------------------


def test_camera_names_are_single_chunks() -> None:
    assert camera_name_problem("cam-1.left") is None
    for bad in ("", "a/b", "cam*", "$*", "a?b", "x" * 201):
        assert camera_name_problem(bad) is not None


def test_the_hub_lists_cameras_and_pairs_results_with_their_frames() -> None:
    """Results published by a replica elsewhere (here: the test) come back with the frame
    they were made from: by frame_id, by the frame sample's timestamp, or by arrival."""
    with (
        peer_pair() as (service, camera),
        contextlib.closing(LiveHub(service, max_bytes=10_000_000, max_pixels=10_000_000)) as hub,
    ):
        views: queue.Queue[LiveView] = queue.Queue()
        unwatch = hub.watch("cam1", views.put)
        publisher = watched_publisher(camera, "cam1")
        wait_for_subscriber(camera, "dlo/cam1/chains")
        frame = scene_jpeg()

        # no result yet: the frame is handed on bare
        publisher.put(frame, attachment=json.dumps({"frame_id": 1}))
        bare = views.get(timeout=TIMEOUT)
        assert (bare.kind, bare.frame.seq, bare.frame.frame_id) == (None, 1, 1)
        assert bare.frame.jpeg(10_000_000) == frame  # a JPEG is passed through untouched

        publisher.put(frame, attachment=json.dumps({"frame_id": 2}))
        publisher.put(frame, attachment=json.dumps({"frame_id": 3}))
        wait_until(lambda: views.qsize() == 2, "the two frames, bare", TIMEOUT)
        detection = Detection(width=240, height=160, segment_length=10).model_dump_json()
        camera.put(
            "dlo/cam1/chains", detection, attachment=json.dumps({"frame_id": 2, "replica": "r1"})
        )
        view = next_result(views)
        assert (view.kind, view.pairing, view.frame.frame_id, view.replica) == (
            "chains",
            "frame_id",
            2,
            "r1",
        )
        assert view.result == detection.encode()
        assert view.latency_ms is not None and view.latency_ms >= 0

        # a stamped frame without a frame_id: paired by its sample's timestamp
        stamp = camera.new_timestamp()
        publisher.put(frame, timestamp=stamp)
        record = json.dumps({"camera": "cam1", "error": "invalid_image", "detail": "bad"})
        attachment = {"sample_timestamp": stamp.to_string_rfc3339_lossy(), "replica": "r1"}
        wait_until(lambda: hub.cameras()[0]["frames"] == 4, "the stamped frame", TIMEOUT)
        camera.put("dlo/cam1/errors", record, attachment=json.dumps(attachment))
        view = next_result(views)
        assert (view.kind, view.pairing, view.frame.seq) == ("errors", "sample_timestamp", 4)

        # neither: the newest frame that had arrived when the detection began
        publisher.put(frame)
        wait_until(lambda: hub.cameras()[0]["frames"] == 5, "the anonymous frame", TIMEOUT)
        camera.put("dlo/cam1/chains", detection)
        view = next_result(views)
        assert (view.kind, view.pairing, view.frame.seq) == ("chains", "arrival", 5)

        listed = hub.cameras()
        assert [(c["camera"], c["frames"], c["watchers"]) for c in listed] == [("cam1", 5, 1)]
        unwatch()
        assert hub.cameras()[0]["watchers"] == 0
        while not views.empty():  # bare frames handed on before unwatch
            assert views.get().kind is None
        publisher.put(frame, attachment=json.dumps({"frame_id": 6}))
        wait_until(lambda: hub.cameras()[0]["frames"] == 6, "a frame nobody watches", TIMEOUT)
        assert views.empty()  # unwatched: counted for the list, handed to nobody


def test_a_result_that_overtakes_its_frame_waits_for_it() -> None:
    """The replica's result can reach the hub before the frame it was made from (their
    callbacks run on different threads): it is paired when the frame comes, not lost."""
    with watched_hub("cam3") as (_, camera, views, publisher):
        wait_for_subscriber(camera, "dlo/cam3/chains")
        detection = Detection(width=240, height=160, segment_length=10).model_dump_json()
        camera.put("dlo/cam3/chains", detection, attachment=json.dumps({"frame_id": 7}))
        frame = scene_jpeg()
        publisher.put(frame, attachment=json.dumps({"frame_id": 7}))
        view = views.get(timeout=TIMEOUT)  # the paired view, not the frame bare
        assert (view.kind, view.pairing, view.frame.frame_id) == ("chains", "frame_id", 7)
        assert view.result == detection.encode() and view.latency_ms == 0.0
        assert view.frame.jpeg(10_000_000) == frame


def test_tracks_win_over_chains_for_auto_watchers() -> None:
    with (
        peer_pair() as (service, camera),
        contextlib.closing(LiveHub(service, max_bytes=10_000_000, max_pixels=10_000_000)) as hub,
    ):
        auto: queue.Queue[LiveView] = queue.Queue()
        chains_only: queue.Queue[LiveView] = queue.Queue()
        hub.watch("cam2", auto.put)
        hub.watch("cam2", chains_only.put, results="chains")
        publisher = watched_publisher(camera, "cam2")
        wait_for_subscriber(camera, "dlo/cam2/tracks")
        detection = Detection(width=240, height=160, segment_length=10).model_dump_json()
        publisher.put(scene_jpeg(), attachment=json.dumps({"frame_id": "a"}))
        for views in (auto, chains_only):
            assert views.get(timeout=TIMEOUT).kind is None
        wait_until(lambda: hub.cameras()[0]["frames"] == 1, "the frame", TIMEOUT)
        camera.put("dlo/cam2/tracks", detection, attachment=json.dumps({"frame_id": "a"}))
        assert next_result(auto).kind == "tracks"
        camera.put("dlo/cam2/chains", detection, attachment=json.dumps({"frame_id": "a"}))
        assert next_result(chains_only).kind == "chains"
        with pytest.raises(queue.Empty):
            auto.get(timeout=0.5)  # the chains of a tracked camera are not shown to auto


def test_png_frames_are_sent_as_jpeg_and_unreadable_ones_say_why() -> None:
    with watched_hub("cam3") as (_, _, views, publisher):
        png = encoded_scene(1, ".png")
        publisher.put(png)
        jpeg = views.get(timeout=TIMEOUT).frame.jpeg(10_000_000)
        assert jpeg.startswith(b"\xff\xd8")
        decoded = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert decoded.shape == (160, 240, 3)
        publisher.put(b"not an image")
        with pytest.raises(ValueError, match="not an image"):
            views.get(timeout=TIMEOUT).frame.jpeg(10_000_000)
        publisher.put(png)
        with pytest.raises(ValueError, match="megapixels"):
            views.get(timeout=TIMEOUT).frame.jpeg(1000)


# --- the endpoints -------------------------------------------------------------------------------


def test_frames_stream_with_the_chains_the_service_detected() -> None:
    """The service's own bus detects the camera; the WebSocket pairs each result with its
    frame: the JPEG and the Detection of that very frame."""
    with service_with_zenoh() as (base, endpoint), client_of(endpoint) as camera:
        with open_socket(base, "cam1") as socket:
            hello = next_text(socket, "hello")
            assert (hello["camera"], hello["window"]) == ("cam1", WINDOW)
            publisher = watched_publisher(camera, "cam1")
            wait_for_subscriber(camera, "dlo/cam1/chains")  # the hub's, for the results
            images = {index: scene_jpeg(index) for index in range(3)}
            paired = {}
            for index, image in images.items():
                publisher.put(image, attachment=json.dumps({"frame_id": index}))
                header, result, jpeg = acknowledged_until(socket, "chains", index)
                assert header["pairing"] == "frame_id"
                assert header["camera"] == "cam1" and jpeg == image
                paired[index] = Detection.model_validate_json(result)
            for index, image in images.items():
                decoded = cv2.imdecode(np.frombuffer(image, np.uint8), cv2.IMREAD_COLOR)
                direct = detect(decoded)
                assert len(paired[index].chains) == len(direct.chains)
        listed = httpx.get(f"{base}/v1/live/cameras").json()
        assert listed["key"] == "dlo/*/image"
        assert [(c["camera"], c["frames"]) for c in listed["cameras"]] == [("cam1", 3)]


def test_a_client_that_does_not_acknowledge_gets_only_the_newest_frame() -> None:
    """Back-pressure: at most WINDOW frames ahead of the acknowledgements; meanwhile the
    newest replaces the one waiting, and the replaced ones are counted."""
    # this replica detects another camera only: cam9's frames are handed on bare, all of them
    options = {"zenoh_image_keys": ["dlo/elsewhere/image"]}
    with service_with_zenoh(**options) as (base, endpoint), client_of(endpoint) as camera:
        with open_socket(base, "cam9") as socket:
            next_text(socket, "hello")
            publisher = watched_publisher(camera, "cam9")
            frames = 12
            for index in range(1, frames + 1):
                publisher.put(scene_jpeg(), attachment=json.dumps({"frame_id": index}))
            first = [next_frame(socket)[0] for _ in range(WINDOW)]
            assert [h["frame_id"] for h in first] == sorted(h["frame_id"] for h in first)
            waiting = frames - WINDOW - 1  # one waits, the rest were replaced
            while True:  # statuses only, no frame, until every frame reached the server
                message = socket.recv(timeout=TIMEOUT)
                assert isinstance(message, str), "a frame beyond the window"
                status = json.loads(message)
                if status["type"] == "status" and status["dropped_slow_link"] == waiting:
                    break
            assert status["waiting_for_ack"] is True
            ack(socket)
            header, _, _ = next_frame(socket)
            assert header["frame_id"] == frames and header["seq"] == frames
            assert header["kind"] is None and header["dropped_slow_link"] == waiting
        wait_until(
            lambda: httpx.get(f"{base}/v1/live/cameras").json()["cameras"][0]["watchers"] == 0,
            "the closed socket to stop watching",
            TIMEOUT,
        )


def refusal(socket: ClientConnection) -> tuple[dict, int]:
    """The error message and the close code of a refused socket."""
    error = next_text(socket, "error")
    with pytest.raises(ConnectionClosed) as closed:
        socket.recv(timeout=TIMEOUT)
    assert closed.value.rcvd is not None
    return error, closed.value.rcvd.code


def test_the_token_is_needed_in_the_header_or_the_first_message() -> None:
    with service_with_zenoh(api_token=TOKEN) as (base, _):
        assert httpx.get(f"{base}/v1/live/cameras").status_code == 401
        headers = {"Authorization": f"Bearer {TOKEN}"}
        assert httpx.get(f"{base}/v1/live/cameras", headers=headers).status_code == 200
        with open_socket(base, "cam1", additional_headers=headers) as socket:
            assert next_text(socket, "hello")["camera"] == "cam1"
        with open_socket(base, "cam1") as socket:  # a browser: the token in a message
            socket.send(json.dumps({"type": "auth", "token": TOKEN}))
            assert next_text(socket, "hello")["camera"] == "cam1"
        with open_socket(base, "cam1") as socket:
            socket.send(json.dumps({"type": "auth", "token": "wrong"}))
            error, code = refusal(socket)
            assert (error["status"], code) == (401, 4401)
            assert "not the service's" in error["detail"] and TOKEN not in error["detail"]
        with open_socket(base, "cam1", additional_headers={"Authorization": "Bearer x"}) as socket:
            assert refusal(socket)[1] == 4401


def test_bad_cameras_other_sites_and_zenoh_off_are_refused() -> None:
    with service_with_zenoh() as (base, _):
        for camera, results in (("cam*", "auto"), ("cam1", "everything")):
            with connect(ws_url(base, camera, results), proxy=None) as socket:
                error, code = refusal(socket)
                assert (error["status"], code) == (422, 4422)
        with pytest.raises(InvalidStatus) as refused:  # a page of another site
            open_socket(base, "cam1", origin="http://elsewhere.example")
        assert refused.value.response.status_code == 403
        with open_socket(base, "cam1", origin=base) as socket:  # the viewer's own page
            next_text(socket, "hello")
        behind_a_proxy = {"X-Forwarded-Host": "cell.example"}
        with open_socket(
            base, "cam1", origin="https://cell.example", additional_headers=behind_a_proxy
        ) as socket:
            next_text(socket, "hello")
    with running_server(Settings(workers=1, zenoh=False)) as base:
        response = httpx.get(f"{base}/v1/live/cameras")
        assert response.status_code == 503 and "zenoh is off" in response.json()["detail"]
        with open_socket(base, "cam1") as socket:
            error, code = refusal(socket)
            assert (error["status"], code) == (503, 4503)


def test_a_tracked_camera_shows_the_trackers_ids_live() -> None:
    """``dlo serve --track``: the viewer's socket carries the service's own tracks (the
    real tracker's ids, kept from frame to frame), not only chains published by hand."""
    from schemas import Tracks

    from .test_bus_tracks import encoded_frames

    frames = encoded_frames(5)  # two drifting cables
    with (
        service_with_zenoh(track=["cam1"]) as (base, endpoint),
        client_of(endpoint) as camera,
        open_socket(base, "cam1") as socket,
    ):
        next_text(socket, "hello")
        publisher = watched_publisher(camera, "cam1")
        wait_for_subscriber(camera, "dlo/cam1/tracks")  # the hub's
        shown = []
        for index, image in enumerate(frames):
            publisher.put(image, attachment=json.dumps({"frame_id": index}))
            _, result, _ = acknowledged_until(socket, "tracks", index)
            shown.append(Tracks.model_validate_json(result))
    ids = [sorted(chain.id for chain in tracks.chains) for tracks in shown]
    assert ids[0] == [0, 1] and all(frame_ids == ids[0] for frame_ids in ids)
    assert [tracks.tracking.frame for tracks in shown] == list(range(len(frames)))
    assert len({tracks.tracking.session for tracks in shown}) == 1
