"""A track that is two cables, split again (service.perception.track_splitting)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from service.perception import warm_up
from service.perception.geometry import arc_lengths
from service.perception.track_identity import Candidate
from service.perception.track_matching import Chains, Fit, Piece
from service.perception.track_merging import joins
from service.perception.track_splitting import Seam, split_tracks, track_seams
from service.perception.track_update import turns_too_sharply
from service.perception.tracking import _started

STEP = 10.0


@pytest.fixture(scope="module", autouse=True)
def _kernels_loaded():
    warm_up()


def record(track_id, joints, tips, seams=(), born=0):
    colour = np.array([120.0, 150.0, 150.0])
    started = _started(Candidate(joints, tips, 4.0, colour), track_id, STEP, 0.0, born)
    return replace(started, joints=joints, tips=tips, seams=seams, first_joint=0)


def vertical(x, y0, y1, count):
    return np.column_stack([np.full(count, float(x)), np.linspace(y0, y1, count)])


def piece(chain, joints, tips=(False, False)):
    return Piece(chain, 0, joints, tips, 4.0, arc_lengths(joints))


# Two cables of one look leave the picture's top edge side by side, 12 px apart: cable A
# at x = 100, cable B at x = 112. One frame's detection joined them round a V at the
# edge, and one track (joints 0..19 up A, 20..39 down B) was made of both: its seam is
# after joint 19.
A = vertical(100.0, 200.0, 10.0, 20)
B = vertical(112.0, 10.0, 200.0, 20)
FUSED = np.vstack([A, B])
SEAM = Seam(number=19, side=1, revive=5, born=3, made_s=0.0)


def test_two_chains_on_either_side_of_a_seam_are_two_cables():
    # The detection shows them apart again: chain 0 along A (up to y = 20), chain 1
    # along B (from y = 20), each fitting its own part of the track.
    on_a, on_b = A[:-1], B[1:]
    fitted = [
        (piece(0, on_a), Fit(0, 1, 0.0, 0.1, 1.0)),
        (piece(1, on_b), Fit(0, 1, 21 * STEP, 0.1, 1.0)),
    ]
    seams = track_seams((SEAM,), 0, 40, fitted, STEP, 0.5, 5.0)
    assert [s.apart for s in seams] == [1]
    seams = track_seams(seams, 0, 40, fitted, STEP, 0.6, 5.0)
    assert [s.apart for s in seams] == [2]
    # A chain holding both parts (the V again) says nothing apart: the count starts over.
    whole = [(piece(0, FUSED), Fit(0, 1, 0.0, 0.1, 1.0))]
    assert [s.apart for s in track_seams(seams, 0, 40, whole, STEP, 0.7, 5.0)] == [0]
    # A seam older than the memory is forgotten.
    assert track_seams(seams, 0, 40, fitted, STEP, 6.0, 5.0) == ()


def test_a_cable_hidden_between_two_chains_is_not_split():
    # One cable along y = 100, its stretch x = 100..140 under something: two chains whose
    # ends face each other across the gap.
    joints = np.column_stack([STEP * np.arange(35), np.full(35, 100.0)])
    seam = Seam(number=9, side=1, revive=5, born=3, made_s=0.0)
    fitted = [
        (piece(0, joints[:10]), Fit(0, 1, 0.0, 0.1, 1.0)),
        (piece(1, joints[15:]), Fit(0, 1, 15 * STEP, 0.1, 1.0)),
    ]
    assert [s.apart for s in track_seams((seam,), 0, 35, fitted, STEP, 0.5, 5.0)] == [0]


def test_a_seam_apart_for_the_confirmation_frames_splits_the_track_and_gives_the_id_back():
    fused = record(0, FUSED, (True, True), seams=(replace(SEAM, apart=1),))
    other = record(1, vertical(300.0, 50.0, 250.0, 21), (True, True))
    # Apart for one frame only: not yet.
    kept, next_id = split_tracks([fused, other], 7, confirm_frames=2, frame=80)
    assert [t.id for t in kept] == [0, 1] and next_id == 7
    due = replace(fused, seams=(replace(SEAM, apart=2),))
    parts, next_id = split_tracks([due, other], 7, confirm_frames=2, frame=80)
    assert sorted(t.id for t in parts) == [0, 1, 5] and next_id == 7
    older = next(t for t in parts if t.id == 0)
    newer = next(t for t in parts if t.id == 5)
    # The older part keeps its joints and their numbers; its end at the seam is open.
    np.testing.assert_allclose(older.joints, A)
    assert older.first_joint == 0 and older.tips == (True, False) and older.seams == ()
    # The newer part is numbered from its far end (B's free end at y = 200), as the
    # track it was before the join, and keeps when it began.
    np.testing.assert_allclose(newer.joints, B[::-1])
    assert newer.tips == (True, False) and newer.born == 3
    # A track that was numbered from its end at the seam is numbered so again.
    from_seam = replace(fused, seams=(replace(SEAM, apart=2, from_seam=True),))
    parts, _ = split_tracks([from_seam, other], 7, confirm_frames=2, frame=80)
    again = next(t for t in parts if t.id == 5)
    np.testing.assert_allclose(again.joints, B)
    assert again.tips == (False, True)
    # When its old id is taken meanwhile, the newer part gets a new one.
    taken = record(5, vertical(400.0, 50.0, 250.0, 21), (True, True))
    parts, next_id = split_tracks([due, taken], 7, confirm_frames=2, frame=80)
    assert sorted(t.id for t in parts) == [0, 5, 7] and next_id == 8


def test_a_track_grown_past_its_free_end_gives_back_the_id_joined_on_beyond():
    # The track grew past its free end (seam after joint 19, no id of its own) along
    # cable B, then B's track (id 2) was joined on further out (seam after joint 29).
    grown = Seam(number=19, side=1, revive=None, born=0, made_s=0.0, apart=2)
    joined = Seam(number=29, side=1, revive=2, born=0, made_s=0.0, apart=0)
    track = record(0, FUSED, (True, True), seams=(grown, joined))
    parts, next_id = split_tracks([track], 3, confirm_frames=2, frame=80)
    assert sorted(t.id for t in parts) == [0, 2] and next_id == 3


def test_a_junction_no_cable_could_turn_through_is_refused():
    # Up A, then back down B 12 px to the side: a U-turn needs 2 r = 20 px for a cable of
    # radius 4 (tightest bend 10 px).
    assert turns_too_sharply(A[-3:], B[:3], 4.0)
    # Half a circle of that bend radius, in joints 10 px apart, is a cable's.
    angles = np.arange(4) * 2.0 * math.asin(STEP / 20.0)
    arc = 10.0 * np.column_stack([np.sin(angles), 1.0 - np.cos(angles)])
    assert not turns_too_sharply(arc[:2], arc[2:], 4.0)
    # Straight on across a gap, or round a wide bend, too.
    assert not turns_too_sharply(A[-3:], vertical(100.0, -40.0, -60.0, 3), 4.0)
    assert not turns_too_sharply(A[-3:], np.array([[140.0, -30.0], [150.0, -30.0]]), 4.0)


def test_two_tracks_are_not_joined_round_a_v():
    # One chain runs up A, round a V at the edge and down B; a track holds each cable.
    apex = np.array([[106.0, 2.0]])
    for younger_joints, joined in ((B, False), (vertical(100.0, 0.0, -190.0, 20), True)):
        chain = (
            np.vstack([A, apex, younger_joints]) if not joined else np.vstack([A, younger_joints])
        )
        older = record(0, A, (True, False))
        younger = record(1, younger_joints, (False, True), born=5)
        start = len(A) + (0 if joined else 1)
        pieces = [piece_of(chain, 0, 17), piece_of(chain, start + 2, start + 19)]
        fits = [Fit(0, 1, 0.0, 0.1, 1.0), Fit(1, 1, 2 * STEP, 0.1, 1.0)]
        found = joins([older, younger], pieces, fits, chains_of([chain]))
        assert len(found) == (1 if joined else 0)


def piece_of(joints, first, last):
    part = joints[first : last + 1]
    return Piece(0, first, part, (False, False), 4.0, arc_lengths(part))


def chains_of(joints_list):
    return Chains(
        joints=joints_list,
        arcs=[arc_lengths(points) for points in joints_list],
        radii=[4.0] * len(joints_list),
        inferred=[np.zeros(len(points) - 1, bool) for points in joints_list],
        width=640,
        height=480,
        step=STEP,
        colour_breaks=[np.zeros(len(points) - 1, bool) for points in joints_list],
    )
