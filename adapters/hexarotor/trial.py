"""The aerial grasp experiment: approaches to detected cable points, flown against the fake.

:func:`trial_targets` picks grasp points on cables detected in a generated scene;
:func:`run_trials` starts the fake hexarotor (:mod:`adapters.hexarotor.fake_vehicle`) on a
free loopback UDP port, connects :class:`~adapters.hexarotor.driver.MavlinkVehicle` to it
and flies one approach per target. The error reported is the fake's ground truth: the
distance between the gripper and the grasp point at the instant the vehicle received the
close-gripper command.
"""

from __future__ import annotations

import math
import socket
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from adapters.grasp.errors import GraspPlanningError
from adapters.grasp.target import plan_grasp
from adapters.hexarotor.approach import ApproachConfig, ned_from_enu, yaw_ned_from_enu
from adapters.hexarotor.clock import LockstepClock, WallClock
from adapters.hexarotor.driver import MavlinkVehicle
from adapters.hexarotor.fake_dynamics import Disturbance
from adapters.hexarotor.fake_vehicle import Autopilot, FakeVehicle
from schemas import CameraModel, GraspSelector, GraspTarget

TRIAL_CAMERA = CameraModel(
    fx=900.0,
    fy=900.0,
    cx=320.0,
    cy=180.0,
    width=640,
    height=360,
    T_base_camera=(
        (1.0, 0.0, 0.0, 0.30),
        (0.0, -1.0, 0.0, 0.00),
        (0.0, 0.0, -1.0, 0.60),
        (0.0, 0.0, 0.0, 1.0),
    ),
    surface={"plane_z": 0.0},
)
"""The camera of ``docs/examples/camera.json``: 640 x 360 px, 0.6 m above the table, facing down."""

CELL_ORIGIN_NED = (1.5, 0.0, -1.0)
"""Where the robot cell's origin (on the table top) lies in the vehicle's local NED frame:
1.5 m north of the take-off point and 1 m above the ground."""

TRIAL_APPROACH = ApproachConfig(approach_speed_m_s=0.4)
"""The adapter's defaults (0.5 m standoff, 10 mm tolerance, 0.3 s dwell, gripper 0.40 m ahead
of and 0.20 m below the vehicle origin) with a brisker final move (0.4 m/s, not 0.25)."""

TAKEOFF_HEIGHT_M = 1.0
"""The vehicle takes off from the ground to this height before the first approach."""

TRIAL_SCENE_CABLES = 3
TRIAL_FRACTIONS = (0.15, 0.85)
"""Grasp points are drawn uniformly between these fractions of a chain's length."""


@dataclass(frozen=True)
class TrialTarget:
    """One grasp target of the experiment, in the cell frame and in local NED."""

    grasp: GraspTarget
    target_ned: tuple[float, float, float]
    heading_ned: float
    """The vehicle faces along the cable so that its gripper, closing across the body
    (left-right), closes across the cable: heading = closing direction - 90 degrees."""


@dataclass
class TrialOutcome:
    """Errors of the closed approaches and the reasons of the failed ones."""

    errors_m: list[float] = field(default_factory=list)
    """Ground truth: gripper to grasp point when the close command arrived."""
    measured_errors_m: list[float] = field(default_factory=list)
    """What the adapter measured (noisy telemetry) when it decided to close."""
    failures: list[str] = field(default_factory=list)
    simulated_s: float = 0.0
    """The vehicle's time the trials took (simulated in lockstep), s."""

    def summary(self) -> dict[str, float | int]:
        """Number of tests, max, mean and sample standard deviation of the error, mm."""
        errors = np.asarray(self.errors_m) * 1000.0
        count = len(errors)
        return {
            "trials": count + len(self.failures),
            "closed": count,
            "failed": len(self.failures),
            "max_mm": float(errors.max()) if count else math.nan,
            "mean_mm": float(errors.mean()) if count else math.nan,
            "std_mm": float(errors.std(ddof=1)) if count > 1 else 0.0,
        }


def trial_targets(trials: int, seed: int) -> list[TrialTarget]:
    """Grasp targets on cables detected in one generated scene seen by :data:`TRIAL_CAMERA`.

    The scene comes from :func:`service.synthetic.make_scene`, the chains from
    :func:`service.perception.pipeline.detect`, each point from
    :func:`adapters.grasp.target.plan_grasp` at a random fraction of a random chain (points on
    inferred segments are drawn again).
    """
    from service.perception.pipeline import detect
    from service.synthetic import make_scene

    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    scene = make_scene(
        TRIAL_CAMERA.width,
        TRIAL_CAMERA.height,
        TRIAL_SCENE_CABLES,
        seed=seed,
        margin=20.0,
        loops=False,
    )
    detection = detect(scene.image)
    if not detection.chains:
        raise ValueError(f"no cable detected in the scene of seed {seed}")
    rng = np.random.default_rng(seed)
    chain_ids = sorted(chain.id for chain in detection.chains)
    targets: list[TrialTarget] = []
    attempts = 0
    while len(targets) < trials:
        attempts += 1
        if attempts > 50 * trials:
            raise ValueError(f"too few graspable points in the scene of seed {seed}")
        selector = GraspSelector(
            chain=int(rng.choice(chain_ids)),
            point={"kind": "fraction", "value": float(rng.uniform(*TRIAL_FRACTIONS))},
        )
        try:
            grasp = plan_grasp(detection, TRIAL_CAMERA, selector)
        except GraspPlanningError:
            continue
        target = ned_from_enu(grasp.position_m, CELL_ORIGIN_NED)
        closing_ned = yaw_ned_from_enu(grasp.yaw_rad)
        heading = math.remainder(closing_ned - math.pi / 2, 2 * math.pi)
        targets.append(TrialTarget(grasp, tuple(float(v) for v in target), heading))
    return targets


def run_trials(
    targets: list[TrialTarget],
    *,
    seed: int,
    autopilot: Autopilot = "ardupilot",
    disturbance: Disturbance | None = None,
    config: ApproachConfig | None = None,
    on_trial: Callable[[int, TrialTarget, float | None, str], None] | None = None,
    realtime: bool = False,
) -> TrialOutcome:
    """Fly one approach per target against a fresh fake vehicle; collect the errors.

    The fake runs in this process on its own thread, sending to a free loopback UDP
    port that the adapter listens on. The vehicle takes off from the ground, flies the
    approaches (the gripper opens again between them) and lands.

    By default the fake and the adapter run in lockstep on the fake's simulated clock
    (:class:`~adapters.hexarotor.clock.LockstepClock`): as fast as the two can exchange
    their messages, and the same outcome for the same seed on every run. ``realtime``
    runs both on the wall clock instead, as against a vehicle or SITL in real time (the
    outcome then varies a little from run to run with the machine's timing).
    """
    config = config or TRIAL_APPROACH
    port = free_udp_port()
    outcome = TrialOutcome()
    fake = FakeVehicle(
        f"udpout:127.0.0.1:{port}",
        autopilot=autopilot,
        seed=seed,
        disturbance=disturbance,
        end_effector_frd=config.end_effector_frd,
        lockstep=not realtime,
    )
    clock = WallClock() if realtime else LockstepClock()
    vehicle = MavlinkVehicle(f"udpin:127.0.0.1:{port}", clock=clock)
    with fake, vehicle:
        vehicle.wait_for_state()
        vehicle.set_guided_mode()
        vehicle.arm()
        vehicle.take_off(TAKEOFF_HEIGHT_M)
        for index, target in enumerate(targets):
            report = vehicle.approach(target.target_ned, target.heading_ned, config)
            if not report.ok:
                outcome.failures.append(report.reason)
                if on_trial is not None:
                    on_trial(index, target, None, report.reason)
                if report.reason == "link lost":
                    break
                continue
            closed = [event for event in fake.gripper_events if event.grab][-1]
            error = float(np.linalg.norm(np.subtract(closed.end_effector_ned, target.target_ned)))
            outcome.errors_m.append(error)
            outcome.measured_errors_m.append(float(report.error_m))
            if on_trial is not None:
                on_trial(index, target, error, "closed")
            vehicle.set_gripper(False)
        vehicle.land()
        outcome.simulated_s = fake.sim_time_s
    return outcome


def format_trial_table(summary: dict[str, float | int]) -> str:
    """The paper's table as Markdown: number of tests, max, mean and std of the error."""
    return "\n".join(
        [
            "| Number of tests | Max error (mm) | Mean error (mm) | Std (mm) |",
            "|---:|---:|---:|---:|",
            f"| {summary['closed']} | {summary['max_mm']:.2f} | {summary['mean_mm']:.2f} "
            f"| {summary['std_mm']:.2f} |",
        ]
    )


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port on ``host`` that nothing was bound to a moment ago (for the fake's link)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])
