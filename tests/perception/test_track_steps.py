"""The tracker's steps on small hand-made cases: the rigid motion a seen free end gives,
a cable laid again from the free end it shows, joins measured from the joints seen,
pieces longer than their track, and a free end moving fast along its cable."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from service.perception import Tracker, warm_up
from service.perception.geometry import arc_lengths, rigid_fit
from service.perception.track_identity import (
    Candidate,
    Continuation,
    orientation,
    other_end,
    revived_joints,
    waits,
    where_it_left,
)
from service.perception.track_matching import Chains, Fit, Piece, cut_at_met_ends, fit_pieces
from service.perception.track_merging import joins
from service.perception.track_motion import motion
from service.perception.track_update import Observation, observe, register
from service.perception.tracking import _extended, _joined, _started

STEP = 10.0


@pytest.fixture(scope="module", autouse=True)
def _kernels_loaded():
    warm_up()


def straight(x0, count, y=100.0):
    return np.column_stack([x0 + STEP * np.arange(count), np.full(count, y)])


def record(track_id, joints, tips, seen=None, born=0):
    colour = np.array([120.0, 150.0, 150.0])
    started = _started(Candidate(joints, tips, 4.0, colour), track_id, STEP, 0.0, born)
    return replace(started, joints=joints, tips=tips, seen=seen)


def test_a_free_end_seen_in_both_frames_gives_the_motion_along_a_straight_cable():
    previous = straight(0.0, 20)
    current = previous + np.array([7.0, 0.0])  # slid along itself: nothing across it
    use = np.ones(20, bool)
    # Across the cable nothing moved: alone, the fit keeps a straight cable still.
    assert np.abs(motion(previous, current, use)).max() < 0.5
    pinned = [(19, np.array([7.0, 0.0]))]  # its free end, found 7 px further on
    moved = motion(previous, current, use, pinned)
    np.testing.assert_allclose(moved, np.tile([7.0, 0.0], (20, 1)), atol=0.5)


def test_a_revived_cable_is_laid_from_the_free_end_it_shows():
    old = straight(0.0, 30)  # joint 29 is the cable's free end
    # Back in view: only its last 8 segments, from the picture's edge (mid-cable) down
    # to its free end at (200, 400).
    shown = np.column_stack([np.full(9, 200.0), 320.0 + STEP * np.arange(9)])
    candidate = Candidate(shown, (False, True), 4.0, None)
    joints = revived_joints(old, candidate, first_is_head=True, step=STEP)
    assert len(joints) == 30
    np.testing.assert_allclose(joints[-1], [200.0, 400.0], atol=1e-6)
    np.testing.assert_allclose(joints[-9:], shown, atol=1e-6)
    # The rest goes on beyond the edge, away from the free end (up, out of the picture).
    assert joints[0, 1] < 320.0 - 15 * STEP


def chains_of(joints_list, width=640, height=480):
    return Chains(
        joints=joints_list,
        arcs=[arc_lengths(points) for points in joints_list],
        radii=[4.0] * len(joints_list),
        inferred=[np.zeros(len(points) - 1, bool) for points in joints_list],
        width=width,
        height=height,
        step=STEP,
        colour_breaks=[np.zeros(len(points) - 1, bool) for points in joints_list],
    )


def piece_of(chain, joints, first, last, tips=(False, False)):
    part = joints[first : last + 1]
    return Piece(chain, first, part, tips, 4.0, arc_lengths(part))


def test_a_hidden_free_end_does_not_stop_a_join():
    # One cable along y = 100 from x = 0 to 400, its end at x = 400 free. The older
    # track saw it to x = 100 and its end there once, but that stretch has been hidden
    # and its guesses went astray; a younger track holds x = 140 .. 400. This frame's
    # chain runs along the whole cable.
    chain = straight(0.0, 41)
    older_joints = straight(0.0, 41)
    older_joints[11:, 1] += np.linspace(5.0, 150.0, 30)  # the hidden guesses
    seen = np.arange(41) <= 10
    older = record(0, older_joints, (True, True), seen=seen)
    younger = record(1, straight(140.0, 27), (False, True), born=5)
    chains = chains_of([chain])
    pieces = [piece_of(0, chain, 0, 10, (True, False)), piece_of(0, chain, 14, 40, (False, True))]
    fits = [Fit(0, 1, 0.0, 0.1, 1.0), Fit(1, 1, 0.0, 0.1, 1.0)]
    found = joins([older, younger], pieces, fits, chains)
    assert len(found) == 1
    join = found[0]
    assert (join.older, join.younger, join.end, join.anchor) == (0, 1, 1, 10)
    # Laid from the last joint seen, along the cable to its free end.
    assert join.tip
    np.testing.assert_allclose(join.joints[:, 1], 100.0, atol=1e-6)
    np.testing.assert_allclose(join.joints[-1], [400.0, 100.0], atol=1e-6)
    # Made, the older track keeps all its joints and their numbers, even where the
    # younger one is shorter than the stretch it lays again (joint 0 of the older track
    # stays its first joint).
    short = record(1, straight(140.0, 10), (False, True), born=5)
    short_fits = [fits[0], Fit(1, 1, 0.0, 0.1, 1.0)]
    short_pieces = [pieces[0], piece_of(0, chain, 14, 23, (False, True))]
    made = _joined([older, short], joins([older, short], short_pieces, short_fits, chains), 0.0)
    assert len(made) == 1 and len(made[0].joints) >= len(older_joints)
    assert made[0].first_joint == 0
    np.testing.assert_allclose(made[0].joints[: len(older_joints) - 30], older_joints[:11])
    # A free end seen this frame does not go on, nor does the younger track's.
    seen_end = record(0, straight(0.0, 11), (True, True))
    assert joins([seen_end, younger], pieces, fits, chains) == []
    younger_tip = record(1, straight(140.0, 27), (True, True), born=5)
    younger_tip = replace(younger_tip, seen=np.arange(27) >= 2)  # its facing end hidden
    assert joins([older, younger_tip], pieces, fits, chains) == []


def test_a_piece_longer_than_its_track_still_fits_it():
    track = straight(100.0, 5)  # 4 segments: a cable that just came into view
    piece_joints = straight(90.0, 13)  # 12 segments of it in this frame
    piece = Piece(0, 0, piece_joints, (False, True), 4.0, arc_lengths(piece_joints))
    fits = fit_pieces([piece], [track], np.array([15.0]), STEP)
    assert fits[0] is not None and fits[0].track == 0 and fits[0].sign == 1
    assert abs(fits[0].offset + 10.0) < 1.0


def drawn(tip_x, width=640, height=240):
    """A straight cable from the left edge to a free end at ``tip_x``."""
    image = np.full((height, width, 3), 40, np.uint8)
    cv2.line(image, (-50, 120), (int(tip_x), 120), (0, 200, 255), 9)
    return image


def test_a_free_end_moving_fast_along_its_cable_is_not_taken_for_more_cable():
    # The cable is pulled along itself, out of the left edge into view, 32 px a frame
    # (more than the 3 segments beyond a free end that would mean more cable hidden
    # there): its free end leads, the new cable comes in at the edge.
    tracker = Tracker()
    first = tracker.update(drawn(250)).chains
    assert len(first) == 1 and first[0].ends == ("tip", "open")
    for frame in range(1, 4):
        tracks = tracker.update(drawn(250 + 32 * frame), timestamp_s=frame / 30).chains
        assert [chain.id for chain in tracks] == [first[0].id]
        # Joint 0 is still the free end's: no joints were added before it ...
        assert tracks[0].first_joint == 0 and tracks[0].ends[0] == "tip"
        # ... and it moves on with the cable.
        assert tracks[0].points[0][0] > 250 + 32 * (frame - 1)


def test_a_join_at_the_first_end_keeps_joint_numbers_at_or_below_zero():
    # The same cable as above, the older track running the other way: its hidden free
    # end is its first, and the younger track is shorter than the stretch beyond the
    # older one's outermost seen joint.
    chain = straight(0.0, 41)[::-1]  # x from 400 down to 0
    older_joints = straight(0.0, 41)
    older_joints[11:, 1] += np.linspace(5.0, 150.0, 30)
    older = record(0, older_joints[::-1].copy(), (True, True), seen=np.arange(41) >= 30)
    younger = record(1, straight(140.0, 10), (False, True), born=5)
    chains = chains_of([chain])
    pieces = [piece_of(0, chain, 17, 26), piece_of(0, chain, 30, 40, (False, True))]
    fits = [Fit(1, -1, 90.0, 0.1, 1.0), Fit(0, 1, 300.0, 0.1, 1.0)]
    found = joins([older, younger], pieces, fits, chains)
    assert [(j.older, j.younger, j.end, j.anchor) for j in found] == [(0, 1, 0, 30)]
    made = _joined([older, younger], found, 0.0)
    assert len(made) == 1
    assert made[0].first_joint <= 0
    assert len(made[0].joints) >= 41
    np.testing.assert_allclose(made[0].joints[-11:], older.joints[30:])


def test_a_whole_cable_in_one_chain_pins_both_ends_though_a_stub_is_cut_off():
    # A straight cable of 33 segments, detected whole as one chain from x = 40 to 370
    # with a free end at each end. Its first 5 segments lie near another cable and are
    # cut off as crowded, so the one piece shows only the free end at x = 370. The track
    # (x = 50 .. 380) has slid a segment along the cable: that free end is a segment
    # short of the track's end, which alone reads as an end hidden under something.
    track = straight(50.0, 34)
    chain = straight(40.0, 34)
    chains = chains_of([chain])
    piece = piece_of(0, chain, 5, 33, (False, True))
    fitted = [(piece, Fit(0, 1, 40.0, 0.1, 1.0))]
    observed = observe(track, (True, True), fitted, chains, np.array([True]), [(0, 5, 33)])
    # The chain shows the whole cable: both of its ends are the cable's, and the track
    # slides towards them (a share of the segment per frame).
    assert observed.free_ends == (True, True)
    assert observed.slide > 0.3 * STEP
    np.testing.assert_allclose(observed.free_end_points, [[40.0, 100.0], [370.0, 100.0]])
    # The same chain with its first end inferred (that end hidden, the chain's guess
    # beyond it): the free end that went in is taken for one hidden, as before.
    hidden = replace(chains, inferred=[np.r_[True, np.zeros(32, bool)]])
    observed = observe(track, (True, True), fitted, hidden, np.array([True]), [(0, 5, 33)])
    assert observed.slide == 0.0 and observed.free_ends == (False, True)


def test_a_track_as_long_as_its_cable_slides_instead_of_growing():
    # The cable: 20 segments from x = 60 to 260, one chain with a free end at each end.
    # The track (x = 40 .. 240) has slid 2 segments towards x = 0: the chain goes on 2
    # segments beyond its last joint. A track whose length is not known grows there; one
    # known to be as long as its cable (both free ends once seen at once) does not, and
    # slides towards the cable seen beyond it instead.
    track = straight(40.0, 21)
    chain = straight(60.0, 21)
    chains = chains_of([chain])
    piece = piece_of(0, chain, 0, 20)  # no free end seen (touching something at both)
    fitted = [(piece, Fit(0, 1, 20.0, 0.1, 1.0))]
    args = (track, (False, False), fitted, chains, np.array([True]), [(0, 0, 20)])
    free = observe(*args)
    assert len(free.tail_growth) == 2 and free.slide == 0.0
    known = observe(*args, length_known=True)
    assert len(known.tail_growth) == 0 and len(known.head_growth) == 0
    assert known.slide < -0.3 * STEP  # the pieces lie further back along the track
    # Laid from the targets, every joint moves on towards x = 260.
    assert np.all(known.targets[known.covered, 0] > track[known.covered, 0])
    # A known length is remembered from a frame showing both free ends as far apart as
    # the track's ends.
    both = piece_of(0, chain, 0, 20, (True, True))
    seen = observe(track, (True, True), [(both, Fit(0, 1, 20.0, 0.1, 1.0))], *args[3:])
    assert seen.length_known and seen.free_ends == (True, True)


def test_a_join_onto_a_track_as_long_as_its_cable_moves_it_along():
    # A track of 21 joints (x = 100 .. 300) known to be as long as its cable, continued
    # at its first end from its joint 2 by 5 joints of cable (x = 110 .. 70): 3 more
    # than it had there. It keeps 21 joints (the 3 at its last end, off the cable, go)
    # and its joint numbers.
    track = replace(record(0, straight(100.0, 21), (True, True)), length_known=True)
    beyond = straight(70.0, 5)[::-1]  # nearest first
    moved = _extended(track, Continuation(0, 0, 2, beyond, True), 0.0)
    assert len(moved.joints) == 21 and moved.first_joint == 0
    np.testing.assert_allclose(moved.joints[0], [70.0, 100.0])
    np.testing.assert_allclose(moved.joints[-1], [270.0, 100.0])
    # Not known, it grows there.
    grown = _extended(replace(track, length_known=False), Continuation(0, 0, 2, beyond, True), 0.0)
    assert len(grown.joints) == 24 and grown.first_joint == -3


def curved(count, turn=0.01):
    """A cable ``STEP`` apart whose bending grows along it (a shape with no symmetry)."""
    headings = turn * np.arange(count - 1) ** 1.5
    steps = STEP * np.column_stack([np.cos(headings), np.sin(headings)])
    return np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)]) + np.array([100.0, 100.0])


def test_a_cable_back_without_a_free_end_is_laid_where_its_shape_fits():
    # A remembered cable of 30 joints comes back turned and moved, showing only joints
    # 12 to 24 (both ends outside the picture): no free end to go by.
    old = curved(30)
    angle = 0.3
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    now = old @ rotation.T + [60.0, 25.0]
    shown = Candidate(now[12:25], (False, False), 4.0, None)
    ends = (old[0], old[-1])
    assert orientation(shown, old, (True, True), ends, (0.0, 0.0))
    reversed_shown = replace(shown, joints=shown.joints[::-1].copy())
    assert not orientation(reversed_shown, old, (True, True), ends, (0.0, 0.0))
    joints = revived_joints(old, shown, first_is_head=True, step=STEP)
    # Its joints 12 .. 24 on the stretch shown, the rest carried along with it.
    assert len(joints) == 30
    np.testing.assert_allclose(joints[12:25], now[12:25], atol=0.5)
    np.testing.assert_allclose(joints[[0, -1]], now[[0, -1]], atol=1.0)


def turned(points, angle, shift):
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return points @ rotation.T + np.asarray(shift)


def test_the_stretch_out_of_view_keeps_its_shape_and_moves_with_its_seen_neighbours():
    # A bent cable going out of the picture: joints 0-14 seen this frame, turned and
    # moved; the last of them a pixel or two off (a chain cut by the picture's edge
    # bends there), the rest outside the picture.
    previous = curved(30, turn=0.02)
    now = turned(previous, 0.05, [12.0, -6.0])
    targets = now.copy()
    targets[14] += [0.0, 2.5]
    covered = np.arange(30) <= 14
    observation = Observation(targets, covered, (False, False), np.empty((0, 2)), np.empty((0, 2)))
    joints = register(previous, observation, STEP, 4.0, previous)
    # The joints out of view are the cable where it now is: its shape kept, carried by
    # the motion of the seen joints next to them, not bent by the last one's error.
    np.testing.assert_allclose(joints[15:], now[15:], atol=3.5)
    np.testing.assert_allclose(np.linalg.norm(np.diff(joints, axis=0), axis=1), STEP, atol=1e-6)


def test_joints_out_of_view_move_with_the_cable_as_a_whole():
    previous = curved(30, turn=0.02)
    current = turned(previous, 0.02, [4.0, 3.0])
    guessed = current.copy()
    guessed[20:] += np.linspace(0.0, 8.0, 10)[:, None] * [0.3, 1.0]  # guesses out of view
    use = np.arange(30) < 20
    outside = ~use
    clean = motion(previous, current, use, rigid_only=outside)
    moved = motion(previous, guessed, use, rigid_only=outside)
    # Outside the seen stretch: the rigid motion the seen joints give, whatever was
    # guessed there (without that, the guesses' own motion leaks in).
    np.testing.assert_allclose(moved[outside], clean[outside], atol=0.05)
    leaked = motion(previous, guessed, use)
    assert np.abs(leaked[outside] - clean[outside]).max() > 1.0
    # ... and it is one rigid motion: the same turn and shift for every joint there.
    source, rotation, target = rigid_fit(previous[outside], previous[outside] + moved[outside])
    laid = (previous[outside] - source) @ rotation.T + target
    np.testing.assert_allclose(laid, previous[outside] + moved[outside], atol=0.05)


def test_a_cable_comes_back_where_it_left_with_what_left_last():
    # A track of 55 joints whose joints 44-46 were seen last, at the picture's bottom
    # right; the rest of it out of view. The cable comes back there showing one free end.
    track_length = 55
    numbers = np.array([44, 45, 46])
    points = np.array([[630.0, 474.0], [634.0, 465.0], [637.0, 455.0]])
    shown = np.column_stack([np.linspace(611.0, 601.0, 6), np.linspace(433.0, 479.0, 6)])
    tip_first = Candidate(shown, (True, False), 5.0, None)
    # Its free end is the track's end nearest (along it) the stretch seen last: joint 54.
    assert where_it_left(tip_first, track_length, (numbers, points), 5.0, STEP) == (False, None)
    tip_last = Candidate(shown[::-1].copy(), (False, True), 5.0, None)
    assert where_it_left(tip_last, track_length, (numbers, points), 5.0, STEP) == (True, None)
    # Elsewhere in the picture it cannot tell: the shape must.
    far = Candidate(shown - [300.0, 0.0], (True, False), 5.0, None)
    assert where_it_left(far, track_length, (numbers, points), 5.0, STEP) is None
    # Seen last in its middle, a free end coming back cannot be told from there.
    middle = (np.arange(25, 30), np.column_stack([600.0 + STEP * np.arange(5), np.full(5, 470.0)]))
    near_middle = Candidate(middle[1][:3] - [0.0, 10.0], (True, False), 5.0, None)
    assert where_it_left(near_middle, track_length, middle, 5.0, STEP) is None


def test_a_stretch_back_without_a_free_end_is_laid_on_the_joints_seen_last():
    # Joints 20-32 of a 52-joint track were seen last along the bottom edge; the cable
    # comes back there, showing joints 23-30 (no free end), a little further up.
    old = curved(52, turn=0.004)
    numbers = np.arange(20, 33)
    last = (numbers, old[numbers])
    shown = old[23:31] + np.array([0.0, -6.0])
    forward = Candidate(shown, (False, False), 4.0, None)
    assert where_it_left(forward, 52, last, 4.0, STEP) == (True, 23)
    backward = Candidate(shown[::-1].copy(), (False, False), 4.0, None)
    way, offset = where_it_left(backward, 52, last, 4.0, STEP)
    assert not way and offset == 23
    joints = revived_joints(old, forward, True, STEP, offset=23)
    np.testing.assert_allclose(joints[23:31], shown, atol=0.5)
    assert len(joints) == 52


def test_the_far_end_of_a_cable_seen_in_part_is_its_track_s_other_end():
    # An arch of 40 joints over the picture's top edge: joints 0-9 seen, the rest out of
    # view kept in a shape turned 0.12 rad (about joint 9) from where the cable is. Its
    # far end comes into view elsewhere: the last 6 joints, its free end last.
    truth = curved(40, turn=0.01)
    pivot = truth[9]
    angle = 0.12
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    kept = truth.copy()
    kept[10:] = (truth[10:] - pivot) @ rotation.T + pivot
    seen = np.zeros(40, bool)
    seen[:10] = True
    colour = np.array([120.0, 150.0, 150.0])
    shown = Candidate(truth[34:].copy(), (False, True), 4.0, colour)
    reached = other_end(shown, [(kept, seen, 4.0, colour)], STEP)
    assert reached is not None and (reached.track, reached.end) == (0, 1)
    np.testing.assert_allclose(reached.joints[34:], truth[34:], atol=1e-6)
    np.testing.assert_allclose(reached.joints[:10], kept[:10])
    # The stretch between follows: turned back, the truth within a segment.
    assert np.linalg.norm(reached.joints[10:34] - truth[10:34], axis=1).max() < STEP
    # Elsewhere in the picture, or without one free end, or of another colour: not it.
    far = Candidate(truth[34:] + np.array([0.0, 200.0]), (False, True), 4.0, colour)
    assert other_end(far, [(kept, seen, 4.0, colour)], STEP) is None
    both = Candidate(truth[34:].copy(), (True, True), 4.0, colour)
    assert other_end(both, [(kept, seen, 4.0, colour)], STEP) is None
    other = Candidate(truth[34:].copy(), (False, True), 4.0, np.array([120.0, 100.0, 200.0]))
    assert other_end(other, [(kept, seen, 4.0, colour)], STEP) is None


def test_a_stretch_with_no_free_end_out_along_a_track_seen_in_part_is_more_of_it():
    # A cable of 40 joints coming in broadside over the picture's edge, in pieces: its
    # joints 0-9 seen (its track's out-of-view stretch kept in a shape turned 0.12 rad
    # about joint 9), and elsewhere joints 20-31 with no free end, either way round.
    truth = curved(40, turn=0.01)
    kept = truth.copy()
    kept[10:] = turned(truth[10:] - truth[9], 0.12, truth[9])
    seen = np.arange(40) <= 9
    colour = np.array([120.0, 150.0, 150.0])
    for joints in (truth[20:32], truth[20:32][::-1]):
        shown = Candidate(joints.copy(), (False, False), 4.0, colour)
        reached = other_end(shown, [(kept, seen, 4.0, colour)], STEP)
        assert reached is not None and (reached.track, reached.end, reached.tip) == (0, 1, False)
        np.testing.assert_allclose(reached.joints[20:32], truth[20:32], atol=1e-6)
        np.testing.assert_allclose(reached.joints[:10], kept[:10])
        # Between, and beyond it to the cable's end: turned back, within a segment.
        assert np.linalg.norm(reached.joints[10:] - truth[10:], axis=1).max() < STEP
    # The same stretch moved away from where the track could lie, or of another colour.
    far = Candidate(truth[20:32] + np.array([0.0, 120.0]), (False, False), 4.0, colour)
    assert other_end(far, [(kept, seen, 4.0, colour)], STEP) is None
    red = Candidate(truth[20:32].copy(), (False, False), 4.0, np.array([120.0, 100.0, 200.0]))
    assert other_end(red, [(kept, seen, 4.0, colour)], STEP) is None


def test_a_free_end_back_where_one_end_was_last_seen_is_that_end():
    # A straight cable (the shape cannot tell) that left broadside: its first end was
    # seen last (a frame later), but its free end comes back at the far side, where the
    # last end went out.
    old = straight(0.0, 30)
    ends = (old[0], old[-1])
    shown = Candidate(straight(250.0, 6)[::-1].copy(), (True, False), 4.0, None)
    assert not orientation(shown, old, (True, True), ends, (1.0, 0.97))
    # Back midway between where both ends were: the end seen last.
    middle = Candidate(straight(140.0, 6)[::-1].copy(), (True, False), 4.0, None)
    assert orientation(middle, old, (True, True), ends, (1.0, 0.97))


def test_a_cable_coming_in_fast_becomes_a_track_in_its_second_frame():
    # Nothing in the first frame; then a cable moving 25 px a frame across itself (a
    # new cable's speed is not known: it is looked for as far as a track just begun).
    tracker = Tracker()
    counts = []
    for shift in (None, 0, 25, 50):
        image = np.zeros((200, 300, 3), np.uint8)
        if shift is not None:
            _ = cv2.line(image, (40 + shift, 20), (60 + shift, 180), (0, 200, 255), 9)
        counts.append(len(tracker.update(image).chains))
    assert counts == [0, 0, 1, 1]


def test_a_piece_waits_while_a_track_of_its_look_just_begun_goes_on_out_of_view():
    colour = np.array([120.0, 150.0, 150.0])
    piece = Candidate(straight(0.0, 8), (False, False), 4.0, colour)
    young = [(colour, 4.0)]
    assert waits(piece, young, STEP)
    assert waits(replace(piece, tips=(True, False)), young, STEP)
    # A whole cable in view is a cable of its own; so is one of another colour or width.
    assert not waits(replace(piece, tips=(True, True)), young, STEP)
    assert not waits(piece, [(np.array([120.0, 100.0, 200.0]), 4.0)], STEP)
    assert not waits(piece, [(colour, 9.0)], STEP)
    assert not waits(piece, [], STEP)


def test_a_piece_running_from_one_track_s_free_end_onto_another_s_is_cut_there():
    # Two tracks end to end on one line, their free ends 1 segment apart (x = 200, 210):
    # the detection holds both cables in one chain.
    left, right = straight(0.0, 21)[::-1].copy(), straight(210.0, 20)
    chain = straight(0.0, 40)
    piece = piece_of(0, chain, 0, 39)
    gates = np.array([10.0, 10.0])
    halves = cut_at_met_ends([piece], [left, right], [(True, False), (True, False)], gates, STEP)
    # Each half holds the joints that lie beside its track (the ones at x = 200 and 210
    # lie on no track's side: the segment between them belongs to neither).
    assert [(h.first, len(h.joints)) for h in halves] == [(0, 20), (22, 18)]
    assert [h.tips for h in halves] == [(False, False), (False, False)]
    fits = fit_pieces(halves, [left, right], gates, STEP)
    assert [fit.track for fit in fits] == [0, 1]
    # Ends that are not free (one cable held by two tracks, to be joined) stay one piece.
    for tips in ([(False, False), (True, False)], [(True, False), (False, False)]):
        assert cut_at_met_ends([piece], [left, right], tips, gates, STEP) == [piece]


def two_cables(shift, width=640, height=360):
    """One colour: a cable from the left edge to a free end, pulled right along itself,
    and one from the top edge down to a free end, pulled down; the ends meet at a corner."""
    image = np.full((height, width, 3), 40, np.uint8)
    cv2.line(image, (-50, 200), (min(200 + shift, 326), 200), (0, 200, 255), 9)
    cv2.line(image, (330, -50), (330, min(60 + shift, 196)), (0, 200, 255), 9)
    return image


def test_two_cables_whose_free_ends_meet_keep_their_own_tracks():
    # Where the ends meet the detection joins the two cables into one L-shaped chain;
    # each track keeps its own cable (before, the first took the whole chain and grew
    # round the corner, and the second was lost).
    tracker = Tracker()
    first = tracker.update(two_cables(0)).chains
    assert [chain.ends for chain in first] == [("tip", "open"), ("tip", "open")]
    for frame in range(1, 36):
        tracks = tracker.update(two_cables(6 * frame), timestamp_s=frame / 30).chains
        assert [chain.id for chain in tracks] == [0, 1]
        horizontal, vertical = (np.asarray(chain.points) for chain in tracks)
        assert np.ptp(horizontal[:, 1]) < 5.0 and np.ptp(vertical[:, 0]) < 5.0
        assert tracks[0].unseen == 0 and tracks[1].unseen == 0
