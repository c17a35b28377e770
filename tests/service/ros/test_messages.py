"""ROS 2 messages of a detection, and images read from ROS 2 messages; every message is
decoded (or encoded) by mcap-ros2-support, independently of the rosbags that we use."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from schemas import Chain, Crossing, Detection
from service.perception.render import chain_colour
from service.ros.messages import (
    BASE_FRAME,
    DEFAULT_RADIUS_M,
    MARKER_ARRAY,
    PIXEL_FRAME,
    TEXT_HEIGHT_M,
    RosMessageError,
    compressed_image_cdr,
    markers_cdr,
    read_compressed_image_message,
    read_image_message,
)
from tests.service.ros.decoding import (
    DELETEALL,
    LINE_LIST,
    LINE_STRIP,
    SPHERE_LIST,
    TEXT_VIEW_FACING,
    compressed_image_message,
    decode_cdr,
    image_message,
    line_strips,
)

STAMP_NS = 1_767_225_600_250_000_001


def two_crossing_chains() -> Detection:
    return Detection(
        width=100,
        height=80,
        segment_length=10.0,
        chains=[
            Chain(
                id=3,
                points=[(10.0, 40.0), (20.0, 40.0), (30.0, 40.0), (40.5, 40.25)],
                radius=2.5,
                inferred=[False, True, False],
            ),
            Chain(id=7, points=[(25.0, 20.0), (25.0, 30.0), (25.0, 50.0)], radius=0.2,
                  inferred=[False, False]),
        ],
        crossings=[
            Crossing(x=25.0, y=40.0, over=7, under=3, over_segment=1, under_segment=1,
                     confidence=0.8)
        ],
    )  # fmt: skip


def test_markers_hold_one_line_strip_per_chain_with_its_joints() -> None:
    detection = two_crossing_chains()

    markers = decode_cdr(markers_cdr(detection, STAMP_NS), MARKER_ARRAY).markers

    assert markers[0].action == DELETEALL
    for marker in markers:
        assert marker.header.frame_id == PIXEL_FRAME
        assert (marker.header.stamp.sec, marker.header.stamp.nanosec) == (
            1_767_225_600,
            250_000_001,
        )
        assert marker.pose.orientation.w == 1.0
    assert line_strips(decode_cdr(markers_cdr(detection, STAMP_NS), MARKER_ARRAY)) == {
        3: [(10.0, 40.0, 0.0), (20.0, 40.0, 0.0), (30.0, 40.0, 0.0), (40.5, 40.25, 0.0)],
        7: [(25.0, 20.0, 0.0), (25.0, 30.0, 0.0), (25.0, 50.0, 0.0)],
    }
    strips = {marker.id: marker for marker in markers if marker.type == LINE_STRIP}
    assert strips[3].ns == "chains" and strips[3].scale.x == 5.0
    assert strips[7].scale.x == 1.0  # never thinner than a pixel
    blue, green, red = chain_colour(3)
    colour = strips[3].color
    assert (colour.r, colour.g, colour.b, colour.a) == pytest.approx(
        (red / 255, green / 255, blue / 255, 1.0)
    )


def test_inferred_stretches_crossings_and_ids_have_markers_of_their_own() -> None:
    markers = decode_cdr(markers_cdr(two_crossing_chains(), STAMP_NS), MARKER_ARRAY).markers

    by_kind = {(marker.ns, marker.type, marker.id): marker for marker in markers}
    assert sorted(by_kind) == [
        ("", 0, 0),
        ("chains", LINE_STRIP, 3),
        ("chains", LINE_STRIP, 7),
        ("crossings", SPHERE_LIST, 0),
        ("ids", TEXT_VIEW_FACING, 3),
        ("ids", TEXT_VIEW_FACING, 7),
        ("inferred", LINE_LIST, 3),
    ]
    inferred = by_kind[("inferred", LINE_LIST, 3)]
    assert [(p.x, p.y, p.z) for p in inferred.points] == [(20.0, 40.0, -1.0), (30.0, 40.0, -1.0)]
    crossings = by_kind[("crossings", SPHERE_LIST, 0)]
    assert [(p.x, p.y) for p in crossings.points] == [(25.0, 40.0)]
    blue, _, red = chain_colour(7)  # the strand on top
    assert (crossings.colors[0].r, crossings.colors[0].b) == pytest.approx((red / 255, blue / 255))
    label = by_kind[("ids", TEXT_VIEW_FACING, 7)]
    assert label.text == "7"
    assert (label.pose.position.x, label.pose.position.y) == (25.0, 20.0)  # joint 0


def test_an_empty_detection_only_clears_the_previous_markers() -> None:
    detection = Detection(width=10, height=10, segment_length=5.0)

    markers = decode_cdr(markers_cdr(detection, 0), MARKER_ARRAY).markers

    assert [(marker.action, marker.ns) for marker in markers] == [(DELETEALL, "")]


def test_compressed_image_round_trip() -> None:
    image = np.zeros((30, 40, 3), np.uint8)
    image[5:25, 10:30] = (0, 128, 255)
    png = cv2.imencode(".png", image)[1].tobytes()

    message = decode_cdr(
        compressed_image_cdr(png, "png", STAMP_NS), "sensor_msgs/msg/CompressedImage"
    )

    assert message.format == "png" and bytes(message.data) == png
    received = read_compressed_image_message(compressed_image_message(png, "png", STAMP_NS))
    assert received.encoded == png
    assert received.stamp_s == pytest.approx(STAMP_NS / 1e9)


@pytest.mark.parametrize("encoding", ["bgr8", "rgb8", "bgra8", "rgba8", "8UC3", "8UC4"])
def test_colour_images_arrive_as_bgr(encoding: str) -> None:
    rng = np.random.default_rng(1)
    bgr = rng.integers(0, 256, (12, 17, 3), dtype=np.uint8)
    pixels = {
        "bgr8": bgr,
        "8UC3": bgr,
        "rgb8": bgr[:, :, ::-1],
        "bgra8": np.dstack([bgr, np.full(bgr.shape[:2], 255, np.uint8)]),
        "8UC4": np.dstack([bgr, np.full(bgr.shape[:2], 9, np.uint8)]),
        "rgba8": np.dstack([bgr[:, :, ::-1], np.full(bgr.shape[:2], 255, np.uint8)]),
    }[encoding]

    received = read_image_message(image_message(pixels, encoding, STAMP_NS))

    np.testing.assert_array_equal(received.image, bgr)
    assert received.stamp_s == pytest.approx(STAMP_NS / 1e9)


def test_rows_padded_to_a_longer_step_are_read_row_by_row() -> None:
    gray = np.arange(7 * 5, dtype=np.uint8).reshape(7, 5)

    received = read_image_message(image_message(gray, "mono8", step=8))

    np.testing.assert_array_equal(received.image, gray)
    assert received.stamp_s is None  # an unset stamp is no capture time


@pytest.mark.parametrize("big_endian", [False, True])
def test_sixteen_bit_images_are_stretched_to_eight_bits(big_endian: bool) -> None:
    depth = np.array([[1000, 1500], [3000, 1000]], np.uint16)

    received = read_image_message(image_message(depth, "mono16", big_endian=big_endian))

    np.testing.assert_array_equal(received.image, [[0, 64], [255, 0]])  # 63.75 rounded


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (b"", "not a CDR sensor_msgs/msg/Image"),
        (b"\x00\x01\x00\x00\x05", "not a CDR sensor_msgs/msg/Image"),
        (image_message(np.zeros((4, 4, 2), np.uint8), "yuv422"), "encoding 'yuv422' is not"),
        (image_message(np.zeros((4, 4), np.uint8), "mono8", step=2), "for 4x4 mono8 with a step"),
        (image_message(np.zeros((0, 4), np.uint8), "mono8"), "empty image (4x0)"),
    ],
)
def test_unusable_image_messages_are_refused_with_the_reason(payload: bytes, message: str) -> None:
    with pytest.raises(RosMessageError, match=r"^sensor_msgs|^not a CDR") as caught:
        read_image_message(payload)
    assert message in str(caught.value)
    assert "\n" not in str(caught.value)


def test_the_size_is_checked_before_the_pixels_are_converted() -> None:
    sizes = []

    def refuse(width: int, height: int) -> None:
        sizes.append((width, height))
        raise OverflowError("too large")

    with pytest.raises(OverflowError):
        read_image_message(image_message(np.zeros((3, 5), np.uint8), "mono8"), refuse)
    assert sizes == [(5, 3)]


def test_a_lifted_detection_gives_markers_in_metres_in_the_base_frame() -> None:
    flat = two_crossing_chains()
    lifted_chains = [
        flat.chains[0].model_copy(
            update={
                "points_3d": [(0.1, 0.2, 0.0), (0.11, 0.2, 0.0), None, (0.13, 0.2, 0.001)],
                "radius_m": 0.004,
            }
        ),
        flat.chains[1].model_copy(
            update={"points_3d": [(0.2, 0.1, 0.0), (0.2, 0.11, 0.002), (0.2, 0.13, 0.002)]}
        ),
    ]
    lifted = flat.model_copy(update={"chains": lifted_chains})

    markers = decode_cdr(markers_cdr(lifted, STAMP_NS), MARKER_ARRAY)

    assert {marker.header.frame_id for marker in markers.markers} == {BASE_FRAME}
    assert line_strips(markers) == {  # a joint without a 3-D point is left out
        3: [(0.1, 0.2, 0.0), (0.11, 0.2, 0.0), (0.13, 0.2, 0.001)],
        7: [(0.2, 0.1, 0.0), (0.2, 0.11, 0.002), (0.2, 0.13, 0.002)],
    }
    by_kind = {(marker.ns, marker.id): marker for marker in markers.markers}
    assert by_kind[("chains", 3)].scale.x == pytest.approx(0.008)
    assert by_kind[("chains", 7)].scale.x == pytest.approx(2 * DEFAULT_RADIUS_M)
    assert ("inferred", 3) not in by_kind  # its inferred segment ends at the unknown joint
    (crossing,) = by_kind[("crossings", 0)].points  # halfway along chain 7's segment 1
    assert (crossing.x, crossing.y, crossing.z) == pytest.approx((0.2, 0.12, 0.002))
    assert by_kind[("ids", 7)].scale.z == TEXT_HEIGHT_M
