"""``dlo hexa trial`` and ``dlo feasibility``: the paper's aerial experiments, runnable anywhere.

``service/cli.py`` registers them with ``app.add_typer(hexa_app, name="hexa")`` and
``app.command()(feasibility)``.

``dlo hexa trial`` starts the fake hexarotor (:mod:`adapters.fake_vehicle`) on a free
loopback UDP port, connects :class:`adapters.mavlink.MavlinkVehicle` to it, and flies
grasp approaches to cable points detected in a generated scene. The error reported is
the fake's ground truth: the distance between the gripper and the grasp point at the
instant the vehicle received the close-gripper command.

Output conventions follow the other ``dlo`` commands: stdout carries the result (the
table, or JSON with ``--json``), progress and errors go to stderr as one line each.
Exit status: 0 done, 1 a trial failed or the plot could not be written, 2 a usage error.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import cv2
import numpy as np
import typer

from adapters.fake_vehicle import Autopilot, Disturbance, FakeVehicle, free_udp_port
from adapters.grasp import GraspPlanningError, plan_grasp
from adapters.mavlink import (
    ApproachConfig,
    MavlinkError,
    MavlinkVehicle,
    ned_from_enu,
    yaw_ned_from_enu,
)
from adapters.wrench import (
    DEFAULT_ARM_LENGTH_M,
    DEFAULT_DRAG_COEFF_M,
    DEFAULT_MASS_KG,
    DEFAULT_MAX_THRUST_N,
    DEFAULT_TILT_DEG,
    HexarotorGeometry,
    PullFeasibility,
    pull_feasibility,
    slice_axis_for,
    slice_polygon,
)
from schemas import CameraModel, GraspSelector, GraspTarget
from service.console import EXIT_FAILED, exit_usage, print_error, stderr_console

hexa_app = typer.Typer(
    name="hexa",
    help="Fly grasp approaches with a hexarotor over MAVLink (against the built-in fake).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

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
    :func:`adapters.grasp.plan_grasp` at a random fraction of a random chain (points on
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
) -> TrialOutcome:
    """Fly one approach per target against a fresh fake vehicle; collect the errors.

    The fake runs in this process on its own thread, sending to a free loopback UDP
    port that the adapter listens on. Between approaches the gripper opens again.
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
    )
    vehicle = MavlinkVehicle(f"udpin:127.0.0.1:{port}")
    with fake, vehicle:
        vehicle.wait_for_state()
        vehicle.set_guided_mode()
        vehicle.arm()
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
        vehicle.hold()
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


@hexa_app.command("trial")
def trial_command(
    trials: Annotated[int, typer.Option(min=1, max=200, help="Number of approaches.")] = 20,
    seed: Annotated[int, typer.Option(help="Seed of the scene, the targets and the fake.")] = 1,
    autopilot: Annotated[
        str, typer.Option(help="Flavour of the fake: ardupilot (GUIDED) or px4 (OFFBOARD).")
    ] = "ardupilot",
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Fly grasp approaches to detected cable points with the fake hexarotor; print the errors."""
    console = stderr_console()
    if autopilot not in ("ardupilot", "px4"):
        exit_usage(console, f"--autopilot must be ardupilot or px4, not {autopilot!r}")
    try:
        targets = trial_targets(trials, seed)
    except ValueError as error:
        print_error(console, str(error))
        raise typer.Exit(EXIT_FAILED) from None

    def progress(index: int, target: TrialTarget, error: float | None, reason: str) -> None:
        shown = f"{error * 1000:.2f} mm" if error is not None else f"failed ({reason})"
        console.print(f"trial {index + 1}/{trials}: {shown}", highlight=False)

    started = time.monotonic()
    disturbance = Disturbance()
    try:
        outcome = run_trials(
            targets, seed=seed, autopilot=autopilot, disturbance=disturbance, on_trial=progress
        )
    except (MavlinkError, ValueError) as error:
        print_error(console, f"the fake vehicle link failed: {error}")
        raise typer.Exit(EXIT_FAILED) from None
    summary = outcome.summary()
    if as_json:
        result = {
            **summary,
            "seed": seed,
            "autopilot": autopilot,
            "errors_mm": [round(e * 1000, 3) for e in outcome.errors_m],
            "measured_errors_mm": [round(e * 1000, 3) for e in outcome.measured_errors_m],
            "failures": outcome.failures,
            "disturbance": vars(disturbance),
        }
        typer.echo(json.dumps(result, indent=2))
    elif summary["closed"]:
        typer.echo(format_trial_table(summary))
    console.print(
        f"{summary['closed']} of {summary['trials']} approaches closed the gripper "
        f"in {time.monotonic() - started:.0f} s",
        highlight=False,
    )
    if outcome.failures:
        print_error(console, f"{len(outcome.failures)} approaches failed: {outcome.failures}")
        raise typer.Exit(EXIT_FAILED)


# -- feasibility ----------------------------------------------------------------------------


def feasibility(
    pull: Annotated[
        float,
        typer.Option(help="Force to exert ON the environment, N (e.g. 15.84 to unplug USB-A)."),
    ],
    direction: Annotated[
        tuple[float, float, float],
        typer.Option(help="Body direction X Y Z of that force (x fwd, y left, z up)."),
    ],
    mass: Annotated[float, typer.Option(help="Vehicle mass, kg.")] = DEFAULT_MASS_KG,
    arm_length: Annotated[
        float, typer.Option(help="Rotor distance from the centre, m.")
    ] = DEFAULT_ARM_LENGTH_M,
    tilt_deg: Annotated[
        float, typer.Option(help="Alternating rotor tilt about the arm, degrees.")
    ] = DEFAULT_TILT_DEG,
    max_thrust: Annotated[
        float, typer.Option(help="Largest thrust of one rotor, N.")
    ] = DEFAULT_MAX_THRUST_N,
    drag_coeff: Annotated[
        float, typer.Option(help="Rotor drag torque per newton of thrust, m.")
    ] = DEFAULT_DRAG_COEFF_M,
    as_json: Annotated[
        bool, typer.Option("--json", help='Print {"feasible", "max_force_n", "margin_n"}.')
    ] = False,
    plot: Annotated[
        Path | None,
        typer.Option(metavar="FILE.png", help="Draw the slice of available forces here."),
    ] = None,
) -> None:
    """Can a fully-actuated hexarotor pull this hard while hovering with zero net torque?"""
    console = stderr_console()
    try:
        geometry = HexarotorGeometry(mass, arm_length, tilt_deg, max_thrust, drag_coeff)
        answer = pull_feasibility(geometry, pull, direction)
    except ValueError as error:
        exit_usage(console, str(error))
    unit = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    if not answer.hover_feasible:
        print_error(console, "the vehicle cannot hold its own weight with zero net torque")
    if as_json:
        typer.echo(
            json.dumps(
                {
                    "feasible": answer.feasible,
                    "max_force_n": round(answer.max_force_n, 4),
                    "margin_n": round(answer.margin_n, 4),
                }
            )
        )
    else:
        typer.echo(format_feasibility(geometry, pull, unit, answer))
    if plot is not None:
        if plot.suffix.lower() != ".png":
            exit_usage(console, f"--plot must name a .png file, not {plot}")
        try:
            image = draw_force_slice(geometry, pull, unit, answer)
        except ValueError as error:  # the vehicle cannot hover: nothing to draw
            print_error(console, f"no plot: {error}")
            raise typer.Exit(EXIT_FAILED) from None
        if not cv2.imwrite(str(plot), image):
            print_error(console, f"{plot}: could not write the plot")
            raise typer.Exit(EXIT_FAILED)
        console.print(f"plot written to {plot}", highlight=False)


def format_feasibility(
    geometry: HexarotorGeometry, pull: float, unit: np.ndarray, answer: PullFeasibility
) -> str:
    """The human-readable answer of ``dlo feasibility``."""
    shown = ", ".join(f"{v:.3f}" for v in unit)
    return "\n".join(
        [
            f"vehicle: {geometry.mass_kg:g} kg, 6 rotors at {geometry.arm_length_m:g} m tilted "
            f"+/-{geometry.tilt_deg:g} deg, max {geometry.max_thrust_n:g} N each, "
            f"drag {geometry.drag_coeff_m:g} m",
            f"pull on the environment: {pull:g} N along body [{shown}]",
            f"largest force along it while hovering at zero torque: {answer.max_force_n:.2f} N",
            f"margin: {answer.margin_n:+.2f} N",
            f"feasible: {'yes' if answer.feasible else 'no'}",
        ]
    )


PLOT_SIZE = (760, 720)
PLOT_MARGIN = (90, 60, 30, 70)
"""Left, top, right, bottom margins of the plot area, px."""


def _nice_step(span: float) -> float:
    raw = span / 8.0
    magnitude = 10 ** math.floor(math.log10(raw))
    for factor in (1, 2, 5, 10):
        if factor * magnitude >= raw:
            return factor * magnitude
    return 10 * magnitude  # pragma: no cover


def draw_force_slice(
    geometry: HexarotorGeometry, pull: float, unit: np.ndarray, answer: PullFeasibility
) -> np.ndarray:
    """Draw the forces the hovering vehicle can exert in the vertical plane holding the pull.

    The plane is spanned by the pull's horizontal part and body ``z`` (body ``y`` and ``z``
    for a vertical pull, the paper's view). Returns a BGR image.
    """
    axis = slice_axis_for(unit)
    polygon = slice_polygon(geometry, axis, samples=120)
    pull_point = np.array([pull * float(unit @ axis), pull * unit[2]])
    reach_point = pull_point * (answer.max_force_n / pull) if pull > 0 else pull_point
    extent = max(float(np.abs(polygon).max()), float(np.abs(pull_point).max()), 1.0) * 1.1
    step = _nice_step(2 * extent)
    limit = math.ceil(extent / step) * step

    width, height = PLOT_SIZE
    left, top, right, bottom = PLOT_MARGIN
    side = min(width - left - right, height - top - bottom)
    scale = side / (2 * limit)
    origin = np.array([left + side / 2, top + side / 2])

    def to_pixel(point: np.ndarray) -> tuple[int, int]:
        return (
            round(origin[0] + point[0] * scale),
            round(origin[1] - point[1] * scale),
        )

    image = np.full((height, width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    grey, dark = (225, 225, 225), (40, 40, 40)
    ticks = np.arange(-limit, limit + step / 2, step)
    for tick in ticks:
        x0, y0 = to_pixel(np.array([tick, -limit]))
        x1, y1 = to_pixel(np.array([tick, limit]))
        cv2.line(image, (x0, y0), (x1, y1), grey, 1)
        cv2.putText(image, f"{tick:g}", (x0 - 12, y0 + 22), font, 0.45, dark, 1, cv2.LINE_AA)
        x0, y0 = to_pixel(np.array([-limit, tick]))
        x1, y1 = to_pixel(np.array([limit, tick]))
        cv2.line(image, (x0, y0), (x1, y1), grey, 1)
        cv2.putText(image, f"{tick:g}", (x0 - 50, y0 + 5), font, 0.45, dark, 1, cv2.LINE_AA)
    cv2.rectangle(
        image, to_pixel(np.array([-limit, limit])), to_pixel(np.array([limit, -limit])), dark, 1
    )
    cv2.line(image, to_pixel(np.array([-limit, 0])), to_pixel(np.array([limit, 0])), dark, 1)
    cv2.line(image, to_pixel(np.array([0, -limit])), to_pixel(np.array([0, limit])), dark, 1)

    outline = np.array([to_pixel(p) for p in polygon], np.int32)
    fill = image.copy()
    cv2.fillPoly(fill, [outline], (235, 200, 150))
    image = cv2.addWeighted(fill, 0.6, image, 0.4, 0)
    cv2.polylines(image, [outline], True, (160, 90, 30), 2, cv2.LINE_AA)

    colour = (40, 160, 40) if answer.feasible else (40, 40, 220)
    cv2.arrowedLine(
        image, to_pixel(np.zeros(2)), to_pixel(pull_point), colour, 2, cv2.LINE_AA, tipLength=0.06
    )
    cv2.circle(image, to_pixel(reach_point), 5, (160, 90, 30), -1, cv2.LINE_AA)

    name = _axis_name(axis)
    cv2.putText(
        image,
        f"force along {name} (N)",
        (left + side // 2 - 110, top + side + 55),
        font,
        0.55,
        dark,
        1,
        cv2.LINE_AA,
    )
    label = np.full((30, 260, 3), 255, np.uint8)
    cv2.putText(label, "force along body z (N)", (5, 20), font, 0.55, dark, 1, cv2.LINE_AA)
    rotated = cv2.rotate(label, cv2.ROTATE_90_COUNTERCLOCKWISE)
    y0 = top + side // 2 - rotated.shape[0] // 2
    image[y0 : y0 + rotated.shape[0], 8 : 8 + rotated.shape[1]] = rotated
    verdict = "feasible" if answer.feasible else "NOT feasible"
    title = (
        f"Forces on the environment while hovering, zero torque ({geometry.mass_kg:g} kg, "
        f"tilt {geometry.tilt_deg:g} deg)"
    )
    cv2.putText(image, title, (left - 60, 25), font, 0.5, dark, 1, cv2.LINE_AA)
    legend = f"pull {pull:g} N: {verdict}; max {answer.max_force_n:.2f} N (dot)"
    cv2.putText(image, legend, (left - 60, 48), font, 0.5, colour, 1, cv2.LINE_AA)
    return image


def _axis_name(axis: np.ndarray) -> str:
    for name, unit in (("body x", (1, 0, 0)), ("body y", (0, 1, 0))):
        if np.allclose(axis, unit):
            return name
        if np.allclose(axis, -np.asarray(unit)):
            return f"-{name}"
    return f"body [{axis[0]:.2f}, {axis[1]:.2f}, 0]"
