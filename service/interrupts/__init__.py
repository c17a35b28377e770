"""Holding Ctrl-C back while a unit of output is written, so files stay whole.

A ``KeyboardInterrupt`` raised in the middle of writing one frame's outputs would leave a
record half serialised (pydantic wraps it as a serialisation error, which then reads as an
internal error) or a recording with half a frame. :func:`interrupts_held` defers SIGINT to
the end of the block and then delivers it exactly as it would have been delivered.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from typing import Any


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold SIGINT back until the block is done, then deliver it as before.

    Only the main thread receives signals (elsewhere this does nothing).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[Any] = []
    previous = signal.signal(signal.SIGINT, lambda number, frame: caught.append(frame))
    try:
        yield
    finally:
        if previous is not None:  # None: a handler not installed from Python, left alone
            signal.signal(signal.SIGINT, previous)
        if caught:
            if callable(previous):
                previous(signal.SIGINT, caught[0])
            elif previous == signal.SIG_DFL:
                signal.raise_signal(signal.SIGINT)


def raise_if_interrupted(exc: BaseException) -> None:
    """Raise ``KeyboardInterrupt`` when ``exc`` wraps one, else do nothing.

    Ctrl-C that lands while compiled code runs (a numba kernel) surfaces as a
    ``SystemError`` ("returned a result with an exception set") caused by the
    ``KeyboardInterrupt``; a catch-all that reports one bad frame or file must not swallow
    the user's Ctrl-C with it.
    """
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            raise KeyboardInterrupt from exc
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
