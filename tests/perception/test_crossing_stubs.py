"""A strand crossing another just before it passes out of sight: its evidence read at the
stub's front past the crossing (service/perception/crossing_stubs.py)."""

from dataclasses import replace

import numpy as np
import pytest

from service.evaluation.synthetic_eval import evaluate_scene
from service.perception.crossing_stubs import (
    LazyEnds,
    ends_past_crossings,
    evidence_ends,
    stub_front,
)
from service.perception.merging import ChainEnd
from service.synthetic.families import make_family_scene

HALF_WIDTH = 4.0


def _crossing(stub_to: int) -> tuple[np.ndarray, np.ndarray]:
    """A horizontal cable (rows 56-64) crossed by a vertical one (columns 56-64) coming
    up from the bottom and cut square at row ``stub_to`` (an object's border), and the
    crossing's junction zone: a disc of 10 px round it."""
    mask = np.zeros((120, 120), bool)
    mask[56:65, :] = True
    mask[stub_to:, 56:65] = True
    ys, xs = np.mgrid[:120, :120]
    zones = np.hypot(xs - 60, ys - 60) <= 10.0
    return mask, zones


def _end_at_crossing() -> ChainEnd:
    # The vertical strand's piece, cut at the zone: its top end points up into it.
    return ChainEnd(
        piece=0,
        at_start=False,
        position=np.array([60.0, 72.0]),
        direction=np.array([0.0, -1.0]),
        skip=HALF_WIDTH,
        width=HALF_WIDTH,
    )


def _pieces() -> list[np.ndarray]:
    vertical = np.column_stack([np.full(8, 60.0), np.linspace(118.0, 71.0, 8)])
    left = np.column_stack([np.linspace(1.0, 49.0, 6), np.full(6, 60.0)])
    right = np.column_stack([np.linspace(71.0, 118.0, 6), np.full(6, 60.0)])
    return [vertical, left, right]


def _ends(pieces: list[np.ndarray]) -> list[ChainEnd]:
    ends = []
    for index, points in enumerate(pieces):
        for at_start in (True, False):
            tip, inner = (points[0], points[1]) if at_start else (points[-1], points[-2])
            direction = (tip - inner) / np.hypot(*(tip - inner))
            ends.append(ChainEnd(index, at_start, tip, direction, width=HALF_WIDTH))
    ends[1] = _end_at_crossing()
    return ends


def test_the_front_of_a_stub_past_a_crossing_is_where_the_strand_is_cut():
    """The vertical strand runs on 14 px past the zone (rows 36-46) and is cut square at
    row 36: the ray along it leaves the zone at row 50 and the foreground at row 35."""
    mask, zones = _crossing(36)
    found = stub_front(np.array([60.0, 71.0]), np.array([0.0, -1.0]), mask, zones, 40.0)
    assert found is not None
    exit_at, front = found
    assert 20.0 <= exit_at <= 22.0
    assert front == pytest.approx(36.0, abs=0.6)


def test_only_a_stub_without_a_piece_moves_its_end():
    """The free end in the crossing moves to the stub's front, its hook gone (skip 0); an
    end in the zone whose strand ends at the other cable's far side does not (no stub),
    nor one whose stub still holds a piece of its own (a strand with its own end)."""
    pieces = _pieces()
    in_junction = np.array([False, True, False, True, True, False])
    mask, zones = _crossing(36)
    ends = _ends(pieces)
    moved = ends_past_crossings(pieces, ends, in_junction, mask, zones, 40.0)
    assert moved[1] is not ends[1]
    assert moved[1].position == pytest.approx([60.0, 35.5], abs=0.6)
    assert moved[1].skip == 0.0
    # The horizontal strand's ends run on as the other piece: never moved.
    assert moved[3] is ends[3] and moved[4] is ends[4]
    # No stub: the vertical strand stops at the horizontal cable's far side.
    mask, zones = _crossing(56)
    assert ends_past_crossings(pieces, ends, in_junction, mask, zones, 40.0)[1] is ends[1]
    # The stub holds a piece: its own strand, not the lost skeleton of this one.
    mask, zones = _crossing(36)
    with_stub = [*pieces, np.array([[60.0, 40.0], [60.0, 49.0]])]
    ends_with_stub = [*ends, *_ends(with_stub)[6:]]
    in_junction_with_stub = np.append(in_junction, [False, True])
    moved = ends_past_crossings(with_stub, ends_with_stub, in_junction_with_stub, mask, zones, 40.0)
    assert moved[1] is ends_with_stub[1]


def test_ends_are_read_when_first_asked_for_and_kept():
    """The ends are moved lazily (most are never asked for on a photograph), each once:
    the same object on every ask, as the list they replace gave."""
    made = []
    lazy = LazyEnds(3, lambda index: made.append(index) or object())
    assert len(lazy) == 3 and made == []
    first = lazy[2]
    assert lazy[2] is first and lazy[-1] is first and made == [2]
    assert lazy[0:2][1] is lazy[1] and made == [2, 0, 1]
    with pytest.raises(IndexError):
        lazy[3]
    # The evidence ends take a judged end's own colour and width, the moved end's place.
    pieces = _pieces()
    in_junction = np.array([False, True, False, True, True, False])
    mask, zones = _crossing(36)
    ends = _ends(pieces)
    moved = ends_past_crossings(pieces, ends, in_junction, mask, zones, 40.0)
    judged = [replace(end, width=9.0) for end in ends]
    seen = evidence_ends(judged, ends, moved)
    assert seen[0] is judged[0]
    assert seen[1].width == 9.0 and seen[1].position == pytest.approx(moved[1].position)
    with pytest.raises(ValueError):
        evidence_ends(judged[:2], ends, moved)


@pytest.mark.parametrize(
    ("family", "seed"), [("occluded", 330077), ("occluded", 94033), ("occluded", 86016)]
)
def test_a_strand_crossing_just_before_an_object_is_joined_across_it(family, seed):
    """Tuning scenes (true mask): a cable crosses another and, a few widths on, passes
    under an object (a disc of another colour, 330077; a box of the background's own
    colour, 94033; a disc of the background's colour beside the crossing, 86016); the
    stretch between the crossing and the object lost its skeleton. Each cable one chain."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.n_chains == score.frame.n_cables
    assert score.frame.correct, score.frame.coverage
