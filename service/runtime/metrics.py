"""Prometheus metrics of one service instance, in a registry of its own."""

from __future__ import annotations

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    Info,
    generate_latest,
)

from schemas import Detection, StageTimings

STAGE_BUCKETS_S = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)
"""Histogram buckets for detection stages, in seconds (1 ms .. 10 s)."""


class Metrics:
    """The service's counters and histograms.

    Each instance has its own :class:`CollectorRegistry`, so that several apps (tests,
    or an HTTP and a zenoh front end later) never clash in the global one.
    """

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        self.requests = Counter(
            "dlo_http_requests",
            "HTTP requests answered, by route template, method and status code.",
            ("route", "method", "status"),
            registry=self.registry,
        )
        self.request_seconds = Histogram(
            "dlo_http_request_duration_seconds",
            "Time from request to response, by route template.",
            ("route",),
            registry=self.registry,
        )
        self.stage_seconds = Histogram(
            "dlo_detection_stage_seconds",
            "Time spent in each detection stage (from the Detection's timings_ms).",
            ("stage",),
            buckets=STAGE_BUCKETS_S,
            registry=self.registry,
        )
        self.frames_dropped = Counter(
            "dlo_frames_dropped",
            "Frames rejected with 503 because every worker and queue slot was taken.",
            registry=self.registry,
        )
        self.detection_failures = Counter(
            "dlo_detection_failures",
            "Detections that failed inside the service (answered with 500).",
            registry=self.registry,
        )
        self.over_budget = Counter(
            "dlo_detection_over_budget",
            "Detections stopped at their time budget (DLO_MAX_DETECT_SECONDS), answered "
            "with 422 time_budget_exceeded.",
            registry=self.registry,
        )
        self.in_flight = Gauge(
            "dlo_detections_in_flight",
            "Detections running or waiting in the queue.",
            registry=self.registry,
        )
        self.bus_frames = Counter(
            "dlo_zenoh_frames",
            "Samples received on the zenoh bus, by outcome: published, replaced (a newer "
            "frame of the same camera arrived before it was processed), rejected (not an "
            "image or bad parameters), failed (detection failed inside the service) or "
            "not_owned (another replica's camera, dropped before decoding).",
            ("outcome",),
            registry=self.registry,
        )
        self.bus_replica = Info(
            "dlo_zenoh_replica",
            "This replica's id (its zenoh session's), as in its token dlo/@replicas/<id> and "
            "in the attachment of its results.",
            registry=self.registry,
        )
        self.bus_replicas = Gauge(
            "dlo_zenoh_replicas",
            "Live replicas sharing this one's cameras (liveliness tokens under "
            "dlo/@replicas/), itself included once announced.",
            registry=self.registry,
        )
        self.bus_cameras_active = Gauge(
            "dlo_zenoh_cameras_active",
            "Cameras that sent a frame lately (the ones the replicas share out).",
            registry=self.registry,
        )
        self.bus_cameras_owned = Gauge(
            "dlo_zenoh_cameras_owned",
            "Active cameras this replica detects; the other replicas drop their frames.",
            registry=self.registry,
        )
        self.bus_handovers = Counter(
            "dlo_zenoh_handovers",
            "Cameras handed over when replicas came or went: gained by this replica, or lost "
            "to another.",
            ("direction",),
            registry=self.registry,
        )
        self.bus_queries = Counter(
            "dlo_zenoh_queries",
            "Queries on dlo/detect, by outcome: answered, rejected, failed or busy.",
            ("outcome",),
            registry=self.registry,
        )
        self.ready = Gauge(
            "dlo_ready", "1 once the warm-up detection has finished.", registry=self.registry
        )

    def observe_detection(self, detection: Detection) -> None:
        """Record the stage timings of one finished detection."""
        for stage in StageTimings.model_fields:
            milliseconds = getattr(detection.timings_ms, stage)
            self.stage_seconds.labels(stage).observe(milliseconds / 1000.0)

    def render(self) -> bytes:
        """The Prometheus text exposition of every metric."""
        return generate_latest(self.registry)
