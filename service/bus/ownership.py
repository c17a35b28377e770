"""Which replica detects which camera, decided by every replica alone, the same way.

Replicas that subscribe to the same image keys form a pool. Each announces itself with a
zenoh liveliness token, ``dlo/@replicas/<zenoh id>`` (``dlo/@replicas/<pool>/<zenoh id>``
for a pool with its own image keys, :func:`replicas_key`), and watches the pool's tokens:
zenoh removes a token when its session ends, closed or killed (a lost TCP link at once, a
silent one after the transport's lease). From the live replicas and the cameras seen
lately, :func:`assign` gives each camera one owner; all replicas compute the same function
of the same inputs, so exactly one of them detects each camera's frames, and the others
drop them before decoding.

The rule is rendezvous (highest-random-weight) hashing: camera ``c`` ranks the replicas by
``weight(r, c)``, a hash of both names, and goes to the first. Plain rendezvous
(``balanced=False``) moves only the cameras of a replica that leaves, and only the cameras a
newcomer wins, and needs nothing but the replica set; but with few cameras it leaves
replicas idle (three cameras land on three replicas one each only 2 times in 9). So by
default (``balanced=True``) the loads are bounded: cameras, in the order of their own hash,
each take the first replica of their ranking that has room, and no replica holds more than
one camera more than another (consistent hashing with bounded loads, Mirrokni, Thorup and
Zadimoghaddam 2018, at its tightest bound). A join or a leave then also moves a camera
whose first choice gains or loses room (on average 0.3 cameras beyond the leaver's own for
3 to 8 cameras on 3 replicas), and the assignment depends on the set of active cameras,
which every replica learns from the same frames: a camera is active while it sent a frame
in the last ``camera_idle_s`` seconds.
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections.abc import Callable, Iterable

from service.runtime.settings import IMAGE_KEYS

REPLICAS_KEY = "dlo/@replicas"
"""Where the replicas of the default pool (image keys ``dlo/*/image``) announce themselves."""
CAMERA_IDLE_S = 10.0
"""A camera without a frame for this long no longer counts in the balanced assignment."""
MAX_CAMERAS = 10_000
"""Cameras remembered at most; beyond, the one silent the longest is forgotten."""


def replicas_key(image_keys: Iterable[str]) -> str:
    """The liveliness prefix of the pool of replicas subscribed to ``image_keys``.

    ``dlo/@replicas`` for the default ``dlo/*/image``; for other keys (static partitions),
    ``dlo/@replicas/keys-<hash of the sorted keys>``, so that replicas share cameras only
    with replicas that receive the same frames.
    """
    keys = sorted(set(image_keys))
    if keys == [IMAGE_KEYS]:
        return REPLICAS_KEY
    digest = hashlib.blake2b("\n".join(keys).encode(), digest_size=4).hexdigest()
    return f"{REPLICAS_KEY}/keys-{digest}"


def weight(replica: str, camera: str) -> int:
    """The rendezvous weight of ``replica`` for ``camera``: 64 bits of a hash of both."""
    data = camera.encode() + b"\0" + replica.encode()
    return int.from_bytes(hashlib.blake2b(data, digest_size=8).digest(), "big")


def ranking(camera: str, replicas: Iterable[str]) -> list[str]:
    """The replicas in ``camera``'s order of preference, heaviest first."""
    return sorted(replicas, key=lambda replica: (weight(replica, camera), replica), reverse=True)


def _camera_order(camera: str) -> tuple[bytes, str]:
    return hashlib.blake2b(camera.encode(), digest_size=8).digest(), camera


def assign(
    cameras: Iterable[str], replicas: Iterable[str], balanced: bool = True
) -> dict[str, str]:
    """The owner of each camera among ``replicas`` (empty without replicas).

    Parameters
    ----------
    cameras, replicas : iterable of str
        Camera names and replica ids; the order does not matter.
    balanced : bool
        Bound the loads: no replica owns more than one camera more than another. Otherwise
        plain rendezvous hashing: each camera to the first replica of its :func:`ranking`.

    Examples
    --------
    >>> owners = assign(["cam1", "cam2", "cam3"], ["a", "b", "c"])
    >>> sorted(owners.values())
    ['a', 'b', 'c']
    >>> owners == assign(["cam3", "cam1", "cam2"], ["c", "a", "b"])
    True
    """
    pool = sorted(set(replicas))
    wanted = sorted(set(cameras), key=_camera_order)
    if not pool:
        return {}
    if not balanced:
        return {camera: ranking(camera, pool)[0] for camera in wanted}
    base, extra = divmod(len(wanted), len(pool))
    load = dict.fromkeys(pool, 0)
    above_base = 0  # replicas holding base + 1 cameras; at most `extra` of them
    owners = {}
    for camera in wanted:
        for replica in ranking(camera, pool):
            if load[replica] < base or (load[replica] == base and above_base < extra):
                above_base += load[replica] == base
                load[replica] += 1
                owners[camera] = replica
                break
    return owners


class Ownership:
    """One replica's view of its pool: the live replicas, the active cameras, and which
    cameras are its own (:func:`assign`). Thread-safe: zenoh's callbacks update it.

    Parameters
    ----------
    me : str
        This replica's id; it owns nothing until :meth:`announce`.
    balanced : bool
        See :func:`assign`.
    camera_idle_s : float
        A camera silent for longer no longer counts as active.
    clock : callable
        Seconds, monotonic (tests inject their own).
    on_handover : callable, optional
        ``on_handover(direction, cameras)`` when cameras are handed over to this replica
        (``"gained"``) or by it (``"lost"``); called with the lock held: keep it short.
    """

    def __init__(
        self,
        me: str,
        *,
        balanced: bool = True,
        camera_idle_s: float = CAMERA_IDLE_S,
        clock: Callable[[], float] = time.monotonic,
        on_handover: Callable[[str, int], None] | None = None,
    ) -> None:
        self.me = me
        self.balanced = balanced
        self.camera_idle_s = camera_idle_s
        self._clock = clock
        self._on_handover = on_handover
        self._lock = threading.Lock()
        self._others: set[str] = set()
        self._announced = False
        self._last_frame: dict[str, float] = {}
        self._expiry_check = float("inf")
        self._owners: dict[str, str] = {}
        self.gained = 0
        """Cameras handed over to this replica by another since the start."""
        self.lost = 0
        """Cameras handed over by this replica to another since the start."""

    # -- what changes the assignment ---------------------------------------------------------

    def announce(self) -> None:
        """This replica counts from now on (its liveliness token is declared)."""
        with self._lock:
            self._announced = True
            self._reassign()

    def withdraw(self) -> None:
        """This replica stops (its token is about to go): it owns nothing from now on."""
        with self._lock:
            self._announced = False
            self._reassign()

    def replica_seen(self, replica: str) -> bool:
        """A replica's token appeared; True when it is new."""
        with self._lock:
            if replica == self.me or replica in self._others:
                return False
            self._others.add(replica)
            self._reassign()
            return True

    def replica_gone(self, replica: str) -> bool:
        """A replica's token vanished (it stopped, or its link died); True when it was known."""
        with self._lock:
            if replica not in self._others:
                return False
            self._others.discard(replica)
            self._reassign()
            return True

    def owns(self, camera: str) -> bool:
        """Whether this replica detects ``camera``'s frame arriving now (and note the frame)."""
        now = self._clock()
        with self._lock:
            new = camera not in self._last_frame
            self._last_frame[camera] = now
            forgot = self._forget_idle(now)
            if new or forgot:
                self._reassign()
            return self._owners.get(camera) == self.me

    # -- what it says ------------------------------------------------------------------------

    @property
    def replicas(self) -> list[str]:
        """The live replicas of the pool, this one included once announced."""
        with self._lock:
            return sorted(self._pool())

    def owned(self) -> list[str]:
        """The active cameras this replica owns."""
        with self._lock:
            self._refresh()
            return sorted(camera for camera, owner in self._owners.items() if owner == self.me)

    def active(self) -> int:
        """The number of cameras that sent a frame in the last ``camera_idle_s``."""
        with self._lock:
            self._refresh()
            return len(self._last_frame)

    # -- inside the lock ----------------------------------------------------------------------

    def _pool(self) -> set[str]:
        return self._others | {self.me} if self._announced else set(self._others)

    def _refresh(self) -> None:
        if self._forget_idle(self._clock()):
            self._reassign()

    def _forget_idle(self, now: float) -> bool:
        """Drop the cameras silent for longer than ``camera_idle_s``; True if any was."""
        forgot = False
        while len(self._last_frame) > MAX_CAMERAS:
            del self._last_frame[min(self._last_frame, key=self._last_frame.__getitem__)]
            forgot = True
        if now < self._expiry_check:
            return forgot
        idle = [
            camera for camera, last in self._last_frame.items() if now - last > self.camera_idle_s
        ]
        for camera in idle:
            del self._last_frame[camera]
        oldest = min(self._last_frame.values(), default=float("inf"))
        self._expiry_check = oldest + self.camera_idle_s
        return forgot or bool(idle)

    def _reassign(self) -> None:
        before = self._owners
        after = assign(self._last_frame, self._pool(), self.balanced)
        moved = [(before[c], owner) for c, owner in after.items() if before.get(c, owner) != owner]
        gained = sum(owner == self.me for _, owner in moved)  # a camera just seen is not moved
        lost = sum(previous == self.me for previous, _ in moved)
        self.gained += gained
        self.lost += lost
        if self._on_handover is not None:
            for direction, cameras in (("gained", gained), ("lost", lost)):
                if cameras:
                    self._on_handover(direction, cameras)
        self._owners = after
        if self._expiry_check == float("inf") and self._last_frame:
            self._expiry_check = min(self._last_frame.values()) + self.camera_idle_s
