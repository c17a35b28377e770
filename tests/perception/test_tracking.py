"""The tracker: its kernels against plain references, and its behaviour on generated
videos whose every material point is known (service/synthetic/videos.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from schemas import Detection, DetectParams, TrackParams, Tracks
from service.perception import Tracker, advance, detect, new_state, warm_up
from service.perception import _tracking_kernels as kernels
from service.synthetic import make_video
from tests.perception.references import tracking as reference

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module", autouse=True)
def _kernels_loaded():
    warm_up()


def random_polylines(rng, count, points):
    lines = []
    for _ in range(count):
        heading = rng.uniform(0, 2 * np.pi) + np.cumsum(rng.normal(0, 0.3, points - 1))
        steps = 10.0 * np.column_stack([np.cos(heading), np.sin(heading)])
        start = rng.uniform(0, 200, 2)
        lines.append(np.vstack([start, start + np.cumsum(steps, axis=0)]))
    return lines


def stacked(lines):
    counts = np.array([len(line) for line in lines], np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return np.ascontiguousarray(np.concatenate(lines)), starts, counts


# --------------------------------------------------------------------------- kernels


@pytest.mark.parametrize("seed", range(4))
def test_nearest_on_polylines_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    joints, starts, counts = stacked(random_polylines(rng, 3, 12))
    points = rng.uniform(-20, 220, (40, 2))
    angles = rng.uniform(0, 2 * np.pi, 40)
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    gate = rng.uniform(5, 60, 3)
    got = kernels.nearest_on_polylines(points, directions, joints, starts, counts, gate)
    want = reference.nearest_on_polylines(points, directions, joints, starts, counts, gate)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)


@pytest.mark.parametrize("seed", range(4))
def test_crowded_segments_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    joints, starts, counts = stacked(random_polylines(rng, 3, 15))
    reach = rng.uniform(2, 8, 3)
    gap = np.array([3, 4, 5], np.int64)
    np.testing.assert_array_equal(
        kernels.crowded_segments(joints, starts, counts, reach, gap),
        reference.crowded_segments(joints, starts, counts, reach, gap),
    )


def test_near_any_segment_equals_the_reference():
    rng = np.random.default_rng(7)
    line = random_polylines(rng, 1, 20)[0]
    points = rng.uniform(0, 200, (60, 2))
    reach = rng.uniform(1, 15, 60)
    starts, ends = np.ascontiguousarray(line[:-1]), np.ascontiguousarray(line[1:])
    np.testing.assert_array_equal(
        kernels.near_any_segment(points, reach, starts, ends),
        reference.near_any_segment(points, reach, starts, ends),
    )


def test_fit_statistics_equals_the_reference():
    rng = np.random.default_rng(3)
    joints, starts, counts = stacked(random_polylines(rng, 2, 20))
    piece = random_polylines(np.random.default_rng(3), 1, 20)[0][2:12] + rng.normal(0, 1, (10, 2))
    steps = np.diff(piece, axis=0)
    directions = np.vstack([steps, steps[-1:]])
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    sample_arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(steps, axis=1))])
    gates = np.array([12.0, 12.0])
    distance, arc, cosine = kernels.nearest_on_polylines(
        np.ascontiguousarray(piece), directions, joints, starts, counts, gates
    )
    arc *= 10.0
    for lengths in (np.array([190.0, 190.0]), np.array([20.0, 190.0])):  # a short track too
        args = (distance, arc, cosine, sample_arc, np.array([0, 4]), np.array([4, 6]), gates)
        got = kernels.fit_statistics(*args, 0.5, lengths)
        want = reference.fit_statistics(*args, 0.5, lengths)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_allclose(a, b, atol=1e-9)
    args = (distance, arc, cosine, sample_arc, np.array([0, 4]), np.array([4, 6]), gates, 0.5)
    args += (np.array([190.0, 190.0]),)
    got = kernels.fit_statistics(*args)
    want = reference.fit_statistics(*args)
    assert got[0].any()  # the piece fits its own polyline
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)


@pytest.mark.parametrize("sign", [1, -1])
def test_refine_offset_and_chord_walk_equal_the_references(sign):
    rng = np.random.default_rng(11)
    piece = random_polylines(rng, 1, 16)[0]
    arcs = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(piece, axis=0), axis=1))])
    track = piece[::sign] + rng.normal(0, 0.7, piece.shape)
    offset = 0.0 if sign > 0 else float(arcs[-1])
    got = kernels.refine_offset(track, piece, arcs, sign, offset + 4.0, 10.0, 3)
    want = reference.refine_offset(track, piece, arcs, sign, offset + 4.0, 10.0, 3)
    assert got == pytest.approx(want, abs=1e-9)
    assert got == pytest.approx(offset, abs=2.0)  # the 4 px error is mostly undone
    start = 23.0 if sign > 0 else float(arcs[-1]) - 23.0
    walked = kernels.chord_walk(piece, arcs, start, sign, 10.0, 8)
    np.testing.assert_allclose(
        walked, reference.chord_walk(piece, arcs, start, sign, 10.0, 8), atol=1e-6
    )
    np.testing.assert_allclose(np.linalg.norm(np.diff(walked, axis=0), axis=1), 10.0, atol=1e-9)


def test_constrain_chain_makes_every_segment_exact():
    rng = np.random.default_rng(5)
    joints = np.cumsum(rng.normal(0, 6, (30, 2)), axis=0)
    mass = np.where(rng.random(30) < 0.5, 1.0, 25.0)
    out = kernels.constrain_chain(joints, mass, 10.0, np.zeros(30), 24, 12)
    np.testing.assert_allclose(np.linalg.norm(np.diff(out, axis=0), axis=1), 10.0, atol=1e-9)
    assert np.array_equal(out[12], joints[12]) or np.linalg.norm(out[12] - joints[12]) < 20


# --------------------------------------------------------------------------- behaviour


def track_video(video, frames=None, params=None, track_params=None):
    """Every frame's Tracks and the video's frames."""
    tracker = Tracker(params, track_params)
    results = []
    for frame in video.frames(0, frames):
        results.append((frame, tracker.update(frame.image, timestamp_s=frame.timestamp_s)))
    return results


def matched_cable(frame, chain):
    """Index of the cable the chain lies on (its seen joints within the radius + 3 px)."""
    points = np.asarray(chain.points)
    best, best_share = None, 0.0
    for index, cable in enumerate(frame.cables):
        distance = np.min(np.linalg.norm(points[:, None] - cable.points[None], axis=2), axis=1)
        share = float(np.mean(distance <= cable.radius + 3.0))
        if share > best_share:
            best, best_share = index, share
    return best if best_share >= 0.6 else None


def test_a_drifting_cable_keeps_its_id_its_joints_and_its_end():
    video = make_video(0, "drift", n_frames=60, n_cables=1)
    results = track_video(video)
    first = results[0][1].chains[0]
    for _, tracks in results:
        assert [chain.id for chain in tracks.chains] == [first.id]
        chain = tracks.chains[0]
        assert len(chain.points) == len(first.points)
        lengths = np.linalg.norm(np.diff(np.asarray(chain.points), axis=0), axis=1)
        np.testing.assert_allclose(lengths, tracks.segment_length, atol=1e-6)
    # Joint 0 stays at the same end of the cable, on (nearly) the same material point.
    ends = []
    for frame, tracks in results:
        cable = frame.cables[0]
        head = np.asarray(tracks.chains[0].points[0])
        ends.append(int(np.argmin(np.linalg.norm(cable.points - head, axis=1))))
    assert max(ends) - min(ends) < 2 * tracks.segment_length / cable.spacing


def test_two_crossing_cables_keep_their_ids_while_the_crossing_forms_and_parts():
    video = make_video(196, "crossings", n_frames=90, n_cables=2)  # they part at frame 54
    results = track_video(video)
    owners: dict[int, set] = {}
    for frame, tracks in results:
        for chain in tracks.chains:
            cable = matched_cable(frame, chain)
            if cable is not None:
                owners.setdefault(cable, set()).add(chain.id)
    assert set(owners) == {0, 1}
    assert all(len(ids) == 1 for ids in owners.values()), owners
    crossing_frames = [tracks for _, tracks in results if tracks.crossings]
    assert 10 < len(crossing_frames) < len(results) - 10, "the crossing should form and part"
    for tracks in crossing_frames:
        ids = {chain.id for chain in tracks.chains}
        assert all(c.over in ids and c.under in ids for c in tracks.crossings)


def test_a_cable_that_leaves_and_comes_back_gets_its_id_back():
    video = make_video(5, "enter_leave", n_frames=230, n_cables=1)
    results = track_video(video)
    seen_ids = [tracks.chains[0].id if tracks.chains else None for _, tracks in results]
    out = [i for i, (frame, _) in enumerate(results) if frame.cables[0].visible_length == 0]
    assert out, "the cable should leave the picture in this video"
    back = [i for i in range(out[-1], len(results)) if seen_ids[i] is not None]
    assert back, "and come back"
    assert seen_ids[back[-1]] == seen_ids[0]
    assert seen_ids[0] in results[out[-1]][1].tracking.remembered


def inside_polygon(point, polygon, margin):
    """Whether ``point`` lies inside the convex ``polygon``, at least ``margin`` from its sides."""
    signs = []
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        edge = b - a
        signs.append((edge[0] * (point[1] - a[1]) - edge[1] * (point[0] - a[0])) / np.hypot(*edge))
    signs = np.array(signs)
    return bool(np.all(signs > margin) or np.all(signs < -margin))


def test_joints_under_an_occluder_are_inferred_and_stay_near_their_cable():
    video = make_video(3, "occluders", n_frames=90, n_cables=1)
    hidden_errors = []
    checked = 0
    for frame, tracks in track_video(video):
        if not tracks.chains:
            continue
        chain = tracks.chains[0]
        cable = frame.cables[0]
        points = np.asarray(chain.points)
        for k, flag in enumerate(chain.inferred):
            middle = 0.5 * (points[k] + points[k + 1])
            if any(
                inside_polygon(middle, o.polygon, 2 * cable.radius + 4) for o in frame.occluders
            ):
                checked += 1
                assert flag, f"frame {frame.index}: segment {k} is under an occluder, not inferred"
        nearest = np.argmin(np.linalg.norm(points[:, None] - cable.points[None], axis=2), axis=1)
        hidden = cable.hidden[nearest]
        for k in np.flatnonzero(hidden):
            hidden_errors.append(np.linalg.norm(points[k] - cable.points[nearest[k]]))
    assert checked and hidden_errors
    assert np.median(hidden_errors) < 3.0


def test_lost_frames_are_crossed_and_reported():
    video = make_video(0, "drift", n_frames=30, n_cables=1)
    tracker = Tracker()
    ids = []
    for frame in video.frames():
        if 10 <= frame.index < 14:
            tracker.lose()  # four frames that never arrived
            continue
        tracks = tracker.update(frame.image, timestamp_s=frame.timestamp_s)
        ids.append(tracks.chains[0].id)
        if frame.index == 14:
            assert tracks.tracking.frames_lost == 4
            assert tracks.tracking.frames_lost_total == 4
    assert set(ids) == {ids[0]}


def test_a_frame_of_another_size_starts_a_new_session():
    small = make_video(0, "drift", n_frames=3, n_cables=1, width=320, height=240)
    large = make_video(0, "drift", n_frames=3, n_cables=1)
    tracker = Tracker()
    first = tracker.update(small.frame(0).image)
    assert first.tracking.reset is None
    second = tracker.update(large.frame(0).image)
    assert second.tracking.reset is not None
    assert "320x240" in second.tracking.reset and "640x480" in second.tracking.reset
    assert second.tracking.session != first.tracking.session
    assert [chain.id for chain in second.chains] == list(range(len(second.chains)))


def test_advance_is_pure_the_same_state_gives_the_same_tracks():
    video = make_video(6, "drift", n_frames=4, n_cables=2)
    frames = list(video.frames())
    state = new_state("test")
    for frame in frames[:3]:
        detection = detect(frame.image)
        state, _ = advance(state, detection, frame.image, timestamp_s=frame.timestamp_s)
    detection = detect(frames[3].image)
    joints_before = [track.joints.copy() for track in state.tracks]
    first = advance(state, detection, frames[3].image, timestamp_s=frames[3].timestamp_s)[1]
    second = advance(state, detection, frames[3].image, timestamp_s=frames[3].timestamp_s)[1]
    assert first.model_dump(exclude={"tracking"}) == second.model_dump(exclude={"tracking"})
    for track, before in zip(state.tracks, joints_before, strict=True):
        np.testing.assert_array_equal(track.joints, before)


def test_tracks_are_a_detection_on_the_wire():
    video = make_video(6, "drift", n_frames=2, n_cables=2)
    tracks = track_video(video)[-1][1]
    text = tracks.model_dump_json()
    assert Tracks.model_validate_json(text) == tracks
    as_detection = Detection.model_validate_json(text)  # a Detection reader reads it
    assert [c.points for c in as_detection.chains] == [c.points for c in tracks.chains]
    body = json.loads(text)
    assert {"first_joint", "ends", "age", "unseen"} <= set(body["chains"][0])
    assert {"session", "frame", "frames_lost", "remembered"} <= set(body["tracking"])


def test_a_new_cable_waits_for_confirmation_after_the_first_frame():
    video = make_video(11, "enter_leave", n_frames=120, n_cables=2)  # cable 1 comes in

    def first_frames(confirm):
        seen = {}
        for frame, tracks in track_video(video, track_params=TrackParams(confirm_frames=confirm)):
            for chain in tracks.chains:
                seen.setdefault(chain.id, frame.index)
        return seen

    at_once, confirmed = first_frames(1), first_frames(3)
    assert at_once[0] == confirmed[0] == 0  # the first frame's cables start at once
    late = [track for track in at_once if at_once[track] > 0]
    assert late, "a cable should come in during the video"
    assert confirmed[late[0]] == at_once[late[0]] + 2


def test_the_segment_length_is_the_tracks_own():
    video = make_video(0, "drift", n_frames=2, n_cables=1)
    tracks = track_video(video, params=DetectParams(segment_length=14))[-1][1]
    points = np.asarray(tracks.chains[0].points)
    np.testing.assert_allclose(np.linalg.norm(np.diff(points, axis=0), axis=1), 14.0, atol=1e-6)


FRESH_PROCESS = """
import json
from numba.core.dispatcher import Dispatcher
from service.perception import Tracker, warm_up, _tracking_kernels
from service.perception.tracking_warm_up import warm_up_tracking
from service.synthetic import make_video

def signatures():
    return {name: len(value.signatures) for name, value in vars(_tracking_kernels).items()
            if isinstance(value, Dispatcher)}

warm_up()
warm_up_tracking()
before = signatures()
tracker = Tracker()
for frame in make_video(4, "crossings", n_frames=12).frames():
    tracker.update(frame.image, timestamp_s=frame.timestamp_s)
after = signatures()
changed = {name: after[name] - before[name] for name in after if after[name] != before[name]}
print(json.dumps(changed))
"""


def test_after_warm_up_tracking_compiles_nothing():
    result = subprocess.run(
        [sys.executable, "-c", FRESH_PROCESS], cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout.strip().splitlines()[-1]) == {}


def test_window_medians_are_nanmedians_of_the_seen_rows():
    """The colour-change windows' medians: np.nanmedian's, NaN where a window has none."""
    import warnings

    from service.perception.track_matching import _window_medians

    rng = np.random.default_rng(0)
    for _ in range(200):
        values = rng.normal(size=(int(rng.integers(4, 30)), 3))
        values[rng.random(len(values)) < 0.4] = np.nan  # hidden joints
        width = int(rng.integers(1, 5))
        windows = np.lib.stride_tricks.sliding_window_view(values, width, axis=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows
            expected = np.nanmedian(windows, axis=2)
        np.testing.assert_allclose(_window_medians(values, width), expected)
