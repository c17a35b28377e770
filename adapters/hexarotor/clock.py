"""The hexarotor adapter's clock port: the wall clock, or the vehicle's simulated time in lockstep.

:class:`~adapters.hexarotor.driver.MavlinkVehicle` reads the time, waits for the vehicle,
runs its periodic tasks (our heartbeat, the setpoint stream) and applies the messages it
receives through one of two clocks:

* :class:`WallClock` (the default; a real vehicle, or a simulator in real time): the time is
  ``time.monotonic()``, each periodic task runs on its own thread, a message is applied as
  it arrives, and a vehicle's ``TIMESYNC`` request is answered at once.
* :class:`LockstepClock` (a simulator that steps in lockstep, as SITL can with its physics;
  ``dlo hexa trial`` with the fake vehicle): the time is the vehicle's. The vehicle ends each
  simulation step with a ``TIMESYNC`` request whose ``ts1`` is its simulated time (ns) and
  does not step on before the answer. At each such request the adapter applies the messages
  of that step (they arrived before it, on the same link), runs the periodic tasks that fell
  due, lets the thread that drives it (the *owner*: the one that connected) react until it
  waits again, and only then answers. So no simulated time passes while the adapter works,
  the vehicle sees every command at a definite simulated instant, and a run with the same
  seed gives the same numbers on any machine, as fast as the two sides can exchange the
  messages. When the owner is busy outside the adapter, the vehicle waits for it too.

  If the vehicle stops stepping (the link or the simulator died), a waiting owner lets
  ``stall_s`` wall-clock seconds count as simulated time, so link-loss and command deadlines
  still expire.

The MAVLink side is standard: ``TIMESYNC`` requests carry ``tc1 = 0`` and the sender's time in
``ts1``; the answer carries our time in ``tc1`` and the request's ``ts1`` back. A ground
station that is not in lockstep (MAVSDK, QGroundControl, :class:`WallClock`) answers at once.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

Predicate = Callable[[], bool]


@dataclass(frozen=True)
class PeriodicTask:
    """Work the adapter repeats: ``run(now)`` every ``period_s`` seconds of the clock."""

    name: str
    period_s: float
    run: Callable[[float], None]
    immediately: bool = False
    """Run at the start as well, not only after the first period."""


class Clock(Protocol):
    """What the driver needs of its clock (see the module docstring)."""

    def now(self) -> float:
        """Seconds on this clock."""
        ...

    def start(self, tasks: Sequence[PeriodicTask], stop: threading.Event) -> list[threading.Thread]:
        """Begin running ``tasks`` until ``stop`` is set; the threads started for them."""
        ...

    def wait_for(
        self, condition: threading.Condition, predicate: Predicate, timeout_s: float
    ) -> bool:
        """Wait until ``predicate()`` (evaluated holding ``condition``) holds; False after
        ``timeout_s`` seconds of this clock. Call without holding ``condition``."""
        ...

    def deliver(self, apply: Callable[[], None]) -> None:
        """Apply a received message (``apply`` takes the driver's lock itself)."""
        ...

    def vehicle_step(self, time_s: float, answer: Callable[[], None]) -> None:
        """The vehicle asked for a time sync at its time ``time_s``; ``answer`` sends the reply."""
        ...

    def close(self) -> None:
        """Release every wait (the driver is closing)."""
        ...


class WallClock:
    """Real time: ``time.monotonic()``, threads for the periodic tasks, messages applied at once."""

    WAKE_S = 0.1
    """Longest a wait sleeps without looking at its predicate again."""

    def now(self) -> float:
        return time.monotonic()

    def start(self, tasks: Sequence[PeriodicTask], stop: threading.Event) -> list[threading.Thread]:
        threads = []
        for task in tasks:
            thread = threading.Thread(
                target=self._repeat, args=(task, stop), name=task.name, daemon=True
            )
            thread.start()
            threads.append(thread)
        return threads

    def _repeat(self, task: PeriodicTask, stop: threading.Event) -> None:
        if task.immediately:
            task.run(self.now())
        while not stop.wait(task.period_s):
            task.run(self.now())

    def wait_for(
        self, condition: threading.Condition, predicate: Predicate, timeout_s: float
    ) -> bool:
        deadline = self.now() + timeout_s
        with condition:
            while not predicate():
                remaining = deadline - self.now()
                if remaining <= 0:
                    return False
                condition.wait(min(remaining, self.WAKE_S))
            return True

    def deliver(self, apply: Callable[[], None]) -> None:
        apply()

    def vehicle_step(self, time_s: float, answer: Callable[[], None]) -> None:
        answer()

    def close(self) -> None:
        pass


class LockstepClock:
    """The vehicle's simulated time, stepped in lockstep with the adapter (module docstring).

    Parameters
    ----------
    stall_s
        Wall-clock seconds a waiting owner gives the vehicle to step before counting them as
        simulated time (the vehicle is gone; deadlines must still expire).
    """

    def __init__(self, stall_s: float = 5.0) -> None:
        if not stall_s > 0:
            raise ValueError(f"stall_s must be > 0, got {stall_s}")
        self.stall_s = stall_s
        self._lock = threading.Condition()
        self._now = 0.0
        self._step = 0
        """Steps the vehicle has made so far (TIMESYNC requests taken)."""
        self._last_step_s: float | None = None
        self._pending: list[Callable[[], None]] = []
        self._tasks: list[PeriodicTask] = []
        self._due: list[float | None] = []
        self._owner: int | None = None
        self._owner_waiting = False
        self._owner_checked = -1
        """The step at which the waiting owner last looked at its predicate."""
        self._closed = False

    @property
    def steps(self) -> int:
        """Vehicle steps taken so far."""
        with self._lock:
            return self._step

    def now(self) -> float:
        with self._lock:
            return self._now

    def start(self, tasks: Sequence[PeriodicTask], stop: threading.Event) -> list[threading.Thread]:
        """Take the calling thread as the owner; the tasks run at the vehicle's steps."""
        with self._lock:
            self._owner = threading.get_ident()
            self._tasks = list(tasks)
            self._due = [None] * len(self._tasks)
            self._closed = False
        return []

    def deliver(self, apply: Callable[[], None]) -> None:
        """Keep the message for the end of the vehicle's step (its TIMESYNC request)."""
        with self._lock:
            self._pending.append(apply)

    def vehicle_step(self, time_s: float, answer: Callable[[], None]) -> None:
        """Apply the step's messages, run due tasks, let the owner react, then ``answer``.

        A request for a step already taken (the vehicle sent it again while we worked on
        it) is answered at once.
        """
        with self._lock:
            repeated = self._last_step_s is not None and time_s <= self._last_step_s
            if not repeated:
                self._last_step_s = time_s
                self._now = max(self._now, time_s)
            now = self._now
        if repeated:
            answer()
            return
        self._apply_pending()
        for index, task in enumerate(self._tasks):
            due = self._due[index]
            if due is None:
                due = now if task.immediately else now + task.period_s
            if due <= now:
                task.run(now)
                due += task.period_s
                if due <= now:  # the vehicle stepped further than one period: skip
                    due = now + task.period_s
            self._due[index] = due
        with self._lock:
            self._step += 1
            self._lock.notify_all()
            while not (self._closed or self._owner_idle()):
                self._lock.wait(self.stall_s)
        answer()

    def _owner_idle(self) -> bool:
        return self._owner is None or (self._owner_waiting and self._owner_checked >= self._step)

    def wait_for(
        self, condition: threading.Condition, predicate: Predicate, timeout_s: float
    ) -> bool:
        deadline = self.now() + timeout_s
        while True:
            with self._lock:
                step = self._step
            with condition:
                if predicate():
                    return True
            if self.now() >= deadline:
                return False
            self._await_step(step)

    def _await_step(self, checked: int) -> None:
        """Wait (as an idle owner, when called by it) for a step after ``checked``."""
        stalled = False
        with self._lock:
            owner = threading.get_ident() == self._owner
            if owner:
                self._owner_waiting = True
                self._owner_checked = checked
                self._lock.notify_all()
            try:
                while self._step <= checked and not self._closed:
                    if not self._lock.wait(self.stall_s) and self._step <= checked:
                        self._now += self.stall_s  # the vehicle is not stepping: time passes
                        stalled = True
                        break
            finally:
                if owner:
                    self._owner_waiting = False
        if stalled:
            self._apply_pending()

    def _apply_pending(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, []
        for apply in pending:
            apply()

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._owner = None
            self._lock.notify_all()
        self._apply_pending()
