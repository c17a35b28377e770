"""``dlo track`` and the stream tracker behind it: tracks per frame, bad frames, resets."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from schemas import Detection
from service.synthetic import make_video, write_video
from service.tracking import StreamTracker, read_track_records
from service.video import Frame, FrameSource, process_stream
from tests.service.test_video import assert_no_traceback, lines_starting, run_dlo


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    """Forty frames of two drifting cables, as a video file."""
    path = tmp_path_factory.mktemp("clips") / "cables.mp4"
    return write_video(make_video(6, "drift", n_frames=40), path)


def test_dlo_track_writes_one_line_of_tracks_per_frame(clip, tmp_path):
    result = run_dlo("track", clip, "--out-dir", tmp_path, "--overlay-video")
    assert_no_traceback(result)
    assert result.exit_code == 0, result.stderr
    records = list(read_track_records(tmp_path / "cables.jsonl"))
    assert [r.frame for r in records] == list(range(40))
    ids = [sorted(c.id for c in r.detection.chains) for r in records]
    assert ids[0] == [0, 1] and all(frame_ids == ids[0] for frame_ids in ids)
    # Joints are only ever added (at an open end), never dropped or renumbered.
    previous = {c.id: c for c in records[0].detection.chains}
    for record in records[1:]:
        for chain in record.detection.chains:
            before = previous[chain.id]
            grown_at_head = before.first_joint - chain.first_joint
            assert grown_at_head >= 0 and len(chain.points) >= len(before.points) + grown_at_head
            if len(chain.points) > len(before.points):
                assert "open" in before.ends
            previous[chain.id] = chain
        assert record.detection.tracking.session == records[0].detection.tracking.session
    # The same lines read as plain Detections too.
    line = (tmp_path / "cables.jsonl").read_text().splitlines()[5]
    Detection.model_validate(json.loads(line)["detection"])
    capture = cv2.VideoCapture(str(tmp_path / "cables.overlay.mp4"))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 40
    summary = lines_starting(result, str(clip))
    assert summary and "40 frame(s) processed" in summary[-1]


def test_dlo_track_refuses_what_it_cannot_track(clip, tmp_path):
    result = run_dlo("track", clip)
    assert result.exit_code == 2 and "--out-dir" in result.stderr
    result = run_dlo("track", clip, "--out-dir", tmp_path, "--memory", "-1")
    assert result.exit_code == 2 and "--memory" in result.stderr
    result = run_dlo("track", clip, "--out-dir", tmp_path, "--outputs", "labels")
    assert result.exit_code == 2
    image = tmp_path / "still.png"
    cv2.imwrite(str(image), np.zeros((50, 50, 3), np.uint8))
    result = run_dlo("track", image, "--out-dir", tmp_path)
    assert_no_traceback(result)
    assert result.exit_code == 1
    assert lines_starting(result, "error:") == [
        f"error: {image}: not a video (tracking needs a video or --camera)"
    ]


def source_of(frames, name="stream") -> FrameSource:
    return FrameSource(name=name, label=name, frames=frames, fps=30.0)


def test_dropped_and_broken_frames_keep_the_tracks_and_are_counted(tmp_path):
    video = make_video(0, "drift", n_frames=20, n_cables=1)
    frames = []
    for frame in video.frames():
        image = frame.image
        if frame.index in (6, 7):
            image = None  # unreadable: dropped by the source
        elif frame.index == 8:
            image = np.zeros((0, 0, 3), np.uint8)  # broken: the detection refuses it
        frames.append(Frame(frame.index, frame.timestamp_s, image))
    summary = process_stream(source_of(frames), None, tmp_path, analyser=StreamTracker())
    assert (summary.processed, summary.unreadable, summary.failed) == (17, 2, 1)
    records = list(read_track_records(tmp_path / "stream.jsonl"))
    after = next(r for r in records if r.frame == 9)
    assert after.detection.tracking.frames_lost == 3
    assert {c.id for r in records for c in r.detection.chains} == {0}


def test_a_frame_of_another_size_resets_the_tracks_with_a_warning(tmp_path):
    small = make_video(0, "drift", n_frames=3, n_cables=1, width=320, height=240)
    large = make_video(0, "drift", n_frames=3, n_cables=1)
    frames = [Frame(i, i / 30, f.image) for i, f in enumerate(small.frames())]
    frames += [Frame(3 + i, (3 + i) / 30, f.image) for i, f in enumerate(large.frames())]
    warnings = []
    tracker = StreamTracker(on_reset=lambda frame, why: warnings.append((frame.index, why)))
    summary = process_stream(source_of(frames), None, tmp_path, analyser=tracker)
    assert summary.processed == 6
    assert len(warnings) == 1 and warnings[0][0] == 3
    assert "320x240" in warnings[0][1] and "\n" not in warnings[0][1]
    records = list(read_track_records(tmp_path / "stream.jsonl"))
    assert records[3].detection.tracking.reset == warnings[0][1]
    assert records[3].detection.tracking.session != records[2].detection.tracking.session


def test_dlo_track_warns_of_a_reset_on_one_line(tmp_path, monkeypatch):
    small = make_video(0, "drift", n_frames=2, n_cables=1, width=320, height=240)
    large = make_video(0, "drift", n_frames=2, n_cables=1)
    frames = [Frame(i, i / 30, f.image) for i, f in enumerate(small.frames())]
    frames += [Frame(2 + i, (2 + i) / 30, f.image) for i, f in enumerate(large.frames())]
    monkeypatch.setattr(
        "service.cli.track.open_camera", lambda source: source_of(frames, "camera0")
    )
    result = run_dlo("track", "--camera", "0", "--out-dir", tmp_path)
    assert_no_traceback(result)
    assert result.exit_code == 0, result.stderr
    warnings = lines_starting(result, "warning:")
    assert len(warnings) == 1 and "frame 2" in warnings[0] and "started afresh" in warnings[0]
    assert len(list(read_track_records(tmp_path / "camera0.jsonl"))) == 4


def test_dlo_track_records_the_tracks_in_mcap(clip, tmp_path):
    """--outputs mcap: the stock reader gives one MarkerArray and one image per frame, a
    LINE_STRIP per track with the track's id and joints, as in the JSON Lines."""
    from tests.service.ros.decoding import read_recording
    from tests.service.ros.test_recording import assert_frame_matches, frames_of

    result = run_dlo("track", clip, "--out-dir", tmp_path, "--outputs", "json,mcap")
    assert_no_traceback(result)
    assert result.exit_code == 0, result.stderr
    assert sorted(entry.name for entry in tmp_path.iterdir()) == ["cables.jsonl", "cables.mcap"]
    records = list(read_track_records(tmp_path / "cables.jsonl"))
    frames = frames_of(read_recording(tmp_path / "cables.mcap"))
    assert len(frames) == len(records) == 40
    for (image, markers), record in zip(frames, records, strict=True):
        assert abs(markers.log_time - record.timestamp_s * 1e9) <= 1000  # JSON: to the µs
        assert_frame_matches(image, markers, record.detection)
    # The marker ids are the track ids, the same in every frame.
    first = {c.id for c in records[0].detection.chains}
    assert first and all({c.id for c in r.detection.chains} == first for r in records)
