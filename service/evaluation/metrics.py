"""Instance segmentation metrics for label images.

The mean instance DICE follows ``../shared/README.md``: ground-truth instances are
matched one-to-one to predicted instances by the Hungarian assignment on pairwise
DICE; an unmatched ground-truth instance scores 0; the image score is the mean over
the ground-truth instances. Pixels marked ``ignore`` (in ariadne, where two cables'
masks overlap) are left out of both the prediction and the truth.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment


def _without_ignored(truth, predicted, ignore):
    if truth.shape != predicted.shape:
        raise ValueError(f"label images differ in shape: {truth.shape} and {predicted.shape}")
    if ignore is None:
        return truth, predicted
    ignore = np.asarray(ignore, dtype=bool)
    if ignore.shape != truth.shape:
        raise ValueError(f"the ignore mask is {ignore.shape}, the label images {truth.shape}")
    return np.where(ignore, 0, truth), np.where(ignore, 0, predicted)


def pairwise_dice(truth: np.ndarray, predicted: np.ndarray, ignore: np.ndarray | None = None):
    """DICE between every ground-truth and every predicted instance.

    Parameters
    ----------
    truth, predicted : ndarray of int
        Label images of one shape; 0 is background.
    ignore : ndarray of bool, optional
        Pixels left out of both (counted in neither instance).

    Returns
    -------
    dice : ndarray
        ``(n_truth, n_predicted)`` matrix.
    truth_ids, predicted_ids : ndarray
        The instance labels the rows and columns stand for.
    """
    truth, predicted = _without_ignored(truth, predicted, ignore)
    truth_ids = np.unique(truth[truth > 0])
    predicted_ids = np.unique(predicted[predicted > 0])
    if len(truth_ids) == 0 or len(predicted_ids) == 0:
        return np.zeros((len(truth_ids), len(predicted_ids))), truth_ids, predicted_ids
    # Index both label sets densely so one bincount gives every intersection.
    t_index = np.searchsorted(truth_ids, truth.ravel())
    t_index[truth.ravel() == 0] = len(truth_ids)
    p_index = np.searchsorted(predicted_ids, predicted.ravel())
    p_index[predicted.ravel() == 0] = len(predicted_ids)
    joint = np.bincount(
        t_index * (len(predicted_ids) + 1) + p_index,
        minlength=(len(truth_ids) + 1) * (len(predicted_ids) + 1),
    ).reshape(len(truth_ids) + 1, len(predicted_ids) + 1)
    intersection = joint[:-1, :-1].astype(np.float64)
    truth_sizes = joint[:-1, :].sum(axis=1).astype(np.float64)
    predicted_sizes = joint[:, :-1].sum(axis=0).astype(np.float64)
    dice = 2.0 * intersection / (truth_sizes[:, None] + predicted_sizes[None, :])
    return dice, truth_ids, predicted_ids


def instance_dice(
    truth: np.ndarray, predicted: np.ndarray, ignore: np.ndarray | None = None
) -> float:
    """Mean instance DICE of one image (see the module docstring).

    Returns 1.0 when neither image has an instance, and 0.0 when only the prediction
    has none. ``ignore`` (bool, same shape) marks pixels left out of both images.

    Examples
    --------
    >>> import numpy as np
    >>> truth = np.array([[1, 1, 0, 2, 2]])
    >>> instance_dice(truth, np.array([[5, 5, 0, 7, 7]]))
    1.0
    >>> instance_dice(truth, np.array([[5, 5, 0, 5, 5]]))
    0.3333333333333333
    """
    truth, predicted = _without_ignored(truth, predicted, ignore)
    dice, truth_ids, _ = pairwise_dice(truth, predicted)
    if len(truth_ids) == 0:
        return 1.0 if not (predicted > 0).any() else 0.0
    if dice.shape[1] == 0:
        return 0.0
    rows, cols = linear_sum_assignment(dice, maximize=True)
    return float(dice[rows, cols].sum() / len(truth_ids))


def foreground_dice(truth: np.ndarray, predicted: np.ndarray) -> float:
    """DICE of two foreground masks: ``2 |T & P| / (|T| + |P|)``; 1.0 when both are empty.

    Examples
    --------
    >>> import numpy as np
    >>> foreground_dice(np.array([1, 1, 0, 0], bool), np.array([0, 1, 1, 0], bool))
    0.5
    """
    truth = np.asarray(truth, dtype=bool)
    predicted = np.asarray(predicted, dtype=bool)
    if truth.shape != predicted.shape:
        raise ValueError(f"masks differ in shape: {truth.shape} and {predicted.shape}")
    total = int(np.count_nonzero(truth)) + int(np.count_nonzero(predicted))
    if total == 0:
        return 1.0
    return 2.0 * int(np.count_nonzero(truth & predicted)) / total
