"""Detection over zenoh: images in on ``dlo/<camera>/image``, Detections out on ``.../chains``.

:class:`DetectionBus` opens a zenoh session (an embedded peer unless a configuration says
otherwise) and

* subscribes to ``dlo/*/image``: the payload is an encoded JPEG or PNG, the optional
  attachment the detection parameters as JSON (:class:`schemas.DetectParams`). The
  Detection JSON is published on ``dlo/<camera>/chains``; a sample that cannot be
  processed (not an image, bad parameters, too large) gives an error record
  ``{"camera", "error", "detail"}`` on ``dlo/<camera>/errors`` instead;
* answers queries on ``dlo/detect``: the query's payload is the image, its attachment
  the parameters; the reply is the Detection JSON, or an error reply holding
  ``{"error", "detail"}``.

Detection runs in one thread per bus. Latest frame wins: per camera only the newest
frame waits; a frame replaced before it was processed is dropped and counted. Queries
are never replaced, but at most ``max_queries`` wait; beyond that they are refused.
"""

from __future__ import annotations

import json
import logging
import threading
from collections import Counter, OrderedDict
from dataclasses import dataclass
from typing import Any

import zenoh
from pydantic import ValidationError

from schemas import DetectParams
from service.batch import describe_json_validation_error
from service.bus.config import IMAGE_KEYS, JSON, QUERY_KEY, chains_key, errors_key
from service.runtime.errors import RequestError
from service.runtime.frames import Frame, check_upload
from service.runtime.jobs import OVER_BUDGET, DetectFunction, default_detect, run_detection
from service.runtime.metrics import Metrics

logger = logging.getLogger(__name__)


def params_from_attachment(attachment: zenoh.ZBytes | None) -> DetectParams:
    """The parameters sent as JSON in a sample's attachment; defaults without one.

    Raises
    ------
    RequestError
        422 when the attachment is not a JSON object of valid parameters.
    """
    if attachment is None:
        return DetectParams()
    try:
        return DetectParams.model_validate_json(attachment.to_bytes())
    except ValidationError as exc:
        problems = describe_json_validation_error(exc, "attachment")
        raise RequestError(422, "invalid_params", f"parameters: {problems}") from None


@dataclass
class _Job:
    """One image waiting for detection: a camera frame, or a query to answer."""

    image: bytes
    attachment: zenoh.ZBytes | None
    camera: str | None = None
    query: zenoh.Query | None = None


class DetectionBus:
    """Serve detection on a zenoh session; see the module's documentation.

    Parameters
    ----------
    config : zenoh.Config, optional
        The session's configuration (see :func:`make_config`); default: zenoh's (a peer).
    detect : callable, optional
        ``detect(image, params, mask, deadline) -> Detection``; default
        :func:`service.perception.detect`.
    metrics : Metrics, optional
        Counters to update (the HTTP app's when the bus runs inside it); default: its own.
    max_pixels, max_bytes : int
        Largest image accepted, in pixels and in encoded bytes.
    max_queries : int
        Queries that may wait for the detection thread; beyond that they are refused.
    max_detect_seconds : float, optional
        Time budget of one detection (decoding included); past it the frame or query
        gets the error ``time_budget_exceeded`` and the thread goes on. None: no limit.
    """

    def __init__(
        self,
        config: zenoh.Config | None = None,
        *,
        detect: DetectFunction | None = None,
        metrics: Metrics | None = None,
        max_pixels: int = 40_000_000,
        max_bytes: int = 25 * 1024 * 1024,
        max_queries: int = 8,
        max_detect_seconds: float | None = None,
    ) -> None:
        self._config = config if config is not None else zenoh.Config()
        self._detect = detect if detect is not None else default_detect
        self.metrics = metrics if metrics is not None else Metrics()
        self.max_pixels = max_pixels
        self.max_bytes = max_bytes
        self.max_queries = max_queries
        self.max_detect_seconds = max_detect_seconds
        self.counts: Counter[str] = Counter()
        """Outcomes so far: ``published``, ``replaced``, ``rejected``, ``failed`` for frames,
        ``query_answered`` ... for queries (also in ``metrics``)."""
        self._pending: OrderedDict[tuple[str, Any], _Job] = OrderedDict()
        self._queries_waiting = 0
        self._next_query = 0
        self._condition = threading.Condition()
        self._stopping = False
        self._session: zenoh.Session | None = None
        self._thread: threading.Thread | None = None
        self._declared: list[Any] = []
        self._open = False
        self._life = threading.Lock()

    # -- life cycle ---------------------------------------------------------------------

    @property
    def is_open(self) -> bool:
        """True between :meth:`open` and :meth:`close`."""
        return self._open

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("the bus is not open")
        return self._session

    def open(self) -> DetectionBus:
        """Open the session, start the detection thread, subscribe and declare the queryable."""
        with self._life:
            if self._session is not None:
                raise RuntimeError("the bus is already open")
            self._stopping = False
            session = zenoh.open(self._config)
            self._session = session
            self._thread = threading.Thread(target=self._work, name="dlo-zenoh", daemon=True)
            self._thread.start()
            self._declared = [
                session.declare_subscriber(IMAGE_KEYS, self._on_sample),
                session.declare_queryable(QUERY_KEY, self._on_query),
            ]
            self._open = True
        logger.info("zenoh bus open (session %s)", session.zid())
        return self

    def close(self) -> None:
        """Stop taking samples, let the running detection finish, close the session.

        Frames still waiting are dropped; waiting queries get an error reply. Waits for an
        :meth:`open` running in another thread, so that no session is left behind.
        """
        with self._life:
            if self._session is None:
                return
            self._open = False
            for entity in self._declared:
                entity.undeclare()
            self._declared = []
            with self._condition:
                self._stopping = True
                left = list(self._pending.values())
                self._pending.clear()
                self._condition.notify_all()
            if self._thread is not None:
                self._thread.join(timeout=30)
            for job in left:
                if job.query is not None:
                    self._reply_error(job.query, "unavailable", "the service is shutting down")
            self._session.close()
            self._session = None
        logger.info("zenoh bus closed")

    def __enter__(self) -> DetectionBus:
        return self.open()

    def __exit__(self, *_: object) -> None:
        self.close()

    def pending(self, camera: str) -> int:
        """Frames of ``camera`` waiting for detection: 0 or 1."""
        with self._condition:
            return sum(1 for kind, name in self._pending if kind == "camera" and name == camera)

    # -- zenoh callbacks (zenoh's threads: keep them short) -------------------------------

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        camera = str(sample.key_expr).split("/")[1]
        job = _Job(sample.payload.to_bytes(), sample.attachment, camera=camera)
        with self._condition:
            if self._stopping:
                return
            key = ("camera", camera)
            if key in self._pending:
                self._count("replaced")
                logger.debug("camera %s: frame replaced by a newer one before detection", camera)
            self._pending[key] = job  # keeps its place in the line, with the newest image
            self._condition.notify()

    def _on_query(self, query: zenoh.Query) -> None:
        payload = query.payload
        with self._condition:
            busy = self._stopping or self._queries_waiting >= self.max_queries
            if not busy:
                image = payload.to_bytes() if payload is not None else b""
                self._pending[("query", self._next_query)] = _Job(
                    image, query.attachment, query=query
                )
                self._next_query += 1
                self._queries_waiting += 1
                self._condition.notify()
                return
        self._count_query("busy")
        self._reply_error(
            query, "busy", f"{self.max_queries} queries are already waiting; retry in a second"
        )

    # -- the detection thread -----------------------------------------------------------

    def _work(self) -> None:
        while True:
            with self._condition:
                while not self._pending and not self._stopping:
                    self._condition.wait()
                if self._stopping:
                    return
                _, job = self._pending.popitem(last=False)
                if job.query is not None:
                    self._queries_waiting -= 1
            try:
                self._process(job)
            except Exception:  # publishing itself failed: log, keep serving
                logger.exception("zenoh bus: could not deliver a result")

    def _process(self, job: _Job) -> None:
        where = f"camera {job.camera}" if job.query is None else "query dlo/detect"
        try:
            if not job.image:
                raise RequestError(422, "invalid_image", "image: empty payload (0 bytes)")
            if len(job.image) > self.max_bytes:
                raise RequestError(
                    413,
                    "image_too_large",
                    f"image: {len(job.image)} bytes, more than the limit of {self.max_bytes}",
                )
            params = params_from_attachment(job.attachment)
            check_upload(job.image, "image", self.max_pixels)
            _, detection = run_detection(
                Frame(job.image, params), self._detect, self.max_pixels, self.max_detect_seconds
            )
        except RequestError as exc:
            if exc.code == OVER_BUDGET:
                self.metrics.over_budget.inc()
            logger.warning("%s: sample rejected: %s", where, exc.message)
            self._fail(job, "rejected", exc.code, exc.message)
            return
        except Exception:
            logger.exception("%s: detection failed", where)
            self.metrics.detection_failures.inc()
            self._fail(job, "failed", "internal", "detection failed inside the service")
            return
        self.metrics.observe_detection(detection)
        body = detection.model_dump_json()
        # counted first, so that whoever receives the result sees the count already
        if job.query is not None:
            self._count_query("answered")
            with job.query:  # finalised (dropped) on exit, so the querier is not left waiting
                job.query.reply(QUERY_KEY, body, encoding=JSON)
        else:
            assert job.camera is not None
            self._count("published")
            self.session.put(chains_key(job.camera), body, encoding=JSON)

    def _fail(self, job: _Job, outcome: str, code: str, message: str) -> None:
        if job.query is not None:
            self._count_query(outcome)
            self._reply_error(job.query, code, message)
            return
        assert job.camera is not None
        self._count(outcome)
        record = {"camera": job.camera, "error": code, "detail": message}
        self.session.put(errors_key(job.camera), json.dumps(record), encoding=JSON)

    @staticmethod
    def _reply_error(query: zenoh.Query, code: str, message: str) -> None:
        with query:
            query.reply_err(json.dumps({"error": code, "detail": message}), encoding=JSON)

    def _count(self, outcome: str) -> None:
        self.counts[outcome] += 1
        self.metrics.bus_frames.labels(outcome).inc()

    def _count_query(self, outcome: str) -> None:
        self.counts[f"query_{outcome}"] += 1
        self.metrics.bus_queries.labels(outcome).inc()
