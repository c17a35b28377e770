"""Scoring of synthetic scenes like the paper's table, and ``dlo eval --synthetic``."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from schemas import Chain, Crossing, Detection
from service.cli import app
from service.evaluation.synthetic_eval import (
    cable_at,
    cables_for_seed,
    distance_to_polyline,
    hidden_runs,
    parse_cable_counts,
    score_crossings,
    score_frame,
    score_merges,
    score_scene,
    summarise_scenes,
    tolerance,
)
from service.perception import DetectionResult
from service.perception.merging import ChainEnd, Join
from service.synthetic import FAMILY_NAMES, SyntheticCable, SyntheticCrossing, make_scene

ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")
runner = CliRunner()


def run_dlo(*args):
    return runner.invoke(app, [str(arg) for arg in args], prog_name="dlo")


def straight_cable(start, end, radius=5.0, hidden=None) -> SyntheticCable:
    """A straight cable sampled every 0.5 px, optionally with hidden samples ``start:stop``."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    count = int(np.ceil(np.hypot(*(end - start)) / 0.5)) + 1
    centreline = start + np.linspace(0.0, 1.0, count)[:, None] * (end - start)
    flags = np.zeros(count, bool)
    if hidden is not None:
        flags[hidden[0] : hidden[1]] = True
    return SyntheticCable(centreline, radius, (255, 255, 255), flags, 0)


def joints_along(cable: SyntheticCable, step: float = 10.0) -> np.ndarray:
    """Chain joints ``step`` apart in arc length exactly on the cable's centreline."""
    points = cable.centreline
    arcs = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    targets = np.append(np.arange(0.0, arcs[-1], step), arcs[-1])
    return np.column_stack(
        [np.interp(targets, arcs, points[:, 0]), np.interp(targets, arcs, points[:, 1])]
    )


# --------------------------------------------------------------------------- helpers


def test_hidden_runs_are_maximal_runs_of_true() -> None:
    assert hidden_runs(np.zeros(5, bool)) == []
    assert hidden_runs(np.ones(4, bool)) == [(0, 4)]
    assert hidden_runs(np.array([1, 1, 0, 1, 0, 0, 1], bool)) == [(0, 2), (3, 4), (6, 7)]
    assert hidden_runs(np.array([], bool)) == []


def test_distance_to_polyline_measures_to_segments() -> None:
    polyline = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    points = np.array([[5.0, -2.0], [13.0, 5.0], [12.0, 13.0], [10.0, 0.0]])

    distances = distance_to_polyline(points, polyline)

    np.testing.assert_allclose(distances, [2.0, 3.0, np.hypot(2.0, 3.0), 0.0])


def test_tolerance_is_the_radius_but_at_least_4_px() -> None:
    assert tolerance(2.0) == 4.0
    assert tolerance(7.5) == 7.5


def test_cable_counts_parse_and_cycle_by_seed() -> None:
    assert parse_cable_counts("3") == (3, 3)
    assert parse_cable_counts("1-3") == (1, 3)
    assert [cables_for_seed(seed, 1, 3) for seed in range(1, 5)] == [2, 3, 1, 2]
    for bad in ("0", "3-1", "x", "1-2-3", "11"):
        with pytest.raises(ValueError, match="--cables"):
            parse_cable_counts(bad)


# --------------------------------------------------------------------------- frames


def test_chain_on_the_centreline_makes_a_correct_frame_and_occlusion() -> None:
    cable = straight_cable((10, 50), (200, 50), hidden=(100, 160))

    score = score_frame([cable], [joints_along(cable)])

    assert score.correct
    assert score.matches == (0,)
    assert score.coverage == (1.0,)
    assert [(o.start, o.stop, o.correct) for o in score.occlusions] == [(100, 160, True)]


def test_chain_offset_by_twice_the_tolerance_is_incorrect() -> None:
    cable = straight_cable((10, 50), (200, 50), radius=5.0, hidden=(100, 160))
    offset = joints_along(cable) + np.array([0.0, 2.0 * tolerance(cable.radius)])

    score = score_frame([cable], [offset])

    assert not score.correct
    assert score.matches == (None,)
    assert [o.correct for o in score.occlusions] == [False]


def test_chain_within_the_tolerance_is_still_correct() -> None:
    cable = straight_cable((10, 50), (200, 50), radius=5.0)

    score = score_frame([cable], [joints_along(cable) + np.array([0.0, 0.9 * tolerance(5.0)])])

    assert score.correct


def test_gap_over_the_hidden_stretch_fails_frame_and_occlusion_only() -> None:
    cable = straight_cable((10, 50), (200, 50), hidden=(100, 160))  # x from 60 to 89.5
    joints = joints_along(cable)
    left, right = joints[joints[:, 0] <= 50], joints[joints[:, 0] >= 100]
    other = straight_cable((10, 150), (200, 150))

    score = score_frame([cable, other], [joints_along(other), left, right])

    assert not score.correct
    assert score.matches[1] == 0
    assert score.matches[0] in (1, 2)
    assert [o.correct for o in score.occlusions] == [False]


def test_extra_chain_makes_the_frame_incorrect() -> None:
    cable = straight_cable((10, 50), (200, 50))
    stray = np.array([[10.0, 120.0], [60.0, 120.0]])

    score = score_frame([cable], [stray, joints_along(cable)])

    assert score.matches == (1,)
    assert score.coverage == (1.0,)
    assert not score.correct


def test_cables_are_matched_to_chains_one_to_one() -> None:
    first = straight_cable((10, 50), (200, 50))
    second = straight_cable((10, 100), (200, 100))

    score = score_frame([first, second], [joints_along(second), joints_along(first)])

    assert score.correct
    assert score.matches == (1, 0)


# --------------------------------------------------------------------------- merges


def end(position, direction) -> ChainEnd:
    return ChainEnd(0, False, np.asarray(position, float), np.asarray(direction, float))


def test_merges_are_correct_when_both_ends_lie_on_one_cable() -> None:
    horizontal = straight_cable((0, 100), (300, 100), radius=4.0)
    vertical = straight_cable((150, 0), (150, 200), radius=4.0)
    cables = [horizontal, vertical]
    across_gap = Join(end((100, 101), (1, 0)), end((130, 99), (-1, 0)), 0.1)
    wrong_cable = Join(end((100, 101), (1, 0)), end((150, 60), (0, 1)), 0.2)
    # Both ends at the crossing: the direction decides the cable.
    at_crossing = Join(end((147, 100), (1, 0)), end((153, 100), (-1, 0)), 0.1)
    off_every_cable = Join(end((100, 101), (1, 0)), end((250, 180), (-1, 0)), 0.3)

    verdicts = score_merges([across_gap, wrong_cable, at_crossing, off_every_cable], cables)

    assert verdicts == (True, False, True, False)
    assert cable_at(np.array([150.0, 103.0]), np.array([0.0, -1.0]), cables) == 1
    assert cable_at(np.array([150.0, 103.0]), np.array([1.0, 0.1]), cables) == 0
    assert cable_at(np.array([150.0, 140.0]), np.array([1.0, 0.0]), cables) == 1


def test_an_end_lies_on_its_cable_not_on_one_alongside() -> None:
    # Two cables side by side, touching: centrelines 8 px apart, both within 2 r + 3 of an
    # end on the first, in the same direction; the nearer one is the end's cable.
    first = straight_cable((0, 100), (300, 100), radius=4.0)
    second = straight_cable((0, 108), (300, 108), radius=4.0)

    assert cable_at(np.array([150.0, 101.0]), np.array([1.0, 0.02]), [first, second]) == 0
    assert cable_at(np.array([150.0, 107.5]), np.array([1.0, -0.02]), [first, second]) == 1
    joins = [Join(end((100, 101), (1, 0)), end((140, 100.5), (-1, 0)), 0.1)]
    assert score_merges(joins, [first, second]) == (True,)
    assert score_merges(joins, [second, first]) == (True,)


# --------------------------------------------------------------------------- crossings


def crossing_detection(over: int, under: int, x: float = 151.0, y: float = 101.0) -> Detection:
    chains = [
        Chain(id=0, points=[(0, 100), (150, 100), (300, 100)], radius=4, inferred=[False] * 2),
        Chain(id=1, points=[(150, 0), (150, 100), (150, 200)], radius=4, inferred=[False] * 2),
    ]
    crossing = Crossing(
        x=x, y=y, over=over, under=under, over_segment=0, under_segment=0, confidence=1
    )
    return Detection(width=300, height=200, segment_length=150, chains=chains, crossings=[crossing])


def test_crossing_order_between_cables_uses_the_matched_chains() -> None:
    cables = [straight_cable((0, 100), (300, 100)), straight_cable((150, 0), (150, 200))]
    truth = [SyntheticCrossing(x=150, y=100, over=1, under=0)]

    right = score_crossings(truth, cables, crossing_detection(over=1, under=0), (0, 1))
    wrong = score_crossings(truth, cables, crossing_detection(over=0, under=1), (0, 1))
    missed = score_crossings(truth, cables, crossing_detection(1, 0, x=170), (0, 1))

    assert (right.between_total, right.between_found, right.between_correct) == (1, 1, 1)
    assert (wrong.between_found, wrong.between_correct) == (1, 0)
    assert (missed.between_found, missed.between_correct) == (0, 0)
    assert right.self_total == 0


# --------------------------------------------------------------------------- whole scenes


def perfect_result(scene, reverse: int | None = None, step: float = 10.0) -> DetectionResult:
    """The detection a perfect detector would make of ``scene`` (chain ``reverse`` flipped)."""
    chains, segments = [], []
    for index, cable in enumerate(scene.cables):
        joints = joints_along(cable, step)
        flipped = index == reverse
        chains.append(
            Chain(
                id=index,
                points=[tuple(p) for p in (joints[::-1] if flipped else joints)],
                radius=cable.radius,
                inferred=[False] * (len(joints) - 1),
            )
        )
        segments.append((len(joints) - 1, flipped))

    def segment(cable: int, arc: float) -> int:
        count, flipped = segments[cable]
        forward = min(int(arc // step), count - 1)
        return count - 1 - forward if flipped else forward

    crossings = [
        Crossing(
            x=c.x,
            y=c.y,
            over=c.over,
            under=c.under,
            over_segment=segment(c.over, c.over_arc),
            under_segment=segment(c.under, c.under_arc),
            confidence=1.0,
        )
        for c in scene.crossings
    ]
    height, width = scene.mask.shape
    detection = Detection(
        width=width, height=height, segment_length=step, chains=chains, crossings=crossings
    )
    return DetectionResult(detection, scene.mask, scene.mask, [])


@pytest.fixture(scope="module")
def scene():
    # Seed 8: two cables, one loop crossing itself, one crossing of the two, one occluder.
    scene = make_scene(640, 360, 2, seed=8, occluders=1)
    kinds = sorted(c.over == c.under for c in scene.crossings)
    assert kinds == [False, True]
    assert any(cable.hidden.any() for cable in scene.cables)
    return scene


@pytest.mark.parametrize("reverse", [None, 0, 1])
def test_perfect_detection_of_a_scene_scores_everything_correct(scene, reverse) -> None:
    score = score_scene(scene, perfect_result(scene, reverse), seed=8, ms=1.0)

    assert score.frame.correct
    assert score.frame.occlusions and all(o.correct for o in score.frame.occlusions)
    crossings = score.crossings
    assert (crossings.between_total, crossings.between_correct) == (1, 1)
    assert (crossings.self_total, crossings.self_correct) == (1, 1)
    assert score.dice > 0.95
    summary = summarise_scenes([score])
    assert summary.frames.accuracy == 100.0
    assert summary.failed_frames == ()


def test_swapped_crossing_order_is_incorrect(scene) -> None:
    result = perfect_result(scene)
    detection = result.detection
    swapped = [
        c.model_copy(
            update={
                "over": c.under,
                "under": c.over,
                "over_segment": c.under_segment,
                "under_segment": c.over_segment,
            }
        )
        for c in detection.crossings
    ]
    changed = detection.model_copy(update={"crossings": swapped})

    score = score_scene(scene, DetectionResult(changed, scene.mask, scene.mask, []), 8, 1.0)

    assert score.frame.correct
    assert (score.crossings.between_found, score.crossings.between_correct) == (1, 0)
    assert (score.crossings.self_found, score.crossings.self_correct) == (1, 0)


# --------------------------------------------------------------------------- command line


def test_dlo_eval_synthetic_prints_the_results_table() -> None:
    result = run_dlo("eval", "--synthetic", 3, "--seed", 1, "--width", 640, "--height", 360)

    assert result.exit_code == 0, result.stderr
    text = ANSI_ESCAPE.sub("", result.stdout)
    for row in ("Frames", "Occlusions", "Merges", "Crossing order"):
        assert row in text
    assert "83.7 % frames" in text
    assert "Traceback" not in result.stderr


def test_dlo_eval_synthetic_json_is_machine_readable() -> None:
    result = run_dlo(
        "eval", "--synthetic", 2, "--seed", 4, "--width", 640, "--height", 360,
        "--cables", "2", "--occluders", "1", "--json",
    )  # fmt: skip

    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["setup"]["cables"] == "2"
    assert data["frames"]["total"] == 2
    assert data["occlusions"]["total"] == 2
    assert data["merges"]["correct"] + data["merges"]["incorrect"] == data["merges"]["total"]
    assert data["paper_accuracy"]["frames"] == 83.7


def test_dlo_eval_params_reach_the_detector(tmp_path) -> None:
    rows = tmp_path / "scenes.csv"
    params = tmp_path / "params.json"
    params.write_text('{"expected_count": 1}')
    result = run_dlo(
        "eval", "--synthetic", 2, "--seed", 4, "--width", 640, "--height", 360,
        "--cables", "2", "--occluders", "0", "--json", "--csv", rows, "--params", params,
    )  # fmt: skip

    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["setup"]["params"] == {"expected_count": 1}
    # Told there is one cable, merging joins the two into one chain in every scene.
    chains = [line.split(",")[2] for line in rows.read_text().splitlines()[1:]]
    assert chains == ["1", "1"]


def test_dlo_eval_family_scores_each_family_and_the_total(tmp_path) -> None:
    rows = tmp_path / "families.csv"
    result = run_dlo(
        "eval", "--synthetic", 2, "--seed", 1, "--family", "loops,edge", "--width", 640,
        "--height", 480, "--mask-from-labels", "--json", "--csv", rows,
    )  # fmt: skip

    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["setup"]["families"] == ["loops", "edge"]
    assert [f["family"] for f in data["families"]] == ["loops", "edge"]
    assert [f["frames"]["total"] for f in data["families"]] == [2, 2]
    assert data["total"]["frames"]["total"] == 4
    assert data["total"]["frames"]["correct"] == sum(
        f["frames"]["correct"] for f in data["families"]
    )
    assert all(f["mean_foreground_dice"] > 0.99 for f in data["families"])
    lines = rows.read_text().splitlines()
    assert lines[0].startswith("family,seed,")
    assert [line.split(",")[:2] for line in lines[1:]] == [
        ["loops", "1"], ["loops", "2"], ["edge", "1"], ["edge", "2"],
    ]  # fmt: skip


def test_dlo_eval_family_all_prints_one_row_per_family(tmp_path) -> None:
    out_dir = tmp_path / "out"
    result = run_dlo(
        "eval", "--synthetic", 1, "--seed", 3, "--family", "all", "--width", 640,
        "--height", 480, "--mask-from-labels", "--out-dir", out_dir,
    )  # fmt: skip

    assert result.exit_code == 0, result.stderr
    text = ANSI_ESCAPE.sub("", result.stdout)
    for name in (*FAMILY_NAMES, "total", "frames", "occlusions", "merges", "fg DICE"):
        assert name in text
    assert (out_dir / "side_by_side_3.png").is_file()
    assert (out_dir / "side_by_side_3.overlay.png").is_file()


def test_dlo_eval_one_family_prints_the_paper_table() -> None:
    result = run_dlo(
        "eval", "--synthetic", 1, "--seed", 2, "--family", "doubled_back", "--width", 640,
        "--height", 480, "--json",
    )  # fmt: skip

    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["setup"]["family"] == "doubled_back"
    assert data["frames"]["total"] == 1
    assert 0.0 <= data["mean_foreground_dice"] <= 1.0


def test_dlo_eval_help_states_the_seed_convention() -> None:
    result = run_dlo("eval", "--help")

    text = " ".join(ANSI_ESCAPE.sub("", result.stdout).split())
    assert "0-99999" in text and "100000" in text and "held out" in text
    assert "--family" in text


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((), "give a DATASET_DIR or --synthetic N"),
        (("--synthetic", "2", "--family", "spirals"), "unknown family 'spirals'"),
        (("--synthetic", "2", "--family", "loops", "--cables", "2"), "only without --family"),
        (("--synthetic", "2", "--family", "loops", "--width", "300"), "--family needs"),
        (("some_dir", "--family", "loops"), "--family apply only with --synthetic N"),
        (("some_dir", "--synthetic", "2"), "not both"),
        (("some_dir", "--seed", "2"), "--seed apply only with --synthetic N"),
        (("--synthetic", "0"), "--synthetic must be 1 or more"),
        (("--synthetic", "2", "--cables", "0-2"), "--cables"),
        (("--synthetic", "2", "--width", "20"), "--width"),
        (("--synthetic", "2", "--params", '{"gap_curve": "wiggly"}'), "--params: gap_curve"),
        (("--synthetic", "2", "--params", '{"segment_length": '), "--params: value: Invalid JSON"),
        (("--synthetic", "2", "--params", "no_such_file.json"), "neither a JSON object nor a file"),
    ],
)
def test_usage_errors_are_one_line_and_exit_2(args, message) -> None:
    result = run_dlo("eval", *args)

    assert result.exit_code == 2
    lines = [ANSI_ESCAPE.sub("", line) for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1
    assert lines[0].startswith("error: ")
    assert message in lines[0]
    assert result.stdout == ""
