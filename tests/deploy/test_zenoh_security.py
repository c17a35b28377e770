"""deploy/zenoh/secure/: mutual TLS and access control on a real zenoh router, on loopback.

The site's certificates are issued in each test by ``make-certs.sh`` (the script users run),
the router is opened from ``router.json5`` and the clients from ``client.json5``, with only
the paths and the port rewritten. A denied message is always followed, on the same link, by an
allowed one that travels to the same receiver; once the allowed one has arrived, the denied
one would have arrived before it had the router let it through (zenoh keeps a link's order).
"""

from __future__ import annotations

import contextlib
import json
import queue
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from tests.helpers import free_port, wait_until

SECURE = Path(__file__).resolve().parents[2] / "deploy" / "zenoh" / "secure"
TIMEOUT_S = 15.0

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl")


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A site's certificates, and a second CA's camera certificate (an impostor)."""
    root = tmp_path_factory.mktemp("site")
    subprocess.run([str(SECURE / "make-certs.sh"), str(root / "tls")], check=True)
    subprocess.run([str(SECURE / "make-certs.sh"), str(root / "other")], check=True)
    return root


def _set(config: zenoh.Config, key: str, value) -> None:
    config.insert_json5(key, json.dumps(value))


@pytest.fixture(scope="module")
def router(site: Path) -> Iterator[int]:
    """The locked-down router on a free loopback port; yields the port."""
    port = free_port()
    config = zenoh.Config.from_file(str(SECURE / "router.json5"))
    _set(config, "listen/endpoints", [f"tls/127.0.0.1:{port}"])
    tls = site / "tls"
    _set(config, "transport/link/tls/root_ca_certificate", str(tls / "ca.pem"))
    _set(config, "transport/link/tls/listen_certificate", str(tls / "router.pem"))
    _set(config, "transport/link/tls/listen_private_key", str(tls / "router-key.pem"))
    session = zenoh.open(config)
    try:
        yield port
    finally:
        session.close()


def client_config(port: int, tls: Path, role: str | None) -> zenoh.Config:
    """``client.json5`` pointed at the test router, with ``role``'s certificate (or none)."""
    config = zenoh.Config.from_file(str(SECURE / "client.json5"))
    _set(config, "connect/endpoints", [f"tls/localhost:{port}"])
    # fail at once instead of waiting for the router for ever, as a device would
    _set(config, "connect/timeout_ms", 3000)
    _set(config, "connect/exit_on_failure", True)
    _set(config, "transport/link/tls/root_ca_certificate", str(tls / "ca.pem"))
    if role is None:
        _set(config, "transport/link/tls/enable_mtls", False)
        _set(config, "transport/link/tls/connect_certificate", None)
        _set(config, "transport/link/tls/connect_private_key", None)
    else:
        _set(config, "transport/link/tls/connect_certificate", str(tls / f"{role}.pem"))
        _set(config, "transport/link/tls/connect_private_key", str(tls / f"{role}-key.pem"))
    return config


@contextlib.contextmanager
def joined(router: int, site: Path, role: str) -> Iterator[zenoh.Session]:
    session = zenoh.open(client_config(router, site / "tls", role))
    try:
        yield session
    finally:
        session.close()


class Inbox:
    """Every ``(key, payload)`` a subscriber of ``session`` receives on ``key_expr``."""

    def __init__(self, session: zenoh.Session, key_expr: str) -> None:
        self.samples: queue.Queue[tuple[str, bytes]] = queue.Queue()
        self.subscriber = session.declare_subscriber(
            key_expr, lambda s: self.samples.put((str(s.key_expr), s.payload.to_bytes()))
        )

    def next(self) -> tuple[str, bytes]:
        return self.samples.get(timeout=TIMEOUT_S)


def publisher_when_heard(session: zenoh.Session, key: str) -> zenoh.Publisher:
    """A publisher on ``key``, once the router has told it that someone subscribes."""
    publisher = session.declare_publisher(key)
    wait_until(lambda: publisher.matching_status.matching, f"a subscriber of {key}")
    return publisher


def test_a_client_without_a_certificate_cannot_connect(router: int, site: Path) -> None:
    with pytest.raises(zenoh.ZError):
        zenoh.open(client_config(router, site / "tls", None))


def test_a_certificate_of_another_ca_cannot_connect(router: int, site: Path) -> None:
    impostor = client_config(router, site / "tls", "camera")
    other = site / "other"
    _set(impostor, "transport/link/tls/connect_certificate", str(other / "camera.pem"))
    _set(impostor, "transport/link/tls/connect_private_key", str(other / "camera-key.pem"))
    with pytest.raises(zenoh.ZError):
        zenoh.open(impostor)


def test_frames_reach_services_and_results_reach_robots(router: int, site: Path) -> None:
    with (
        joined(router, site, "service") as service,
        joined(router, site, "robot") as robot,
        joined(router, site, "dashboard") as dashboard,
        joined(router, site, "camera") as camera,
    ):
        frames = Inbox(service, "dlo/*/image")
        results = Inbox(robot, "dlo/*/chains")
        watched_frames = Inbox(dashboard, "dlo/*/image")
        watched_results = Inbox(dashboard, "dlo/*/chains")
        publisher_when_heard(camera, "dlo/cam1/image").put(b"frame 1")
        assert frames.next() == ("dlo/cam1/image", b"frame 1")
        assert watched_frames.next() == ("dlo/cam1/image", b"frame 1")
        publisher_when_heard(service, "dlo/cam1/chains").put(b"chains 1")
        assert results.next() == ("dlo/cam1/chains", b"chains 1")
        assert watched_results.next() == ("dlo/cam1/chains", b"chains 1")


def test_only_services_answer_detect_and_cameras_may_ask(router: int, site: Path) -> None:
    with joined(router, site, "service") as service, joined(router, site, "camera") as camera:
        queryable = service.declare_queryable(
            "dlo/detect", lambda query: query.reply("dlo/detect", b"detection")
        )
        try:
            wait_until(
                lambda: any(r.ok for r in camera.get("dlo/detect", timeout=1.0)),
                "the camera's query to be answered",
            )
        finally:
            queryable.undeclare()


def test_a_camera_may_not_publish_results(router: int, site: Path) -> None:
    with joined(router, site, "dashboard") as dashboard, joined(router, site, "camera") as camera:
        # the results subscription first: once the router has passed on the frames one
        # (which the camera waits for), it has taken this one too
        watched_results = Inbox(dashboard, "dlo/*/chains")
        watched_frames = Inbox(dashboard, "dlo/*/image")
        frames = publisher_when_heard(camera, "dlo/cam1/image")
        camera.put("dlo/cam1/chains", b"forged chains")  # denied at the router ...
        frames.put(b"frame after")  # ... and this one, on the same link, allowed
        assert watched_frames.next() == ("dlo/cam1/image", b"frame after")
        assert watched_results.samples.empty()


def test_a_robot_may_not_publish_frames_nor_subscribe_to_them(router: int, site: Path) -> None:
    with joined(router, site, "service") as service, joined(router, site, "robot") as robot:
        frames = Inbox(service, "dlo/*/image")
        seen_by_robot = Inbox(robot, "dlo/*/image")
        results = service.declare_publisher("dlo/cam1/chains")
        robot.put("dlo/cam1/image", b"forged frame")  # denied at the router ...
        later = Inbox(robot, "dlo/*/chains")  # ... and this declaration, on the same link, allowed
        wait_until(lambda: results.matching_status.matching, "the robot's later subscription")
        assert frames.samples.empty()
        # the robot's image subscription was refused: a service's frame does not reach it
        assert later.samples.empty()
        results.put(b"chains")
        assert later.next() == ("dlo/cam1/chains", b"chains")
        assert seen_by_robot.samples.qsize() == 1  # only its own put, delivered locally


def test_two_service_replicas_share_the_cameras_through_the_locked_down_router(
    router: int, site: Path
) -> None:
    """The replicas' liveliness tokens, their complete queryable and their results are
    allowed by the rules: each frame gives one result, and a camera's query one reply."""
    from schemas import ResultAttachment
    from service.bus.detection import DetectionBus
    from tests.service.test_replicas import Cameras, Results, quick_detect

    def replica() -> DetectionBus:
        config = client_config(router, site / "tls", "service")
        return DetectionBus(config, detect=quick_detect, learn_s=0.0)

    with (
        replica() as first,
        replica() as second,
        joined(router, site, "robot") as robot,
        joined(router, site, "camera") as camera,
    ):
        wait_until(
            lambda: len(first.ownership.replicas) == len(second.ownership.replicas) == 2,
            "the replicas to see each other's tokens",
        )
        results = Results(robot)
        cameras = Cameras(camera, ["cam1", "cam2", "cam3", "cam4"])
        rounds = []
        for _ in range(3):
            rounds.append(cameras.send_round())
            assert results.wait_for(rounds[-1])
        everything = [frame for frames in rounds for frame in frames]
        assert [results.times_answered(frame) for frame in everything] == [1] * 12
        # both replicas answered the last round: any second answer would have come before
        assert results.replicas_of(rounds[-1]) == {first.replica_id, second.replica_id}

        replies = list(camera.get("dlo/detect", payload=cameras.image))
        assert len(replies) == 1 and replies[0].ok is not None
        reply = ResultAttachment.model_validate_json(replies[0].ok.attachment.to_bytes())
        assert reply.replica in {first.replica_id, second.replica_id}
