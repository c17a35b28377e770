"""A bounded worker pool: detection is CPU work, so it runs in threads, never on an event loop."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")


class PoolBusyError(Exception):
    """Every worker is busy and the queue is full."""


class WorkerPool:
    """A thread pool that takes at most ``workers + queue_size`` jobs at a time.

    :meth:`run` refuses at once (:class:`PoolBusyError`) instead of queueing without
    limit. A slot is freed when the job really ends in its thread, not when the waiting
    request goes away, so the bound holds even when clients disconnect.
    Must be used from one event loop.
    """

    def __init__(self, workers: int, queue_size: int) -> None:
        self.workers = workers
        self.queue_size = queue_size
        self.capacity = workers + queue_size
        self.admitted = 0
        self._executor = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="dlo-detect")

    async def run(self, function: Callable[..., T], *args: Any) -> T:
        """Run ``function(*args)`` in a worker thread and wait for its result.

        Raises
        ------
        PoolBusyError
            ``capacity`` jobs are already running or waiting.
        """
        if self.admitted >= self.capacity:
            raise PoolBusyError
        loop = asyncio.get_running_loop()
        self.admitted += 1
        try:
            job = self._executor.submit(function, *args)
        except BaseException:
            self.admitted -= 1
            raise
        job.add_done_callback(lambda _: self._release_from_any_thread(loop))
        return await asyncio.wrap_future(job)

    def _release_from_any_thread(self, loop: asyncio.AbstractEventLoop) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is already closed at shutdown
            loop.call_soon_threadsafe(self._release)

    def _release(self) -> None:
        self.admitted -= 1

    def shutdown(self) -> None:
        """Drop queued jobs; running ones finish in their threads."""
        self._executor.shutdown(wait=False, cancel_futures=True)
