"""Tracks over zenoh (service/bus/tracks.py), with real sessions on loopback."""

from __future__ import annotations

import json
import queue

import cv2
import numpy as np
import pytest

from schemas import ResultAttachment, Tracks
from service.bus.tracks import CameraTrackers
from service.synthetic import make_video
from tests.service.test_bus import (
    TIMEOUT,
    bus_and_client,
    publisher_to_bus,
    subscribe,
    take,
    wait_for_subscriber,
)


def encoded_frames(count: int) -> list[bytes]:
    frames = []
    for frame in make_video(6, "drift", n_frames=count).frames():
        ok, data = cv2.imencode(".png", frame.image)
        assert ok
        frames.append(data.tobytes())
    return frames


def test_a_tracked_camera_gets_its_tracks_beside_its_chains():
    frames = encoded_frames(6)
    with bus_and_client(tracking=CameraTrackers(["cam1"])) as (bus, client):
        tracks = subscribe(client, "dlo/cam1/tracks")
        chains = subscribe(client, "dlo/cam1/chains")
        wait_for_subscriber(bus.session, "dlo/cam1/tracks")
        publisher = publisher_to_bus(client, "dlo/cam1/image", bus.session)
        received = []
        for number, data in enumerate(frames):
            publisher.put(data, attachment=json.dumps({"frame_id": number}))
            take(chains)
            key, payload = take(tracks)
            assert key == "dlo/cam1/tracks"
            received.append(Tracks.model_validate_json(payload))
        ids = [sorted(chain.id for chain in t.chains) for t in received]
        assert ids[0] == [0, 1] and all(frame_ids == ids[0] for frame_ids in ids)
        assert len({t.tracking.session for t in received}) == 1
        assert [t.tracking.frame for t in received] == list(range(6))
        assert bus.counts["tracked"] == 6


def test_tracks_carry_the_frame_identity_and_untracked_cameras_get_none():
    frames = encoded_frames(2)
    with bus_and_client(tracking=CameraTrackers(["cam1"])) as (bus, client):
        samples: queue.Queue[tuple[str, bytes]] = queue.Queue()
        client.declare_subscriber(
            "dlo/*/tracks", lambda s: samples.put((str(s.key_expr), s.attachment.to_bytes()))
        )
        chains = subscribe(client, "dlo/*/chains")
        wait_for_subscriber(bus.session, "dlo/cam1/tracks")
        untracked = publisher_to_bus(client, "dlo/cam2/image", bus.session)
        untracked.put(frames[0])
        assert take(chains)[0] == "dlo/cam2/chains"
        tracked = publisher_to_bus(client, "dlo/cam1/image", bus.session)
        tracked.put(frames[1], attachment=json.dumps({"frame_id": "f-7", "capture_time": 12.5}))
        key, attachment = samples.get(timeout=TIMEOUT)
        # The bus answers frames in turn: tracks of cam2 would have come first.
        assert key == "dlo/cam1/tracks" and samples.empty()
        identity = ResultAttachment.model_validate_json(attachment)
        assert identity.frame_id == "f-7" and identity.capture_time == 12.5
        assert identity.replica == bus.replica_id


def test_camera_trackers_count_lost_frames_and_forget_a_handed_over_camera():
    trackers = CameraTrackers(["line1-$*"])
    assert trackers.tracks("line1-a") and not trackers.tracks("cam1")
    assert not trackers.tracks("bad/name")
    video = make_video(0, "drift", n_frames=3, n_cables=1)
    from schemas import FrameIdentity
    from service.perception import detect

    frames = list(video.frames())
    first = trackers.follow(
        "line1-a", detect(frames[0].image), frames[0].image, FrameIdentity(), 0.0
    )
    trackers.lose("line1-a")
    trackers.lose("line1-a")
    second = trackers.follow(
        "line1-a", detect(frames[1].image), frames[1].image, FrameIdentity(), 0.1
    )
    assert second.tracking.frames_lost == 2
    assert second.tracking.session == first.tracking.session
    trackers.forget("line1-a")
    assert trackers.tracked() == []
    third = trackers.follow(
        "line1-a", detect(frames[2].image), frames[2].image, FrameIdentity(), 0.2
    )
    assert third.tracking.session != first.tracking.session
    assert third.tracking.frame == 0
    with pytest.raises(ValueError):
        CameraTrackers([])
    assert np.isfinite(third.tracking.tracking_ms)
