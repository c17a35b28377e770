"""Detection over zenoh: images in on ``dlo/<camera>/image``, Detections out on ``.../chains``.

:class:`DetectionBus` opens a zenoh session (see :func:`~service.bus.config.service_config`)
and

* subscribes to its image keys (``dlo/*/image`` unless told otherwise): the payload is an
  encoded JPEG or PNG, the optional attachment a JSON object of detection parameters
  (:class:`schemas.DetectParams`), the frame's identity (:class:`schemas.FrameIdentity`:
  ``frame_id``, ``capture_time``) and optionally ``mask``: a PNG or JPEG of the image's
  size, non-zero on cable pixels, as base64 text (:data:`MASK_FIELD`), detected from as
  HTTP's ``mask`` upload is. The Detection JSON is published on
  ``dlo/<camera>/chains``, and the same detection as a CDR
  ``visualization_msgs/msg/MarkerArray`` on ``dlo/<camera>/markers`` (ROS 2 through
  zenoh-bridge-ros2dds, :mod:`service.bus.ros`); a sample that cannot be processed (not an
  image, bad parameters, too large) gives an error record ``{"camera", "error", "detail"}``
  on ``dlo/<camera>/errors`` instead. All carry :class:`schemas.ResultAttachment` (the
  identity given back, the frame sample's zenoh timestamp, this replica's id);
* takes ROS 2 frames of the same cameras beside them: a CDR ``sensor_msgs/msg/Image`` on
  ``dlo/<camera>/image_raw``, a ``sensor_msgs/msg/CompressedImage`` on
  ``.../image_raw/compressed`` (the message's ``header.stamp`` is the frame's
  ``capture_time`` unless a JSON attachment gives one; any other attachment is ignored).
  They are the camera's frames as any other: the same owner, the latest one wins;
* shares the cameras with the other replicas of its pool (:mod:`service.bus.ownership`):
  it announces itself with a liveliness token under ``dlo/@replicas/`` and detects only the
  frames of the cameras it owns; the others' frames are dropped before decoding;
* tracks the cameras it is asked to (``tracking``, :mod:`service.bus.tracks`): their frames'
  :class:`schemas.Tracks` go to ``dlo/<camera>/tracks`` too, with the same attachment;
* answers queries on ``dlo/detect``, declared *complete*, so that a ``get`` with zenoh's
  default target (``BEST_MATCHING``) reaches one replica: the query's payload is the image,
  its attachment as a frame's; the reply is the Detection JSON, or an error reply holding
  ``{"error", "detail"}``.

Detection runs in one thread per bus. Latest frame wins: per camera only the newest
frame waits; a frame replaced before it was processed is dropped and counted. Queries
are never replaced, but at most ``max_queries`` wait; beyond that they are refused.
"""

from __future__ import annotations

import base64
import binascii
import json
import logging
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh
from pydantic import ValidationError

from schemas import DetectParams, FrameIdentity, ResultAttachment
from schemas.bus import IDENTITY_FIELDS
from service.batch import describe_json_validation_error
from service.bus.config import (
    CDR,
    IMAGE_KEYS,
    JSON,
    QUERY_KEY,
    chains_key,
    errors_key,
    markers_key,
    ros_image_keys,
)
from service.bus.ownership import CAMERA_IDLE_S, Ownership, replicas_key
from service.bus.ros import (
    ENCODED,
    frame_kind,
    markers_payload,
    read_ros_frame,
    ros_attachment,
    with_stamp,
)
from service.bus.tracks import CameraTrackers, tracks_key
from service.ros.messages import warm_up as warm_up_ros_messages
from service.runtime.errors import RequestError
from service.runtime.frames import Frame, check_frame, check_upload
from service.runtime.jobs import (
    OVER_BUDGET,
    DetectFunction,
    budget,
    decode_upload_mask,
    default_detect,
    detect_decoded,
    run_detection,
)
from service.runtime.metrics import Metrics

logger = logging.getLogger(__name__)

RENDEZVOUS_LEARN_S = 1.0
"""How long a newcomer watches the pool before announcing itself, with plain rendezvous."""


MASK_FIELD = "mask"
"""The attachment key of a frame's mask: a PNG or JPEG file as base64 text (RFC 4648)."""


@dataclass(frozen=True)
class FrameAttachment:
    """What a frame's (or a query's) attachment holds."""

    identity: FrameIdentity
    params: DetectParams
    mask: bytes | None = None
    """The encoded mask (PNG or JPEG), not yet decoded or checked; None: segment the image."""


def read_attachment(attachment: zenoh.ZBytes | None) -> FrameAttachment:
    """The frame's identity, the detection parameters and the mask a sample's attachment
    holds.

    The attachment is a JSON object: ``frame_id`` and ``capture_time`` are the identity,
    :data:`MASK_FIELD` the mask, any other key a parameter; any part may be missing, or the
    whole attachment (defaults, no mask).

    Raises
    ------
    RequestError
        422 ``invalid_attachment`` when it is not a JSON object or the identity is invalid,
        ``invalid_params`` when a parameter is, ``invalid_mask`` when the mask is not base64
        text (the identity is then in ``identity`` of :class:`AttachmentError`, so that the
        error record can still carry it).
    """
    if attachment is None:
        return FrameAttachment(FrameIdentity(), DetectParams())
    try:
        fields = json.loads(attachment.to_bytes())
    except (ValueError, UnicodeDecodeError) as exc:
        reason = exc.msg if isinstance(exc, json.JSONDecodeError) else "not UTF-8 text"
        raise AttachmentError(
            422, "invalid_params", f"attachment: not JSON ({reason}); send a JSON object"
        ) from None
    if not isinstance(fields, dict):
        raise AttachmentError(
            422, "invalid_params", f"attachment: a JSON {type(fields).__name__}, not an object"
        )
    identity_fields = {name: fields.pop(name) for name in IDENTITY_FIELDS if name in fields}
    mask_text = fields.pop(MASK_FIELD, None)
    try:
        identity = FrameIdentity.model_validate(identity_fields)
    except ValidationError as exc:
        problems = describe_json_validation_error(exc, "attachment")
        raise AttachmentError(422, "invalid_attachment", f"frame identity: {problems}") from None
    try:
        params = DetectParams.model_validate(fields)
    except ValidationError as exc:
        problems = describe_json_validation_error(exc, "attachment")
        raise AttachmentError(
            422, "invalid_params", f"parameters: {problems}", identity=identity
        ) from None
    return FrameAttachment(identity, params, _mask_bytes(mask_text, identity))


def _mask_bytes(text: object, identity: FrameIdentity) -> bytes | None:
    """The mask file the attachment's base64 text holds (None: no mask)."""
    if text is None:
        return None
    if not isinstance(text, str):
        raise AttachmentError(
            422,
            "invalid_mask",
            f"attachment: {MASK_FIELD} is a JSON {type(text).__name__}; send the mask's PNG "
            "file as base64 text",
            identity=identity,
        )
    try:
        data = base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise AttachmentError(
            422,
            "invalid_mask",
            f"attachment: {MASK_FIELD} is not base64 text; send the mask's PNG file as base64",
            identity=identity,
        ) from None
    if not data:
        raise AttachmentError(
            422, "invalid_mask", f"attachment: {MASK_FIELD} is empty (0 bytes)", identity=identity
        )
    return data


def params_from_attachment(attachment: zenoh.ZBytes | None) -> DetectParams:
    """The parameters of :func:`read_attachment` (defaults without an attachment)."""
    return read_attachment(attachment).params


@dataclass
class AttachmentError(RequestError):
    """An attachment the service cannot use; ``identity``: the frame's, when it was valid."""

    identity: FrameIdentity = field(default_factory=FrameIdentity)


@dataclass
class _Job:
    """One image waiting for detection: a camera frame, or a query to answer."""

    image: bytes
    attachment: zenoh.ZBytes | None
    camera: str | None = None
    query: zenoh.Query | None = None
    timestamp: zenoh.Timestamp | None = None
    """The zenoh timestamp of the frame's sample, when it has one."""
    kind: str = ENCODED
    """What the payload is: an encoded image, or a ROS 2 message (:mod:`service.bus.ros`)."""
    received_s: float = field(default_factory=time.monotonic)
    """When the sample arrived (the time tracking goes by without a capture time)."""


class DetectionBus:
    """Serve detection on a zenoh session; see the module's documentation.

    Parameters
    ----------
    config : zenoh.Config, optional
        The session's configuration (see :func:`~service.bus.config.service_config`);
        default: zenoh's (a peer).
    detect : callable, optional
        ``detect(image, params, mask, deadline) -> Detection``; default
        :func:`service.perception.detect`.
    metrics : Metrics, optional
        Counters to update (the HTTP app's when the bus runs inside it); default: its own.
    max_pixels, max_bytes : int
        Largest image accepted, in pixels and in encoded bytes.
    max_queries : int
        Queries that may wait for the detection thread; beyond that they are refused.
    image_keys : sequence of str
        The key expressions of the frames to take (``dlo/<camera or pattern>/image``), and
        with each its ROS 2 keys (``.../image_raw``, ``.../image_raw/compressed``).
        Replicas with the same keys share their cameras; other keys make another pool.
    balanced : bool
        How the pool splits its cameras (:func:`service.bus.ownership.assign`).
    camera_idle_s : float
        A camera without a frame for this long no longer counts as active.
    learn_s : float, optional
        A replica that finds others already serving watches this long before it announces
        itself (and takes cameras), so that it knows the replicas and, balanced, the active
        cameras as they do; default ``camera_idle_s`` balanced, else
        :data:`RENDEZVOUS_LEARN_S`. A replica alone announces itself at once.
    max_detect_seconds : float, optional
        Time budget of one detection (decoding included); past it the frame or query
        gets the error ``time_budget_exceeded`` and the thread goes on. None: no limit.
    tracking : CameraTrackers, optional
        Track the cameras it names: each of their frames' Tracks goes to
        ``dlo/<camera>/tracks`` too (:mod:`service.bus.tracks`).
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
        image_keys: Sequence[str] = (IMAGE_KEYS,),
        balanced: bool = True,
        camera_idle_s: float = CAMERA_IDLE_S,
        learn_s: float | None = None,
        max_detect_seconds: float | None = None,
        tracking: CameraTrackers | None = None,
    ) -> None:
        self._config = config if config is not None else zenoh.Config()
        self._detect = detect if detect is not None else default_detect
        self.metrics = metrics if metrics is not None else Metrics()
        self.max_pixels = max_pixels
        self.max_bytes = max_bytes
        self.max_queries = max_queries
        self.image_keys = tuple(dict.fromkeys(image_keys))
        self.balanced = balanced
        self.camera_idle_s = camera_idle_s
        if learn_s is None:
            learn_s = camera_idle_s if balanced else RENDEZVOUS_LEARN_S
        self.learn_s = learn_s
        self.replicas_key = replicas_key(self.image_keys)
        """The pool's liveliness prefix; this replica's token is ``<it>/<replica id>``."""
        self.max_detect_seconds = max_detect_seconds
        self.tracking = tracking
        """Per-camera trackers (:mod:`service.bus.tracks`); None: nothing is tracked."""
        self.counts: Counter[str] = Counter()
        """Outcomes so far: ``published``, ``replaced``, ``rejected``, ``failed``,
        ``not_owned``, ``tracked`` for frames, ``query_answered`` ... for queries (also in
        ``metrics``)."""
        self._pending: OrderedDict[tuple[str, Any], _Job] = OrderedDict()
        self._queries_waiting = 0
        self._next_query = 0
        self._condition = threading.Condition()
        self._stopping = False
        self._session: zenoh.Session | None = None
        self._thread: threading.Thread | None = None
        self._announcing: threading.Timer | None = None
        self._declared: list[Any] = []
        self._ownership: Ownership | None = None
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

    @property
    def ownership(self) -> Ownership:
        """Which cameras this replica detects, among which replicas (once open)."""
        if self._ownership is None:
            raise RuntimeError("the bus is not open")
        return self._ownership

    @property
    def replica_id(self) -> str:
        """This replica's id: its zenoh session's id (once open)."""
        return self.ownership.me

    def open(self) -> DetectionBus:
        """Open the session, start the detection thread, join the pool of replicas,
        subscribe to the frames and declare the queryable."""
        with self._life:
            if self._session is not None:
                raise RuntimeError("the bus is already open")
            self._stopping = False
            warm_up_ros_messages()  # no frame waits for rosbags to generate its code
            session = zenoh.open(self._config)
            self._session = session
            ownership = Ownership(
                str(session.zid()),
                balanced=self.balanced,
                camera_idle_s=self.camera_idle_s,
                on_handover=self._count_handover,
            )
            self._ownership = ownership
            self._watch_metrics(ownership)
            self._thread = threading.Thread(target=self._work, name="dlo-zenoh", daemon=True)
            self._thread.start()
            liveliness = session.liveliness()
            # Asked before the subscriber is declared: zenoh answers a get that follows a
            # liveliness subscriber at once from that subscriber's (still empty) view. The
            # answer only decides whether to watch first; the members come from the
            # subscriber alone, whose history and removals are one consistent stream.
            others = {
                _replica_of(reply.ok.key_expr)
                for reply in liveliness.get(f"{self.replicas_key}/*", timeout=2.0)
                if reply.ok is not None
            }
            self._declared = [
                liveliness.declare_subscriber(
                    f"{self.replicas_key}/*", self._on_replica, history=True
                ),
                *(
                    session.declare_subscriber(key, self._on_sample)
                    for image_key in self.image_keys
                    for key in (image_key, *ros_image_keys(image_key))
                ),
                session.declare_queryable(QUERY_KEY, self._on_query, complete=True),
            ]
            if others and self.learn_s > 0:
                # learn the members (and, balanced, the active cameras) before taking any
                self._announcing = threading.Timer(self.learn_s, self._announce)
                self._announcing.daemon = True
                self._announcing.start()
            else:
                self._announce_now(session, ownership)
            self._open = True
        logger.info(
            "zenoh bus open: replica %s, %s other replica(s) under %s/, frames of %s",
            ownership.me,
            len(others),
            self.replicas_key,
            ", ".join(self.image_keys),
        )
        return self

    def _announce(self) -> None:
        with self._life:
            if self._session is not None and self._ownership is not None and self._open:
                self._announce_now(self._session, self._ownership)

    def _announce_now(self, session: zenoh.Session, ownership: Ownership) -> None:
        key = f"{self.replicas_key}/{ownership.me}"
        self._declared.append(session.liveliness().declare_token(key))
        ownership.announce()
        logger.info("replica %s announced on %s; owns %s", ownership.me, key, ownership.owned())

    def close(self) -> None:
        """Stop taking samples, let the running detection finish, close the session.

        Frames still waiting are dropped; waiting queries get an error reply. Waits for an
        :meth:`open` running in another thread, so that no session is left behind.
        """
        if self._announcing is not None:
            self._announcing.cancel()
        with self._life:
            if self._session is None:
                return
            self._open = False
            if self._ownership is not None:
                self._ownership.withdraw()  # from now on, the others' cameras only
            for entity in reversed(self._declared):  # the token first: hand the cameras over
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

    def _watch_metrics(self, ownership: Ownership) -> None:
        metrics = self.metrics
        metrics.bus_replica.info({"replica": ownership.me})
        metrics.bus_replicas.set_function(lambda: len(ownership.replicas))
        metrics.bus_cameras_owned.set_function(lambda: len(ownership.owned()))
        metrics.bus_cameras_active.set_function(ownership.active)

    # -- zenoh callbacks (zenoh's threads: keep them short) -------------------------------

    def _on_replica(self, sample: zenoh.Sample) -> None:
        replica = _replica_of(sample.key_expr)
        ownership = self.ownership
        if sample.kind == zenoh.SampleKind.PUT:
            if ownership.replica_seen(replica):
                logger.info("replica %s joined; owning %s", replica, ownership.owned())
        elif ownership.replica_gone(replica):
            logger.info("replica %s left; owning %s", replica, ownership.owned())

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        key = str(sample.key_expr)
        camera = key.split("/")[1]
        if not self.ownership.owns(camera):  # another replica's: not even copied
            with self._condition:
                self._count("not_owned")
            if self.tracking is not None:
                self.tracking.forget(camera)  # a new session should it come back
            return
        job = _Job(
            sample.payload.to_bytes(),
            sample.attachment,
            camera=camera,
            timestamp=sample.timestamp,
            kind=frame_kind(key),
        )
        with self._condition:
            if self._stopping:
                return
            key = ("camera", camera)
            if key in self._pending:
                self._count("replaced")
                logger.debug("camera %s: frame replaced by a newer one before detection", camera)
                if self.tracking is not None:
                    self.tracking.lose(camera)
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
        identity = FrameIdentity()
        image = None
        try:
            ros = job.kind != ENCODED
            attached = read_attachment(ros_attachment(job.attachment) if ros else job.attachment)
            identity, params, mask = attached.identity, attached.params, attached.mask
            if not job.image:
                raise RequestError(422, "invalid_image", "image: empty payload (0 bytes)")
            for name, data in (("image", job.image), ("mask", mask)):
                if data is not None and len(data) > self.max_bytes:
                    raise RequestError(
                        413,
                        f"{name}_too_large",
                        f"{name}: {len(data)} bytes, more than the limit of {self.max_bytes}",
                    )
            encoded = job.image
            if ros:
                deadline = budget(self.max_detect_seconds)  # counted from here, as below
                frame = read_ros_frame(job.kind, job.image, self.max_pixels)
                identity = with_stamp(identity, frame.stamp_s)
                if frame.image is not None:
                    image = frame.image
                    decoded_mask = None
                    if mask is not None:
                        check_upload(mask, "mask", self.max_pixels)
                        decoded_mask = decode_upload_mask(mask, image.shape)
                    detection = detect_decoded(image, params, self._detect, decoded_mask, deadline)
                encoded = frame.encoded
            if encoded is not None:
                upload = Frame(encoded, params, mask)
                check_frame(upload, self.max_pixels)
                image, detection = run_detection(
                    upload, self._detect, self.max_pixels, self.max_detect_seconds
                )
        except RequestError as exc:
            if isinstance(exc, AttachmentError):
                identity = exc.identity
            if exc.code == OVER_BUDGET:
                self.metrics.over_budget.inc()
            logger.warning("%s: sample rejected: %s", where, exc.message)
            self._fail(job, identity, "rejected", exc.code, exc.message)
            return
        except Exception:
            logger.exception("%s: detection failed", where)
            self.metrics.detection_failures.inc()
            self._fail(job, identity, "failed", "internal", "detection failed inside the service")
            return
        self.metrics.observe_detection(detection)
        body = detection.model_dump_json()
        attachment = self._result_attachment(job, identity)
        # counted first, so that whoever receives the result sees the count already
        if job.query is not None:
            self._count_query("answered")
            with job.query:  # finalised (dropped) on exit, so the querier is not left waiting
                job.query.reply(QUERY_KEY, body, encoding=JSON, attachment=attachment)
        else:
            assert job.camera is not None
            self._count("published")
            self.session.put(chains_key(job.camera), body, encoding=JSON, attachment=attachment)
            markers = markers_payload(detection, job.camera, identity, job.timestamp)
            self.session.put(markers_key(job.camera), markers, encoding=CDR, attachment=attachment)
            if self.tracking is not None and self.tracking.tracks(job.camera):
                self._publish_tracks(job, detection, image, identity, attachment)

    def _publish_tracks(self, job, detection, image, identity, attachment) -> None:
        """Track a camera frame's detection and publish the Tracks on ``.../tracks``."""
        assert self.tracking is not None and job.camera is not None
        try:
            tracks = self.tracking.follow(job.camera, detection, image, identity, job.received_s)
        except Exception:  # the chains went out; tracking this frame failed: log it
            logger.exception("camera %s: tracking failed", job.camera)
            self.tracking.lose(job.camera)
            return
        self.counts["tracked"] += 1  # beside published, not a sample outcome of its own
        self.session.put(
            tracks_key(job.camera), tracks.model_dump_json(), encoding=JSON, attachment=attachment
        )

    def _result_attachment(self, job: _Job, identity: FrameIdentity) -> str:
        """The :class:`ResultAttachment` of every result of ``job``'s frame, as JSON."""
        stamp = job.timestamp
        return ResultAttachment(
            **identity.model_dump(),
            sample_timestamp=None if stamp is None else stamp.to_string_rfc3339_lossy(),
            replica=self.replica_id,
        ).model_dump_json()

    def _fail(
        self, job: _Job, identity: FrameIdentity, outcome: str, code: str, message: str
    ) -> None:
        if job.query is not None:
            self._count_query(outcome)
            self._reply_error(job.query, code, message)
            return
        assert job.camera is not None
        attachment = self._result_attachment(job, identity)
        self._count(outcome)
        if self.tracking is not None:
            self.tracking.lose(job.camera)
        record = {"camera": job.camera, "error": code, "detail": message}
        self.session.put(
            errors_key(job.camera), json.dumps(record), encoding=JSON, attachment=attachment
        )

    @staticmethod
    def _reply_error(query: zenoh.Query, code: str, message: str) -> None:
        # zenoh's error replies carry no attachment; the querier knows which query it asked
        with query:
            query.reply_err(json.dumps({"error": code, "detail": message}), encoding=JSON)

    def _count_handover(self, direction: str, cameras: int) -> None:
        self.metrics.bus_handovers.labels(direction).inc(cameras)

    def _count(self, outcome: str) -> None:
        self.counts[outcome] += 1
        self.metrics.bus_frames.labels(outcome).inc()

    def _count_query(self, outcome: str) -> None:
        self.counts[f"query_{outcome}"] += 1
        self.metrics.bus_queries.labels(outcome).inc()


def _replica_of(key_expr: zenoh.KeyExpr) -> str:
    """The replica id at the end of a liveliness key ``dlo/@replicas/.../<id>``."""
    return str(key_expr).rsplit("/", 1)[1]
