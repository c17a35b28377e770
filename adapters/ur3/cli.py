"""``dlo ur3``: plan a grasp on a detected cable (a dry run) or pick it with a UR3.

A typer sub-app; the ``dlo`` CLI (:mod:`service.cli`) names :data:`ur3_app` and imports
this module only when ``dlo ur3`` runs. Tests build their own with
:func:`build_ur3_app` and a fake robot's ``connect``. Importing this module stays light:
detection, OpenCV and NumPy are imported by the steps that use them.

The input is an image (detected here, with the default parameters unless told) or a
Detection JSON written by ``dlo detect`` (``.json``). A camera whose surface is a depth
image needs ``--depth`` (a 16-bit PNG, or a ``.npy`` array) aligned with the image.
stdout carries the JSON result only; errors go to stderr as ``error: <problem>``. Exit
status: 0 done (a plan was printed, or the pick succeeded), 1 the pick failed
mid-sequence, 2 a usage error, an unreadable input, camera or depth file, an unplannable
grasp, or a refusal before any motion.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NoReturn

import typer
from pydantic import ValidationError

from adapters.errors import UnsafeTargetError
from adapters.grasp.errors import DepthImageError, GraspPlanningError
from adapters.ur3.driver import ConnectFactory, RobotNotReadyError, UR3Picker
from adapters.ur3.driver import connect as connect_ur_rtde
from schemas import CameraModel, DepthSurface, Detection, GraspSelector
from service.console import (
    EXIT_FAILED,
    EXIT_USAGE,
    print_error,
    print_warning,
    stderr_console,
    typer_app,
)

if TYPE_CHECKING:
    import numpy as np

    from schemas.grasp import GraspPlan

DETECTION_SUFFIX = ".json"
"""An input with this suffix is a saved Detection; anything else is an image to detect."""

InputArgument = Annotated[
    Path,
    typer.Argument(
        metavar="IMAGE",
        help="Image to detect the cables in, or a Detection JSON (.json) from `dlo detect`.",
        show_default=False,
    ),
]
CameraOption = Annotated[
    Path,
    typer.Option(
        "--camera",
        "-c",
        metavar="CAMERA",
        help="Camera model file, .json or .yaml (intrinsics, pose in the base frame, surface).",
        show_default=False,
    ),
]
DepthOption = Annotated[
    Path | None,
    typer.Option(
        "--depth",
        metavar="DEPTH",
        help="Depth image aligned with IMAGE, for a camera whose surface is 'depth': a "
        "16-bit PNG or a .npy array, in units of the surface's depth_scale.",
        show_default=False,
    ),
]
ChainOption = Annotated[
    str, typer.Option(metavar="ID", help="Chain id, or 'longest' (ties: the lowest id).")
]
FractionOption = Annotated[
    float | None,
    typer.Option(
        metavar="F",
        help="Point at this fraction (0..1) of the arc length; the default point.",
        show_default="0.5",
    ),
]
SegmentOption = Annotated[int | None, typer.Option(metavar="K", help="Midpoint of segment K.")]
PixelOption = Annotated[
    tuple[float, float] | None,
    typer.Option(metavar="X Y", help="Point of the chain nearest to this pixel."),
]
EndOption = Annotated[
    str | None, typer.Option(metavar="start|end", help="First or last point of the chain.")
]
InferredOption = Annotated[
    bool, typer.Option("--allow-inferred", help="Allow a point on an inferred segment.")
]
SegmentLengthOption = Annotated[
    float | None,
    typer.Option(metavar="PX", help="Segment length for detecting an image (as dlo detect)."),
]
ExpectedCountOption = Annotated[
    int | None,
    typer.Option(metavar="N", help="Number of cables in view, for detecting an image."),
]

POINT_OPTIONS = ("--fraction", "--segment", "--pixel", "--end")


def build_ur3_app(connect: ConnectFactory = connect_ur_rtde) -> typer.Typer:
    """The ``dlo ur3`` sub-app, opening robot connections with ``connect``.

    Parameters
    ----------
    connect
        ``connect(robot_ip) -> (control, receive, io)``: ur_rtde by default, a fake's
        ``connect`` in tests.
    """
    app = typer_app(name="ur3", help="Plan a grasp on a detected cable and pick it with a UR3.")

    @app.command("plan")
    def plan_command(
        input_path: InputArgument,
        camera: CameraOption,
        depth: DepthOption = None,
        chain: ChainOption = "longest",
        fraction: FractionOption = None,
        segment: SegmentOption = None,
        pixel: PixelOption = None,
        end: EndOption = None,
        allow_inferred: InferredOption = False,
        segment_length: SegmentLengthOption = None,
        expected_count: ExpectedCountOption = None,
    ) -> None:
        """Print the grasp target and the motions a pick would send, as JSON. No robot.

        The same as `dlo ur3 pick --dry-run`.
        """
        selector = selector_from_options(chain, fraction, segment, pixel, end, allow_inferred)
        plan = plan_from_files(input_path, camera, selector, segment_length, expected_count, depth)
        print_plan(plan)

    @app.command("pick")
    def pick_command(
        input_path: InputArgument,
        camera: CameraOption,
        depth: DepthOption = None,
        robot_ip: Annotated[
            str | None,
            typer.Option("--robot-ip", metavar="IP", help="UR3 controller address."),
        ] = None,
        dry_run: Annotated[
            bool,
            typer.Option(
                "--dry-run", help="Print the target and motions as JSON; no robot needed."
            ),
        ] = False,
        chain: ChainOption = "longest",
        fraction: FractionOption = None,
        segment: SegmentOption = None,
        pixel: PixelOption = None,
        end: EndOption = None,
        allow_inferred: InferredOption = False,
        segment_length: SegmentLengthOption = None,
        expected_count: ExpectedCountOption = None,
    ) -> None:
        """Detect, plan, check the robot and the workspace, then pick: MOVES THE ROBOT.

        Prints the pick report as JSON. With --dry-run, prints the plan instead and
        moves nothing.
        """
        selector = selector_from_options(chain, fraction, segment, pixel, end, allow_inferred)
        if robot_ip is None and not dry_run:
            fail("--robot-ip is required to pick (or give --dry-run to only plan)")
        plan = plan_from_files(input_path, camera, selector, segment_length, expected_count, depth)
        if dry_run:
            print_plan(plan)
            return
        assert robot_ip is not None
        pick(plan, robot_ip, connect)

    return app


def fail(message: str, status: int = EXIT_USAGE) -> NoReturn:
    """Print ``error: <message>`` on stderr and exit with ``status``."""
    print_error(stderr_console(), message)
    raise typer.Exit(status)


def selector_from_options(
    chain: str,
    fraction: float | None,
    segment: int | None,
    pixel: tuple[float, float] | None,
    end: str | None,
    allow_inferred: bool,
) -> GraspSelector:
    """The :class:`GraspSelector` of the command-line options (exit 2 when they conflict).

    At most one of ``--fraction``, ``--segment``, ``--pixel`` and ``--end`` may be
    given; none means the middle of the chain (fraction 0.5).
    """
    chosen = [
        name
        for name, value in zip(POINT_OPTIONS, (fraction, segment, pixel, end), strict=True)
        if value is not None
    ]
    if len(chosen) > 1:
        fail(f"give at most one of {', '.join(POINT_OPTIONS)}; got {' and '.join(chosen)}")
    if end is not None and end not in ("start", "end"):
        fail(f"--end: must be 'start' or 'end', got {end!r}")
    if chain != "longest" and not chain.isdigit():
        fail(f"--chain: must be a chain id (0, 1, ...) or 'longest', got {chain!r}")
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
        option = {"fraction": "--fraction", "segment": "--segment", "pixel": "--pixel"}
        fail(f"{option.get(point['kind'], 'grasp selection')}: {describe(error)}")


def plan_from_files(
    input_path: Path,
    camera_path: Path,
    selector: GraspSelector,
    segment_length: float | None = None,
    expected_count: int | None = None,
    depth_path: Path | None = None,
) -> GraspPlan:
    """Load the camera and depth, detect (or load) the chains and plan; exit 2 on any problem.

    The camera and the depth image are read first, so that a bad file is reported before
    the detection runs.
    """
    from adapters.grasp.pick import plan_pick

    camera = load_camera(camera_path)
    depth = load_depth(depth_path, camera)
    detection = load_or_detect(input_path, segment_length, expected_count)
    try:
        return plan_pick(detection, camera, selector, depth=depth)
    except (GraspPlanningError, DepthImageError) as error:
        fail(str(error))


def load_camera(path: Path) -> CameraModel:
    """:meth:`CameraModel.from_file`, with a one-line error naming the file (exit 2)."""
    try:
        return CameraModel.from_file(path)
    except OSError as error:
        fail(f"camera file {path}: {error.strerror or error}")
    except ValidationError as error:
        fail(f"camera file {path}: {describe(error)}")
    except ValueError as error:  # unknown suffix, YAML syntax, not UTF-8
        fail(f"camera file {path}: {str(error).removeprefix(f'{path}: ')}")


def load_depth(path: Path | None, camera: CameraModel) -> np.ndarray | None:
    """The depth image at ``path`` checked against ``camera``; None for a plane (exit 2).

    ``.npy``: a NumPy array (uint16 or float); anything else: an image file OpenCV reads
    unchanged, a single-channel 16-bit PNG. Refused: no ``--depth`` for a depth surface,
    a ``--depth`` for a plane, and a file that is unreadable, of another size than the
    camera's, with more than one channel or of another sample type.
    """
    if not isinstance(camera.surface, DepthSurface):
        if path is not None:
            fail(
                f"--depth: the camera's surface is the plane z = {camera.surface.plane_z} m; "
                'a depth image needs the surface {"kind": "depth", "depth_scale": ...}'
            )
        return None
    if path is None:
        fail(
            "the camera's surface is a depth image (kind 'depth'): give --depth DEPTH "
            "(a 16-bit PNG or a .npy array aligned with the image)"
        )
    from service.geometry3d.depth import check_depth_image, read_depth_file

    try:
        return check_depth_image(camera, read_depth_file(path))
    except OSError as error:
        fail(f"depth file {path}: {error.strerror or error}")
    except DepthImageError as error:
        fail(f"depth file {path}: {error}")


def load_or_detect(
    path: Path, segment_length: float | None, expected_count: int | None
) -> Detection:
    """A saved Detection (``.json``), or the detection of the image at ``path`` (exit 2)."""
    if path.suffix.lower() == DETECTION_SUFFIX:
        if segment_length is not None or expected_count is not None:
            fail(
                "--segment-length and --expected-count apply to an image; "
                f"{path} is a saved detection"
            )
        try:
            return Detection.model_validate_json(path.read_text(encoding="utf-8"))
        except OSError as error:
            fail(f"{path}: {error.strerror or error}")
        except ValidationError as error:
            fail(f"{path}: not a Detection: {describe(error)}")
        except ValueError as error:  # not UTF-8
            fail(f"{path}: {error}")
    from service.batch import (
        InvalidParametersError,
        build_params,
        failure_message,
        process_file,
    )
    from service.perception import InvalidInputError

    try:
        params = build_params(segment_length=segment_length, expected_count=expected_count)
    except InvalidParametersError as error:
        fail(str(error))
    try:
        return process_file(path, params, out_dir=None)
    except InvalidInputError as error:
        fail(failure_message(path, error))


def describe(error: ValidationError) -> str:
    """Every problem of a pydantic error on one line: ``field: message; ...``."""
    problems = []
    for detail in error.errors(include_url=False):
        message = str(detail["msg"]).removeprefix("Value error, ")
        where = ".".join(str(part) for part in detail["loc"])
        problems.append(f"{where}: {message}" if where else message)
    return "; ".join(problems)


def print_plan(plan: GraspPlan) -> None:
    """The plan as indented JSON on stdout; a warning on stderr when a pick would refuse it."""
    typer.echo(plan.model_dump_json(indent=2, exclude_none=True))
    if not plan.within_workspace:
        print_warning(stderr_console(), f"a pick would refuse this plan: {plan.refusal}")


def pick(plan: GraspPlan, robot_ip: str, connect: ConnectFactory) -> None:
    """Pick ``plan.target`` with the UR3 at ``robot_ip`` and print the report.

    Nothing is sent when the workspace or the robot's pre-checks refuse (exit 2); a
    failure during the sequence prints the report and exits 1.
    """
    if not plan.within_workspace:
        fail(f"refused, nothing sent: {plan.refusal}")
    picker = UR3Picker(robot_ip, connect=connect)
    try:
        picker.open()
    except Exception as error:  # ur_rtde raises RuntimeError on a refused connection
        picker.close()
        fail(f"could not connect to the robot at {robot_ip}: {error}")
    try:
        report = picker.pick(plan.target)
    except (UnsafeTargetError, RobotNotReadyError) as error:
        fail(f"refused, nothing sent: {error}")
    finally:
        picker.close()
    typer.echo(report.model_dump_json(indent=2))
    if not report.ok:
        fail(f"pick failed: {report.reason}", status=EXIT_FAILED)


ur3_app = build_ur3_app()
