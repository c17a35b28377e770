"""How much of a score is lost to labels that are not where the image puts the cable.

Hand-drawn labels may be a pixel or three off the photographed cable (ariadne's are
tubes of one width drawn along hand-placed centre lines). Exact DICE then punishes a mask
that follows the photograph as much as one that misses the cable by as many pixels. A
**tolerance band** says how much of a score is such misalignment: a predicted pixel
counts as agreeing with a true instance when it lies within ``tolerance`` px of it, and
a true pixel counts as found when a pixel of the prediction lies within ``tolerance``
px of it (the boundary F-measure of segmentation benchmarks, applied to every pixel).
At tolerance 0 it is exact DICE.

The band is an upper bound on what misalignment can explain: at 2 px a mask that
follows the photograph loses nothing to a label 2 px off, and what it still loses is
a real error (a missed cable, a cable taken for two, paper taken for a cable).

``python -m service.evaluation.label_tolerance DATASET [...]`` prints, per subset, the
mean instance DICE and foreground DICE at tolerances 0 to 3 px, for the true mask
(``--mask-from-labels``) and end to end.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from service.evaluation.metrics import _without_ignored


def _disc_offsets(tolerance: int) -> list[tuple[int, int]]:
    """Offsets ``(dy, dx)`` within ``tolerance`` px (Euclidean) of the origin."""
    return [
        (dy, dx)
        for dy in range(-tolerance, tolerance + 1)
        for dx in range(-tolerance, tolerance + 1)
        if dy * dy + dx * dx <= tolerance * tolerance
    ]


def _near_counts(source: np.ndarray, other: np.ndarray, n_source: int, n_other: int, tolerance):
    """``counts[i, j]``: pixels of ``source`` label ``i + 1`` with a pixel of ``other``
    label ``j + 1`` within ``tolerance`` px; labels dense from 1, 0 is background."""
    height, width = source.shape
    ys, xs = np.nonzero(source)
    keys = []
    for dy, dx in _disc_offsets(tolerance):
        y, x = ys + dy, xs + dx
        inside = (y >= 0) & (y < height) & (x >= 0) & (x < width)
        pixel = np.flatnonzero(inside)
        near = other[y[inside], x[inside]]
        hit = near > 0
        keys.append(pixel[hit].astype(np.int64) * (n_other + 1) + near[hit])
    if not keys:
        return np.zeros((n_source, n_other))
    # A pixel counts once per label near it, however many of its pixels are near.
    unique = np.unique(np.concatenate(keys))
    pixel, label = unique // (n_other + 1), unique % (n_other + 1)
    counts = np.zeros((n_source + 1, n_other + 1))
    np.add.at(counts, (source[ys[pixel], xs[pixel]], label), 1.0)
    return counts[1:, 1:]


def _dense(labels: np.ndarray) -> tuple[np.ndarray, int]:
    """Labels renumbered 1..n (0 stays background), and n."""
    ids, inverse = np.unique(labels, return_inverse=True)
    dense = inverse.reshape(labels.shape).astype(np.int64)
    if ids[0] != 0:
        dense += 1
    return dense, int(len(ids) - (ids[0] == 0))


def tolerant_pairwise_dice(
    truth: np.ndarray,
    predicted: np.ndarray,
    tolerance: int,
    ignore: np.ndarray | None = None,
) -> np.ndarray:
    """DICE with a tolerance band between every true and every predicted instance.

    ``(|P_j near T_i| + |T_i near P_j|) / (|T_i| + |P_j|)``, where "near" is within
    ``tolerance`` px; at tolerance 0 it is :func:`~service.evaluation.metrics.pairwise_dice`.

    Returns
    -------
    ndarray
        ``(n_truth, n_predicted)``, rows and columns in the order of the sorted labels.

    Examples
    --------
    >>> import numpy as np
    >>> truth = np.zeros((5, 9), int); truth[2, 1:8] = 1
    >>> shifted = np.zeros((5, 9), int); shifted[3, 1:8] = 4  # one row lower
    >>> float(tolerant_pairwise_dice(truth, shifted, 0)[0, 0])
    0.0
    >>> float(tolerant_pairwise_dice(truth, shifted, 1)[0, 0])
    1.0
    """
    if tolerance < 0:
        raise ValueError(f"tolerance must be >= 0 px, not {tolerance}")
    truth, predicted = _without_ignored(truth, predicted, ignore)
    truth, n_truth = _dense(truth)
    predicted, n_predicted = _dense(predicted)
    if n_truth == 0 or n_predicted == 0:
        return np.zeros((n_truth, n_predicted))
    truth_near = _near_counts(truth, predicted, n_truth, n_predicted, tolerance)
    predicted_near = _near_counts(predicted, truth, n_predicted, n_truth, tolerance)
    truth_sizes = np.bincount(truth.ravel(), minlength=n_truth + 1)[1:].astype(np.float64)
    predicted_sizes = np.bincount(predicted.ravel(), minlength=n_predicted + 1)[1:]
    return (truth_near + predicted_near.T) / (truth_sizes[:, None] + predicted_sizes[None, :])


def tolerant_instance_dice(
    truth: np.ndarray,
    predicted: np.ndarray,
    tolerance: int,
    ignore: np.ndarray | None = None,
) -> float:
    """Mean instance DICE with a tolerance band: instances matched one to one (Hungarian)
    on :func:`tolerant_pairwise_dice`, an unmatched true instance scoring 0."""
    dice = tolerant_pairwise_dice(truth, predicted, tolerance, ignore)
    if dice.shape[0] == 0:
        return 1.0 if not (np.asarray(predicted) > 0).any() else 0.0
    if dice.shape[1] == 0:
        return 0.0
    rows, cols = linear_sum_assignment(dice, maximize=True)
    return float(dice[rows, cols].sum() / dice.shape[0])


def tolerant_foreground_dice(truth: np.ndarray, predicted: np.ndarray, tolerance: int) -> float:
    """Foreground DICE with a tolerance band (1.0 when both masks are empty)."""
    truth = np.asarray(truth, bool)
    predicted = np.asarray(predicted, bool)
    total = int(truth.sum()) + int(predicted.sum())
    if total == 0:
        return 1.0
    if tolerance == 0:
        return 2.0 * int((truth & predicted).sum()) / total
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * tolerance + 1, 2 * tolerance + 1))
    near_truth = cv2.dilate(truth.view(np.uint8), disc).view(bool)
    near_predicted = cv2.dilate(predicted.view(np.uint8), disc).view(bool)
    return (int((predicted & near_truth).sum()) + int((truth & near_predicted).sum())) / total


def main(argv: Sequence[str] | None = None) -> int:
    """Print the tolerance table of one or more data sets (see the module docstring)."""
    from service.evaluation import dataset
    from service.imageio import read_image

    parser = argparse.ArgumentParser(prog="python -m service.evaluation.label_tolerance")
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--tolerances", default="0,1,2,3")
    args = parser.parse_args(argv)
    tolerances = [int(value) for value in args.tolerances.split(",")]
    header = " ".join(f"{kind}@{t}" for kind in ("inst", "fg") for t in tolerances)
    print(f"dataset subset mode images {header}")
    for root in args.datasets:
        items, _ = dataset.find_labelled_images(root)
        for subset in sorted({item.subset for item in items}):
            chosen = [item for item in items if item.subset == subset]
            for mask_from_labels in (True, False):
                rows = []
                for item in chosen:
                    truth = dataset.read_labels(item.labels)
                    mask = item.mask and dataset.read_mask(item.mask)
                    _, result, predicted = dataset.evaluate_image(
                        read_image(item.image),
                        truth,
                        mask_from_labels=mask_from_labels,
                        truth_mask=mask,
                        judge_crossings=False,
                    )
                    ignore = dataset.ignored_pixels(truth)
                    foreground = truth > 0 if mask is None else mask
                    rows.append(
                        [tolerant_instance_dice(truth, predicted, t, ignore) for t in tolerances]
                        + [tolerant_foreground_dice(foreground, result.mask, t) for t in tolerances]
                    )
                means = " ".join(f"{value:.4f}" for value in np.mean(rows, axis=0))
                mode = "true-mask" if mask_from_labels else "end-to-end"
                print(f"{root} {subset} {mode} {len(rows)} {means}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
