"""Which replica owns which camera: the pure rule (:func:`assign`) and one replica's view."""

from __future__ import annotations

import random
from collections import Counter

import pytest

from service.bus.ownership import (
    REPLICAS_KEY,
    Ownership,
    assign,
    ranking,
    replicas_key,
    weight,
)


def names(prefix: str, count: int, rng: random.Random) -> list[str]:
    return [f"{prefix}{rng.getrandbits(64):016x}" for _ in range(count)]


SIZES = [(1, 1), (3, 3), (6, 3), (4, 2), (7, 3), (2, 5), (12, 4), (40, 3)]


@pytest.mark.parametrize("balanced", [True, False])
@pytest.mark.parametrize(("cameras", "replicas"), SIZES)
def test_every_camera_gets_one_owner_whatever_the_order(
    cameras: int, replicas: int, balanced: bool
) -> None:
    rng = random.Random(cameras * 100 + replicas)
    camera_names, replica_names = names("cam", cameras, rng), names("r", replicas, rng)
    owners = assign(camera_names, replica_names, balanced)
    assert set(owners) == set(camera_names) and set(owners.values()) <= set(replica_names)
    for _ in range(3):  # every replica computes the same, whatever order it learnt things in
        rng.shuffle(camera_names)
        rng.shuffle(replica_names)
        assert assign(camera_names, replica_names, balanced) == owners


@pytest.mark.parametrize(("cameras", "replicas"), SIZES)
def test_balanced_loads_differ_by_one_camera_at_most(cameras: int, replicas: int) -> None:
    rng = random.Random(7)
    for _ in range(20):
        replica_names = names("r", replicas, rng)
        loads = Counter(assign(names("cam", cameras, rng), replica_names).values())
        counts = [loads[replica] for replica in replica_names]
        assert max(counts) - min(counts) <= 1


def test_three_cameras_on_three_replicas() -> None:
    """Balanced: one each, always. Plain rendezvous: as the hash falls (often not)."""
    rng = random.Random(3)
    spread = Counter()
    for _ in range(200):
        cameras, replicas = names("cam", 3, rng), names("r", 3, rng)
        assert sorted(Counter(assign(cameras, replicas).values()).values()) == [1, 1, 1]
        spread[len(set(assign(cameras, replicas, balanced=False).values()))] += 1
    assert spread[3] < 100  # 2 times in 9 on average: why balanced is the default


def test_plain_rendezvous_moves_only_what_a_replica_gains_or_loses() -> None:
    rng = random.Random(11)
    cameras = names("cam", 50, rng)
    replicas = names("r", 4, rng)
    before = assign(cameras, replicas, balanced=False)
    gone = replicas[1]
    after = assign(cameras, [r for r in replicas if r != gone], balanced=False)
    assert {c for c in cameras if before[c] != after[c]} == {
        c for c in cameras if before[c] == gone
    }
    newcomer = "r-new"
    joined = assign(cameras, [*replicas, newcomer], balanced=False)
    assert {c for c in cameras if before[c] != joined[c]} == {
        c for c in cameras if joined[c] == newcomer
    }
    for camera in cameras:  # the owner is the head of the camera's ranking
        assert before[camera] == ranking(camera, replicas)[0]
        assert weight(before[camera], camera) == max(weight(r, camera) for r in replicas)


def test_balanced_hands_a_dead_replicas_cameras_over_and_moves_few_others() -> None:
    rng = random.Random(5)
    extra_moves = []
    for _ in range(300):
        cameras, replicas = names("cam", 6, rng), names("r", 3, rng)
        before = assign(cameras, replicas)
        gone = rng.choice(replicas)
        after = assign(cameras, [r for r in replicas if r != gone])
        assert gone not in after.values()
        moved = {c for c in cameras if before[c] != after[c]}
        orphans = {c for c in cameras if before[c] == gone}
        assert orphans <= moved
        extra_moves.append(len(moved - orphans))
    assert max(extra_moves) <= 2 and sum(extra_moves) / len(extra_moves) < 0.6


def test_no_replica_no_owner() -> None:
    assert assign(["cam1"], []) == {}
    assert assign([], ["r1"]) == {}


def test_pools_by_image_keys() -> None:
    assert replicas_key(["dlo/*/image"]) == REPLICAS_KEY == "dlo/@replicas"
    line1 = replicas_key(["dlo/line1-$*/image"])
    assert line1.startswith("dlo/@replicas/keys-") and line1.count("/") == 2
    assert replicas_key(["dlo/a/image", "dlo/b/image"]) == replicas_key(
        ["dlo/b/image", "dlo/a/image", "dlo/a/image"]
    )
    assert replicas_key(["dlo/a/image"]) != line1


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_one_replicas_view() -> None:
    clock = Clock()
    handovers: list[tuple[str, int]] = []
    me = Ownership("b", camera_idle_s=10.0, clock=clock, on_handover=lambda *h: handovers.append(h))
    assert not me.owns("cam1")  # not announced yet: owns nothing, alone or not
    assert me.replica_seen("a") and not me.replica_seen("a") and not me.replica_seen("b")
    me.announce()
    assert me.replicas == ["a", "b"]
    for camera in ("cam1", "cam2", "cam3", "cam4"):
        me.owns(camera)
    mine = me.owned()
    assert mine == sorted(
        c for c, owner in assign(["cam1", "cam2", "cam3", "cam4"], "ab").items() if owner == "b"
    )
    assert len(mine) == 2 and me.active() == 4
    # a camera that appears may move another between the replicas (balanced loads)
    gained, lost = me.gained, me.lost
    handovers.clear()

    assert me.replica_gone("a") and not me.replica_gone("a")
    assert me.owned() == ["cam1", "cam2", "cam3", "cam4"]
    assert handovers == [("gained", 2)] and me.gained == gained + 2

    me.replica_seen("c")
    assert len(me.owned()) == 2 and handovers[-1] == ("lost", 2) and me.lost == lost + 2

    # cam4 goes quiet: after 10 s it no longer counts, and the rest are shared again
    clock.now = 6.0
    for camera in ("cam1", "cam2", "cam3"):
        me.owns(camera)
    clock.now = 10.5
    assert me.active() == 3
    clock.now = 16.5
    assert me.owns("cam1") is ("cam1" in me.owned())
    assert me.active() == 1


def test_a_replica_that_stops_owns_nothing_from_then_on() -> None:
    me = Ownership("b")
    me.replica_seen("a")
    me.announce()
    for camera in ("cam1", "cam2"):
        me.owns(camera)
    assert len(me.owned()) == 1
    lost = me.lost
    me.withdraw()  # its token is about to go: the others take over when they see it
    assert me.owned() == [] and not me.owns("cam1") and not me.owns("cam2")
    assert me.lost == lost + 1
