"""Scoring detections against a labelled data set of photographs (``dlo eval DIR``).

The layout is that of ``../shared/datasets/mbest`` and ``../shared/datasets/ariadne``: one
folder per subset, each with an ``images`` and a ``labels`` folder and optionally a
``masks`` folder; an image, its label image and its mask share a file stem::

    DATASET_DIR/S1/images/img0.jpg    the photograph
    DATASET_DIR/S1/labels/img0.png    0 = background, 1..K = cable instance
    DATASET_DIR/S1/masks/img0.png     optional: the true foreground (nonzero = cable)

In an 8-bit label image the value 255 (:data:`IGNORE_LABEL`) marks pixels that belong to
no single cable: ariadne labels every cable in full, so where two cables' masks overlap
(at a crossing) the pixels carry 255. They are left out of the instance score, in the
prediction and in the truth alike. The true foreground is the ``masks/`` image where
there is one, otherwise ``labels > 0`` (255 included: those pixels are cable).

Three scores per image:

instance DICE
    :func:`service.evaluation.metrics.instance_dice` of the ground-truth labels and the
    label image :func:`service.perception.render_labels` makes of the detection, with
    the 255 pixels left out.
foreground DICE
    :func:`service.evaluation.metrics.foreground_dice` of the detector's foreground mask
    and the true foreground: how good the segmentation is, apart from the instances
    (1.0 by construction when the detector is given the true mask).
crossing order
    The label images show only the cable on top at a crossing, which is enough to
    judge the order the detector gave a crossing: each chain is matched to a
    ground-truth instance by the same Hungarian assignment on pairwise DICE as the
    instance DICE. A detected crossing whose ``over`` and ``under`` chains are matched
    to two *different* instances is judged: the ground-truth label that holds the
    majority of the labelled pixels in a disc of radius ``max(1, r / 2)`` around the
    crossing (``r`` the radius of the ``over`` chain) is the cable on top, and the
    crossing is correct when that is the instance matched to ``over``. Crossings of a
    chain with itself (a loop) cannot be judged from labels, nor crossings whose
    chains are unmatched or matched to one instance, nor those with no labelled pixel
    in the disc; they are counted but not judged. A data set whose label images mark
    overlaps with 255 (ariadne) says nothing about which cable is on top, so its
    crossings are not judged at all (:func:`has_crossing_order_truth`).

Everything here is a pure function of arrays except the two readers of files.
"""

from __future__ import annotations

import os
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from schemas import Detection, DetectParams
from service.evaluation.metrics import foreground_dice, instance_dice, pairwise_dice
from service.imageio import IMAGE_SUFFIXES, ImageFileError
from service.perception import DetectionResult, detect_full, render_labels

IMAGES_FOLDER = "images"
LABELS_FOLDER = "labels"
MASKS_FOLDER = "masks"
IGNORE_LABEL = 255
"""In an 8-bit label image: a pixel of two cables at once (left out of the score)."""


class DatasetLayoutError(ValueError):
    """The data-set folder does not exist or holds no labelled image; one-line message."""


@dataclass(frozen=True)
class LabelledImage:
    """One image of a data set, its ground-truth label image and its mask, if any."""

    subset: str
    image: Path
    labels: Path
    mask: Path | None = None

    @property
    def name(self) -> str:
        """The image's file stem, e.g. ``img12``."""
        return self.image.stem


@dataclass(frozen=True)
class CrossingOrderScore:
    """How the detected crossings of one image fare against the label image.

    Attributes
    ----------
    detected : int
        Crossings in the detection.
    self_crossings : int
        Of those, crossings of a chain with itself (not judged).
    judged : int
        Crossings between chains matched to two different ground-truth instances,
        with labelled pixels at the crossing.
    correct : int
        Judged crossings whose ``over`` chain is matched to the instance on top.
    """

    detected: int = 0
    self_crossings: int = 0
    judged: int = 0
    correct: int = 0


@dataclass(frozen=True)
class ImageScore:
    """The scores of one image.

    Attributes
    ----------
    subset, image : str
        Subset folder name and image stem.
    dice : float
        Mean instance DICE.
    foreground_dice : float
        DICE of the detector's foreground mask against the true foreground.
    n_gt, n_chains : int
        Ground-truth instances and detected chains.
    crossings : CrossingOrderScore
    ms : float
        Wall time of the detection alone (no file I/O, no scoring), milliseconds.
    """

    subset: str
    image: str
    dice: float
    foreground_dice: float
    n_gt: int
    n_chains: int
    crossings: CrossingOrderScore
    ms: float


@dataclass(frozen=True)
class SubsetSummary:
    """Scores of the images of one subset (or of all of them).

    Attributes
    ----------
    subset : str
    images : int
    mean_dice, min_dice : float
        NaN when ``images`` is 0.
    mean_foreground_dice : float
        Mean of the images' foreground DICE; NaN when ``images`` is 0.
    worst : tuple of (str, float)
        The lowest-scoring images, lowest first, as (stem, DICE).
    crossings_detected, crossings_self, crossings_judged, crossings_correct : int
        Sums of :class:`CrossingOrderScore` over the images.
    mean_ms : float
        Mean detection time per image.
    """

    subset: str
    images: int
    mean_dice: float
    min_dice: float
    mean_foreground_dice: float
    worst: tuple[tuple[str, float], ...]
    crossings_detected: int
    crossings_self: int
    crossings_judged: int
    crossings_correct: int
    mean_ms: float

    @property
    def crossing_accuracy(self) -> float:
        """Correct over judged crossings; NaN when none was judged."""
        if self.crossings_judged == 0:
            return float("nan")
        return self.crossings_correct / self.crossings_judged


def natural_key(text: str) -> tuple:
    """Sort key that orders embedded numbers by value: ``img2`` before ``img10``."""
    return tuple(
        (0, int(part), "") if part.isdigit() else (1, 0, part.lower())
        for part in re.split(r"(\d+)", text)
        if part
    )


def find_labelled_images(root: str | os.PathLike[str]) -> tuple[list[LabelledImage], list[str]]:
    """Every image of a data set that has a label image, subset by subset.

    Parameters
    ----------
    root : str or Path
        The data-set folder: its subfolders holding ``images/`` and ``labels/`` are the
        subsets (sorted by name, numbers by value). A folder that itself holds
        ``images/`` and ``labels/`` is one subset named after the folder. A subset's
        ``masks/<stem>.png``, where present, is the image's true foreground.

    Returns
    -------
    items : list of LabelledImage
        In subset order, then image order (numbers by value).
    unlabelled : list of str
        ``"<image>: no label image"`` for each image without a ``labels/<stem>.png``.

    Raises
    ------
    DatasetLayoutError
        ``root`` is missing, not a folder, or holds no labelled image.
    """
    root = Path(root)
    if not root.exists():
        raise DatasetLayoutError(f"{root}: no such directory")
    if not root.is_dir():
        raise DatasetLayoutError(f"{root}: not a directory")
    if _is_subset(root):
        subsets = [root]
    else:
        subsets = sorted(
            (entry for entry in root.iterdir() if _is_subset(entry)),
            key=lambda entry: natural_key(entry.name),
        )
    items: list[LabelledImage] = []
    unlabelled: list[str] = []
    for folder in subsets:
        labels = _files_by_stem(folder / LABELS_FOLDER)
        masks = _files_by_stem(folder / MASKS_FOLDER) if (folder / MASKS_FOLDER).is_dir() else {}
        images = sorted(
            (
                entry
                for entry in (folder / IMAGES_FOLDER).iterdir()
                if entry.suffix.lower() in IMAGE_SUFFIXES
                and not entry.name.startswith(".")
                and entry.is_file()
            ),
            key=lambda entry: natural_key(entry.name),
        )
        for image in images:
            if image.stem in labels:
                items.append(
                    LabelledImage(folder.name, image, labels[image.stem], masks.get(image.stem))
                )
            else:
                unlabelled.append(f"{image}: no label image")
    if not items:
        raise DatasetLayoutError(
            f"{root}: no labelled image (expected <subset>/{IMAGES_FOLDER}/<name>.jpg "
            f"with <subset>/{LABELS_FOLDER}/<name>.png)"
        )
    return items, unlabelled


def _files_by_stem(folder: Path) -> dict[str, Path]:
    return {
        entry.stem: entry
        for entry in folder.iterdir()
        if entry.suffix.lower() in IMAGE_SUFFIXES and entry.is_file()
    }


def _is_subset(folder: Path) -> bool:
    return (folder / IMAGES_FOLDER).is_dir() and (folder / LABELS_FOLDER).is_dir()


def read_labels(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a ground-truth label image as a 2-D integer array.

    Raises
    ------
    ImageFileError
        The file is missing, unreadable, not an image, or has colour channels that
        differ (a label image has one channel).
    """
    try:
        buffer = np.fromfile(Path(path), dtype=np.uint8)
    except OSError as exc:
        raise ImageFileError(path, f"cannot read: {exc.strerror or exc}") from None
    if buffer.size == 0:
        raise ImageFileError(path, "empty file (0 bytes)")
    labels = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
    if labels is None or labels.size == 0:
        raise ImageFileError(path, "not an image, or a format OpenCV cannot decode")
    if labels.ndim == 3:
        if not all(np.array_equal(labels[:, :, 0], labels[:, :, k]) for k in (1, 2)):
            raise ImageFileError(path, "label image has differing colour channels")
        labels = labels[:, :, 0]
    if labels.dtype.kind not in "ui":
        raise ImageFileError(path, f"label image has non-integer samples ({labels.dtype})")
    return labels


def read_mask(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a true-foreground mask (nonzero = cable) as a boolean array.

    Raises
    ------
    ImageFileError
        As :func:`read_labels`.
    """
    return read_labels(path) > 0


def ignored_pixels(truth: np.ndarray) -> np.ndarray | None:
    """Pixels of an 8-bit label image marked :data:`IGNORE_LABEL`, or None if there are none."""
    if truth.dtype != np.uint8:
        return None
    ignore = truth == IGNORE_LABEL
    return ignore if ignore.any() else None


def has_crossing_order_truth(items: Sequence[LabelledImage]) -> bool:
    """Whether the label images show the cable on top at a crossing.

    A data set that labels every cable in full marks the overlaps with
    :data:`IGNORE_LABEL` and so says nothing about the order: False when any of its
    label images has such a pixel. Unreadable label images are passed over here (the
    evaluation reports them).
    """
    for item in items:
        try:
            if ignored_pixels(read_labels(item.labels)) is not None:
                return False
        except ImageFileError:
            continue
    return True


def match_chains(
    truth: np.ndarray, predicted: np.ndarray, ignore: np.ndarray | None = None
) -> dict[int, int]:
    """Predicted instance -> ground-truth instance, by Hungarian assignment on DICE.

    The assignment is the one :func:`~service.evaluation.metrics.instance_dice` makes
    (``ignore``: pixels left out of both); pairs that do not overlap at all are left out.

    Returns
    -------
    dict
        Predicted label value -> ground-truth label value.
    """
    dice, truth_ids, predicted_ids = pairwise_dice(truth, predicted, ignore)
    if dice.size == 0:
        return {}
    rows, cols = linear_sum_assignment(dice, maximize=True)
    return {
        int(predicted_ids[col]): int(truth_ids[row])
        for row, col in zip(rows, cols, strict=True)
        if dice[row, col] > 0
    }


def label_on_top(truth: np.ndarray, x: float, y: float, radius: float) -> int:
    """The ground-truth label most of the labelled pixels near ``(x, y)`` have.

    Parameters
    ----------
    truth : ndarray
        Ground-truth label image.
    x, y : float
        Centre of the disc (px).
    radius : float
        Disc radius (px); at least 1 is used.

    Returns
    -------
    int
        The majority non-zero label in the disc; 0 when it has no labelled pixel.
        Ties go to the smaller label.
    """
    height, width = truth.shape
    reach = max(1.0, float(radius))
    x0, x1 = max(0, int(np.floor(x - reach))), min(width - 1, int(np.ceil(x + reach)))
    y0, y1 = max(0, int(np.floor(y - reach))), min(height - 1, int(np.ceil(y + reach)))
    if x0 > x1 or y0 > y1:
        return 0
    rows, cols = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
    inside = (cols - x) ** 2 + (rows - y) ** 2 <= reach**2
    values = truth[y0 : y1 + 1, x0 : x1 + 1][inside]
    values = values[values > 0]
    if values.size == 0:
        return 0
    found, counts = np.unique(values, return_counts=True)
    return int(found[np.argmax(counts)])


def score_crossing_order(
    detection: Detection, truth: np.ndarray, predicted: np.ndarray
) -> CrossingOrderScore:
    """Judge the over/under order of the detected crossings against a label image.

    See the module docstring for the rule.

    Parameters
    ----------
    detection : Detection
    truth : ndarray
        Ground-truth label image.
    predicted : ndarray
        :func:`render_labels` of ``detection`` (chain ``i`` labelled ``i + 1``).

    Returns
    -------
    CrossingOrderScore
    """
    to_truth = match_chains(truth, predicted)
    self_crossings = judged = correct = 0
    for crossing in detection.crossings:
        if crossing.over == crossing.under:
            self_crossings += 1
            continue
        over_truth = to_truth.get(crossing.over + 1)
        under_truth = to_truth.get(crossing.under + 1)
        if over_truth is None or under_truth is None or over_truth == under_truth:
            continue
        radius = detection.chain(crossing.over).radius / 2.0
        on_top = label_on_top(truth, crossing.x, crossing.y, radius)
        if on_top == 0:
            continue
        judged += 1
        correct += int(on_top == over_truth)
    return CrossingOrderScore(len(detection.crossings), self_crossings, judged, correct)


def score_detection(
    result: DetectionResult,
    truth: np.ndarray,
    image: np.ndarray | None = None,
    *,
    judge_crossings: bool = True,
) -> tuple[float, CrossingOrderScore, np.ndarray]:
    """Instance DICE and crossing order of one detection against its label image.

    ``image`` (BGR), when given, lets the label image split crossings by colour, as
    ``dlo detect`` does (:func:`service.perception.render_labels`). Pixels labelled
    :data:`IGNORE_LABEL` are left out of the DICE. With ``judge_crossings`` False (a data
    set without over/under truth) the crossings are counted but none is judged.

    Returns
    -------
    dice : float
    crossings : CrossingOrderScore
    predicted : ndarray
        The predicted label image (``uint16``) both were computed from.
    """
    if truth.shape != result.mask.shape:
        raise ValueError(
            f"labels are {truth.shape[1]}x{truth.shape[0]} but the image is "
            f"{result.mask.shape[1]}x{result.mask.shape[0]}"
        )
    predicted = render_labels(result.detection, result.mask, image)
    dice = instance_dice(truth, predicted, ignored_pixels(truth))
    if judge_crossings:
        crossings = score_crossing_order(result.detection, truth, predicted)
    else:
        detected = result.detection.crossings
        crossings = CrossingOrderScore(
            detected=len(detected),
            self_crossings=sum(crossing.over == crossing.under for crossing in detected),
        )
    return dice, crossings, predicted


def evaluate_image(
    image: np.ndarray,
    truth: np.ndarray,
    *,
    subset: str = "",
    name: str = "",
    params: DetectParams | None = None,
    mask_from_labels: bool = False,
    truth_mask: np.ndarray | None = None,
    judge_crossings: bool = True,
) -> tuple[ImageScore, DetectionResult, np.ndarray]:
    """Detect the cables in one image and score the detection.

    Parameters
    ----------
    image : ndarray
        BGR image.
    truth : ndarray
        Its ground-truth label image, same height and width.
    subset, name : str
        Carried into the :class:`ImageScore`.
    params : DetectParams, optional
        Defaults when None.
    mask_from_labels : bool
        Give the detector the true foreground as its mask (the image is still given,
        for the order of the strands at crossings).
    truth_mask : ndarray of bool, optional
        The true foreground (a data set's ``masks/`` image); ``truth > 0`` when None.
    judge_crossings : bool
        False for a data set whose labels have no over/under truth.

    Returns
    -------
    score : ImageScore
    result : DetectionResult
    predicted : ndarray
        The predicted label image.

    Raises
    ------
    ValueError
        The image, the labels and the mask differ in size.
    InvalidInputError
        The detector cannot use the image or the mask.
    """
    for what, array in (("labels", truth), ("mask", truth_mask)):
        if array is not None and array.shape[:2] != image.shape[:2]:
            raise ValueError(
                f"{what} are {array.shape[1]}x{array.shape[0]} but the image is "
                f"{image.shape[1]}x{image.shape[0]}"
            )
    foreground = truth > 0 if truth_mask is None else np.asarray(truth_mask, dtype=bool)
    started = time.perf_counter()
    result = detect_full(image, params, mask=foreground if mask_from_labels else None)
    elapsed_ms = (time.perf_counter() - started) * 1000.0
    dice, crossings, predicted = score_detection(
        result, truth, image, judge_crossings=judge_crossings
    )
    instances = np.unique(truth[truth > 0])
    if ignored_pixels(truth) is not None:
        instances = instances[instances != IGNORE_LABEL]
    score = ImageScore(
        subset=subset,
        image=name,
        dice=dice,
        foreground_dice=foreground_dice(foreground, result.mask),
        n_gt=len(instances),
        n_chains=len(result.detection.chains),
        crossings=crossings,
        ms=elapsed_ms,
    )
    return score, result, predicted


def summarise(
    scores: Sequence[ImageScore], subset: str, worst: int = 3, *, qualify: bool = False
) -> SubsetSummary:
    """Aggregate image scores into one :class:`SubsetSummary`.

    Parameters
    ----------
    scores : sequence of ImageScore
    subset : str
        Name of the summary (``"all"`` for every subset together).
    worst : int
        How many of the lowest-scoring images to keep.
    qualify : bool
        Name the worst images ``<subset>/<stem>`` rather than ``<stem>``.
    """
    dice = np.array([score.dice for score in scores], dtype=np.float64)
    lowest = sorted(range(len(scores)), key=lambda k: (scores[k].dice, k))[: max(worst, 0)]
    return SubsetSummary(
        subset=subset,
        images=len(scores),
        mean_dice=float(dice.mean()) if len(dice) else float("nan"),
        min_dice=float(dice.min()) if len(dice) else float("nan"),
        mean_foreground_dice=(
            float(np.mean([score.foreground_dice for score in scores])) if scores else float("nan")
        ),
        worst=tuple(
            (
                f"{scores[k].subset}/{scores[k].image}" if qualify else scores[k].image,
                scores[k].dice,
            )
            for k in lowest
        ),
        crossings_detected=sum(score.crossings.detected for score in scores),
        crossings_self=sum(score.crossings.self_crossings for score in scores),
        crossings_judged=sum(score.crossings.judged for score in scores),
        crossings_correct=sum(score.crossings.correct for score in scores),
        mean_ms=float(np.mean([score.ms for score in scores])) if scores else float("nan"),
    )


def summarise_by_subset(
    scores: Sequence[ImageScore], worst: int = 3
) -> tuple[list[SubsetSummary], SubsetSummary]:
    """One summary per subset (in order of first appearance) and one of all images."""
    subsets: dict[str, list[ImageScore]] = {}
    for score in scores:
        subsets.setdefault(score.subset, []).append(score)
    per_subset = [summarise(items, name, worst) for name, items in subsets.items()]
    return per_subset, summarise(scores, "all", worst, qualify=True)


CSV_COLUMNS = (
    "subset",
    "image",
    "dice",
    "foreground_dice",
    "n_gt",
    "n_chains",
    "crossings_judged",
    "crossings_correct",
    "ms",
)


def csv_row(score: ImageScore) -> dict[str, str]:
    """One row of the ``--csv`` file (see :data:`CSV_COLUMNS`)."""
    return {
        "subset": score.subset,
        "image": score.image,
        "dice": f"{score.dice:.4f}",
        "foreground_dice": f"{score.foreground_dice:.4f}",
        "n_gt": str(score.n_gt),
        "n_chains": str(score.n_chains),
        "crossings_judged": str(score.crossings.judged),
        "crossings_correct": str(score.crossings.correct),
        "ms": f"{score.ms:.1f}",
    }
