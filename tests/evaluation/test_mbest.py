"""The CLI on real photographs from ../shared/datasets/mbest (skipped when absent)."""

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from service.evaluation.metrics import instance_dice

DATASET = Path(__file__).resolve().parents[2].parent / "shared" / "datasets" / "mbest"
# A few images of each subset: 1, 2 and 3 cables, with loops and crossings.
SAMPLES = {"S1": (0, 9), "S2": (3, 21), "S3": (7, 30)}

pytestmark = [
    pytest.mark.shared_data,
    pytest.mark.skipif(not DATASET.is_dir(), reason=f"{DATASET} is absent"),
]


def test_cli_on_photographs_scores_mean_instance_dice_above_0_9(tmp_path):
    images = [
        DATASET / subset / "images" / f"img{index}.jpg"
        for subset, indices in SAMPLES.items()
        for index in indices
    ]
    completed = subprocess.run(
        [sys.executable, "-c", "from service.cli import main; main()", "detect"]
        + [str(p) for p in images]
        + ["--out-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    scores = []
    for image in images:
        truth = cv2.imread(str(image.parent.parent / "labels" / f"{image.stem}.png"), 0)
        predicted = cv2.imread(str(tmp_path / f"{image.stem}.labels.png"), cv2.IMREAD_UNCHANGED)
        assert predicted.dtype == np.uint16 and predicted.shape == truth.shape
        scores.append(instance_dice(truth, predicted))
    assert np.mean(scores) > 0.9, scores
