"""``dlo grasp``: plan a grasp from a detection (dry run) or pick it with a UR3.

A typer sub-app; ``service/cli.py`` registers it with
``app.add_typer(grasp_app, name="grasp")``.

stdout carries the JSON result only; errors go to stderr as ``error: <problem>``.
Exit status: 0 done, 1 the pick failed mid-sequence, 2 a usage error, an
unplannable grasp, or a refusal before any motion.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from pydantic import ValidationError

from adapters.grasp import GraspPlanningError, plan_grasp
from adapters.ur3 import RobotNotReadyError, UnsafeTargetError, UR3Config, UR3Picker, plan_motions
from schemas import CameraModel, Detection, GraspSelector, GraspTarget

grasp_app = typer.Typer(
    name="grasp",
    help="Plan a grasp on a detected cable and pick it with a UR3.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

DetectionOption = Annotated[
    Path, typer.Option("--detection", "-d", help="Detection JSON (dlo detect output).")
]
CameraOption = Annotated[
    Path, typer.Option("--camera", "-c", help="Camera model, JSON (YAML with PyYAML).")
]
ChainOption = Annotated[str, typer.Option(help="Chain id, or 'longest'.")]
FractionOption = Annotated[
    float | None, typer.Option(help="Point at this fraction (0..1) of the arc length.")
]
SegmentOption = Annotated[int | None, typer.Option(help="Midpoint of this segment.")]
PixelOption = Annotated[
    tuple[float, float] | None, typer.Option(help="Point nearest to this pixel X Y.")
]
EndOption = Annotated[str | None, typer.Option(help="'start' or 'end' of the chain.")]
InferredOption = Annotated[
    bool, typer.Option("--allow-inferred", help="Allow a point on an inferred segment.")
]


def _fail(message: str, status: int = 2) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(status)


def _selector(
    chain: str,
    fraction: float | None,
    segment: int | None,
    pixel: tuple[float, float] | None,
    end: str | None,
    allow_inferred: bool,
) -> GraspSelector:
    options = {"fraction": fraction, "segment": segment, "pixel": pixel, "end": end}
    given = [name for name, value in options.items() if value is not None]
    if len(given) > 1:
        _fail(f"give at most one of --fraction, --segment, --pixel, --end (got {given})")
    if fraction is not None:
        point = {"kind": "fraction", "value": fraction}
    elif segment is not None:
        point = {"kind": "segment", "index": segment}
    elif pixel is not None:
        point = {"kind": "pixel", "x": pixel[0], "y": pixel[1]}
    elif end is not None:
        point = {"kind": "end", "end": end}
    else:
        point = {"kind": "fraction", "value": 0.5}
    chain_choice: int | str = int(chain) if chain.isdigit() else chain
    try:
        return GraspSelector(chain=chain_choice, point=point, allow_inferred=allow_inferred)
    except ValidationError as error:
        _fail(f"invalid grasp selection: {_first_error(error)}")


def _first_error(error: ValidationError) -> str:
    first = error.errors()[0]
    where = ".".join(str(part) for part in first["loc"])
    return f"{where}: {first['msg']}" if where else first["msg"]


def _plan(
    detection_path: Path, camera_path: Path, selector: GraspSelector
) -> tuple[GraspTarget, CameraModel]:
    try:
        detection = Detection.model_validate_json(detection_path.read_text(encoding="utf-8"))
    except (OSError, ValidationError) as error:
        _fail(f"{detection_path}: {error}")
    try:
        camera = CameraModel.from_file(camera_path)
    except (OSError, ValueError) as error:
        _fail(f"{camera_path}: {error}")
    try:
        return plan_grasp(detection, camera, selector), camera
    except GraspPlanningError as error:
        _fail(str(error))


@grasp_app.command("plan")
def plan_command(
    detection: DetectionOption,
    camera: CameraOption,
    chain: ChainOption = "longest",
    fraction: FractionOption = None,
    segment: SegmentOption = None,
    pixel: PixelOption = None,
    end: EndOption = None,
    allow_inferred: InferredOption = False,
) -> None:
    """Print the grasp target and the UR3 motions it would take (a dry run: no robot)."""
    selector = _selector(chain, fraction, segment, pixel, end, allow_inferred)
    target, _ = _plan(detection, camera, selector)
    motions = plan_motions(target, UR3Config())
    result = {
        "target": target.model_dump(mode="json"),
        "motions": [motion.model_dump(mode="json", exclude_none=True) for motion in motions],
    }
    typer.echo(json.dumps(result, indent=2))


@grasp_app.command("pick")
def pick_command(
    detection: DetectionOption,
    camera: CameraOption,
    robot_ip: Annotated[str, typer.Option("--robot-ip", help="UR3 controller address.")],
    chain: ChainOption = "longest",
    fraction: FractionOption = None,
    segment: SegmentOption = None,
    pixel: PixelOption = None,
    end: EndOption = None,
    allow_inferred: InferredOption = False,
) -> None:
    """Plan the grasp, check the robot and workspace, then pick: MOVES THE ROBOT."""
    selector = _selector(chain, fraction, segment, pixel, end, allow_inferred)
    target, _ = _plan(detection, camera, selector)
    picker = UR3Picker(robot_ip)
    try:
        picker.open()
    except Exception as error:  # ur_rtde raises RuntimeError on a refused connection
        _fail(f"could not connect to the robot at {robot_ip}: {error}")
    try:
        report = picker.pick(target)
    except (UnsafeTargetError, RobotNotReadyError) as error:
        _fail(f"refused, nothing sent: {error}")
    finally:
        picker.close()
    typer.echo(report.model_dump_json(indent=2))
    if not report.ok:
        _fail(f"pick failed: {report.reason}", status=1)
