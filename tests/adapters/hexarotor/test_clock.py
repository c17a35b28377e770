"""The adapter's clocks: the lockstep rules, with one thread playing the vehicle's side."""

from __future__ import annotations

import queue
import threading

import pytest

from adapters.hexarotor.clock import LockstepClock, PeriodicTask, WallClock
from tests.helpers import wait_until


class Vehicle:
    """The vehicle's TIMESYNC requests, taken one after the other as a receive loop does."""

    def __init__(self, clock: LockstepClock) -> None:
        self.clock = clock
        self.answered: list[float] = []
        self._requests: queue.Queue[float | None] = queue.Queue()
        self._thread = threading.Thread(target=self._receive, daemon=True)
        self._thread.start()

    def request(self, time_s: float) -> None:
        self._requests.put(time_s)

    def _receive(self) -> None:
        while (time_s := self._requests.get()) is not None:
            self.clock.vehicle_step(time_s, lambda t=time_s: self.answered.append(t))

    def close(self) -> None:
        self._requests.put(None)


@pytest.fixture
def lockstep():
    """A lockstep clock owned by the test's thread, two tasks, and the vehicle's side."""
    clock = LockstepClock(stall_s=60.0)  # never reached here: every wait ends on a step
    ran: list[tuple[str, float]] = []
    tasks = [
        PeriodicTask("beat", 1.0, lambda now: ran.append(("beat", now)), immediately=True),
        PeriodicTask("stream", 0.05, lambda now: ran.append(("stream", now))),
    ]
    clock.start(tasks, threading.Event())
    vehicle = Vehicle(clock)
    yield clock, vehicle, ran
    clock.close()
    vehicle.close()


def test_a_step_is_answered_only_once_the_owner_waits_again(lockstep) -> None:
    clock, vehicle, _ = lockstep
    vehicle.request(0.0)
    vehicle.request(0.025)
    wait_until(lambda: clock.steps >= 1, "the first step")
    # The owner (this thread) is busy: the first step stays unanswered, so the second
    # cannot be taken either.
    assert clock.steps == 1 and vehicle.answered == []
    looked_at: list[tuple[float, list[float]]] = []

    def second_step() -> bool:
        looked_at.append((clock.now(), list(vehicle.answered)))
        return clock.steps >= 2

    assert clock.wait_for(threading.Condition(), second_step, timeout_s=1.0)
    # Looked at once at each step's time; the first answer went out only once we waited.
    assert looked_at == [(0.0, []), (0.025, [0.0])]
    assert vehicle.answered == [0.0]  # the second waits for us again


def test_messages_are_applied_at_the_end_of_the_vehicles_step(lockstep) -> None:
    clock, vehicle, _ = lockstep
    inbox: list[str] = []
    clock.deliver(lambda: inbox.append("telemetry"))
    assert inbox == []  # kept until the step's TIMESYNC request
    vehicle.request(0.0)
    assert clock.wait_for(threading.Condition(), lambda: inbox == ["telemetry"], timeout_s=1.0)
    assert clock.now() == 0.0


def test_periodic_tasks_run_at_the_steps_they_fall_due(lockstep) -> None:
    clock, vehicle, ran = lockstep
    for index in range(5):
        vehicle.request(index * 0.025)
        clock.wait_for(threading.Condition(), lambda i=index: clock.steps > i, timeout_s=1.0)
    assert ran == [("beat", 0.0), ("stream", 0.05), ("stream", 0.1)]


def test_a_repeated_request_is_answered_at_once_without_a_new_step(lockstep) -> None:
    clock, vehicle, _ = lockstep
    vehicle.request(0.0)
    vehicle.request(0.0)  # sent again while we worked on it
    vehicle.request(0.025)
    assert clock.wait_for(threading.Condition(), lambda: clock.steps == 2, timeout_s=1.0)
    assert clock.now() == 0.025
    assert vehicle.answered == [0.0, 0.0]


def test_without_steps_time_passes_by_the_stall_allowance() -> None:
    clock = LockstepClock(stall_s=0.05)
    clock.start([], threading.Event())
    assert not clock.wait_for(threading.Condition(), lambda: False, timeout_s=0.2)
    assert clock.now() == pytest.approx(0.2)


def test_the_wall_clock_runs_tasks_on_threads_and_answers_at_once() -> None:
    clock = WallClock()
    stop = threading.Event()
    calls: list[float] = []
    threads = clock.start([PeriodicTask("tick", 0.01, calls.append, immediately=True)], stop)
    wait_until(lambda: len(calls) >= 3, "three ticks")
    stop.set()
    for thread in threads:
        thread.join(timeout=10)
    assert calls == sorted(calls)
    answered: list[str] = []
    clock.vehicle_step(1.0, lambda: answered.append("at once"))
    assert answered == ["at once"]
