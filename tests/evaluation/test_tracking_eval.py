"""The tracking scores (service/evaluation/tracking_eval.py) and ``dlo eval --tracking``."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from schemas import Chain, Detection
from service.cli import app
from service.evaluation import tracking_eval
from service.synthetic import make_video

STEP = 10.0


def chain_on(cable, chain_id: int, reverse: bool = False, shift: float = 0.0) -> Chain:
    """A chain with joints every ``STEP`` px of material arc along a true cable, moved
    ``shift`` px along it."""
    samples = np.arange(0.0, len(cable.points) * cable.spacing - STEP, STEP) + shift
    index = np.clip(np.rint(samples / cable.spacing).astype(int), 0, len(cable.points) - 1)
    points = cable.points[index][:: -1 if reverse else 1]
    return Chain(
        id=chain_id,
        points=points.tolist(),
        radius=cable.radius,
        inferred=[False] * (len(points) - 1),
    )


def score(frames, chains_of):
    source = tracking_eval._Source([tracking_eval.CableScore() for _ in frames[0].cables])
    for frame in frames:
        detection = Detection(width=640, height=480, segment_length=STEP, chains=chains_of(frame))
        tracking_eval._score_frame(source, frame, detection, STEP, materials=True)
    return source, tracking_eval._summary(source.cables)


def test_chains_on_the_cables_with_steady_ids_score_perfectly():
    frames = list(make_video(16, "crossings", n_frames=12, n_cables=2).frames())
    source, (identity, same_end, switches, counted) = score(
        frames, lambda frame: [chain_on(c, i) for i, c in enumerate(frame.cables)]
    )
    assert identity == (counted, counted) and same_end[0] == same_end[1] > 0
    assert switches == 0
    assert source.error_sum / source.error_frames < 0.1


def test_swapped_ids_turned_chains_and_sliding_joints_are_seen():
    frames = list(make_video(16, "crossings", n_frames=12, n_cables=2).frames())

    def chains_of(frame):
        swapped = frame.index >= 8
        return [
            chain_on(cable, (i + swapped) % 2, reverse=frame.index in (3, 4), shift=frame.index)
            for i, cable in enumerate(frame.cables)
        ]

    source, (identity, same_end, switches, counted) = score(frames, chains_of)
    assert switches == 2  # one per cable, at frame 8
    assert identity == (2 * 8, counted)
    assert same_end[0] == same_end[1] - 2 * 2  # frames 3 and 4 run from the other end
    # Joints turned round are far from their material points.
    assert source.error_sum / source.error_frames > 1.0


def test_the_joint_error_is_the_slide_along_the_cable():
    frames = list(make_video(16, "crossings", n_frames=12, n_cables=2).frames())
    source, _ = score(
        frames,
        lambda frame: [chain_on(c, i, shift=2.0 * frame.index) for i, c in enumerate(frame.cables)],
    )
    # 2 px of material a frame, frames 1 to 11: a mean of 12 px, 1.2 segment lengths.
    assert 1.0 < source.error_sum / source.error_frames < 1.4


def test_dlo_eval_tracking_prints_a_row_per_kind_and_a_total():
    result = CliRunner().invoke(
        app,
        ["eval", "--tracking", "2", "--frames", "12", "--seed", "3", "--json"],
        prog_name="dlo",
    )
    assert result.exit_code == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["videos"] == 2 and report["failed"] == 0
    assert [row["kind"] for row in report["kinds"]] == ["occluders", "crossings", "all"]
    for row in report["kinds"]:
        assert 0.0 <= row["identity"] <= 1.0 and row["cable_minutes"] > 0


def test_dlo_eval_tracking_refuses_options_of_the_other_modes():
    result = CliRunner().invoke(
        app, ["eval", "--tracking", "2", "--family", "loops"], prog_name="dlo"
    )
    assert result.exit_code == 2 and "--family" in result.stderr
    result = CliRunner().invoke(
        app, ["eval", "--tracking", "1", "--kinds", "spin"], prog_name="dlo"
    )
    assert result.exit_code == 2 and "spin" in result.stderr
