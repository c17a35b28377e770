"""What one running service holds: settings, metrics, the worker pool and readiness."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

from service.http.jobs import DetectFunction
from service.http.metrics import Metrics
from service.http.settings import Settings

if TYPE_CHECKING:
    from service.bus import DetectionBus

logger = logging.getLogger(__name__)

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


@dataclass
class AppState:
    """Everything the routes need, created by the app's lifespan.

    The zenoh front end (:class:`service.bus.DetectionBus`, in ``bus`` when enabled)
    shares the metrics and the detect function; it runs detection in a thread of its own.
    """

    settings: Settings
    metrics: Metrics
    detect: DetectFunction
    pool: WorkerPool
    ready: bool = False
    warm_up_error: str | None = None
    background: list[asyncio.Task[Any] | Future[Any]] = field(default_factory=list)
    bus: DetectionBus | None = None
    bus_error: str | None = None

    @property
    def bus_ready(self) -> bool:
        """True when zenoh is disabled, or its session is open."""
        return not self.settings.zenoh or (self.bus is not None and self.bus.is_open)

    @classmethod
    def start(cls, settings: Settings, metrics: Metrics, detect: DetectFunction) -> AppState:
        pool = WorkerPool(settings.workers, settings.queue_size)
        metrics.in_flight.set_function(lambda: pool.admitted)
        return cls(settings=settings, metrics=metrics, detect=detect, pool=pool)

    async def close(self) -> None:
        for task in self.background:
            task.cancel()
        if self.bus is not None:
            await asyncio.to_thread(self.bus.close)
        self.pool.shutdown()
