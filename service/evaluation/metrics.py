"""Instance segmentation metrics for label images.

The mean instance DICE follows ``../shared/README.md``: ground-truth instances are
matched one-to-one to predicted instances by the Hungarian assignment on pairwise
DICE; an unmatched ground-truth instance scores 0; the image score is the mean over
the ground-truth instances.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment


def pairwise_dice(truth: np.ndarray, predicted: np.ndarray):
    """DICE between every ground-truth and every predicted instance.

    Parameters
    ----------
    truth, predicted : ndarray of int
        Label images of one shape; 0 is background.

    Returns
    -------
    dice : ndarray
        ``(n_truth, n_predicted)`` matrix.
    truth_ids, predicted_ids : ndarray
        The instance labels the rows and columns stand for.
    """
    if truth.shape != predicted.shape:
        raise ValueError(f"label images differ in shape: {truth.shape} and {predicted.shape}")
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


def instance_dice(truth: np.ndarray, predicted: np.ndarray) -> float:
    """Mean instance DICE of one image (see the module docstring).

    Returns 1.0 when neither image has an instance, and 0.0 when only the prediction
    has none.

    Examples
    --------
    >>> import numpy as np
    >>> truth = np.array([[1, 1, 0, 2, 2]])
    >>> instance_dice(truth, np.array([[5, 5, 0, 7, 7]]))
    1.0
    >>> instance_dice(truth, np.array([[5, 5, 0, 5, 5]]))
    0.3333333333333333
    """
    dice, truth_ids, _ = pairwise_dice(truth, predicted)
    if len(truth_ids) == 0:
        return 1.0 if not (predicted > 0).any() else 0.0
    if dice.shape[1] == 0:
        return 0.0
    rows, cols = linear_sum_assignment(dice, maximize=True)
    return float(dice[rows, cols].sum() / len(truth_ids))
