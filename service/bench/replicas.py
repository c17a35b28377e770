"""``dlo bench --service --replicas N``: does the zenoh work spread over replicas?

On loopback: a ``dlo router`` process, then in turn one and N replica processes (each a
:class:`~service.bus.detection.DetectionBus`, a client of the router, as ``dlo serve``
runs it), and C cameras in this process, each sending its next frame as soon as the
previous one's chains arrive (a closed loop: a camera never has two frames in flight, so
none is replaced). After a warm-up (the cameras appear, the replicas share them out), the
chains samples received in a fixed time give the throughput, and the ratio of N replicas'
to one replica's says how well the cameras are spread.

The detection is made CPU-light by default: it sleeps ``detect_ms`` instead of computing
(:func:`sleeping_detect`; the frame is still decoded, a 96x64 PNG). This machine has 2
cores, shared with other work: with the real detector, three replicas could never do more
than two cores' worth, and the zenoh threads, the decoding and the router take their share
of the same cores, so the figure would measure the cores, not the distribution. With
``detect_ms = 0`` the real detector runs on a 640x360 scene, for comparison.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import socket
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import asdict, dataclass

from service.bench.detector import THREAD_VARIABLES

READY_TIMEOUT_S = 180.0
"""A replica with the real detector compiles the kernels on a machine's first run."""
LOST_FRAME_S = 5.0
"""A frame without an answer by then is sent again (a sample lost on the way)."""
REPLICA_LEARN_S = 1.0
"""How long a replica that finds others watches before announcing itself (no frames flow
while the replicas start, so there is nothing to learn; the service's default is 10 s)."""
DLO = [sys.executable, "-c", "from service.cli import main; main()"]
REPLICA = [sys.executable, "-c", "from service.bench.replicas import replica_main; replica_main()"]


@dataclass
class Run:
    """What one configuration did."""

    replicas: int
    cameras: int
    frames: int
    seconds: float
    per_second: float
    frames_by_replica: list[int]
    """How many of the frames each replica detected, largest first."""
    cameras_by_replica: list[int]
    """How many cameras each replica answered for while measured, largest first."""


def sleeping_detect(detect_ms: float):
    """A detect function that waits ``detect_ms`` without using the CPU."""
    from schemas import Detection

    def detect(image, params, mask, deadline):
        time.sleep(detect_ms / 1000.0)
        return Detection(width=image.shape[1], height=image.shape[0], segment_length=10.0)

    return detect


def replica_main() -> None:
    """A replica process: ``... ENDPOINT DETECT_MS ASSIGNMENT``; serves until its stdin
    closes."""
    endpoint, detect_ms, assignment = sys.argv[1], float(sys.argv[2]), sys.argv[3]
    from service.bus.config import make_config
    from service.bus.detection import DetectionBus

    if detect_ms > 0:
        detect = sleeping_detect(detect_ms)
    else:
        from service.runtime.jobs import default_detect, warm_up

        warm_up(default_detect)
        detect = default_detect
    config = make_config(
        mode="client", connect=[endpoint], listen=[], multicast=False, gossip=False
    )
    balanced = assignment == "balanced"
    with DetectionBus(config, detect=detect, balanced=balanced, learn_s=REPLICA_LEARN_S) as bus:
        print(f"ready {bus.replica_id}", flush=True)
        sys.stdin.read()  # until the benchmark closes it (or dies)


def run_replica_bench(
    replicas: int,
    cameras: int,
    detect_ms: float,
    quick: bool,
    as_json: bool,
    assignment: str = "balanced",
) -> int:
    """Measure one replica, then ``replicas``; print a table (or JSON). Exit status."""
    seconds, warm_up_s = (2.0, 1.0) if quick else (10.0, 3.0)
    image = _frame(detect_ms)
    runs = []
    with _router() as endpoint:
        for count in dict.fromkeys((1, replicas)):
            with _replicas(endpoint, count, detect_ms, assignment) as ids:
                runs.append(_measure(endpoint, ids, cameras, image, seconds, warm_up_s))
    ratio = runs[-1].per_second / runs[0].per_second if runs[0].per_second else 0.0
    results = {
        "detection": f"sleep {detect_ms:g} ms (no CPU)" if detect_ms > 0 else "real, 640x360",
        "cameras": cameras,
        "assignment": assignment,
        "runs": [asdict(run) for run in runs],
        "ratio": ratio,
        "quick": quick,
    }
    if as_json:
        print(json.dumps(results, indent=2))
    else:
        _print_table(results, runs)
    return 0


def _frame(detect_ms: float) -> bytes:
    import cv2

    from service.synthetic import make_scene

    width, height = (96, 64) if detect_ms > 0 else (640, 360)
    scene = make_scene(width, height, 1 if detect_ms > 0 else 3, seed=0)
    encoded_ok, encoded = cv2.imencode(".png", scene.image)
    assert encoded_ok
    return encoded.tobytes()


@contextlib.contextmanager
def _router() -> Iterator[str]:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    endpoint = f"tcp/127.0.0.1:{port}"
    router = subprocess.Popen(
        [*DLO, "router", "--listen", endpoint, "--no-multicast"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 1):
                break
            if router.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("dlo router did not start")
            time.sleep(0.05)
        yield endpoint
    finally:
        router.terminate()
        router.wait(timeout=30)


@contextlib.contextmanager
def _replicas(endpoint: str, count: int, detect_ms: float, assignment: str) -> Iterator[list[str]]:
    """``count`` replica processes, each announced; yields their ids; stopped (and gone)
    on the way out."""
    processes = [
        subprocess.Popen(
            [*REPLICA, endpoint, str(detect_ms), assignment],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            # one thread per numeric library, as the other benchmarks (real detection)
            env=dict(os.environ, **dict.fromkeys(THREAD_VARIABLES, "1")),
        )
        for _ in range(count)
    ]
    try:
        ids = []
        for process in processes:
            assert process.stdout is not None
            line = process.stdout.readline().decode().split()
            if line[:1] != ["ready"]:
                raise RuntimeError("a replica did not start")
            ids.append(line[1])
        with _session(endpoint) as session:
            _wait(lambda: len(_tokens(session)) == count, f"{count} replicas announced")
        yield ids
    finally:
        for process in processes:
            assert process.stdin is not None
            process.stdin.close()
        for process in processes:
            process.wait(timeout=30)
        with _session(endpoint) as session:
            _wait(lambda: not _tokens(session), "the replicas' tokens to go")


@contextlib.contextmanager
def _session(endpoint: str) -> Iterator:
    import zenoh

    from service.bus.config import make_config

    config = make_config(
        mode="client", connect=[endpoint], listen=[], multicast=False, gossip=False
    )
    with zenoh.open(config) as session:
        yield session


def _tokens(session) -> list[str]:
    from service.bus.ownership import REPLICAS_KEY

    replies = session.liveliness().get(f"{REPLICAS_KEY}/*", timeout=5.0)
    return [str(reply.ok.key_expr) for reply in replies if reply.ok is not None]


def _wait(condition, what: str, timeout: float = READY_TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for {what}")
        time.sleep(0.05)


def _measure(
    endpoint: str, replicas: list[str], cameras: int, image: bytes, seconds: float, warm_up_s: float
) -> Run:
    """The closed loop of ``cameras`` cameras for ``warm_up_s`` then ``seconds``."""
    import zenoh

    from schemas import ResultAttachment

    names = [f"bench{number}" for number in range(cameras)]
    answered: queue.Queue[tuple[str, int, str, float]] = queue.Queue()

    def on_chains(sample: zenoh.Sample) -> None:
        attachment = ResultAttachment.model_validate_json(sample.attachment.to_bytes())
        camera = str(sample.key_expr).split("/")[1]
        answered.put((camera, int(attachment.frame_id), attachment.replica, time.monotonic()))

    with _session(endpoint) as session:
        subscriber = session.declare_subscriber("dlo/*/chains", on_chains)
        publishers = {
            name: session.declare_publisher(
                f"dlo/{name}/image", congestion_control=zenoh.CongestionControl.BLOCK
            )
            for name in names
        }
        _wait(lambda: all(p.matching_status.matching for p in publishers.values()), "replicas")
        waiting: dict[str, tuple[int, float]] = {}  # camera -> (frame id, sent at)
        next_id = 0

        def send(camera: str) -> None:
            nonlocal next_id
            next_id += 1
            waiting[camera] = (next_id, time.monotonic())
            publishers[camera].put(image, attachment=json.dumps({"frame_id": next_id}))

        for name in names:
            send(name)
        start = time.monotonic() + warm_up_s
        end = start + seconds
        counted: list[tuple[str, str]] = []
        while (now := time.monotonic()) < end:
            try:
                camera, frame_id, replica, at = answered.get(timeout=0.1)
            except queue.Empty:
                for camera, (_, sent) in list(waiting.items()):
                    if now - sent > LOST_FRAME_S:
                        send(camera)
                continue
            if waiting.get(camera, (None,))[0] != frame_id:
                continue  # a late answer to a frame already sent again
            if start <= at < end:
                counted.append((camera, replica))
            send(camera)
        subscriber.undeclare()
    frames_by_replica = Counter(dict.fromkeys(replicas, 0))
    frames_by_replica.update(replica for _, replica in counted)
    cameras_by_replica = Counter(dict.fromkeys(replicas, 0))
    cameras_by_replica.update(replica for _, replica in set(counted))
    return Run(
        replicas=len(replicas),
        cameras=cameras,
        frames=len(counted),
        seconds=seconds,
        per_second=len(counted) / seconds,
        frames_by_replica=sorted(frames_by_replica.values(), reverse=True),
        cameras_by_replica=sorted(cameras_by_replica.values(), reverse=True),
    )


def _print_table(results: dict, runs: list[Run]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title=f"zenoh replicas ({results['assignment']}): {results['cameras']} cameras, closed "
        f"loop, detection {results['detection']}"
    )
    for column in ("replicas", "frames/s", "frames per replica", "cameras per replica"):
        table.add_column(column, justify="right")
    for run in runs:
        table.add_row(
            str(run.replicas),
            f"{run.per_second:.1f}",
            " / ".join(map(str, run.frames_by_replica)),
            " / ".join(map(str, run.cameras_by_replica)),
        )
    console = Console()
    console.print(table)
    if len(runs) > 1:
        console.print(
            f"{runs[-1].replicas} replicas / 1 replica: [bold]{results['ratio']:.2f}x[/bold]"
        )
