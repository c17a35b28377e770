"""Videos and camera streams: JSON Lines per frame, overlay video, bad input, Ctrl-C."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

import service.cli.detect
import service.video
from schemas import Detection
from service.cli import app
from service.video import (
    Frame,
    FrameRecord,
    FrameSource,
    VideoSourceError,
    _JsonLinesWriter,
    process_stream,
    read_frame_records,
)

ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")
WIDTH, HEIGHT = 320, 240
FRAMES = 10
FPS = 10.0

runner = CliRunner()


def run_dlo(*args: str | Path):
    return runner.invoke(app, [str(arg) for arg in args], prog_name="dlo")


def stderr_lines(result) -> list[str]:
    return [ANSI_ESCAPE.sub("", line) for line in result.stderr.splitlines() if line.strip()]


def lines_starting(result, prefix: str) -> list[str]:
    return [line for line in stderr_lines(result) if line.startswith(prefix)]


def assert_no_traceback(result) -> None:
    assert "Traceback" not in result.stdout
    assert "Traceback" not in result.stderr
    assert result.exception is None or isinstance(result.exception, SystemExit)


def cable_frame(index: int) -> np.ndarray:
    """A bright sine-shaped cable on a dark background, shifting with ``index``."""
    image = np.full((HEIGHT, WIDTH, 3), 30, np.uint8)
    xs = np.linspace(20, WIDTH - 20, 12)
    ys = HEIGHT / 2 + 45 * np.sin(xs / WIDTH * 2 * np.pi + 0.3 * index)
    curve = np.stack([xs, ys], axis=1).round().astype(np.int32)
    cv2.polylines(image, [curve], isClosed=False, color=(0, 200, 255), thickness=9)
    return image


def write_video(path: Path, fourcc: str = "mp4v", frames: int = FRAMES) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), FPS, (WIDTH, HEIGHT))
    assert writer.isOpened(), f"OpenCV cannot write {fourcc} into {path.suffix} here"
    for index in range(frames):
        writer.write(cable_frame(index))
    writer.release()
    return path


def count_video_frames(path: Path) -> tuple[int, tuple[int, int]]:
    capture = cv2.VideoCapture(str(path))
    assert capture.isOpened()
    count, size = 0, (0, 0)
    while True:
        ok, image = capture.read()
        if not ok:
            break
        count += 1
        size = (image.shape[1], image.shape[0])
    capture.release()
    return count, size


def in_memory_source(frames: Iterator[Frame] | list[Frame], name: str = "clip") -> FrameSource:
    return FrameSource(name=name, label=f"{name}.mp4", frames=frames, fps=FPS)


def frames_then(count: int, error: BaseException | None) -> Iterator[Frame]:
    """``count`` good frames, then ``error`` raised (or the end)."""
    for index in range(count):
        yield Frame(index, index / FPS, cable_frame(index))
    if error is not None:
        raise error


def jsonl_lines(path: Path) -> list[str]:
    text = path.read_text(encoding="utf-8")
    assert text == "" or text.endswith("\n")
    return text.splitlines()


@pytest.fixture(scope="module")
def clip_mp4(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_video(tmp_path_factory.mktemp("video") / "clip.mp4")


@pytest.mark.parametrize(("suffix", "fourcc"), [(".mp4", "mp4v"), (".avi", "MJPG")])
def test_video_is_processed_end_to_end_and_read_back_frame_by_frame(
    tmp_path: Path, suffix: str, fourcc: str
) -> None:
    video = write_video(tmp_path / f"moving{suffix}", fourcc)
    out_dir = tmp_path / "out"

    result = run_dlo("detect", video, "--out-dir", out_dir, "--overlay-video")

    assert result.exit_code == 0, result.stderr
    assert_no_traceback(result)
    assert result.stdout == ""
    assert sorted(entry.name for entry in out_dir.iterdir()) == [
        "moving.jsonl",
        "moving.overlay.mp4",
    ]
    indices, timestamps = [], []
    with open(out_dir / "moving.jsonl", encoding="utf-8") as stream:
        for line in stream:
            record = json.loads(line)
            assert set(record) == {"frame", "timestamp_s", "detection"}
            detection = Detection.model_validate(record["detection"])
            assert (detection.width, detection.height) == (WIDTH, HEIGHT)
            assert len(detection.chains) == 1
            indices.append(record["frame"])
            timestamps.append(record["timestamp_s"])
    assert indices == list(range(FRAMES))
    assert timestamps == sorted(timestamps)
    assert timestamps == pytest.approx([index / FPS for index in range(FRAMES)], abs=1e-3)
    assert count_video_frames(out_dir / "moving.overlay.mp4") == (FRAMES, (WIDTH, HEIGHT))
    summary = [line for line in stderr_lines(result) if line.startswith(f"{video}: ")]
    assert len(summary) == 1
    assert f"{FRAMES} frame(s) processed, 0 dropped or unreadable, 0 failed" in summary[0]
    assert "ms/frame" in summary[0]


def test_records_read_back_with_the_helper_match_the_raw_lines(
    tmp_path: Path, clip_mp4: Path
) -> None:
    result = run_dlo("detect", clip_mp4, "--out-dir", tmp_path, "--max-frames", "3")

    assert result.exit_code == 0, result.stderr
    records = list(read_frame_records(tmp_path / "clip.jsonl"))
    assert [record.frame for record in records] == [0, 1, 2]
    for record, line in zip(records, jsonl_lines(tmp_path / "clip.jsonl"), strict=True):
        assert record == FrameRecord.model_validate_json(line)


def test_outputs_overlay_writes_only_the_overlay_video(tmp_path: Path, clip_mp4: Path) -> None:
    result = run_dlo("detect", clip_mp4, "--out-dir", tmp_path, "--outputs", "overlay")

    assert result.exit_code == 0, result.stderr
    assert [entry.name for entry in tmp_path.iterdir()] == ["clip.overlay.mp4"]
    assert count_video_frames(tmp_path / "clip.overlay.mp4")[0] == FRAMES


@pytest.mark.parametrize(
    ("outputs", "message"),
    [
        ("json,labels", "error: --outputs: labels are not available for videos"),
        ("json,pictures", "error: --outputs: unknown output 'pictures'"),
        (" , ", "error: --outputs: name at least one of json, labels, overlay"),
    ],
)
def test_bad_outputs_for_a_video_are_one_line_usage_errors(
    tmp_path: Path, clip_mp4: Path, outputs: str, message: str
) -> None:
    result = run_dlo("detect", clip_mp4, "--out-dir", tmp_path / "out", "--outputs", outputs)

    assert result.exit_code == 2
    assert len(stderr_lines(result)) == 1
    assert stderr_lines(result)[0].startswith(message)
    assert not (tmp_path / "out").exists()


def test_outputs_select_the_files_written_per_image(tmp_path: Path) -> None:
    image = tmp_path / "scene.png"
    assert cv2.imwrite(str(image), cable_frame(0))
    out_dir = tmp_path / "out"

    result = run_dlo("detect", image, "--out-dir", out_dir, "--outputs", "json")

    assert result.exit_code == 0, result.stderr
    assert [entry.name for entry in out_dir.iterdir()] == ["scene.json"]
    assert Detection.model_validate_json((out_dir / "scene.json").read_text()).chains

    result = run_dlo("detect", image, "--out-dir", out_dir, "--outputs", "Overlay, labels")

    assert result.exit_code == 0, result.stderr
    assert sorted(entry.name for entry in out_dir.iterdir()) == [
        "scene.json",
        "scene.labels.png",
        "scene.overlay.png",
    ]


def test_videos_and_images_go_together(tmp_path: Path, clip_mp4: Path) -> None:
    image = tmp_path / "still.png"
    assert cv2.imwrite(str(image), cable_frame(3))

    result = run_dlo("detect", image, clip_mp4, "--out-dir", tmp_path / "out")

    assert result.exit_code == 0, result.stderr
    assert sorted(entry.name for entry in (tmp_path / "out").iterdir()) == [
        "clip.jsonl",
        "still.json",
        "still.labels.png",
        "still.overlay.png",
    ]
    assert len(jsonl_lines(tmp_path / "out" / "clip.jsonl")) == FRAMES


def test_unopenable_videos_are_one_line_errors_and_the_good_one_is_processed(
    tmp_path: Path, clip_mp4: Path
) -> None:
    bad = {
        tmp_path / "garbage.mp4": b"this is not a video\n" * 20,
        tmp_path / "empty.avi": b"",
        tmp_path / "cut.mp4": clip_mp4.read_bytes()[: clip_mp4.stat().st_size // 2],
    }
    for path, content in bad.items():
        path.write_bytes(content)
    missing = tmp_path / "missing.mkv"
    out_dir = tmp_path / "out"

    result = run_dlo("detect", *bad, missing, clip_mp4, "--out-dir", out_dir)

    assert result.exit_code == 1
    assert_no_traceback(result)
    expected = {
        "garbage.mp4": "cannot open as a video",
        "empty.avi": "empty file (0 bytes)",
        "cut.mp4": "cannot open as a video",
        "missing.mkv": "no such file or directory",
    }
    errors = lines_starting(result, "error: ")
    assert len(errors) == len(expected), errors
    for name, problem in expected.items():
        assert any(line.startswith(f"error: {tmp_path / name}: {problem}") for line in errors)
    assert len(jsonl_lines(out_dir / "clip.jsonl")) == FRAMES


def test_a_single_unopenable_video_fails(tmp_path: Path) -> None:
    video = tmp_path / "broken.mov"
    video.write_bytes(b"\x00" * 4096)

    result = run_dlo("detect", video, "--out-dir", tmp_path / "out")

    assert result.exit_code == 1
    assert stderr_lines(result) == [
        f"error: {video}: cannot open as a video (damaged file, or a format OpenCV cannot read)"
    ]
    assert not (tmp_path / "out" / "broken.jsonl").exists()


def test_truncated_video_keeps_the_frames_read_and_counts_the_rest(tmp_path: Path) -> None:
    whole = write_video(tmp_path / "whole.avi", "MJPG", frames=12)
    cut = tmp_path / "cut.avi"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])

    result = run_dlo("detect", cut, "--out-dir", tmp_path / "out")

    assert result.exit_code == 0, result.stderr
    assert_no_traceback(result)
    lines = jsonl_lines(tmp_path / "out" / "cut.jsonl")
    assert 1 <= len(lines) < 12
    assert [FrameRecord.model_validate_json(line).frame for line in lines] == list(
        range(len(lines))
    )
    warnings = lines_starting(result, "warning: ")
    assert len(warnings) == 1
    assert warnings[0].startswith(f"warning: {cut}: no frame could be read after frame")
    assert "missing" in warnings[0]
    missing = 12 - len(lines)
    assert f"{len(lines)} frame(s) processed, {missing} dropped or unreadable" in result.stderr


def test_corrupt_frame_in_the_middle_is_skipped_and_counted(tmp_path: Path) -> None:
    video = write_video(tmp_path / "glitch.avi", "MJPG", frames=12)
    data = bytearray(video.read_bytes())
    # Each MJPG frame is a JPEG; wipe the start of the sixth one.
    starts = [match.start() for match in re.finditer(rb"\xff\xd8\xff", bytes(data))]
    assert len(starts) == 12
    data[starts[5] : starts[5] + 2000] = bytes(2000)
    video.write_bytes(bytes(data))

    result = run_dlo("detect", video, "--out-dir", tmp_path / "out")

    assert result.exit_code == 0, result.stderr
    frames = [record.frame for record in read_frame_records(tmp_path / "out" / "glitch.jsonl")]
    assert frames == [index for index in range(12) if index != 5]
    assert lines_starting(result, "warning: ") == [
        f"warning: {video}: frame 5: unreadable frame, skipped"
    ]
    assert "11 frame(s) processed, 1 dropped or unreadable, 0 failed" in result.stderr


def test_source_lost_mid_stream_keeps_the_frames_written(tmp_path: Path) -> None:
    source = in_memory_source(frames_then(3, VideoSourceError("cam", "unplugged")))

    summary = process_stream(source, None, tmp_path, overlay_video=True)

    assert (summary.processed, summary.unreadable, summary.failed) == (3, 0, 0)
    assert summary.stop_reason == "unplugged"
    assert summary.succeeded
    assert [record.frame for record in read_frame_records(tmp_path / "clip.jsonl")] == [0, 1, 2]
    assert count_video_frames(tmp_path / "clip.overlay.mp4")[0] == 3


def test_unexpected_source_exception_ends_the_stream_cleanly(tmp_path: Path) -> None:
    source = in_memory_source(frames_then(2, RuntimeError("driver\ncrashed")))

    summary = process_stream(source, None, tmp_path)

    assert summary.processed == 2
    assert summary.stop_reason == "reading failed: RuntimeError: driver crashed"
    assert len(jsonl_lines(tmp_path / "clip.jsonl")) == 2


def test_unreadable_and_undetectable_frames_are_skipped_and_counted(tmp_path: Path) -> None:
    seen = []
    frames = [
        Frame(0, 0.0, cable_frame(0)),
        Frame(1, 0.1, None),
        Frame(2, 0.2, np.zeros((HEIGHT, WIDTH, 4, 2), np.uint8)),  # no image shape
        Frame(3, 0.3, cable_frame(3)),
    ]

    summary = process_stream(in_memory_source(frames), None, tmp_path, on_frame=seen.append)

    assert (summary.processed, summary.unreadable, summary.failed) == (2, 1, 1)
    assert summary.p50_ms is not None and len(summary.frame_ms) == 2
    assert [record.frame for record in read_frame_records(tmp_path / "clip.jsonl")] == [0, 3]
    assert [outcome.index for outcome in seen] == [0, 1, 2, 3]
    assert seen[1].problem == "frame 1: unreadable frame, skipped"
    assert seen[2].problem is not None and seen[2].problem.startswith("frame 2: ")
    assert "\n" not in seen[2].problem
    assert seen[0].problem is None and seen[0].detection is not None


@pytest.mark.parametrize("after", [0, 1, 4])
def test_ctrl_c_leaves_exactly_the_frames_processed(tmp_path: Path, after: int) -> None:
    source = in_memory_source(frames_then(after, KeyboardInterrupt()))

    summary = process_stream(source, None, tmp_path, overlay_video=True)

    assert summary.interrupted
    assert summary.processed == after
    lines = jsonl_lines(tmp_path / "clip.jsonl")
    assert len(lines) == after
    assert [FrameRecord.model_validate_json(line).frame for line in lines] == list(range(after))
    if after:
        assert count_video_frames(tmp_path / "clip.overlay.mp4")[0] == after


def test_ctrl_c_during_a_frame_keeps_the_earlier_lines(tmp_path: Path) -> None:
    def interrupt_on_third(outcome) -> None:
        if outcome.index == 2:
            raise KeyboardInterrupt

    summary = process_stream(
        in_memory_source(frames_then(6, None)), None, tmp_path, on_frame=interrupt_on_third
    )

    assert summary.interrupted
    assert [record.frame for record in read_frame_records(tmp_path / "clip.jsonl")] == [0, 1, 2]


def test_a_line_cut_short_is_dropped_when_the_file_is_closed(tmp_path: Path) -> None:
    path = tmp_path / "lines.jsonl"
    writer = _JsonLinesWriter(path)
    writer.write('{"frame": 0}\n')
    writer._file.write(b'{"frame": 1, "detec')  # what an interrupted write leaves behind

    writer.close()

    assert path.read_text() == '{"frame": 0}\n'


def test_a_whole_line_out_before_the_interrupt_is_kept(tmp_path: Path) -> None:
    """Ctrl-C between a line's bytes going out and write() noting them keeps the line."""
    path = tmp_path / "lines.jsonl"
    writer = _JsonLinesWriter(path)
    writer.write('{"frame": 0}\n')
    writer._file.write(b'{"frame": 1}\n{"fra')  # a whole line, then a broken one

    writer.close()

    assert path.read_text() == '{"frame": 0}\n{"frame": 1}\n'


def test_max_frames_stops_early(tmp_path: Path, clip_mp4: Path) -> None:
    result = run_dlo("detect", clip_mp4, "--out-dir", tmp_path, "--max-frames", "4")

    assert result.exit_code == 0, result.stderr
    assert len(jsonl_lines(tmp_path / "clip.jsonl")) == 4


def test_ctrl_c_in_the_cli_is_a_clean_stop_that_exits_130(
    tmp_path: Path, clip_mp4: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        service.cli.detect,
        "open_video",
        lambda path: in_memory_source(frames_then(2, KeyboardInterrupt())),
    )

    result = run_dlo("detect", clip_mp4, "--out-dir", tmp_path)

    assert result.exit_code == 130, result.stderr  # a script must not take it for complete
    assert_no_traceback(result)
    assert "2 frame(s) processed" in result.stderr
    assert "(interrupted)" in result.stderr
    assert len(jsonl_lines(tmp_path / "clip.jsonl")) == 2


def test_ctrl_c_before_any_frame_exits_130(
    tmp_path: Path, clip_mp4: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        service.cli.detect,
        "open_video",
        lambda path: in_memory_source(frames_then(0, KeyboardInterrupt())),
    )

    result = run_dlo("detect", clip_mp4, "--out-dir", tmp_path)

    assert result.exit_code == 130
    assert_no_traceback(result)
    assert jsonl_lines(tmp_path / "clip.jsonl") == []


def test_video_that_yields_nothing_fails(
    tmp_path: Path, clip_mp4: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(service.cli.detect, "open_video", lambda path: in_memory_source([]))

    result = run_dlo("detect", clip_mp4, "--out-dir", tmp_path)

    assert result.exit_code == 1
    assert lines_starting(result, "error: ") == ["error: clip.mp4: no frame could be processed"]


class FakeCamera:
    """Stands in for an open ``cv2.VideoCapture``: scripted reads, None = a failed read."""

    script: tuple[int | None, ...] = ()
    opens = True

    def __init__(self, source) -> None:
        self.source = source
        self.reads = iter(self.script)

    def get(self, prop: int) -> float:
        return 50.0 if prop == cv2.CAP_PROP_FPS else 0.0

    def read(self):
        index = next(self.reads, None)
        return (False, None) if index is None else (True, cable_frame(index))

    def release(self) -> None:
        pass


class FakeClock:
    """``time`` for :mod:`service.video`: only sleeping moves the monotonic clock on."""

    perf_counter = staticmethod(time.perf_counter)

    def __init__(self) -> None:
        self.now = 100.0

    def monotonic(self) -> float:
        return self.now

    def time(self) -> float:  # the wall clock, which cameras' recordings are stamped with
        return 1_767_225_600.0 + self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


@pytest.fixture
def fake_camera(monkeypatch: pytest.MonkeyPatch) -> type[FakeCamera]:
    monkeypatch.setattr(service.video, "time", FakeClock())
    monkeypatch.setattr(
        service.video,
        "_open_capture",
        lambda source: FakeCamera(source) if FakeCamera.opens else None,
    )
    monkeypatch.setattr(service.video, "CAMERA_TIMEOUT_S", 0.15)
    monkeypatch.setattr(FakeCamera, "script", (0, 1, 2, None, None, 3, 4))
    monkeypatch.setattr(FakeCamera, "opens", True)
    return FakeCamera


def test_camera_that_disappears_keeps_the_frames_and_counts_the_drops(
    tmp_path: Path, fake_camera: type[FakeCamera]
) -> None:
    result = run_dlo("detect", "--camera", "0", "--out-dir", tmp_path, "--overlay-video")

    assert result.exit_code == 0, result.stderr
    assert_no_traceback(result)
    records = list(read_frame_records(tmp_path / "camera0.jsonl"))
    assert [record.frame for record in records] == [0, 1, 2, 5, 6]
    timestamps = [record.timestamp_s for record in records]
    assert timestamps == sorted(timestamps)
    assert lines_starting(result, "warning: camera 0: stopped delivering frames")
    assert "5 frame(s) processed, 2 dropped or unreadable, 0 failed" in result.stderr
    assert count_video_frames(tmp_path / "camera0.overlay.mp4")[0] == 5


def test_stream_url_names_the_outputs(tmp_path: Path, fake_camera: type[FakeCamera]) -> None:
    result = run_dlo(
        "detect", "--camera", "rtsp://10.0.0.5/live/bench", "--out-dir", tmp_path,
        "--max-frames", "2",
    )  # fmt: skip

    assert result.exit_code == 0, result.stderr
    assert len(jsonl_lines(tmp_path / "bench.jsonl")) == 2


def test_camera_that_cannot_be_opened_is_a_one_line_error(
    tmp_path: Path, fake_camera: type[FakeCamera], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(FakeCamera, "opens", False)

    result = run_dlo("detect", "--camera", "2", "--out-dir", tmp_path)

    assert result.exit_code == 1
    assert stderr_lines(result) == ["error: camera 2: cannot open camera or stream"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--camera", "0"], "error: --camera needs --out-dir"),
        (["--camera", "0", "x.png", "--out-dir", "o"], "error: --camera cannot be combined"),
        (["--camera", "0", "--out-dir", "o", "--mask", "m.png"], "error: --mask applies"),
        (["--camera", "0", "--out-dir", "o", "--max-frames", "0"], "error: --max-frames"),
        (["clip.mp4"], "error: videos need --out-dir"),
        (["clip.mp4", "--mask", "m.png", "--out-dir", "o"], "error: --mask applies"),
        ([], "error: give image or video files"),
        (["x.png", "--outputs", "json"], "error: --outputs needs --out-dir"),
    ],
)
def test_stream_usage_errors(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, args: list[str], message: str
) -> None:
    monkeypatch.chdir(tmp_path)

    result = run_dlo("detect", *args)

    assert result.exit_code == 2
    assert len(stderr_lines(result)) == 1
    assert stderr_lines(result)[0].startswith(message)
    assert not (tmp_path / "o").exists()


def test_videos_with_the_same_stem_do_not_overwrite_each_other(
    tmp_path: Path, clip_mp4: Path
) -> None:
    other = tmp_path / "elsewhere" / "clip.mkv"
    other.parent.mkdir()
    other.write_bytes(b"never opened")

    result = run_dlo("detect", clip_mp4, other, "--out-dir", tmp_path / "out")

    assert result.exit_code == 1
    assert lines_starting(result, "error: ") == [
        f"error: {other}: outputs would overwrite those of {clip_mp4} (same name)"
    ]
    assert len(jsonl_lines(tmp_path / "out" / "clip.jsonl")) == FRAMES
