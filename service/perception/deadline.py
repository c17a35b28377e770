"""A time budget for one detection: :class:`Deadline`, checked cooperatively.

Python threads cannot be stopped from outside, so a detection that must not hold its
worker for minutes is given a deadline as an argument (the core stays pure: it keeps no
state and reads nothing but a monotonic clock). The pipeline checks it between its steps
and inside the loops whose length grows with the number of cable pieces; past it, the
detection raises :class:`DeadlineExceeded` and its thread is free again. A compiled
kernel is not interrupted, but each one is linear in the pixels or pieces it walks, so a
check follows it within a fraction of the budget.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class DeadlineExceeded(Exception):
    """The detection ran past its :class:`Deadline`; ``str()`` says where, on one line.

    Attributes
    ----------
    stage : str
        The step that was running (``"merging"`` ...).
    budget_s : float
        The budget the deadline was made with, in seconds.
    """

    def __init__(self, stage: str, budget_s: float) -> None:
        self.stage = stage
        self.budget_s = budget_s
        super().__init__(f"detection stopped in {stage} after its budget of {budget_s:g} s")


class Deadline:
    """The moment a detection must end by, ``budget_s`` seconds after it was made.

    Parameters
    ----------
    budget_s : float
        Seconds from now.
    clock : callable, optional
        Seconds as a float; :func:`time.monotonic` by default (tests pass their own).

    Examples
    --------
    >>> Deadline(60.0).check("segmentation")  # within the budget: returns
    >>> ticks = iter([0.0, 1.0])  # made at 0 s, checked at 1 s
    >>> try:
    ...     Deadline(0.5, clock=lambda: next(ticks)).check("merging")
    ... except DeadlineExceeded as exc:
    ...     print(exc)
    detection stopped in merging after its budget of 0.5 s
    """

    __slots__ = ("_clock", "budget_s", "ends_at")

    def __init__(self, budget_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self.budget_s = float(budget_s)
        self.ends_at = clock() + self.budget_s

    def expired(self) -> bool:
        """True once the budget is spent."""
        return self._clock() > self.ends_at

    def check(self, stage: str) -> None:
        """Raise :class:`DeadlineExceeded` naming ``stage`` once the budget is spent."""
        if self._clock() > self.ends_at:
            raise DeadlineExceeded(stage, self.budget_s)


def check(deadline: Deadline | None, stage: str) -> None:
    """:meth:`Deadline.check` when there is a deadline (``None``: no budget)."""
    if deadline is not None:
        deadline.check(stage)
