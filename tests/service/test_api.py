"""The Python API: detect / render_* on generated scenes, from threads, and its examples."""

from __future__ import annotations

import doctest
import inspect
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest

import service.batch
import service.video
from schemas import Detection, DetectParams
from service.perception import detect, detect_full, render_labels, render_overlay
from service.synthetic import make_scene

SCENES = 6


@pytest.fixture(scope="module")
def scenes() -> list[np.ndarray]:
    return [make_scene(480, 320, 2, seed=seed).image for seed in range(SCENES)]


def without_timings(detection: Detection) -> dict:
    return detection.model_dump(exclude={"timings_ms"})


def test_detect_returns_a_detection_for_each_scene(scenes: list[np.ndarray]) -> None:
    for image in scenes:
        detection = detect(image)
        assert isinstance(detection, Detection)
        assert (detection.width, detection.height) == (480, 320)
        assert detection.chains
        assert Detection.model_validate_json(detection.model_dump_json()) == detection


def test_detect_from_several_threads_gives_the_sequential_results(
    scenes: list[np.ndarray],
) -> None:
    params = DetectParams(segment_length=12)
    sequential = [without_timings(detect(image, params)) for image in scenes]

    # Every scene twice, so that threads also run the same image at the same time.
    with ThreadPoolExecutor(max_workers=4) as pool:
        threaded = list(pool.map(lambda image: detect(image, params), scenes + scenes))

    assert [without_timings(detection) for detection in threaded] == sequential + sequential


def test_rendering_from_several_threads_gives_the_sequential_results(
    scenes: list[np.ndarray],
) -> None:
    results = [detect_full(image) for image in scenes]

    def render(index: int) -> tuple[np.ndarray, np.ndarray]:
        result = results[index]
        return (
            render_labels(result.detection, result.mask),
            render_overlay(scenes[index], result.detection),
        )

    sequential = [render(index) for index in range(SCENES)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        threaded = list(pool.map(render, range(SCENES)))

    for (labels, overlay), (labels_t, overlay_t) in zip(sequential, threaded, strict=True):
        assert labels.dtype == np.uint16 and labels.shape == (320, 480)
        assert overlay.dtype == np.uint8 and overlay.shape == (320, 480, 3)
        np.testing.assert_array_equal(labels, labels_t)
        np.testing.assert_array_equal(overlay, overlay_t)


def test_detect_leaves_its_input_untouched(scenes: list[np.ndarray]) -> None:
    image = scenes[0].copy()
    detect(image)
    render_overlay(image, detect(image))
    np.testing.assert_array_equal(image, scenes[0])


def test_readme_snippet_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    cv2.imwrite("photo.jpg", make_scene(480, 320, 2, seed=1).image)

    # The five lines of the README's Python API section.
    image = cv2.imread("photo.jpg")  # BGR uint8
    detection = detect(image)  # schemas.Detection
    for chain in detection.chains:
        print(chain.id, len(chain.points), "joints,", f"{chain.length:.0f} px")
    cv2.imwrite("overlay.png", render_overlay(image, detection))

    assert len(detection.chains) == 2
    assert cv2.imread("overlay.png").shape == (320, 480, 3)


@pytest.mark.parametrize(
    "function",
    [detect, detect_full, render_labels, render_overlay],
    ids=lambda function: function.__name__,
)
def test_api_docstring_examples_run(function) -> None:
    run_examples(function)


@pytest.mark.parametrize("module", [service.video, service.batch], ids=lambda m: m.__name__)
def test_module_docstring_examples_run(module) -> None:
    run_examples(module)


def run_examples(target) -> None:
    """Run the ``>>>`` examples in the docstrings of a function or a module."""
    module = target if inspect.ismodule(target) else inspect.getmodule(target)
    runner = doctest.DocTestRunner()
    for test in doctest.DocTestFinder().find(target, module=module, globs=vars(module).copy()):
        failed, _ = runner.run(test)
        assert failed == 0, f"example in {test.name} failed (see the captured output)"
