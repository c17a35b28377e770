"""``dlo eval DATASET_DIR`` on a small fake data set made of synthetic scenes."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from schemas import Chain, Crossing, Detection
from service.cli import app
from service.evaluation.dataset import (
    IGNORE_LABEL,
    DatasetLayoutError,
    find_labelled_images,
    has_crossing_order_truth,
    ignored_pixels,
    label_on_top,
    match_chains,
    natural_key,
    read_mask,
    score_crossing_order,
    score_detection,
)
from service.evaluation.metrics import instance_dice
from service.perception import DetectionResult, render_labels
from service.synthetic import make_scene

ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")
runner = CliRunner()

SCENES = {"S1": (1, 2), "S2": (3,)}  # subset -> seeds; S1 one cable, S2 two


def run_dlo(*args):
    return runner.invoke(app, [str(arg) for arg in args], prog_name="dlo")


def error_lines(result) -> list[str]:
    lines = [ANSI_ESCAPE.sub("", line) for line in result.stderr.splitlines() if line.strip()]
    return [line for line in lines if line.startswith("error: ")]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``S1/images/img<seed>.jpg`` + ``S1/labels/img<seed>.png``, and likewise S2."""
    root = tmp_path_factory.mktemp("dataset")
    for subset, seeds in SCENES.items():
        (root / subset / "images").mkdir(parents=True)
        (root / subset / "labels").mkdir(parents=True)
        cables = int(subset[1:])
        for seed in seeds:
            scene = make_scene(480, 320, cables, seed=seed, loops=False)
            assert cv2.imwrite(str(root / subset / "images" / f"img{seed}.jpg"), scene.image)
            labels = scene.labels.astype(np.uint8)
            assert cv2.imwrite(str(root / subset / "labels" / f"img{seed}.png"), labels)
    return root


def test_fake_dataset_scores_high_and_the_csv_has_one_row_per_image(
    dataset: Path, tmp_path: Path
) -> None:
    table = tmp_path / "scores.csv"
    out_dir = tmp_path / "out"

    result = run_dlo("eval", dataset, "--csv", table, "--out-dir", out_dir, "--json")

    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["failed"] == 0
    [report] = data["datasets"]
    assert report["crossing_order_truth"] is True
    assert [s["subset"] for s in report["subsets"]] == ["S1", "S2"]
    assert [s["images"] for s in report["subsets"]] == [2, 1]
    assert report["all"]["images"] == 3
    assert report["all"]["mean_dice"] > 0.9
    assert report["all"]["mean_foreground_dice"] > 0.9

    with table.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == [
        "subset", "image", "dice", "foreground_dice", "n_gt", "n_chains",
        "crossings_judged", "crossings_correct", "ms",
    ]  # fmt: skip
    assert [(row["subset"], row["image"], row["n_gt"]) for row in rows] == [
        ("S1", "img1", "1"),
        ("S1", "img2", "1"),
        ("S2", "img3", "2"),
    ]
    assert np.mean([float(row["dice"]) for row in rows]) == pytest.approx(
        report["all"]["mean_dice"], abs=1e-3
    )
    assert all(float(row["ms"]) > 0 for row in rows)
    assert sorted(path.name for path in out_dir.iterdir() if path.name.startswith("S1_img1")) == [
        "S1_img1.json",
        "S1_img1.labels.png",
        "S1_img1.overlay.png",
    ]
    assert Detection.model_validate_json((out_dir / "S2_img3.json").read_text()).chains


def test_table_names_the_subsets_and_the_worst_images(dataset: Path) -> None:
    result = run_dlo("eval", dataset, "--mask-from-labels", "--worst", "1")

    assert result.exit_code == 0, result.stderr
    text = ANSI_ESCAPE.sub("", result.stdout)
    assert "mask from labels" in text
    for word in ("S1", "S2", "all", "mean DICE", "fg DICE", "crossing order", "worst 1"):
        assert word in text
    assert "self-crossing" in text


def test_missing_or_empty_dataset_is_a_one_line_usage_error(tmp_path: Path) -> None:
    missing = run_dlo("eval", tmp_path / "nowhere")
    (tmp_path / "empty" / "S1" / "images").mkdir(parents=True)
    (tmp_path / "empty" / "S1" / "labels").mkdir(parents=True)
    empty = run_dlo("eval", tmp_path / "empty")

    assert missing.exit_code == 2
    assert error_lines(missing) == [f"error: {tmp_path / 'nowhere'}: no such directory"]
    assert empty.exit_code == 2
    assert len(error_lines(empty)) == 1
    assert "no labelled image" in error_lines(empty)[0]
    for result in (missing, empty):
        assert result.stdout == ""
        assert "Traceback" not in result.stderr


def test_bad_label_file_is_reported_and_the_rest_scored(dataset: Path, tmp_path: Path) -> None:
    root = tmp_path / "data"
    (root / "S1" / "images").mkdir(parents=True)
    (root / "S1" / "labels").mkdir(parents=True)
    for name in ("img1.jpg", "img2.jpg"):
        (root / "S1" / "images" / name).write_bytes((dataset / "S1" / "images" / name).read_bytes())
    (root / "S1" / "labels" / "img1.png").write_bytes(b"not a png")
    (root / "S1" / "labels" / "img2.png").write_bytes(
        (dataset / "S1" / "labels" / "img2.png").read_bytes()
    )

    result = run_dlo("eval", root, "--json")

    assert result.exit_code == 1
    assert len(error_lines(result)) == 1
    assert error_lines(result)[0].startswith(f"error: {root / 'S1' / 'labels' / 'img1.png'}: ")
    assert json.loads(result.stdout)["datasets"][0]["all"]["images"] == 1


def test_images_are_found_in_natural_order_and_unlabelled_ones_reported(tmp_path: Path) -> None:
    for folder in ("S10/images", "S10/labels", "S2/images", "S2/labels", "notes"):
        (tmp_path / folder).mkdir(parents=True)
    for name in ("img10.jpg", "img2.jpg", "img1.jpg"):
        (tmp_path / "S2" / "images" / name).write_bytes(b"")
        (tmp_path / "S2" / "labels" / name.replace(".jpg", ".png")).write_bytes(b"")
    (tmp_path / "S10" / "images" / "img0.jpg").write_bytes(b"")

    with pytest.raises(DatasetLayoutError, match="no such directory"):
        find_labelled_images(tmp_path / "missing")
    items, unlabelled = find_labelled_images(tmp_path)

    assert [(item.subset, item.name) for item in items] == [
        ("S2", "img1"),
        ("S2", "img2"),
        ("S2", "img10"),
    ]
    assert unlabelled == [f"{tmp_path / 'S10' / 'images' / 'img0.jpg'}: no label image"]
    assert sorted(["a10", "a9", "b1"], key=natural_key) == ["a9", "a10", "b1"]


# --------------------------------------------------------------------------- crossing order


def cross_scene(top: int) -> tuple[np.ndarray, Detection]:
    """A horizontal (label 1) and a vertical (label 2) bar; label ``top`` at the crossing."""
    truth = np.zeros((100, 120), np.uint8)
    horizontal = (slice(46, 55), slice(5, 115))
    vertical = (slice(5, 95), slice(56, 65))
    first, second = (vertical, horizontal) if top == 1 else (horizontal, vertical)
    truth[first] = 2 if first is vertical else 1
    truth[second] = 2 if second is vertical else 1
    chains = [
        Chain(id=0, points=[(60, 10), (60, 50), (60, 90)], radius=4, inferred=[False] * 2),
        Chain(id=1, points=[(10, 50), (60, 50), (110, 50)], radius=4, inferred=[False] * 2),
    ]
    return truth, Detection(width=120, height=100, segment_length=40, chains=chains)


def with_crossing(detection: Detection, over: int, under: int) -> Detection:
    crossing = Crossing(
        x=60, y=50, over=over, under=under, over_segment=0, under_segment=0, confidence=1
    )
    return detection.model_copy(update={"crossings": [crossing]})


def test_crossing_order_is_judged_from_the_label_on_top() -> None:
    truth, detection = cross_scene(top=1)  # the horizontal bar is on top
    predicted = render_labels(detection, truth > 0)

    assert match_chains(truth, predicted) == {1: 2, 2: 1}
    assert label_on_top(truth, 60, 50, 2.0) == 1
    right = score_crossing_order(with_crossing(detection, over=1, under=0), truth, predicted)
    wrong = score_crossing_order(with_crossing(detection, over=0, under=1), truth, predicted)
    loop = score_crossing_order(with_crossing(detection, over=0, under=0), truth, predicted)

    assert (right.detected, right.judged, right.correct) == (1, 1, 1)
    assert (wrong.judged, wrong.correct) == (1, 0)
    assert (loop.self_crossings, loop.judged, loop.correct) == (1, 0, 0)


def test_crossing_order_with_the_other_bar_on_top() -> None:
    truth, detection = cross_scene(top=2)
    predicted = render_labels(detection, truth > 0)

    score = score_crossing_order(with_crossing(detection, over=0, under=1), truth, predicted)

    assert (score.judged, score.correct) == (1, 1)


# --------------------------------------------------------------------------- ariadne's layout

ARIADNE_SEEDS = {"simple": (1, 2), "hard": (4,)}  # two cables crossing in each


def ariadne_labels(scene) -> np.ndarray:
    """Labels as ariadne gives them: every cable in full, 255 where two overlap."""
    labels = scene.labels.astype(np.uint8)
    rows, cols = np.indices(labels.shape)
    for crossing in scene.crossings:
        reach = max(scene.cables[crossing.over].radius, scene.cables[crossing.under].radius)
        disc = (cols - crossing.x) ** 2 + (rows - crossing.y) ** 2 <= reach**2
        labels[disc & scene.mask] = 255
    return labels


@pytest.fixture(scope="module")
def ariadne_like(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``<subset>/images``, ``labels`` (255 at crossings) and ``masks`` (0/255)."""
    root = tmp_path_factory.mktemp("ariadne")
    for subset, seeds in ARIADNE_SEEDS.items():
        for folder in ("images", "labels", "masks"):
            (root / subset / folder).mkdir(parents=True)
        for seed in seeds:
            scene = make_scene(480, 320, 2, seed=seed, loops=False)
            assert any(c.over != c.under for c in scene.crossings)
            name = f"{seed:05d}"
            assert cv2.imwrite(str(root / subset / "images" / f"{name}.jpg"), scene.image)
            assert cv2.imwrite(str(root / subset / "labels" / f"{name}.png"), ariadne_labels(scene))
            mask = scene.mask.astype(np.uint8) * 255
            assert cv2.imwrite(str(root / subset / "masks" / f"{name}.png"), mask)
    return root


def test_overlap_pixels_are_left_out_of_prediction_and_truth() -> None:
    truth, detection = cross_scene(top=1)
    truth[46:55, 56:65] = IGNORE_LABEL  # both bars claim the crossing
    predicted = render_labels(detection, truth > 0)
    result = DetectionResult(detection, truth > 0, truth > 0, [])

    dice, crossings, _ = score_detection(result, truth, judge_crossings=False)

    # The chains follow the bars exactly; only the crossing square, which the prediction
    # gives to one of them, differs, and it is left out.
    assert dice == 1.0
    assert instance_dice(truth, predicted) < 0.7  # 255 counted as a third cable
    assert (crossings.detected, crossings.judged) == (0, 0)
    assert ignored_pixels(truth).sum() == 81
    assert ignored_pixels(truth.astype(np.uint16)) is None  # 255 is an id in 16-bit labels


def test_masks_are_found_and_overlap_labels_mean_no_order_truth(
    ariadne_like: Path, dataset: Path
) -> None:
    items, unlabelled = find_labelled_images(ariadne_like)

    assert unlabelled == []
    assert [(item.subset, item.name) for item in items] == [
        ("hard", "00004"),
        ("simple", "00001"),
        ("simple", "00002"),
    ]
    assert all(
        item.mask == item.labels.parent.parent / "masks" / item.labels.name for item in items
    )
    assert read_mask(items[0].mask).dtype == bool
    assert has_crossing_order_truth(items) is False
    mbest_like, _ = find_labelled_images(dataset)
    assert all(item.mask is None for item in mbest_like)
    assert has_crossing_order_truth(mbest_like) is True


def test_dlo_eval_reads_ariadne_layout(ariadne_like: Path, tmp_path: Path) -> None:
    table = tmp_path / "scores.csv"
    result = run_dlo("eval", ariadne_like, "--mask-from-labels", "--json", "--csv", table)

    assert result.exit_code == 0, result.stderr
    [report] = json.loads(result.stdout)["datasets"]
    assert report["crossing_order_truth"] is False
    assert [s["subset"] for s in report["subsets"]] == ["hard", "simple"]
    assert report["all"]["mean_dice"] > 0.9
    assert report["all"]["mean_foreground_dice"] > 0.99
    assert report["all"]["crossings_judged"] == 0
    with table.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [row["n_gt"] for row in rows] == ["2", "2", "2"]  # 255 is no cable


def test_mask_from_labels_uses_the_masks_folder(ariadne_like: Path, tmp_path: Path) -> None:
    root = tmp_path / "data"
    (root / "S").mkdir(parents=True)
    for folder in ("images", "labels"):
        (root / "S" / folder).symlink_to(ariadne_like / "simple" / folder)
    without_masks = run_dlo("eval", root, "--mask-from-labels", "--json")
    (root / "S" / "masks").mkdir()
    for seed in ARIADNE_SEEDS["simple"]:
        # A mask of the left half of the cables only.
        mask = cv2.imread(str(ariadne_like / "simple" / "masks" / f"{seed:05d}.png"), 0)
        mask[:, 240:] = 0
        assert cv2.imwrite(str(root / "S" / "masks" / f"{seed:05d}.png"), mask)
    with_half_masks = run_dlo("eval", root, "--mask-from-labels", "--json")

    assert without_masks.exit_code == 0, without_masks.stderr
    whole = json.loads(without_masks.stdout)["datasets"][0]["all"]
    assert whole["mean_dice"] > 0.9
    assert with_half_masks.exit_code == 0, with_half_masks.stderr
    half = json.loads(with_half_masks.stdout)["datasets"][0]["all"]
    # The detector was given the half masks: it misses the right half of every cable, and
    # its foreground is scored against them.
    assert half["mean_dice"] < whole["mean_dice"] - 0.2
    assert half["mean_foreground_dice"] > 0.99


def test_two_data_sets_in_one_table(dataset: Path, ariadne_like: Path, tmp_path: Path) -> None:
    table = tmp_path / "both.csv"
    as_json = run_dlo("eval", dataset, ariadne_like, "--mask-from-labels", "--json", "--csv", table)
    as_table = run_dlo("eval", dataset, ariadne_like, "--mask-from-labels", "--worst", "1")

    assert as_json.exit_code == 0, as_json.stderr
    reports = json.loads(as_json.stdout)["datasets"]
    assert [Path(r["dataset"]).name for r in reports] == [dataset.name, ariadne_like.name]
    assert [r["crossing_order_truth"] for r in reports] == [True, False]
    with table.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert {row["dataset"] for row in rows} == {dataset.name, ariadne_like.name}
    assert as_table.exit_code == 0, as_table.stderr
    text = ANSI_ESCAPE.sub("", as_table.stdout)
    for word in (dataset.name, ariadne_like.name, "data set", "fg DICE", "n/a", "255"):
        assert word in text
