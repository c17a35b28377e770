"""Scoring detections of synthetic scenes like the results table of Keipour et al.

Synthetic scenes (:func:`service.synthetic.make_scene`) know every cable's whole
centreline, hidden stretches included, so a detection can be judged the way the paper
judges its video frames (Frames, Occlusions, Merges: total, correct, incorrect,
accuracy). The rules used here:

tolerance
    A centreline sample of a cable of radius ``r`` is *covered* by a chain when it lies
    within ``max(4 px, r)`` of the chain's polyline.
matching
    Cables are matched one-to-one to chains by the Hungarian assignment on the fraction
    of each cable's centreline samples that the chain covers; a pair covering nothing
    is no match.
frames
    A frame is correct when it has as many chains as cables and every cable's whole
    centreline (hidden stretches included) is covered by its matched chain.
occlusions
    Each hidden stretch (maximal run of ``hidden`` samples of a cable) is correct when
    all its samples are covered by the chain matched to that cable (none, when the cable
    is unmatched).
merges
    Each join of the merging step (:attr:`DetectionResult.joins`) is correct when both
    joined ends lie on the same cable. An end lies on the cable whose centreline is
    nearest to the end's position, among cables within ``2 r + 3`` px of it; when
    several cables are about as near (within ``max(r, 3 px)`` of the nearest distance:
    the end is at a crossing), on the one whose local centreline direction is closest to
    the end's direction (either sense). A cable lying alongside, a cable's width further
    away, does not compete. An end near no cable lies on none, and its join is incorrect.
crossings
    A ground-truth crossing between two different cables is correct when the detected
    crossing nearest to it, within 10 px, has as ``over`` and ``under`` the chains
    matched to the ground-truth ``over`` and ``under`` cables. A self-crossing (a loop,
    ``over == under``) is correct when the nearest detected crossing within 10 px is a
    crossing of the chain matched to that cable with itself whose ``over`` segment runs
    closer to the direction of the top strand than to that of the bottom strand. The two
    kinds are counted apart.

foreground DICE
    The detector's foreground mask against the scene's visible-cable mask (about 1 when
    the detector is given that mask).

Seeds (:mod:`service.evaluation.conventions`): seeds 0-99999 are for tuning and for
looking at failures; seeds from 100000 up are held out, to be run only to report a result.

All functions are pure; only :func:`evaluate_scene` runs the detector.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from schemas import Detection, DetectParams
from service.evaluation.metrics import foreground_dice, instance_dice
from service.perception import DetectionResult, detect_full, render_labels
from service.synthetic import SyntheticCable, SyntheticCrossing, SyntheticScene

MIN_TOLERANCE_PX = 4.0
"""Smallest distance (px) from a chain at which a centreline sample still counts as covered."""
CROSSING_MATCH_PX = 10.0
"""Largest distance between a ground-truth and a detected crossing that are the same."""
MERGE_END_SLACK_PX = 3.0
"""An end lies on a cable when within ``2 r`` plus this of its centreline."""

PAPER_ACCURACY = {"frames": 83.7, "occlusions": 90.7, "merges": 99.6}
"""Accuracy (%) in the results table of Keipour et al. (4,230 frames of 7 videos)."""

_CHUNK = 2048


def tolerance(radius: float) -> float:
    """Distance within which a chain covers a centreline sample: ``max(4 px, radius)``."""
    return max(MIN_TOLERANCE_PX, float(radius))


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Euclidean distance from each point to a polyline (its segments, not its vertices).

    Parameters
    ----------
    points : ndarray
        ``(K, 2)`` query points ``[x, y]``.
    polyline : ndarray
        ``(M, 2)`` vertices, ``M >= 1``.

    Returns
    -------
    ndarray
        ``(K,)`` distances.

    Examples
    --------
    >>> import numpy as np
    >>> distance_to_polyline(np.array([[5.0, 3.0], [-4.0, 0.0]]),
    ...                      np.array([[0.0, 0.0], [10.0, 0.0]])).tolist()
    [3.0, 4.0]
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    polyline = np.asarray(polyline, dtype=np.float64).reshape(-1, 2)
    if len(polyline) == 0:
        raise ValueError("the polyline has no vertex")
    if len(polyline) == 1:
        return np.hypot(*(points - polyline[0]).T)
    starts = polyline[:-1]
    steps = polyline[1:] - starts
    squared = np.maximum(np.einsum("ij,ij->i", steps, steps), 1e-18)
    result = np.empty(len(points))
    for first in range(0, len(points), _CHUNK):
        chunk = points[first : first + _CHUNK]
        offsets = chunk[:, None, :] - starts[None, :, :]
        t = np.clip(np.einsum("kmj,mj->km", offsets, steps) / squared, 0.0, 1.0)
        gaps = offsets - t[:, :, None] * steps[None, :, :]
        result[first : first + _CHUNK] = np.sqrt(np.einsum("kmj,kmj->km", gaps, gaps).min(axis=1))
    return result


def hidden_runs(hidden: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True in a boolean array, as ``(start, stop)`` index pairs.

    Examples
    --------
    >>> import numpy as np
    >>> hidden_runs(np.array([0, 1, 1, 0, 0, 1, 1, 1], bool))
    [(1, 3), (5, 8)]
    """
    flags = np.asarray(hidden, dtype=bool).astype(np.int8)
    edges = np.diff(np.concatenate([[0], flags, [0]]))
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def covered_samples(cable: SyntheticCable, chain: np.ndarray) -> np.ndarray:
    """Which centreline samples of ``cable`` lie within :func:`tolerance` of ``chain``."""
    return distance_to_polyline(cable.centreline, chain) <= tolerance(cable.radius)


@dataclass(frozen=True)
class OcclusionScore:
    """One hidden stretch of a cable: samples ``start:stop`` of its centreline."""

    cable: int
    start: int
    stop: int
    correct: bool


@dataclass(frozen=True)
class FrameScore:
    """How the chains of one frame cover its cables.

    Attributes
    ----------
    correct : bool
        As many chains as cables, and every cable wholly covered by its matched chain.
    n_cables, n_chains : int
    matches : tuple of (int or None)
        Per cable, the index of its matched chain in the chain list, or None.
    coverage : tuple of float
        Per cable, the fraction of its centreline samples its matched chain covers
        (0 when unmatched).
    occlusions : tuple of OcclusionScore
    """

    correct: bool
    n_cables: int
    n_chains: int
    matches: tuple[int | None, ...]
    coverage: tuple[float, ...]
    occlusions: tuple[OcclusionScore, ...]


def score_frame(cables: Sequence[SyntheticCable], chains: Sequence[np.ndarray]) -> FrameScore:
    """Match cables to chains and judge the frame and every hidden stretch.

    Parameters
    ----------
    cables : sequence of SyntheticCable
        Ground truth (centreline, radius and hidden flags are used).
    chains : sequence of ndarray
        Detected chains as ``(K, 2)`` joint arrays.

    Returns
    -------
    FrameScore
    """
    covered = [[covered_samples(cable, chain) for chain in chains] for cable in cables]
    fractions = np.array(
        [[float(flags.mean()) for flags in row] for row in covered], dtype=np.float64
    ).reshape(len(cables), len(chains))
    matches: list[int | None] = [None] * len(cables)
    if fractions.size:
        rows, cols = linear_sum_assignment(fractions, maximize=True)
        for row, col in zip(rows, cols, strict=True):
            if fractions[row, col] > 0:
                matches[row] = int(col)
    coverage = tuple(
        float(fractions[k, match]) if match is not None else 0.0 for k, match in enumerate(matches)
    )
    occlusions = []
    for k, cable in enumerate(cables):
        for start, stop in hidden_runs(cable.hidden):
            match = matches[k]
            correct = match is not None and bool(covered[k][match][start:stop].all())
            occlusions.append(OcclusionScore(k, start, stop, correct))
    correct = len(chains) == len(cables) and all(
        match is not None and bool(covered[k][match].all()) for k, match in enumerate(matches)
    )
    return FrameScore(
        correct=correct,
        n_cables=len(cables),
        n_chains=len(chains),
        matches=tuple(matches),
        coverage=coverage,
        occlusions=tuple(occlusions),
    )


def _tangent_at(polyline: np.ndarray, index: int) -> np.ndarray:
    """Unit direction of the polyline around vertex ``index`` (a few vertices either side)."""
    behind = max(index - 3, 0)
    ahead = min(index + 3, len(polyline) - 1)
    step = polyline[ahead] - polyline[behind]
    norm = float(np.hypot(*step))
    return step / norm if norm > 1e-12 else np.zeros(2)


def cable_at(
    position: np.ndarray, direction: np.ndarray, cables: Sequence[SyntheticCable]
) -> int | None:
    """The cable a chain end lies on (see the module docstring), or None.

    Parameters
    ----------
    position : ndarray
        ``[x, y]`` of the end.
    direction : ndarray
        Unit direction of the end (either sense).
    cables : sequence of SyntheticCable

    Returns
    -------
    int or None
        Index of the cable.
    """
    position = np.asarray(position, dtype=np.float64)
    direction = np.asarray(direction, dtype=np.float64)
    near: list[tuple[int, float]] = []
    for k, cable in enumerate(cables):
        distance = float(distance_to_polyline(position[None, :], cable.centreline)[0])
        if distance <= 2.0 * cable.radius + MERGE_END_SLACK_PX:
            near.append((k, distance))
    if not near:
        return None
    nearest = min(distance for _, distance in near)
    near = [
        (k, distance)
        for k, distance in near
        if distance <= nearest + max(cables[k].radius, MERGE_END_SLACK_PX)
    ]
    if len(near) == 1:
        return near[0][0]
    best, best_alignment = near[0][0], -1.0
    for k, _ in near:
        centreline = cables[k].centreline
        nearest = int(np.argmin(np.hypot(*(centreline - position).T)))
        alignment = abs(float(np.dot(_tangent_at(centreline, nearest), direction)))
        if alignment > best_alignment:
            best, best_alignment = k, alignment
    return best


def score_merges(joins: Sequence, cables: Sequence[SyntheticCable]) -> tuple[bool, ...]:
    """Per join: do both joined ends lie on the same cable?

    Parameters
    ----------
    joins : sequence of Join
        Objects with ``end_a`` and ``end_b``, each with ``position`` and ``direction``.
    cables : sequence of SyntheticCable

    Returns
    -------
    tuple of bool
    """
    verdicts = []
    for join in joins:
        first = cable_at(join.end_a.position, join.end_a.direction, cables)
        second = cable_at(join.end_b.position, join.end_b.direction, cables)
        verdicts.append(first is not None and first == second)
    return tuple(verdicts)


@dataclass(frozen=True)
class CrossingScore:
    """Ground-truth crossings of one frame and how many the detection got right.

    ``between_*`` count crossings of two different cables, ``self_*`` loops of one
    cable; ``*_found`` those with a detected crossing within :data:`CROSSING_MATCH_PX`.
    """

    between_total: int = 0
    between_found: int = 0
    between_correct: int = 0
    self_total: int = 0
    self_found: int = 0
    self_correct: int = 0


def _arc_tangent(centreline: np.ndarray, arc: float) -> np.ndarray:
    steps = np.hypot(*np.diff(centreline, axis=0).T)
    arcs = np.concatenate([[0.0], np.cumsum(steps)])
    index = int(np.clip(np.searchsorted(arcs, arc), 0, len(centreline) - 1))
    return _tangent_at(centreline, index)


def _segment_direction(points: Sequence[tuple[float, float]], segment: int) -> np.ndarray:
    a = np.asarray(points[segment], dtype=np.float64)
    b = np.asarray(points[min(segment + 1, len(points) - 1)], dtype=np.float64)
    step = b - a
    norm = float(np.hypot(*step))
    return step / norm if norm > 1e-12 else np.zeros(2)


def score_crossings(
    truth: Sequence[SyntheticCrossing],
    cables: Sequence[SyntheticCable],
    detection: Detection,
    chain_of_cable: Sequence[int | None],
) -> CrossingScore:
    """Judge the detected crossings against the ground-truth ones.

    Parameters
    ----------
    truth : sequence of SyntheticCrossing
    cables : sequence of SyntheticCable
    detection : Detection
    chain_of_cable : sequence of (int or None)
        Per cable, the **id** of its matched chain, or None.

    Returns
    -------
    CrossingScore
    """
    detected = detection.crossings
    positions = np.array([[c.x, c.y] for c in detected], dtype=np.float64).reshape(-1, 2)
    counts = dict.fromkeys(CrossingScore.__dataclass_fields__, 0)
    for crossing in truth:
        kind = "self" if crossing.over == crossing.under else "between"
        counts[f"{kind}_total"] += 1
        if not len(positions):
            continue
        distances = np.hypot(*(positions - [crossing.x, crossing.y]).T)
        nearest = int(np.argmin(distances))
        if distances[nearest] > CROSSING_MATCH_PX:
            continue
        counts[f"{kind}_found"] += 1
        found = detected[nearest]
        over_chain = chain_of_cable[crossing.over]
        under_chain = chain_of_cable[crossing.under]
        if over_chain is None or (found.over, found.under) != (over_chain, under_chain):
            continue
        if kind == "self":
            centreline = cables[crossing.over].centreline
            top = _arc_tangent(centreline, crossing.over_arc)
            bottom = _arc_tangent(centreline, crossing.under_arc)
            segment = _segment_direction(detection.chain(found.over).points, found.over_segment)
            if abs(float(np.dot(segment, top))) <= abs(float(np.dot(segment, bottom))):
                continue
        counts[f"{kind}_correct"] += 1
    return CrossingScore(**counts)


@dataclass(frozen=True)
class SceneScore:
    """Every score of one synthetic scene.

    Attributes
    ----------
    seed : int
        The seed the scene was made with.
    frame : FrameScore
    merges : tuple of bool
        Per join of the merging step, whether it was correct.
    crossings : CrossingScore
    dice : float
        Mean instance DICE of the rendered labels against the scene's labels.
    foreground_dice : float
        DICE of the detector's foreground mask against the scene's mask.
    ms : float
        Wall time of the detection alone, milliseconds.
    """

    seed: int
    frame: FrameScore
    merges: tuple[bool, ...]
    crossings: CrossingScore
    dice: float
    foreground_dice: float
    ms: float


def score_scene(scene: SyntheticScene, result: DetectionResult, seed: int, ms: float) -> SceneScore:
    """Score a detection of a synthetic scene (pure; see :func:`evaluate_scene`)."""
    detection = result.detection
    chains = [np.asarray(chain.points, dtype=np.float64) for chain in detection.chains]
    frame = score_frame(scene.cables, chains)
    chain_ids = tuple(
        detection.chains[match].id if match is not None else None for match in frame.matches
    )
    predicted = render_labels(detection, result.mask, scene.image)
    return SceneScore(
        seed=seed,
        frame=frame,
        merges=score_merges(result.joins, scene.cables),
        crossings=score_crossings(scene.crossings, scene.cables, detection, chain_ids),
        dice=instance_dice(scene.labels, predicted),
        foreground_dice=foreground_dice(scene.mask, result.mask),
        ms=ms,
    )


def evaluate_scene(
    scene: SyntheticScene,
    seed: int = 0,
    params: DetectParams | None = None,
    mask_from_labels: bool = False,
) -> tuple[SceneScore, DetectionResult]:
    """Detect the cables of a synthetic scene and score the detection.

    Parameters
    ----------
    scene : SyntheticScene
    seed : int
        Recorded in the score, so that a failing frame can be made again.
    params : DetectParams, optional
        Defaults when None (no ``expected_count``: the detector is not told how many
        cables there are).
    mask_from_labels : bool
        Give the detector the scene's exact visible-cable mask instead of segmenting.

    Returns
    -------
    SceneScore, DetectionResult
    """
    started = time.perf_counter()
    result = detect_full(scene.image, params, mask=scene.mask if mask_from_labels else None)
    elapsed_ms = (time.perf_counter() - started) * 1000.0
    return score_scene(scene, result, seed, elapsed_ms), result


@dataclass(frozen=True)
class Tally:
    """A row of the results table: how many were judged and how many were correct."""

    total: int = 0
    correct: int = 0

    @property
    def incorrect(self) -> int:
        return self.total - self.correct

    @property
    def accuracy(self) -> float:
        """Percent correct; NaN when nothing was judged."""
        return 100.0 * self.correct / self.total if self.total else float("nan")


@dataclass(frozen=True)
class SyntheticSummary:
    """The results table over many scenes.

    Attributes
    ----------
    frames, occlusions, merges : Tally
        The rows of the paper's table.
    crossings, self_crossings : Tally
        Crossing order between two cables, and of loops.
    crossings_found, self_crossings_found : int
        Ground-truth crossings with a detected crossing within 10 px.
    mean_dice, mean_foreground_dice : float
    mean_ms : float
    failed_frames : tuple of int
        Seeds of the incorrect frames.
    """

    frames: Tally
    occlusions: Tally
    merges: Tally
    crossings: Tally
    self_crossings: Tally
    crossings_found: int
    self_crossings_found: int
    mean_dice: float
    mean_foreground_dice: float
    mean_ms: float
    failed_frames: tuple[int, ...] = field(default_factory=tuple)


def summarise_scenes(scores: Sequence[SceneScore]) -> SyntheticSummary:
    """Add up scene scores into the results table."""
    occlusions = [o.correct for s in scores for o in s.frame.occlusions]
    merges = [verdict for s in scores for verdict in s.merges]
    return SyntheticSummary(
        frames=Tally(len(scores), sum(s.frame.correct for s in scores)),
        occlusions=Tally(len(occlusions), sum(occlusions)),
        merges=Tally(len(merges), sum(merges)),
        crossings=Tally(
            sum(s.crossings.between_total for s in scores),
            sum(s.crossings.between_correct for s in scores),
        ),
        self_crossings=Tally(
            sum(s.crossings.self_total for s in scores),
            sum(s.crossings.self_correct for s in scores),
        ),
        crossings_found=sum(s.crossings.between_found for s in scores),
        self_crossings_found=sum(s.crossings.self_found for s in scores),
        mean_dice=float(np.mean([s.dice for s in scores])) if scores else float("nan"),
        mean_foreground_dice=(
            float(np.mean([s.foreground_dice for s in scores])) if scores else float("nan")
        ),
        mean_ms=float(np.mean([s.ms for s in scores])) if scores else float("nan"),
        failed_frames=tuple(s.seed for s in scores if not s.frame.correct),
    )


def parse_cable_counts(text: str) -> tuple[int, int]:
    """Parse ``--cables``: ``"3"`` (every scene) or ``"1-3"`` (cycled by seed).

    Raises
    ------
    ValueError
        Not a count or a range of counts from 1 to 10.
    """
    parts = text.strip().split("-")
    try:
        low, high = (int(parts[0]), int(parts[-1])) if len(parts) in (1, 2) else (0, -1)
    except ValueError:
        low, high = 0, -1
    if not 1 <= low <= high <= 10:
        raise ValueError(
            f"--cables must be a count N or a range LOW-HIGH within 1-10, not {text!r}"
        )
    return low, high


def cables_for_seed(seed: int, low: int, high: int) -> int:
    """Number of cables of the scene made with ``seed``: ``low + seed mod (high - low + 1)``."""
    return low + seed % (high - low + 1)


def csv_row(score: SceneScore) -> dict[str, str]:
    """One row of the ``--csv`` file in synthetic mode (see :data:`CSV_COLUMNS`)."""
    crossings = score.crossings
    return {
        "seed": str(score.seed),
        "n_cables": str(score.frame.n_cables),
        "n_chains": str(score.frame.n_chains),
        "frame_correct": str(int(score.frame.correct)),
        "min_coverage": f"{min(score.frame.coverage, default=1.0):.4f}",
        "occlusions": str(len(score.frame.occlusions)),
        "occlusions_correct": str(sum(o.correct for o in score.frame.occlusions)),
        "merges": str(len(score.merges)),
        "merges_correct": str(sum(score.merges)),
        "crossings": str(crossings.between_total),
        "crossings_correct": str(crossings.between_correct),
        "self_crossings": str(crossings.self_total),
        "self_crossings_correct": str(crossings.self_correct),
        "dice": f"{score.dice:.4f}",
        "foreground_dice": f"{score.foreground_dice:.4f}",
        "ms": f"{score.ms:.1f}",
    }


CSV_COLUMNS = (
    "seed",
    "n_cables",
    "n_chains",
    "frame_correct",
    "min_coverage",
    "occlusions",
    "occlusions_correct",
    "merges",
    "merges_correct",
    "crossings",
    "crossings_correct",
    "self_crossings",
    "self_crossings_correct",
    "dice",
    "foreground_dice",
    "ms",
)
