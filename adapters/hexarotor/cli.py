"""``dlo hexa trial`` and ``dlo feasibility``: the paper's aerial experiments, runnable anywhere.

The ``dlo`` CLI (:mod:`service.cli`) names :data:`hexa_app` and :func:`feasibility` and
imports this module only when one of them runs. Importing it stays light: pymavlink, OpenCV,
SciPy and the detection are imported by the commands that use them.

``dlo hexa trial`` flies grasp approaches with the hexarotor adapter against the fake
vehicle (:mod:`adapters.hexarotor.trial`); ``dlo feasibility`` answers from the wrench-set
linear programs (:mod:`adapters.hexarotor.wrench`).

Output conventions follow the other ``dlo`` commands: stdout carries the result (the
table, or JSON with ``--json``), progress and errors go to stderr as one line each.
Exit status: 0 done, 1 a trial failed or the plot could not be written, 2 a usage error.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer

from adapters.hexarotor.wrench import (
    DEFAULT_ARM_LENGTH_M,
    DEFAULT_DRAG_COEFF_M,
    DEFAULT_MASS_KG,
    DEFAULT_MAX_THRUST_N,
    DEFAULT_TILT_DEG,
    HexarotorGeometry,
    pull_feasibility,
)
from service.console import EXIT_FAILED, exit_usage, print_error, stderr_console, typer_app

if TYPE_CHECKING:
    from adapters.hexarotor.trial import TrialTarget
    from adapters.hexarotor.wrench import PullFeasibility

hexa_app = typer_app(
    name="hexa",
    help="Fly grasp approaches with a hexarotor over MAVLink (against the built-in fake).",
)


@hexa_app.command("trial")
def trial_command(
    trials: Annotated[int, typer.Option(min=1, max=200, help="Number of approaches.")] = 20,
    seed: Annotated[int, typer.Option(help="Seed of the scene, the targets and the fake.")] = 1,
    autopilot: Annotated[
        str, typer.Option(help="Flavour of the fake: ardupilot (GUIDED) or px4 (OFFBOARD).")
    ] = "ardupilot",
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    realtime: Annotated[
        bool,
        typer.Option(
            "--realtime",
            help="Run the fake and the adapter on the wall clock (about 4 s a trial) instead "
            "of in lockstep on the fake's simulated clock (faster, the same table every run).",
        ),
    ] = False,
) -> None:
    """Fly grasp approaches to detected cable points with the fake hexarotor; print the errors.

    By default the fake vehicle runs on a simulated clock, in lockstep with the adapter
    over the real MAVLink link: faster than real time, and the same seed gives the same
    table on every run.
    """
    console = stderr_console()
    if autopilot not in ("ardupilot", "px4"):
        exit_usage(console, f"--autopilot must be ardupilot or px4, not {autopilot!r}")
    from adapters.hexarotor.driver import MavlinkError
    from adapters.hexarotor.fake_dynamics import Disturbance
    from adapters.hexarotor.trial import format_trial_table, run_trials, trial_targets

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
            targets,
            seed=seed,
            autopilot=autopilot,
            disturbance=disturbance,
            on_trial=progress,
            realtime=realtime,
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
            "clock": "wall" if realtime else "lockstep",
            "simulated_s": round(outcome.simulated_s, 3),
            "errors_mm": [round(e * 1000, 3) for e in outcome.errors_m],
            "measured_errors_mm": [round(e * 1000, 3) for e in outcome.measured_errors_m],
            "failures": outcome.failures,
            "disturbance": vars(disturbance),
        }
        typer.echo(json.dumps(result, indent=2))
    elif summary["closed"]:
        typer.echo(format_trial_table(summary))
    clock = "" if realtime else f" ({outcome.simulated_s:.0f} s simulated in lockstep)"
    console.print(
        f"{summary['closed']} of {summary['trials']} approaches closed the gripper "
        f"in {time.monotonic() - started:.1f} s{clock}",
        highlight=False,
    )
    if outcome.failures:
        print_error(console, f"{len(outcome.failures)} approaches failed: {outcome.failures}")
        raise typer.Exit(EXIT_FAILED)


@hexa_app.command("fake-vehicle")
def fake_vehicle_command(
    url: Annotated[
        str,
        typer.Option(
            metavar="URL",
            help="pymavlink URL to send from, e.g. udpout:127.0.0.1:14540 (a ground station "
            "or MAVSDK listening with udpin there).",
        ),
    ] = "udpout:127.0.0.1:14550",
    autopilot: Annotated[
        str, typer.Option(help="Behave as ardupilot (ArduCopter) or px4 toward the ground station.")
    ] = "ardupilot",
    seed: Annotated[int, typer.Option(help="Seed of the gusts and the sensor noise.")] = 0,
    home: Annotated[
        tuple[float, float, float] | None,
        typer.Option(
            metavar="LAT LON ALT",
            help="Home: latitude, longitude (deg) and altitude above sea level (m) of the "
            "local origin. [default: PX4 SITL's, 47.397742 8.545594 488]",
            show_default=False,
        ),
    ] = None,
    lockstep: Annotated[
        bool,
        typer.Option(
            "--lockstep",
            help="Step the simulation in lockstep with the ground station (it must answer "
            "TIMESYNC requests only when it has caught up, as dlo's LockstepClock does) "
            "instead of following the wall clock.",
        ),
    ] = False,
) -> None:
    """Run the SITL-free fake hexarotor until Ctrl-C, for a ground station or MAVSDK.

    It runs on the wall clock by default, as SITL without lockstep: a ground station, MAVSDK
    or QGroundControl keeps real time, and a simulated clock could only run as fast as it
    allows.
    """
    from adapters.hexarotor.fake_dynamics import Disturbance
    from adapters.hexarotor.fake_vehicle import DEFAULT_HOME, FakeVehicle, run_until_interrupted

    console = stderr_console()
    if autopilot not in ("ardupilot", "px4"):
        exit_usage(console, f"--autopilot must be ardupilot or px4, not {autopilot!r}")
    try:
        vehicle = FakeVehicle(
            url,
            autopilot=autopilot,
            seed=seed,
            disturbance=Disturbance(),
            home=home or DEFAULT_HOME,
            lockstep=lockstep,
        ).start()
    except (OSError, ValueError) as error:  # a URL pymavlink cannot open
        exit_usage(console, f"--url {url}: {error}")
    clock = "in lockstep" if lockstep else "in real time"
    console.print(f"fake {autopilot} hexarotor on {url}, {clock}; Ctrl-C stops it", highlight=False)
    run_until_interrupted(vehicle)


# -- feasibility ----------------------------------------------------------------------------


def feasibility(
    pull: Annotated[
        float,
        typer.Option(help="Force to exert ON the environment, N (e.g. 15.84 to unplug USB-A)."),
    ],
    direction: Annotated[
        tuple[float, float, float],
        typer.Option(
            metavar="X Y Z",
            help="Body direction of that force, three numbers separated by spaces, e.g. "
            "--direction 1 0 0 (x forward, y left, z up; any length).",
        ),
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
        import cv2

        from adapters.hexarotor.force_plot import draw_force_slice

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
