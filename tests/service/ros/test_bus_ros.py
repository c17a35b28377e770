"""ROS 2 over zenoh: MarkerArray samples on dlo/<camera>/markers, and sensor_msgs images in
on dlo/<camera>/image_raw and .../image_raw/compressed. Real zenoh sessions on loopback
(no scouting); every CDR sample is decoded, or written, by mcap-ros2-support."""

from __future__ import annotations

import base64
import json
import queue
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import zenoh

from schemas import Detection, DetectParams, ResultAttachment
from service.bus.config import markers_key, ros_image_keys
from service.bus.detection import DetectionBus
from service.perception import detect as real_detect
from service.perception import warm_up
from service.ros.messages import MARKER_ARRAY
from service.synthetic import make_scene
from tests.service.ros.decoding import (
    compressed_image_message,
    decode_cdr,
    image_message,
    line_strips,
)
from tests.service.test_bus import (
    TIMEOUT,
    bus_and_client,
    encoded_scene,
    one_cable_mask,
    publisher_to_bus,
    wait_for_subscriber,
)
from tests.service.test_replicas import Cameras, Results, two_replicas

CAPTURE_NS = 1_767_225_600_125_000_000


@pytest.fixture(scope="module", autouse=True)
def kernels_loaded() -> None:
    """The detector's kernels loaded (compiled, on a machine's first run) before any wait
    on a result starts its clock."""
    warm_up()


def scene_bgr(seed: int = 0) -> np.ndarray:
    return make_scene(240, 160, 2, seed=seed, loops=False, noise_sigma=2.0).image


class Samples:
    """Every sample on a key: (key, payload, attachment), in a queue."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.queue: queue.Queue[tuple[str, bytes, bytes | None]] = queue.Queue()
        self.encodings: list[str] = []
        self.subscriber = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.encodings.append(str(sample.encoding))
        attachment = None if sample.attachment is None else sample.attachment.to_bytes()
        self.queue.put((str(sample.key_expr), sample.payload.to_bytes(), attachment))

    def take(self, bus: DetectionBus | None = None) -> tuple[str, bytes, bytes | None]:
        """The next sample; with ``bus``, a timeout says what the bus did with the frames."""
        try:
            return self.queue.get(timeout=TIMEOUT)
        except queue.Empty:
            if bus is None:
                raise
            ownership = bus.ownership
            pytest.fail(
                f"no sample in {TIMEOUT} s; bus counts {dict(bus.counts)}, replicas "
                f"{ownership.replicas}, owned {ownership.owned()}"
            )


def assert_markers_match(payload: bytes, detection: Detection, frame_id: str, stamp_ns: int):
    markers = decode_cdr(payload, MARKER_ARRAY)
    assert line_strips(markers) == {
        chain.id: [(x, y, 0.0) for x, y in chain.points] for chain in detection.chains
    }
    for marker in markers.markers:
        assert marker.header.frame_id == frame_id
        stamp = marker.header.stamp
        assert stamp.sec * 1_000_000_000 + stamp.nanosec == stamp_ns


def test_each_detection_is_also_published_as_a_cdr_marker_array() -> None:
    with bus_and_client() as (bus, client):
        chains = Samples(client, "dlo/cam1/chains")
        markers = Samples(client, "dlo/cam1/markers")
        publisher = publisher_to_bus(client, "dlo/cam1/image", bus.session)
        wait_for_subscriber(bus.session, "dlo/cam1/markers")
        capture = {"frame_id": 7, "capture_time": CAPTURE_NS / 1e9}

        publisher.put(encoded_scene(), attachment=json.dumps(capture))

        _, body, attachment = chains.take()
        key, payload, marker_attachment = markers.take()
        assert key == "dlo/cam1/markers"
        detection = Detection.model_validate_json(body)
        assert detection.chains
        assert_markers_match(payload, detection, "cam1_pixels", CAPTURE_NS)
        assert marker_attachment == attachment
        assert ResultAttachment.model_validate_json(marker_attachment).frame_id == 7
        assert markers.encodings == ["application/cdr"]

        publisher.put(encoded_scene(1))  # no capture time: stamped with the sample, or now
        before = client.new_timestamp().get_time().timestamp()
        _, body, _ = chains.take()
        _, payload, _ = markers.take()
        stamp = decode_cdr(payload, MARKER_ARRAY).markers[0].header.stamp
        assert abs(stamp.sec + stamp.nanosec / 1e9 - before) < 60


def test_a_cdr_image_sample_in_gives_chains_out() -> None:
    image = scene_bgr()
    expected = real_detect(image, DetectParams(segment_length=12))
    with bus_and_client() as (bus, client):
        chains = Samples(client, "dlo/cam2/chains")
        markers = Samples(client, "dlo/cam2/markers")
        publisher = publisher_to_bus(client, "dlo/cam2/image_raw", bus.session)
        wait_for_subscriber(bus.session, "dlo/cam2/markers")

        publisher.put(
            image_message(image[:, :, ::-1], "rgb8", CAPTURE_NS),
            attachment=json.dumps({"segment_length": 12, "frame_id": "f-1"}),
        )

        _, body, attachment = chains.take(bus)
        detection = Detection.model_validate_json(body)
        assert detection.chains
        assert detection.model_dump(exclude={"timings_ms"}) == expected.model_dump(
            exclude={"timings_ms"}
        )
        identity = ResultAttachment.model_validate_json(attachment)
        assert identity.frame_id == "f-1"
        assert identity.capture_time == CAPTURE_NS / 1e9  # the message's header.stamp
        assert_markers_match(markers.take()[1], detection, "cam2_pixels", CAPTURE_NS)
        assert bus.counts["published"] == 1


def test_compressed_images_and_foreign_attachments() -> None:
    image = scene_bgr(2)
    jpeg = cv2.imencode(".jpg", image)[1].tobytes()
    with bus_and_client() as (bus, client):
        chains = Samples(client, "dlo/cam3/chains")
        publisher = publisher_to_bus(client, "dlo/cam3/image_raw/compressed", bus.session)
        rmw_zenoh_like = (42).to_bytes(8, "little") + (7).to_bytes(8, "little") + bytes(16)

        publisher.put(compressed_image_message(jpeg, "jpeg", CAPTURE_NS), attachment=rmw_zenoh_like)

        _, body, attachment = chains.take()
        detection = Detection.model_validate_json(body)
        assert (detection.width, detection.height) == (240, 160) and detection.chains
        assert detection.segment_length == DetectParams().segment_length
        identity = ResultAttachment.model_validate_json(attachment)
        assert identity.capture_time == CAPTURE_NS / 1e9 and identity.frame_id is None


def test_a_ros_image_takes_a_mask_in_its_json_attachment() -> None:
    image, mask, mask_text = one_cable_mask(3)
    expected = real_detect(image, DetectParams(), mask).model_dump(exclude={"timings_ms"})
    with bus_and_client() as (bus, client):
        chains = Samples(client, "dlo/cam5/chains")
        errors = Samples(client, "dlo/cam5/errors")
        publisher = publisher_to_bus(client, "dlo/cam5/image_raw", bus.session)
        wait_for_subscriber(bus.session, "dlo/cam5/errors")

        publisher.put(image_message(image, "bgr8"), attachment=json.dumps({"mask": mask_text}))
        detection = Detection.model_validate_json(chains.take()[1])
        assert detection.model_dump(exclude={"timings_ms"}) == expected

        small = cv2.imencode(".png", np.zeros((10, 10), np.uint8))[1].tobytes()
        attachment = json.dumps({"mask": base64.b64encode(small).decode()})
        publisher.put(image_message(image, "bgr8"), attachment=attachment)
        record = json.loads(errors.take()[1])
        assert record["error"] == "invalid_mask" and "10x10" in record["detail"]


def test_bad_ros_samples_give_one_line_errors_and_the_next_good_one_works() -> None:
    with bus_and_client() as (bus, client):
        chains = Samples(client, "dlo/cam4/chains")
        errors = Samples(client, "dlo/cam4/errors")
        raw = publisher_to_bus(client, "dlo/cam4/image_raw", bus.session)
        compressed = publisher_to_bus(client, "dlo/cam4/image_raw/compressed")
        wait_for_subscriber(bus.session, "dlo/cam4/errors")
        bus.max_pixels = 100 * 100

        bad = [
            (raw, encoded_scene(), 422, "image_raw: not a CDR sensor_msgs/msg/Image"),
            (raw, image_message(np.zeros((8, 8, 2), np.uint8), "yuv422"), 422, "'yuv422'"),
            (raw, image_message(np.zeros((120, 100), np.uint8), "mono8"), 413, "100x120"),
            (compressed, compressed_image_message(b"not an image", "jpeg"), 422, "image"),
            (compressed, compressed_image_message(b"", "jpeg"), 422, "no image data"),
        ]
        for publisher, payload, _, detail in bad:
            publisher.put(payload)
            record = json.loads(errors.take()[1])
            assert record["camera"] == "cam4"
            assert record["error"] in ("invalid_image", "image_too_large")
            assert detail in record["detail"] and "\n" not in record["detail"]
        assert bus.counts["rejected"] == len(bad)

        bus.max_pixels = 40_000_000
        raw.put(image_message(scene_bgr(), "bgr8"))
        assert Detection.model_validate_json(chains.take()[1]).chains


def test_ros_frames_go_to_the_cameras_owner_like_any_other() -> None:
    """Two replicas share the cameras; frames on image_raw are answered once, by the owner
    of the camera, whichever key the camera uses."""
    names = ["cam1", "cam2", "cam3", "cam4"]
    with two_replicas() as (client, first, second):
        results = Results(client)
        encoded = Cameras(client, names)
        assert results.wait_for(encoded.send_round())  # the cameras become active
        raw = {
            name: client.declare_publisher(
                f"dlo/{name}/image_raw", congestion_control=zenoh.CongestionControl.BLOCK
            )
            for name in names
        }
        message = image_message(scene_bgr(), "bgr8")
        frames = []
        for number, (name, publisher) in enumerate(raw.items(), start=100):
            publisher.put(message, attachment=json.dumps({"frame_id": number}))
            frames.append((name, number))
        assert results.wait_for(frames)
        for frame in frames:
            assert results.times_answered(frame) == 1, frame
        for name, number in frames:
            owner = first if name in first.ownership.owned() else second
            assert results.answers[(name, number)][0].replica == owner.replica_id
        assert results.replicas_of(frames) == {first.replica_id, second.replica_id}


def test_the_ros_keys_follow_the_image_keys() -> None:
    assert ros_image_keys("dlo/*/image") == ("dlo/*/image_raw", "dlo/*/image_raw/compressed")
    assert ros_image_keys("dlo/line1-$*/image") == (
        "dlo/line1-$*/image_raw",
        "dlo/line1-$*/image_raw/compressed",
    )


def test_the_bridge_configuration_routes_the_services_ros_topics() -> None:
    """deploy/zenoh/ros2-bridge.json5: ROS 2 topic = "/" + zenoh key, for our keys only."""
    path = Path(__file__).resolve().parents[3] / "deploy" / "zenoh" / "ros2-bridge.json5"
    allow = json.loads(zenoh.Config.from_file(str(path)).get_json("plugins/ros2dds/allow"))

    def routed(kind: str, key: str) -> bool:
        return any(re.fullmatch(pattern, "/" + key) for pattern in allow[kind])

    raw, compressed = ros_image_keys("dlo/cam_1/image")
    assert routed("publishers", raw) and routed("publishers", compressed)
    assert routed("subscribers", markers_key("cam_1"))
    assert not routed("publishers", "dlo/cam_1/image")  # encoded frames are not ROS 2's
    assert not routed("subscribers", "dlo/cam_1/chains")
    assert not routed("publishers", "rosout") and not routed("subscribers", "dlo/a/b/markers")
