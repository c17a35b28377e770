"""MCAP recordings (``--outputs mcap``), read back with the stock reader and decoded with an
independent CDR decoder (tests/service/ros/decoding.py)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from schemas import Detection
from service.cli import app
from service.ros.messages import BASE_FRAME, CAMERA_FRAME, PIXEL_FRAME
from service.ros.recording import (
    CHAINS_TOPIC,
    IMAGE_TOPIC,
    MIN_STEP_NS,
    McapRecorder,
)
from service.synthetic import make_scene
from service.synthetic.scene3d import make_scene_3d
from tests.helpers import DLO, wait_until
from tests.service.ros.decoding import (
    DELETEALL,
    Recorded,
    decoded_image,
    line_strips,
    read_recording,
)

WIDTH, HEIGHT = 320, 240
FPS = 10.0
FRAMES = 6
runner = CliRunner()


def run_dlo(*args: str | Path):
    return runner.invoke(app, [str(arg) for arg in args], prog_name="dlo")


def scene_image(seed: int, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    return make_scene(width, height, 2, seed=seed, loops=False, noise_sigma=2.0).image


def write_video(path: Path, frames: int, width: int = WIDTH, height: int = HEIGHT) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (width, height))
    assert writer.isOpened()
    images = [scene_image(seed, width, height) for seed in range(min(frames, 12))]
    for index in range(frames):
        writer.write(images[index % len(images)])
    writer.release()
    return path


def frames_of(recorded: list[Recorded]) -> list[tuple[Recorded, Recorded]]:
    """(image, markers) per frame; every frame has exactly one of each, in order."""
    images = [entry for entry in recorded if entry.topic == IMAGE_TOPIC]
    markers = [entry for entry in recorded if entry.topic == CHAINS_TOPIC]
    assert {entry.topic for entry in recorded} <= {IMAGE_TOPIC, CHAINS_TOPIC}
    assert len(images) == len(markers)
    assert [entry.sequence for entry in images] == list(range(len(images)))
    assert [entry.sequence for entry in markers] == list(range(len(markers)))
    for image, marker in zip(images, markers, strict=True):
        assert image.log_time == marker.log_time
        assert image.schema_name == "sensor_msgs/msg/CompressedImage"
        assert marker.schema_name == "visualization_msgs/msg/MarkerArray"
    return list(zip(images, markers, strict=True))


def assert_frame_matches(image: Recorded, markers: Recorded, detection: Detection) -> None:
    """One LINE_STRIP per chain with the chain's joints; stamps; the image's size."""
    stamp = markers.message.markers[0].header.stamp
    assert stamp.sec * 1_000_000_000 + stamp.nanosec == markers.log_time == markers.publish_time
    assert markers.message.markers[0].action == DELETEALL
    assert {marker.header.frame_id for marker in markers.message.markers} == {PIXEL_FRAME}
    strips = line_strips(markers.message)
    assert sorted(strips) == sorted(chain.id for chain in detection.chains)
    for chain in detection.chains:
        assert strips[chain.id] == [(x, y, 0.0) for x, y in chain.points]
    assert image.message.header.frame_id == CAMERA_FRAME
    image_stamp = image.message.header.stamp
    assert image_stamp.sec * 1_000_000_000 + image_stamp.nanosec == image.log_time
    assert decoded_image(image.message).shape[:2] == (detection.height, detection.width)


def jsonl_records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_a_video_gives_one_recording_with_one_marker_array_and_image_per_frame(
    tmp_path: Path,
) -> None:
    video = write_video(tmp_path / "clip.mp4", FRAMES)

    result = run_dlo("detect", video, "--out-dir", tmp_path / "out", "--outputs", "json,mcap")

    assert result.exit_code == 0, result.stderr
    assert sorted(entry.name for entry in (tmp_path / "out").iterdir()) == [
        "clip.jsonl",
        "clip.mcap",
    ]
    assert "out/clip.mcap" in result.stderr
    records = jsonl_records(tmp_path / "out" / "clip.jsonl")
    frames = frames_of(read_recording(tmp_path / "out" / "clip.mcap"))
    assert len(frames) == len(records) == FRAMES
    for (image, markers), record in zip(frames, records, strict=True):
        detection = Detection.model_validate(record["detection"])
        assert detection.chains
        assert markers.log_time == round(record["timestamp_s"] * 1e9)  # from the video's start
        assert_frame_matches(image, markers, detection)
        assert image.message.format == "jpeg"


def test_a_folder_of_images_gives_one_recording_of_the_files_own_bytes(tmp_path: Path) -> None:
    folder = tmp_path / "shots"
    folder.mkdir()
    sizes = [(WIDTH, HEIGHT), (200, 150), (WIDTH, HEIGHT)]
    for index, (width, height) in enumerate(sizes):
        assert cv2.imwrite(str(folder / f"s{index}.png"), scene_image(index, width, height))
    os.utime(folder / "s2.png", ns=(10**18, 10**18))  # later than the others
    os.utime(folder / "s1.png", ns=(10**18, 10**18))  # the same time as s2
    os.utime(folder / "s0.png", ns=(9 * 10**17, 9 * 10**17))

    result = run_dlo("detect", folder, "--out-dir", tmp_path / "out", "--outputs", "json,mcap")

    assert result.exit_code == 0, result.stderr
    assert "(recorded in " in result.stderr
    frames = frames_of(read_recording(tmp_path / "out" / "shots.mcap"))
    assert len(frames) == 3
    for index, (image, markers) in enumerate(frames):
        detection = Detection.model_validate_json((tmp_path / "out" / f"s{index}.json").read_text())
        assert_frame_matches(image, markers, detection)
        assert image.message.format == "png"
        assert bytes(image.message.data) == (folder / f"s{index}.png").read_bytes()
    stamps = [markers.log_time for _, markers in frames]
    assert stamps == [9 * 10**17, 10**18, 10**18 + MIN_STEP_NS]  # mtime, nudged when equal


def test_mcap_alone_writes_only_the_recording(tmp_path: Path) -> None:
    image = tmp_path / "scene.jpg"
    assert cv2.imwrite(str(image), scene_image(3))

    result = run_dlo("detect", image, "--out-dir", tmp_path / "out", "--outputs", "mcap")

    assert result.exit_code == 0, result.stderr
    assert [entry.name for entry in (tmp_path / "out").iterdir()] == ["scene.mcap"]
    ((image_message, _),) = frames_of(read_recording(tmp_path / "out" / "scene.mcap"))
    assert image_message.message.format == "jpeg"


def test_a_camera_recording_is_stamped_with_the_wall_clock(tmp_path: Path) -> None:
    video = write_video(tmp_path / "feed.mp4", 3)
    before = time.time_ns()

    result = run_dlo(
        "detect", "--camera", str(video), "--out-dir", tmp_path / "out", "--outputs", "mcap"
    )

    after = time.time_ns()
    assert result.exit_code == 0, result.stderr
    frames = frames_of(read_recording(tmp_path / "out" / "feed.mcap"))
    assert len(frames) == 3
    stamps = [markers.log_time for _, markers in frames]
    assert stamps == sorted(stamps)
    assert before <= stamps[0] and stamps[-1] <= after


def test_a_recording_that_cannot_be_created_is_a_one_line_error(tmp_path: Path) -> None:
    video = write_video(tmp_path / "clip.mp4", 2)
    out_dir = tmp_path / "out"
    (out_dir / "clip.mcap").mkdir(parents=True)  # a directory where the file should go

    result = run_dlo("detect", video, "--out-dir", out_dir, "--outputs", "mcap")

    assert result.exit_code == 1
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines[0].startswith(f"error: cannot write {out_dir / 'clip.mcap'}:")
    assert "Traceback" not in result.stderr


def test_recorder_closes_once_and_refuses_a_frame_without_an_image(tmp_path: Path) -> None:
    recorder = McapRecorder(tmp_path / "empty.mcap")
    detection = Detection(width=4, height=4, segment_length=2.0)
    with pytest.raises(ValueError, match="give the frame"):
        recorder.write(0, detection)
    recorder.close()
    recorder.close()
    assert read_recording(tmp_path / "empty.mcap") == []


def test_ctrl_c_leaves_a_readable_recording_of_whole_frames(tmp_path: Path) -> None:
    """A real SIGINT to a ``dlo detect`` process in the middle of a 640x480 video."""
    video = write_video(tmp_path / "long.mp4", 400, 640, 480)
    out_dir = tmp_path / "out"
    jsonl = out_dir / "long.jsonl"
    log = tmp_path / "dlo.log"

    def lines_written() -> int:
        return jsonl.read_bytes().count(b"\n") if jsonl.exists() else 0

    with log.open("wb") as output:
        process = subprocess.Popen(
            [*DLO, "detect", str(video), "--out-dir", str(out_dir), "--outputs", "json,mcap"],
            stdout=output,
            stderr=subprocess.STDOUT,
        )
        try:
            wait_until(lambda: lines_written() >= 5, "five frames written", timeout=180)
            process.send_signal(signal.SIGINT)
            code = process.wait(timeout=60)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
    assert code == 130, log.read_text()  # stopped by Ctrl-C, what was written is whole
    assert "(interrupted)" in log.read_text()
    records = jsonl_records(jsonl)
    frames = frames_of(read_recording(out_dir / "long.mcap"))
    assert 5 <= len(records) < 400
    # the JSON line of a frame is written just before its recording
    assert len(frames) in (len(records), len(records) - 1)
    for (image, markers), record in zip(frames, records, strict=False):
        assert_frame_matches(image, markers, Detection.model_validate(record["detection"]))


def test_with_a_camera_model_the_markers_are_in_metres_in_the_base_frame(tmp_path: Path) -> None:
    scene = make_scene_3d("down", seed=7, width=640, height=480, focal=700.0)
    assert cv2.imwrite(str(tmp_path / "flat.png"), scene.image)
    scene.camera.to_json_file(tmp_path / "camera.json")

    result = run_dlo(
        "detect", tmp_path / "flat.png", "--camera", tmp_path / "camera.json",
        "--out-dir", tmp_path / "out", "--outputs", "json,mcap",
    )  # fmt: skip

    assert result.exit_code == 0, result.stderr
    detection = Detection.model_validate_json((tmp_path / "out" / "flat.json").read_text())
    assert detection.chains and all(chain.points_3d for chain in detection.chains)
    ((image, markers),) = frames_of(read_recording(tmp_path / "out" / "flat.mcap"))
    assert {marker.header.frame_id for marker in markers.message.markers} == {BASE_FRAME}
    assert line_strips(markers.message) == {
        chain.id: [tuple(point) for point in chain.points_3d if point is not None]
        for chain in detection.chains
    }
    assert decoded_image(image.message).shape[:2] == (480, 640)
