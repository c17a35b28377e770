"""The ``dlo`` command line: outputs, one-line errors, exit statuses."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

import service.batch
from schemas import Detection
from service.cli import app

ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")

runner = CliRunner()


def run_dlo(*args: str | Path):
    """Invoke the app in-process; stdout and stderr are captured separately."""
    return runner.invoke(app, [str(arg) for arg in args], prog_name="dlo")


def stderr_lines(result) -> list[str]:
    return [ANSI_ESCAPE.sub("", line) for line in result.stderr.splitlines() if line.strip()]


def error_lines(result) -> list[str]:
    return [line for line in stderr_lines(result) if line.startswith("error: ")]


def assert_no_traceback(result) -> None:
    assert "Traceback" not in result.stdout
    assert "Traceback" not in result.stderr
    assert result.exception is None or isinstance(result.exception, SystemExit)


def draw_cables(width: int, height: int, cables: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Thick bright curves across a dark noisy background: (BGR image, bool mask).

    Drawn here rather than with :mod:`service.synthetic` so that these tests of the
    command line do not change when the scene generator does.
    """
    rng = np.random.default_rng(seed)
    image = rng.integers(15, 45, (height, width, 3), dtype=np.uint8)
    mask = np.zeros((height, width), np.uint8)
    thickness = max(6, width // 40)
    for index in range(cables):
        xs = np.linspace(0.08 * width, 0.92 * width, 7)
        row = height * (index + 0.5) / cables
        ys = row + 0.12 * height * np.sin(xs / width * 2 * np.pi + rng.uniform(0, np.pi))
        curve = np.stack([xs, ys], axis=1).round().astype(np.int32)
        colour = [int(value) for value in rng.integers(150, 255, 3)]
        cv2.polylines(image, [curve], isClosed=False, color=colour, thickness=thickness)
        cv2.polylines(mask, [curve], isClosed=False, color=255, thickness=thickness)
    return image, mask > 0


def write_scene(path: Path, seed: int = 1, cables: int = 2) -> Path:
    """A small scene saved under ``path`` (format from the extension)."""
    image, _ = draw_cables(320, 240, cables, seed)
    assert cv2.imwrite(str(path), image)
    return path


def png_bytes(image: np.ndarray) -> bytes:
    encode_ok, data = cv2.imencode(".png", image)
    assert encode_ok
    return data.tobytes()


@pytest.fixture(scope="module")
def scene_png(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scene(tmp_path_factory.mktemp("scene") / "scene.png")


def test_single_image_prints_detection_json_on_stdout(scene_png: Path) -> None:
    result = run_dlo("detect", scene_png)

    assert result.exit_code == 0, result.stderr
    detection = Detection.model_validate_json(result.stdout)
    assert (detection.width, detection.height) == (320, 240)
    assert detection.chains
    assert error_lines(result) == []
    assert_no_traceback(result)


def test_directory_with_out_dir_writes_three_files_per_image(tmp_path: Path) -> None:
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    write_scene(inputs / "first.png", seed=1)
    write_scene(inputs / "second.jpg", seed=2, cables=1)
    out_dir = tmp_path / "out" / "nested"

    result = run_dlo("detect", inputs, "--out-dir", out_dir, "--segment-length", "12")

    assert result.exit_code == 0, result.stderr
    assert result.stdout == ""
    assert sorted(entry.name for entry in out_dir.iterdir()) == [
        "first.json",
        "first.labels.png",
        "first.overlay.png",
        "second.json",
        "second.labels.png",
        "second.overlay.png",
    ]
    for stem in ("first", "second"):
        detection = Detection.model_validate_json((out_dir / f"{stem}.json").read_text())
        assert detection.segment_length == 12
        labels = cv2.imread(str(out_dir / f"{stem}.labels.png"), cv2.IMREAD_UNCHANGED)
        assert labels.dtype == np.uint16
        assert labels.shape == (240, 320)
        assert labels.max() > 0
        overlay = cv2.imread(str(out_dir / f"{stem}.overlay.png"), cv2.IMREAD_UNCHANGED)
        assert overlay.shape == (240, 320, 3)


def test_bad_files_fail_one_by_one_and_the_good_one_is_processed(
    tmp_path: Path, scene_png: Path
) -> None:
    good = tmp_path / "good.png"
    good.write_bytes(scene_png.read_bytes())
    png = png_bytes(cv2.imread(str(scene_png)))
    encode_ok, jpeg = cv2.imencode(".jpg", cv2.imread(str(scene_png)))
    assert encode_ok
    bad = {
        tmp_path / "zero.png": b"",
        tmp_path / "text.png": b"this is not a picture\n",
        tmp_path / "cut.png": png[: len(png) // 3],
        tmp_path / "cut_jpeg.jpg": jpeg.tobytes()[: jpeg.size // 3],
    }
    for path, content in bad.items():
        path.write_bytes(content)
    missing = tmp_path / "missing.png"
    out_dir = tmp_path / "out"

    result = run_dlo("detect", *bad, good, missing, "--out-dir", out_dir)

    assert result.exit_code == 1
    assert_no_traceback(result)
    errors = error_lines(result)
    assert len(errors) == len(bad) + 1
    expected = {
        "zero.png": "empty file",
        "text.png": "not an image",
        "cut.png": "truncated PNG file",
        "cut_jpeg.jpg": "truncated JPEG file",
        "missing.png": "no such file",
    }
    for name, problem in expected.items():
        matching = [line for line in errors if line.startswith(f"error: {tmp_path / name}: ")]
        assert len(matching) == 1, (name, errors)
        assert problem in matching[0]
    assert not any("good.png" in line for line in errors)
    assert Detection.model_validate_json((out_dir / "good.json").read_text()).chains
    assert (out_dir / "good.labels.png").is_file()
    assert (out_dir / "good.overlay.png").is_file()
    assert not (out_dir / "zero.json").exists()


def test_mask_of_another_size_is_a_clear_error(tmp_path: Path, scene_png: Path) -> None:
    mask = tmp_path / "mask.png"
    mask.write_bytes(png_bytes(np.full((100, 100), 255, np.uint8)))

    result = run_dlo("detect", scene_png, "--mask", mask)

    assert result.exit_code == 1
    assert result.stdout == ""
    assert error_lines(result) == [
        f"error: {mask}: mask is 100x100 but the image is 320x240",
    ]
    assert_no_traceback(result)


def test_all_empty_mask_is_a_clear_error(tmp_path: Path, scene_png: Path) -> None:
    mask = tmp_path / "mask.png"
    mask.write_bytes(png_bytes(np.zeros((240, 320), np.uint8)))

    result = run_dlo("detect", scene_png, "--mask", mask)

    assert result.exit_code == 1
    assert result.stdout == ""
    errors = error_lines(result)
    assert len(errors) == 1
    assert errors[0].startswith(f"error: {scene_png}: ")
    assert_no_traceback(result)


def test_given_mask_replaces_segmentation(tmp_path: Path) -> None:
    picture, foreground = draw_cables(320, 240, 1, seed=3)
    image = tmp_path / "scene.png"
    mask = tmp_path / "mask.png"
    image.write_bytes(png_bytes(picture))
    mask.write_bytes(png_bytes(np.where(foreground, 255, 0).astype(np.uint8)))

    result = run_dlo("detect", image, "--mask", mask)

    assert result.exit_code == 0, result.stderr
    assert Detection.model_validate_json(result.stdout).chains


def test_mask_with_several_inputs_is_a_usage_error(tmp_path: Path, scene_png: Path) -> None:
    result = run_dlo(
        "detect", scene_png, scene_png, "--mask", scene_png, "--out-dir", tmp_path / "out"
    )

    assert result.exit_code == 2
    assert error_lines(result) == ["error: --mask applies to a single input image"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("value", ["0", "-3"])
def test_absurd_segment_length_is_a_one_line_usage_error(scene_png: Path, value: str) -> None:
    result = run_dlo("detect", scene_png, "--segment-length", value)

    assert result.exit_code == 2
    assert result.stdout == ""
    assert len(stderr_lines(result)) == 1
    assert stderr_lines(result)[0].startswith("error: --segment-length: ")
    assert "greater than" in stderr_lines(result)[0]


def test_inconsistent_hsv_bounds_are_a_one_line_usage_error(scene_png: Path) -> None:
    result = run_dlo(
        "detect", scene_png, "--segmentation", "hsv", "--hsv-low", "90", "0", "0",
        "--hsv-high", "10", "255", "255",
    )  # fmt: skip

    assert result.exit_code == 2
    assert len(stderr_lines(result)) == 1
    assert "exceeds" in stderr_lines(result)[0]


def test_hsv_segmentation_is_accepted(scene_png: Path) -> None:
    result = run_dlo(
        "detect", scene_png, "--segmentation", "hsv", "--hsv-low", "0", "0", "100",
        "--hsv-high", "179", "255", "255", "--expected-count", "2",
    )  # fmt: skip

    assert result.exit_code == 0, result.stderr
    assert len(Detection.model_validate_json(result.stdout).chains) == 2


def test_several_inputs_without_out_dir_is_a_usage_error(tmp_path: Path, scene_png: Path) -> None:
    other = tmp_path / "other.png"
    other.write_bytes(scene_png.read_bytes())

    result = run_dlo("detect", scene_png, other)

    assert result.exit_code == 2
    assert result.stdout == ""
    assert error_lines(result) == ["error: several inputs need --out-dir"]


def test_directory_without_images_is_reported(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()

    result = run_dlo("detect", empty, "--out-dir", tmp_path / "out")

    assert result.exit_code == 1
    errors = error_lines(result)
    assert len(errors) == 1
    assert errors[0].startswith(f"error: {empty}: directory holds no image")


def test_inputs_with_the_same_stem_do_not_overwrite_each_other(
    tmp_path: Path, scene_png: Path
) -> None:
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "scene.png").write_bytes(scene_png.read_bytes())

    result = run_dlo(
        "detect", tmp_path / "a" / "scene.png", tmp_path / "b" / "scene.png",
        "--out-dir", tmp_path / "out",
    )  # fmt: skip

    assert result.exit_code == 1
    errors = error_lines(result)
    assert len(errors) == 1
    assert errors[0].startswith(f"error: {tmp_path / 'b' / 'scene.png'}: outputs would overwrite")
    assert (tmp_path / "out" / "scene.json").is_file()


def test_unexpected_exception_is_one_line_and_the_batch_goes_on(
    tmp_path: Path, scene_png: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_detect_full = service.batch.detect_full

    def failing_on_first(image, params=None, mask=None, segmenter=None):
        if image.shape[1] == 320 and failing_on_first.calls == 0:
            failing_on_first.calls += 1
            raise RuntimeError("boom\nsecond line")
        return real_detect_full(image, params, mask=mask, segmenter=segmenter)

    failing_on_first.calls = 0
    monkeypatch.setattr(service.batch, "detect_full", failing_on_first)
    first, second = tmp_path / "first.png", tmp_path / "second.png"
    first.write_bytes(scene_png.read_bytes())
    second.write_bytes(scene_png.read_bytes())

    result = run_dlo("detect", first, second, "--out-dir", tmp_path / "out")

    assert result.exit_code == 1
    assert error_lines(result) == [
        f"error: {first}: internal error: RuntimeError: boom second line",
    ]
    assert (tmp_path / "out" / "second.json").is_file()
    assert_no_traceback(result)


def test_demo_writes_the_scene_and_the_outputs(tmp_path: Path) -> None:
    out_dir = tmp_path / "demo"

    result = run_dlo("demo", "--out-dir", out_dir, "--seed", "3")

    assert result.exit_code == 0, result.stderr
    written = [Path(line) for line in result.stdout.splitlines()]
    assert {path.name for path in written} == {
        "example.png",
        "example.json",
        "example.labels.png",
        "example.overlay.png",
    }
    assert all(path.is_file() for path in written)
    detection = Detection.model_validate_json((out_dir / "example.json").read_text())
    assert (detection.width, detection.height) == (1280, 720)
    assert "chain" in result.stderr


def test_version() -> None:
    result = run_dlo("version")

    assert result.exit_code == 0
    assert result.stdout.startswith("dlo-service ")


def test_installed_console_script_reports_a_bad_file_without_traceback(tmp_path: Path) -> None:
    dlo = Path(sys.executable).parent / "dlo"
    if not dlo.exists():
        pytest.skip("the dlo console script is not installed next to this Python")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n truncated")

    completed = subprocess.run(
        [str(dlo), "detect", str(bad)], capture_output=True, text=True, timeout=120, check=False
    )

    assert completed.returncode == 1
    assert completed.stdout == ""
    assert ANSI_ESCAPE.sub("", completed.stderr).strip() == f"error: {bad}: truncated PNG file"
