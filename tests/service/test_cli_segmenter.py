"""``dlo detect --segmenter-model`` and ``segmentation=model`` over HTTP."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest

from schemas import Detection
from tests.service.test_cli import assert_no_traceback, error_lines, run_dlo

pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
from tests.perception.test_segmenter import build_model, red_line_image


@pytest.fixture
def red_png(tmp_path: Path) -> Path:
    image, _ = red_line_image(320, 240)
    path = tmp_path / "red.png"
    assert cv2.imwrite(str(path), image)
    return path


def test_segmenter_model_makes_the_mask(tmp_path: Path, red_png: Path) -> None:
    model = build_model(tmp_path / "red.onnx")
    result = run_dlo("detect", red_png, "--segmenter-model", model)
    assert result.exit_code == 0, result.stderr
    assert len(Detection.model_validate_json(result.stdout).chains) == 1
    # The same with the method named, and for a folder of images.
    result = run_dlo("detect", red_png, "--segmentation", "model", "--segmenter-model", model)
    assert result.exit_code == 0, result.stderr
    result = run_dlo(
        "detect", red_png.parent, "--segmenter-model", model, "--out-dir", tmp_path / "o"
    )
    assert result.exit_code == 0, result.stderr
    assert (tmp_path / "o" / "red.json").is_file()


@pytest.mark.parametrize(
    ("make_args", "message"),
    [
        (lambda tmp: ["--segmenter-model", tmp / "none.onnx"], "none.onnx: no such file"),
        (lambda tmp: ["--segmentation", "model"], "--segmentation model needs --segmenter-model"),
        (
            lambda tmp: ["--segmenter-model", build_model(tmp / "m.onnx"), "--segmentation", "hsv"],
            "--segmenter-model cannot be used with --segmentation hsv",
        ),
        (
            lambda tmp: ["--segmenter-model", build_model(tmp / "m.onnx", channels=1)],
            "input of shape 1 x 1 x ? x ?",
        ),
    ],
    ids=["missing file", "no model", "another method", "wrong input shape"],
)
def test_bad_segmenter_options_are_one_line_usage_errors(tmp_path, red_png, make_args, message):
    result = run_dlo("detect", red_png, *make_args(tmp_path))
    assert result.exit_code == 2
    assert result.stdout == ""
    lines = error_lines(result)
    assert len(lines) == 1 and message in lines[0], lines
    assert_no_traceback(result)


def test_not_an_onnx_file_is_a_usage_error(tmp_path: Path, red_png: Path) -> None:
    junk = tmp_path / "junk.onnx"
    junk.write_text("not a model")
    result = run_dlo("detect", red_png, "--segmenter-model", junk)
    assert result.exit_code == 2
    assert len(error_lines(result)) == 1
    assert "not a valid ONNX model" in error_lines(result)[0]


def test_http_segmentation_model_is_422_without_a_model_and_works_with_one(tmp_path: Path) -> None:
    import httpx

    from service.http import Settings
    from tests.service.test_http import assert_error, encode, running_server

    image, _ = red_line_image(320, 240)
    body = encode(image)
    headers = {"Content-Type": "image/png"}
    with running_server(Settings(workers=1, zenoh=False)) as base:
        response = httpx.post(f"{base}/v1/detect?segmentation=model", content=body, headers=headers)
        assert_error(response, 422, "needs a segmenter")
    settings = Settings(workers=1, zenoh=False, segmenter_model=build_model(tmp_path / "m.onnx"))
    with running_server(settings) as base:
        response = httpx.post(f"{base}/v1/detect?segmentation=model", content=body, headers=headers)
        assert response.status_code == 200, response.text
        assert len(Detection.model_validate(response.json()).chains) == 1


def test_serve_with_a_missing_model_is_a_one_line_usage_error(tmp_path: Path) -> None:
    result = run_dlo("serve", "--no-zenoh", "--segmenter-model", tmp_path / "none.onnx")
    assert result.exit_code == 2
    assert "none.onnx: no such file" in result.stderr
    assert_no_traceback(result)
